"""The identification experiment: excitation runs on the plant, then every fit (docs/design.md section 7).

Data: excitation trajectories run in closed loop on the plant by :mod:`eval.identification.excitation`; only the
observations are kept: encoder angles and measured motor torques. The algorithms of :mod:`controllers.identification`
then fit, on the same samples, MId and MId+F by the paper's method and by our joint least squares, and MId+F+R (rod
forearms, beyond the paper), and compare every model on a held-out stress trajectory. The drive's lag is fitted
separately (:func:`controllers.drive.identify_lag`) to the commands each run held and the torques the drive
reported, one fit per trajectory; the file keeps the median over the trajectories. A robot's drive logs
(:func:`identify_logs`) go through the same fits.

The result is an :class:`~controllers.identification.IdentificationResult` with provenance; the parameter files,
one per robot identity, are kept by :mod:`eval.identification.parameter_files`.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from controllers.base import PDController
from controllers.dynamics import DeltaDynamics
from controllers.estimation import ENCODER_NOISE_STD, SMOOTHER_JERK_STD
from controllers.identification import (
    FRICTION_VELOCITY_THRESHOLD,
    REST_VELOCITY,
    RHO1_GRID,
    RHO2_GRID,
    TRIM_SAMPLES,
    ComplianceFit,
    DriveLog,
    IdentificationResult,
    LeastSquaresFit,
    MotionData,
    StribeckFit,
    between_trajectory_spread,
    concatenate,
    error_table,
    fit_compliance,
    fit_joint_least_squares,
    fit_least_squares,
    fit_paper_method,
    fit_stribeck,
    prepare_motion,
    read_log,
)
from controllers.identification.bags import BagTopics, is_bag, read_bag
from controllers.identification.compliance import (
    UnexplainedTorqueError,
    UnseenModeError,
    fit_motor_side_compliance,
)
from controllers.identification.logs import read_table_log
from controllers.servo import ResonanceNotch
from delta_env.config import PlantConfig
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.scenario import datasheet_identity, load_robot, plant_identity
from delta_env.scene import build_mjcf
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from delta_env.validation import require_count
from eval.console import progress_bar
from eval.identification.compliance import arm_inertia, identify_compliance
from eval.identification.excitation import (
    DEFAULT_DURATION,
    NOMINAL_REGION,
    VALIDATION_DURATION,
    ExcitationRecord,
    ExcitationRegion,
    ExcitationSpec,
    run_excitation,
)
from eval.processes import DEFAULT_WORKERS, run_jobs
from eval.run_folder import json_ready, package_versions

logger = logging.getLogger(__name__)


DEFAULT_TRAJECTORIES = 12
"""Excitation trajectories of the identification, as in the paper."""

IDENTIFICATION_VERSION = 2
"""Version of the simulated identification, recorded in its provenance (``method.version``). Raise it with every
change of this code that changes the numbers it writes: the cache of a robot's identification is keyed by the robot
alone, and a cached file of another version (or of none, written before the version was recorded) is identified again
(:func:`eval.identification.parameter_files.outdated`). The exception: a change of the compliant drives'
identification alone (their fit or its refusals) raises :data:`COMPLIANCE_VERSION` instead, so that it re-identifies
the robots with compliant drives and leaves the rigid robots' files as they are."""

COMPLIANCE_VERSION = 2
"""Version of the compliant drives' identification and of its refusals, recorded in the provenance's
``compliance.version`` (fitted or refused). Raise it with every change of the drives' fit or of what it refuses: a
cached file with compliant drives of another version (or of none: 1 was never recorded) is identified again
(:func:`eval.identification.parameter_files.outdated`). 2: the motor-side fit's refusal judged up to
:data:`~controllers.identification.compliance.MOTOR_SIDE_CHECK_TOP` and the unseen mode refused."""

_Output = TypeVar("_Output")


