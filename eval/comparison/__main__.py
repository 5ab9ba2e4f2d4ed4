"""``python -m eval``: every controller on the same seeded pick-and-place episodes (docs/design.md section 8).

The episodes are those of a scenario (``--scenario``, a preset or a TOML file; ``nominal`` by default;
``paper`` is the paper's experiment: standard cycles with 3.8 kg on every pick), optionally on another
robot (``--geometry``, a design of the design study).

1. Loads the identified MId, MId+F and MId+F+R parameters of the scenario's robot
   (``eval.identification.parameter_files.identify_robot``: one file per robot identity, identified when missing, about
   a minute; ``worn`` and ``randomized`` are the nominal robot and share its file).
2. Runs the comparison (:mod:`eval.comparison.run`): tares each payload estimator on ``--calibration-episodes``
   payload-free episodes (measured once per robot and setup, kept beside the identification), runs every
   controller on episodes ``seed, seed + 1, ...`` and the Table 2 run.
   The ``residual`` row is the learned residual policy (``--residual``, by default the shipped one) on
   the base it was trained on, rebuilt from the policy file.
3. Writes the run folder (``--out``, else ``<runs root>/eval/<UTC time stamp>``; :mod:`eval.run_folder`):
   ``config.json`` (the manifest: resolved configuration, command, status, start and end times),
   ``scenario.toml`` (the scenario, every field resolved),
   ``episodes.csv`` and ``carries.csv`` (per episode, pick-rate scores included, and per carried object),
   ``table2.csv``, ``faults.csv`` (every injected fault, detected, missed or latent, and every detection that
   matched none: :mod:`eval.fault_scores`; a header only when there were none), ``confusion.csv`` (only then: per
   controller, injected kind by detected kind), ``traces.npz`` and ``table2_run.npz`` (time
   series: the first episode of each row, with its reference and platform paths), ``summary.md`` (with a Faults
   section when any fault was injected or detected) and the plots made from these files (:mod:`eval.comparison.plots`);
   prints the summary. Diverged episodes are counted in the table, never dropped silently: their
   metrics cover the steps before the divergence.

With ``--video``, the first episode of each row is also filmed (:mod:`eval.comparison.video`): ``video_<key>.mp4`` in
the run folder (GIF where ffmpeg is unavailable), 960 x 720 px at 30 fps; headless with ``MUJOCO_GL=egl``.

Usage: python -m eval [--scenario nominal|paper|FILE] [--geometry FILE] [--seed 0] [--episodes 10] [--cycles 3]
                      [--controllers pd,mid_f_rls] [--out DIR] [--runs-dir DIR] [--video]
"""

from __future__ import annotations

import sys

from eval.processes import pool_context, runs_a_pool, start_worker_server

if __name__ == "__main__" and runs_a_pool(sys.argv[1:]):
    start_worker_server()  # its imports run beside this module's own, below

import argparse
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import (
    CONTROLLER_LABELS,
    controller_entry,
    controller_label,
    estimation_model,
    parse_controller_keys,
)
from controllers.residual import read_policy_settings
from delta_env.sensors import CONTROL_PERIOD
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, calibration_seeds
from eval.comparison import plots, video
from eval.comparison.report import (
    bound_section,
    fault_section,
    payload_target_section,
    pick_rate_section,
    residual_section,
)
from eval.comparison.run import (
    TABLE2_KEY,
    TABLE2_PAYLOAD,
    ComparisonConfig,
    first_episodes,
    run_all,
    table2_statistics,
    tabulate,
    tabulate_faults,
)
from eval.comparison.tables import FEEDBACK_LINES, controller_table, table2_table
from eval.console import CommandParser, command_main, plural, progress_bar
from eval.engine import Prepared, kept_tares
from eval.fault_tables import confusion_counts, write_confusion_csv, write_fault_csv
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
    check_parameter_file,
    check_ranges,
    scenario_from_arguments,
)


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    width = max(map(len, CONTROLLER_LABELS))
    rows = "\n".join(f"  {key:<{width}}  {label}" for key, label in CONTROLLER_LABELS.items())
    parser = CommandParser(
        prog="python -m eval",
        description=__doc__,
        epilog=f"controllers (--controllers key: row label):\n{rows}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    parser.add_argument(
        "--cycles", type=int, default=None, help="pick-and-place cycles per episode (default: the scenario's)"
    )
    parser.add_argument(
        "--controllers",
        default=None,
        help="comma-separated controller keys, the built-in ones listed with their labels below, or your own as "
        "module:attr (README, 'Compare your own controller') (default: all built-in ones; without 'residual' when the "
        "residual policy was trained on another robot than the scenario's)",
    )
    parser.add_argument("--out", type=Path, default=None, help="run folder (default <runs root>/eval/<UTC time>)")
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    add_parameters_argument(parser)
    add_servo_argument(parser)
    parser.add_argument(
        "--calibration-episodes",
        type=int,
        default=DEFAULT_CALIBRATION_EPISODES,
        help=f"payload-free episodes of the tare (default {DEFAULT_CALIBRATION_EPISODES})",
    )
    add_residual_argument(parser)
    add_workers_argument(parser)
    parser.add_argument(
        "--video",
        action="store_true",
        help="also film the first episode of each row into the run folder (video_<key>.mp4; MUJOCO_GL=egl headless)",
    )
    return parser


