"""What runs the identification's excitation trajectories on the plant (docs/design.md section 7).

An excitation trajectory (:func:`delta_env.excitation.excitation_trajectory`, 6 g, workspace edges, slow moves),
described by an :class:`ExcitationSpec`, runs in closed loop on the plant (PD plus MKH feedforward along the
reference) with the episode runner :func:`eval.episodes.run_episode`; only the observations are kept, as an
:class:`ExcitationRecord`: encoder angles, measured motor torques and the commands the drive held.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation, PDController
from controllers.dynamics import DeltaDynamics
from controllers.identification import DriveLog
from controllers.servo import ResonanceNotch, joint_inertia, notch_sample
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.excitation import excitation_trajectory
from delta_env.geometry import GRAVITY, NOMINAL_GEOMETRY, DeltaGeometry
from delta_env.limits import WORKSPACE_LIMITS, WorkspaceLimits
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import WORKING_HEIGHT, Trajectory
from eval.console import progress_bar
from eval.episodes import run_episode
from eval.processes import run_jobs

DEFAULT_DURATION = 8.0
"""Length of each excitation trajectory (s)."""

VALIDATION_DURATION = 10.0
"""Length of the held-out free-motion stress trajectory (s), the paper's upsilon_F."""


@dataclass(frozen=True)
class ExcitationRegion:
    """Where a robot's excitation trajectories start and move.

    Attributes:
        start: Platform position (m) where every trajectory starts and ends.
        limits: Region the trajectories visit.
    """

    start: tuple[float, float, float]
    limits: WorkspaceLimits


NOMINAL_REGION = ExcitationRegion(start=(0.0, 0.0, WORKING_HEIGHT), limits=WORKSPACE_LIMITS)
"""The nominal robot's excitation region: its working height and workspace."""


@dataclass(frozen=True)
class ExcitationSpec:
    """One excitation trajectory: the arguments of ``excitation_trajectory`` and the episode seed.

    Attributes:
        seed: Seeds the trajectory's generator and the env's reset (its torque noise).
        duration: Length (s).
        peak_acceleration: Largest peak Cartesian |xdd| of a move (m/s^2).
        min_acceleration_fraction: Smallest peak |xdd| of a fast move, relative to the largest.
        edge_fraction: Probability that a fast move ends on the workspace edge.
        slow_fraction: Probability that a move is slow (friction near zero speed).
        start: Platform position (m) where the trajectory starts and ends.
        limits: Region the trajectory visits; the default suits the nominal geometry.
    """

    seed: int
    duration: float = DEFAULT_DURATION
    peak_acceleration: float = 6.0 * GRAVITY
    min_acceleration_fraction: float = 0.2
    edge_fraction: float = 0.3
    slow_fraction: float = 0.2
    start: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT)
    limits: WorkspaceLimits = WORKSPACE_LIMITS

    @classmethod
    def stress(cls, seed: int, duration: float = VALIDATION_DURATION) -> ExcitationSpec:
        """The held-out free-motion stress trajectory (the paper's upsilon_F): fast moves only (3 to 6 g),
        half of them to the workspace edge, with the excitation's short dwells (0 to 0.1 s)."""
        return cls(seed=seed, duration=duration, min_acceleration_fraction=0.5, edge_fraction=0.5, slow_fraction=0.0)

    def reference(self, geometry: DeltaGeometry = NOMINAL_GEOMETRY) -> Trajectory:
        """The reference :class:`~delta_env.trajectories.Trajectory` of a robot with ``geometry`` (1 kHz)."""
        return excitation_trajectory(
            geometry,
            np.random.default_rng(self.seed),
            self.duration,
            self.peak_acceleration,
            start=self.start,
            min_acceleration_fraction=self.min_acceleration_fraction,
            edge_fraction=self.edge_fraction,
            slow_fraction=self.slow_fraction,
            limits=self.limits,
            dt=CONTROL_PERIOD,
        )


@dataclass(frozen=True, eq=False)
class ExcitationRecord:
    """What the drive recorded along one excitation run: observations only, never the plant's truth.

    Attributes:
        spec: The trajectory that was run.
        dt: Sample period (s).
        angles: Encoder angles (rad), ``(N, 3)``.
        torques: Measured motor torques (N m), ``(N, 3)``; sample k is
            :data:`delta_env.sensors.MEASURED_TORQUE_DELAY` older than angle sample k.
        commands: Command the drive held after each sample (N m), ``(N - 1, 3)``: command k, sent with
            sample k, is followed by the torque reported with sample k + 1.
        max_loop_gap: Largest loop-closure gap of the plant during the run (m), the simulation's health.
    """

    spec: ExcitationSpec
    dt: float
    angles: NDArray[np.float64]
    torques: NDArray[np.float64]
    commands: NDArray[np.float64]
    max_loop_gap: float

    @property
    def log(self) -> DriveLog:
        """What the drive's logger recorded: angles, torques and commands (:mod:`controllers.identification.logs`)."""
        return DriveLog(self.angles, self.torques, self.commands, self.dt)


