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

import numpy as np

from controllers.base import DEFAULT_KD, DEFAULT_KP, JointFeedback, PDController
from controllers.compliance import DriveCompliance
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import FeedforwardController, LagCompensatedController, model_controller
from controllers.payload import EmptyMoveSums
from controllers.servo import DEFAULT_FRICTION_WIDTH, JointServo, compliant_servo, joint_inertia, servo_gains
from delta_env.drive import MAX_TIME_CONSTANT, DriveLimits
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, TORQUE_LIMIT, DeltaGeometry, DeltaMasses
from delta_env.records import content_hash, from_table, to_table
from delta_env.sensors import (
    ENCODER_BITS,
    MEASURED_TORQUE_DELAY,
    PHYSICS_TIMESTEP,
    encoder_resolution,
    rate_window,
    require_torque_age,
)
from delta_env.validation import require_joint_vector


@dataclass(frozen=True)
class ModelRow:
    """What a built-in model row (:func:`model_row`) is made of.

    Attributes:
        parameters: The identified set its model takes from :class:`ControllerSetup` (``"mid"``, ``"mid_f"`` or
            ``"mid_f_rods"``); None: plain MKH, the datasheet model.
        forearm_rods: Its model has rod forearms (``+R``, :class:`~controllers.dynamics.DeltaDynamics`).
        regressor: The joint states of its payload estimator (:class:`~controllers.payload.PayloadEstimator`, tared
            with the setup's tare and empty moves of its key); None: it runs none and feeds forward mp = 0.
        leads_lag: Its feedforward leads the identified drive lag (:class:`~controllers.feedforward.
            LagCompensatedController`): it needs ``ControllerSetup.drive_lag``.
    """

    parameters: Literal["mid", "mid_f", "mid_f_rods"] | None
    forearm_rods: bool = False
    regressor: Literal["smoothed", "reference"] | None = None
    leads_lag: bool = False

    def model_parameters(self, setup: ControllerSetup) -> ModelParameters | None:
        """The identified set of ``setup`` this row's model takes (None: MKH's datasheet model)."""
        sets = {"mid": setup.mid, "mid_f": setup.mid_f, "mid_f_rods": setup.mid_f_rods}
        return None if self.parameters is None else sets[self.parameters]


MODEL_ROWS: dict[str, ModelRow] = {
    "mkh": ModelRow(None),
    "mid": ModelRow("mid"),
    "mid_f": ModelRow("mid_f"),
    "mid_f_r": ModelRow("mid_f_rods", forearm_rods=True),
    "mid_f_rls": ModelRow("mid_f_rods", forearm_rods=True, regressor="smoothed"),
    "mid_f_rls_ref": ModelRow("mid_f_rods", forearm_rods=True, regressor="reference"),
    "mid_f_rls_lag": ModelRow("mid_f_rods", forearm_rods=True, regressor="smoothed", leads_lag=True),
}
"""The built-in rows with a model feedforward (:func:`model_row`), by key, in the comparison's order."""

ESTIMATOR_REGRESSORS: dict[str, Literal["smoothed", "reference"]] = {
    key: row.regressor for key, row in MODEL_ROWS.items() if row.regressor is not None
}
"""The payload estimator variant of each built-in RLS controller key (the model rows with a regressor)."""

SERVOS = ("servo", "pd")
"""The feedback of the model rows and of the oracle bound: ``"servo"``, the servo layer
(:class:`~controllers.servo.JointServo`, gains from the row's identified model and the identified drive lag; the
default), or ``"pd"``, the paper's fixed PD (``pd_gains``; the oracle: its own PD gains)."""


