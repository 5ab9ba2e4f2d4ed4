"""Closed-loop verification of a design on its own MuJoCo plant (beyond the paper).

For a geometry: build the realistic plant with the scaled masses, identify MId+F+R on it with the same
least squares as the nominal robot (excitation runs in closed loop, Kalman RTS smoothing, joint least
squares on the rod-forearm model of that geometry), tare the payload estimator, then run PD,
MId+F+R+RLS+PD and the oracle on seeded standard cycles carrying 3.8 kg. A design is infeasible, and
reported as such, when its plant cannot be assembled, a run diverges, or a loop opens by more than
:data:`LOOP_GAP_LIMIT`.

This module is the only one of the design study that calls identification, controller building and
episode running, so that those calls live in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from controllers.base import PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import FeedforwardController, OracleController
from controllers.identification import ExcitationRecord, ExcitationSpec, fit_joint_least_squares, prepare_motion
from controllers.payload import PayloadEstimator, tare_from_observations
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.model import PlantConfig
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import Trajectory, WorkspaceLimits, excitation_trajectory
from delta_env.validation import require_count
from delta_env.workspace import pose_measures
from eval.design.performance import PAYLOAD, TASK_CYCLES, Performance, design_model, payload_profile, task_cycle

LOOP_GAP_LIMIT = 1e-4
"""Largest loop gap (m) a feasible design's plant may show in any run: 0.1 mm."""

IDENTIFICATION_TRAJECTORIES = 4
"""Excitation trajectories per design: a third of the nominal robot's 12, to fit the time budget; the
eight friction and inertia parameters stay well determined (thousands of moving samples each)."""

IDENTIFICATION_DURATION = 6.0
"""Length of each excitation trajectory (s)."""

EPISODE_CYCLES = 2
"""Standard cycles per verification episode."""

CONTROLLERS = ("PD", "MId+F+R+RLS+PD", "Oracle+PD (bound)")
"""The controllers compared on every design."""

EXCITATION_MARGIN = 0.5
"""Excitation paths keep min |k_i| and |det A| above this share of their values at the cylinder's centre."""


@dataclass(frozen=True)
class EpisodeResult:
    """One controller on one episode of a design's plant.

    Attributes:
        controller: Controller label.
        seed: Episode seed.
        tracking_rms_mm: RMS Cartesian tracking error (mm).
        torque_peak_nm: Largest |applied torque| (N m).
        torque_rms_nm: RMS applied torque over samples and joints (N m).
        max_loop_gap_m: Largest loop gap (m).
        diverged: True if the simulation diverged.
    """

    controller: str
    seed: int
    tracking_rms_mm: float
    torque_peak_nm: float
    torque_rms_nm: float
    max_loop_gap_m: float
    diverged: bool


@dataclass(frozen=True)
class Verification:
    """A design's closed-loop verification.

    Attributes:
        name: Design name.
        geometry: Its lengths (m).
        masses: Its scaled masses (kg).
        feasible: False if the plant could not be assembled, diverged or opened a loop.
        reason: Why it is infeasible ("" when feasible).
        parameters: Identified MId+F+R parameters, or None.
        tare_kg: Apparent payload of the empty gripper of its estimator (kg).
        episodes: Every run.
        predicted: Per episode seed, the design model's (peak, RMS) torque along the reference (N m).
        identified: Per episode seed, the identified model's (peak, RMS) torque along the reference (N m).
    """

    name: str
    geometry: DeltaGeometry
    masses: DeltaMasses
    feasible: bool
    reason: str = ""
    parameters: ModelParameters | None = None
    tare_kg: float = math.nan
    episodes: tuple[EpisodeResult, ...] = ()
    predicted: dict[int, tuple[float, float]] = field(default_factory=dict)
    identified: dict[int, tuple[float, float]] = field(default_factory=dict)

    def mean(self, controller: str, metric: str) -> float:
        """Mean of ``metric`` over the controller's episodes (NaN if none)."""
        values = [getattr(e, metric) for e in self.episodes if e.controller == controller]
        return float(np.mean(values)) if values else math.nan

    def predicted_mean(self, which: str, index: int) -> float:
        """Mean over episodes of the design model's (``which="predicted"``) or identified model's figure
        ``index`` (0 peak, 1 RMS) in N m."""
        values = [v[index] for v in getattr(self, which).values()]
        return float(np.mean(values)) if values else math.nan