def resolve(args: argparse.Namespace, parser: argparse.ArgumentParser) -> ComparisonConfig:
    """The configuration of the parsed command line ``args`` (left as they are); a bad value is a parser error."""
    try:
        controllers = parse_controller_keys(args.controllers or ",".join(CONTROLLER_LABELS))
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    scenario = scenario_from_arguments(args, parser)
    check_parameter_file(parser, args.parameters, scenario)
    check_ranges(parser, args, {"seed": 0, "episodes": 1, "cycles": 1, "calibration_episodes": 1, "workers": 1})
    check_episode_seeds(parser, args)
    if args.video and (error := video.rendering_error()) is not None:
        parser.error(f"--video: {error}")
    config = ComparisonConfig(
        **{
            **vars(args),
            "scenario": scenario,
            "cycles": scenario.task.n_cycles if args.cycles is None else args.cycles,
            "controllers": tuple(controllers),
        }
    )
    return _with_policy_base(parser, config, chosen=args.controllers is not None)


def parse_args(argv: Sequence[str] | None) -> ComparisonConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def _with_policy_base(parser: argparse.ArgumentParser, config: ComparisonConfig, *, chosen: bool) -> ComparisonConfig:
    """``config`` with its policy file's base recorded (when a row reads the policy file), or, when the policy was
    trained on another robot, without those rows if they were not ``chosen`` (else a parser error)."""
    policy_rows = [key for key in config.controllers if controller_entry(key).reads_policy_file]
    if not policy_rows:
        return config
    # Fail now, not after the other controllers have run. Only the settings are read here: the actor is read
    # by the workers that run the policy's episodes, which the comparison runs first.
    try:
        base = read_policy_settings(config.residual).base
    except (FileNotFoundError, ValueError) as error:
        parser.error(f"--residual: {error}")
    config = dataclasses.replace(
        config,
        residual_base=None if base is None else base.name,
        residual_base_moves=base is not None and bool(base.setup.empty_moves),
        residual_base_servo=None if base is None else base.setup.servo,
    )
    robot = config.scenario.plant
    if base is None:
        return config
    trained_on = _drives(base.setup.compliance is not None)
    here = _drives(robot.realism.compliance is not None)
    if (base.setup.geometry, base.setup.masses, trained_on) == (robot.geometry, robot.masses, here):
        return config
    rows = " and ".join(policy_rows)
    if not chosen:
        return dataclasses.replace(
            config,
            controllers=tuple(key for key in config.controllers if key not in policy_rows),
            left_out=f"The {rows} row{'s are' if len(policy_rows) > 1 else ' is'} left out: its policy "
            f"({config.residual.name}) was trained on another robot.",
        )
    parser.error(
        f"--residual: {config.residual} was trained on a robot with {base.setup.geometry}, "
        f"{base.setup.masses} and {trained_on}, not on this scenario's {robot.geometry}, {robot.masses} and "
        f"{here}; leave {' and '.join(repr(key) for key in policy_rows)} out of --controllers or train a policy "
        "on this robot (python -m eval.residual --scenario/--geometry)"
    )