@dataclass(frozen=True)
class ControllerSetup:
    """What the controllers may know besides the observation.

    Attributes:
        mid: Identified MId parameters (rho1, rho2).
        mid_f: Identified MId+F parameters (rho1, rho2, friction).
        mid_f_rods: Identified MId+F+R parameters (the model with rod forearms).
        drive_lag: Identified drive lag T (s) per joint; None if unknown (then ``mid_f_rls_lag`` cannot be built).
        stribeck_excess: Identified Stribeck excess of each joint's friction near zero speed (N m): the servo layer of
            a row that models friction pushes its Coulomb friction plus this at rest (the breakaway); None: unknown
            (the Coulomb friction alone).
        tares: Apparent payload of the empty gripper (kg) per RLS controller key; missing keys use 0.
        empty_moves: Sums of the robot's earlier empty moves per RLS controller key (its calibration episodes,
            :class:`~controllers.payload.EmptyMoveSums`), which seed the estimator's fit of the robot's mass and
            friction errors at every episode; only for the robot they were measured on. Missing keys: none.
        pd_gains: (Kp (N m/rad), Kd (N m s/rad)) of the PD row and of the model rows' feedback with ``servo="pd"``.
        servo: The model rows' feedback, one of :data:`SERVOS` (:func:`row_servo`).
        residual_policy: The residual policy file of the ``residual`` row; None is the shipped policy.
        geometry: Lengths (m) of the robot the parameters were identified on; the models are of this robot.
        masses: Datasheet masses (kg) of that robot.
        drive: The robot's drive (its data sheet), for the fault monitor's plausibility checks.
        encoder_bits: Its encoders' resolution (bits per revolution; None: exact), likewise.
        torque_delay: How much older (s) its torque readings are than the encoder sample they come with: the
            plant's physics step, as its identification takes it (the payload estimator and the fault monitor form
            their equations at the state this far back).
        fault_reaction: What the monitored rows do after detecting a collision, a slip or a drive fault
            (:data:`delta_env.faults.FAULT_REACTIONS`).
        compliance: The drives' compliance (rotor inertia, gearhead stiffness and damping per joint,
            :class:`~controllers.compliance.DriveCompliance`) as identified or from the data sheet; None: rigid drives.
            With it the servo layer notches its torque at each joint's drive mode (:func:`row_servo`).
    """

    mid: ModelParameters
    mid_f: ModelParameters
    mid_f_rods: ModelParameters
    drive_lag: tuple[float, float, float] | None = None
    stribeck_excess: tuple[float, float, float] | None = None
    tares: Mapping[str, float] = field(default_factory=dict)
    empty_moves: Mapping[str, EmptyMoveSums] = field(default_factory=dict)
    pd_gains: tuple[float, float] = (DEFAULT_KP, DEFAULT_KD)
    servo: Literal["servo", "pd"] = "servo"
    residual_policy: Path | None = None
    geometry: DeltaGeometry = NOMINAL_GEOMETRY
    masses: DeltaMasses = NOMINAL_MASSES
    drive: DriveLimits = field(default_factory=DriveLimits)
    encoder_bits: int | None = ENCODER_BITS
    torque_delay: float = MEASURED_TORQUE_DELAY
    fault_reaction: Literal["continue", "slow", "stop"] = "continue"
    compliance: DriveCompliance | None = None

    def __post_init__(self) -> None:
        if self.servo not in SERVOS:
            raise ValueError(f"servo must be one of {', '.join(SERVOS)}, got {self.servo!r}")
        if self.drive_lag is not None:
            require_joint_vector("drive_lag", self.drive_lag, 0.0, MAX_TIME_CONSTANT, unit="s")
        if self.stribeck_excess is not None:
            require_joint_vector("stribeck_excess", self.stribeck_excess, 0.0, TORQUE_LIMIT, unit="N m")
        require_torque_age(self.torque_delay)

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
    :func:`controllers.feedforward.controller_name`). With compliant drives (``setup.compliance``) its servo layer
    holds the rotors at the reference plus the gearheads' deflection (docs/design.md section 6, "The deflection
    feedforward"); the paper's PD (``servo="pd"``) holds them at the reference."""
    if key not in MODEL_ROWS:
        raise ValueError(f"{key!r} is not a model row; choose from {', '.join(MODEL_ROWS)}")
    row = MODEL_ROWS[key]
    if row.leads_lag and setup.drive_lag is None:
        raise ValueError(f"{key!r} needs the identified drive lag; ControllerSetup.drive_lag is None")
    parameters = row.model_parameters(setup)
    dynamics = DeltaDynamics.of_robot(setup.geometry, setup.masses, parameters, forearm_rods=row.forearm_rods)
    servo = row_servo(setup, dynamics)
    return model_controller(
        parameters,
        forearm_rods=row.forearm_rods,
        regressor=row.regressor,
        tare=setup.tares.get(key, 0.0),
        empty_moves=setup.empty_moves.get(key),
        servo=servo,
        name=name,
        geometry=setup.geometry,
        masses=setup.masses,
        drive_lag=setup.drive_lag if row.leads_lag else None,
        torque_delay=setup.torque_delay,
        compliance=setup.compliance if isinstance(servo, JointServo) else None,
    )


def row_servo(setup: ControllerSetup, dynamics: DeltaDynamics) -> JointFeedback:
    """The feedback of a model row with model ``dynamics``: the servo layer on that model and the identified drive lag
    (``setup.servo == "servo"``), or the paper's PD with ``setup.pd_gains``. The servo pushes at rest the breakaway
    torque of the model's friction: its Coulomb friction plus the identified Stribeck excess (none for a model
    without friction). With compliant drives (``setup.compliance``) it notches its torque at each joint's drive mode
    (:class:`~controllers.servo.ResonanceNotch`) and places its gains on the rotor alone inside a backlash's band
    (:attr:`~controllers.compliance.DriveCompliance.resolved_backlash`).

    Raises:
        ValueError: for the servo layer without an identified drive lag.
    """
    if setup.servo == "pd":
        return PDController(*setup.pd_gains)
    if setup.drive_lag is None:
        raise ValueError(
            "the servo layer's gains need the identified drive lag (ControllerSetup.drive_lag is None); "
            "identify it, or use servo='pd'"
        )
    step = DEFAULT_FRICTION_WIDTH if setup.encoder_bits is None else encoder_resolution(setup.encoder_bits)
    window = rate_window(setup.encoder_bits, PHYSICS_TIMESTEP)
    inertia = joint_inertia(dynamics.inverse_dynamics)
    coulomb = np.array(dynamics.parameters.coulomb)
    excess = setup.stribeck_excess if setup.stribeck_excess is not None and coulomb.any() else (0.0, 0.0, 0.0)
    compliance, breakaway = setup.compliance, coulomb + excess
    if compliance is None:
        return JointServo(servo_gains(inertia, breakaway, setup.drive_lag, friction_width=step), rate_window=window)
    return compliant_servo(
        inertia,
        breakaway,
        setup.drive_lag,
        compliance,
        friction_width=step,
        rate_window=window,
        rotor_friction=coulomb,
    )