class DesignInfeasible(RuntimeError):
    """The plant of a design cannot be assembled, diverged, or opened a loop beyond the limit."""


def episode_reference(geometry: DeltaGeometry, seed: int) -> Trajectory:
    """The verification path of episode ``seed``: the standard cycle at task place ``seed mod 5``, 1 kHz."""
    centre, heading = TASK_CYCLES[seed % len(TASK_CYCLES)]
    return task_cycle(geometry, centre, heading, n_cycles=EPISODE_CYCLES, dt=CONTROL_PERIOD)


def excitation_limits(performance: Performance) -> WorkspaceLimits:
    """The region identification paths of a design may visit: its dexterous cylinder with margins."""
    cylinder = performance.cylinder
    if cylinder is None:
        raise DesignInfeasible("the design has no dexterous cylinder to identify it in")
    centre = pose_measures(performance.geometry, np.array([0.0, 0.0, cylinder.top - cylinder.height / 2]))
    return WorkspaceLimits(
        radius=cylinder.diameter / 2,
        z_min=cylinder.bottom,
        z_max=cylinder.top,
        min_abs_k=EXCITATION_MARGIN * float(centre.min_abs_k),
        min_abs_det_a=EXCITATION_MARGIN * abs(float(centre.det_a)),
    )


def _run(
    env: DeltaPickPlaceEnv, controller: object, reference: Trajectory, seed: int, masses: list[float] | None
) -> tuple[EpisodeResult, NDArray, NDArray, list]:
    """One episode: the result, encoder angles (N, 3), measured torques (N, 3) and the observations."""
    options = {"reference": reference}
    if masses is not None:
        options["payload_masses"] = masses
    observation, info = env.reset(seed=seed, options=options)
    if isinstance(controller, OracleController):
        controller.set_payload_masses(info["payload_masses"])
    controller.reset()
    steps = len(reference) - 1
    angles, measured, observations = [observation["joint_angles"]], [observation["joint_torques"]], [observation]
    applied, errors, gap, diverged = np.zeros((steps, 3)), np.full(steps, math.nan), 0.0, False
    for n in range(steps):
        observation, _, terminated, truncated, info = env.step(controller(observation))
        applied[n], errors[n] = info["applied_torque"], info["tracking_error"]
        gap = max(gap, info["loop_gap"]) if math.isfinite(info["loop_gap"]) else math.inf
        if info["diverged"]:
            diverged = True
            break
        angles.append(observation["joint_angles"])
        measured.append(observation["joint_torques"])
        observations.append(observation)
        if terminated or truncated:
            break
    done = applied[: n + 1]
    result = EpisodeResult(
        controller=getattr(controller, "name", type(controller).__name__),
        seed=seed,
        tracking_rms_mm=1e3 * float(np.sqrt(np.nanmean(errors[: n + 1] ** 2))),
        torque_peak_nm=float(np.max(np.abs(done))),
        torque_rms_nm=float(np.sqrt(np.mean(done**2))),
        max_loop_gap_m=gap,
        diverged=diverged,
    )
    return result, np.array(angles), np.array(measured), observations


def _check(result: EpisodeResult, what: str) -> None:
    if result.diverged:
        raise DesignInfeasible(f"{what} diverged")
    if not result.max_loop_gap_m <= LOOP_GAP_LIMIT:
        raise DesignInfeasible(f"{what} opened a loop by {1e3 * result.max_loop_gap_m:.3f} mm (> 0.1 mm)")


