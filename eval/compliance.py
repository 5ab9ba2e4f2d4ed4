"""What runs the compliance excitation on a compliant plant, and the plant's first mode measured by a frequency
response (docs/design.md section 7, "Compliant drives").

The excitation holds the robot at rest poses (a soft joint PD on the motor encoders plus MKH's gravity torque, stiff
enough to hold, soft enough that the gearhead mode leaves it stable) and adds a random-phase multisine torque per
drive (:func:`delta_env.excitation.multisine_torques`); the logger records the motor-side encoders, the load-side
encoders and the measured torques (:class:`~controllers.identification.DriveLog` with ``load_angles``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controllers.identification import DriveLog
from delta_env import kinematics
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.excitation import MULTISINE_BAND, MULTISINE_PERIOD, multisine_torques
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import WORKING_HEIGHT, Trajectory
from eval.excitation import robot_model

COMPLIANCE_POSES = ((0.0, 0.0, WORKING_HEIGHT), (0.3, -0.15, -1.0), (-0.2, 0.35, -0.8))
"""Platform positions (m) where the compliance excitation holds the robot: the work zone's centre, low and off
centre, high and off centre (the first mode moves with the pose)."""

HOLD_KP = 3000.0
"""Stiffness (N m/rad) of the hold's joint PD on the motor encoders: the PD that the default gearhead's mode leaves
stable (docs/measurements.md, "Compliant drives")."""

HOLD_KD = 30.0
"""Damping (N m s/rad) of the hold's joint PD."""

EXCITATION_RMS = 20.0
"""RMS multisine torque per drive (N m): the gearheads deflect by about 1e-4 rad, 20 steps of a 20-bit load encoder."""

EXCITATION_PERIODS = 8
"""Periods recorded per pose after the settling one."""


@dataclass(frozen=True)
class ComplianceExcitationSpec:
    """One compliance excitation run.

    Attributes:
        seed: Seeds the multisine's phases and the env's reset (its torque noise).
        pose: Platform position (m) held.
        periods: Periods of the multisine, the settling one included.
        rms: RMS multisine torque per drive (N m).
        period: The multisine's period (s).
        band: Its band (Hz).
    """

    seed: int
    pose: tuple[float, float, float] = COMPLIANCE_POSES[0]
    periods: int = EXCITATION_PERIODS + 1
    rms: float = EXCITATION_RMS
    period: float = MULTISINE_PERIOD
    band: tuple[float, float] = MULTISINE_BAND


def run_compliance_excitation(spec: ComplianceExcitationSpec, plant: PlantConfig) -> DriveLog:
    """Hold ``spec.pose`` on the compliant ``plant`` and drive a multisine through its drives; the log of what the
    logger recorded: motor-side angles (the encoders), load-side angles, measured torques, commands.

    Raises:
        ValueError: if the plant has no compliant drives or no load-side encoder.
        RuntimeError: if the plant diverges.
    """
    compliance = plant.realism.compliance
    if compliance is None or compliance.load_encoder_bits is None:
        raise ValueError(
            "the compliance excitation needs compliant drives with a load-side encoder "
            "(PlantRealism.compliance.load_encoder_bits)"
        )
    theta = kinematics.inverse(plant.geometry, np.asarray(spec.pose, dtype=float))
    samples_per_period = round(spec.period / CONTROL_PERIOD)
    length = spec.periods * samples_per_period
    reference = Trajectory(
        dt=CONTROL_PERIOD,
        xyz=np.tile(spec.pose, (length + 1, 1)),
        xyz_dot=np.zeros((length + 1, 3)),
        xyz_ddot=np.zeros((length + 1, 3)),
        theta=np.tile(theta, (length + 1, 1)),
        theta_dot=np.zeros((length + 1, 3)),
        theta_ddot=np.zeros((length + 1, 3)),
        gripper=np.zeros(length + 1, dtype=bool),
        pick_indices=np.zeros(0, dtype=np.int64),
        place_indices=np.zeros(0, dtype=np.int64),
    )
    rng = np.random.default_rng(spec.seed)
    excitation = multisine_torques(rng, spec.rms, spec.period, spec.band)
    gravity = robot_model(plant).inverse_dynamics(theta, np.zeros(3), np.zeros(3))
    env = DeltaPickPlaceEnv(plant=plant)
    observation, _ = env.reset(seed=spec.seed, options={"reference": reference})
    motor, load, torque, command = [], [], [], []
    for step in range(length):
        motor.append(observation["joint_angles"])
        load.append(observation["load_angles"])
        torque.append(observation["joint_torques"])
        action = (
            gravity
            + HOLD_KP * (theta - observation["joint_angles"])
            - HOLD_KD * observation["joint_velocities"]
            + excitation[step % samples_per_period]
        )
        command.append(action)
        observation, _, diverged, _, _ = env.step(action)
        if diverged:
            env.close()
            raise RuntimeError(f"the plant diverged at step {step + 1} of compliance excitation seed {spec.seed}")
    env.close()
    motor_angles = np.array(motor)
    return DriveLog(
        motor_angles,
        np.array(torque),
        np.array(command[:-1]),
        CONTROL_PERIOD,
        motor_angles=motor_angles,
        load_angles=np.array(load),
    )
