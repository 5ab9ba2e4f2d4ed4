"""Fault campaign: each kind of fault injected once per episode, its detection and what it did to the estimate.

For every fault kind, runs ``--episodes`` episodes of ``--scenario`` (a preset or file; its own faults are replaced)
with one fault of that kind at a random point of a random carry (the ``FaultSpec`` default ranges), and the same
episodes without it (the fault-free twins: the same seed, path, objects and noise). Reports per kind, for each of
``--controllers`` (rows of the registry, ``mid_f_rls`` by default):

- detected / scored (latent drive faults, which changed nothing, are counted apart), median and worst latency
  (ms), consequences and false alarms (:mod:`eval.fault_scores`), and the confusion matrix, injected kind by detected
  kind;
- for sensor faults (``encoder_glitch``, ``encoder_stuck``, ``sensor_nan``, ``torque_glitch``) and collisions: the
  largest change of the payload estimate against the twin from the fault to the end of its carry, and the change
  left at the place, as shares of the object's mass (a push must not move the estimate: the object is still held);
- for slips: the time from the slip until the estimate reads below 0.1 kg (the object is gone);
- for each of ``--reactions`` (default: the scenario's ``fault_reaction``), what the cell's reaction to the fault
  cost: the pick rate of the faulty episode against its twin's (picks/min lost, :func:`reaction_cost`) and the
  episodes a stop ended. The detection tables are those of the first reaction listed.

Writes ``faults.csv`` (:data:`eval.fault_tables.FAULT_COLUMNS`; the twins' detections too, false alarms),
``confusion.csv`` (:data:`eval.fault_tables.CONFUSION_COLUMNS`), ``campaign.csv`` (one row per faulty episode) and
``summary.md`` into ``--out`` (default ``<runs root>/fault_campaign/<UTC time>``, with the manifest ``config.json`` of
:mod:`eval.run_folder`), and prints the tables. The controllers are tared on fault-free payload-free episodes, as
``python -m eval`` tares them.

Usage: python -m eval.faults [--scenario nominal] [--geometry FILE] [--episodes 20] [--kinds all] [--seed 0]
                                        [--controllers mid_f_rls] [--reactions continue,slow,stop] [--out DIR]
                                        [--workers 2] [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.monitor.tuning import TORQUE_MARGIN
from controllers.registry import controller_label, controllers_help, parse_controller_keys
from delta_env.faults import FAULT_KINDS, FAULT_REACTIONS, SENSOR_KINDS, FaultSpec
from delta_env.scenario import Scenario
from delta_env.sensors import CONTROL_PERIOD
from eval import metrics
from eval.console import CommandParser, command_main, plural, progress_bar
from eval.engine import prepare
from eval.episodes import EpisodeRecord
from eval.fault_tables import (
    confusion_counts,
    confusion_table,
    fault_rows,
    fault_summary,
    write_confusion_csv,
    write_fault_csv,
)
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    command_run_folder,
    configuration_record,
    write_csv,
)
from eval.scenario_args import (
    add_scenario_arguments,
    add_workers_argument,
    check_episode_seeds,
    check_ranges,
    scenario_from_arguments,
)
from eval.work import WorkUnit, run_grid

GONE_MASS = 0.1
"""Estimate (kg) below which a slipped object counts as forgotten."""


@dataclass(frozen=True)
class CampaignConfig:
    """The resolved configuration of a campaign (:func:`parse_args`), as ``config.json`` records it.

    Attributes:
        scenario: The robot and the work (its own faults are replaced).
        seed: Seed of the first episode.
        episodes: Episodes per fault kind.
        kinds: The fault kinds injected.
        controllers: Registry keys of the rows.
        reactions: The cell's reactions to a detected fault, each run on every faulty episode; the first gives the
            detection tables.
        out: Run folder; None: ``<runs root>/fault_campaign/<UTC time>``.
        force: Write into a non-empty ``out``.
        runs_dir: Root of the run folders and of the cached identifications; None: the default.
        workers: Processes running the episodes.
    """

    scenario: Scenario
    seed: int
    episodes: int
    kinds: tuple[str, ...]
    controllers: tuple[str, ...]
    reactions: tuple[str, ...]
    out: Path | None
    force: bool
    runs_dir: Path | None
    workers: int


def argument_parser() -> CommandParser:
    """The command line's parser."""
    parser = CommandParser(prog="python -m eval.faults", description=__doc__.split("\n\n")[0])
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per fault kind (default 20)")
    kinds = ", ".join(FAULT_KINDS)
    parser.add_argument("--kinds", default="all", help=f"comma-separated fault kinds or 'all' ({kinds})")
    parser.add_argument("--controllers", default="mid_f_rls", help=controllers_help("mid_f_rls"))
    parser.add_argument(
        "--reactions",
        default=None,
        help=f"comma-separated reactions of the cell to a detected fault ({', '.join(FAULT_REACTIONS)}), each run on "
        "every faulty episode (default: the scenario's fault_reaction)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="run folder (default <runs root>/fault_campaign/<UTC time>)"
    )
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    add_workers_argument(parser)
    return parser