def _drives(compliant: bool) -> str:
    """How a robot's drives are known to its controllers, in the words of the error above: a base that knows no
    compliance runs no notch and no deflection feedforward, and on compliant drives its loop rings."""
    return "compliant drives" if compliant else "rigid drives"


@command_main("python -m eval")
def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    config = parse_args(argv)
    with command_run_folder(
        "eval", "eval", argv, config, {"arguments": configuration_record(config)}, scenarios=[config.scenario]
    ) as run:
        compare(config, run, started)
    return 0


def compare(config: ComparisonConfig, run: Run, started: float) -> None:
    """Run the comparison of ``config`` (:func:`parse_args`) into ``run``'s folder and print its summary; ``started``
    is the :func:`time.perf_counter` time at the start of the command."""
    out, keys = run.folder, config.controllers
    config = dataclasses.replace(config, out=out)
    prepared, results = run_all(config)
    config = dataclasses.replace(config, parameters=prepared.parameter_file)
    # The figures are drawn beside the rest of this function, on the core the episodes' workers have left.
    with plots.Plotter(out, pool_context() if config.workers > 1 else None) as plotter:
        traces = first_episodes(results, keys, config.seed)
        np.savez_compressed(
            out / "traces.npz",
            dt=CONTROL_PERIOD,
            keys=np.array(list(traces)),
            labels=np.array([controller_label(key) for key in traces]),
            estimates_payload=np.array([controller_entry(key).estimates_payload for key in traces]),
            privileged=np.array([controller_entry(key).privileged for key in traces]),
            **{f"{key}.{name}": getattr(record, name) for key, record in traces.items() for name in plots.TRACE_FIELDS},
            **{
                f"{key}.{plots.REFERENCE_FIELD}": record.reference.xyz[1 : len(record.tracking_error) + 1]
                for key, record in traces.items()
            },
        )
        plotter.saved("traces.npz")
        table2_record = results[-1][1]
        model_torques = table2_record.model_torques(
            estimation_model(prepared.setup), prepared.calibration.tares[TABLE2_KEY]
        )
        np.savez_compressed(out / "table2_run.npz", **model_torques)
        table2_rows = table2_statistics(model_torques)
        write_csv(out / "table2.csv", table2_rows)
        plotter.saved("table2_run.npz", "table2.csv")
        episode_rows, carry_rows = tabulate(results, keys, config.seed)
        write_csv(out / "episodes.csv", episode_rows)
        plotter.saved("episodes.csv")
        if carry_rows:
            write_csv(out / "carries.csv", carry_rows)
        fault_rows = tabulate_faults(results, keys, config.seed)
        write_fault_csv(out / "faults.csv", fault_rows)
        plotter.saved("faults.csv")
        if fault_rows:
            write_confusion_csv(
                out / "confusion.csv", confusion_counts(fault_rows, [controller_label(k) for k in keys])
            )
        videos = _film(config, prepared) if config.video else []
        summary = _summarize(
            config, run, started, prepared, (episode_rows, carry_rows, table2_rows, fault_rows), videos=videos
        )
    print(summary)


def _film(config: ComparisonConfig, prepared: Prepared) -> list[video.Video]:
    """The videos of ``--video``: the first episode of each row, filmed into the run folder
    (:func:`eval.comparison.video.film_first_episodes`)."""
    keys = config.controllers
    with progress_bar(len(keys), "videos", "video") as progress:
        return video.film_first_episodes(
            config.scenario,
            prepared.setup,
            keys,
            config.seed,
            config.cycles,
            config.out,
            workers=config.workers,
            progress=progress,
        )


