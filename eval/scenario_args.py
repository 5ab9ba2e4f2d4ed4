"""``--scenario NAME|FILE``, ``--geometry FILE``, ``--release``, ``--parameters FILE`` and ``--workers N``: the same
options on every command line, and the range checks of their numeric options (:func:`check_ranges`)."""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from controllers.identification import ParameterFileError, load_result
from controllers.residual import DEFAULT_POLICY_PATH
from controllers.setup import SERVOS
from delta_env.cycles import RELEASES
from delta_env.scaling import scaled_masses
from delta_env.scenario import (
    Scenario,
    load_geometry,
    load_masses,
    preset_names,
    resolve_scenario,
    with_geometry,
)
from delta_env.validation import require_count, require_positive
from eval.calibration import CALIBRATION_SEED_OFFSET
from eval.identification.parameter_files import MISSING_PARAMETER_FILE, check_identity
from eval.processes import DEFAULT_WORKERS

GEOMETRY_HELP = (
    "geometry TOML file ([geometry] ra, rb, l1, l2 in m, e.g. a design of python -m eval.design): "
    "the scenario on a robot of these lengths (a new robot, identified once), its masses those of the file's "
    "[masses] table (m1, m2, m0 in kg: a robot file) or else following the lengths by the rule of delta_env.scaling"
)
"""Help text of ``--geometry``."""


def add_geometry_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--geometry`` to ``parser``."""
    parser.add_argument("--geometry", default=None, help=GEOMETRY_HELP)


def add_scenario_arguments(parser: argparse.ArgumentParser, default: str = "nominal") -> None:
    """Add ``--scenario`` (default ``default``), ``--geometry`` and ``--release`` to ``parser``."""
    parser.add_argument(
        "--scenario",
        default=default,
        help=f"preset ({', '.join(preset_names())}) or scenario TOML file (default {default})",
    )
    add_geometry_argument(parser)
    parser.add_argument(
        "--release",
        choices=RELEASES,
        default=None,
        help="when the gripper switches (default: the scenario's, in_position): once the cell judges the platform "
        "in position, then after the air activation; or timed, mid-way through a 0.1 s dwell (the paper's cell)",
    )


def existing_parameter_file(text: str) -> Path:
    """An argparse type: the path ``text`` if it is a readable parameter file, else an error naming it (a parameter
    file the user gives is read, never identified there:
    :func:`eval.identification.parameter_files.robot_identification`)."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: {MISSING_PARAMETER_FILE}")
    try:
        load_result(path)
    except ParameterFileError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return path


def check_parameter_file(parser: argparse.ArgumentParser, parameters: Path | None, scenario: Scenario) -> None:
    """A parser error when ``--parameters`` records another robot than ``scenario``'s
    (:func:`eval.identification.parameter_files.check_identity`)."""
    if parameters is None:
        return
    try:
        check_identity(load_result(parameters), scenario.plant, parameters)
    except ParameterFileError as error:
        parser.error(f"--parameters: {error}")


