"""The parameter files of the identified robots, kept by robot identity (docs/design.md section 7).

The identification belongs to a robot (its plant), not to the conditions it runs in: :func:`identify_robot` keeps
one file per robot identity (:func:`delta_env.scenario.plant_identity`),
``<runs root>/identification/<identity>/parameters.json`` (the runs root of :func:`eval.run_folder.runs_root`:
``--runs-dir``, ``$DELTA_RUNS_DIR`` or ``./runs``), which :func:`load_or_identify` reads, or creates with
:func:`eval.identification.run.identify` when it is missing; the file records the identity and
:func:`check_identity` checks it on reading. A new robot is identified once, when first needed.

That file holds the identification of the default settings (:data:`DEFAULT_SETTINGS`) and nothing else: the
settings a simulated identification ran with are in its provenance (:func:`identification_settings`);
:func:`check_settings` refuses a robot's file made with others, and ``python -m eval.identification`` installs a run of
other settings only where ``--parameters`` says (:func:`install_path`). A parameter file given by the user
(``--parameters``) is read as it is, whatever its settings, and must exist.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from controllers.identification import IdentificationResult, ParameterFileError, load_result, older_format, save_result
from controllers.registry import ControllerSetup
from delta_env.config import PlantConfig
from delta_env.scenario import datasheet_identity, plant_identity
from eval.identification.excitation import DEFAULT_DURATION, VALIDATION_DURATION
from eval.identification.run import COMPLIANCE_VERSION, DEFAULT_TRAJECTORIES, IDENTIFICATION_VERSION, identify
from eval.run_folder import runs_root

logger = logging.getLogger(__name__)

DEFAULT_SETTINGS = {
    "trajectories": DEFAULT_TRAJECTORIES,
    "duration_s": DEFAULT_DURATION,
    "validation_duration_s": VALIDATION_DURATION,
    "seed": 0,
}
"""The settings of the identification kept per robot (:func:`parameter_path`): ``python -m eval.identification``'s
defaults and those :func:`identify_robot` identifies a missing robot with."""

SETTING_FLAGS = {
    "trajectories": "--trajectories",
    "duration_s": "--duration",
    "validation_duration_s": "--validation-duration",
    "seed": "--seed",
}
"""The ``python -m eval.identification`` option of each setting."""


MISSING_PARAMETER_FILE = (
    "no such parameter file; give an existing one (python -m eval.identification --parameters FILE writes one), or "
    "leave --parameters out to use the robot's own identification"
)
"""Why a ``--parameters`` that does not exist is refused (rather than identified there)."""


def identification_root(runs_dir: str | os.PathLike[str] | None = None) -> Path:
    """Folder of the identifications, one subfolder per robot identity: ``identification`` under the runs root
    (:func:`eval.run_folder.runs_root` of ``runs_dir``)."""
    return runs_root(runs_dir) / "identification"


def parameter_path(plant: PlantConfig, root: str | os.PathLike[str] | None = None) -> Path:
    """Where the identification of the robot ``plant`` builds is kept: ``root/<identity>/parameters.json``
    (``root`` None: :func:`identification_root`)."""
    return Path(identification_root() if root is None else root) / plant_identity(plant) / "parameters.json"


def load_or_identify(
    path: str | os.PathLike[str],
    outdated: Callable[[IdentificationResult], bool] | None = None,
    **identify_kwargs: Any,
) -> IdentificationResult:
    """The identified parameters at ``path``; if the file does not exist, identify and save them there.

    Args:
        path: Parameter file.
        outdated: Whether a readable file's result was made by another version of the identification
            (:func:`outdated`); such a cache is identified again and
            replaced, with a warning. None: none is.
        **identify_kwargs: Arguments of :func:`identify`, used only when the file is missing.

    A file of an older format (:func:`~controllers.identification.parameter_file.older_format`) is a cache this
    version cannot read: it is identified again and replaced, with a warning; one identified from logs is refused
    (a simulation would not replace it).

    Raises:
        ParameterFileError: if the file exists but is corrupt (it is never silently replaced).
    """
    path = Path(path)
    if path.exists() and not older_format(path):
        result = load_result(path)
        if outdated is None or not outdated(result):
            return result
        logger.warning(
            "%s was identified by another version of this project's identification: identifying again (about a minute)",
            path,
        )
    elif path.exists():
        if json.loads(path.read_text()).get("provenance", {}).get("plant", {}).get("source") == "logs":
            raise ParameterFileError(
                f"{path}: an identification from logs in an older file format; identify the logs again "
                "(python -m eval.identification --log FILE ... --robot ROBOT) to write this version's format"
            )
        logger.warning("%s was written by an older version of this project: identifying again (about a minute)", path)
    else:
        logger.info("no identified parameters at %s: identifying (about a minute)", path)
    result = identify(**identify_kwargs)
    save_result(result, path)
    return result


def identification_settings(result: IdentificationResult) -> dict[str, float] | None:
    """The settings (:data:`DEFAULT_SETTINGS`' keys) a simulated identification ran with, read from its provenance;
    None for an identification from logs or a file that does not record them."""
    provenance = result.provenance
    try:
        trajectories = provenance["trajectories"]
        return {
            "trajectories": len(trajectories),
            "duration_s": float(trajectories[0]["duration"]),
            "validation_duration_s": float(provenance["validation_trajectory"]["duration"]),
            "seed": int(provenance["seed"]),
        }
    except (KeyError, IndexError, TypeError, ValueError):
        return None


def describe_settings(settings: dict[str, float]) -> str:
    """``settings`` as the options of ``python -m eval.identification``: ``--trajectories 3 --duration 3 ...``."""
    return " ".join(f"{SETTING_FLAGS[name]} {value:g}" for name, value in settings.items())


def install_path(
    plant: PlantConfig, settings: dict[str, float], root: str | os.PathLike[str] | None = None
) -> Path | None:
    """Where ``python -m eval.identification`` installs an identification of ``plant`` made with ``settings`` when no
    ``--parameters`` is given: the robot's own file (:func:`parameter_path`) for :data:`DEFAULT_SETTINGS`, else
    nowhere (None): the robot's file never holds a shorter or otherwise different identification."""
    return parameter_path(plant, root) if settings == DEFAULT_SETTINGS else None


def check_settings(result: IdentificationResult, path: str | os.PathLike[str]) -> None:
    """Refuse a robot's own file (:func:`parameter_path`) that holds an identification of other settings than
    :data:`DEFAULT_SETTINGS` (a file that does not record them, from logs or an older version, is taken as it is).

    Raises:
        ParameterFileError: naming the file, its settings and the defaults.
    """
    settings = identification_settings(result)
    if settings is not None and settings != DEFAULT_SETTINGS:
        raise ParameterFileError(
            f"{path}: the robot's cached identification was made with {describe_settings(settings)}, not the "
            f"defaults {describe_settings(DEFAULT_SETTINGS)}; delete it to identify again with the defaults, or "
            "move it elsewhere and pass it with --parameters"
        )


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
            "(pass the file of this robot, or, for the cache under the runs root, delete it to identify again)"
        )


