"""The sweep's unit of work: one episode of one controller on one scenario, reduced to one row of metrics.

Every call of the sweep into the episode runner (:func:`eval.episodes.run_episode`), the identification
(:func:`eval.identification.identify_robot`) and the tare calibration (:mod:`eval.calibration`) is in this
module. Both backends run :func:`run_unit`; it never raises for a failing episode: the row says
``status = "failed"`` with the error, so the failure is recorded, never dropped.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import (
    CONTROLLER_LABELS,
    ESTIMATING_KEYS,
    ESTIMATOR_REGRESSORS,
    ControllerSetup,
    build_controller,
)
from controllers.residual import DEFAULT_POLICY_PATH
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from eval import metrics
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, calibrate_tares, calibrated_setup
from eval.comparison import calibration_seeds
from eval.episodes import run_episode
from eval.faults import FAULT_KIND_METRICS, FAULT_METRICS, fault_kind_metrics
from eval.identification import identify_robot, robot_setup
from eval.run_folder import package_versions
from eval.tasks import CELL_ESTIMATOR_KEY, timed

CONTROLLERS = CONTROLLER_LABELS
"""Controller keys of ``--controllers`` and their labels."""

EPISODE_METRICS = (
    "tracking_rms_mm",
    "tracking_max_mm",
    "joint_error_rms_mrad",
    "torque_rms_nm",
    "torque_peak_nm",
    "energy_j",
    "diverged",
    "saturated_steps",
    "steps",
    "picks_per_min",
    "cycle_time_mean_s",
    "cycle_time_max_s",
    "place_error_mean_mm",
    "place_error_max_mm",
    "path_deviation_rms_mm",
    "path_deviation_max_mm",
    "envelope_violations",
    "peak_torque_ratio",
    "rms_torque_ratio",
    "thermal_margin",
    "speed_override",
    "stopped",
)
"""Metrics of every episode, the pick-rate scores included (definitions in :mod:`eval.metrics`), and the fault
reaction's speed override and stop (:class:`~eval.episodes.EpisodeRecord`)."""

PAYLOAD_METRICS = ("payload_end_error_percent", "payload_settling_ms")
"""Payload metrics of the estimating controllers over the carries of objects >= 0.5 kg: mean |end error|
(%) and the worst settling time to +-5 % (ms, NaN if a carry never settles); NaN for the others."""

METRIC_FIELDS = (*EPISODE_METRICS, *PAYLOAD_METRICS, *FAULT_METRICS, *FAULT_KIND_METRICS)
"""The metrics of a row: the episode's, the payload's and the faults' (:data:`eval.faults.FAULT_METRICS`: faults
injected, detected and missed, detections, false alarms, consequences, median and worst detection latency; and
:data:`eval.faults.FAULT_KIND_METRICS` per fault kind)."""

_CODE_PACKAGES = ("delta_env", "controllers", "eval")
_CODE_DEPENDENCIES = ("mujoco", "numpy", "scipy", "filterpy", "gymnasium")


@dataclass(frozen=True)
class WorkUnit:
    """One episode of the grid.

    Attributes:
        scenario: The robot and the work.
        controller: Controller key (see :data:`CONTROLLERS`).
        seed: Episode seed: the same seed gives every controller the same path and objects.
    """

    scenario: Scenario
    controller: str
    seed: int


def run_unit(unit: WorkUnit, setup: ControllerSetup) -> dict[str, Any]:
    """Run one episode and return its row: ``status``, ``error``, the :data:`METRIC_FIELDS`, ``seconds``
    (wall), ``cpu_seconds`` (this process's CPU time), ``host`` and ``pid``. Exceptions of the episode are
    caught and recorded in the row."""
    started, cpu_started = time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"status": "ok", "error": "", **dict.fromkeys(METRIC_FIELDS, math.nan)}
    try:
        env = DeltaPickPlaceEnv(scenario=unit.scenario)
        try:
            controller = timed(env, build_controller(unit.controller, setup, env), unit.controller, setup)
            record = run_episode(env, controller, unit.seed)
        finally:
            env.close()
        episode = record.metrics()
        row.update({name: episode[name] for name in (*EPISODE_METRICS, *FAULT_METRICS)})
        row.update(fault_kind_metrics(record.faults()))
        if unit.controller in ESTIMATING_KEYS:
            scored = [carry for carry in record.carries() if carry.mass >= metrics.MIN_RELATIVE_MASS]
            if scored:
                row["payload_end_error_percent"] = float(np.mean([abs(c.end_error_percent) for c in scored]))
                row["payload_settling_ms"] = max(c.settling_time_ms for c in scored)
    except Exception as error:
        row["status"], row["error"] = "failed", f"{type(error).__name__}: {error}"
    row.update(
        seconds=time.perf_counter() - started,
        cpu_seconds=time.process_time() - cpu_started,
        host=socket.gethostname(),
        pid=os.getpid(),
    )
    return row


