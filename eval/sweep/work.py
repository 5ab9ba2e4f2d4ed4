"""The experiments' unit of work: one episode of one controller on one scenario (:class:`WorkUnit`).

:func:`unit_record` runs it and returns its :class:`~eval.episodes.EpisodeRecord` (the comparison and the residual
scores read whole records); :func:`run_unit` reduces it to one row of metrics (the sweep's table) and never raises
for a failing episode: the row says ``status = "failed"`` with the error, so the failure is recorded, never dropped.
Both backends of :func:`eval.engine.run_grid` run either.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controllers.registry import (
    CELL_ESTIMATOR_KEY,
    ControllerSetup,
    controller_entry,
    controller_source,
    residual_policy_path,
)
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval import metrics
from eval.episodes import EpisodeRecord
from eval.faults import FAULT_KIND_METRICS, FAULT_METRICS, fault_kind_metrics
from eval.run_folder import package_versions
from eval.tasks import Task, run_task

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

METRIC_FIELDS = (*EPISODE_METRICS, *metrics.PAYLOAD_SCORES, *FAULT_METRICS, *FAULT_KIND_METRICS)
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
        controller: Controller key (:func:`controllers.registry.controller_entry`).
        seed: Episode seed: the same seed gives every controller the same path and objects.
        masses: Object masses (kg) instead of the drawn ones (one per cycle), or None.
        reference: A path (1 kHz) to follow instead of the scenario's pick-and-place cycles, or None; it is not timed.
    """

    scenario: Scenario
    controller: str
    seed: int
    masses: tuple[float, ...] | None = None
    reference: Trajectory | None = None


def unit_record(unit: WorkUnit, setup: ControllerSetup) -> EpisodeRecord:
    """Run one episode of ``unit`` with what its controller knows (``setup``) and return its record."""
    task = Task(
        "episode",
        unit.controller,
        0,
        unit.seed,
        unit.scenario.task.n_cycles,
        setup,
        unit.masses,
        unit.scenario,
        unit.reference,
    )
    return run_task(task)[1]


def run_unit(unit: WorkUnit, setup: ControllerSetup) -> dict[str, Any]:
    """Run one episode and return its row: ``status``, ``error``, the :data:`METRIC_FIELDS`, ``seconds``
    (wall), ``cpu_seconds`` (this process's CPU time), ``host`` and ``pid``. Exceptions of the episode are
    caught and recorded in the row."""
    started, cpu_started = time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"status": "ok", "error": "", **dict.fromkeys(METRIC_FIELDS, math.nan)}
    try:
        record = unit_record(unit, setup)
        episode = record.metrics()
        row.update({name: episode[name] for name in (*EPISODE_METRICS, *FAULT_METRICS)})
        row.update(fault_kind_metrics(record.faults()))
        if controller_entry(unit.controller).estimates_payload:
            row.update(metrics.payload_scores(record.carries()))
    except Exception as error:
        row["status"], row["error"] = "failed", f"{type(error).__name__}: {error}"
    row.update(
        seconds=time.perf_counter() - started,
        cpu_seconds=time.process_time() - cpu_started,
        host=socket.gethostname(),
        pid=os.getpid(),
    )
    return row


def setup_digest(setup: ControllerSetup, controller: str) -> str:
    """Content hash (16 hex digits) of what ``controller`` knows: every field of ``setup``
    (:meth:`~controllers.registry.ControllerSetup.content_hash`) with the tares and empty-move sums of this controller
    and of the cell's estimator (which an online timing runs beside it) only; the residual policy by its file's bytes,
    for a row that reads it only (:attr:`~controllers.registry.ControllerEntry.reads_policy_file`); and a user
    controller's source (:func:`controllers.registry.controller_source`), whose code the project's version does not
    cover. Adding a controller to a grid, or editing another's code, leaves the
    keys of this controller's rows as they were."""
    own = {controller, CELL_ESTIMATOR_KEY}
    known = dataclasses.replace(
        setup,
        residual_policy=None,
        tares={key: tare for key, tare in setup.tares.items() if key in own},
        empty_moves={key: sums for key, sums in setup.empty_moves.items() if key in own},
    )
    digest = hashlib.sha256(known.content_hash().encode())
    if controller_entry(controller).reads_policy_file:
        digest.update(residual_policy_path(setup).read_bytes())
    digest.update(controller_source(controller))
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