def outdated(result: IdentificationResult) -> bool:
    """Whether ``result``, a cached simulated identification, was written by another version of the identification
    than this code's (:data:`~eval.identification.run.IDENTIFICATION_VERSION`; a file written before the version was
    recorded has none), or holds compliant drives (fitted or refused) of another version of their identification
    (:data:`~eval.identification.run.COMPLIANCE_VERSION`). The cache key, the robot's identity, does not change with
    the code, so such a file would be read as it is. An identification from logs is never outdated: it is the user's,
    from data this code cannot make again."""
    provenance = result.provenance
    if provenance.get("plant", {}).get("source") == "logs":
        return False
    compliance = provenance.get("compliance")
    if compliance is not None and compliance.get("version") != COMPLIANCE_VERSION:
        return True
    return provenance.get("method", {}).get("version") != IDENTIFICATION_VERSION


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
        ParameterFileError: if the file is corrupt, records another robot or other settings than the defaults
            (:func:`check_settings`).
    """
    path = parameter_path(plant, root)
    result = load_or_identify(
        path,
        outdated=outdated,
        plant=plant,
        **identify_kwargs,
    )
    check_identity(result, plant, path)
    check_settings(result, path)
    return result


def robot_identification(
    plant: PlantConfig,
    parameters: str | os.PathLike[str] | None = None,
    root: str | os.PathLike[str] | None = None,
) -> tuple[Path, IdentificationResult]:
    """The parameter file and identification of ``plant``'s robot: ``parameters`` (a file the user gave, read as
    it is) or, when None, its own file under ``root`` (:func:`identify_robot`, identified when missing); either must
    record this robot.

    Raises:
        ParameterFileError: if ``parameters`` does not exist, or the file is corrupt or records another robot.
    """
    if parameters is None:
        return parameter_path(plant, root), identify_robot(plant, root)
    if not Path(parameters).is_file():
        raise ParameterFileError(f"--parameters {parameters}: {MISSING_PARAMETER_FILE}")
    result = load_result(parameters)
    check_identity(result, plant, parameters)
    return Path(parameters), result


def identified_torque_age(result: IdentificationResult, plant: PlantConfig) -> float:
    """The age (s) of the robot's torque readings against their encoder samples: ``plant``'s physics step for a
    simulated identification (the age its readings have), the age the logs were identified with
    (``--torque-age``, recorded in ``result``'s provenance) for a robot identified from its logs."""
    provenance = result.provenance
    if provenance.get("plant", {}).get("source") == "logs":
        return float(provenance["method"]["torque_sample_delay_s"])
    return plant.timestep


def robot_setup(plant: PlantConfig, result: IdentificationResult, **setup_kwargs: Any) -> ControllerSetup:
    """What the controllers know of the robot ``plant`` builds: its lengths, datasheet masses and ``result`` (with the
    drives' compliance when the identification fitted it: the model rows' servo then notches its drive mode).

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
        stribeck_excess=result.stribeck_excess,
        geometry=plant.geometry,
        masses=plant.masses,
        drive=plant.drive,
        encoder_bits=plant.realism.encoder_bits,
        torque_delay=identified_torque_age(result, plant),
        compliance=result.compliance,
        **setup_kwargs,
    )
