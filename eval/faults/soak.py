"""Fault-free soak: how often each controller's fault monitor raises a false alarm on hard, healthy work.

Runs fault-free episodes ``seed, seed + 1, ...`` of each controller on each condition (``--conditions``,
:data:`CONDITIONS`, default all) until each pair has completed ``--carries`` carries (objects picked and placed,
:meth:`eval.episodes.EpisodeRecord.carries`; default 10000) and, if given, ``--minutes`` simulated minutes:

- ``3g``, ``6g``, ``10g``, ``15g``: conveyor cycles at that fixed peak acceleration, objects U[0, 4] kg (the rated
  payload);
- ``declared-mixed``, ``declared-0.1kg``, ``declared-4kg``, ``online-mixed``, ``online-0.1kg``, ``online-4kg``: the
  pick-rate data sheet's time-optimal timings on the whole envelope, built as ``python -m eval.rate`` builds them
  (:func:`eval.rate.study.rate_scenario`: the standard cycle, ``torque_share``
  :data:`eval.rate.study.RATE_TORQUE_SHARE`, its
  cycles per episode), with objects U[0, 4] kg, 0.1 kg or 4 kg. Every controller runs at its own pace (an online
  carry of a row without an estimator is retimed on the cell's, as a cell would run it), where the data sheet has
  those rows replay its first controller's references;
- ``10kg-3g``, ``10kg-6g``: conveyor cycles at 3 or 6 g with 10 kg objects (2.5 x the rated payload).

The plants are the ``--scenario``'s, a preset or a scenario file (default ``randomized``: masses +-10 %, friction
+-30 %, current-loop lag 0.5-2 ms, drawn per episode; ``nominal``; ``compliant``: the gearheads' twist and
motor-side encoders), on the robot of ``--geometry``; the scenario's own faults are left out. No fault is injected,
so every detection is a false alarm (:mod:`eval.fault_scores` counts them; an episode that carried an injected fault
all the same is counted apart and reported). The controllers are built as ``python -m eval`` builds them: the
robot's identification (``<runs root>/identification``, identified once when missing, a minute or a few) and the
tares of the payload
estimators measured on payload-free episodes of the same conditions on the comparison's calibration seeds
(:mod:`eval.calibration`; the timed conditions tare as the data sheet does, on its declared mixed stream).

The table gives, per condition and controller, the carries counted, the false alarms per kind and per 10,000
carries; with none, "0 in N carries" and the rule of three's 95 % upper bound (3 / N), and with some, the first
one's episode seed and time.

Writes into the folder ``--out`` (default ``<runs root>/fault_soak/<UTC time>``; :mod:`eval.run_folder`):

- ``episodes.csv``: one row per episode (:data:`EPISODE_COLUMNS`), appended as each finishes;
- ``faults.csv``: every detection, as rows of :data:`eval.fault_tables.FAULT_COLUMNS` with the episode's condition
  (false alarms here);
- ``config.json``: the manifest (the command, the conditions, status, times); ``summary.md``: the table, also
  printed.

An interrupted run loses nothing already written: rerun the same command with the same ``--out`` and it resumes,
running only the episodes it lacks (a larger ``--carries`` or ``--minutes``, or more conditions or controllers,
extend a finished soak).

Usage: python -m eval.faults.soak [--carries 10000] [--minutes M] [--conditions 3g,online-4kg,...]
                                    [--scenario randomized|FILE] [--geometry FILE] [--controllers mid_f_rls]
                                    [--seed 0]
                                    [--out DIR] [--workers 2] [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controllers.registry import CELL_ESTIMATOR_KEY, controller_label, controllers_help, parse_controller_keys
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import GRAVITY
from delta_env.scenario import Scenario
from delta_env.sensors import CONTROL_PERIOD
from delta_env.validation import require_count
from eval import metrics
from eval.calibration import DEFAULT_CALIBRATION_EPISODES
from eval.console import CommandParser, UsageError, command_main, progress_bar
from eval.engine import prepare
from eval.episodes import EpisodeRecord
from eval.fault_tables import FAULT_COLUMNS, fault_rows
from eval.rate.study import CALIBRATION_EPISODES, FULL_STUDY, MIXED, RATE_TORQUE_SHARE, payload_label, rate_scenario
from eval.run_folder import Run, add_runs_dir_argument, append_csv_rows, command_line, read_csv_rows, run_folder
from eval.scenario_args import add_scenario_arguments, add_workers_argument, check_ranges, scenario_from_arguments
from eval.work import WorkUnit, run_grid


@dataclass(frozen=True)
class SoakCondition:
    """One condition of the soak.

    Attributes:
        timing: How the moves are timed (:data:`delta_env.scenario.TIMINGS`): ``fixed`` on the scenario's conveyor
            cycle, else the data sheet's time-optimal timing (:func:`eval.rate.study.rate_scenario`).
        payload: Every object's mass (kg), or :data:`eval.rate.study.MIXED` (U[0, rated payload]).
        peak_acceleration: Peak Cartesian acceleration of a fixed timing (m/s^2); unused by the others.
        description: What the condition is, in words.
    """

    timing: str
    payload: float | str
    peak_acceleration: float
    description: str

    def scenario(self, base: Scenario, name: str) -> Scenario:
        """``base``'s plants under this condition, named ``<base>/<name>``."""
        if self.timing == "fixed":
            masses = (0.0, RATED_PAYLOAD) if self.payload == MIXED else (float(self.payload), float(self.payload))
            task = dataclasses.replace(base.task, peak_acceleration=self.peak_acceleration, payload_mass_range=masses)
        else:  # the data sheet's row: its cycles per episode, on the whole envelope
            timed = dataclasses.replace(base.task, n_cycles=FULL_STUDY.cycles, torque_share=RATE_TORQUE_SHARE)
            task = rate_scenario(dataclasses.replace(base, task=timed), self.timing, self.payload).task
        return dataclasses.replace(
            base, name=f"{base.name}/{name}", description=f"{base.name} plants, {self.description}", task=task
        )

    def tare_scenario(self, base: Scenario, name: str) -> Scenario:
        """The scenario whose payload-free episodes tare the estimators: the condition's own for a fixed timing, the
        data sheet's declared mixed stream for a time-optimal one (as ``python -m eval.rate`` tares)."""
        scenario = self.scenario(base, name)
        if self.timing == "fixed":
            return scenario
        return rate_scenario(scenario, "declared", MIXED)


