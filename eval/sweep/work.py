"""The sweep's row of a work unit (:class:`eval.work.WorkUnit`): :func:`run_unit` reduces the unit's episode to one
row of metrics and never raises for a failing episode: the row says ``status = "failed"`` with the error, so the
failure is recorded, never dropped. :func:`setup_digest` keys what a row's controller knows.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import socket
import time
from typing import Any

from controllers.registry import (
    CELL_ESTIMATOR_KEY,
    ControllerSetup,
    controller_entry,
    controller_source,
    residual_policy_path,
)
from eval import metrics
from eval.fault_scores import FAULT_KIND_METRICS, FAULT_METRICS, fault_kind_metrics
from eval.work import WorkUnit, unit_record

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
"""The metrics of a row: the episode's, the payload's and the faults' (:data:`eval.fault_scores.FAULT_METRICS`: faults
injected, detected and missed, detections, false alarms, consequences, median and worst detection latency; and
:data:`eval.fault_scores.FAULT_KIND_METRICS` per fault kind)."""


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