def add_parameters_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--parameters`` (the identified parameter file of the scenario's robot, which must exist) to ``parser``."""
    parser.add_argument(
        "--parameters",
        type=existing_parameter_file,
        default=None,
        help="identified parameter file of the scenario's robot (default: <runs root>/identification/<robot "
        "identity>/parameters.json, identified when missing)",
    )


def add_servo_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--servo`` (the model rows' feedback, :data:`controllers.setup.SERVOS`) to ``parser``."""
    parser.add_argument(
        "--servo",
        choices=SERVOS,
        default=SERVOS[0],
        help="feedback of the model rows (the residual's base: the one its policy file records): 'servo', the servo "
        "layer (integral action, friction compensation at rest, gains from the identified model and drive lag), or "
        f"'pd', the paper's fixed PD (default {SERVOS[0]}; the pd row is always the PD)",
    )


def add_residual_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--residual`` (the policy file of the ``residual`` row; the shipped one by default) to ``parser``."""
    parser.add_argument(
        "--residual",
        type=Path,
        default=DEFAULT_POLICY_PATH,
        help=f"residual policy of the 'residual' row (default: the shipped {DEFAULT_POLICY_PATH.name})",
    )


def add_workers_argument(parser: argparse.ArgumentParser, help: str = "processes (default: up to 2)") -> None:
    """Add ``--workers`` (default :data:`DEFAULT_WORKERS`; check it with :func:`check_ranges`, minimum 1) to
    ``parser``."""
    parser.add_argument("--workers", type=int, default=DEFAULT_WORKERS, help=help)


def on_geometry(scenario: Scenario, path: str | os.PathLike[str]) -> Scenario:
    """``scenario`` on the robot of the geometry file ``path``, named ``<scenario>+<file stem>``.

    Its masses are the file's ``[masses]`` (a robot file, :func:`delta_env.scenario.load_robot`), or else follow
    the lengths by :func:`delta_env.scaling.scaled_masses` from the scenario's robot, as in the design study.

    Raises:
        ValueError: for a bad geometry or robot file (naming the file and the field).
    """
    geometry = load_geometry(path)
    masses = load_masses(path)
    if masses is None:
        masses = scaled_masses(geometry, scenario.plant.geometry, scenario.plant.masses)
    scenario = with_geometry(scenario, geometry, masses)
    return dataclasses.replace(scenario, name=f"{scenario.name}+{Path(path).stem}")


def scenario_from_arguments(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Scenario:
    """The scenario of ``--scenario`` on the robot of ``--geometry`` (:func:`on_geometry`), released as
    ``--release`` says; a bad value is a parser error."""
    try:
        scenario = resolve_scenario(args.scenario)
        if args.geometry is not None:
            scenario = on_geometry(scenario, args.geometry)
    except ValueError as error:
        parser.error(f"--scenario/--geometry: {error}")
    if getattr(args, "release", None) is not None:
        scenario = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, release=args.release))
    return scenario


def check_episode_seeds(parser: argparse.ArgumentParser, args: object) -> None:
    """A parser error when the episodes ``--seed`` .. ``--seed + --episodes - 1`` reach the tare calibration's
    seeds (:data:`eval.calibration.CALIBRATION_SEED_OFFSET` and up): a tare measured on the episodes it is
    scored on would flatter the estimator. ``args``: the parsed arguments or the resolved configuration."""
    last = args.seed + getattr(args, "episodes", 1) - 1
    if last >= CALIBRATION_SEED_OFFSET:
        parser.error(
            f"--seed {args.seed} with --episodes {getattr(args, 'episodes', 1)} reaches seed {last}: episode seeds "
            f"must lie in [0, {CALIBRATION_SEED_OFFSET - 1}], the seeds from {CALIBRATION_SEED_OFFSET} on are the "
            "tare calibration's"
        )


def check_ranges(
    parser: argparse.ArgumentParser,
    args: object,
    counts: Mapping[str, int],
    positive: Sequence[str] = (),
) -> None:
    """A parser error naming the option, its allowed range and the value for the first argument out of range
    (arguments left at None are not checked).

    Args:
        parser: The command line's parser.
        args: Its parsed arguments or resolved configuration.
        counts: Integer arguments by ``dest`` and their minimum.
        positive: Real arguments (``dest``) that must be finite and > 0.
    """
    try:
        for name, minimum in counts.items():
            if getattr(args, name) is not None:
                require_count(_flag(name), getattr(args, name), minimum)
        for name in positive:
            if getattr(args, name) is not None:
                require_positive(_flag(name), getattr(args, name))
    except ValueError as error:
        parser.error(str(error))


def _flag(dest: str) -> str:
    """The option of an argparse ``dest``: ``calibration_episodes`` -> ``--calibration-episodes``."""
    return "--" + dest.replace("_", "-")
