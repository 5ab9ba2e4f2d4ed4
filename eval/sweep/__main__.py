"""``python -m eval.sweep``: every controller on every scenario over many seeds, locally or on Ray.

The grid is scenarios x controllers x seeds; each cell is one episode (:func:`eval.sweep.work.run_unit`).
The run folder (``--out``, by default ``<runs root>/sweep/sweep-<hash of the grid>`` so that the same arguments find
the same folder; :func:`eval.run_folder.runs_root`) holds:

- ``results.csv``: one row per episode (scenario, controller, seed, status, error, every metric, the faults'
  counts and detection latencies included: :data:`eval.fault_scores.FAULT_METRICS`),
  appended as each episode finishes; rerun the same command after an interruption and only the missing
  episodes run. An episode's key holds what decides its result and nothing of how it ran (backend, workers,
  host): a rerun on another backend of a finished sweep runs nothing and says so; ``--force`` runs the grid again
  (its old rows are dropped);
- ``summary.csv`` and ``summary.md``: per scenario and controller, mean, std and 95 % interval;
- ``plots/summary.png``: tracking and torque RMS per scenario and controller;
- ``config.json`` (the manifest of the last command: resolved configuration, code version, package versions, the
  command, the tares, status, start and end times) and ``commands.log`` (every command that wrote to the folder),
  ``scenarios/<name>.toml`` (each scenario resolved, every field; ``scenario.toml`` for a grid of one).

Controllers know the identification of each scenario's robot (one per robot identity, identified once and
kept in ``<runs root>/identification/<identity>/``; ``worn`` and ``randomized`` share the nominal robot's) and
the tares of their payload estimators measured on that scenario (:mod:`eval.calibration`), before the grid runs:
measured once and kept beside the identification (:func:`eval.engine.kept_tares`), so that every seed of the grid,
a rerun and ``python -m eval`` on the same scenario use the same tare.

With ``--geometry FILE`` every scenario runs on the robot of that geometry file (as on the other command
lines: masses scaled with the lengths, a new robot identified once), named ``<scenario>+<file stem>``.

Usage: python -m eval.sweep --scenarios nominal,stress-6g,randomized --controllers pd,mid_f_rls --seed 0 --episodes 10
           [--geometry FILE] [--backend local|ray] [--address auto|ray://host:port] [--workers 2] [--cycles N]
           [--out DIR] [--runs-dir DIR] [--force]

The seeds are ``--seed`` to ``--seed + --episodes - 1``, as on the other command lines.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from controllers.registry import controller_label, controllers_help, parse_controller_keys
from controllers.residual import DEFAULT_POLICY_PATH
from delta_env.scenario import Scenario, preset_names, resolve_scenario
from eval.console import CommandParser, UsageError, command_main, plural, progress_bar
from eval.engine import prepare
from eval.fault_tables import sweep_fault_table
from eval.identification.parameter_files import identification_root, parameter_path
from eval.processes import import_ray
from eval.run_folder import (
    Run,
    add_runs_dir_argument,
    command_run_folder,
    configuration_record,
    runs_root,
    write_csv,
)
from eval.scenario_args import (
    add_geometry_argument,
    add_servo_argument,
    add_workers_argument,
    check_episode_seeds,
    check_ranges,
    on_geometry,
)
from eval.sweep import report
from eval.sweep.runner import ResultsTable, run_sweep, unit_key
from eval.sweep.work import setup_digest
from eval.work import WorkUnit, code_version


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """The resolved configuration of a sweep (``python -m eval.sweep``).

    Attributes:
        scenarios: The grid's scenarios, on ``geometry``'s robot and with ``cycles`` cycles when given.
        controllers: The grid's controller keys.
        seed: Seed of the first episode.
        episodes: Episodes per scenario and controller.
        cycles: ``--cycles``, or None (each scenario's).
        backend: ``local`` or ``ray``.
        address: The Ray cluster to join, or None.
        workers: Local processes, or the CPUs of a Ray started here.
        out: The run folder (by default named by the grid's hash).
        runs_dir: ``--runs-dir``, or None.
        force: Run every episode again.
        residual: The policy file of the ``residual`` row.
        servo: Feedback of the model rows (:data:`controllers.setup.SERVOS`).
        geometry: The geometry file of ``--geometry``, or None.
    """

    scenarios: tuple[Scenario, ...]
    controllers: tuple[str, ...]
    seed: int
    episodes: int
    cycles: int | None
    backend: str
    address: str | None
    workers: int
    out: Path
    runs_dir: Path | None
    force: bool
    residual: Path
    servo: str
    geometry: str | None

    @property
    def seeds(self) -> list[int]:
        """The episodes' seeds: ``seed`` to ``seed + episodes - 1``."""
        return list(range(self.seed, self.seed + self.episodes))


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    parser = CommandParser(
        prog="python -m eval.sweep", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scenarios", default="nominal", help=f"comma-separated presets ({', '.join(preset_names())}) or TOML files"
    )
    parser.add_argument("--controllers", default="pd,mid_f_rls", help=controllers_help("pd,mid_f_rls"))
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument(
        "--episodes", type=int, default=10, help="episodes per scenario and controller, from --seed (default 10)"
    )
    parser.add_argument("--cycles", type=int, default=None, help="override every scenario's cycles per episode")
    parser.add_argument("--backend", choices=("local", "ray"), default="local", help="local process pool or Ray")
    parser.add_argument("--address", default=None, help="Ray cluster to join: auto or ray://host:port (ray only)")
    add_workers_argument(
        parser,
        help="local processes, or the CPUs of a Ray started here (default: up to 2); a joined cluster uses all CPUs",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="run folder (default <runs root>/sweep/sweep-<grid hash>)"
    )
    add_runs_dir_argument(parser)
    parser.add_argument("--force", action="store_true", help="run every episode again, even those already done")
    parser.add_argument("--residual", type=Path, default=DEFAULT_POLICY_PATH, help="policy of the 'residual' row")
    add_servo_argument(parser)
    add_geometry_argument(parser)
    return parser


def resolve(args: argparse.Namespace, parser: argparse.ArgumentParser) -> SweepConfig:
    """The configuration of the parsed command line ``args`` (left as they are); a bad value is a parser error."""
    check_ranges(parser, args, {"seed": 0, "episodes": 1, "cycles": 1, "workers": 1})
    check_episode_seeds(parser, args)
    try:
        scenarios = [resolve_scenario(spec.strip()) for spec in args.scenarios.split(",") if spec.strip()]
        if args.geometry is not None:
            scenarios = [on_geometry(scenario, args.geometry) for scenario in scenarios]
        if args.cycles is not None:
            scenarios = [
                dataclasses.replace(s, task=dataclasses.replace(s.task, n_cycles=args.cycles)) for s in scenarios
            ]
    except ValueError as error:
        parser.error(str(error))
    names = [scenario.name for scenario in scenarios]
    if not scenarios or len(set(names)) != len(names):
        parser.error(f"--scenarios must name distinct scenarios, got {names}")
    try:
        controllers = parse_controller_keys(args.controllers)
    except ValueError as error:
        parser.error(f"--controllers: {error}")
    if args.address is not None and args.backend != "ray":
        parser.error("--address needs --backend ray")
    config = SweepConfig(**{**vars(args), "scenarios": tuple(scenarios), "controllers": tuple(controllers)})
    if args.out is None:
        grid = {
            "scenarios": [s.content_hash for s in scenarios],
            "controllers": controllers,
            "seeds": config.seeds,
        }
        digest = hashlib.sha256(json.dumps(grid, sort_keys=True).encode()).hexdigest()[:10]
        config = dataclasses.replace(config, out=runs_root(args.runs_dir) / "sweep" / f"sweep-{digest}")
    if config.backend == "ray" and not (config.out / "results.csv").exists():  # a new sweep: all of it needs Ray
        _require_ray(parser)
    return config


def parse_args(argv: Sequence[str] | None) -> SweepConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def _require_ray(parser: argparse.ArgumentParser) -> None:
    """A parser error naming the extra to install when Ray is missing."""
    try:
        import_ray()
    except ImportError as error:
        parser.error(str(error))


@command_main("python -m eval.sweep")
def main(argv: Sequence[str] | None = None) -> int:
    config = parse_args(argv)
    grid = {"scenarios": [s.name for s in config.scenarios], "controllers": config.controllers, "seeds": config.seeds}
    backend = {"name": config.backend, "address": config.address, "workers": config.workers}
    with command_run_folder(
        "sweep",
        "eval.sweep",
        argv,
        config,
        {"arguments": configuration_record(config), "grid": grid, "backend": backend},
        scenarios=config.scenarios,
        reuse=True,  # a sweep resumes in its folder
    ) as run:
        sweep(config, run)
    return 0


def sweep(config: SweepConfig, run: Run) -> None:
    """Run the sweep of ``config`` (:func:`parse_args`) into ``run``'s folder, the rows already there skipped unless
    ``--force``; write the summary and print it."""
    out = run.folder
    with (out / "commands.log").open("a") as log:
        log.write(run.manifest["command"] + "\n")
    setups = {
        s.content_hash: prepare(
            s,
            config.controllers,
            runs_dir=config.runs_dir,
            workers=config.workers,
            residual_policy=config.residual,
            servo=config.servo,
        ).setup
        for s in config.scenarios
    }
    version = code_version()
    digests = {
        (content, key): setup_digest(setup, key) for content, setup in setups.items() for key in config.controllers
    }
    units = [WorkUnit(s, key, seed) for s in config.scenarios for key in config.controllers for seed in config.seeds]
    manifest = {
        "arguments": configuration_record(config),
        "grid": {
            "scenarios": {
                s.name: {
                    "content_hash": s.content_hash,
                    "robot_identity": s.robot_identity,
                    "setup_digests": {key: digests[s.content_hash, key] for key in config.controllers},
                    "tares_kg": dict(setups[s.content_hash].tares),
                }
                for s in config.scenarios
            },
            "controllers": {key: controller_label(key) for key in config.controllers},
            "seeds": config.seeds,
            "episodes": len(units),
        },
        "backend": {"name": config.backend, "address": config.address, "workers": config.workers},
        "code_version": version,
        "identifications": {
            s.name: str(parameter_path(s.plant, identification_root(config.runs_dir))) for s in config.scenarios
        },
        "residual_policy": str(config.residual),
        "pd_gains": list(next(iter(setups.values())).pd_gains),
    }
    run.record(config=manifest)

    table = ResultsTable(out / "results.csv")
    keys = {unit_key(unit, version, digests[unit.scenario.content_hash, unit.controller]) for unit in units}
    if config.force:
        table.drop(keys)
    done = keys <= {row["key"] for row in table.load()}
    if config.backend == "ray" and not done:
        try:
            import_ray()
        except ImportError as error:
            raise UsageError(str(error)) from None
    with progress_bar(len(units), "sweep", "ep") as progress:
        counts = run_sweep(
            units,
            setups,
            table,
            version,
            digests,
            backend=config.backend,
            workers=config.workers,
            address=config.address,
            progress=progress,
        )

    rows = [row for row in table.load() if row["key"] in keys]
    summary = report.summarize(rows, [s.name for s in config.scenarios], config.controllers)
    write_csv(out / "summary.csv", summary)
    text = "\n".join(
        [
            f"# Sweep: {plural(len(config.scenarios), 'scenario')} x {plural(len(config.controllers), 'controller')} x "
            f"{plural(len(config.seeds), 'seed')}",
            "",
            "Mean ± 95 % CI half-width over the episodes that neither failed nor diverged.",
            "",
            report.markdown(summary),
            "",
            f"Ran {plural(counts['ran'], 'episode')} ({counts['failed']} failed), {counts['skipped']} already in the "
            "table.",
        ]
    )
    faults = sweep_fault_table(rows, {key: controller_label(key) for key in config.controllers})
    if faults:
        text += "\n\n## Faults\n\nPer controller and fault kind, over the sweep's episodes (a detection of the "
        text += "fault's kind from its start to 50 ms after its end; docs/design.md section 8).\n\n" + faults
    (out / "summary.md").write_text(text + "\n")
    report.plot(summary, out / "plots" / "summary.png")
    if done:
        text += (
            f"\n\nNothing to run: all {plural(len(units), 'episode')} of this grid were already in {table.path} (an "
            "episode's key holds what decides its result, not the backend, workers or host that ran it); --force runs "
            "them again."
        )
    print(f"{text}\n\nRun folder: {out}")


if __name__ == "__main__":
    sys.exit(main())
