"""The experiment engine: what every experiment does before its episodes, once.

:func:`robot_knowledge` gives what every row knows of a scenario's robot: its identification (a given parameter
file, or the robot's own, identified once and cached per robot identity:
:func:`eval.parameter_files.robot_identification`) and the :class:`~controllers.registry.ControllerSetup` built from
it with the scenario's fault reaction. :func:`prepare` adds the tares and empty-move sums of the tared controllers,
measured on the scenario's payload-free episodes on the calibration seeds (:func:`eval.calibration.tare_setup`).
The episodes themselves are tasks (:mod:`eval.tasks`), one work unit for every experiment and both sweep backends.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from controllers.identification import IdentificationResult
from controllers.registry import ControllerSetup
from delta_env.scenario import Scenario
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, Calibration, tare_setup
from eval.parameter_files import identification_root, robot_identification, robot_setup


class Prepared(NamedTuple):
    """What :func:`prepare` found.

    Attributes:
        setup: What the controllers know, tared on the scenario.
        parameter_file: The parameter file the identification came from.
        identification: The robot's identification.
        calibration: Tares (kg), their spreads (kg) and the empty moves' sums per tared controller.
    """

    setup: ControllerSetup
    parameter_file: Path
    identification: IdentificationResult
    calibration: Calibration


def robot_knowledge(
    scenario: Scenario, parameters: str | Path | None = None, runs_dir: str | Path | None = None, **setup_fields: Any
) -> tuple[Path, IdentificationResult, ControllerSetup]:
    """The parameter file, the identification and the untared setup of the scenario's robot, with the scenario's
    fault reaction (arguments as :func:`prepare`'s): what every row knows before the tare."""
    parameter_file, identification = robot_identification(scenario.plant, parameters, identification_root(runs_dir))
    fields = {"fault_reaction": scenario.task.fault_reaction, **setup_fields}
    return parameter_file, identification, robot_setup(scenario.plant, identification, **fields)


def prepare(
    scenario: Scenario,
    controllers: Iterable[str],
    *,
    parameters: str | Path | None = None,
    runs_dir: str | Path | None = None,
    seed: int = 0,
    calibration_episodes: int = DEFAULT_CALIBRATION_EPISODES,
    workers: int = 1,
    progress: Any = None,
    **setup_fields: Any,
) -> Prepared:
    """Identify (or load) the scenario's robot and tare ``controllers`` on the scenario.

    Args:
        scenario: The robot and the work; its faults are left out of the tare's episodes.
        controllers: Controller keys (:func:`controllers.registry.controller_entry`); the tared ones are tared.
        parameters: A parameter file of this robot (identified there when missing); None: the robot's own, under
            the runs root (:func:`eval.parameter_files.identification_root` of ``runs_dir``).
        runs_dir: The runs root (:func:`eval.run_folder.runs_root`).
        seed: Seed of the experiment's first episode; the calibration runs on its calibration seeds.
        calibration_episodes: Payload-free episodes per tared controller.
        workers: Processes of the identification's and the calibration's episodes.
        progress: tqdm bar advanced once per calibration episode.
        **setup_fields: Other fields of :class:`~controllers.registry.ControllerSetup` (e.g. ``residual_policy``).
    """
    parameter_file, identification, setup = robot_knowledge(scenario, parameters, runs_dir, **setup_fields)
    setup, calibration = tare_setup(
        scenario, setup, controllers, seed=seed, episodes=calibration_episodes, workers=workers, progress=progress
    )
    return Prepared(setup, parameter_file, identification, calibration)
