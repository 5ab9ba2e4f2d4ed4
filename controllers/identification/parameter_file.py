"""The identified-parameter file: a JSON document with every parameter set and its provenance."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.compliance import DriveCompliance
from controllers.dynamics import ModelParameters
from controllers.identification.data import REST_VELOCITY
from delta_env.drive import MAX_TIME_CONSTANT
from delta_env.geometry import TORQUE_LIMIT
from delta_env.validation import require_in

FILE_FORMAT_VERSION = 4
"""Version of the JSON parameter file; bumped on incompatible changes (3: the drive lag ``drive_lag_s``; 4: the
Stribeck excess ``stribeck_excess_nm`` and its decay speed ``stribeck_velocity_rad_s``)."""

MODEL_FIELDS = ("mid", "mid_f", "mid_f_rods", "paper_mid", "paper_mid_f")
"""The parameter sets of an :class:`IdentificationResult`, in the order of the JSON file."""

COMPLIANCE_KEY = "compliance"
"""The file's optional section of compliant drives (absent for rigid ones: files without it read as before)."""

COMPLIANCE_FIELDS = {
    "rotor_inertia": "rotor_inertia_kg_m2",
    "stiffness": "stiffness_nm_per_rad",
    "damping": "damping_nm_s_per_rad",
    "backlash": "backlash_rad",
}
"""The section's keys (per joint, SI) by the :class:`~controllers.compliance.DriveCompliance` field they hold; a file
without ``backlash_rad`` (written before it was stored) holds none."""


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameter sets with their provenance.

    Attributes:
        mid: MId by least squares of (rho1, rho2) alone (no friction).
        mid_f: MId+F by the joint least squares of all parameters (ours).
        mid_f_rods: MId+F+R: the same least squares on the model with rod forearms
            (``DeltaDynamics.nominal(mid_f_rods, forearm_rods=True)``).
        paper_mid: MId by the paper's grid search, averaged over trajectories.
        paper_mid_f: MId+F by the paper's method (grid rho + per-joint friction LS, averaged).
        drive_lag: Time constant T (s) of each joint's first-order drive lag
            (:func:`controllers.drive.identify_lag`), each in [0, 0.1]; None when the data had no commands to fit it
            on (logs without them): then no controller leads a lag it does not know.
        stribeck_excess: Stribeck excess fs_i of each joint's friction near zero speed (N m, >= 0) on the MId+F+R
            model (:func:`controllers.identification.stribeck.fit_stribeck`): a joint at rest breaks away at
            fc_i + fs_i of ``mid_f_rods``. None when the data had too few slow moving samples to fit it.
        stribeck_velocity: Decay speed vs (rad/s) of the Stribeck excess; None with ``stribeck_excess``.
        standard_errors: Standard errors of the least-squares estimates, keyed ``"mid.rho1"``,
            ``"mid_f.viscous_2"``, ... (units of the parameter); optimistic, see
            :attr:`controllers.identification.least_squares.LeastSquaresFit.standard_errors`.
        provenance: JSON-ready record of how the parameters were obtained: method, trajectories, plant
            summary, sample counts, residual statistics, held-out validation, run times, versions, date.
        compliance: The drives' compliance (:class:`controllers.compliance.DriveCompliance`) identified from the
            compliance excitation's logs (:mod:`controllers.identification.compliance`); None for rigid drives or
            logs without the load-side angle. The file's optional ``compliance`` section.
    """

    mid: ModelParameters
    mid_f: ModelParameters
    mid_f_rods: ModelParameters
    paper_mid: ModelParameters
    paper_mid_f: ModelParameters
    drive_lag: tuple[float, float, float] | None
    stribeck_excess: tuple[float, float, float] | None
    stribeck_velocity: float | None
    standard_errors: dict[str, float]
    provenance: dict[str, Any]
    compliance: DriveCompliance | None = None

    def __post_init__(self) -> None:
        if (self.stribeck_excess is None) != (self.stribeck_velocity is None):
            raise ValueError("stribeck_excess and stribeck_velocity are given together or not at all")

    @property
    def breakaway(self) -> tuple[float, float, float]:
        """Torque (N m) that starts each joint from rest on MId+F+R: its Coulomb friction plus the Stribeck excess
        (the Coulomb friction alone without an identified excess)."""
        excess = (0.0, 0.0, 0.0) if self.stribeck_excess is None else self.stribeck_excess
        return tuple(c + e for c, e in zip(self.mid_f_rods.coulomb, excess, strict=True))


class ParameterFileError(ValueError):
    """An identified-parameter file that cannot be used; the message names the path and the problem."""


def _model_to_json(parameters: ModelParameters) -> dict[str, Any]:
    return {
        "rho1": parameters.rho1,
        "rho2": parameters.rho2,
        "viscous": list(parameters.viscous),
        "coulomb": list(parameters.coulomb),
    }


def _json_ready(value: Any) -> Any:
    """Numpy scalars and arrays inside ``value`` as plain Python numbers and lists."""
    if isinstance(value, Mapping):
        return {str(key): _json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(item) for item in value]
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def save_result(result: IdentificationResult, path: str | os.PathLike[str]) -> Path:
    """Write ``result`` as JSON to ``path`` (parent folders are created; the write is atomic).

    Returns:
        The path written.
    """
    path = Path(path)
    document = {"format_version": FILE_FORMAT_VERSION}
    document.update({name: _model_to_json(getattr(result, name)) for name in MODEL_FIELDS})
    document["drive_lag_s"] = None if result.drive_lag is None else list(result.drive_lag)
    document["stribeck_excess_nm"] = None if result.stribeck_excess is None else list(result.stribeck_excess)
    document["stribeck_velocity_rad_s"] = result.stribeck_velocity
    document["standard_errors"] = dict(result.standard_errors)
    document["provenance"] = result.provenance
    if result.compliance is not None:
        document[COMPLIANCE_KEY] = {
            key: list(getattr(result.compliance, name)) for name, key in COMPLIANCE_FIELDS.items()
        }
    text = json.dumps(_json_ready(document), indent=2, allow_nan=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(text + "\n")
    os.replace(temporary, path)
    return path


def _number(path: Path, where: str, value: Any, low: float = -math.inf, high: float = math.inf) -> float:
    """A JSON number of the file in [low, high], else :class:`ParameterFileError` naming the path."""
    try:
        return require_in(where, value, low, high)
    except ValueError as error:
        raise ParameterFileError(f"{path}: {error}") from None


def _entry(path: Path, mapping: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in mapping:
        raise ParameterFileError(f"{path}: missing key {key!r} in {where}")
    return mapping[key]


def _json_object(path: Path, value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ParameterFileError(f"{path}: {where} must be a JSON object, got {type(value).__name__}")
    return value


def _model_from_json(path: Path, document: Mapping[str, Any], name: str) -> ModelParameters:
    entry = _json_object(path, _entry(path, document, name, "the file"), name)
    values: dict[str, Any] = {}
    for key in ("rho1", "rho2"):
        values[key] = _number(path, f"{name}.{key}", _entry(path, entry, key, name))
    for key in ("viscous", "coulomb"):
        joints = _entry(path, entry, key, name)
        if not isinstance(joints, list) or len(joints) != 3:
            raise ParameterFileError(f"{path}: {name}.{key} must be a list of 3 numbers, got {joints!r}")
        values[key] = tuple(_number(path, f"{name}.{key}[{i}]", v) for i, v in enumerate(joints))
    try:
        return ModelParameters(**values)
    except ValueError as error:
        raise ParameterFileError(f"{path}: {name}: {error}") from error


def _joint_values(path: Path, document: Mapping[str, Any], key: str, high: float) -> tuple[float, float, float] | None:
    """The file's per-joint values under ``key``, each in [0, high], or None (null)."""
    values = _entry(path, document, key, "the file")
    if values is None:
        return None
    if not isinstance(values, list) or len(values) != 3:
        raise ParameterFileError(f"{path}: {key} must be a list of 3 numbers or null, got {values!r}")
    return tuple(_number(path, f"{key}[{i}]", v, 0.0, high) for i, v in enumerate(values))


