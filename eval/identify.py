"""``python -m eval.identify``: identify MId, MId+F and MId+F+R on the plant and write a validation report.

The plant is the robot of ``--scenario`` (and ``--geometry``); its condition (wear) and task do not enter:
an identification belongs to the robot. Runs :func:`eval.identification.run_identification`, writes the
parameter file into the run folder and (unless ``--no-install``) to the path the controllers of that robot
load (``<runs root>/identification/<robot identity>/parameters.json``; :func:`eval.run_folder.runs_root`; for
the default settings only: :func:`eval.parameter_files.install_path`, else ``--parameters`` if given), the
scenario (``scenario.toml``), the manifest (``config.json``), the held-out validation data, a Markdown report and the
figures (made from the saved data), and prints the report. ``--save-logs DIR`` also writes what the drive recorded
along every run as log files (:mod:`controllers.identification.logs`; ``--log-format mcap`` or ``sqlite3``: ROS 2
bags, :mod:`controllers.identification.bags`) and the robot file ``robot.toml``. ``--quick`` is a smoke run of a
few seconds (:data:`QUICK`), said on the console and in the report, recorded in ``config.json`` and written to the
run folder only: it never replaces the robot's parameter file, which ``python -m eval`` loads.

With ``--log FILE [FILE ...] --robot ROBOT.toml`` nothing is simulated: the robot is identified from its logs
alone (:func:`eval.identification.identify_logs`, the same fits), the last log held out for the report (a log is a
CSV or Parquet table or a ROS 2 bag; ``--topic``, ``--joint-names`` and ``--command-topic`` say what to read from
a bag); the parameter file goes to the run folder (and to ``--parameters`` if given) and records the identity of
the robot file, which ``python -m eval --parameters FILE`` accepts for a scenario on that robot
(``--geometry ROBOT.toml``).

The report (:mod:`eval.identification_report`) of a simulation compares the identified friction and drive lag with
the plant's true values: the only place that reads the plant's truth, labelled as ground truth for the report; the
identification never sees it. Logs come with no truth.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections.abc import Callable
from pathlib import Path

from controllers.identification import BAG_SUFFIXES, save_result, write_log
from controllers.identification.bags import JOINT_COMMANDS_TOPIC, JOINT_STATES_TOPIC, BagTopics, is_bag
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.scenario import save_robot
from eval.console import CommandParser, command_main, resolved_arguments
from eval.excitation import DEFAULT_DURATION, VALIDATION_DURATION
from eval.identification import DEFAULT_TRAJECTORIES, IdentificationRun, identify_logs, run_identification
from eval.identification_report import ground_truth, plot_figures, render_report, save_validation_data
from eval.parameter_files import DEFAULT_SETTINGS, describe_settings, identification_root, install_path, parameter_path
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    command_line,
    command_run_folder,
    utc_stamp,
)
from eval.scenario_args import add_scenario_arguments, scenario_from_arguments

DURATION_RANGE = (1.0, 600.0)
"""Allowed lengths (s) of a simulated trajectory: 1 s leaves 900 samples after the trimmed ends."""

LOG_FORMATS = {"csv": ".csv", "parquet": ".parquet", "mcap": ".mcap", "sqlite3": ".db3"}
"""``--log-format``: file ending of each log format (MCAP and sqlite3: ROS 2 bags,
:mod:`controllers.identification.bags`)."""

QUICK = {"trajectories": 3, "duration": 3.0, "validation_duration": 3.0, "workers": 1}
"""Settings of ``--quick`` (a smoke run in seconds, rough parameters), unless given explicitly; one process, as
starting a second costs more than the four short runs it would share."""

BAG_OPTIONS = ("topic", "joint_names", "command_topic")
"""Options that say what to read from the ROS 2 bags among the ``--log`` files."""

SIMULATION_OPTIONS = (
    "seed",
    "trajectories",
    "duration",
    "validation_duration",
    "geometry",
    "save_logs",
    "log_format",
    "no_install",
    "quick",
)
"""Options that only a simulated identification takes; with ``--log`` they are errors (a log-identified file is
installed only where ``--parameters`` says)."""


def _number_in(kind: Callable[[str], float], low: float, high: float, unit: str = "") -> Callable[[str], float]:
    """An argparse type: ``kind(text)`` if in [low, high], else an error naming the value and the range."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            expected = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"must be {expected}, got {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            suffix = f" {unit}" if unit else ""
            raise argparse.ArgumentTypeError(f"must lie in [{low:g}, {high:g}]{suffix}, got {text}")
        return value

    return parse


def _describe_quick() -> str:
    return ", ".join(f"--{name.replace('_', '-')} {value:g}" for name, value in QUICK.items())


def _joint_names(text: str) -> tuple[str, str, str]:
    """An argparse type: three distinct joint names separated by commas."""
    names = tuple(name.strip() for name in text.split(","))
    if len(names) != 3 or len(set(names)) != 3 or not all(names):
        raise argparse.ArgumentTypeError(f"must be three distinct joint names a,b,c (joints 1, 2, 3), got {text!r}")
    return names


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    parser = CommandParser(prog="python -m eval.identify", description=__doc__.splitlines()[0])
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of trajectories and sensor noise")
    parser.add_argument(
        "--trajectories",
        type=_number_in(int, 1, 1000),
        default=DEFAULT_TRAJECTORIES,
        help="excitation trajectories, 1 to 1000",
    )
    parser.add_argument(
        "--duration",
        type=_number_in(float, *DURATION_RANGE, "s"),
        default=DEFAULT_DURATION,
        help=f"length of each trajectory (s), {DURATION_RANGE[0]:g} to {DURATION_RANGE[1]:g}",
    )
    parser.add_argument(
        "--validation-duration",
        type=_number_in(float, *DURATION_RANGE, "s"),
        default=VALIDATION_DURATION,
        help=f"held-out stress trajectory (s), {DURATION_RANGE[0]:g} to {DURATION_RANGE[1]:g}",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"a smoke run in seconds with rough parameters ({_describe_quick()}, unless given), written to the "
        "run folder only, never as the robot's identification",
    )
    parser.add_argument(
        "--save-logs",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write each simulated run as the drive would log it (excitation_NN and, last, validation) and the "
        "robot file robot.toml into DIR",
    )
    parser.add_argument(
        "--log-format",
        choices=list(LOG_FORMATS),
        default="csv",
        help="format of --save-logs (default csv); mcap and sqlite3 write ROS 2 bags (JointState on "
        f"{JOINT_STATES_TOPIC}, commands on {JOINT_COMMANDS_TOPIC})",
    )
    parser.add_argument(
        "--log",
        type=Path,
        nargs="+",
        default=None,
        metavar="FILE",
        help="identify from these logs (CSV, Parquet or ROS 2 bags: .mcap, .db3 or rosbag2 folders; at least 2, the "
        "last one is held out for the report) instead of simulating; needs --robot",
    )
    parser.add_argument(
        "--topic",
        default=JOINT_STATES_TOPIC,
        help=f"bags: the sensor_msgs/msg/JointState topic of the measured joints (default {JOINT_STATES_TOPIC})",
    )
    parser.add_argument(
        "--joint-names",
        type=_joint_names,
        default=None,
        metavar="A,B,C",
        help="bags: the JointState names of joints 1, 2, 3 (default: the first message's first three names)",
    )
    parser.add_argument(
        "--command-topic",
        default=None,
        help="bags: a sensor_msgs/msg/JointState topic whose effort is the commanded torque (default: no commands; "
        f"--save-logs writes {JOINT_COMMANDS_TOPIC})",
    )
    parser.add_argument(
        "--robot", type=Path, default=None, help="robot file of the logs ([geometry] in m, [masses] in kg)"
    )
    parser.add_argument(
        "--workers", type=_number_in(int, 1, 64), default=None, help="processes (default: up to 2 cores)"
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="run folder (default <runs root>/identification/<UTC time>_seed<seed>)"
    )
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    parser.add_argument(
        "--parameters",
        type=Path,
        default=None,
        help="parameter file the controllers load (default: <runs root>/identification/<robot identity>/"
        "parameters.json, only for the default --trajectories, --duration, --validation-duration and --seed; "
        "otherwise, and with --log, the run folder's only)",
    )
    parser.add_argument("--no-install", action="store_true", help="write the parameters to the run folder only")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    arguments = parser.parse_args(argv)
    bag_options = [name for name in BAG_OPTIONS if getattr(arguments, name) != parser.get_default(name)]
    if bag_options and not any(map(is_bag, arguments.log or ())):
        names = ", ".join("--" + name.replace("_", "-") for name in bag_options)
        parser.error(f"{names} say what to read from ROS 2 bags; no --log file is a bag (.mcap, .db3 or a folder)")
    if arguments.quick and arguments.log is None:
        if arguments.parameters is not None:
            parser.error("--quick writes its rough parameters to the run folder only; drop --parameters")
        # an explicit setting wins over --quick
        quick = {name: value for name, value in QUICK.items() if getattr(arguments, name) == parser.get_default(name)}
        arguments = resolved_arguments(arguments, **quick, no_install=True)
    if arguments.log is None:
        if arguments.robot is not None:
            parser.error("--robot names the robot of --log files; without --log the robot is the scenario's")
        scenario = scenario_from_arguments(arguments, parser)
        own = parameter_path(scenario.plant, identification_root(arguments.runs_dir))
        settings = simulation_settings(arguments)
        if arguments.parameters is None:
            parameters = install_path(scenario.plant, settings, identification_root(arguments.runs_dir))
        elif arguments.parameters.resolve() == own.resolve() and settings != DEFAULT_SETTINGS:
            parser.error(
                f"--parameters {arguments.parameters} is the robot's own identification, which holds the default "
                f"settings ({describe_settings(DEFAULT_SETTINGS)}), not {describe_settings(settings)}; name another "
                "file"
            )
        else:
            parameters = arguments.parameters
        return resolved_arguments(arguments, scenario=scenario, parameters=parameters)
    given = [name for name in SIMULATION_OPTIONS if getattr(arguments, name) != parser.get_default(name)]
    if arguments.scenario != parser.get_default("scenario"):
        given.insert(0, "scenario")
    if given:
        names = ", ".join("--" + name.replace("_", "-") for name in given)
        parser.error(f"--log identifies from files; {names} {'is' if len(given) == 1 else 'are'} for a simulation")
    if arguments.robot is None:
        parser.error("--log needs --robot ROBOT.toml, the robot file of the logs ([geometry] in m, [masses] in kg)")
    if len(arguments.log) < 2:
        parser.error(f"--log needs at least 2 files (the last one is held out), got {len(arguments.log)}")
    return resolved_arguments(arguments, scenario=None)


def simulation_settings(arguments: argparse.Namespace) -> dict[str, float]:
    """The settings of a simulated identification (:data:`eval.parameter_files.DEFAULT_SETTINGS`' keys) given by
    ``arguments``."""
    return {
        "trajectories": arguments.trajectories,
        "duration_s": arguments.duration,
        "validation_duration_s": arguments.validation_duration,
        "seed": arguments.seed,
    }


def save_logs(run: IdentificationRun, geometry: DeltaGeometry, masses: DeltaMasses, folder: Path, suffix: str) -> Path:
    """Write the run's logs as a robot's logger would (excitation_01 ... and, last, validation) and the robot file
    ``robot.toml``, what ``--log`` and ``--robot`` read; returns the robot file."""
    *excitation, validation = run.logs
    digits = max(2, len(str(len(excitation))))  # the names sort in run order, the held-out one last
    for index, log in enumerate(excitation, start=1):
        write_log(log, folder / f"excitation_{index:0{digits}d}{suffix}")
    write_log(validation, folder / f"validation{suffix}")
    return save_robot(geometry, masses, folder / "robot.toml")


@command_main("python -m eval.identify")
def main(argv: list[str] | None = None) -> int:
    arguments = parse_arguments(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command = command_line("eval.identify", argv)
    if arguments.quick:
        print(
            f"Quick identification (--quick): {arguments.trajectories} excitation "
            f"{'trajectory' if arguments.trajectories == 1 else 'trajectories'} of "
            f"{arguments.duration:g} s and a {arguments.validation_duration:g} s held-out one, not "
            f"{DEFAULT_TRAJECTORIES} of {DEFAULT_DURATION:g} s and {VALIDATION_DURATION:g} s: rough parameters, "
            "written to the run folder only (never as the robot's identification)."
        )
    if arguments.log:
        try:
            run = identify_logs(
                arguments.log,
                arguments.robot,
                workers=arguments.workers or 1,
                progress=not arguments.no_progress,
                topics=BagTopics(arguments.topic, arguments.joint_names, arguments.command_topic),
            )
        except ValueError as error:  # a bad log or robot file, or logs that do not excite the model
            print(f"python -m eval.identify: error: {error}", file=sys.stderr)
            return 2
        config = {**vars(arguments), "robot_identity": run.result.provenance["plant"]["identity"]}
        scenarios, stamp = [], f"{utc_stamp()}_logs"
    else:
        run, scenario = None, arguments.scenario
        config = {**vars(arguments), "scenario": scenario.name, "robot_identity": scenario.robot_identity}
        scenarios, stamp = [scenario], f"{utc_stamp()}_seed{arguments.seed}"
    with command_run_folder(
        "identification", "eval.identify", argv, arguments, config, scenarios=scenarios, stamp=stamp
    ) as run_dir:
        run_dir.record(config={**config, "out": run_dir.folder})
        identify_into(arguments, run_dir, command, run)
    return 0


def identify_into(arguments: argparse.Namespace, run_dir: Run, command: str, run: IdentificationRun | None) -> None:
    """Identify the robot of ``arguments`` (:func:`parse_arguments`), or take ``run``, its identification from logs,
    and write the parameters, the validation data, the figures and the report into the run folder, the method into
    its manifest; print the report."""
    folder = run_dir.folder
    if run is not None:
        plant = run.result.provenance["plant"]
        save_robot(DeltaGeometry(**plant["geometry_m"]), DeltaMasses(**plant["masses_kg"]), folder / "robot.toml")
        truth, install = None, arguments.parameters
    else:
        scenario = arguments.scenario
        run = run_identification(
            arguments.trajectories,
            arguments.seed,
            arguments.duration,
            validation_duration=arguments.validation_duration,
            progress=not arguments.no_progress,
            workers=arguments.workers,
            plant=scenario.plant,
        )
        if arguments.save_logs is not None:
            suffix = LOG_FORMATS[arguments.log_format]
            save_logs(run, scenario.plant.geometry, scenario.plant.masses, arguments.save_logs, suffix)
            if suffix in BAG_SUFFIXES:
                print(
                    f"The runs are ROS 2 bags: JointState on {JOINT_STATES_TOPIC}, commands on {JOINT_COMMANDS_TOPIC} "
                    f"(--log ... --command-topic {JOINT_COMMANDS_TOPIC} reads them back)."
                )
        truth = ground_truth(scenario.plant)
        install = None if arguments.no_install else arguments.parameters
    save_result(run.result, folder / "parameters.json")
    if install is not None:
        save_result(run.result, install)
    run_dir.record(method=run.result.provenance["method"])

    validation_file = folder / "validation.npz"
    save_validation_data(run, validation_file)
    figures = plot_figures(validation_file, folder)
    report = render_report(run, validation_file, command, figures, truth)
    if arguments.quick:
        report += "\nA quick run (--quick): rough parameters from little data, not the robot's identification.\n"
    (folder / "report.md").write_text(report)
    print(report)
    written = "" if install is None else f" and {install}"
    if install is None and truth is not None and not arguments.no_install:
        written += (
            " (not installed as the robot's identification: made with "
            f"{describe_settings(simulation_settings(arguments))}, not the defaults "
            f"{describe_settings(DEFAULT_SETTINGS)}; --parameters FILE installs it there)"
        )
    if arguments.save_logs is not None:
        written += f"; the logs and robot.toml in {arguments.save_logs}/"
    print(f"Wrote {folder}/ (parameters.json, config.json, report.md, figures){written}.")


if __name__ == "__main__":
    sys.exit(main())
