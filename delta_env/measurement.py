"""The env's sensors, sampled once per control step: encoder readings, their rates and the measured torques with
their noise, as the observation reports them (the sensor models' constants: :mod:`delta_env.sensors`)."""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from delta_env.fault_injection import FaultInjector
from delta_env.plant import DeltaPlant
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import Trajectory

_GRIPPER_CLOSED, _GRIPPER_OPEN = np.array([1.0]), np.array([0.0])
"""The ``gripper`` readings, copied into each observation."""


def observation_space(load_encoder: bool = False) -> spaces.Dict:
    """The env's observation space: the keys :class:`Sensors` fills, float64, shape (3,) but ``gripper`` (1,)
    (units and meanings: :class:`~delta_env.env.DeltaPickPlaceEnv`); ``load_angles`` too with a ``load_encoder``."""
    unbounded = {"low": -np.inf, "high": np.inf, "shape": (3,), "dtype": np.float64}
    keys = {
        "joint_angles": spaces.Box(**unbounded),
        "joint_velocities": spaces.Box(**unbounded),
        "joint_torques": spaces.Box(**unbounded),
        "reference_angles": spaces.Box(**unbounded),
        "reference_velocities": spaces.Box(**unbounded),
        "reference_accelerations": spaces.Box(**unbounded),
        "gripper": spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float64),
    }
    if load_encoder:
        keys["load_angles"] = spaces.Box(**unbounded)
    return spaces.Dict(keys)


