"""The pick-rate data sheet's study (``python -m eval.rate``, docs/design.md section 9): its settings (the payloads,
the study sizes, the goals, :class:`RateConfig`) and its runs: a row per planner, controller and payload
(:func:`run_rows`) and the second controller's fastest fixed timing (:func:`fastest_fixed`). The report of the rows
is :mod:`eval.rate.report`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import (
    controller_entry,
    controller_label,
)
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import GRAVITY
from delta_env.scenario import TIMINGS, PickPlaceTask, Scenario
from eval.engine import grid
from eval.processes import DEFAULT_WORKERS
from eval.work import WorkUnit, run_grid

RATE_PAYLOADS = (0.1, 1.0, 2.0, RATED_PAYLOAD)
"""Payloads (kg) of the data sheet; the last is the robot's rated payload."""

RATE_TORQUE_SHARE = 1.0
"""Share of the drive's envelope (after the planner's 10 % margin) the data sheet's planned timings use unless
``--torque-share`` says otherwise: the whole envelope, within the thermal rating, as a maker rates its robot."""

CYCLE_TERMS = ("air_activation", "in_position_window")
"""The scenario task's terms of the cycle's ends with the in-position release: the air-activation time at pick and
place (s) and the in-position window within which the gripper switches (m)."""

JERK_LIMITED = "+jerk"
"""The suffix of a planner whose planned timing is jerk-limited (``online+jerk``: the task's ``jerk_limited``, its
laws averaged over one period of the drives' first mode, :class:`controllers.shaping.JerkLimitedTiming`)."""

PLANNERS = (*TIMINGS, *(f"{timing}{JERK_LIMITED}" for timing in TIMINGS if timing != "fixed"))
"""The data sheet's planners: the timings (:data:`delta_env.scenario.TIMINGS`) and the planned ones jerk-limited."""

COMPARED_PLANNERS = ("online", "declared", "worst_case", "fixed", *PLANNERS[len(TIMINGS) :])
"""The planner whose rows stand beside the published ones: the first of these that ran (a jerk-limited one only
when no other did)."""


@dataclass(frozen=True)
class StudySize:
    """How much a run of the data sheet measures (the defaults of ``--episodes``, ``--cycles``, ``--payloads``).

    Attributes:
        episodes: Episodes per row.
        cycles: Pick-and-place cycles per episode.
        payloads: Payloads (kg) besides the mixed stream.
        fastest: Whether to search the second controller's fastest fixed timing.
        workers: Processes (the default of ``--workers``).
    """

    episodes: int
    cycles: int
    payloads: tuple[float, ...]
    fastest: bool
    workers: int


FULL_STUDY = StudySize(episodes=3, cycles=4, payloads=RATE_PAYLOADS, fastest=True, workers=DEFAULT_WORKERS)
"""The data sheet."""

QUICK_STUDY = StudySize(episodes=1, cycles=2, payloads=(0.1, RATED_PAYLOAD), fastest=False, workers=1)
"""``--quick``: both ends of the payload range and the mixed stream, one short episode per row, no search, in this
process (each process plans the time-optimal moves afresh, and planning is most of a short run's work)."""

QUICK_NOTE = "Quick run: fewer episodes, cycles and payloads than the data sheet (python -m eval.rate without --quick)."
"""What a ``--quick`` run says first, on the console and in its summary."""

MIXED = "mixed"
"""The ``payload`` of the mixed stream's rows: objects drawn from U[0, rated payload]."""

DEFAULT_CONTROLLERS = ("mid_f_rls_lag", "pd")
"""The model-based controller (which runs every row) and the controllers scored at its timings."""

CALIBRATION_EPISODES = 3
"""Payload-free episodes of the tare of the estimator that retimes the online carries."""

TRACKING_GOAL_MM = 0.5
"""Tracking RMS (mm) a row must keep to count as holding its timing."""

PLACE_GOAL_MM = 0.5
"""Largest place-position error at release (mm) a row must keep to count as holding its timing."""

FASTEST_SEARCH = (0.1 * GRAVITY, 6.0 * GRAVITY, 7)
"""Fixed-timing search of the fastest timing that meets the goals: lowest and highest peak acceleration (m/s^2)
and bisection steps (on a log scale, about 3 % resolution)."""