def prepare_log(
    log: DriveLog, torque_delay: float = MEASURED_TORQUE_DELAY
) -> tuple[MotionData, NDArray[np.float64] | None]:
    """The smoothed samples of one log and the drive lag (s, per joint) fitted to it (None without commands), its
    torque readings ``torque_delay`` (s) older than their encoder samples: a simulated plant's physics step (the
    force held over the last step), ``MEASURED_TORQUE_DELAY`` for a log file.

    The one preparation of every record, simulated or read from a file.
    """
    return prepare_motion(log.angles, log.torques, log.dt, torque_delay=torque_delay), log.drive_lag(torque_delay)


def _collect_and_prepare(
    spec: ExcitationSpec, plant: PlantConfig | None, notch: ResonanceNotch | None = None
) -> tuple[ExcitationRecord, MotionData, NDArray[np.float64] | None]:
    """One excitation run (``notch``: on the PD at compliant drives' modes), its smoothed samples and the drive lag
    (s, per joint) fitted to it."""
    record = run_excitation(spec, plant, notch)
    return record, *prepare_log(record.log, (PlantConfig() if plant is None else plant).timestep)


@dataclass(frozen=True)
class IdentificationRun:
    """An identification with its held-out validation data, for reports.

    Attributes:
        result: The identified parameters.
        data: Samples of the identification trajectories.
        validation: Samples of the held-out trajectory (the free-motion stress trajectory of a simulation).
        models: The models compared on it, with their parameters (Table 1 rows), by name.
        logs: The logs identified on, then the held-out one: what the drive recorded.
        max_loop_gap: Largest loop gap of the plant over every excitation run (m), the simulation's health; None
            for logs.
        compliance_logs: The compliance excitation's logs (:mod:`eval.identification.compliance`) the drives'
            compliance was identified on; empty without it.
    """

    result: IdentificationResult
    data: tuple[MotionData, ...]
    validation: MotionData
    models: dict[str, DeltaDynamics]
    logs: tuple[DriveLog, ...]
    max_loop_gap: float | None
    compliance_logs: tuple[DriveLog, ...] = ()


def _trajectory_seeds(seed: int, n_trajectories: int) -> tuple[list[int], int]:
    """Distinct episode seeds of the identification trajectories and of the held-out one."""
    training, held_out = np.random.SeedSequence(seed).spawn(2)
    seeds = [int(s) for s in training.generate_state(n_trajectories)]
    validation_seed = int(held_out.generate_state(1)[0])
    if len({*seeds, validation_seed}) != n_trajectories + 1:
        raise RuntimeError(f"seed {seed} gave repeated trajectory seeds {seeds} + {validation_seed}")
    return seeds, validation_seed


def _plant_summary(plant: PlantConfig) -> dict[str, Any]:
    """What a test-bench log would state about the robot: no friction or mass values (those are truth)."""
    return {
        "identity": plant_identity(plant),
        "geometry_m": dataclasses.asdict(plant.geometry),
        "masses_kg": dataclasses.asdict(plant.masses),
        "variant": plant.variant,
        "mjcf_sha256": hashlib.sha256(build_mjcf(plant).encode()).hexdigest(),
        "control_period_s": CONTROL_PERIOD,
        "encoder_bits": plant.realism.encoder_bits,
        "torque_noise_std_Nm": plant.realism.torque_noise_std,
    }


def _standard_errors(fits: Mapping[str, LeastSquaresFit], stribeck: StribeckFit | None) -> dict[str, float]:
    errors = {
        f"{label}.{name}": error
        for label, fit in fits.items()
        for name, error in zip(fit.names, fit.standard_errors, strict=True)
    }
    if stribeck is not None:
        errors.update({f"stribeck.excess_{j}": e for j, e in enumerate(stribeck.standard_errors, start=1)})
    return errors


def _best_time(function: Callable[[], _Output], repeats: int = 3) -> tuple[_Output, float]:
    """The result of ``function()`` and its shortest wall time (s) over ``repeats`` calls.

    The shortest of a few runs is the least disturbed by other processes on the machine.
    """
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        output = function()
        times.append(time.perf_counter() - started)
    return output, min(times)