class Sensors:
    """The drive's sensors on a plant: what :class:`~delta_env.env.DeltaPickPlaceEnv` observes.

    The encoders read the drives' motor side (:meth:`~delta_env.plant.DeltaPlant.rotor_angle_values`: the arms' own
    angles on rigid drives, the rotors' on compliant ones); an optional load encoder reads the arms' angles.

    Args:
        plant: The plant measured.
        encoder_step: Encoder resolution at the joint (rad); None for ideal encoders, whose rates are the true rates.
        torque_noise_std: Standard deviation (N m) of the white noise on the measured torques.
        load_encoder_step: Resolution (rad) of the load encoder, or None (default): none.

    Attributes:
        angles: The last encoder readings (rad), three floats.
        cell_angles: The last readings the cell judges the platform from (rad), three floats: the load encoder's
            where one is fitted (it reads the arms, which the motor encoders of compliant drives do not: they read
            the rotors, a gearhead's deflection away), else :attr:`angles`.
        torque_noise: The measured torques' noise of every sample of the reference (N m), (samples, 3).
    """

    def __init__(
        self,
        plant: DeltaPlant,
        encoder_step: float | None,
        torque_noise_std: float,
        load_encoder_step: float | None = None,
    ) -> None:
        self.plant = plant
        self.encoder_step = encoder_step
        self.load_encoder_step = load_encoder_step
        self.torque_noise_std = torque_noise_std
        self._actuator_force = plant.data.actuator_force  # a view: mjData keeps its buffers for its lifetime
        self.angles = [0.0, 0.0, 0.0]
        self.cell_angles = self.angles
        self.torque_noise = np.zeros((1, 3))
        self._spare_noise: np.random.Generator | None = None

    def draw_noise(self, rng: np.random.Generator, samples: int, spare: bool) -> None:
        """Draw the noise of an episode's ``samples`` from ``rng``; with ``spare`` (a reference an online timing
        lengthens), the noise of later samples from a generator of its own drawn now, so that the retimes leave
        ``rng`` as a fixed timing would."""
        self.torque_noise = rng.normal(0.0, self.torque_noise_std, size=(samples, 3))
        self._spare_noise = np.random.default_rng(rng.integers(2**63)) if spare else None

    def cover(self, samples: int, rng: np.random.Generator) -> None:
        """Draw the noise of a reference lengthened to ``samples`` from the spare generator; without one, from a
        stream of its own derived from ``rng``'s seed, so that ``rng`` draws as before."""
        missing = samples - len(self.torque_noise)
        if missing > 0:
            if self._spare_noise is None:
                self._spare_noise = np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0])
            extra = self._spare_noise.normal(0.0, self.torque_noise_std, size=(missing, 3))
            self.torque_noise = np.concatenate((self.torque_noise, extra))

    def first_observation(self, trajectory: Trajectory, holding: bool) -> dict[str, NDArray[np.float64]]:
        """The observation at a reset (step 0), the robot at rest."""
        self.angles = self._encoder_floats(*self.plant.rotor_angle_values())
        return self._observation(0, trajectory, holding, np.array(self.plant.rotor_velocity_values()))

    def observe(
        self, k: int, trajectory: Trajectory, holding: bool, faults: FaultInjector | None
    ) -> dict[str, NDArray[np.float64]]:
        """Sample the sensors for the observation ``k`` (after step k - 1), with the sensor faults of ``faults``
        acting on it (None: no fault this episode)."""
        previous = self.angles
        velocities = self._measure_joints()
        if faults is None:
            return self._observation(k, trajectory, holding, velocities)
        readings, torque_offsets = faults.corrupt_readings(k - 1, self.angles, previous)
        if readings != self.angles:
            self.angles = readings
            if self.encoder_step is None:
                velocities[np.isnan(readings)] = math.nan
            else:
                velocities = (np.array(readings) - np.array(previous)) / CONTROL_PERIOD
        observation = self._observation(k, trajectory, holding, velocities)
        for joint, offset in torque_offsets:
            observation["joint_torques"][joint] += offset  # NaN for a sensor_nan
        return observation

    def _encoder_floats(self, a0: float, a1: float, a2: float) -> list[float]:
        """Encoder reading (rad) of three joint angles given as floats: rounded to whole counts when quantized."""
        step = self.encoder_step
        if step is None:
            return [a0, a1, a2]
        return [round(a0 / step) * step, round(a1 / step) * step, round(a2 / step) * step]

    def _measure_joints(self) -> NDArray[np.float64]:
        """Sample the encoders; return the measured joint rates (rad/s)."""
        p0, p1, p2 = self.angles
        self.angles = m0, m1, m2 = self._encoder_floats(*self.plant.rotor_angle_values())
        if self.encoder_step is None:
            return np.array(self.plant.rotor_velocity_values())
        rate = 1.0 / CONTROL_PERIOD
        return np.array([(m0 - p0) * rate, (m1 - p1) * rate, (m2 - p2) * rate])

    def _observation(
        self, k: int, trajectory: Trajectory, holding: bool, joint_velocities: NDArray[np.float64]
    ) -> dict[str, NDArray[np.float64]]:
        # Reference rows are read-only views; the noise of the whole episode is drawn at reset.
        f0, f1, f2 = self._actuator_force.tolist()
        n0, n1, n2 = self.torque_noise[k].tolist()
        observation = {
            "joint_angles": np.array(self.angles),
            "joint_velocities": joint_velocities,
            "joint_torques": np.array((f0 + n0, f1 + n1, f2 + n2)),
            "reference_angles": trajectory.theta[k],
            "reference_velocities": trajectory.theta_dot[k],
            "reference_accelerations": trajectory.theta_ddot[k],
            "gripper": (_GRIPPER_CLOSED if holding else _GRIPPER_OPEN).copy(),
        }
        if self.load_encoder_step is None:
            self.cell_angles = self.angles
        else:
            load_angles = self._load_angles()
            observation["load_angles"] = load_angles
            self.cell_angles = load_angles.tolist()
        return observation

    def _load_angles(self) -> NDArray[np.float64]:
        """The load encoder's reading of the arms' angles (rad), shape (3,), rounded to whole counts."""
        step = self.load_encoder_step
        return np.round(self.plant.joint_angles() / step) * step