def resolve(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> CampaignConfig:
    """The campaign's configuration from the parsed ``arguments`` (left as parsed); a bad value is ``parser``'s
    error."""
    check_ranges(parser, arguments, {"episodes": 1, "seed": 0, "workers": 1})
    check_episode_seeds(parser, arguments)
    kinds = list(FAULT_KINDS) if arguments.kinds == "all" else arguments.kinds.split(",")
    unknown = sorted(set(kinds) - set(FAULT_KINDS))
    if unknown:
        parser.error(f"--kinds: unknown {unknown}; choose from {list(FAULT_KINDS)} or 'all'")
    try:
        controllers = parse_controller_keys(arguments.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    scenario = scenario_from_arguments(arguments, parser)
    reactions = arguments.reactions.split(",") if arguments.reactions else [scenario.task.fault_reaction]
    unknown = sorted(set(reactions) - set(FAULT_REACTIONS))
    if unknown or len(set(reactions)) < len(reactions):
        parser.error(f"--reactions: unknown or repeated {unknown or reactions}; choose from {list(FAULT_REACTIONS)}")
    return CampaignConfig(
        scenario=scenario,
        seed=arguments.seed,
        episodes=arguments.episodes,
        kinds=tuple(kinds),
        controllers=tuple(controllers),
        reactions=tuple(reactions),
        out=arguments.out,
        force=arguments.force,
        runs_dir=arguments.runs_dir,
        workers=arguments.workers,
    )


def parse_args(argv: Sequence[str] | None) -> CampaignConfig:
    """The campaign's configuration from the command line ``argv``."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def with_faults(scenario: Scenario, faults: tuple[FaultSpec, ...], reaction: str | None = None) -> Scenario:
    """``scenario`` with these faults instead of its own, and ``reaction`` as its fault reaction (None: its own)."""
    reaction = scenario.task.fault_reaction if reaction is None else reaction
    task = dataclasses.replace(scenario.task, faults=faults, fault_reaction=reaction)
    return dataclasses.replace(scenario, task=task)


def reaction_cost(faulty: EpisodeRecord, twin: EpisodeRecord) -> dict[str, float | bool]:
    """What the cell's reaction to a fault cost: ``picks_lost_per_min``, the twin's pick rate minus the faulty
    episode's (1/min; :func:`eval.metrics.picks_per_min`, over the work each did), and ``stopped``, whether a stop
    ended the faulty episode (its rate then covers only the work before the stop)."""
    rates = [record.metrics()["picks_per_min"] for record in (twin, faulty)]
    return {"picks_lost_per_min": rates[0] - rates[1], "stopped": faulty.stopped}


def fault_effect(faulty: EpisodeRecord, twin: EpisodeRecord) -> dict[str, float]:
    """What the fault did: to the payload estimate (sensor faults, collisions), the largest change against the twin
    from the fault to the end of its carry (the earlier of the two places) and the change left at its end, as shares
    of the object's mass; for a slip, the time until the estimate of the slipped object fell below
    :data:`GONE_MASS` (NaN if it did not before the place); for a drive fault, the most torque (N m) it withheld from
    the command (the env's truth, :attr:`~delta_env.faults.InjectedFault.withheld`; 0: the fault changed nothing,
    latent)."""
    (fault,) = faulty.injected_faults
    start = fault.start_step + 1  # the first observation it affects
    carry = int(np.searchsorted(faulty.pick_indices, start, side="right")) - 1
    places = faulty.place_indices
    end = int(places[carry]) if 0 <= carry < len(places) else len(faulty.payload_estimate)
    end = min(end, len(faulty.payload_estimate), len(twin.payload_estimate))
    if 0 <= carry < len(twin.place_indices):  # after the fault the twin's waits may place a step or more apart
        end = min(end, int(twin.place_indices[carry]))  # compare while both carry: at a release the estimate goes to 0
    effect = {"estimate_change": math.nan, "end_change": math.nan, "forgotten_ms": math.nan, "withheld_nm": math.nan}
    if fault.kind == "drive_fault":
        effect["withheld_nm"] = fault.withheld
    if start >= end:
        return effect
    if fault.kind == "slip":
        below = np.flatnonzero(faulty.payload_estimate[start:end] < GONE_MASS)
        effect["forgotten_ms"] = 1e3 * below[0] * CONTROL_PERIOD if below.size else math.nan
    elif fault.kind in (*SENSOR_KINDS, "collision") and 0 <= carry < len(faulty.masses):
        change = np.abs(faulty.payload_estimate[start:end] - twin.payload_estimate[start:end])
        mass = max(faulty.masses[carry], GONE_MASS)
        effect["estimate_change"] = float(np.max(change) / mass)
        effect["end_change"] = float(change[-1] / mass)
    return effect


def effective_drive(rows: list[dict[str, Any]], fault_csv_rows: list[dict[str, Any]]) -> str:
    """Detected / injected of the drive faults that withheld more than the torque check's margin."""
    detected = {
        int(row["seed"]) for row in fault_csv_rows if row["kind"] == "drive_fault" and row["outcome"] == "detected"
    }
    effective = [row for row in rows if row["withheld_nm"] > TORQUE_MARGIN]
    return f"{sum(row['seed'] in detected for row in effective)}/{len(effective)}"


def summary_table(rows: list[dict[str, Any]], by_kind: dict[str, list[dict[str, Any]]], kinds: Sequence[str]) -> str:
    """Per fault kind, over the episodes that carried it: detection, latency, the other detections there
    (consequences, false alarms), and what the fault did to the estimate or the drive."""
    summaries = {kind: next((s for s in fault_summary(by_kind[kind]) if s.kind == kind), None) for kind in kinds}
    header = [
        "Fault",
        "Detected / scored",
        "Latent",
        "Latency median / max (ms)",
        "Consequences",
        "False alarms",
        "Estimate change, max (% of mass)",
        "At the place (% of mass)",
        "Slip forgotten, max (ms)",
        f"Drive faults withholding > {TORQUE_MARGIN:g} N m: detected",
    ]
    body = []
    for kind in kinds:
        summary = summaries.get(kind)
        mine = [row for row in rows if row["kind"] == kind]
        changes = [row["estimate_change"] for row in mine if not math.isnan(row["estimate_change"])]
        end_changes = [row["end_change"] for row in mine if not math.isnan(row["end_change"])]
        forgotten = [row["forgotten_ms"] for row in mine]
        slow_forget = "never" if any(math.isnan(f) for f in forgotten) else f"{max(forgotten, default=math.nan):.0f}"
        body.append(
            [
                kind,
                f"{summary.detected}/{summary.detected + summary.missed}" if summary else "0/0",
                str(summary.latent) if summary else "0",
                f"{summary.latency_median_ms:.0f} / {summary.latency_max_ms:.0f}"
                if summary and summary.detected
                else "n/a",
                str(sum(row["outcome"] == "consequence" for row in by_kind[kind])),
                str(sum(row["outcome"] == "false_alarm" for row in by_kind[kind])),
                f"{100 * max(changes):.1f}" if changes else "",
                f"{100 * max(end_changes):.1f}" if end_changes else "",
                slow_forget if kind == "slip" else "",
                effective_drive(mine, by_kind[kind]) if kind == "drive_fault" else "",
            ]
        )
    return metrics.markdown_table(header, body)


def reaction_table(rows: list[dict[str, Any]], kinds: Sequence[str], reactions: Sequence[str]) -> str:
    """Per fault kind and reaction: the picks/min lost against the twins, mean and worst over the episodes a stop
    did not end, and how many a stop ended."""
    body = []
    for kind in kinds:
        cells = [kind]
        for reaction in reactions:
            mine = [row for row in rows if row["kind"] == kind and row["reaction"] == reaction]
            lost = [row["picks_lost_per_min"] for row in mine if not row["stopped"]]
            stopped = sum(bool(row["stopped"]) for row in mine)
            cell = f"{np.mean(lost):.1f} / {np.max(lost):.1f}" if lost else "n/a"
            cells.append(cell + (f" ({stopped} stopped)" if stopped else ""))
        body.append(cells)
    return metrics.markdown_table(["Fault", *(f"{r}: picks/min lost, mean / max" for r in reactions)], body)


@command_main("python -m eval.faults")
def main(argv: Sequence[str] | None = None) -> int:
    config = parse_args(argv)
    with command_run_folder(
        "fault_campaign", "eval.faults", argv, config, configuration_record(config), scenarios=[config.scenario]
    ) as run:
        campaign(config, run)
    return 0


def campaign(args: CampaignConfig, run: Run) -> None:
    """The campaign of ``args`` (:func:`parse_args`) into ``run``'s folder, its tables printed."""
    out = run.folder
    healthy = with_faults(args.scenario, ())
    setup = prepare(healthy, args.controllers, runs_dir=args.runs_dir, workers=args.workers).setup
    seeds = [args.seed + i for i in range(args.episodes)]
    faulty = [with_faults(healthy, (FaultSpec(kind),), reaction) for reaction in args.reactions for kind in args.kinds]
    scenarios = [healthy, *faulty]
    units = [WorkUnit(scenario, key, seed) for key in args.controllers for scenario in scenarios for seed in seeds]
    setups = {s.content_hash: dataclasses.replace(setup, fault_reaction=s.task.fault_reaction) for s in scenarios}
    with progress_bar(len(units), "episodes", "ep") as bar:
        records = list(zip(units, run_grid(units, setups, workers=args.workers, progress=bar), strict=True))
    rows: list[dict[str, Any]] = []
    fault_csv_rows: list[dict[str, Any]] = []
    text = f"# Fault campaign: {args.scenario.name}, {plural(args.episodes, 'episode')} per kind\n"
    for key in args.controllers:
        label = controller_label(key)
        mine = [(unit, record) for unit, record in records if unit.controller == key]
        twins = {unit.seed: record for unit, record in mine if not unit.scenario.task.faults}
        key_rows: list[dict[str, Any]] = []
        by_kind: dict[str, list[dict[str, Any]]] = {kind: [] for kind in args.kinds}
        twin_rows: list[dict[str, Any]] = []  # their detections: false alarms
        for unit, record in mine:
            identity = {"controller": label, "key": key, "episode": unit.seed - args.seed, "seed": unit.seed}
            if not unit.scenario.task.faults:
                twin_rows += fault_rows(identity, record.faults())
                continue
            kind, reaction = unit.scenario.task.faults[0].kind, unit.scenario.task.fault_reaction
            if reaction == args.reactions[0]:
                by_kind[kind] += fault_rows(identity, record.faults())
            if record.injected_faults:  # else the drawn carry fault fell after the episode's end
                twin = twins[unit.seed]
                cost = reaction_cost(record, twin)
                key_rows.append(
                    {"kind": kind, "reaction": reaction, "seed": unit.seed, **fault_effect(record, twin), **cost}
                )
        twin_alarms = len(twin_rows)
        fault_csv_rows += [row for kind in args.kinds for row in by_kind[kind]] + twin_rows
        rows += [{"controller": label, "key": key, **row} for row in key_rows]
        first = [row for row in key_rows if row["reaction"] == args.reactions[0]]
        text += f"\n## {label}\n\n{summary_table(first, by_kind, args.kinds)}\n\n"
        text += f"The {len(twins)} fault-free twins raised {twin_alarms} false alarm(s).\n"
        text += (
            "\nWhat each reaction cost against the twins (their mean: "
            f"{np.mean([twin.metrics()['picks_per_min'] for twin in twins.values()]):.1f} picks/min):\n\n"
            + reaction_table(key_rows, args.kinds, args.reactions)
            + "\n"
        )
    matrices = confusion_counts(fault_csv_rows, [controller_label(key) for key in args.controllers])
    text += (
        "\n## Confusion matrix\n\nInjected kind by detected kind: a cell counts the faults reported at least once as "
        "that kind within the fault's window (a fault reported as two kinds counts twice); column none: no "
        "detection; row none: false alarms, the twins' included.\n\n" + confusion_table(matrices) + "\n"
    )
    write_fault_csv(out / "faults.csv", fault_csv_rows)
    write_confusion_csv(out / "confusion.csv", matrices)
    write_csv(out / "campaign.csv", rows)
    (out / "summary.md").write_text(text)
    print(text)
    print(f"\nRun folder: {out}")


if __name__ == "__main__":
    sys.exit(main())
