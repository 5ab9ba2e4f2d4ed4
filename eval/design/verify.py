"""Closed-loop verification of a design on its own MuJoCo plant (beyond the paper).

For a geometry: build the realistic plant with the scaled masses, identify it by the nominal robot's
identification (:func:`eval.identification.run.run_identification`, the same excitation runs in closed loop but
inside the design's dexterous cylinder, the same fits on that geometry's models, the drive lag), tare the
payload estimator by :func:`eval.calibration.calibrate_tares` on payload-free standard cycles, then run PD,
MId+F+R+RLS+PD and the oracle by the experiment engine (:func:`eval.work.run_grid`) on seeded standard
cycles carrying 3.8 kg. The plant is built with its collision geometry on (``PlantConfig.collisions``: links and
base collide, :func:`delta_env.robot.collision_geom_names`), and every episode checks the contacts it saw. A
design is infeasible, and reported as such, when its plant cannot be assembled, a run diverges, a loop opens by
more than :data:`LOOP_GAP_LIMIT` or its links touch each other or the base.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.registry import ControllerSetup, controller_label
from delta_env.config import PlantConfig
from delta_env.cylinder import Cylinder, largest_cylinder
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.limits import WorkspaceLimits
from delta_env.scenario import preset, with_geometry
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import Trajectory
from delta_env.validation import require_count
from delta_env.workspace import pose_measures
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, calibration_seeds, tare_setup
from eval.design.model import design_model, payload_profile
from eval.design.performance import PAYLOAD, TASK_BAND, TASK_CYCLES, Performance, task_cycle
from eval.episodes import EpisodeRecord
from eval.identification.excitation import ExcitationRegion
from eval.identification.parameter_files import robot_setup
from eval.identification.run import run_identification
from eval.work import WorkUnit, run_grid

LOOP_GAP_LIMIT = 1e-4
"""Largest loop gap (m) a feasible design's plant may show in any run: 0.1 mm."""

EPISODE_CYCLES = 2
"""Standard cycles per verification episode."""

RLS_KEY = "mid_f_rls"
"""Registry key of the model-based controller verified: MId+F+R feedforward with the payload RLS."""

CONTROLLER_KEYS = ("pd", RLS_KEY, "oracle")
"""Registry keys of the controllers compared on every design."""

CONTROLLERS = tuple(controller_label(key) for key in CONTROLLER_KEYS)
"""Their labels."""

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
        drive_lag: Identified drive lag per joint (s), or None.
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
    drive_lag: tuple[float, float, float] | None = None
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
    """The plant of a design cannot be assembled, diverged, opened a loop beyond the limit, or its links collided."""


def episode_reference(geometry: DeltaGeometry, seed: int) -> Trajectory:
    """The verification path of episode ``seed``: the standard cycle at task place ``seed mod 5``, 1 kHz."""
    centre, heading = TASK_CYCLES[seed % len(TASK_CYCLES)]
    return task_cycle(geometry, centre, heading, n_cycles=EPISODE_CYCLES, dt=CONTROL_PERIOD)


def excitation_cylinder(performance: Performance) -> Cylinder:
    """The design's largest dexterous cylinder reaching the lifted belt, below it too: room to excite the
    robot where it works (the data-sheet cylinder above the belt can be a thin disc)."""
    cylinder = largest_cylinder(performance.geometry, required_top=TASK_BAND[1])
    if cylinder is None:
        raise DesignInfeasible("the design has no dexterous cylinder to identify it in")
    return cylinder


def _result(record: EpisodeRecord, controller: str, seed: int) -> EpisodeResult:
    figures = record.metrics()
    return EpisodeResult(
        controller=controller,
        seed=seed,
        tracking_rms_mm=figures["tracking_rms_mm"],
        torque_peak_nm=figures["torque_peak_nm"],
        torque_rms_nm=figures["torque_rms_nm"],
        max_loop_gap_m=record.max_loop_gap,
        diverged=record.diverged,
    )


def _check(diverged: bool, loop_gap: float, what: str) -> None:
    if diverged:
        raise DesignInfeasible(f"{what} diverged")
    if not loop_gap <= LOOP_GAP_LIMIT:
        raise DesignInfeasible(f"{what} opened a loop by {1e3 * loop_gap:.3f} mm (> {1e3 * LOOP_GAP_LIMIT} mm)")


def _check_contacts(contacts: dict[tuple[str, str], float], what: str) -> None:
    if contacts:
        touching = ", ".join(f"{a} / {b} ({1e3 * depth:.1f} mm)" for (a, b), depth in sorted(contacts.items()))
        raise DesignInfeasible(f"{what}: links collide: {touching}")


def excitation_region(performance: Performance) -> ExcitationRegion:
    """Where the design's excitation trajectories start and move: from the centre of :func:`excitation_cylinder`,
    inside it, with min |k_i| and |det A| above :data:`EXCITATION_MARGIN` of their values at that centre."""
    cylinder = excitation_cylinder(performance)
    start = (0.0, 0.0, cylinder.top - cylinder.height / 2)
    centre = pose_measures(performance.geometry, np.array(start))
    limits = WorkspaceLimits(
        radius=cylinder.diameter / 2,
        z_min=cylinder.bottom,
        z_max=cylinder.top,
        min_abs_k=EXCITATION_MARGIN * float(centre.min_abs_k),
        min_abs_det_a=EXCITATION_MARGIN * abs(float(centre.det_a)),
    )
    return ExcitationRegion(start=start, limits=limits)


