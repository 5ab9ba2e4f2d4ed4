"""The controllers of the comparison, by key, and the one factory that builds them (docs/design.md section 6).

Every controller is built from the datasheet geometry and masses of the robot it was identified on
(:attr:`ControllerSetup.geometry`, :attr:`ControllerSetup.masses`) and the identified parameters only; the
oracle row is the labelled exception that knows the plant (and, from the evaluation, the payloads).
:func:`controllers.feedforward.model_controller` is the one builder of a model-based controller:
:func:`build_controller` uses it for every model row, and the residual policy file rebuilds its base with it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from controllers.base import DEFAULT_KD, DEFAULT_KP, Controller, PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import OracleController, model_controller
from controllers.monitor import FaultMonitor, MonitoredController
from controllers.payload import EmptyMoveSums, PayloadEstimator
from controllers.residual import DEFAULT_POLICY_PATH, ResidualPolicy, load_residual_controller, residual_controller
from delta_env.drive import DriveLimits
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.sensors import ENCODER_BITS, encoder_resolution

CONTROLLER_LABELS = {
    "pd": "PD",
    "mkh": "MKH+PD",
    "mid": "MId+PD",
    "mid_f": "MId+F+PD",
    "mid_f_r": "MId+F+R+PD",
    "mid_f_rls": "MId+F+R+RLS+PD",
    "mid_f_rls_ref": "MId+F+R+RLS(ref)+PD",
    "mid_f_rls_lag": "MId+F+R+RLS+lag+PD",
    "oracle": "Oracle+PD (bound)",
    "residual": "Residual + its base",
}
"""Controller keys and their labels. ``+R``: the identified model with rod forearms
(``DeltaDynamics(forearm_rods=True)``, beyond the paper), which the payload estimators use. ``mid_f_rls``
estimates the payload on the Kalman-smoothed joint states (the default estimator); ``mid_f_rls_ref`` on the
reference, for comparison. ``mid_f_rls_lag`` is ``mid_f_rls`` with its feedforward led through the
inverse of the identified drive lag (:class:`~controllers.feedforward.LagCompensatedController`). The oracle
knows the plant and the true payloads: an upper bound, not a controller. ``residual`` is the learned
residual policy (:mod:`controllers.residual`) on the base it was trained on, rebuilt from the policy file (the
policy file names its base: ``BaseSetup.name``)."""

ESTIMATOR_REGRESSORS: dict[str, Literal["smoothed", "reference"]] = {
    "mid_f_rls": "smoothed",
    "mid_f_rls_ref": "reference",
    "mid_f_rls_lag": "smoothed",
}
"""The payload estimator variant of each RLS controller key."""

ESTIMATING_KEYS = (*ESTIMATOR_REGRESSORS, "residual")
"""Controllers that estimate the payload: the RLS rows (tared by the experiment that runs them) and the
residual (its base's tare comes with the policy file)."""


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


def residual_policy_path(setup: ControllerSetup) -> Path:
    """The policy file of the ``residual`` row: ``setup.residual_policy``, or the shipped policy when None."""
    return DEFAULT_POLICY_PATH if setup.residual_policy is None else setup.residual_policy


def build_controller(
    key: str,
    setup: ControllerSetup,
    env: DeltaPickPlaceEnv | None = None,
    *,
    policy: ResidualPolicy | None = None,
) -> Controller:
    """The controller of ``key`` (see :data:`CONTROLLER_LABELS`).

    Args:
        key: Controller key.
        setup: Identified parameters, tares and gains.
        env: Needed for the oracle only, which inverts the env's plant; never given to the others.
        policy: For ``residual``: the policy of :func:`residual_policy_path` already loaded (a caller building
            many controllers loads it once); None loads it from the file.
    """
    if key not in CONTROLLER_LABELS:
        raise ValueError(f"unknown controller {key!r}; choose from {sorted(CONTROLLER_LABELS)}")
    label = CONTROLLER_LABELS[key]
    if key == "pd":
        return monitored(PDController(*setup.pd_gains), setup)
    if key == "residual":
        if policy is None:
            return monitored(load_residual_controller(residual_policy_path(setup), name=label), setup)
        return monitored(residual_controller(policy, name=label), setup)
    if key == "oracle":
        if env is None:
            raise ValueError("the oracle needs the env whose plant it inverts")
        # its own feedback gains (see OracleController); the monitor keeps a faulty reading from it, as from the rows
        return monitored(OracleController(env.plant_config), setup)
    return monitored(_model_row(key, setup, label), setup)


def _model_row(key: str, setup: ControllerSetup, label: str) -> Controller:
    """The controller of a model-based row, without its monitor."""
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
            name=label,
            geometry=setup.geometry,
            masses=setup.masses,
            drive_lag=setup.drive_lag if key == "mid_f_rls_lag" else None,
        )
    parameters = {"mkh": None, "mid": setup.mid, "mid_f": setup.mid_f}[key]
    return model_controller(
        parameters, pd_gains=setup.pd_gains, name=label, geometry=setup.geometry, masses=setup.masses
    )


def fault_monitor(setup: ControllerSetup) -> FaultMonitor:
    """A fault monitor on the identified model (MId+F+R) of the robot of ``setup``, with its drive and encoders."""
    return FaultMonitor(
        estimation_model(setup),
        setup.drive.peak_torque,
        drive_lag=setup.drive_lag,
        encoder_step=None if setup.encoder_bits is None else encoder_resolution(setup.encoder_bits),
    )


def monitored(controller: Controller, setup: ControllerSetup) -> MonitoredController:
    """``controller`` behind the :func:`fault_monitor` of ``setup``, reacting as ``setup.fault_reaction`` says."""
    return MonitoredController(controller, fault_monitor(setup), setup.fault_reaction)


def payload_estimator(key: str, setup: ControllerSetup) -> PayloadEstimator:
    """A fresh, untared payload estimator of the RLS controller ``key`` (the one its controller runs), without
    seeded empty moves."""
    if key not in ESTIMATOR_REGRESSORS:
        raise ValueError(f"{key!r} estimates no payload; RLS controllers: {sorted(ESTIMATOR_REGRESSORS)}")
    return build_controller(key, dataclasses.replace(setup, tares={}, empty_moves={})).estimator


def estimation_model(setup: ControllerSetup) -> DeltaDynamics:
    """MId+F+R: the identified model with rod forearms, of the payload estimators and their feedforward."""
    return DeltaDynamics.of_robot(setup.geometry, setup.masses, setup.mid_f_rods, forearm_rods=True)