def _fixed(g: float, payload: float | str) -> SoakCondition:
    objects = f"U[0, {RATED_PAYLOAD:g}] kg" if payload == MIXED else f"{payload_label(payload)} kg"
    return SoakCondition("fixed", payload, g * GRAVITY, f"conveyor cycles at {g:g} g, objects {objects}")


def _timed(timing: str, payload: float | str) -> SoakCondition:
    objects = f"U[0, {RATED_PAYLOAD:g}] kg" if payload == MIXED else f"{payload_label(payload)} kg"
    return SoakCondition(
        timing, payload, 0.0, f"standard cycle, {timing} time-optimal timing on the whole envelope, objects {objects}"
    )


HEAVY_PAYLOAD = 10.0
"""Object mass (kg) of the heavy conditions: 2.5 x the rated payload."""

CONDITIONS: dict[str, SoakCondition] = {
    **{f"{g:g}g": _fixed(g, MIXED) for g in (3.0, 6.0, 10.0, 15.0)},
    **{
        f"{timing}-{'mixed' if payload == MIXED else payload_label(payload) + 'kg'}": _timed(timing, payload)
        for timing in ("declared", "online")
        for payload in (MIXED, 0.1, RATED_PAYLOAD)
    },
    **{f"{HEAVY_PAYLOAD:g}kg-{g:g}g": _fixed(g, HEAVY_PAYLOAD) for g in (3.0, 6.0)},
}
"""The soak's conditions by name (the module docstring lists them)."""

DEFAULT_CARRIES = 10_000
"""Carries per controller and condition of the issue's false-alarm target."""

DEFAULT_SCENARIO = "randomized"
"""The preset whose plants the soak runs unless ``--scenario`` says otherwise."""