class ReferenceFeedforward:
    """PD plus a feedforward torque computed beforehand along the reference, one row per control step; on compliant
    drives the PD's torque goes through a notch at each joint's drive mode, as commissioning sets a servo drive's
    resonance filter once the mode is known (docs/design.md section 7).

    Args:
        feedforward: Torques (N m), ``(N, 3)``: row k is added at the k-th call after :meth:`reset`.
        pd: The feedback; ``PDController()`` when None.
        notch: The notch's coefficients per control step and joint (:meth:`ResonanceNotch.coefficients`),
            ``(N, 3, 5)``; None: no notch.
    """

    name = "MKH (precomputed)+PD"

    def __init__(
        self,
        feedforward: NDArray[np.float64],
        pd: PDController | None = None,
        notch: NDArray[np.float64] | None = None,
    ) -> None:
        self.feedforward = feedforward
        self.pd = PDController() if pd is None else pd
        self.notch = notch
        self._step = 0
        self._notch_state = [[0.0, 0.0] for _ in range(3)]

    def reset(self) -> None:
        self._step = 0
        self._notch_state = [[0.0, 0.0] for _ in range(3)]

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        feedback = self.pd(observation)
        if self.notch is not None:
            coefficients = self.notch[min(self._step, len(self.notch) - 1)]
            for joint in range(3):
                feedback[joint] = notch_sample(tuple(coefficients[joint]), self._notch_state[joint], feedback[joint])
        torque = self.feedforward[self._step] + feedback
        self._step += 1
        return torque


def notch_along(notch: ResonanceNotch, model: DeltaDynamics, reference: Trajectory) -> NDArray[np.float64]:
    """The coefficients of ``notch`` centred on each joint's drive mode along ``reference``, ``(N, 3, 5)``: the
    joint's inertia, rotor included, is the model's at the reference's angles (:func:`controllers.servo.joint_inertia`,
    as the servo centres its notch; the datasheet model, whose ``rho1`` is 1, holds no rotor) plus the rotor's."""
    inertia = np.array([joint_inertia(model.inverse_dynamics, theta) for theta in reference.theta])
    inertia += np.asarray(notch.rotor_inertia)
    frequencies = np.array([notch.frequency(row) for row in inertia])
    return np.array([[notch.coefficients(float(f)) for f in row] for row in frequencies])


def run_excitation(
    spec: ExcitationSpec, plant: PlantConfig | None = None, notch: ResonanceNotch | None = None
) -> ExcitationRecord:
    """Run ``spec`` with PD + MKH feedforward on the plant; record encoder angles and measured torques.

    The reference and the MKH model are those of the plant's geometry and built masses (its datasheet). ``notch``:
    a notch on the PD's torque at the drive modes of compliant drives (their identified compliance), None: none.

    Raises:
        RuntimeError: if the plant diverges.
    """
    plant = PlantConfig() if plant is None else plant
    reference = spec.reference(plant.geometry)
    # MKH feedforward along the reference, in one batch (the batched model is much faster than single samples).
    mkh = robot_model(plant)
    feedforward = mkh.inverse_dynamics(reference.theta, reference.theta_dot, reference.theta_ddot)
    coefficients = None if notch is None else notch_along(notch, mkh, reference)
    env = DeltaPickPlaceEnv(plant=plant)
    record = run_episode(env, ReferenceFeedforward(feedforward, notch=coefficients), spec.seed, reference=reference)
    env.close()
    if record.diverged:
        steps = len(record.tracking_error)
        raise RuntimeError(f"the plant diverged at step {steps} of excitation seed {spec.seed}")
    return ExcitationRecord(
        spec=spec,
        dt=CONTROL_PERIOD,
        angles=record.encoder_angles,
        torques=record.measured_torque,
        commands=record.command,
        max_loop_gap=record.max_loop_gap,
    )


def robot_model(plant: PlantConfig, *, forearm_rods: bool = False) -> DeltaDynamics:
    """MKH of the robot ``plant`` builds: its lengths and datasheet masses, nothing identified yet."""
    return DeltaDynamics.of_robot(plant.geometry, plant.masses, forearm_rods=forearm_rods)


def collect_excitation_data(
    specs: Sequence[ExcitationSpec],
    *,
    plant: PlantConfig | None = None,
    workers: int = 1,
    progress: bool = False,
) -> list[ExcitationRecord]:
    """Run excitation trajectories in closed loop on the plant and record the observations.

    Each run: ``DeltaPickPlaceEnv(plant)`` reset with the trajectory as reference (no picks),
    ``PDController()`` plus MKH feedforward precomputed along the reference. Recorded: the encoder
    angles and the measured motor torques of the observations (with the plant's sensor noise and
    quantization), never the simulator's state.

    Args:
        specs: The trajectories.
        plant: Plant configuration; None is the default realistic plant.
        workers: Processes running trajectories in parallel.
        progress: Show a tqdm progress bar.

    Raises:
        RuntimeError: if the plant diverges.
    """
    specs = list(specs)
    with progress_bar(len(specs), "excitation runs", "run", disable=not progress) as bar:
        return run_jobs(functools.partial(run_excitation, plant=plant), specs, workers=workers, progress=bar)
