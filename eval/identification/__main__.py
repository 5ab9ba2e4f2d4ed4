"""``python -m eval.identification``: identify MId, MId+F and MId+F+R on the plant and write a validation report.

The plant is the robot of ``--scenario`` (and ``--geometry``); its condition (wear) and task do not enter:
an identification belongs to the robot. Runs :func:`eval.identification.run.run_identification`, writes the
parameter file into the run folder and (unless ``--no-install``) to the path the controllers of that robot
load (``<runs root>/identification/<robot identity>/parameters.json``; :func:`eval.run_folder.runs_root`; for
the default settings only: :func:`eval.identification.parameter_files.install_path`, else ``--parameters`` if given),
the scenario (``scenario.toml``), the manifest (``config.json``), the held-out validation data, a Markdown report and
the figures (made from the saved data), and prints the report. ``--save-logs DIR`` also writes what the drive recorded
along every run as log files (:mod:`controllers.identification.logs`; ``--log-format mcap`` or ``sqlite3``: ROS 2
bags, :mod:`controllers.identification.bags`) and the robot file ``robot.toml``. ``--quick`` is a smoke run of a
few seconds (:data:`QUICK`), said on the console and in the report, recorded in ``config.json`` and written to the
run folder only: it never replaces the robot's parameter file, which ``python -m eval`` loads.

With ``--log FILE [FILE ...] --robot ROBOT.toml`` nothing is simulated: the robot is identified from its logs
alone (:func:`eval.identification.run.identify_logs`, the same fits), the last log held out for the report (a log is a
CSV or Parquet table or a ROS 2 bag; ``--topic``, ``--joint-names`` and ``--command-topic`` say what to read from
a bag; ``--compliance-log`` the compliance excitation's tables of compliant drives, ``--torque-age`` the age of the
drive's torque readings); the parameter file goes to the run folder (and to ``--parameters`` if given) and records
the identity of the robot file, which ``python -m eval --parameters FILE`` accepts for a scenario on that robot
(``--geometry ROBOT.toml``).

The report (:mod:`eval.identification.report`) of a simulation compares the identified friction and drive lag with
the plant's true values: the only place that reads the plant's truth, labelled as ground truth for the report; the
identification never sees it. Logs come with no truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from controllers.identification import BAG_SUFFIXES, save_result, write_log
from controllers.identification.bags import JOINT_COMMANDS_TOPIC, JOINT_STATES_TOPIC, BagTopics, is_bag
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.scenario import Scenario, save_robot
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY, require_torque_age
from eval.console import CommandParser, command_main, resolved_arguments
from eval.identification.excitation import DEFAULT_DURATION, VALIDATION_DURATION
from eval.identification.parameter_files import (
    DEFAULT_SETTINGS,
    describe_settings,
    identification_root,
    install_path,
    parameter_path,
)
from eval.identification.report import ground_truth, plot_figures, render_report, save_validation_data
from eval.identification.run import DEFAULT_TRAJECTORIES, IdentificationRun, identify_logs, run_identification
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    command_run_folder,
    configuration_record,
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


def _torque_age(text: str) -> float:
    """An argparse type: a torque reading's age (s), :func:`~delta_env.sensors.require_torque_age`."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    try:
        return require_torque_age(value)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _joint_names(text: str) -> tuple[str, str, str]:
    """An argparse type: three distinct joint names separated by commas."""
    names = tuple(name.strip() for name in text.split(","))
    if len(names) != 3 or len(set(names)) != 3 or not all(names):
        raise argparse.ArgumentTypeError(f"must be three distinct joint names a,b,c (joints 1, 2, 3), got {text!r}")
    return names


