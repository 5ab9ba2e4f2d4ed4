"""The sweep's unit of work: one episode of one controller on one scenario, reduced to one row of metrics.

Every call of the sweep into the episode runner (``eval.episodes``) and the identification
(``controllers.identification``) is in this module, so that they are re-pointed in one place when those
move. Both backends run :func:`run_unit`; it never raises for a failing episode: the row says
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
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from controllers.identification import DEFAULT_PARAMETER_PATH, load_or_identify
from controllers.residual import DEFAULT_POLICY_PATH
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from eval import metrics
from eval.episodes import CONTROLLER_LABELS, ESTIMATING_KEYS, ControllerSetup, build_controller, run_episode

__all__ = ["DEFAULT_PARAMETER_PATH", "DEFAULT_POLICY_PATH", "ControllerSetup"]  # re-exported for the sweep

CONTROLLERS = CONTROLLER_LABELS
"""Controller keys of ``--controllers`` and their labels."""

IDENTIFIED_KEYS = frozenset({"mid", "mid_f", "mid_f_r", "mid_f_rls", "mid_f_rls_ref"})
"""Controllers built from the identified parameters (the others: PD, plain MKH, the oracle, the residual
policy, which carries its own base)."""

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
)
"""Metrics of every episode (definitions in :mod:`eval.metrics`)."""

PAYLOAD_METRICS = ("payload_end_error_percent", "payload_settling_ms")
"""Payload metrics of the estimating controllers over the carries of objects >= 0.5 kg: mean |end error|
(%) and the worst settling time to +-5 % (ms, NaN if a carry never settles); NaN for the others."""

METRIC_FIELDS = (*EPISODE_METRICS, *PAYLOAD_METRICS)

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
            controller = build_controller(unit.controller, setup, env)
            record = run_episode(env, controller, unit.seed)
        finally:
            env.close()
        episode = record.metrics()
        row.update({name: episode[name] for name in EPISODE_METRICS})
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


def controller_setup(parameter_path: Path, residual_policy: Path = DEFAULT_POLICY_PATH) -> ControllerSetup:
    """What the controllers may know: the identified parameters at ``parameter_path`` (identified and saved
    there when the file is missing, about a minute) and the residual policy file.

    The payload estimators run untared (tare 0 kg): the sweep has no calibration episodes. With the
    rod-forearm model (MId+F+R) the empty gripper's apparent payload is a few grams.
    """
    identification = load_or_identify(parameter_path)
    return ControllerSetup(
        mid=identification.mid,
        mid_f=identification.mid_f,
        mid_f_rods=identification.mid_f_rods,
        residual_policy=Path(residual_policy),
    )


def setup_digest(setup: ControllerSetup, controllers: tuple[str, ...]) -> str:
    """Content hash (16 hex digits) of what the controllers know: parameters, tares, gains and, if the
    residual row runs, the policy file's bytes."""
    digest = hashlib.sha256(repr((setup.mid, setup.mid_f, setup.mid_f_rods, sorted(setup.tares.items()))).encode())
    digest.update(repr(setup.pd_gains).encode())
    if "residual" in controllers:
        digest.update(Path(setup.residual_policy).read_bytes())
    return digest.hexdigest()[:16]


def code_version() -> str:
    """Content hash (16 hex digits) of the project's Python sources and the versions of the libraries that
    decide an episode's numbers: any change of either gives new work-unit keys."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in _CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    versions = {}
    for name in _CODE_DEPENDENCIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    digest.update(json.dumps(versions, sort_keys=True).encode())
    return digest.hexdigest()[:16]
