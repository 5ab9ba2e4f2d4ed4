"""``python -m eval.rate``: the pick-rate data sheet (docs/design.md section 9).

Picks per minute on the industry's 25/305/25 mm standard cycle, like a Delta picker's data sheet, at payloads
0.1, 1, 2 and 4 kg (the rated payload) and on a mixed stream of objects drawn from U[0, 4] kg, for each way of
timing the moves (``--planners``). Planned timings use the drive's whole envelope (after the planner's 10 % margin
for model error) within its thermal rating (``--torque-share`` takes less); the cycle's ends (air activation, the
in-position window) are the scenario's. ABB's published rows (:mod:`eval.rate.published`) stand beside ours.

- ``fixed``: today's timing, every move at the scenario's peak acceleration (3 g);
- ``worst_case``: time-optimal within the drive, every carry for the heaviest object of the stream;
- ``declared``: time-optimal, each carry for its object's true mass (the reference, not a controller);
- ``online``: time-optimal, a carry starts for the heaviest object and is retimed once the payload estimate
  has settled (:mod:`controllers.payload_timing`);
- ``worst_case+jerk``, ``declared+jerk``, ``online+jerk``: a planned timing whose laws are averaged over one period
  of the drives' first mode (:class:`controllers.shaping.JerkLimitedTiming`), for compliant drives: the path
  acceleration ramps instead of stepping, each move a period longer. The input-shaped rows are controllers:
  ``--controllers mid_f_rls_lag,controllers.shaping:LAG_ZV,controllers.shaping:LAG_ZVD`` (their tracking is judged
  against the shaped reference they follow).

The first controller of ``--controllers`` (by default the model-based MId+F+R+RLS+lag+PD) runs every row, and
so does every other controller that estimates the payload itself (the RLS rows, the residual:
:func:`eval.rate.study.paced`), at its own pace: timed on its own estimate, released in position. The others (PD, the
rows without an estimate) run the first's references (its episodes' reference, replayed with the same objects), so
that they are scored at the same timings. For each payload it also finds the fastest fixed timing at which the second
controller (PD by default) meets the tracking and place goals (:data:`eval.rate.study.TRACKING_GOAL_MM`,
:data:`~eval.rate.study.PLACE_GOAL_MM`):
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
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from controllers.registry import (
    CELL_ESTIMATOR_KEY,
    controller_entry,
    controller_label,
    controllers_help,
    parse_controller_keys,
)
from controllers.residual import read_policy_settings
from delta_env.config import RATED_PAYLOAD
from delta_env.scenario import TIMINGS
from eval.calibration import calibration_seeds, tared_keys
from eval.console import CommandParser, command_main, progress_bar
from eval.engine import prepare
from eval.rate.published import ABB_IRB_360
from eval.rate.report import save_rate_figure, study_line, summary_lines
from eval.rate.study import (
    CALIBRATION_EPISODES,
    DEFAULT_CONTROLLERS,
    FULL_STUDY,
    JERK_LIMITED,
    MIXED,
    PLACE_GOAL_MM,
    PLANNERS,
    QUICK_NOTE,
    QUICK_STUDY,
    RATE_TORQUE_SHARE,
    TRACKING_GOAL_MM,
    RateConfig,
    cycle_terms,
    fastest_episodes,
    fastest_fixed,
    kilograms,
    rate_scenario,
    row_episodes,
    run_rows,
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
    add_parameters_argument,
    add_residual_argument,
    add_scenario_arguments,
    add_servo_argument,
    add_workers_argument,
    check_episode_seeds,
    check_ranges,
    scenario_from_arguments,
)


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
        f"{kilograms(QUICK_STUDY.payloads).replace(',', ' and ')} kg and the mixed stream, no fastest-fixed search, "
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
        help=f"comma-separated timings from {', '.join(PLANNERS)} (default: {', '.join(TIMINGS)}); {JERK_LIMITED}: "
        "the planned timing's laws averaged over one period of the drives' first mode (needs the drives' compliance)",
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
        f"(default {kilograms(FULL_STUDY.payloads)}; {kilograms(QUICK_STUDY.payloads)} with --quick)",
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
    payload_text = kilograms(size.payloads) if args.payloads is None else args.payloads
    workers = size.workers if args.workers is None else args.workers
    sized = argparse.Namespace(**{**vars(args), "episodes": episodes, "cycles": cycles, "workers": workers})
    check_ranges(parser, sized, {"seed": 0, "episodes": 1, "cycles": 1, "workers": 1})
    check_episode_seeds(parser, sized)
    scenario = scenario_from_arguments(args, parser)
    try:  # one home: the scenario every row derives
        task = dataclasses.replace(scenario.task, n_cycles=cycles, torque_share=args.torque_share)
    except ValueError as error:
        parser.error(f"--torque-share: {error}")
    planners = _listed(parser, "--planners", args.planners, PLANNERS)
    jerky = [planner for planner in planners if planner.endswith(JERK_LIMITED)]
    if jerky and scenario.plant.realism.compliance is None:
        parser.error(
            f"--planners {','.join(jerky)}: a jerk-limited timing averages over the drives' mode; the scenario "
            f"{scenario.name!r} has rigid drives (e.g. --scenario compliant)"
        )
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


def _listed(parser: argparse.ArgumentParser, flag: str, text: str, allowed: Sequence[str]) -> list[str]:
    """The comma-separated values of ``flag``, each one of ``allowed`` (a parser error otherwise)."""
    values = list(dict.fromkeys(value.strip() for value in text.split(",") if value.strip()))
    unknown = [value for value in values if value not in allowed]
    if unknown or not values:
        parser.error(f"{flag}: unknown or no values {unknown}; choose from {', '.join(allowed)}")
    return values


@command_main("python -m eval.rate")
def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    config = parse_args(argv)
    with command_run_folder(
        "rate", "eval.rate", argv, config, {"arguments": configuration_record(config)}, scenarios=[config.scenario]
    ) as run:
        rate(config, run, started)
    return 0


def rate(config: RateConfig, run: Run, started: float) -> None:
    """The data sheet of ``config`` (:func:`parse_args`) into ``run``'s folder, its summary printed; ``started`` is
    the :func:`time.perf_counter` time at the start of the command."""
    out = run.folder
    scenario = config.scenario
    # Every tared row is tared; the lead's estimator retimes the online carries (the cell's own if the lead has none).
    tared = tared_keys(config.controllers, None)
    if not controller_entry(config.controllers[0]).has_estimator and CELL_ESTIMATOR_KEY not in tared:
        tared.append(CELL_ESTIMATOR_KEY)
    if config.quick:
        print(f"{QUICK_NOTE} Measuring {study_line(config)}.", flush=True)
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
    summary = "\n".join(summary_lines(config, rows, fastest, out, time.perf_counter() - started))
    (out / "summary.md").write_text(summary + "\n")
    run.record(
        config={
            "arguments": configuration_record(config),
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


if __name__ == "__main__":
    sys.exit(main())