@dataclasses.dataclass(frozen=True)
class IdentifyConfig:
    """The resolved configuration of an identification (``python -m eval.identification``), recorded as it is in the
    run's manifest (:func:`eval.run_folder.configuration_record`); the options are described by ``--help``.

    Attributes:
        scenario: The scenario whose robot is simulated (on ``geometry``'s robot), or None with ``log``.
        geometry: The geometry file of ``--geometry``, or None.
        release: ``--release``, or None.
        seed: Seed of the trajectories and the sensor noise.
        trajectories: Excitation trajectories (``--quick``'s unless given).
        duration: Length of each trajectory (s).
        validation_duration: Length of the held-out stress trajectory (s).
        quick: A smoke run (:data:`QUICK`), written to the run folder only.
        save_logs: The folder of ``--save-logs``, or None.
        log_format: The format of ``--save-logs`` (:data:`LOG_FORMATS`).
        log: The logs identified from instead of a simulation, the held-out one last; or None.
        topic: Bags: the JointState topic of the measured joints.
        joint_names: Bags: the names of joints 1, 2, 3, or None.
        command_topic: Bags: the topic of the commanded torques, or None.
        robot: The robot file of ``log``, or None.
        compliance_log: Logs of the compliance excitation to identify compliant drives on (with ``log``), or None.
        torque_age: Age of the logs' torque readings against their angles (s), with ``log`` (the default physics
            step's unless given); None for a simulation, which knows its own.
        workers: Processes, or None (up to 2 cores).
        out: The run folder: ``--out`` until the folder is made, then the folder.
        force: Write into an existing, non-empty ``out``.
        runs_dir: ``--runs-dir``, or None.
        parameters: Where the parameter file is installed besides the run folder, or None (run folder only).
        no_install: Write the parameters to the run folder only.
        no_progress: Hide the progress bar.
        robot_identity: The identified robot's identity: the scenario's, or, from logs, the robot file's once the
            logs are read (None until then).
    """

    scenario: Scenario | None
    geometry: str | None
    release: str | None
    seed: int
    trajectories: int
    duration: float
    validation_duration: float
    quick: bool
    save_logs: Path | None
    log_format: str
    log: tuple[Path, ...] | None
    topic: str
    joint_names: tuple[str, str, str] | None
    command_topic: str | None
    robot: Path | None
    compliance_log: tuple[Path, ...] | None
    torque_age: float | None
    workers: int | None
    out: Path | None
    force: bool
    runs_dir: Path | None
    parameters: Path | None
    no_install: bool
    no_progress: bool
    robot_identity: str | None


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    parser = CommandParser(prog="python -m eval.identification", description=__doc__.splitlines()[0])
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
        "--compliance-log",
        type=Path,
        nargs="+",
        default=None,
        metavar="FILE",
        help="with --log: the compliance excitation's logs (CSV or Parquet, all with load_angle columns or all "
        "without them, then from the motor side alone; --save-logs writes them as compliance_NN for a compliant "
        "plant), to identify the drives' stiffness and damping on, read at their own sample period",
    )
    parser.add_argument(
        "--torque-age",
        type=_torque_age,
        default=None,
        metavar="S",
        help="with --log: how much older the logs' torque readings are than their angles (s), in "
        f"(0, {CONTROL_PERIOD:g}] (default {MEASURED_TORQUE_DELAY:g}, a simulated drive at the default physics step; "
        "a simulated plant's is its physics step)",
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
    return parser


def resolve(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> IdentifyConfig:
    """The configuration of the parsed command line ``arguments`` (left as they are): ``--quick``'s settings where
    not given, the scenario and the parameter file's install path resolved; a bad combination is a parser error."""
    bag_options = [name for name in BAG_OPTIONS if getattr(arguments, name) != parser.get_default(name)]
    if bag_options and not any(map(is_bag, arguments.log or ())):
        names = ", ".join("--" + name.replace("_", "-") for name in bag_options)
        parser.error(f"{names} say what to read from ROS 2 bags; no --log file is a bag (.mcap, .db3 or a folder)")
    if arguments.log is not None:
        _check_log_arguments(arguments, parser)
        compliance_log = None if arguments.compliance_log is None else tuple(arguments.compliance_log)
        return IdentifyConfig(
            **{
                **vars(arguments),
                "scenario": None,
                "log": tuple(arguments.log),
                "compliance_log": compliance_log,
                "torque_age": MEASURED_TORQUE_DELAY if arguments.torque_age is None else arguments.torque_age,
                "robot_identity": None,
            }
        )
    if arguments.quick:
        if arguments.parameters is not None:
            parser.error("--quick writes its rough parameters to the run folder only; drop --parameters")
        # an explicit setting wins over --quick
        quick = {name: value for name, value in QUICK.items() if getattr(arguments, name) == parser.get_default(name)}
        arguments = resolved_arguments(arguments, **quick, no_install=True)
    if arguments.robot is not None:
        parser.error("--robot names the robot of --log files; without --log the robot is the scenario's")
    log_options = [name for name in ("compliance_log", "torque_age") if getattr(arguments, name) is not None]
    if log_options:
        names = " and ".join("--" + name.replace("_", "-") for name in log_options)
        parser.error(f"{names}: only for --log files; a simulation knows its own drives' timing and logs")
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
    return IdentifyConfig(
        **{**vars(arguments), "scenario": scenario, "parameters": parameters, "robot_identity": scenario.robot_identity}
    )


def _check_log_arguments(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """A parser error unless ``arguments`` identify from logs alone: no simulation option, a robot file, 2 logs or
    more."""
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


def parse_args(argv: Sequence[str] | None = None) -> IdentifyConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def simulation_settings(arguments: argparse.Namespace | IdentifyConfig) -> dict[str, float]:
    """The settings of a simulated identification (:data:`eval.identification.parameter_files.DEFAULT_SETTINGS`' keys)
    given by ``arguments``: the parsed command line or its configuration."""
    return {
        "trajectories": arguments.trajectories,
        "duration_s": arguments.duration,
        "validation_duration_s": arguments.validation_duration,
        "seed": arguments.seed,
    }


def save_logs(
    run: IdentificationRun, geometry: DeltaGeometry, masses: DeltaMasses, folder: Path, suffix: str
) -> tuple[Path, list[Path]]:
    """Write the run's logs as a robot's logger would (excitation_01 ... and, last, validation), the compliance
    excitation's (compliance_01 ..., for identified compliant drives: CSV when ``suffix`` is a bag's, which holds one
    angle per joint) and the robot file ``robot.toml``, what ``--log``, ``--compliance-log`` and
    ``--robot`` read; returns the robot file and the compliance logs."""
    *excitation, validation = run.logs
    digits = max(2, len(str(len(excitation))))  # the names sort in run order, the held-out one last
    for index, log in enumerate(excitation, start=1):
        write_log(log, folder / f"excitation_{index:0{digits}d}{suffix}")
    write_log(validation, folder / f"validation{suffix}")
    table_suffix = ".csv" if suffix in BAG_SUFFIXES else suffix
    compliance = [
        write_log(log, folder / f"compliance_{index:02d}{table_suffix}")
        for index, log in enumerate(run.compliance_logs, start=1)
    ]
    return save_robot(geometry, masses, folder / "robot.toml"), compliance


def read_back_command(folder: Path, robot: Path, compliance: Sequence[Path], scenario: Scenario) -> str:
    """The command line that identifies the robot from the logs :func:`save_logs` wrote into ``folder``."""
    command = f"python -m eval.identification --log {folder}/excitation_* {folder}/validation.* --robot {robot}"
    if compliance:
        command += f" --compliance-log {folder}/compliance_*"
    if scenario.plant.timestep != MEASURED_TORQUE_DELAY:
        command += f" --torque-age {scenario.plant.timestep:g}"
    return command


@command_main("python -m eval.identification")
def main(argv: Sequence[str] | None = None) -> int:
    config = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    if config.quick:
        print(
            f"Quick identification (--quick): {config.trajectories} excitation "
            f"{'trajectory' if config.trajectories == 1 else 'trajectories'} of "
            f"{config.duration:g} s and a {config.validation_duration:g} s held-out one, not "
            f"{DEFAULT_TRAJECTORIES} of {DEFAULT_DURATION:g} s and {VALIDATION_DURATION:g} s: rough parameters, "
            "written to the run folder only (never as the robot's identification)."
        )
    run = None
    if config.log is not None:
        try:
            run = identify_logs(
                config.log,
                config.robot,
                workers=config.workers or 1,
                progress=not config.no_progress,
                topics=BagTopics(config.topic, config.joint_names, config.command_topic),
                compliance_paths=config.compliance_log or (),
                torque_delay=config.torque_age,
            )
        except ValueError as error:  # a bad log or robot file, or logs that do not excite the model
            print(f"python -m eval.identification: error: {error}", file=sys.stderr)
            return 2
        config = dataclasses.replace(config, robot_identity=run.result.provenance["plant"]["identity"])
    suffix = "logs" if config.scenario is None else f"seed{config.seed}"
    scenarios = [] if config.scenario is None else [config.scenario]
    with command_run_folder(
        "identification",
        "eval.identification",
        argv,
        config,
        configuration_record(config),
        scenarios=scenarios,
        stamp=f"{utc_stamp()}_{suffix}",
    ) as run_dir:
        config = dataclasses.replace(config, out=run_dir.folder)
        run_dir.record(config=configuration_record(config))
        identify_into(config, run_dir, run)
    return 0


def identify_into(config: IdentifyConfig, run_dir: Run, run: IdentificationRun | None) -> None:
    """Identify the robot of ``config`` (:func:`parse_args`), or take ``run``, its identification from logs,
    and write the parameters, the validation data, the figures and the report into the run folder, the method into
    its manifest; print the report."""
    folder = run_dir.folder
    if run is not None:
        plant = run.result.provenance["plant"]
        save_robot(DeltaGeometry(**plant["geometry_m"]), DeltaMasses(**plant["masses_kg"]), folder / "robot.toml")
        truth, install = None, config.parameters
    else:
        scenario = config.scenario
        run = run_identification(
            config.trajectories,
            config.seed,
            config.duration,
            validation_duration=config.validation_duration,
            progress=not config.no_progress,
            workers=config.workers,
            plant=scenario.plant,
        )
        if config.save_logs is not None:
            suffix = LOG_FORMATS[config.log_format]
            robot, compliance = save_logs(run, scenario.plant.geometry, scenario.plant.masses, config.save_logs, suffix)
            if suffix in BAG_SUFFIXES:
                print(
                    f"The runs are ROS 2 bags: JointState on {JOINT_STATES_TOPIC}, commands on {JOINT_COMMANDS_TOPIC} "
                    f"(--log ... --command-topic {JOINT_COMMANDS_TOPIC} reads them back)."
                )
            print(f"To identify from these logs: {read_back_command(config.save_logs, robot, compliance, scenario)}")
        truth = ground_truth(scenario.plant)
        install = None if config.no_install else config.parameters
    save_result(run.result, folder / "parameters.json")
    if install is not None:
        save_result(run.result, install)
    run_dir.record(method=run.result.provenance["method"])

    validation_file = folder / "validation.npz"
    save_validation_data(run, validation_file)
    figures = plot_figures(validation_file, folder)
    report = render_report(run, validation_file, run_dir.manifest["command"], figures, truth)
    if config.quick:
        report += "\nA quick run (--quick): rough parameters from little data, not the robot's identification.\n"
    (folder / "report.md").write_text(report)
    print(report)
    written = "" if install is None else f" and {install}"
    if install is None and truth is not None and not config.no_install:
        written += (
            " (not installed as the robot's identification: made with "
            f"{describe_settings(simulation_settings(config))}, not the defaults "
            f"{describe_settings(DEFAULT_SETTINGS)}; --parameters FILE installs it there)"
        )
    if config.save_logs is not None:
        written += f"; the logs and robot.toml in {config.save_logs}/"
    print(f"Wrote {folder}/ (parameters.json, config.json, report.md, figures){written}.")


if __name__ == "__main__":
    sys.exit(main())
