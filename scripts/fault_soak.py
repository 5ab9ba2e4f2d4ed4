"""Fault-free soak: how often each controller's fault monitor raises a false alarm on hard, healthy work.

Runs fault-free episodes ``seed, seed + 1, ...`` of fast, hard conditions until each controller has run
``--minutes`` simulated minutes: the ``randomized`` preset's plants (masses +-10 %, friction +-30 %, current-loop
lag 0.5-2 ms, drawn per episode) on conveyor cycles at 6 g peak acceleration with objects drawn from U[0, 6] kg
(1.5 x the rated payload). No fault is injected, so every detection is a false alarm (:mod:`eval.faults` counts
them; an episode that carried an injected fault all the same is counted apart and reported). The controllers
are built as ``python -m eval`` builds them: the nominal robot's identification (``<runs root>/identification``,
identified once when missing, about a minute) and the tares of the payload estimators measured on payload-free
episodes of the same conditions on the comparison's calibration seeds (:mod:`eval.calibration`).

Writes into the folder ``--out`` (default ``<runs root>/fault_soak/<UTC time>``; :mod:`eval.run_folder`):

- ``episodes.csv``: one row per episode (:data:`EPISODE_COLUMNS`), appended as each finishes;
- ``faults.csv``: every detection, as rows of :data:`eval.faults.FAULT_COLUMNS` (false alarms here);
- ``config.json``: the manifest (the command, the conditions, status, times); ``summary.md``: the table, also
  printed.

An interrupted run loses nothing already written: rerun the same command with the same ``--out`` and it resumes,
running only the episodes it lacks (a larger ``--minutes`` extends a finished soak).

Usage: python scripts/fault_soak.py [--minutes 30] [--controllers mid_f_rls] [--seed 0] [--out DIR] [--workers 2]
                                    [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controllers.registry import controller_label, controllers_help, parse_controller_keys
from delta_env.geometry import GRAVITY
from delta_env.scenario import Scenario, preset
from delta_env.sensors import CONTROL_PERIOD
from delta_env.validation import require_count
from eval import metrics
from eval.console import CommandParser, UsageError, command_main, progress_bar
from eval.engine import prepare, run_grid
from eval.episodes import EpisodeRecord
from eval.faults import FAULT_COLUMNS, fault_rows
from eval.run_folder import Run, add_runs_dir_argument, append_csv_rows, command_line, read_csv_rows, run_folder
from eval.scenario_args import add_workers_argument, check_ranges
from eval.sweep.work import WorkUnit

SOAK_PEAK_ACCELERATION = 6.0 * GRAVITY
"""Peak Cartesian acceleration of the soak's cycles (m/s^2): twice the default's."""

SOAK_PAYLOAD_RANGE = (0.0, 6.0)
"""Object masses of the soak (kg), drawn per pick: up to 1.5 x the rated payload."""

EPISODE_COLUMNS = (
    "controller",
    "key",
    "episode",
    "seed",
    "simulated_s",
    "carries",
    "carries_over",
    "diverged",
    "faults_injected",
    "detections",
    "false_alarms",
    "tracking_rms_mm",
    "torque_peak_nm",
)
"""Columns of ``episodes.csv``: the episode, its simulated time (s) and completed carries, whether it diverged,
faults injected (0 in a fault-free soak), detections, false alarms, and two figures of how hard it ran."""


def soak_scenario(base: Scenario | None = None) -> Scenario:
    """The soak's conditions: the ``randomized`` preset (or ``base``) at :data:`SOAK_PEAK_ACCELERATION` with
    objects from :data:`SOAK_PAYLOAD_RANGE`."""
    base = preset("randomized") if base is None else base
    task = dataclasses.replace(
        base.task, peak_acceleration=SOAK_PEAK_ACCELERATION, payload_mass_range=SOAK_PAYLOAD_RANGE
    )
    return dataclasses.replace(
        base,
        name="fault-soak",
        description="randomized plants, conveyor cycles at 6 g, objects U[0, 6] kg, no fault injected",
        task=task,
    )


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = CommandParser(
        prog="scripts/fault_soak.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--minutes", type=float, default=30.0, help="simulated minutes per controller (default 30)")
    parser.add_argument(
        "--controllers",
        default="mid_f_rls",
        help=controllers_help("mid_f_rls"),
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default <runs root>/fault_soak/<UTC time>)"
    )
    add_runs_dir_argument(parser)
    add_workers_argument(parser)
    args = parser.parse_args(argv)
    check_ranges(parser, args, {"seed": 0, "workers": 1}, ("minutes",))
    try:
        args.controllers = parse_controller_keys(args.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    return args


def episode_row(unit: WorkUnit, record: EpisodeRecord, first_seed: int) -> dict[str, Any]:
    """The row of ``episodes.csv`` of one finished episode of a soak from seed ``first_seed``."""
    scores = record.metrics()
    carries = record.carries()
    return {
        "controller": controller_label(unit.controller),
        "key": unit.controller,
        "episode": unit.seed - first_seed,
        "seed": unit.seed,
        "simulated_s": scores["steps"] * CONTROL_PERIOD,
        "carries": len(carries),
        "carries_over": metrics.payload_targets(carries).overshoots[0],
        "diverged": record.diverged,
        "faults_injected": scores["faults_injected"],
        "detections": scores["detections"],
        "false_alarms": scores["false_alarms"],
        "tracking_rms_mm": scores["tracking_rms_mm"],
        "torque_peak_nm": scores["torque_peak_nm"],
    }


GRID_EPISODES_PER_WORKER = 16
"""Episodes per worker in one grid of the soak: one process pool runs them, and their records (about 350 bytes per
simulated millisecond) stay in memory until the grid ends."""


def episodes_to_go(rows: Sequence[dict[str, Any]], key: str, remaining_s: float, first_batch: int) -> int:
    """Episodes of ``key`` to run for ``remaining_s`` more simulated seconds (s): by the mean simulated time of its
    episodes in ``rows`` (at least one control period), or ``first_batch`` before it has any."""
    lengths = [float(row["simulated_s"]) for row in rows if row["key"] == key]
    if not lengths:
        return first_batch
    return max(1, math.ceil(remaining_s / max(statistics.fmean(lengths), CONTROL_PERIOD)))


def next_units(
    scenario: Scenario, wanted: dict[str, int], first_seed: int, finished: set[tuple[str, int]], start: int, limit: int
) -> tuple[list[WorkUnit], int]:
    """The next episodes: ``wanted[key]`` of each controller, on the seeds from ``first_seed + start`` on, skipping
    those ``finished`` already (so a resumed soak fills its gaps first), seed by seed until there are ``limit`` or
    more (a seed is never split); and the seed index after the last seed used."""
    require_count("limit", limit)
    units: list[WorkUnit] = []
    to_go = {key: count for key, count in wanted.items() if count > 0}
    index = start
    while to_go and len(units) < limit:
        seed = first_seed + index
        for key in [key for key in to_go if (key, seed) not in finished]:
            units.append(WorkUnit(scenario, key, seed))
            to_go[key] -= 1
            if to_go[key] == 0:
                del to_go[key]
        index += 1
    return units, index


def resume(out: Path, config: dict[str, Any]) -> list[dict[str, str]]:
    """The episodes already in the folder ``out`` (none if new); ``faults.csv`` trimmed to them. Refuses a folder of a
    soak under other conditions (another seed, scenario or code of the conditions), before its manifest is
    rewritten."""
    if not out.is_dir():
        return []
    config_path = out / "config.json"
    if config_path.exists():
        written = json.loads(config_path.read_text())["config"]
        for name in ("seed", "scenario_hash"):
            if written.get(name) != config[name]:
                raise UsageError(
                    f"--out {out} holds a soak with {name} {written.get(name)!r}, not {config[name]!r}: use another "
                    "--out"
                )
    done = read_csv_rows(out / "episodes.csv")
    finished = {(row["key"], row["seed"]) for row in done}
    faults_path = out / "faults.csv"
    kept = [row for row in read_csv_rows(faults_path) if (row["key"], row["seed"]) in finished]
    faults_path.unlink(missing_ok=True)
    append_csv_rows(faults_path, FAULT_COLUMNS, kept)  # fault rows of an episode whose row was never written go
    return done


def summary_table(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> str:
    """Per controller: simulated minutes, episodes (diverged), carries and those whose estimate overshot the lift-off
    bound (:data:`eval.metrics.OVERSHOOT_BOUND`), false alarms and their rate per hour."""
    bound_kg, bound_fraction = metrics.OVERSHOOT_BOUND
    over = f"Carries over max({bound_kg} kg, {100 * bound_fraction:.0f} %)"
    header = ["Controller", "Simulated minutes", "Episodes (diverged)", "Carries", over, "False alarms"]
    header.append("False alarms / h")
    by_key = metrics.group_by(rows, "key")
    body = []
    for key in keys:
        group = [row for row in by_key.get(key, []) if int(row["faults_injected"]) == 0]
        seconds = sum(float(row["simulated_s"]) for row in group)
        alarms = sum(int(row["false_alarms"]) for row in group)
        diverged = sum(str(row["diverged"]) == "True" for row in group)
        rate = f"{3600.0 * alarms / seconds:.2f}" if seconds > 0 else "n/a"
        carries = sum(int(row["carries"]) for row in group)
        overshoots = sum(int(row["carries_over"]) for row in group)
        body.append(
            [
                controller_label(key),
                f"{seconds / 60:.1f}",
                f"{len(group)} ({diverged})",
                str(carries),
                str(overshoots),
                str(alarms),
                rate,
            ]
        )
    return metrics.markdown_table(header, body)


@command_main("python scripts/fault_soak.py")
def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    scenario = soak_scenario()
    config = {
        "seed": args.seed,
        "scenario_hash": scenario.content_hash,
        "scenario": scenario.name,
        "description": scenario.description,
        "peak_acceleration_m_s2": SOAK_PEAK_ACCELERATION,
        "payload_mass_range_kg": list(SOAK_PAYLOAD_RANGE),
        "minutes": args.minutes,
        "controllers": args.controllers,
        "workers": args.workers,
    }
    rows = resume(args.out, config) if args.out is not None else []
    command = command_line("scripts/fault_soak.py", argv)
    with run_folder(
        "fault_soak", command, config, out=args.out, runs_dir=args.runs_dir, scenarios=[scenario], reuse=True
    ) as run:
        soak(args, run, scenario, rows)
    return 0


def soak(args: argparse.Namespace, run: Run, scenario: Scenario, rows: list[dict[str, Any]]) -> None:
    """Run the soak of ``args`` (:func:`parse_args`) on ``scenario`` into ``run``'s folder, after the episodes
    ``rows`` already there; its table printed."""
    out, keys = run.folder, args.controllers
    setup = prepare(scenario, keys, runs_dir=args.runs_dir, workers=args.workers).setup

    target = 60.0 * args.minutes
    finished = {(row["key"], int(row["seed"])) for row in rows}
    simulated = {key: sum(float(row["simulated_s"]) for row in rows if row["key"] == key) for key in keys}
    first_batch, grid_limit = 4 * args.workers, GRID_EPISODES_PER_WORKER * args.workers
    index = 0
    with progress_bar(len(keys) * target, "simulated s", "s") as progress:

        def show_progress() -> None:  # set, not added up: sums of float steps overshoot the total in the last bit
            progress.n = sum(min(seconds, target) for seconds in simulated.values())
            progress.refresh()

        show_progress()

        def record_episode(unit: WorkUnit, record: EpisodeRecord) -> None:  # as each episode finishes
            row = episode_row(unit, record, args.seed)
            identity = {name: row[name] for name in ("controller", "key", "episode", "seed")}
            append_csv_rows(out / "faults.csv", FAULT_COLUMNS, fault_rows(identity, record.faults()))
            append_csv_rows(out / "episodes.csv", EPISODE_COLUMNS, [row])
            rows.append(row)
            simulated[unit.controller] += row["simulated_s"]
            show_progress()

        # A first batch shows how long each controller's episodes run; then grids of as many episodes as that says are
        # missing, each of at most GRID_EPISODES_PER_WORKER per worker on one process pool, planned again after each.
        while any(simulated[key] < target for key in keys):
            wanted = {
                key: episodes_to_go(rows, key, target - simulated[key], first_batch)
                for key in keys
                if simulated[key] < target
            }
            units, index = next_units(scenario, wanted, args.seed, finished, index, grid_limit)
            run_grid(units, {scenario.content_hash: setup}, workers=args.workers, on_result=record_episode)

    faulted = sum(int(row["faults_injected"]) > 0 for row in rows)
    lines = [
        f"# Fault-free soak: {scenario.description}, from seed {args.seed}",
        "",
        "Every detection in a fault-free episode is a false alarm.",
        "",
        summary_table(rows, keys),
        "",
        *(
            [f"{faulted} episode(s) carried an injected fault: left out of the table (see episodes.csv).", ""]
            if faulted
            else []
        ),
        f"Run folder: {out}",
    ]
    summary = "\n".join(lines)
    (out / "summary.md").write_text(summary + "\n")
    print(summary)


if __name__ == "__main__":
    sys.exit(main())
