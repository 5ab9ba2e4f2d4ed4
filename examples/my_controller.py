"""An example of your own controller, compared beside the built-in rows (README, "Compare your own controller").

Run it from the repository's root::

    PYTHONPATH=examples python -m eval --controllers pd,mid_f_r,my_controller:computed_torque,oracle
    PYTHONPATH=examples python -m eval.sweep --controllers pd,my_controller:computed_torque --episodes 4

``my_controller:computed_torque`` names a factory: it receives what a controller may know about the robot
(:class:`controllers.registry.ControllerSetup`: the identified parameters, the datasheet geometry and masses, the
PD gains) and returns a controller. A class constructible without arguments works the same way
(``my_controller:StiffPD``), and a :class:`controllers.registry.ControllerEntry` declares capabilities (a payload
estimate to score, a tare to measure).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation, PDController
from controllers.dynamics import DeltaDynamics
from controllers.registry import ControllerSetup
from delta_env import kinematics
from delta_env.trajectories import WORKING_HEIGHT


class StiffPD(PDController):
    """Joint PD feedback at twice the built-in stiffness: Kp 6000 N m/rad, Kd 80 N m s/rad."""

    name = "Stiff PD (example)"

    def __init__(self) -> None:
        super().__init__(kp=6000.0, kd=80.0)


class ComputedTorque:
    """Computed-torque control (inverse-dynamics control) on the identified model, without the payload:

        tau = M(theta) (thdd_ref + wn^2 e + 2 zeta wn e_dot) + h(theta, theta_dot),

    e = theta_ref - theta, h the model's gravity, Coriolis and friction torques, all at the measured joint
    state: the model cancels the arm's own dynamics and the error follows a second-order law of natural
    frequency ``wn`` and damping ratio ``zeta`` at every pose, where PD's stiffness is fixed in torque.

    Args:
        dynamics: The identified model of the robot.
        natural_frequency: wn (rad/s).
        damping_ratio: zeta (dimensionless).
    """

    name = "Computed torque (example)"

    def __init__(self, dynamics: DeltaDynamics, natural_frequency: float, damping_ratio: float) -> None:
        self.dynamics = dynamics
        self.kp = natural_frequency**2
        self.kd = 2.0 * damping_ratio * natural_frequency

    def reset(self) -> None:
        """No state."""

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        angles, velocities = observation["joint_angles"], observation["joint_velocities"]
        error = observation["reference_angles"] - angles
        error_rate = observation["reference_velocities"] - velocities
        acceleration = observation["reference_accelerations"] + self.kp * error + self.kd * error_rate
        return self.dynamics.inverse_dynamics(angles, velocities, acceleration)


def computed_torque(setup: ControllerSetup) -> ComputedTorque:
    """The factory of the row: :class:`ComputedTorque` on the robot's identified MId+F+R model, its error law as
    stiff and as damped as the built-in PD (``setup.pd_gains``) on the model's joint inertia at the conveyor's centre,
    so that the gain over PD is the model's and not stiffer feedback's."""
    model = DeltaDynamics.of_robot(setup.geometry, setup.masses, setup.mid_f_rods, forearm_rods=True)
    centre = kinematics.inverse(setup.geometry, np.array([0.0, 0.0, WORKING_HEIGHT]))
    still = np.zeros(3)
    # joint 1's own inertia: M e_1 = tau(theta, 0, e_1) - tau(theta, 0, 0); the three joints are alike there
    inertia = float(
        model.inverse_dynamics(centre, still, np.eye(3)[0])[0] - model.inverse_dynamics(centre, still, still)[0]
    )
    kp, kd = setup.pd_gains
    return ComputedTorque(model, math.sqrt(kp / inertia), kd / (2.0 * math.sqrt(kp * inertia)))


computed_torque.label = ComputedTorque.name
