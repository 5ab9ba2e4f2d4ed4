"""One drive's pick rate on a design: the timed standard cycle, its check against the drive, the full planner.

Picks per minute on the industry's 25/305/25 mm standard cycle centred on the axis on the belt, across the
conveyors (at the default :data:`~delta_env.trajectories.WORKING_HEIGHT`, the data-sheet placement of
:func:`delta_env.cycles.standard_cycle`; a reconfigured base moves the belt in its frame), as ``python -m
eval.rate`` scores it (:func:`eval.metrics.picks_per_min`: one cycle of dwell, carry, dwell and empty move,
repeated), every move timed by the time-optimal planner of the pick-rate work
(:class:`controllers.payload_timing.PayloadTiming` in ``"declared"`` mode over
:class:`controllers.timing.TimeOptimalPlanner`) on the design's model
(:func:`eval.design.model.design_model`) whose armature is the drive's rotor inertia times the ratio
squared. The planner keeps its 10 % margin of the peak torque and of the maximum speed; the moves may use the
whole envelope left (:data:`TORQUE_SHARE`), and each move with the dwell after it keeps 95 % of the rated torque
RMS (the thermal limit of the repeated cycle).
:func:`planned_rate` is this full path (about 1 s per drive); :mod:`eval.design.screening` is the cheap one and
:mod:`eval.design.codesign` chooses the drive.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from controllers.dynamics import DeltaDynamics
from controllers.payload_timing import PayloadTiming
from controllers.timing import TimeOptimalPlanner
from delta_env.catalogue import DriveOption
from delta_env.cycles import standard_cycle
from delta_env.drive import DriveLimits
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timed_cycles import TimedCycles
from delta_env.trajectories import WORKING_HEIGHT, Trajectory
from delta_env.validation import require_in
from eval import metrics
from eval.design.model import (
    CYCLE_DWELL,
    DRIVE,
    design_model,
    path_limits,
    payload_profile,
    require_belt_height,
)

TORQUE_SHARE = 1.0
"""Share of the planner's envelope (after its margin) the moves may use: the drive's whole capability. The
controllers' tracking share (:data:`delta_env.timing.DEFAULT_TORQUE_SHARE`) is a property of today's controller
on the nominal plant, not of a design."""


@dataclass(frozen=True)
class DriveCheck:
    """How a timed cycle uses its drive, by the model (each share <= 1 holds).

    Attributes:
        peak_torque: Largest |tau| over the cycle (N m).
        rms_torque: Largest joint RMS torque over the repeated cycle (N m).
        max_speed: Largest |theta_dot| (rad/s).
        peak_share: Largest |tau| over the envelope's bound at that sample's speed and direction.
        rms_share: ``rms_torque`` over the rated torque.
        speed_share: ``max_speed`` over the maximum speed.
    """

    peak_torque: float
    rms_torque: float
    max_speed: float
    peak_share: float
    rms_share: float
    speed_share: float

    @property
    def holds(self) -> bool:
        """True if peak torque, RMS torque and speed are all within the drive."""
        return max(self.peak_share, self.rms_share, self.speed_share) <= 1.0


@dataclass(frozen=True)
class PickRate:
    """One drive's timed standard cycle with one payload.

    Attributes:
        option: The drive.
        payload: Carried mass (kg).
        picks_per_min: Picks per minute of the repeated cycle.
        check: Its use of the drive.
        cycles: The timed cycle (dwell, carry, dwell, empty move), for a plant to run.
        exact: True if timed by the full planner, False if by the cheap path.
    """

    option: DriveOption
    payload: float
    picks_per_min: float
    check: DriveCheck
    cycles: TimedCycles
    exact: bool


def drive_model(geometry: DeltaGeometry, option: DriveOption, masses: DeltaMasses | None = None) -> DeltaDynamics:
    """The design's model (:func:`eval.design.model.design_model`) with ``option``'s reflected rotor inertia."""
    return design_model(geometry, masses, dataclasses.replace(DRIVE, armature=option.armature))


def drive_timing(
    geometry: DeltaGeometry,
    option: DriveOption,
    payload: float,
    masses: DeltaMasses | None = None,
    torque_share: float = TORQUE_SHARE,
) -> PayloadTiming:
    """The full planner's timing of ``option`` on the design, every carry for ``payload`` (kg): what a plant runs."""
    planner = TimeOptimalPlanner(drive_model(geometry, option, masses), option.limits, drive_lag=DRIVE.actuator_lag)
    return PayloadTiming(planner, "declared", payload, dwell=CYCLE_DWELL, torque_share=torque_share)