@dataclass(frozen=True)
class RateConfig:
    """The resolved configuration of a data sheet run (``python -m eval.rate``), recorded as it is in the run's
    manifest (:func:`eval.run_folder.configuration_record`); the options as ``--help`` gives them, the study size's
    defaults filled in.

    Attributes:
        scenario: The scenario every row derives (:func:`rate_scenario`): its task's ``n_cycles`` is ``cycles`` and
            its ``torque_share`` is ``torque_share``.
        geometry: The geometry file of ``--geometry``, or None.
        release: ``--release``, or None (the scenario's).
        quick: A ``--quick`` run.
        seed: Seed of the first episode.
        episodes: Episodes per row.
        cycles: Pick-and-place cycles per episode.
        planners: The planners (:data:`PLANNERS`), in order.
        controllers: The controller keys; the first runs every row.
        residual: The policy file of the rows that read one.
        payloads: Payloads (kg) besides the mixed stream.
        torque_share: Share of the drive's envelope the planned timings may use.
        no_fastest: ``--no-fastest``.
        out: The run folder of ``--out``, or None.
        force: Write into an existing, non-empty ``out``.
        runs_dir: ``--runs-dir``, or None.
        parameters: The identified parameter file: ``--parameters`` (None: the robot's own) until it is known.
        servo: Feedback of the model rows (:data:`controllers.setup.SERVOS`).
        workers: Processes.
        fastest: Whether to search the second controller's fastest fixed timing.
    """

    scenario: Scenario
    geometry: str | None
    release: str | None
    quick: bool
    seed: int
    episodes: int
    cycles: int
    planners: tuple[str, ...]
    controllers: tuple[str, ...]
    residual: Path
    payloads: list[float]
    torque_share: float
    no_fastest: bool
    out: Path | None
    force: bool
    runs_dir: Path | None
    parameters: Path | None
    servo: str
    workers: int
    fastest: bool


def kilograms(payloads: Sequence[float]) -> str:
    """Payloads (kg) as ``--payloads`` takes them: ``"0.1,4"``."""
    return ",".join(f"{payload:g}" for payload in payloads)


def rate_scenario(base: Scenario, planner: str, payload: float | str) -> Scenario:
    """``base`` on the standard cycle, timed by ``planner`` (:data:`PLANNERS`), with every object ``payload`` kg (or
    the mixed stream)."""
    masses = (0.0, RATED_PAYLOAD) if payload == MIXED else (float(payload), float(payload))
    timing = planner.removesuffix(JERK_LIMITED)
    task = dataclasses.replace(
        base.task, cycle="standard", timing=timing, jerk_limited=planner != timing, payload_mass_range=masses
    )
    return dataclasses.replace(base, name=f"{base.name}/{planner}/{payload_label(payload)}", task=task)


def planner_name(task: PickPlaceTask) -> str:
    """The planner (:data:`PLANNERS`) of a task :func:`rate_scenario` made."""
    return task.timing + (JERK_LIMITED if task.jerk_limited else "")


def payload_label(payload: float | str) -> str:
    """The ``payload`` column of a row: the mass in kg (``"4"``, ``"0.1"``) or ``"mixed"``."""
    return payload if payload == MIXED else f"{float(payload):g}"


def cycle_terms(task: PickPlaceTask) -> dict[str, float]:
    """The terms of :data:`CYCLE_TERMS` of an in-position release (air activation in s, in-position window in m):
    what the scenario says about the cycle's ends; none for the timed release (a fixed dwell)."""
    if task.release != "in_position":
        return {}
    return {name: float(getattr(task, name)) for name in CYCLE_TERMS}


SETTLE_COLUMNS = (
    ("settle_time_mean_ms", np.mean, float, "settle (ms)"),
    ("settle_time_max_ms", np.max, float, "settle max"),
    ("settle_timeouts", np.sum, int, "time-outs"),
    ("residual_vibration_mean_um", np.mean, float, "residual p-p (um)"),
    ("residual_vibration_max_um", np.max, float, "residual max"),
)
"""Per-episode settle metrics of the in-position release, how a row aggregates each over its episodes, the type of
its cell and its header in the summary: the mean settle time (ms), the longest (ms), the places that never
settled within the time-out (count), and the residual vibration at the place, mean and largest (um: the platform's
peak to peak over :data:`eval.metrics.RESIDUAL_WINDOW` from the in-position signal)."""