def robot_setups(
    scenarios: list[Scenario],
    residual_policy: Path = DEFAULT_POLICY_PATH,
    identification_root: Path | None = None,
) -> dict[str, ControllerSetup]:
    """One untared setup per robot identity among ``scenarios``: the robot's identification (identified once
    and kept under ``identification_root`` when missing, about a minute per robot; None:
    :func:`eval.identification.identification_root`) and the residual policy.

    Returns:
        The setups by robot identity.
    """
    setups = {}
    for scenario in scenarios:
        if scenario.robot_identity not in setups:
            identification = identify_robot(scenario.plant, identification_root)
            setups[scenario.robot_identity] = robot_setup(
                scenario.plant, identification, residual_policy=Path(residual_policy)
            )
    return setups


def tared_setup(
    scenario: Scenario,
    setup: ControllerSetup,
    controllers: list[str],
    *,
    seed: int = 0,
    calibration_episodes: int = DEFAULT_CALIBRATION_EPISODES,
    workers: int = 1,
) -> ControllerSetup:
    """``setup`` with the tares of the RLS controllers among ``controllers``, measured on ``scenario``, and the sums of
    the calibration's empty moves when the scenario's episodes run on its robot (:func:`calibrated_setup`).

    They are measured as ``python -m eval`` measures them (:mod:`eval.calibration`): payload-free
    episodes of the scenario on the calibration seeds of ``seed``. An online timing also tares the cell's estimator,
    which it reads beside the controllers that have none (:func:`eval.tasks.timed`).
    """
    keys = [key for key in controllers if key in ESTIMATOR_REGRESSORS]
    if scenario.task.timing == "online" and CELL_ESTIMATOR_KEY not in keys:
        keys.append(CELL_ESTIMATOR_KEY)
    if not keys:
        return setup
    seeds = calibration_seeds(seed, calibration_episodes)
    calibration = calibrate_tares(keys, setup, seeds, scenario.task.n_cycles, workers=workers, scenario=scenario)
    return calibrated_setup(setup, calibration, scenario)


def setup_digest(setup: ControllerSetup, controllers: tuple[str, ...]) -> str:
    """Content hash (16 hex digits) of what the controllers know: parameters, tares, the empty moves' sums, gains
    and, if the residual row runs, the policy file's bytes."""
    known = (
        *(setup.mid, setup.mid_f, setup.mid_f_rods, setup.drive_lag, sorted(setup.tares.items()), setup.geometry),
        *(setup.masses, setup.drive, setup.encoder_bits, setup.fault_reaction),
    )
    digest = hashlib.sha256(repr(known).encode())
    for key, sums in sorted(setup.empty_moves.items()):
        digest.update(key.encode())
        digest.update(np.ascontiguousarray(sums.information).tobytes())
        digest.update(np.ascontiguousarray(sums.moment).tobytes())
    digest.update(repr(setup.pd_gains).encode())
    if "residual" in controllers:
        digest.update(Path(setup.residual_policy).read_bytes())
    return digest.hexdigest()[:16]


def code_version() -> str:
    """Content hash (16 hex digits) of the project's Python sources and the versions of Python and of the
    libraries that decide an episode's numbers: any change of either gives new work-unit keys."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in _CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    digest.update(json.dumps(package_versions(_CODE_DEPENDENCIES), sort_keys=True).encode())
    return digest.hexdigest()[:16]