def run_identification(
    n_trajectories: int = DEFAULT_TRAJECTORIES,
    seed: int = 0,
    duration: float = DEFAULT_DURATION,
    *,
    validation_duration: float = VALIDATION_DURATION,
    progress: bool = True,
    workers: int | None = None,
    plant: PlantConfig | None = None,
    region: ExcitationRegion | None = None,
) -> IdentificationRun:
    """Collect data, identify with both methods and validate on a held-out stress trajectory.

    The one identification of every robot: the nominal one, a scenario's and a design's.

    Args:
        n_trajectories: Excitation trajectories (distinct seeds derived from ``seed``), >= 1.
        seed: Seed of the whole identification (trajectories and sensor noise).
        duration: Length of each excitation trajectory (s).
        validation_duration: Length of the held-out stress trajectory (s).
        progress: Show a tqdm progress bar.
        workers: Processes simulating trajectories; None: :data:`eval.processes.DEFAULT_WORKERS` (up to 2).
        plant: The robot; None is the default realistic plant.
        region: Where every trajectory, the held-out one included, starts and moves; None is the nominal
            robot's workspace (:data:`NOMINAL_REGION`).
    """
    start = time.perf_counter()
    require_count("n_trajectories", n_trajectories)
    workers = DEFAULT_WORKERS if workers is None else workers
    plant = PlantConfig() if plant is None else plant
    region = NOMINAL_REGION if region is None else region
    seeds, validation_seed = _trajectory_seeds(seed, n_trajectories)
    place = {"start": region.start, "limits": region.limits}
    specs = [ExcitationSpec(seed=s, duration=duration, **place) for s in seeds]
    specs.append(dataclasses.replace(ExcitationSpec.stress(validation_seed, validation_duration), **place))

    # Compliant drives are identified first, at rest poses: the excitation's PD then notches their modes, as a servo
    # drive's resonance filter is set before it moves the robot far and fast (docs/design.md section 7).
    try:
        drives, refusal = _drive_compliance(plant, seed, workers), None
    except (UnexplainedTorqueError, UnseenModeError) as error:
        logger.warning("compliant drives not identified: %s", error)
        drives, refusal = None, error
    notch = (
        None if drives is None else ResonanceNotch(drives[0].compliance.rotor_inertia, drives[0].compliance.stiffness)
    )
    run = functools.partial(_collect_and_prepare, plant=plant, notch=notch)
    with progress_bar(len(specs), "excitation runs", "run", disable=not progress) as bar:
        runs = run_jobs(run, specs, workers=workers, progress=bar)
    source = {
        "seed": seed,
        "trajectories": [json_ready(dataclasses.asdict(spec)) for spec in specs[:-1]],
        "validation_trajectory": json_ready(dataclasses.asdict(specs[-1])),
        "plant": _plant_summary(plant),
    }
    controller = {"kp": PDController().kp, "kd": PDController().kd, "feedforward": "MKH of the robot"}
    if notch is not None:
        controller["notch"] = {"quality": notch.quality, "centre": "each joint's identified drive mode"}
    run = _identify(
        [(motion, lag) for _, motion, lag in runs],
        [record.log for record, _, _ in runs],
        plant.geometry,
        plant.masses,
        data_method=SIMULATED_DATA,
        controller=controller,
        source=source,
        workers=workers,
        started=start,
        max_loop_gap=max(record.max_loop_gap for record, _, _ in runs),
        torque_delay=plant.timestep,
    )
    if drives is not None:
        return _with_compliance(run, *drives)
    if plant.realism.compliance is None:
        return run
    compliance = {"method": f"{MOTOR_SIDE_UNIDENTIFIED}: {refusal}", "version": COMPLIANCE_VERSION}
    provenance = {**run.result.provenance, "compliance": compliance}
    return dataclasses.replace(run, result=dataclasses.replace(run.result, provenance=provenance))


def _drive_compliance(
    plant: PlantConfig, seed: int, workers: int
) -> tuple[ComplianceFit, tuple[DriveLog, ...], dict] | None:
    """The compliance fit of :func:`eval.identification.compliance.identify_compliance` for a plant with compliant
    drives (from the load side with a load-side encoder, else from the motor side alone), None for rigid drives."""
    if plant.realism.compliance is None:
        return None
    return identify_compliance(plant, seed, workers)