EPISODE_COLUMNS = (
    "condition",
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
"""Columns of ``episodes.csv``: the condition (a key of :data:`CONDITIONS`), the episode, its simulated time (s) and
completed carries, whether it diverged, faults injected (0 in a fault-free soak), detections, false alarms, and two
figures of how hard it ran."""

SOAK_FAULT_COLUMNS = ("condition", *FAULT_COLUMNS)
"""Columns of ``faults.csv``: the episode's condition and :data:`eval.fault_tables.FAULT_COLUMNS`."""


@dataclass(frozen=True)
class SoakConfig:
    """The resolved configuration of a soak (:func:`parse_args`).

    Attributes:
        carries: Carries per controller and condition; None: ``minutes`` alone bounds the soak.
        minutes: Simulated minutes per controller and condition; None: no bound in time.
        conditions: The conditions run (:data:`CONDITIONS`), each once, in the order given.
        scenario: The plants and the robot (``--scenario`` on ``--geometry``), without faults.
        controllers: Registry keys of the rows.
        seed: Seed of the first episode.
        out: Output folder; None: ``<runs root>/fault_soak/<UTC time>``.
        runs_dir: Root of the run folders and of the cached identifications; None: the default.
        workers: Processes running the episodes.
    """

    carries: int | None
    minutes: float | None
    conditions: tuple[str, ...]
    scenario: Scenario
    controllers: tuple[str, ...]
    seed: int
    out: Path | None
    runs_dir: Path | None
    workers: int


def argument_parser() -> CommandParser:
    """The command line's parser."""
    parser = CommandParser(
        prog="python -m eval.faults.soak", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--carries",
        type=int,
        default=None,
        help=f"carries per controller and condition (default {DEFAULT_CARRIES} unless --minutes is given)",
    )
    parser.add_argument(
        "--minutes", type=float, default=None, help="simulated minutes per controller and condition (default none)"
    )
    parser.add_argument(
        "--conditions",
        default=",".join(CONDITIONS),
        help=f"comma-separated conditions from {', '.join(CONDITIONS)} (default: all)",
    )
    add_scenario_arguments(parser, default=DEFAULT_SCENARIO)
    parser.add_argument("--controllers", default="mid_f_rls", help=controllers_help("mid_f_rls"))
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default <runs root>/fault_soak/<UTC time>)"
    )
    add_runs_dir_argument(parser)
    add_workers_argument(parser)
    return parser


def resolve(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> SoakConfig:
    """The soak's configuration from the parsed ``arguments`` (left as parsed); a bad value is ``parser``'s error."""
    carries = DEFAULT_CARRIES if arguments.carries is None and arguments.minutes is None else arguments.carries
    check_ranges(
        parser,
        argparse.Namespace(**{**vars(arguments), "carries": carries}),
        {"seed": 0, "workers": 1, **({"carries": 1} if carries is not None else {})},
        ("minutes",) if arguments.minutes is not None else (),
    )
    conditions = [name.strip() for name in arguments.conditions.split(",") if name.strip()]
    unknown = [name for name in conditions if name not in CONDITIONS]
    if unknown or not conditions:
        parser.error(f"--conditions: unknown or no values {unknown}; choose from {', '.join(CONDITIONS)}")
    try:
        controllers = parse_controller_keys(arguments.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    return SoakConfig(
        carries=carries,
        minutes=arguments.minutes,
        conditions=tuple(dict.fromkeys(conditions)),
        scenario=without_faults(scenario_from_arguments(arguments, parser)),
        controllers=tuple(controllers),
        seed=arguments.seed,
        out=arguments.out,
        runs_dir=arguments.runs_dir,
        workers=arguments.workers,
    )


def without_faults(scenario: Scenario) -> Scenario:
    """``scenario`` with no fault injected (a soak counts false alarms)."""
    return dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, faults=()))


def parse_args(argv: Sequence[str] | None) -> SoakConfig:
    """The soak's configuration from the command line ``argv``."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def condition_scenarios(base: Scenario, names: Sequence[str]) -> dict[str, Scenario]:
    """The scenario of each condition of ``names`` on ``base``'s plants."""
    return {name: CONDITIONS[name].scenario(base, name) for name in names}


