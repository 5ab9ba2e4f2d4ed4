"""What a controller knows besides its observation: one record (:class:`ControllerSetup`), and the built-in model rows
built from it (:func:`model_row`).

The record is written and read by the generic writer of :mod:`delta_env.records` (:meth:`ControllerSetup.to_table`,
:meth:`ControllerSetup.from_table`) and hashed from that written form (:meth:`ControllerSetup.content_hash`), so that
no field can be left out of a cache key or a file: the experiments' setups, the tare cache and the residual policy
file's base (:mod:`controllers.residual.policy_file`) are all this record.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from controllers.base import DEFAULT_KD, DEFAULT_KP
from controllers.dynamics import ModelParameters
from controllers.feedforward import FeedforwardController, LagCompensatedController, model_controller
from controllers.payload import EmptyMoveSums
from delta_env.drive import MAX_TIME_CONSTANT, DriveLimits
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.records import content_hash, from_table, to_table
from delta_env.sensors import ENCODER_BITS
from delta_env.validation import require_joint_vector

ESTIMATOR_REGRESSORS: dict[str, Literal["smoothed", "reference"]] = {
    "mid_f_rls": "smoothed",
    "mid_f_rls_ref": "reference",
    "mid_f_rls_lag": "smoothed",
}
"""The payload estimator variant of each built-in RLS controller key."""

MODEL_ROWS = ("mkh", "mid", "mid_f", "mid_f_r", *ESTIMATOR_REGRESSORS)
"""The keys of the built-in rows with a model feedforward (:func:`model_row`)."""


@dataclass(frozen=True)
class ControllerSetup:
    """What the controllers may know besides the observation.

    Attributes:
        mid: Identified MId parameters (rho1, rho2).
        mid_f: Identified MId+F parameters (rho1, rho2, friction).
        mid_f_rods: Identified MId+F+R parameters (the model with rod forearms).
        drive_lag: Identified drive lag T (s) per joint; None if unknown (then ``mid_f_rls_lag`` cannot be built).
        tares: Apparent payload of the empty gripper (kg) per RLS controller key; missing keys use 0.
        empty_moves: Sums of the robot's earlier empty moves per RLS controller key (its calibration episodes,
            :class:`~controllers.payload.EmptyMoveSums`), which seed the estimator's fit of the robot's mass and
            friction errors at every episode; only for the robot they were measured on. Missing keys: none.
        pd_gains: (Kp (N m/rad), Kd (N m s/rad)) of every controller's feedback.
        residual_policy: The residual policy file of the ``residual`` row; None is the shipped policy.
        geometry: Lengths (m) of the robot the parameters were identified on; the models are of this robot.
        masses: Datasheet masses (kg) of that robot.
        drive: The robot's drive (its data sheet), for the fault monitor's plausibility checks.
        encoder_bits: Its encoders' resolution (bits per revolution; None: exact), likewise.
        fault_reaction: What the monitored rows do after detecting a collision, a slip or a drive fault
            (:data:`delta_env.faults.FAULT_REACTIONS`).
    """

    mid: ModelParameters
    mid_f: ModelParameters
    mid_f_rods: ModelParameters
    drive_lag: tuple[float, float, float] | None = None
    tares: Mapping[str, float] = field(default_factory=dict)
    empty_moves: Mapping[str, EmptyMoveSums] = field(default_factory=dict)
    pd_gains: tuple[float, float] = (DEFAULT_KP, DEFAULT_KD)
    residual_policy: Path | None = None
    geometry: DeltaGeometry = NOMINAL_GEOMETRY
    masses: DeltaMasses = NOMINAL_MASSES
    drive: DriveLimits = field(default_factory=DriveLimits)
    encoder_bits: int | None = ENCODER_BITS
    fault_reaction: Literal["continue", "slow", "stop"] = "continue"

    def __post_init__(self) -> None:
        if self.drive_lag is not None:
            require_joint_vector("drive_lag", self.drive_lag, 0.0, MAX_TIME_CONSTANT, unit="s")

    def to_table(self) -> dict[str, Any]:
        """Every field as a table of TOML values (:func:`delta_env.records.to_table`): the record's written form."""
        return to_table(self)

    @classmethod
    def from_table(cls, table: dict[str, Any], path: str = "") -> ControllerSetup:
        """The record of :meth:`to_table`'s ``table``; ValueError naming a missing, unknown or ill-typed field (its
        dotted place under ``path``)."""
        return from_table(cls, table, path)

    def content_hash(self) -> str:
        """16 hex digits of every field as a table (:meth:`to_table`): the cache key of what the controllers know,
        which no field can be left out of."""
        return content_hash(self.to_table())


def model_row(
    key: str, setup: ControllerSetup, name: str | None = None
) -> FeedforwardController | LagCompensatedController:
    """The built-in model row ``key`` (one of :data:`MODEL_ROWS`) for the robot of ``setup``: its feedforward from
    the identified model, its PD and, for the RLS rows, its payload estimator with the setup's tare and empty moves
    of ``key`` (not behind a fault monitor). ``name``: its label (None: the model's name,
    :func:`controllers.feedforward.controller_name`)."""
    if key not in MODEL_ROWS:
        raise ValueError(f"{key!r} is not a model row; choose from {', '.join(MODEL_ROWS)}")
    if key in ("mid_f_r", *ESTIMATOR_REGRESSORS):
        if key == "mid_f_rls_lag" and setup.drive_lag is None:
            raise ValueError(f"{key!r} needs the identified drive lag; ControllerSetup.drive_lag is None")
        return model_controller(
            setup.mid_f_rods,
            forearm_rods=True,
            regressor=ESTIMATOR_REGRESSORS.get(key),
            tare=setup.tares.get(key, 0.0),
            empty_moves=setup.empty_moves.get(key),
            pd_gains=setup.pd_gains,
            name=name,
            geometry=setup.geometry,
            masses=setup.masses,
            drive_lag=setup.drive_lag if key == "mid_f_rls_lag" else None,
        )
    parameters = {"mkh": None, "mid": setup.mid, "mid_f": setup.mid_f}[key]
    geometry, masses = setup.geometry, setup.masses
    return model_controller(parameters, pd_gains=setup.pd_gains, name=name, geometry=geometry, masses=masses)
