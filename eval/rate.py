"""``python -m eval.rate``: the pick-rate data sheet (docs/design.md section 9).

Picks per minute on the industry's 25/305/25 mm standard cycle, like a Delta picker's data sheet, at payloads
0.1, 1, 2 and 4 kg (the rated payload) and on a mixed stream of objects drawn from U[0, 4] kg, for each way of
timing the moves (``--planners``):

- ``fixed``: today's timing, every move at the scenario's peak acceleration (3 g);
- ``worst_case``: time-optimal within the drive, every carry for the heaviest object of the stream;
- ``declared``: time-optimal, each carry for its object's true mass (the reference, not a controller);
- ``online``: time-optimal, a carry starts for the heaviest object and is retimed once the payload estimate
  has settled (:mod:`controllers.payload_timing`).

The first controller of ``--controllers`` (by default the model-based MId+F+R+RLS+lag+PD) runs every row; the
others run the same references (its episodes' reference, replayed with the same objects), so that they are
scored at the same timings. For each payload it also finds the fastest fixed timing at which the second
controller (PD by default) meets the tracking and place goals (:data:`TRACKING_GOAL_MM`, :data:`PLACE_GOAL_MM`):
the ratio of the two pick rates is what the model buys.

Writes ``rate.csv`` (one row per planner, controller and payload: ``payload`` in kg or ``mixed``),
``rate_episodes.csv``, ``pd_fastest.csv``, ``rate.png`` and ``summary.md`` (also printed) into the run folder
(``--out``, else ``<runs root>/rate/<UTC time>``), with its manifest ``config.json`` (:mod:`eval.run_folder`).

Usage: python -m eval.rate [--scenario S] [--geometry FILE] [--seed 0] [--episodes 3] [--cycles 4] [--out DIR]
                           [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import controller_entry, controller_label, controllers_help, parse_controller_keys
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import GRAVITY
from delta_env.scenario import TIMINGS, Scenario
from delta_env.timing import DEFAULT_TORQUE_SHARE
from eval import metrics
from eval.calibration import calibration_seeds
from eval.console import command_main
from eval.engine import grid, prepare, run_grid
from eval.episodes import EpisodeRecord
from eval.run_folder import Run, add_force_argument, add_runs_dir_argument, command_line, run_folder, write_csv
from eval.scenario_args import (
    add_parameters_argument,
    add_scenario_arguments,
    add_workers_argument,
    check_episode_seeds,
    check_ranges,
    scenario_from_arguments,
)
from eval.sweep.work import WorkUnit
from eval.tasks import CELL_ESTIMATOR_KEY

RATE_PAYLOADS = (0.1, 1.0, 2.0, RATED_PAYLOAD)
"""Payloads (kg) of the data sheet; the last is the robot's rated payload."""

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


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m eval.rate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--episodes", type=int, default=3, help="episodes per row (default 3)")
    parser.add_argument("--cycles", type=int, default=4, help="pick-and-place cycles per episode (default 4)")
    parser.add_argument(
        "--planners",
        default=",".join(TIMINGS),
        help=f"comma-separated timings from {', '.join(TIMINGS)} (default: all)",
    )
    parser.add_argument(
        "--controllers",
        default=",".join(DEFAULT_CONTROLLERS),
        help="the first runs every row, the others replay its references; "
        + controllers_help(",".join(DEFAULT_CONTROLLERS)),
    )
    parser.add_argument(
        "--payloads",
        default=",".join(f"{p:g}" for p in RATE_PAYLOADS),
        help=f"comma-separated payloads (kg) in (0, {RATED_PAYLOAD:g}] besides the mixed stream "
        f"(default {','.join(f'{p:g}' for p in RATE_PAYLOADS)})",
    )
    parser.add_argument(
        "--torque-share",
        type=float,
        default=None,
        help="share of the drive's envelope the planned timings may use, in (0, 1] (default: the scenario's, "
        f"{DEFAULT_TORQUE_SHARE:g} unless it sets one)",
    )
    parser.add_argument(
        "--no-fastest", action="store_true", help="skip the search of the second controller's fastest fixed timing"
    )
    parser.add_argument("--out", type=Path, default=None, help="run folder (default <runs root>/rate/<UTC time>)")
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    add_parameters_argument(parser)
    add_workers_argument(parser)
    args = parser.parse_args(argv)
    check_ranges(parser, args, {"seed": 0, "episodes": 1, "cycles": 1, "workers": 1})
    check_episode_seeds(parser, args)
    args.scenario = scenario_from_arguments(args, parser)
    cycles = dataclasses.replace(args.scenario.task, n_cycles=args.cycles)  # one home: the scenario every row derives
    args.scenario = dataclasses.replace(args.scenario, task=cycles)
    if args.torque_share is not None:
        try:
            task = dataclasses.replace(args.scenario.task, torque_share=args.torque_share)
        except ValueError as error:
            parser.error(f"--torque-share: {error}")
        args.scenario = dataclasses.replace(args.scenario, task=task)
    args.planners = _listed(parser, "--planners", args.planners, TIMINGS)
    try:
        args.controllers = parse_controller_keys(args.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    privileged = [key for key in args.controllers if controller_entry(key).privileged]
    if privileged:
        parser.error(f"--controllers: {', '.join(privileged)}: a bound that knows the plant, without a pick rate")
    try:
        payloads = [float(value) for value in args.payloads.split(",") if value.strip()]
    except ValueError:
        parser.error(f"--payloads must be numbers (kg), got {args.payloads!r}")
    if not payloads or not all(0.0 < p <= RATED_PAYLOAD for p in payloads):
        parser.error(f"--payloads must lie in (0, {RATED_PAYLOAD:g}] kg, got {args.payloads!r}")
    args.payloads = payloads
    return args


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


def summarize(records: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """One row of ``rate.csv`` from a row's episodes: means over them, except the worst place error (mm), the
    summed violations and divergences, the largest torque ratios and whether the thermal limit was ever exceeded."""
    rows = [record.metrics() for record in records]

    def column(name: str) -> np.ndarray:
        return np.array([row[name] for row in rows], dtype=float)

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
        "episodes": len(rows),
    }


def holds(row: dict[str, Any]) -> bool:
    """Whether a row holds its timing: the tracking and place goals, no violation, no divergence, no overheating."""
    return (
        row["tracking_rms_mm"] <= TRACKING_GOAL_MM
        and row["place_error_mm"] <= PLACE_GOAL_MM
        and row["envelope_violations"] == 0
        and row["diverged"] == 0
        and not row["thermal_exceeded"]
    )


def run_rows(args: argparse.Namespace, setup: Any) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Every planner x payload row of the first controller, then the others on the same references."""
    lead, others = args.controllers[0], args.controllers[1:]
    loads = [*args.payloads, MIXED]
    scenarios = [rate_scenario(args.scenario, timing, load) for timing in args.planners for load in loads]
    setups = {scenario.content_hash: setup for scenario in scenarios}
    units = grid(scenarios, [lead], range(args.seed, args.seed + args.episodes))
    records = run_grid(units, setups, workers=args.workers)
    replays = [
        WorkUnit(unit.scenario, key, unit.seed, tuple(record.masses.tolist()), record.reference)
        for key in others
        for unit, record in zip(units, records, strict=True)
    ]
    records += run_grid(replays, setups, workers=args.workers)
    grouped: dict[tuple[str, str, str], list[EpisodeRecord]] = {}
    episode_rows = []
    for unit, record in zip([*units, *replays], records, strict=True):
        timing, (low, high) = unit.scenario.task.timing, unit.scenario.task.payload_mass_range
        load = payload_label(low) if low == high else MIXED
        grouped.setdefault((timing, controller_label(unit.controller), load), []).append(record)
        episode_rows.append(
            {"planner": timing, "controller": controller_label(unit.controller), "payload": load, "seed": unit.seed}
            | record.metrics()
        )
    rows = [
        {"planner": timing, "controller": label, "payload": load} | summarize(records)
        for (timing, label, load), records in grouped.items()
    ]
    return rows, episode_rows


def fastest_fixed(args: argparse.Namespace, setup: Any, key: str) -> list[dict[str, Any]]:
    """For each payload, the fastest fixed timing (peak acceleration) at which ``key`` holds the goals."""
    low, high, steps = FASTEST_SEARCH
    rows = []
    for load in [*args.payloads, MIXED]:
        best = None
        lower, upper = math.log(low), math.log(high)
        for _ in range(steps):
            acceleration = math.exp(0.5 * (lower + upper))
            base = dataclasses.replace(
                args.scenario, task=dataclasses.replace(args.scenario.task, peak_acceleration=acceleration)
            )
            scenario = rate_scenario(base, "fixed", load)
            units = grid([scenario], [key], range(args.seed, args.seed + args.episodes))
            row = summarize(run_grid(units, {scenario.content_hash: setup}, workers=args.workers))
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
    args = parse_args(argv)
    with run_folder(
        "rate",
        command_line("eval.rate", argv),
        {"arguments": {**vars(args), "scenario": args.scenario.name}},
        out=args.out,
        runs_dir=args.runs_dir,
        scenarios=[args.scenario],
        reuse=args.force,
    ) as run:
        rate(args, run, started)
    return 0


def rate(args: argparse.Namespace, run: Run, started: float) -> None:
    """The data sheet of ``args`` (:func:`parse_args`) into ``run``'s folder, its summary printed; ``started`` is the
    :func:`time.perf_counter` time at the start of the command."""
    out = run.folder
    scenario = args.scenario
    # Every tared row is tared; the lead's estimator retimes the online carries (the cell's own if the lead has none).
    tared = [key for key in args.controllers if controller_entry(key).tared]
    if not controller_entry(args.controllers[0]).tared:
        tared.append(CELL_ESTIMATOR_KEY)
    prepared = prepare(
        rate_scenario(scenario, "declared", MIXED),
        tared,
        parameters=args.parameters,
        runs_dir=args.runs_dir,
        calibration_episodes=CALIBRATION_EPISODES,
        workers=args.workers,
    )
    args.parameters, setup, calibration = prepared.parameter_file, prepared.setup, prepared.calibration

    rows, episode_rows = run_rows(args, setup)
    fastest = []
    if len(args.controllers) > 1 and not args.no_fastest:
        fastest = fastest_fixed(args, setup, args.controllers[1])
    write_csv(out / "rate.csv", rows)
    write_csv(out / "rate_episodes.csv", episode_rows)
    if fastest:
        write_csv(out / "pd_fastest.csv", fastest)
    _plot(out / "rate.png", rows, fastest, controller_label(args.controllers[0]), scenario.name)
    summary = "\n".join(_summary(args, rows, fastest, out, time.perf_counter() - started))
    (out / "summary.md").write_text(summary + "\n")
    run.record(
        config={
            "arguments": {**vars(args), "scenario": scenario.name},
            "identification": str(args.parameters),
            "tares_kg": calibration.tares,
            "calibration_seeds": calibration_seeds(CALIBRATION_EPISODES),
            "goals_mm": {"tracking_rms": TRACKING_GOAL_MM, "place_error": PLACE_GOAL_MM},
        }
    )
    print(summary)


def _summary(
    args: argparse.Namespace, rows: list[dict[str, Any]], fastest: list[dict[str, Any]], out: Path, seconds: float
) -> list[str]:
    """The summary's lines: the data sheet, the rows in full, the targets, and what the model buys."""
    loads = [payload_label(p) for p in args.payloads] + [MIXED]
    by_key = {(row["planner"], row["controller"], str(row["payload"])): row for row in rows}
    lead = controller_label(args.controllers[0])
    sheet = [
        [planner, label] + [f"{by_key[(planner, label, load)]['picks_per_min']:.1f}" for load in loads]
        for planner in args.planners
        for label in (controller_label(key) for key in args.controllers)
    ]
    full = [
        [
            row["planner"],
            row["controller"],
            str(row["payload"]),
            f"{row['picks_per_min']:.1f}",
            f"{row['tracking_rms_mm']:.3f}",
            f"{row['path_deviation_rms_mm']:.3f}",
            f"{row['place_error_mm']:.3f}",
            str(row["envelope_violations"]),
            f"{row['peak_torque_ratio']:.2f}",
            f"{row['rms_torque_ratio']:.2f}",
            "yes" if holds(row) else "no",
        ]
        for row in rows
    ]
    lines = [
        f"# Pick rate, scenario {args.scenario.name}: 25/305/25 mm standard cycle, {args.episodes} episodes x "
        f"{args.scenario.task.n_cycles} cycles per row from seed {args.seed}",
        "",
        f"Planned timings use {100 * args.scenario.task.torque_share:.0f} % of the drive's envelope (after the "
        "planner's 10 % margin) and keep its thermal rating.",
        "",
        f"Picks per minute ({lead} runs every row; the other controllers follow its references).",
        "",
        metrics.markdown_table(
            ["planner", "controller", *[f"{load} kg" if load != MIXED else load for load in loads]], sheet
        ),
        "",
        f"Every row: tracking RMS and path deviation RMS (mean, mm), place error at release (worst, mm), envelope "
        f"violations (steps), peak and RMS torque over the drive's peak and rated torque (largest); holds = tracking "
        f"<= {TRACKING_GOAL_MM} mm, place error <= {PLACE_GOAL_MM} mm, no violation, no overheating.",
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
                "violations",
                "peak/peak",
                "RMS/rated",
                "holds",
            ],
            full,
        ),
        "",
    ]
    lines += _targets(args, by_key, lead)
    if fastest:
        lines += _fastest_lines(fastest, by_key, lead)
    lines.append(f"Run folder: {out} ({seconds:.0f} s)")
    return lines


