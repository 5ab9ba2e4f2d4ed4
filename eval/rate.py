"""``python -m eval.rate``: the pick-rate data sheet (docs/design.md section 9).

Picks per minute on the industry's 25/305/25 mm standard cycle, like a Delta picker's data sheet, at payloads
0.1, 1, 2 and 4 kg (the rated payload) and on a mixed stream of objects drawn from U[0, 4] kg, for each way of
timing the moves (``--planners``). Planned timings use the drive's whole envelope (after the planner's 10 % margin
for model error) within its thermal rating (``--torque-share`` takes less); the cycle's ends (air activation, the
in-position window) are the scenario's. ABB's published rows (:mod:`eval.published_rates`) stand beside ours.

- ``fixed``: today's timing, every move at the scenario's peak acceleration (3 g);
- ``worst_case``: time-optimal within the drive, every carry for the heaviest object of the stream;
- ``declared``: time-optimal, each carry for its object's true mass (the reference, not a controller);
- ``online``: time-optimal, a carry starts for the heaviest object and is retimed once the payload estimate
  has settled (:mod:`controllers.payload_timing`).

The first controller of ``--controllers`` (by default the model-based MId+F+R+RLS+lag+PD) runs every row, and
so does every other controller that estimates the payload itself (the RLS rows, the residual: :func:`paced`), at
its own pace: timed on its own estimate, released in position. The others (PD, the rows without an estimate) run
the first's references (its episodes' reference, replayed with the same objects), so that they are scored at the
same timings. For each payload it also finds the fastest fixed timing at which the second
controller (PD by default) meets the tracking and place goals (:data:`TRACKING_GOAL_MM`, :data:`PLACE_GOAL_MM`):
the ratio of the two pick rates is what the model buys.

``--quick`` measures 1 episode x 2 cycles per row at 0.1 and 4 kg and the mixed stream in one process, without
the search of the fastest fixed timing: seconds instead of minutes, said in the summary and recorded in
``config.json``.
Progress goes to standard error (a bar on a terminal, plain lines otherwise).

Writes ``rate.csv`` (one row per planner, controller and payload: ``payload`` in kg or ``mixed``),
``rate_episodes.csv``, ``pd_fastest.csv``, ``rate.png`` and ``summary.md`` (also printed) into the run folder
(``--out``, else ``<runs root>/rate/<UTC time>``), with its manifest ``config.json`` (:mod:`eval.run_folder`).

Usage: python -m eval.rate [--quick] [--scenario S] [--geometry FILE] [--seed 0] [--episodes 3] [--cycles 4]
                           [--out DIR] [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import (
    CELL_ESTIMATOR_KEY,
    controller_entry,
    controller_label,
    controllers_help,
    parse_controller_keys,
)
from controllers.residual import read_policy_settings
from delta_env.config import RATED_PAYLOAD, PlantConfig
from delta_env.cycles import DEFAULT_DWELL
from delta_env.geometry import GRAVITY
from delta_env.scenario import TIMINGS, PickPlaceTask, Scenario
from eval import metrics
from eval.calibration import calibration_seeds
from eval.console import CommandParser, command_main, plural, progress_bar
from eval.engine import grid, prepare, run_grid
from eval.processes import DEFAULT_WORKERS
from eval.published_rates import ABB_IRB_360, DIFFERENCES, PublishedSheet
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    command_run_folder,
    write_csv,
)
from eval.scenario_args import (
    add_parameters_argument,
    add_residual_argument,
    add_scenario_arguments,
    add_servo_argument,
    add_workers_argument,
    check_episode_seeds,
    check_ranges,
    scenario_from_arguments,
)
from eval.sweep.work import WorkUnit
from eval.tables import FEEDBACK_LINES

RATE_PAYLOADS = (0.1, 1.0, 2.0, RATED_PAYLOAD)
"""Payloads (kg) of the data sheet; the last is the robot's rated payload."""

RATE_TORQUE_SHARE = 1.0
"""Share of the drive's envelope (after the planner's 10 % margin) the data sheet's planned timings use unless
``--torque-share`` says otherwise: the whole envelope, within the thermal rating, as a maker rates its robot."""

CYCLE_TERMS = ("air_activation", "in_position_window")
"""The scenario task's terms of the cycle's ends with the in-position release: the air-activation time at pick and
place (s) and the in-position window within which the gripper switches (m)."""