def timed_cycle(
    geometry: DeltaGeometry, timing: object, payload: float, belt_height: float = WORKING_HEIGHT
) -> TimedCycles:
    """One standard cycle from rest at its pick point, centred on the axis on the belt at ``belt_height`` (m, base
    frame; < 0), every move timed by ``timing`` (a :class:`delta_env.timing.MoveTiming`)."""
    return standard_cycle(
        geometry,
        n_cycles=1,
        center=(0.0, 0.0, require_belt_height(belt_height)),
        start="pick",
        dwell=CYCLE_DWELL,
        limits=path_limits(geometry),
        dt=CONTROL_PERIOD,
        timing=timing,
        declared_masses=[payload],
    )


def drive_check(model: DeltaDynamics, trajectory: Trajectory, payload: float, limits: DriveLimits) -> DriveCheck:
    """Peak torque against the speed-dependent envelope, RMS torque against the rated torque and speed against the
    maximum speed along ``trajectory`` (one period of a repeated cycle) carrying ``payload`` (kg) while gripped."""
    torque = model.inverse_dynamics(
        trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot, payload_profile(trajectory, payload)
    )
    lower, upper = limits.torque_bounds(trajectory.theta_dot)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(torque >= 0.0, torque / upper, torque / lower)
    share = np.where(np.isnan(share), 0.0, share)  # 0 / 0: no torque at the maximum speed
    rms = float(np.max(np.sqrt(np.mean(torque**2, axis=0))))
    speed = float(np.max(np.abs(trajectory.theta_dot)))
    return DriveCheck(
        peak_torque=float(np.max(np.abs(torque))),
        rms_torque=rms,
        max_speed=speed,
        peak_share=float(np.max(share)),
        rms_share=rms / limits.rated_torque,
        speed_share=speed / limits.max_speed,
    )


def cycle_rate(
    geometry: DeltaGeometry,
    option: DriveOption,
    payload: float,
    cycles: TimedCycles,
    exact: bool,
    masses: DeltaMasses | None,
) -> PickRate:
    """The pick rate and drive check of ``cycles`` (one period of the repeated cycle) on ``option``."""
    reference = cycles.trajectory()
    check = drive_check(drive_model(geometry, option, masses), reference, payload, option.limits)
    rate = metrics.picks_per_min(reference.xyz_dot, reference.pick_indices, reference.dt)
    return PickRate(option, float(payload), rate, check, cycles, exact)


def planned_rate(
    geometry: DeltaGeometry,
    option: DriveOption,
    payload: float,
    masses: DeltaMasses | None = None,
    belt_height: float = WORKING_HEIGHT,
) -> PickRate:
    """The standard cycle of ``option`` with ``payload`` (kg) on the belt at ``belt_height`` (m, base frame) timed
    by the full planner.

    Raises:
        ValueError: on a bad payload or belt height, or if the drive cannot run the payload (no verified law
            within the envelope and the rating).
    """
    require_in("payload", payload, 0.0, unit="kg")
    cycles = timed_cycle(geometry, drive_timing(geometry, option, payload, masses), payload, belt_height)
    return cycle_rate(geometry, option, payload, cycles, True, masses)