def identify_design(plant: PlantConfig, performance: Performance, seed: int, workers: int = 1) -> ControllerSetup:
    """MId, MId+F, MId+F+R and the drive lag of a design's plant by the nominal robot's identification
    (:func:`eval.identification.run.run_identification`, same trajectory count and length), inside the design's
    dexterous cylinder.

    Args:
        plant: The design's plant (its geometry and masses are the models' datasheet values).
        performance: Its figures (the dexterous cylinder bounds the excitation).
        seed: Seed of the excitation trajectories and their sensor noise.
        workers: Processes running the excitation trajectories.

    Returns:
        The controllers' knowledge of the design: its identified parameters, geometry and masses (no tares).

    Raises:
        DesignInfeasible: if no excitation path fits the cylinder, a run diverges or opens a loop.
    """
    try:
        run = run_identification(
            seed=seed, progress=False, workers=workers, plant=plant, region=excitation_region(performance)
        )
    except (RuntimeError, ValueError) as error:  # a divergence, or no excitation path fits the cylinder
        raise DesignInfeasible(f"identification failed: {error}") from error
    _check(False, run.max_loop_gap, "an excitation run")
    return robot_setup(plant, run.result)


def _reference_torques(model: DeltaDynamics, reference: Trajectory) -> tuple[float, float]:
    """Peak and RMS torque (N m) of ``model`` along ``reference`` carrying :data:`PAYLOAD` while gripping."""
    torque = model.inverse_dynamics(
        reference.theta, reference.theta_dot, reference.theta_ddot, payload_profile(reference, PAYLOAD)
    )
    return float(np.max(np.abs(torque))), float(np.sqrt(np.mean(torque**2)))


def verify_design(
    name: str, performance: Performance, *, seed: int = 0, episodes: int = 2, workers: int = 1
) -> Verification:
    """Identify a design's plant and run the controllers on it; never raises for an infeasible plant.

    Args:
        name: Design name for the report.
        performance: The design's figures (geometry, scaled masses, dexterous cylinder).
        seed: Seed of the identification and of the first episode (episodes ``seed .. seed + episodes - 1``).
        episodes: Episodes per controller, >= 1.
        workers: Processes running the identification's excitation trajectories, the tare's and the episodes.
    """
    require_count("episodes", episodes)
    geometry, masses = performance.geometry, performance.masses
    base = {"name": name, "geometry": geometry, "masses": masses}
    try:
        scenario = with_geometry(preset("nominal"), geometry, masses)
        scenario = dataclasses.replace(scenario, plant=dataclasses.replace(scenario.plant, collisions=True))
        plant = scenario.plant
        DeltaPickPlaceEnv(plant=plant, n_cycles=EPISODE_CYCLES).close()  # the plant assembles
    except (ValueError, RuntimeError) as error:
        return Verification(**base, feasible=False, reason=f"plant cannot be assembled: {error}")
    model = design_model(geometry, masses)
    try:
        setup = identify_design(plant, performance, seed, workers)
        standard = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, n_cycles=EPISODE_CYCLES))
        seeds = calibration_seeds(DEFAULT_CALIBRATION_EPISODES)
        try:
            setup, calibration = tare_setup(
                standard,
                setup,
                CONTROLLER_KEYS,
                episodes=len(seeds),
                workers=workers,
                references=[episode_reference(geometry, s) for s in seeds],
                max_loop_gap=LOOP_GAP_LIMIT,
            )
        except RuntimeError as error:
            raise DesignInfeasible(f"tare calibration failed: {error}") from error
        tare = calibration.tares[RLS_KEY]
        parameters, drive_lag = setup.mid_f_rods, setup.drive_lag
        identified = model.with_parameters(parameters)
        episode_seeds = range(seed, seed + episodes)
        references = {s: episode_reference(geometry, s) for s in episode_seeds}
        predicted = {s: _reference_torques(model, references[s]) for s in episode_seeds}
        identified_figures = {s: _reference_torques(identified, references[s]) for s in episode_seeds}
        units = [
            WorkUnit(standard, key, s, (PAYLOAD,) * EPISODE_CYCLES, references[s])
            for s in episode_seeds
            for key in CONTROLLER_KEYS
        ]
        records = run_grid(units, {standard.content_hash: setup}, workers=workers)
        results = []
        for unit, record in zip(units, records, strict=True):
            what = f"{controller_label(unit.controller)} episode {unit.seed}"
            _check(record.diverged, record.max_loop_gap, what)
            _check_contacts(record.robot_contacts, what)
            results.append(_result(record, controller_label(unit.controller), unit.seed))
    except DesignInfeasible as error:
        return Verification(**base, feasible=False, reason=str(error))
    return Verification(
        **base,
        feasible=True,
        parameters=parameters,
        drive_lag=drive_lag,
        tare_kg=tare,
        episodes=tuple(results),
        predicted=predicted,
        identified=identified_figures,
    )