def summarize(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One row of ``rate.csv`` from a row's episodes' metrics (:meth:`EpisodeRecord.metrics`): means over them,
    except the worst place error (mm), the summed violations and divergences, the largest torque ratios, whether
    the thermal limit was ever exceeded, and the :data:`SETTLE_COLUMNS` when every episode has them."""
    rows = list(episodes)

    def column(name: str) -> np.ndarray:
        return np.array([row[name] for row in rows], dtype=float)

    settle = {
        name: kind(reduce(column(name))) for name, reduce, kind, _ in SETTLE_COLUMNS if all(name in row for row in rows)
    }
    return {
        "picks_per_min": float(np.mean(column("picks_per_min"))),
        "cycle_time_mean_s": float(np.mean(column("cycle_time_mean_s"))),
        "tracking_rms_mm": float(np.mean(column("tracking_rms_mm"))),
        "path_deviation_rms_mm": float(np.mean(column("path_deviation_rms_mm"))),
        "place_error_mm": float(np.max(column("place_error_max_mm"))),
        "envelope_violations": int(np.sum(column("envelope_violations"))),
        "peak_torque_ratio": float(np.max(column("peak_torque_ratio"))),
        "rms_torque_ratio": float(np.max(column("rms_torque_ratio"))),
        "thermal_exceeded": bool(np.any(column("thermal_exceeded"))),
        "diverged": int(np.sum(column("diverged"))),
        **settle,
        "episodes": len(rows),
    }


def holds(row: Mapping[str, Any]) -> bool:
    """Whether a row holds its timing: the tracking and place goals, no violation, no divergence, no overheating,
    and no place that never settled in position (when the row reports it)."""
    return (
        row["tracking_rms_mm"] <= TRACKING_GOAL_MM
        and row["place_error_mm"] <= PLACE_GOAL_MM
        and row["envelope_violations"] == 0
        and row["diverged"] == 0
        and not row["thermal_exceeded"]
        and row.get("settle_timeouts", 0) == 0
    )


def row_episodes(config: RateConfig) -> int:
    """Episodes of every planner x payload row of every controller (:func:`run_rows`)."""
    return len(config.planners) * (len(config.payloads) + 1) * len(config.controllers) * config.episodes


def paced(keys: Sequence[str]) -> tuple[list[str], list[str]]:
    """The controllers of ``keys`` that run every row at their own pace (the first, and every other that estimates the
    payload itself: an online timing retimes its carries on its own estimate, as a cell would run it), and those that
    replay the first's references."""
    own = [keys[0], *(key for key in keys[1:] if controller_entry(key).estimates_payload)]
    return own, [key for key in keys if key not in own]


def run_rows(config: RateConfig, setup: Any, progress: Any = None) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Every planner x payload row of the controllers that run at their own pace (:func:`paced`), then the others on
    the first's references; ``progress`` (a bar, or None) is advanced once per episode."""
    own, others = paced(config.controllers)
    loads = [*config.payloads, MIXED]
    scenarios = [rate_scenario(config.scenario, timing, load) for timing in config.planners for load in loads]
    setups = {scenario.content_hash: setup for scenario in scenarios}
    units = grid(scenarios, own, range(config.seed, config.seed + config.episodes))
    records = run_grid(units, setups, workers=config.workers, progress=progress)
    replays = [
        WorkUnit(unit.scenario, key, unit.seed, tuple(record.masses.tolist()), record.reference)
        for key in others
        for unit, record in zip(units, records, strict=True)
        if unit.controller == config.controllers[0]
    ]
    records += run_grid(replays, setups, workers=config.workers, progress=progress)
    grouped: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    episode_rows = []
    for unit, record in zip([*units, *replays], records, strict=True):
        timing, (low, high) = planner_name(unit.scenario.task), unit.scenario.task.payload_mass_range
        load = payload_label(low) if low == high else MIXED
        episode = record.metrics()
        grouped.setdefault((timing, controller_label(unit.controller), load), []).append(episode)
        episode_rows.append(
            {"planner": timing, "controller": controller_label(unit.controller), "payload": load, "seed": unit.seed}
            | episode
        )
    rows = [
        {"planner": timing, "controller": label, "payload": load} | summarize(episodes)
        for (timing, label, load), episodes in grouped.items()
    ]
    return rows, episode_rows


def fastest_episodes(config: RateConfig) -> int:
    """Episodes of :func:`fastest_fixed`."""
    return (len(config.payloads) + 1) * FASTEST_SEARCH[2] * config.episodes


def fastest_fixed(config: RateConfig, setup: Any, key: str, progress: Any = None) -> list[dict[str, Any]]:
    """For each payload, the fastest fixed timing (peak acceleration) at which ``key`` holds the goals; ``progress``
    (a bar, or None) is advanced once per episode."""
    low, high, steps = FASTEST_SEARCH
    rows = []
    for load in [*config.payloads, MIXED]:
        best = None
        lower, upper = math.log(low), math.log(high)
        for _ in range(steps):
            acceleration = math.exp(0.5 * (lower + upper))
            base = dataclasses.replace(
                config.scenario, task=dataclasses.replace(config.scenario.task, peak_acceleration=acceleration)
            )
            scenario = rate_scenario(base, "fixed", load)
            units = grid([scenario], [key], range(config.seed, config.seed + config.episodes))
            records = run_grid(units, {scenario.content_hash: setup}, workers=config.workers, progress=progress)
            row = summarize([record.metrics() for record in records])
            if holds(row):
                lower, best = math.log(acceleration), row | {"peak_acceleration_g": acceleration / GRAVITY}
            else:
                upper = math.log(acceleration)
        rows.append(
            {"controller": controller_label(key), "payload": payload_label(load)}
            | (best if best is not None else {"picks_per_min": math.nan, "peak_acceleration_g": math.nan})
        )
    return rows