def _targets(args: argparse.Namespace, by_key: dict[tuple[str, str, str], dict[str, Any]], lead: str) -> list[str]:
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
            f"{fixed['picks_per_min']:.1f} at the fixed {args.scenario.task.peak_acceleration / GRAVITY:.0f} g timing "
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


def _plot(path: Path, rows: list[dict[str, Any]], fastest: list[dict[str, Any]], lead: str, name: str) -> None:
    """Picks/min against payload for each planner with the lead controller, like a data sheet's chart: a line over
    the fixed payloads (dotted where a row misses the goals) and a cross for the mixed stream at its mean mass."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7.0, 4.5))
    for planner in dict.fromkeys(row["planner"] for row in rows):
        own = [row for row in rows if row["planner"] == planner and row["controller"] == lead]
        points = sorted((float(row["payload"]), row["picks_per_min"]) for row in own if row["payload"] != MIXED)
        style = "-" if all(holds(row) for row in own) else ":"
        (line,) = axis.plot(*zip(*points, strict=True), style, marker="o", label=planner) if points else (None,)
        for row in own:
            if row["payload"] == MIXED:
                color = line.get_color() if line is not None else None
                axis.plot(0.5 * RATED_PAYLOAD, row["picks_per_min"], "x", color=color, markersize=9)
    found = sorted((float(r["payload"]), r["picks_per_min"]) for r in fastest if r["payload"] != MIXED)
    found = [point for point in found if math.isfinite(point[1])]
    if found:
        axis.plot(*zip(*found, strict=True), "k--", marker="s", label=f"{fastest[0]['controller']}, fastest fixed")
    axis.set_ylim(bottom=0.0)
    axis.set_xlabel(f"payload (kg); x: mixed stream U[0, {RATED_PAYLOAD:g}] kg at its mean")
    axis.set_ylabel("picks per minute, 25/305/25 mm cycle")
    axis.set_title(f"{lead} on {name}; dotted: goals not held")
    axis.grid(True, alpha=0.3)
    axis.legend(title="timing, planned on MId+F+R", title_fontsize=8, fontsize=8, loc="lower left")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


if __name__ == "__main__":
    sys.exit(main())