MOTOR_SIDE_UNIDENTIFIED = (
    "not identified: compliant drives without a load-side encoder that the motor side alone does not fit"
)
"""The provenance's ``compliance.method`` (with the fit's reason) of compliant drives whose motor-side fit was refused
(:class:`~controllers.identification.compliance.UnexplainedTorqueError`: the two-mass model does not explain the drive,
as behind a backlash; :class:`~controllers.identification.compliance.UnseenModeError`: the logs do not show the
mode)."""


def _with_compliance(
    run: IdentificationRun, fit: ComplianceFit, logs: tuple[DriveLog, ...], provenance: dict[str, Any]
) -> IdentificationRun:
    """``run`` with the drives' compliance identified: in the result, its standard errors and provenance."""
    errors = {
        f"compliance.{name}_{joint + 1}": float(fit.standard_errors[joint, index])
        for index, name in enumerate(fit.parameter_names)
        for joint in range(3)
    }
    if fit.arm_inertia_scale is not None:
        errors["compliance.arm_inertia_scale"] = fit.arm_inertia_scale[1]
    result = dataclasses.replace(
        run.result,
        compliance=fit.compliance,
        standard_errors={**run.result.standard_errors, **errors},
        provenance={**run.result.provenance, "compliance": {**provenance, "version": COMPLIANCE_VERSION}},
    )
    return dataclasses.replace(run, result=result, compliance_logs=logs)


SIMULATED_DATA = (
    "excitation trajectories in closed loop (PD + MKH feedforward) on the plant; encoder angles "
    "and measured motor torques from the observations; Kalman RTS smoother for rates and accelerations"
)
"""How a simulated identification's data were made (the provenance's ``method.data``)."""

LOGGED_DATA = (
    "drive logs (controllers.identification.logs: CSV, Parquet or ROS 2 bags) resampled onto the control period; "
    "encoder angles and measured motor torques; Kalman RTS smoother for rates and accelerations"
)
"""How an identification from logs got its data (the provenance's ``method.data``)."""


