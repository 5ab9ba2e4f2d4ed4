"""An example of your own controller, compared beside the built-in rows (README, "Compare your own controller").

Run it from the repository's root::

    PYTHONPATH=examples python -m eval --controllers pd,mid_f_rls_lag,my_controller:gravity_pd
    PYTHONPATH=examples python -m eval.sweep --controllers pd,my_controller:gravity_pd --episodes 4

``my_controller:gravity_pd`` names a factory: it receives what a controller may know about the robot
(:class:`controllers.registry.ControllerSetup`: the identified parameters, the datasheet geometry and masses, the
PD gains) and returns a controller. A class constructible without arguments works the same way
(``my_controller:StiffPD``), and a :class:`controllers.registry.ControllerEntry` declares capabilities (a payload
estimate to score, a tare to measure).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation, PDController
from controllers.dynamics import DeltaDynamics
from controllers.registry import ControllerSetup


class StiffPD(PDController):
    """Joint PD feedback at twice the built-in stiffness: Kp 6000 N m/rad, Kd 80 N m s/rad."""

    name = "Stiff PD (example)"

    def __init__(self) -> None:
        super().__init__(kp=6000.0, kd=80.0)


class GravityCompensatedPD:
    """PD feedback plus the identified model's static torque at the reference angles (gravity and the
    parallelogram's weight; no payload, no inertia, no friction).

    Args:
        dynamics: The identified model of the robot.
        kp: Proportional gain (N m/rad).
        kd: Derivative gain (N m s/rad).
    """

    name = "Gravity+PD (example)"

    def __init__(self, dynamics: DeltaDynamics, kp: float, kd: float) -> None:
        self.dynamics = dynamics
        self.pd = PDController(kp, kd)

    def reset(self) -> None:
        self.pd.reset()

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        angles = observation["reference_angles"]
        gravity = self.dynamics.inverse_dynamics(angles, np.zeros(3), np.zeros(3))
        return gravity + self.pd(observation)


def gravity_pd(setup: ControllerSetup) -> GravityCompensatedPD:
    """The factory of the row: :class:`GravityCompensatedPD` on the robot's identified MId+F+R model."""
    model = DeltaDynamics.of_robot(setup.geometry, setup.masses, setup.mid_f_rods, forearm_rods=True)
    return GravityCompensatedPD(model, *setup.pd_gains)


gravity_pd.label = "Gravity+PD (example)"