def identify_design(
    env: DeltaPickPlaceEnv, model: DeltaDynamics, performance: Performance, seed: int
) -> ModelParameters:
    """MId+F+R of a design's plant: the nominal robot's joint least squares on the design's own data."""
    limits = excitation_limits(performance)
    start = (0.0, 0.0, performance.cylinder.top - performance.cylinder.height / 2)
    spawned = np.random.SeedSequence(seed).generate_state(IDENTIFICATION_TRAJECTORIES)
    data = []
    for index, trajectory_seed in enumerate(int(s) for s in spawned):
        spec = ExcitationSpec(seed=trajectory_seed, duration=IDENTIFICATION_DURATION)
        reference = excitation_trajectory(
            model.geometry,
            np.random.default_rng(trajectory_seed),
            spec.duration,
            spec.peak_acceleration,
            start=start,
            min_acceleration_fraction=spec.min_acceleration_fraction,
            edge_fraction=spec.edge_fraction,
            slow_fraction=spec.slow_fraction,
            limits=limits,
        )
        feedforward = _PlainFeedforward(model, reference)
        result, angles, torques, _ = _run(env, feedforward, reference, trajectory_seed, None)
        _check(result, f"excitation run {index}")
        data.append(prepare_motion(ExcitationRecord(spec=spec, dt=CONTROL_PERIOD, angles=angles, torques=torques)))
    return fit_joint_least_squares(data, dynamics=model).parameters


class _PlainFeedforward:
    """PD plus the MKH feedforward of the design along a known reference (the identification's controller)."""

    name = "PD+MKH (excitation)"

    def __init__(self, model: DeltaDynamics, reference: Trajectory) -> None:
        self.torque = model.with_parameters(None).inverse_dynamics(
            reference.theta, reference.theta_dot, reference.theta_ddot
        )
        self.pd = PDController()
        self.step = 0

    def reset(self) -> None:
        self.step = 0

    def __call__(self, observation: dict) -> NDArray[np.float64]:
        torque = self.torque[min(self.step, len(self.torque) - 1)] + self.pd(observation)
        self.step += 1
        return torque


def verify_design(name: str, performance: Performance, *, seed: int = 0, episodes: int = 2) -> Verification:
    """Identify a design's plant and run the controllers on it; never raises for an infeasible plant.

    Args:
        name: Design name for the report.
        performance: The design's figures (geometry, scaled masses, dexterous cylinder).
        seed: Seed of the identification and of the first episode (episodes ``seed .. seed + episodes - 1``).
        episodes: Episodes per controller, >= 1.
    """
    require_count("episodes", episodes)
    geometry, masses = performance.geometry, performance.masses
    base = {"name": name, "geometry": geometry, "masses": masses}
    try:
        env = DeltaPickPlaceEnv(plant=PlantConfig(geometry=geometry, masses=masses), n_cycles=EPISODE_CYCLES)
    except (ValueError, RuntimeError) as error:
        return Verification(**base, feasible=False, reason=f"plant cannot be assembled: {error}")
    model = design_model(geometry, masses)
    try:
        parameters = identify_design(env, model, performance, seed)
        identified = model.with_parameters(parameters)
        estimator = PayloadEstimator(identified, regressor="smoothed")
        rls = FeedforwardController(CONTROLLERS[1], identified, pd=PDController(), estimator=estimator)
        empty = [0.0] * EPISODE_CYCLES
        calibration, *_, observations = _run(env, rls, episode_reference(geometry, seed), seed + 10_000, empty)
        _check(calibration, "tare calibration")
        tare, _ = tare_from_observations(estimator, [observations])
        estimator = PayloadEstimator(identified, regressor="smoothed", tare=tare)
        controllers = (
            PDController(),
            FeedforwardController(CONTROLLERS[1], identified, pd=PDController(), estimator=estimator),
            OracleController(env.plant_config, pd=PDController()),
        )
        results, predicted, identified_figures = [], {}, {}
        for episode_seed in range(seed, seed + episodes):
            reference = episode_reference(geometry, episode_seed)
            carried = payload_profile(reference, PAYLOAD)
            for dynamics, store in ((model, predicted), (identified, identified_figures)):
                torque = dynamics.inverse_dynamics(reference.theta, reference.theta_dot, reference.theta_ddot, carried)
                store[episode_seed] = (float(np.max(np.abs(torque))), float(np.sqrt(np.mean(torque**2))))
            for controller in controllers:
                result, *_ = _run(env, controller, reference, episode_seed, [PAYLOAD] * EPISODE_CYCLES)
                _check(result, f"{result.controller} episode {episode_seed}")
                results.append(result)
    except DesignInfeasible as error:
        env.close()
        return Verification(**base, feasible=False, reason=str(error))
    env.close()
    return Verification(
        **base,
        feasible=True,
        parameters=parameters,
        tare_kg=tare,
        episodes=tuple(results),
        predicted=predicted,
        identified=identified_figures,
    )