def identify_logs(
    paths: Sequence[str | os.PathLike[str]],
    robot: str | os.PathLike[str],
    *,
    workers: int = 1,
    progress: bool = False,
    topics: BagTopics | None = None,
    compliance_paths: Sequence[str | os.PathLike[str]] = (),
    compliance_period: float | None = None,
    torque_delay: float = MEASURED_TORQUE_DELAY,
) -> IdentificationRun:
    """Identify the robot of the robot file ``robot`` from its drive logs alone: the algorithms, fits and
    validation of :func:`run_identification` on the logs' arrays.

    Args:
        paths: Log files (:mod:`controllers.identification.logs`) or ROS 2 bags
            (:mod:`controllers.identification.bags`), at least 2; the last one is held out for validation (the
            Table 1 analogue), the others are identified on.
        robot: Robot file (:func:`delta_env.scenario.load_robot`): lengths and datasheet masses.
        workers: Processes smoothing the logs.
        progress: Show a tqdm progress bar.
        topics: What to read from the bags; None: joint states on ``/joint_states``, the first three joints, no
            commands.
        compliance_paths: Logs of the compliance excitation (:mod:`eval.identification.compliance`: the multisine
            at rest poses), CSV or Parquet tables, to identify compliant drives on: all with ``load_angle`` columns,
            or none (then from the motor side alone); none for rigid drives.
        compliance_period: The sample period (s) those logs are resampled onto; None: their own (the median step
            of the first one's times; a simulated trace's is the physics step), which keeps the drive mode's band.
        torque_delay: Age of every log's torque readings against their angles (s): the drive's timing (a simulated
            drive's is its physics step, :data:`~delta_env.sensors.MEASURED_TORQUE_DELAY` by default).

    Raises:
        ValueError: for fewer than 2 logs, a compliance log that is a ROS 2 bag (a JointState carries no load-side
            angle), or compliance logs of which only some have load-side angles; LogFileError for a bad log;
            ValueError naming the robot file for a bad one; from the motor side alone UnexplainedTorqueError on drives
            the two-mass model does not explain (as behind a backlash) and UnseenModeError on logs that do not show
            the mode.
    """
    start = time.perf_counter()
    paths = [Path(path) for path in paths]
    if len(paths) < 2:
        raise ValueError(f"need at least 2 logs (the last one is held out for validation), got {len(paths)}")
    bags = [str(path) for path in compliance_paths if is_bag(path)]
    if bags:
        raise ValueError(
            f"compliance log {bags[0]} is a ROS 2 bag, whose JointState carries no load-side angle; give the "
            "compliance excitation as CSV or Parquet tables with load_angle columns"
        )
    geometry, masses = load_robot(robot)
    logs, summaries = zip(*(_read_log(path, topics) for path in paths), strict=True)
    with progress_bar(len(logs), "logs", "log", disable=not progress) as bar:
        prepared = run_jobs(
            functools.partial(prepare_log, torque_delay=torque_delay), logs, workers=workers, progress=bar
        )
    source = {
        "logs": list(summaries[:-1]),
        "validation_log": summaries[-1],
        "plant": {
            "identity": datasheet_identity(geometry, masses),
            "source": "logs",
            "robot_file": str(robot),
            "geometry_m": dataclasses.asdict(geometry),
            "masses_kg": dataclasses.asdict(masses),
            "control_period_s": CONTROL_PERIOD,
        },
    }
    run = _identify(
        prepared,
        logs,
        geometry,
        masses,
        data_method=LOGGED_DATA,
        controller="unknown (the logger's)",
        source=source,
        workers=workers,
        started=start,
        max_loop_gap=None,
        torque_delay=torque_delay,
    )
    if not compliance_paths:
        return run
    first = read_table_log(Path(compliance_paths[0]), compliance_period)
    compliance_logs = (first, *(read_table_log(Path(path), first.dt) for path in compliance_paths[1:]))
    load_side = [log.load_angles is not None for log in compliance_logs]
    if all(load_side):
        fit = fit_compliance(compliance_logs, torque_delay=torque_delay)
        method = "the motor side's least squares per joint (controllers.identification.compliance.fit_compliance)"
    elif not any(load_side):
        inertias = [arm_inertia(geometry, masses, log.motor_side_angles.mean(axis=0)) for log in compliance_logs]
        fit = fit_motor_side_compliance(compliance_logs, inertias, torque_delay=torque_delay)
        method = (
            "from the motor side alone (controllers.identification.compliance.fit_motor_side_compliance), the arm's "
            "inertia the robot file's datasheet model with rod forearms at each log's mean angles"
        )
    else:
        raise ValueError(
            "the compliance logs must all have load_angle columns or none, got them in "
            f"{[str(path) for path, has in zip(compliance_paths, load_side, strict=True) if has]} only"
        )
    provenance = {
        "method": f"{method} on the logs' whole periods; torques {torque_delay:g} s older than their angles",
        "logs": [{"path": str(path), "sha256": _sha256(Path(path))} for path in compliance_paths],
        "fit": fit.summary(),
    }
    return _with_compliance(run, fit, compliance_logs, provenance)


def _read_log(path: Path, topics: BagTopics | None) -> tuple[DriveLog, dict[str, Any]]:
    """A log file or bag and what the provenance records of it: where, its hash, its length on the grid, its
    commands and, for a bag, the topics, joint names and clock read."""
    if is_bag(path):
        topics = BagTopics() if topics is None else topics
        bag = read_bag(path, topics)
        log, extra = bag.log, {"bag": {"topic": topics.joint_states, "joint_names": list(bag.joint_names)}}
        extra["bag"] |= {"command_topic": topics.commands, "clock": bag.clock}
    else:
        log, extra = read_log(path), {}
    summary = {
        "path": str(path),
        "sha256": _sha256(path),
        "samples": len(log),
        "duration_s": (len(log) - 1) * log.dt,
        "commands": log.commands is not None,
    }
    return log, summary | extra


