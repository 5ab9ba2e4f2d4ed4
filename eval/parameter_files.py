"""The parameter files of the identified robots, kept by robot identity (docs/design.md section 7).

The identification belongs to a robot (its plant), not to the conditions it runs in: :func:`identify_robot` keeps
one file per robot identity (:func:`delta_env.scenario.plant_identity`),
``<runs root>/identification/<identity>/parameters.json`` (the runs root of :func:`eval.run_folder.runs_root`:
``--runs-dir``, ``$DELTA_RUNS_DIR`` or ``./runs``), which :func:`load_or_identify` reads, or creates with
:func:`eval.identification.identify` when it is missing; the file records the identity and
:func:`check_identity` checks it on reading. A new robot is identified once, when first needed.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path
from typing import Any

from controllers.identification import IdentificationResult, ParameterFileError, load_result, save_result
from controllers.registry import ControllerSetup
from delta_env.config import PlantConfig
from delta_env.scenario import datasheet_identity, plant_identity
from eval.identification import identify
from eval.run_folder import runs_root

logger = logging.getLogger(__name__)


def identification_root(runs_dir: str | os.PathLike[str] | None = None) -> Path:
    """Folder of the identifications, one subfolder per robot identity: ``identification`` under the runs root
    (:func:`eval.run_folder.runs_root` of ``runs_dir``)."""
    return runs_root(runs_dir) / "identification"


def parameter_path(plant: PlantConfig, root: str | os.PathLike[str] | None = None) -> Path:
    """Where the identification of the robot ``plant`` builds is kept: ``root/<identity>/parameters.json``
    (``root`` None: :func:`identification_root`)."""
    return Path(identification_root() if root is None else root) / plant_identity(plant) / "parameters.json"


def load_or_identify(path: str | os.PathLike[str], **identify_kwargs: Any) -> IdentificationResult:
    """The identified parameters at ``path``; if the file does not exist, identify and save them there.

    Args:
        path: Parameter file.
        **identify_kwargs: Arguments of :func:`identify`, used only when the file is missing.

    Raises:
        ParameterFileError: if the file exists but is corrupt (it is never silently replaced).
    """
    path = Path(path)
    if path.exists():
        return load_result(path)
    logger.info("no identified parameters at %s: identifying (about a minute)", path)
    result = identify(**identify_kwargs)
    save_result(result, path)
    return result


def check_identity(result: IdentificationResult, plant: PlantConfig, path: str | os.PathLike[str]) -> None:
    """Refuse an identification of another robot than ``plant``'s.

    A simulated identification records the plant's identity (:func:`delta_env.scenario.plant_identity`); one from
    logs knows the robot only by its robot file, and records the identity of its lengths and datasheet masses
    (:func:`delta_env.scenario.datasheet_identity`): a plant with the same ones is that robot.

    Raises:
        ParameterFileError: if the file records no robot identity or another one than ``plant``'s.
    """
    summary = result.provenance.get("plant", {})
    recorded = summary.get("identity")
    if summary.get("source") == "logs":
        expected = datasheet_identity(plant.geometry, plant.masses)
        if recorded != expected:
            raise ParameterFileError(
                f"{path}: identified from the logs of robot {recorded!r} (robot file {summary.get('robot_file')}: "
                f"{summary.get('geometry_m')} m, {summary.get('masses_kg')} kg), not of this robot {expected!r} "
                f"({dataclasses.asdict(plant.geometry)} m, {dataclasses.asdict(plant.masses)} kg); simulate that robot "
                "(--geometry ROBOT_FILE) or pass the file of this robot"
            )
        return
    expected = plant_identity(plant)
    if recorded != expected:
        raise ParameterFileError(
            f"{path}: identified on robot {recorded!r}, not on this robot {expected!r} "
            "(delete the file to identify again, or pass the file of this robot)"
        )


def identify_robot(
    plant: PlantConfig, root: str | os.PathLike[str] | None = None, **identify_kwargs: Any
) -> IdentificationResult:
    """The identification of the robot ``plant`` builds, from its file under ``root``; identified there when
    missing (about a minute per robot).

    Args:
        plant: The robot as identified (a scenario's ``plant``, without its condition).
        root: Folder of the identifications (:func:`parameter_path`; None: :func:`identification_root`).
        **identify_kwargs: Arguments of :func:`identify` other than ``plant``, used only when identifying.

    Raises:
        ParameterFileError: if the file is corrupt or records another robot.
    """
    path = parameter_path(plant, root)
    result = load_or_identify(path, plant=plant, **identify_kwargs)
    check_identity(result, plant, path)
    return result


def robot_identification(
    plant: PlantConfig,
    parameters: str | os.PathLike[str] | None = None,
    root: str | os.PathLike[str] | None = None,
) -> tuple[Path, IdentificationResult]:
    """The parameter file and identification of ``plant``'s robot: ``parameters`` (identified there when missing)
    or, when None, its own file under ``root`` (:func:`identify_robot`); either must record this robot.

    Raises:
        ParameterFileError: if the file is corrupt or records another robot.
    """
    if parameters is None:
        return parameter_path(plant, root), identify_robot(plant, root)
    result = load_or_identify(parameters, plant=plant)
    check_identity(result, plant, parameters)
    return Path(parameters), result


def robot_setup(plant: PlantConfig, result: IdentificationResult, **setup_kwargs: Any) -> ControllerSetup:
    """What the controllers know of the robot ``plant`` builds: its lengths, datasheet masses and ``result``.

    Args:
        plant: The robot the parameters were identified on.
        result: Its identification.
        **setup_kwargs: Other fields of :class:`~controllers.registry.ControllerSetup` (tares, gains, policy).
    """
    return ControllerSetup(
        mid=result.mid,
        mid_f=result.mid_f,
        mid_f_rods=result.mid_f_rods,
        drive_lag=result.drive_lag,
        geometry=plant.geometry,
        masses=plant.masses,
        drive=plant.drive,
        encoder_bits=plant.realism.encoder_bits,
        **setup_kwargs,
    )