def episode_row(condition: str, unit: WorkUnit, record: EpisodeRecord, first_seed: int) -> dict[str, Any]:
    """The row of ``episodes.csv`` of one finished episode of ``condition`` of a soak from seed ``first_seed``."""
    scores = record.metrics()
    carries = record.carries()
    return {
        "condition": condition,
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

Cell = tuple[str, str]
"""A condition (a key of :data:`CONDITIONS`) and a controller key."""


def _cell(row: dict[str, Any]) -> Cell:
    return (str(row["condition"]), str(row["key"]))


def episodes_to_go(
    rows: Sequence[dict[str, Any]], cell: Cell, remaining: float, first_batch: int, column: str = "simulated_s"
) -> int:
    """Episodes of ``cell`` to run for ``remaining`` more of ``column`` (``simulated_s``: seconds, or ``carries``):
    by its mean per episode of ``cell`` in ``rows`` (at least a control period, or one carry), or ``first_batch``
    before it has any."""
    values = [float(row[column]) for row in rows if _cell(row) == cell]
    if not values:
        return first_batch
    least = CONTROL_PERIOD if column == "simulated_s" else 1.0
    return max(1, math.ceil(remaining / max(statistics.fmean(values), least)))


def next_units(
    scenarios: dict[str, Scenario],
    wanted: dict[Cell, int],
    first_seed: int,
    finished: set[tuple[str, str, int]],
    start: int,
    limit: int,
) -> tuple[list[WorkUnit], int]:
    """The next episodes: ``wanted[cell]`` of each condition and controller (on ``scenarios[condition]``), on the seeds
    from ``first_seed + start`` on, skipping those ``finished`` already (condition, key, seed: a resumed soak fills its
    gaps first), seed by seed until there are ``limit`` or more (a seed is never split, so every cell advances in
    turn); and the seed index after the last seed used."""
    require_count("limit", limit)
    units: list[WorkUnit] = []
    to_go = {cell: count for cell, count in wanted.items() if count > 0}
    index = start
    while to_go and len(units) < limit:
        seed = first_seed + index
        for condition, key in [cell for cell in to_go if (*cell, seed) not in finished]:
            units.append(WorkUnit(scenarios[condition], key, seed))
            to_go[(condition, key)] -= 1
            if to_go[(condition, key)] == 0:
                del to_go[(condition, key)]
        index += 1
    return units, index


def resume(out: Path, config: dict[str, Any]) -> list[dict[str, str]]:
    """The episodes already in the folder ``out`` (none if new); ``faults.csv`` trimmed to them; and ``config``'s
    condition hashes merged with those written (so that a resumed soak of fewer conditions keeps checking the others).
    Refuses a folder of a soak under other conditions (another seed, or another scenario of a condition), before its
    manifest is rewritten."""
    if not out.is_dir():
        return []
    config_path = out / "config.json"
    if config_path.exists():
        written = json.loads(config_path.read_text())["config"]
        if written.get("seed") != config["seed"]:
            raise UsageError(f"--out {out} holds a soak with seed {written.get('seed')!r}, not {config['seed']!r}")
        hashes = written.get("condition_hashes", {})
        for name, content_hash in config["condition_hashes"].items():
            if hashes.get(name, content_hash) != content_hash:
                raise UsageError(
                    f"--out {out} holds a soak whose condition {name} ran another scenario ({hashes[name]}, not "
                    f"{content_hash}; another --scenario or code of the conditions): use another --out"
                )
        config["condition_hashes"] = {**hashes, **config["condition_hashes"]}
    done = read_csv_rows(out / "episodes.csv")
    finished = {(row["condition"], row["key"], row["seed"]) for row in done}
    faults_path = out / "faults.csv"
    kept = [row for row in read_csv_rows(faults_path) if (row["condition"], row["key"], row["seed"]) in finished]
    faults_path.unlink(missing_ok=True)
    append_csv_rows(faults_path, SOAK_FAULT_COLUMNS, kept)  # fault rows of an episode whose row was never written go
    return done


def _per_ten_thousand_value(value: float) -> str:
    return f"{value:.0f}" if value >= 100 else f"{value:.3g}"


def per_ten_thousand(alarms: int, carries: int) -> str:
    """False alarms per 10,000 carries; for none, "0 in N carries" with the rule of three's 95 % upper bound (3 / N)."""
    if carries == 0:
        return "n/a (no carry)"
    if alarms == 0:
        return f"0 in {carries} carries (< {_per_ten_thousand_value(3e4 / carries)} at 95 %)"
    return _per_ten_thousand_value(1e4 * alarms / carries)


def cell_soaks(
    rows: Sequence[dict[str, Any]], alarms: Sequence[dict[str, Any]], conditions: Sequence[str], keys: Sequence[str]
) -> dict[Cell, tuple[list[dict[str, Any]], list[dict[str, Any]]]]:
    """Per condition and controller that ran: its fault-free episodes of ``rows`` and their false alarms of
    ``alarms`` (the false-alarm rows of ``faults.csv``). Episodes that carried an injected fault are left out."""
    clean = {(row["condition"], row["key"], int(row["seed"])) for row in rows if int(row["faults_injected"]) == 0}
    soaks = {}
    for cell in [(condition, key) for condition in conditions for key in keys]:
        group = [row for row in rows if _cell(row) == cell and int(row["faults_injected"]) == 0]
        if group:
            found = [alarm for alarm in alarms if _cell(alarm) == cell and (*cell, int(alarm["seed"])) in clean]
            soaks[cell] = (group, found)
    return soaks


def summary_table(
    rows: Sequence[dict[str, Any]],
    alarms: Sequence[dict[str, Any]],
    conditions: Sequence[str],
    keys: Sequence[str],
) -> str:
    """Per condition and controller: episodes (diverged), carries and those whose estimate overshot the lift-off bound
    (:data:`eval.metrics.OVERSHOOT_BOUND`), simulated minutes, false alarms by kind and per 10,000 carries, and the
    first alarm's seed and time (:func:`cell_soaks`)."""
    bound_kg, bound_fraction = metrics.OVERSHOOT_BOUND
    over = f"Carries over max({bound_kg} kg, {100 * bound_fraction:.0f} %)"
    header = ["Condition", "Controller", "Episodes (diverged)", "Carries", over, "Simulated min"]
    header += ["False alarms by kind", "Per 10,000 carries", "First (seed, s)"]
    body = []
    for (condition, key), (group, found) in cell_soaks(rows, alarms, conditions, keys).items():
        kinds: dict[str, int] = {}
        for alarm in found:
            kinds[str(alarm["kind"])] = kinds.get(str(alarm["kind"]), 0) + 1
        carries = sum(int(row["carries"]) for row in group)
        first = min(found, key=lambda alarm: (int(alarm["seed"]), float(alarm["detected_at_s"])), default=None)
        body.append(
            [
                condition,
                controller_label(key),
                f"{len(group)} ({sum(str(row['diverged']) == 'True' for row in group)})",
                str(carries),
                str(sum(int(row["carries_over"]) for row in group)),
                f"{sum(float(row['simulated_s']) for row in group) / 60:.1f}",
                ", ".join(f"{kind} {count}" for kind, count in sorted(kinds.items())) or "none",
                per_ten_thousand(len(found), carries),
                "" if first is None else f"{first['seed']}, {float(first['detected_at_s']):.3f}",
            ]
        )
    return metrics.markdown_table(header, body)


def matrix_table(
    rows: Sequence[dict[str, Any]],
    alarms: Sequence[dict[str, Any]],
    conditions: Sequence[str],
    keys: Sequence[str],
) -> str:
    """The soak at a glance: a row per controller, a column per condition, each cell its false alarms / carries
    (:func:`cell_soaks`; blank where it did not run)."""
    soaks = cell_soaks(rows, alarms, conditions, keys)
    ran = [condition for condition in conditions if any((condition, key) in soaks for key in keys)]
    body = []
    for key in keys:
        cells = []
        for condition in ran:
            group, found = soaks.get((condition, key), ([], []))
            cells.append(f"{len(found)} / {sum(int(row['carries']) for row in group)}" if group else "")
        body.append([controller_label(key), *cells])
    return metrics.markdown_table(["False alarms / carries", *ran], body)


@command_main("python -m eval.faults.soak")
def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    base = args.scenario
    scenarios = condition_scenarios(base, args.conditions)
    config = {
        "seed": args.seed,
        "scenario": base.name,
        "conditions": {name: scenarios[name].description for name in args.conditions},
        "condition_hashes": {name: scenario.content_hash for name, scenario in scenarios.items()},
        "carries": args.carries,
        "minutes": args.minutes,
        "controllers": list(args.controllers),
        "workers": args.workers,
    }
    rows = resume(args.out, config) if args.out is not None else []
    command = command_line("eval.faults.soak", argv)
    with run_folder(
        "fault_soak",
        command,
        config,
        out=args.out,
        runs_dir=args.runs_dir,
        scenarios=list(scenarios.values()),
        reuse=True,
    ) as run:
        soak(args, run, base, rows)
    return 0


def soak_setups(args: SoakConfig, base: Scenario) -> dict[str, Any]:
    """What the controllers know on each condition's scenario, by its content hash: tared once per tare scenario
    (:meth:`SoakCondition.tare_scenario`), the timed ones with the cell's estimator as the data sheet tares it."""
    setups: dict[str, Any] = {}
    prepared: dict[str, Any] = {}
    for name in args.conditions:
        condition = CONDITIONS[name]
        tare = condition.tare_scenario(base, name)
        if tare.content_hash not in prepared:
            timed = condition.timing != "fixed"
            prepared[tare.content_hash] = prepare(
                tare,
                [*args.controllers, CELL_ESTIMATOR_KEY] if timed else args.controllers,
                runs_dir=args.runs_dir,
                calibration_episodes=CALIBRATION_EPISODES if timed else DEFAULT_CALIBRATION_EPISODES,
                workers=args.workers,
            ).setup
        setups[condition.scenario(base, name).content_hash] = prepared[tare.content_hash]
    return setups


def soak(args: SoakConfig, run: Run, base: Scenario, rows: list[dict[str, Any]]) -> None:
    """Run the soak of ``args`` (:func:`parse_args`) on ``base``'s plants into ``run``'s folder, after the episodes
    ``rows`` already there; its table printed."""
    out, keys = run.folder, args.controllers
    scenarios = condition_scenarios(base, args.conditions)
    condition_of = {scenario.content_hash: name for name, scenario in scenarios.items()}
    setups = soak_setups(args, base)
    cells = [(condition, key) for condition in args.conditions for key in keys]
    targets = {
        column: target
        for column, target in (
            ("carries", args.carries),
            ("simulated_s", None if args.minutes is None else 60.0 * args.minutes),
        )
        if target is not None
    }
    finished = {(row["condition"], row["key"], int(row["seed"])) for row in rows}
    done = {
        column: {cell: sum(float(row[column]) for row in rows if _cell(row) == cell) for cell in cells}
        for column in targets
    }
    first_batch, grid_limit = 4 * args.workers, GRID_EPISODES_PER_WORKER * args.workers
    index = 0
    # the progress of the first stop rule (carries, else simulated seconds)
    shown, unit_name = next(iter(targets)), "carries" if "carries" in targets else "simulated s"

    def missing(cell: Cell) -> bool:
        return any(done[column][cell] < target for column, target in targets.items())

    with progress_bar(len(cells) * targets[shown], unit_name, unit_name) as progress:

        def show_progress() -> None:  # set, not added up: sums of float steps overshoot the total in the last bit
            progress.n = sum(min(value, targets[shown]) for value in done[shown].values())
            progress.refresh()

        show_progress()

        def record_episode(unit: WorkUnit, record: EpisodeRecord) -> None:  # as each episode finishes
            condition = condition_of[unit.scenario.content_hash]
            row = episode_row(condition, unit, record, args.seed)
            identity = {name: row[name] for name in ("controller", "key", "episode", "seed")}
            faults = [{"condition": condition, **fault} for fault in fault_rows(identity, record.faults())]
            append_csv_rows(out / "faults.csv", SOAK_FAULT_COLUMNS, faults)
            append_csv_rows(out / "episodes.csv", EPISODE_COLUMNS, [row])
            rows.append(row)
            for column in targets:
                done[column][(condition, unit.controller)] += float(row[column])
            show_progress()

        # A first batch shows how long each cell's episodes run; then grids of as many episodes as that says are
        # missing, seed by seed over every cell, each of at most GRID_EPISODES_PER_WORKER per worker (or one seed) on
        # one process pool, planned again after each.
        while any(missing(cell) for cell in cells):
            wanted = {
                cell: max(
                    episodes_to_go(rows, cell, target - done[column][cell], first_batch, column)
                    for column, target in targets.items()
                    if done[column][cell] < target
                )
                for cell in cells
                if missing(cell)
            }
            units, index = next_units(scenarios, wanted, args.seed, finished, index, grid_limit)
            run_grid(units, setups, workers=args.workers, on_result=record_episode)

    faulted = sum(int(row["faults_injected"]) > 0 for row in rows)
    alarms = [row for row in read_csv_rows(out / "faults.csv") if row["outcome"] == "false_alarm"]
    shown_conditions = list(dict.fromkeys([*args.conditions, *(str(row["condition"]) for row in rows)]))
    lines = [
        f"# Fault-free soak: {base.name} plants, from seed {args.seed}",
        "",
        "Every detection in a fault-free episode is a false alarm. Conditions:",
        "",
        *(f"- `{name}`: {CONDITIONS[name].description}" for name in shown_conditions if name in CONDITIONS),
        "",
        matrix_table(rows, alarms, shown_conditions, keys),
        "",
        summary_table(rows, alarms, shown_conditions, keys),
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