def _sha256(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (names and contents, in name order)."""
    digest = hashlib.sha256()
    if path.is_dir():
        for member in sorted(p for p in path.rglob("*") if p.is_file()):
            digest.update(str(member.relative_to(path)).encode() + b"\0" + member.read_bytes())
    else:
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _identify(
    prepared: Sequence[tuple[MotionData, NDArray[np.float64] | None]],
    logs: Sequence[DriveLog],
    geometry: DeltaGeometry,
    masses: DeltaMasses,
    *,
    data_method: str,
    controller: Any,
    source: dict[str, Any],
    workers: int,
    started: float,
    max_loop_gap: float | None,
    torque_delay: float,
) -> IdentificationRun:
    """Every fit and the held-out validation on prepared logs (:func:`prepare_log`), the last one held out: the
    one identification of simulated runs and of real logs.

    Args:
        prepared: Samples and drive lag (None without commands) of each log; the last one is held out.
        logs: The logs themselves, in the same order.
        geometry: The robot's lengths (m).
        masses: Its datasheet masses (kg), those of MKH.
        data_method: How the data were made (the provenance's ``method.data``).
        controller: The controller that ran the logs (the provenance's ``method.controller``).
        source: Provenance of the data: seeds and trajectories, or log files; ``plant``, the robot's summary.
        workers: Processes used (provenance).
        started: ``time.perf_counter()`` when the identification started.
        max_loop_gap: The simulation's largest loop gap (m), None for logs.
        torque_delay: Age of the logs' torque readings against their encoder samples (s) they were prepared with
            (:func:`prepare_log`; the provenance's ``method.torque_sample_delay_s``).
    """
    *prepared, (validation, _) = prepared
    data = [motion for motion, _ in prepared]
    lags = [lag for _, lag in prepared if lag is not None]
    if lags:
        lags_per_trajectory = np.array(lags)
        drive_lag = np.median(lags_per_trajectory, axis=0)
    else:
        logger.warning("no commands in the logs: the drive lag is not identified (null in the parameter file)")
        lags_per_trajectory, drive_lag = np.zeros((0, 3)), None
    data_time = time.perf_counter() - started

    lumped = DeltaDynamics.of_robot(geometry, masses)
    rods = DeltaDynamics.of_robot(geometry, masses, forearm_rods=True)
    (rho_fit, joint_fit), ours_time = _best_time(lambda: fit_least_squares(data, dynamics=lumped))
    paper, paper_time = _best_time(lambda: fit_paper_method(data, dynamics=lumped))
    rod_fit = fit_joint_least_squares(data, dynamics=rods)
    try:
        stribeck = fit_stribeck(data, rod_fit.parameters, rods)
        stribeck_error = ""
    except ValueError as error:
        logger.warning("the Stribeck excess is not identified (null in the parameter file): %s", error)
        stribeck, stribeck_error = None, str(error)

    models = {
        "MKH": lumped,
        "MId (paper)": lumped.with_parameters(paper.mid),
        "MId+F (paper)": lumped.with_parameters(paper.mid_f),
        "MId (LS)": lumped.with_parameters(rho_fit.parameters),
        "MId+F (joint LS)": lumped.with_parameters(joint_fit.parameters),
        "MId+F+R (joint LS)": rods.with_parameters(rod_fit.parameters),
    }
    validation_table = error_table(models, validation)
    training_table = error_table(models, concatenate(data))
    provenance = {
        "method": {
            "version": IDENTIFICATION_VERSION,
            "data": data_method,
            "mid": "linear least squares of (rho1, rho2), all samples",
            "mid_f": "joint linear least squares of [rho1, rho2, fv_1..3, fc_1..3]; rows with "
            f"|theta_dot_i| <= {FRICTION_VELOCITY_THRESHOLD} rad/s left out (static and Stribeck friction)",
            "paper_mid": "per-trajectory grid search of (rho1, rho2) minimising RMS torque error (eq. 7), averaged",
            "paper_mid_f": "paper_mid rho + per-trajectory, per-joint LS of (fv, fc) on the remaining error, averaged",
            "mid_f_rods": "the mid_f least squares on the model with homogeneous rod forearms (forearm_rods=True)",
            "stribeck": "on the mid_f_rods model's torque error, rows with "
            f"{REST_VELOCITY} < |theta_dot_i| <= {FRICTION_VELOCITY_THRESHOLD} rad/s: least squares of the excess "
            "fs_i on exp(-(theta_dot_i / vs)^2) sign(theta_dot_i) per joint, vs shared and searched (bounded, "
            "on log vs)"
            if stribeck is not None
            else f"not identified: {stribeck_error}",
            "drive_lag": "output-error fit per joint and trajectory of the first-order lag from the held commands to "
            "the reported torques (controllers.drive.identify_lag); median over the trajectories"
            if lags
            else "not identified: no commands in the logs; T = 0",
            "sample_period_s": CONTROL_PERIOD,
            "velocity_threshold_rad_s": FRICTION_VELOCITY_THRESHOLD,
            "rest_velocity_rad_s": REST_VELOCITY,
            "trim_samples": TRIM_SAMPLES,
            "torque_sample_delay_s": torque_delay,
            "smoother": {"jerk_std": SMOOTHER_JERK_STD, "measurement_std": ENCODER_NOISE_STD},
            "rho1_grid": list(RHO1_GRID),
            "rho2_grid": list(RHO2_GRID),
            "controller": controller,
        },
        **source,
        "samples": {
            "per_trajectory": [len(d) for d in data],
            "total": sum(len(d) for d in data),
            "validation": len(validation),
        },
        "residuals": {"mid": rho_fit.summary(), "mid_f": joint_fit.summary(), "mid_f_rods": rod_fit.summary()},
        "mid_f_between_trajectories": between_trajectory_spread(data, lumped),
        "drive_lag_per_trajectory_s": lags_per_trajectory.tolist(),
        "stribeck_rows_per_joint": None if stribeck is None else list(stribeck.rows),
        "raw_estimates": {
            "mid_f": dict(zip(joint_fit.names, joint_fit.estimate, strict=True)),
            "mid_f_rods": dict(zip(rod_fit.names, rod_fit.estimate, strict=True)),
            "paper_per_trajectory": {
                "rho": paper.rho.tolist(),
                "viscous": paper.viscous.tolist(),
                "coulomb": paper.coulomb.tolist(),
            },
        },
        "torque_error_training": training_table,
        "torque_error_validation": validation_table,
        "run_time_s": {
            "data_collection_and_smoothing": data_time,
            "joint_least_squares": ours_time,
            "paper_method": paper_time,
            "fits_timed_as": "best of 3 runs, from smoothed samples to parameters",
            "total": time.perf_counter() - started,
        },
        "workers": workers,
        "versions": package_versions(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    result = IdentificationResult(
        mid=rho_fit.parameters,
        mid_f=joint_fit.parameters,
        mid_f_rods=rod_fit.parameters,
        paper_mid=paper.mid,
        paper_mid_f=paper.mid_f,
        drive_lag=None if drive_lag is None else tuple(float(lag) for lag in drive_lag),
        stribeck_excess=None if stribeck is None else stribeck.excess,
        stribeck_velocity=None if stribeck is None else stribeck.velocity,
        standard_errors=_standard_errors({"mid": rho_fit, "mid_f": joint_fit, "mid_f_rods": rod_fit}, stribeck),
        provenance=provenance,
    )
    return IdentificationRun(
        result=result,
        data=tuple(data),
        validation=validation,
        models=models,
        logs=tuple(logs),
        max_loop_gap=max_loop_gap,
    )


def identify(
    n_trajectories: int = DEFAULT_TRAJECTORIES,
    seed: int = 0,
    duration: float = DEFAULT_DURATION,
    progress: bool = True,
    workers: int | None = None,
    **kwargs: Any,
) -> IdentificationResult:
    """Identify MId, MId+F, MId+F+R and the drive lag on a plant (the default realistic one unless ``plant`` is
    given), MId and MId+F by the paper's method and ours.

    Args:
        n_trajectories: Excitation trajectories (distinct seeds derived from ``seed``), >= 1.
        seed: Seed of the whole identification (trajectories and sensor noise).
        duration: Length of each excitation trajectory (s).
        progress: Show a tqdm progress bar.
        workers: Processes simulating trajectories; None: :data:`eval.processes.DEFAULT_WORKERS` (up to 2).
        **kwargs: ``validation_duration`` (s), ``plant`` (a PlantConfig) and ``region`` (an ExcitationRegion),
            see :func:`run_identification`.
    """
    return run_identification(n_trajectories, seed, duration, progress=progress, workers=workers, **kwargs).result