def _summarize(
    config: ComparisonConfig,
    run: Run,
    started: float,
    prepared: Prepared,
    rows: tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]],
    videos: Sequence[video.Video] = (),
) -> str:
    """Record the run's configuration and results in its manifest, write ``summary.md`` and return the summary.

    Args:
        config: The comparison's configuration, resolved: its run folder and parameter file known.
        run: The run folder.
        started: :func:`time.perf_counter` time at the start of the command.
        prepared: What the controllers knew (:func:`eval.comparison.run.run_all`).
        rows: The episode, carry, Table 2 and fault rows.
        videos: The videos of ``--video``.
    """
    out, scenario, keys = run.folder, config.scenario, config.controllers
    identification, setup = prepared.identification, prepared.setup
    tares, tare_spreads = prepared.calibration.tares, prepared.calibration.spreads
    episode_rows, carry_rows, table2_rows, fault_rows = rows
    total_time = time.perf_counter() - started
    task = scenario.task
    manifest = {
        "arguments": configuration_record(config),
        "scenario": {
            "name": scenario.name,
            "file": "scenario.toml",
            "content_hash": scenario.content_hash,
            "robot_identity": scenario.robot_identity,
        },
        "episode_seeds": [config.seed + i for i in range(config.episodes)],
        "calibration_seeds": calibration_seeds(config.calibration_episodes),
        "tares": str(kept_tares(scenario, config.runs_dir)),
        "env": {
            "id": "DeltaPickPlace-v0",
            "n_cycles": config.cycles,
            "cycle": task.cycle,
            "start": task.start,
            "peak_acceleration_m_s2": float(task.peak_acceleration),
            "payload_mass_range_kg": [float(mass) for mass in task.payload_mass_range],
            "plant": repr(scenario.effective_plant),
        },
        "controllers": {key: controller_label(key) for key in keys},
        "pd_gains": {"kp_nm_per_rad": setup.pd_gains[0], "kd_nm_s_per_rad": setup.pd_gains[1]},
        "servo": setup.servo,
        "identification": {
            "path": str(config.parameters),
            "mid": dataclasses.asdict(identification.mid),
            "mid_f": dataclasses.asdict(identification.mid_f),
            "mid_f_rods": dataclasses.asdict(identification.mid_f_rods),
            "provenance": identification.provenance,
        },
        "table2": {"controller": controller_label(TABLE2_KEY), "seed": config.seed, "payload_kg": TABLE2_PAYLOAD},
    }
    results_entry = {
        "tare_kg": tares,
        "tare_spread_kg": tare_spreads,
        "seconds": {"total": total_time},
        "videos": [item.path.name for item in videos],
    }
    run.record(config=manifest, results=results_entry)

    summary = "\n".join(
        [
            f"# Controller comparison, scenario {scenario.name}: {plural(config.episodes, 'episode')} x "
            f"{plural(config.cycles, 'cycle')} from seed {config.seed}",
            "",
            f"Scenario {scenario.name} ({scenario.description or 'no description'}); robot {scenario.robot_identity}, "
            f"identified in {config.parameters}.",
            "",
            "Mean ± std over episodes (diverged ones counted, their metrics cover the steps before divergence and "
            "are left out of the means). Payload columns: objects >= 0.5 kg. The oracle knows the plant and the "
            "payloads: a bound, not a controller.",
            "",
            FEEDBACK_LINES[config.servo],
            "",
            controller_table(episode_rows, carry_rows),
            "",
            *pick_rate_section(episode_rows),
            *payload_target_section(carry_rows),
            f"## Table 2 analogue: {controller_label(TABLE2_KEY)}, every object {TABLE2_PAYLOAD} kg, "
            "tau_measured - tau_MId+F+R",
            "",
            table2_table(table2_rows),
            "",
            "Tare (apparent payload of the empty gripper): "
            + ", ".join(f"{controller_label(k)} {tares[k]:+.3f} kg (spread {tare_spreads[k]:.3f})" for k in tares),
            "",
            *fault_section(fault_rows, [controller_label(key) for key in keys]),
            *bound_section(episode_rows),
            *residual_section(config, episode_rows),
            *([config.left_out, ""] if config.left_out else []),
            *(["", "## Videos", "", *video.video_lines(videos), ""] if videos else []),
            f"Run folder: {out} ({total_time:.0f} s)",
        ]
    )
    (out / "summary.md").write_text(summary + "\n")
    return summary


if __name__ == "__main__":
    sys.exit(main())