COMPARED_PLANNERS = ("online", "declared", "worst_case", "fixed")
"""The planner whose rows stand beside the published ones: the first of these that ran."""


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
    manifest (:meth:`manifest`); the options as ``--help`` gives them, the study size's defaults filled in.

    Attributes:
        scenario: The scenario every row derives (:func:`rate_scenario`): its task's ``n_cycles`` is ``cycles`` and
            its ``torque_share`` is ``torque_share``.
        geometry: The geometry file of ``--geometry``, or None.
        release: ``--release``, or None (the scenario's).
        quick: A ``--quick`` run.
        seed: Seed of the first episode.
        episodes: Episodes per row.
        cycles: Pick-and-place cycles per episode.
        planners: The timings (:data:`delta_env.scenario.TIMINGS`), in order.
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

    def manifest(self) -> dict[str, Any]:
        """The configuration as the manifest records it: every field, the scenario by its name (its file is
        ``scenario.toml`` beside)."""
        fields = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        return {**fields, "scenario": self.scenario.name}


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    parser = CommandParser(
        prog="python -m eval.rate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_scenario_arguments(parser)
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"a short run: {QUICK_STUDY.episodes} episode x {QUICK_STUDY.cycles} cycles per row at "
        f"{_kilograms(QUICK_STUDY.payloads).replace(',', ' and ')} kg and the mixed stream, no fastest-fixed search, "
        f"{QUICK_STUDY.workers} process (options given explicitly still apply)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help=f"episodes per row (default {FULL_STUDY.episodes}; {QUICK_STUDY.episodes} with --quick)",
    )
    parser.add_argument(
        "--cycles",
        type=int,
        default=None,
        help=f"pick-and-place cycles per episode (default {FULL_STUDY.cycles}; {QUICK_STUDY.cycles} with --quick)",
    )
    parser.add_argument(
        "--planners",
        default=",".join(TIMINGS),
        help=f"comma-separated timings from {', '.join(TIMINGS)} (default: all)",
    )
    parser.add_argument(
        "--controllers",
        default=",".join(DEFAULT_CONTROLLERS),
        help="the first runs every row, as do those that estimate the payload (e.g. residual); the others replay the "
        "first's references; " + controllers_help(",".join(DEFAULT_CONTROLLERS)),
    )
    add_residual_argument(parser)
    parser.add_argument(
        "--payloads",
        default=None,
        help=f"comma-separated payloads (kg) in (0, {RATED_PAYLOAD:g}] besides the mixed stream "
        f"(default {_kilograms(FULL_STUDY.payloads)}; {_kilograms(QUICK_STUDY.payloads)} with --quick)",
    )
    parser.add_argument(
        "--torque-share",
        type=float,
        default=RATE_TORQUE_SHARE,
        help="share of the drive's envelope (after the planner's 10 %% margin) the planned timings may use, in "
        f"(0, 1]; they always keep the thermal rating (default {RATE_TORQUE_SHARE:g}: the whole envelope, whatever "
        "the scenario sets)",
    )
    parser.add_argument(
        "--no-fastest", action="store_true", help="skip the search of the second controller's fastest fixed timing"
    )
    parser.add_argument("--out", type=Path, default=None, help="run folder (default <runs root>/rate/<UTC time>)")
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    add_parameters_argument(parser)
    add_servo_argument(parser)
    add_workers_argument(parser, f"processes (default {FULL_STUDY.workers}; {QUICK_STUDY.workers} with --quick)")
    parser.set_defaults(workers=None)
    return parser


def resolve(args: argparse.Namespace, parser: argparse.ArgumentParser) -> RateConfig:
    """The configuration of the parsed command line ``args`` (left as they are); a bad value is a parser error."""
    size = QUICK_STUDY if args.quick else FULL_STUDY
    episodes = size.episodes if args.episodes is None else args.episodes
    cycles = size.cycles if args.cycles is None else args.cycles
    payload_text = _kilograms(size.payloads) if args.payloads is None else args.payloads
    workers = size.workers if args.workers is None else args.workers
    sized = argparse.Namespace(**{**vars(args), "episodes": episodes, "cycles": cycles, "workers": workers})
    check_ranges(parser, sized, {"seed": 0, "episodes": 1, "cycles": 1, "workers": 1})
    check_episode_seeds(parser, sized)
    scenario = scenario_from_arguments(args, parser)
    try:  # one home: the scenario every row derives
        task = dataclasses.replace(scenario.task, n_cycles=cycles, torque_share=args.torque_share)
    except ValueError as error:
        parser.error(f"--torque-share: {error}")
    planners = _listed(parser, "--planners", args.planners, TIMINGS)
    try:
        controllers = parse_controller_keys(args.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    if any(controller_entry(key).reads_policy_file for key in controllers):
        try:
            read_policy_settings(args.residual)
        except (FileNotFoundError, ValueError) as error:
            parser.error(f"--residual: {error}")
    privileged = [key for key in controllers if controller_entry(key).privileged]
    if privileged:
        parser.error(f"--controllers: {', '.join(privileged)}: a bound that knows the plant, without a pick rate")
    try:
        payloads = [float(value) for value in payload_text.split(",") if value.strip()]
    except ValueError:
        parser.error(f"--payloads must be numbers (kg), got {payload_text!r}")
    if not payloads or not all(0.0 < p <= RATED_PAYLOAD for p in payloads):
        parser.error(f"--payloads must lie in (0, {RATED_PAYLOAD:g}] kg, got {payload_text!r}")
    return RateConfig(
        **{
            **vars(sized),
            "scenario": dataclasses.replace(scenario, task=task),
            "planners": tuple(planners),
            "controllers": tuple(controllers),
            "payloads": payloads,
            "fastest": size.fastest and not args.no_fastest,
        }
    )


def parse_args(argv: Sequence[str] | None) -> RateConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def _kilograms(payloads: Sequence[float]) -> str:
    """Payloads (kg) as ``--payloads`` takes them: ``"0.1,4"``."""
    return ",".join(f"{payload:g}" for payload in payloads)


def _listed(parser: argparse.ArgumentParser, flag: str, text: str, allowed: Sequence[str]) -> list[str]:
    """The comma-separated values of ``flag``, each one of ``allowed`` (a parser error otherwise)."""
    values = list(dict.fromkeys(value.strip() for value in text.split(",") if value.strip()))
    unknown = [value for value in values if value not in allowed]
    if unknown or not values:
        parser.error(f"{flag}: unknown or no values {unknown}; choose from {', '.join(allowed)}")
    return values


def rate_scenario(base: Scenario, timing: str, payload: float | str) -> Scenario:
    """``base`` on the standard cycle, timed by ``timing``, with every object ``payload`` kg (or the mixed stream)."""
    masses = (0.0, RATED_PAYLOAD) if payload == MIXED else (float(payload), float(payload))
    task = dataclasses.replace(base.task, cycle="standard", timing=timing, payload_mass_range=masses)
    return dataclasses.replace(base, name=f"{base.name}/{timing}/{payload_label(payload)}", task=task)


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
)
"""Per-episode settle metrics of the in-position release, how a row aggregates each over its episodes, the type of
its cell and its header in the summary: the mean settle time (ms), the longest (ms) and the places that never
settled within the time-out (count)."""


def _settle_cell(value: float, kind: type) -> str:
    """A settle column's cell: n/a for a row that never waited in position (it follows the first's reference)."""
    if kind is float:
        return "n/a" if math.isnan(value) else f"{value:.1f}"
    return str(value)


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
        timing, (low, high) = unit.scenario.task.timing, unit.scenario.task.payload_mass_range
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


@command_main("python -m eval.rate")
def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    config = parse_args(argv)
    with command_run_folder(
        "rate", "eval.rate", argv, config, {"arguments": config.manifest()}, scenarios=[config.scenario]
    ) as run:
        rate(config, run, started)
    return 0


def rate(config: RateConfig, run: Run, started: float) -> None:
    """The data sheet of ``config`` (:func:`parse_args`) into ``run``'s folder, its summary printed; ``started`` is
    the :func:`time.perf_counter` time at the start of the command."""
    out = run.folder
    scenario = config.scenario
    # Every tared row is tared; the lead's estimator retimes the online carries (the cell's own if the lead has none).
    tared = [key for key in config.controllers if controller_entry(key).tared]
    if not controller_entry(config.controllers[0]).has_estimator:
        tared.append(CELL_ESTIMATOR_KEY)
    if config.quick:
        print(f"{QUICK_NOTE} Measuring {_study_line(config)}.", flush=True)
    with progress_bar(CALIBRATION_EPISODES * len(tared), "tare calibration", "episodes") as bar:
        prepared = prepare(
            rate_scenario(scenario, "declared", MIXED),
            tared,
            parameters=config.parameters,
            runs_dir=config.runs_dir,
            calibration_episodes=CALIBRATION_EPISODES,
            workers=config.workers,
            progress=bar,
            servo=config.servo,
            residual_policy=config.residual,
        )
    config = dataclasses.replace(config, parameters=prepared.parameter_file)
    setup, calibration = prepared.setup, prepared.calibration

    with progress_bar(row_episodes(config), "data sheet rows", "episodes") as bar:
        rows, episode_rows = run_rows(config, setup, bar)
    fastest = []
    if len(config.controllers) > 1 and config.fastest:
        label = controller_label(config.controllers[1])
        with progress_bar(fastest_episodes(config), f"fastest fixed timing of {label}", "episodes") as bar:
            fastest = fastest_fixed(config, setup, config.controllers[1], bar)
    write_csv(out / "rate.csv", rows)
    write_csv(out / "rate_episodes.csv", episode_rows)
    if fastest:
        write_csv(out / "pd_fastest.csv", fastest)
    save_rate_figure(out / "rate.png", rows, fastest, controller_label(config.controllers[0]), scenario.name)
    summary = "\n".join(_summary(config, rows, fastest, out, time.perf_counter() - started))
    (out / "summary.md").write_text(summary + "\n")
    run.record(
        config={
            "arguments": config.manifest(),
            "study": "quick" if config.quick else "full",
            "cycle_terms": cycle_terms(scenario.task),
            "published": {"source": ABB_IRB_360.source, "cycle": ABB_IRB_360.cycle},
            "identification": str(config.parameters),
            "tares_kg": calibration.tares,
            "calibration_seeds": calibration_seeds(CALIBRATION_EPISODES),
            "goals_mm": {"tracking_rms": TRACKING_GOAL_MM, "place_error": PLACE_GOAL_MM},
        }
    )
    print(summary)


def _pace_line(keys: Sequence[str]) -> str:
    """Who runs every row at its own pace and who follows the first's references (:func:`paced`), for the summary."""
    own, others = (list(map(controller_label, group)) for group in paced(keys))
    line = f"{' and '.join(own)} {'runs' if len(own) == 1 else 'each run'} every row at its own pace"
    if others:
        line += (
            f"; the other controllers follow {own[0]}'s references as given: they do not wait in position, and their "
            "place error is taken at its release"
        )
    return line


def _summary(
    config: RateConfig, rows: list[dict[str, Any]], fastest: list[dict[str, Any]], out: Path, seconds: float
) -> list[str]:
    """The summary's lines: the data sheet, the rows in full, the targets, and what the model buys."""
    loads = [payload_label(p) for p in config.payloads] + [MIXED]
    by_key = {(row["planner"], row["controller"], str(row["payload"])): row for row in rows}
    lead = controller_label(config.controllers[0])
    sheet = [
        [planner, label] + [f"{by_key[(planner, label, load)]['picks_per_min']:.1f}" for load in loads]
        for planner in config.planners
        for label in (controller_label(key) for key in config.controllers)
    ]
    settled = [(name, kind, header) for name, _, kind, header in SETTLE_COLUMNS if all(name in row for row in rows)]
    full = [
        [
            row["planner"],
            row["controller"],
            str(row["payload"]),
            f"{row['picks_per_min']:.1f}",
            f"{row['tracking_rms_mm']:.3f}",
            f"{row['path_deviation_rms_mm']:.3f}",
            f"{row['place_error_mm']:.3f}",
            *(_settle_cell(row[name], kind) for name, kind, _ in settled),
            str(row["envelope_violations"]),
            f"{row['peak_torque_ratio']:.2f}",
            f"{row['rms_torque_ratio']:.2f}",
            "yes" if holds(row) else "no",
        ]
        for row in rows
    ]
    lines = [
        f"# Pick rate, scenario {config.scenario.name}: 25/305/25 mm standard cycle, {_study_line(config)}",
        "",
        *([QUICK_NOTE, ""] if config.quick else []),
        f"Planned timings use {100 * config.scenario.task.torque_share:.0f} % of the drive's envelope (after the "
        f"planner's 10 % margin) and keep its thermal rating. {_cycle_line(config.scenario.task)}",
        "",
        f"{FEEDBACK_LINES[config.servo]} Picks per minute ({_pace_line(config.controllers)}).",
        "",
        metrics.markdown_table(
            ["planner", "controller", *[f"{load} kg" if load != MIXED else load for load in loads]], sheet
        ),
        "",
        "Every row: tracking RMS and path deviation RMS (mean, mm), place error at release (worst, mm), "
        + ("settle time in position (mean and longest, ms) and places that timed out, " if settled else "")
        + "envelope violations (steps), peak and RMS torque over the drive's peak and rated torque (largest); holds = "
        f"tracking <= {TRACKING_GOAL_MM} mm, place error <= {PLACE_GOAL_MM} mm, no violation, no overheating"
        + (", no settle time-out." if settled else "."),
        "",
        metrics.markdown_table(
            [
                "planner",
                "controller",
                "payload",
                "picks/min",
                "tracking",
                "path dev.",
                "place err.",
                *(header for _, _, header in settled),
                "violations",
                "peak/peak",
                "RMS/rated",
                "holds",
            ],
            full,
        ),
        "",
    ]
    lines += _published_lines(config, by_key, lead)
    lines += _targets(config, by_key, lead)
    if fastest:
        lines += _fastest_lines(fastest, by_key, lead)
    lines.append(f"Run folder: {out} ({seconds:.0f} s)")
    return lines


def _targets(config: RateConfig, by_key: dict[tuple[str, str, str], dict[str, Any]], lead: str) -> list[str]:
    """The mixed stream's online capture of the declared gain, and online against the fixed timing at the
    rated payload."""
    lines = []
    mixed = {planner: by_key.get((planner, lead, MIXED)) for planner in ("worst_case", "declared", "online")}
    if all(mixed.values()):
        worst, declared, online = (mixed[p]["picks_per_min"] for p in ("worst_case", "declared", "online"))
        captured = (online - worst) / (declared - worst) if declared != worst else math.nan
        lines += [
            f"Mixed stream, {lead}: online {online:.1f} picks/min = {100 * online / declared:.1f} % of declared "
            f"({declared:.1f}); declared gains {100 * (declared / worst - 1):.1f} % over worst-case ({worst:.1f}) "
            f"and online captures {100 * captured:.0f} % of that gain.",
            "",
        ]
    rated = payload_label(RATED_PAYLOAD)
    fixed, online_rated = by_key.get(("fixed", lead, rated)), by_key.get(("online", lead, rated))
    if fixed and online_rated:
        lines += [
            f"At the rated payload ({rated} kg), {lead}: online {online_rated['picks_per_min']:.1f} picks/min against "
            f"{fixed['picks_per_min']:.1f} at the fixed {config.scenario.task.peak_acceleration / GRAVITY:.0f} g "
            "timing "
            f"({100 * (online_rated['picks_per_min'] / fixed['picks_per_min'] - 1):+.0f} %).",
            "",
        ]
    return lines


def _fastest_lines(
    fastest: list[dict[str, Any]], by_key: dict[tuple[str, str, str], dict[str, Any]], lead: str
) -> list[str]:
    """The second controller's fastest fixed timing per payload, and the lead's online rate over it."""
    table = []
    slowest = f"none down to {FASTEST_SEARCH[0] / GRAVITY:g} g"
    for row in fastest:
        online = by_key.get(("online", lead, str(row["payload"])))
        found = math.isfinite(row["picks_per_min"])
        ratio = f"{online['picks_per_min'] / row['picks_per_min']:.2f}" if online and found else "-"
        table.append(
            [
                str(row["payload"]),
                f"{row['peak_acceleration_g']:.2f}" if found else slowest,
                f"{row['picks_per_min']:.1f}" if found else "-",
                f"{online['picks_per_min']:.1f}" if online else "-",
                ratio,
            ]
        )
    label = fastest[0]["controller"]
    return [
        f"Fastest fixed timing at which {label} holds the goals (bisection over the peak acceleration), and what "
        f"the model buys: {lead} online over it.",
        "",
        metrics.markdown_table(["payload", "peak acc. (g)", f"{label} picks/min", f"{lead} online", "ratio"], table),
        "",
    ]


def _study_line(config: RateConfig) -> str:
    """What a run measures: episodes, cycles, seeds and payloads."""
    return (
        f"{plural(config.episodes, 'episode')} x {plural(config.scenario.task.n_cycles, 'cycle')} per row from seed "
        f"{config.seed}, payloads "
        f"{_kilograms(config.payloads).replace(',', ', ')} kg and the mixed stream"
    )


def _cycle_line(task: PickPlaceTask) -> str:
    """How the scenario's cycle ends at pick and place (:func:`cycle_terms`)."""
    terms = cycle_terms(task)
    if not terms:
        return f"The gripper switches in the middle of a {1e3 * DEFAULT_DWELL:.0f} ms dwell at pick and place."
    return (
        f"Cycle ends: the gripper switches once the platform is within {1e3 * terms['in_position_window']:g} mm; "
        f"{1e3 * terms['air_activation']:.0f} ms of air activation at pick and place."
    )


def compared_planner(planners: Sequence[str]) -> str:
    """The planner whose rows stand beside the published ones (:data:`COMPARED_PLANNERS`)."""
    return next(planner for planner in COMPARED_PLANNERS if planner in planners)


def _published_lines(
    config: RateConfig,
    by_key: dict[tuple[str, str, str], dict[str, Any]],
    lead: str,
    sheet: PublishedSheet = ABB_IRB_360,
) -> list[str]:
    """The published rows of ``sheet`` beside the lead's at the same payloads, and what differs."""
    planner = compared_planner(config.planners)
    table = []
    for published in sheet.rows:
        ours = by_key.get((planner, lead, payload_label(published.payload)))
        if ours is not None:
            cells = [
                f"{ours['picks_per_min']:.1f}",
                f"{ours['picks_per_min'] / published.picks_per_min:.2f}",
                f"{ours['place_error_mm']:.2f}",
            ]
        else:
            missing = f"beyond our rated {RATED_PAYLOAD:g} kg" if published.payload > RATED_PAYLOAD else "not run"
            cells = [missing, "-", "-"]
        table.append([f"{published.payload:g}", published.robot, f"{published.picks_per_min:.0f}", *cells])
    plant: PlantConfig = config.scenario.plant
    drive, geometry = plant.drive, plant.geometry
    air = cycle_terms(config.scenario.task).get("air_activation")
    if air is None:
        ends = [
            f"our cycle dwells {1e3 * DEFAULT_DWELL:.0f} ms at pick and place, {sheet.maker}'s counts "
            f"{1e3 * sheet.air_activation:.0f} ms of air activation"
        ]
    elif not math.isclose(air, sheet.air_activation):
        ends = [f"our air activation is {1e3 * air:.0f} ms, {sheet.maker}'s {1e3 * sheet.air_activation:.0f} ms"]
    else:
        ends = []
    clauses = [*DIFFERENCES, *ends]
    return [
        f"Beside {sheet.maker}'s published rates ({sheet.source}, {sheet.cycle}: {1e3 * sheet.lift:g}/"
        f"{1e3 * sheet.travel:g}/{1e3 * sheet.lift:g} mm, {1e3 * sheet.air_activation:.0f} ms air activation at "
        f"each end, repeatability {1e3 * sheet.repeatability:g} mm), {lead} with {planner} timing (place error: "
        "worst at release, mm):",
        "",
        metrics.markdown_table(
            ["payload (kg)", "robot", "picks/min", f"{lead} {planner}", "ours / theirs", "place error"], table
        ),
        "",
        "What differs:",
        "",
        *(f"- {clause};" for clause in clauses[:-1]),
        f"- {clauses[-1]}.",
        "",
        f"Our robot: {drive.peak_torque:g} N m peak and {drive.rated_torque:g} N m rated torque at each joint, arms "
        f"{1e3 * geometry.l1:.0f}/{1e3 * geometry.l2:.0f} mm, base and platform radii {1e3 * geometry.ra:.0f}/"
        f"{1e3 * geometry.rb:.0f} mm, rated payload {RATED_PAYLOAD:g} kg.",
        "",
    ]


PLANNER_COLORS = {"fixed": "tab:blue", "worst_case": "tab:orange", "declared": "tab:green", "online": "tab:red"}
"""The colour of each planner's bars in ``rate.png``."""

FASTEST_COLOR = "tab:gray"
"""The colour of the second controller's fastest fixed timing in ``rate.png``."""

PUBLISHED_STYLES = (("tab:purple", "-"), ("tab:brown", "--"))
"""Colour and line style of each published robot's rates in ``rate.png``, in the order of
:attr:`PublishedSheet.robots`."""


def rate_figure(
    rows: Sequence[Mapping[str, Any]],
    fastest: Sequence[Mapping[str, Any]],
    lead: str,
    name: str,
    sheet: PublishedSheet = ABB_IRB_360,
) -> Any:
    """Picks/min per payload like a data sheet's chart, as a matplotlib figure: a group of bars per payload (and the
    mixed stream), one bar per planner with the lead controller (hatched where the row misses the goals) and one for
    the second controller's fastest fixed timing, and across each group a line at a published robot's rate.

    Bars side by side stay visible where planners give the same rate (every planned timing does with objects of
    one mass). The legend sits outside the axes and lists only what has data.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = [row for row in rows if row["controller"] == lead]
    found = [row for row in fastest if math.isfinite(row["picks_per_min"])]
    ours = {str(row["payload"]) for row in [*own, *found]}
    masses = {float(load) for load in ours if load != MIXED} | {published.payload for published in sheet.rows}
    loads = [payload_label(mass) for mass in sorted(masses)] + [MIXED]
    position = {load: n for n, load in enumerate(loads)}
    planners = list(dict.fromkeys(row["planner"] for row in own))
    series = [
        (f"{planner} timing", PLANNER_COLORS[planner], [row for row in own if row["planner"] == planner])
        for planner in planners
    ]
    if found:
        series.append((f"{found[0]['controller']}, fastest fixed timing", FASTEST_COLOR, found))
    width = 0.8 / max(len(series), 1)

    figure, axis = plt.subplots(figsize=(10.0, 4.8), layout="constrained")
    for n, (label, color, members) in enumerate(series):
        x = [position[str(row["payload"])] + (n - 0.5 * (len(series) - 1)) * width for row in members]
        bars = axis.bar(x, [row["picks_per_min"] for row in members], width, color=color, label=label)
        for bar, row in zip(bars, members, strict=True):
            if "tracking_rms_mm" in row and not holds(row):
                bar.set_hatch("//")
    for robot, (color, style) in zip(sheet.robots, PUBLISHED_STYLES, strict=False):
        published = [p for p in sheet.rows if p.robot == robot]
        centres = np.array([position[payload_label(p.payload)] for p in published], dtype=float)
        axis.hlines(
            [p.picks_per_min for p in published],
            centres - 0.45,
            centres + 0.45,
            colors=color,
            linestyles=style,
            linewidth=3.0,
            zorder=3,
            label=f"{sheet.maker} {robot} ({sheet.cycle})",
        )

    def tick(load: str) -> str:
        if load == MIXED:
            return f"U[0, {RATED_PAYLOAD:g}]"
        if float(load) > RATED_PAYLOAD:
            return f"{load}\n(beyond our rating)"
        return load + (" (rated)" if float(load) == RATED_PAYLOAD else "") + ("" if load in ours else "\n(not run)")

    axis.set_xticks(range(len(loads)), [tick(load) for load in loads])
    axis.set_xlabel("payload (kg); the last group: the mixed stream")
    axis.set_ylabel("picks per minute, 25/305/25 mm cycle")
    rates = [row["picks_per_min"] for row in [*own, *found]] + [p.picks_per_min for p in sheet.rows]
    axis.set_ylim(0.0, 1.12 * max(rates))
    axis.set_title(f"{lead} on {name}; hatched: misses the goals", fontsize="medium")
    axis.grid(True, axis="y", alpha=0.3)
    axis.set_axisbelow(True)
    figure.legend(loc="outside right upper", fontsize=8)
    return figure


def save_rate_figure(
    path: Path, rows: Sequence[Mapping[str, Any]], fastest: Sequence[Mapping[str, Any]], lead: str, name: str
) -> None:
    """:func:`rate_figure` saved to ``path`` (PNG, 120 dpi)."""
    import matplotlib.pyplot as plt

    figure = rate_figure(rows, fastest, lead, name)
    figure.savefig(path, dpi=120)
    plt.close(figure)


if __name__ == "__main__":
    sys.exit(main())