def older_format(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a parameter file of an older :data:`FILE_FORMAT_VERSION` (an unreadable file is not: its
    reading reports it)."""
    try:
        version = json.loads(Path(path).read_text()).get("format_version")
    except (OSError, ValueError, AttributeError):
        return False
    return isinstance(version, int) and version < FILE_FORMAT_VERSION


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a file written by :func:`save_result`.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ParameterFileError: if it is not valid JSON, has missing keys, wrong types or out-of-range values;
            the message names the path and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"identified parameter file {path} does not exist; run `python -m eval.identification` to create it"
        )
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ParameterFileError(f"{path}: not valid JSON ({error})") from error
    document = _json_object(path, document, "the file")
    version = _entry(path, document, "format_version", "the file")
    if version != FILE_FORMAT_VERSION:
        raise ParameterFileError(
            f"{path}: format_version {version!r} is not {FILE_FORMAT_VERSION}; delete the file or run "
            "`python -m eval.identification` to identify again"
        )
    models = {name: _model_from_json(path, document, name) for name in MODEL_FIELDS}
    drive_lag = _joint_values(path, document, "drive_lag_s", MAX_TIME_CONSTANT)
    stribeck_excess = _joint_values(path, document, "stribeck_excess_nm", TORQUE_LIMIT)
    velocity = _entry(path, document, "stribeck_velocity_rad_s", "the file")
    stribeck_velocity = (
        None if velocity is None else _number(path, "stribeck_velocity_rad_s", velocity, REST_VELOCITY, math.inf)
    )
    if (stribeck_excess is None) != (stribeck_velocity is None):
        raise ParameterFileError(f"{path}: stribeck_excess_nm and stribeck_velocity_rad_s must both be null or not")
    errors = _json_object(path, _entry(path, document, "standard_errors", "the file"), "standard_errors")
    standard_errors = {}
    for key, value in errors.items():
        standard_errors[key] = _number(path, f"standard_errors[{key!r}]", value, low=0.0)
    provenance = _json_object(path, _entry(path, document, "provenance", "the file"), "provenance")
    compliance = None
    if COMPLIANCE_KEY in document:
        section = _json_object(path, document[COMPLIANCE_KEY], COMPLIANCE_KEY)
        values = {}
        for name, key in COMPLIANCE_FIELDS.items():
            if name == "backlash" and key not in section:
                continue  # written before the backlash was stored: none
            joints = _entry(path, section, key, COMPLIANCE_KEY)
            if not isinstance(joints, list) or len(joints) != 3:
                raise ParameterFileError(f"{path}: {COMPLIANCE_KEY}.{key} must be a list of 3 numbers, got {joints!r}")
            values[name] = tuple(_number(path, f"{COMPLIANCE_KEY}.{key}[{i}]", v) for i, v in enumerate(joints))
        try:
            compliance = DriveCompliance(**values)
        except ValueError as error:
            raise ParameterFileError(f"{path}: {COMPLIANCE_KEY}: {error}") from error
    return IdentificationResult(
        **models,
        drive_lag=drive_lag,
        stribeck_excess=stribeck_excess,
        stribeck_velocity=stribeck_velocity,
        standard_errors=standard_errors,
        provenance=dict(provenance),
        compliance=compliance,
    )
