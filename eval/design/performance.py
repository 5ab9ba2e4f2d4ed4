"""The figures of merit of one Delta geometry: workspace, torque on the standard cycle, pick rate, speed.

The workspace is the data-sheet cylinder (:func:`delta_env.cylinder.data_sheet_cylinder`): the largest
dexterous axis-centred cylinder standing on the belt whose top reaches 100 mm above it (the lift and a
product's clearance). The task region, the disc of radius :data:`TASK_RADIUS` holding both conveyor zones
over :data:`TASK_BAND`, must be dexterous too: a constraint, not a credit.

Every design is judged by the design model (:mod:`eval.design.model`: rod forearms, the masses of
:func:`delta_env.scaling.scaled_masses` and the same motors on every design) on the same task: the industry's
25/305/25 mm cycle carrying :data:`PAYLOAD` at the places :data:`TASK_CYCLES`, which lie in the
pick-and-place region of the conveyors.

Pick rate: each design gets the drive (a catalogue motor behind a planetary gearbox) that gives it the most
picks per minute on the standard cycle at the rated payload, timed by the time-optimal planner within that
drive's envelope and thermal rating (:mod:`eval.design.codesign`); the light payload's rate is that drive's.
The cycle is centred on the axis on the belt: at :data:`WORKING_HEIGHT` (the data-sheet placement) unless a
reconfigured base moves the belt in the base frame (``evaluate(..., belt_height=...)``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics
from delta_env import kinematics, workspace
from delta_env.catalogue import CATALOGUE, DriveOption
from delta_env.cycles import PICK_ZONE, PLACE_ZONE, STANDARD_LIFT, STANDARD_TRAVEL, standard_cycle
from delta_env.cylinder import PRODUCT_CLEARANCE, Cylinder, axis_stretch, data_sheet_cylinder, disc_radii
from delta_env.geometry import TORQUE_LIMIT, DeltaGeometry, DeltaMasses
from delta_env.scaling import scaled_masses
from delta_env.trajectories import STANDARD_PEAK_ACCELERATION, WORKING_HEIGHT, Trajectory
from delta_env.validation import require_in, require_positive
from eval.design.codesign import DriveChoice, choose_drive
from eval.design.model import CYCLE_DWELL, design_model, path_limits, payload_profile, require_belt_height

PAYLOAD = 3.8
"""Payload of the standard cycle (kg): the test payload of the dynamic-model paper (docs/design.md section 4)."""

CYCLE_ACCELERATION = STANDARD_PEAK_ACCELERATION
"""Peak Cartesian acceleration of the torque-rated cycle (m/s^2): the environment's default 3 g."""

JOINT_SPEED_LIMIT = 30.0
"""Joint speed limit (rad/s) of the end-effector speed figure: a 3000 rpm servo behind a 10:1 reducer."""

ANALYSIS_PERIOD = 0.002
"""Sample period (s) of the analysed cycles: peaks of the smooth quintic profiles move < 0.1 % from 1 ms."""

TASK_BAND = (WORKING_HEIGHT, WORKING_HEIGHT + STANDARD_LIFT)
"""Heights (m) the task needs: the conveyors and the 25 mm lift above them."""

TASK_BAND_HEIGHTS = 3
"""Heights of :data:`TASK_BAND` (its ends and middle) at which the task disc must be dexterous."""

TASK_RADIUS = float(np.max(np.hypot(*np.vstack((PICK_ZONE.corners(), PLACE_ZONE.corners()))[:, :2].T)))
"""Radius (m) of the smallest axis-centred disc holding both conveyor zones (0.461 m)."""

TASK_CYCLES = (
    ((0.0, 0.0, WORKING_HEIGHT), math.pi / 2),
    ((0.3, 0.0, WORKING_HEIGHT), math.pi / 2),
    ((-0.3, 0.0, WORKING_HEIGHT), math.pi / 2),
    ((0.0, 0.0, WORKING_HEIGHT), 0.0),
    ((0.0, 0.25, WORKING_HEIGHT), 0.0),
)
"""(centre (m), heading (rad)) of the standard cycles: from conveyor to conveyor at the middle and both
ends of the zones (chain 1's side and the opposite one), across the robot, and along the place conveyor."""

STANDARD_TRAVEL_HALF = STANDARD_TRAVEL / 2.0
"""Distance (m) of the pick and of the place point from the centre of a standard cycle."""

ASSEMBLY_MARGIN = 0.05
"""The forearm must exceed r + l1 by this much (m): the plant assembles with its arms horizontal, and home
stays a usable height below the base."""


@dataclass(frozen=True)
class CycleFigures:
    """Torque figures of one standard cycle.

    Attributes:
        peak_torque: Largest |tau_i| over the cycle (N m).
        rms_torque: RMS of tau over samples and joints (N m).
    """

    peak_torque: float
    rms_torque: float


@dataclass(frozen=True)
class Performance:
    """The figures of merit of one geometry; the infeasible ones say why.

    Attributes:
        geometry: The design (m).
        masses: Its masses (kg), :func:`delta_env.scaling.scaled_masses`.
        cylinder: The data-sheet cylinder (module docstring), or None when the dexterous axis from the belt
            does not reach :data:`~delta_env.cylinder.REQUIRED_TOP`.
        shortfall: Task radius minus the dexterous disc radius over the task band (m), <= 0 when met.
        clearance_shortfall: :data:`~delta_env.cylinder.REQUIRED_TOP` minus the top of the dexterous axis
            from the belt (m), <= 0 when met (inf when the belt's axis point is not dexterous).
        workspace_m3: Volume of ``cylinder`` (m^3), 0 without one.
        peak_torque_nm: Largest peak |tau| over the task cycles at :data:`CYCLE_ACCELERATION` (N m).
        rms_torque_nm: Largest RMS torque over the task cycles (N m).
        picks_per_min: Picks per minute on the standard cycle on the belt at the rated payload with the design's
            drive (:func:`eval.design.codesign.choose_drive`); 0 without a drive that runs it.
        picks_per_min_light: The same drive's picks per minute at the light payload.
        speed_m_s: Platform speed reachable in every direction over the task region at
            :data:`JOINT_SPEED_LIMIT` (m/s), its minimum over the region.
        min_conditioning: Smallest 1 / cond(J) over the task region.
        cycles: Figures of each task cycle.
        reason: Why the design is infeasible ("" when feasible).
        drive: The chosen drive, its timed cycles and their checks (None without one).
    """

    geometry: DeltaGeometry
    masses: DeltaMasses
    cylinder: Cylinder | None
    shortfall: float
    clearance_shortfall: float
    workspace_m3: float
    peak_torque_nm: float
    rms_torque_nm: float
    picks_per_min: float
    picks_per_min_light: float
    speed_m_s: float
    min_conditioning: float
    cycles: tuple[CycleFigures, ...] = field(default_factory=tuple)
    reason: str = ""
    drive: DriveChoice | None = None

    @property
    def cylinder_diameter_m(self) -> float:
        """Diameter of the data-sheet cylinder (m), 0 without one."""
        return self.cylinder.diameter if self.cylinder else 0.0

    @property
    def cylinder_height_m(self) -> float:
        """Height of the data-sheet cylinder (m), 0 without one."""
        return self.cylinder.height if self.cylinder else 0.0

    @property
    def cylinder_top_m(self) -> float:
        """Height of the data-sheet cylinder's top (m), NaN without one."""
        return self.cylinder.top if self.cylinder else math.nan

    @property
    def feasible(self) -> bool:
        """True if the task fits, the torque limit holds and a catalogue drive runs the rated payload."""
        return not self.reason


def assembly_gap(geometry: DeltaGeometry) -> float:
    """How far (m) the forearm falls short of r + l1 + :data:`ASSEMBLY_MARGIN`; <= 0 when the design assembles."""
    return geometry.r + geometry.l1 + ASSEMBLY_MARGIN - geometry.l2


def task_cycle(
    geometry: DeltaGeometry,
    centre: tuple[float, float, float],
    heading: float,
    *,
    n_cycles: int = 1,
    peak_acceleration: float = CYCLE_ACCELERATION,
    dt: float = ANALYSIS_PERIOD,
) -> Trajectory:
    """The standard 25/305/25 mm cycle of a design at ``centre`` (m) along ``heading`` (rad), from rest at its pick
    point: the design's figures (motion time, peak and RMS torque) are those of whole cycles and nothing else."""
    centre = tuple(float(c) for c in centre)
    return _task_cycle(geometry, centre, float(heading), n_cycles, float(peak_acceleration), float(dt))


@functools.lru_cache(maxsize=256)
def _task_cycle(
    geometry: DeltaGeometry,
    centre: tuple[float, ...],
    heading: float,
    n_cycles: int,
    peak_acceleration: float,
    dt: float,
) -> Trajectory:
    """:func:`task_cycle`, kept per process (a :class:`Trajectory` is read-only): the reconfiguration's task
    profiles share their cycles at the centre of the belt."""
    return standard_cycle(
        geometry,
        peak_acceleration,
        n_cycles=n_cycles,
        center=centre,
        heading=heading,
        dwell=CYCLE_DWELL,
        start="pick",
        limits=path_limits(geometry),
        dt=dt,
    )


def cycle_figures(model: DeltaDynamics, trajectories: Sequence[Trajectory], payload: float) -> list[CycleFigures]:
    """Peak and RMS torque along each of ``trajectories`` carrying ``payload`` (kg) while the gripper holds: one
    inverse dynamics over the samples of all (per-sample arithmetic: each gets the numbers of a call of its own)."""
    if not trajectories:
        return []
    torque = model.inverse_dynamics(
        *(np.concatenate([getattr(t, name) for t in trajectories]) for name in ("theta", "theta_dot", "theta_ddot")),
        np.concatenate([payload_profile(t, payload) for t in trajectories]),
    )
    ends = np.cumsum([len(t.theta) for t in trajectories])[:-1]
    return [
        CycleFigures(peak_torque=float(np.max(np.abs(part))), rms_torque=float(np.sqrt(np.mean(part**2))))
        for part in np.split(torque, ends)
    ]


def task_region_points(radius: float = TASK_RADIUS, band: tuple[float, float] = TASK_BAND) -> NDArray[np.float64]:
    """Points (m) on rings of the task disc at the band's two heights, ``(n, 3)``."""
    require_positive("radius", radius, "m")
    rings = np.linspace(0.0, radius, 9)
    phi = np.linspace(0.0, 2.0 * math.pi, 36, endpoint=False)
    r, p, z = np.meshgrid(rings, phi, np.asarray(band, dtype=float), indexing="ij")
    return np.stack((r * np.cos(p), r * np.sin(p), z), axis=-1).reshape(-1, 3)


def evaluate(
    geometry: DeltaGeometry,
    *,
    payload: float = PAYLOAD,
    criteria: workspace.Criteria = workspace.DEXTEROUS,
    task_radius: float = TASK_RADIUS,
    cycles: tuple[tuple[tuple[float, float, float], float], ...] = TASK_CYCLES,
    masses: DeltaMasses | None = None,
    exact_drive: bool = False,
    belt_height: float = WORKING_HEIGHT,
    drives: Sequence[DriveOption] | None = None,
) -> Performance:
    """All figures of merit of ``geometry`` (see :class:`Performance`).

    Args:
        geometry: The design.
        payload: Carried mass on the task cycles (kg), >= 0.
        criteria: Dexterity criteria of the workspace.
        task_radius: Radius (m) of the disc that must be dexterous over the task band.
        cycles: (centre, heading) of the task cycles, inside the task region.
        masses: The design's masses; :func:`delta_env.scaling.scaled_masses` when None.
        exact_drive: Choose the drive with the full planner (:func:`eval.design.codesign.choose_drive`), not the
            cheap path of the optimizer.
        belt_height: Height of the conveyor surface in the base frame (m): the task band is it and the lift
            above it (:data:`TASK_BAND` at the default), and the pick-rate cycle is centred on the axis on it;
            a reconfigured base moves it (eval.design.mechanism).
        drives: The drives to choose from; None for the whole catalogue (a design already built keeps its own:
            ``(performance.drive.option,)``).
    """
    require_in("payload", payload, 0.0, math.inf, unit="kg")
    belt_height = require_belt_height(belt_height)
    band = (belt_height, belt_height + STANDARD_LIFT)
    masses = scaled_masses(geometry) if masses is None else masses
    band_radius, cylinder, from_belt = _workspace_figures(geometry, criteria, belt_height)
    shortfall = task_radius - band_radius
    required_top = belt_height + STANDARD_LIFT + PRODUCT_CLEARANCE
    clearance_shortfall = required_top - from_belt[1] if from_belt else math.inf
    points = task_region_points(task_radius, band)
    region = workspace.pose_measures(geometry, points)
    reasons = []
    if shortfall > 0.0:
        reasons.append(f"task region (radius {task_radius:.3f} m) not dexterous: short by {shortfall:.3f} m")
    if cylinder is None:
        reasons.append(f"no dexterous cylinder above the belt reaches {required_top:.3f} m")
    if assembly_gap(geometry) > 0.0:
        reasons.append(f"l2 = {geometry.l2:.3f} m < ra - rb + l1 + {ASSEMBLY_MARGIN} m (cannot assemble)")
    model = design_model(geometry, masses)
    trajectories = []
    try:
        for centre, heading in cycles:
            trajectories.append(task_cycle(geometry, centre, heading))
    except ValueError as error:
        reasons.append(f"task cycle not reachable: {error}")
    figures = cycle_figures(model, trajectories, payload)
    if figures and max(f.peak_torque for f in figures) > TORQUE_LIMIT:
        reasons.append(f"peak torque {max(f.peak_torque for f in figures):.0f} N m > limit {TORQUE_LIMIT:.0f} N m")
    drive = None
    if len(figures) == len(cycles):
        options = CATALOGUE if drives is None else tuple(drives)
        drive = _chosen_drive(geometry, masses, options, exact_drive, belt_height)
        if drive.option is None:
            reasons.append("no catalogue drive runs the rated payload on the standard cycle")
    speed = workspace.isotropic_speed(geometry, points, JOINT_SPEED_LIMIT, region)
    return Performance(
        geometry=geometry,
        masses=masses,
        cylinder=cylinder,
        shortfall=shortfall,
        clearance_shortfall=clearance_shortfall,
        workspace_m3=cylinder.volume if cylinder else 0.0,
        peak_torque_nm=max((f.peak_torque for f in figures), default=math.inf),
        rms_torque_nm=max((f.rms_torque for f in figures), default=math.inf),
        picks_per_min=drive.picks_per_min if drive else 0.0,
        picks_per_min_light=drive.picks_per_min_light if drive else 0.0,
        speed_m_s=float(np.min(speed)) if region.reachable.all() else 0.0,
        min_conditioning=float(np.min(np.nan_to_num(region.conditioning))),
        cycles=tuple(figures),
        reason="; ".join(reasons),
        drive=drive,
    )


@functools.lru_cache(maxsize=1024)
def _workspace_figures(
    geometry: DeltaGeometry, criteria: workspace.Criteria, belt_height: float
) -> tuple[float, Cylinder | None, tuple[float, float] | None]:
    """What :func:`evaluate` needs of the workspace above a belt, whatever the task: the smallest dexterous disc
    radius (m) over the task band, the data-sheet cylinder and the axis stretch from the belt. Kept per process:
    the reconfiguration evaluates each screw setting for every task profile."""
    band = np.linspace(belt_height, belt_height + STANDARD_LIFT, TASK_BAND_HEIGHTS)
    band_radius = float(np.min(disc_radii(geometry, band, criteria)))
    cylinder = data_sheet_cylinder(geometry, criteria, belt=belt_height)
    return band_radius, cylinder, axis_stretch(geometry, belt_height, criteria, floor=belt_height)


@functools.lru_cache(maxsize=1024)
def _chosen_drive(
    geometry: DeltaGeometry, masses: DeltaMasses, options: tuple[DriveOption, ...], exact: bool, belt_height: float
) -> DriveChoice:
    """:func:`~eval.design.codesign.choose_drive`, kept per process: it depends on the design and the belt, not on
    the task profile."""
    return choose_drive(geometry, masses, options, exact=exact, belt_height=belt_height)


def peak_torque_map(
    geometry: DeltaGeometry,
    points: NDArray[np.float64],
    *,
    payload: float = PAYLOAD,
    acceleration: float = CYCLE_ACCELERATION,
    masses: DeltaMasses | None = None,
) -> NDArray[np.float64]:
    """Largest |tau_i| (N m) to accelerate the payload from rest at ``acceleration`` along +-x, +-y, +-z.

    Args:
        geometry: The design.
        points: Platform positions (m), ``(..., 3)``; unreachable ones give NaN.
        payload: Carried mass (kg).
        acceleration: Magnitude of the platform acceleration (m/s^2).
        masses: The design's masses; scaled when None.

    Returns:
        ``(...)`` N m.
    """
    model = design_model(geometry, masses)
    points = np.asarray(points, dtype=float)
    reachable = workspace.pose_measures(geometry, points).reachable
    flat = points[reachable]
    peak = np.zeros(len(flat))
    for direction in np.vstack((np.eye(3), -np.eye(3))):
        theta, theta_dot, theta_ddot = kinematics.cartesian_to_joint(
            geometry, flat, np.zeros_like(flat), np.broadcast_to(acceleration * direction, flat.shape)
        )
        torque = model.inverse_dynamics(theta, theta_dot, theta_ddot, payload)
        peak = np.maximum(peak, np.max(np.abs(torque), axis=-1))
    result = np.full(points.shape[:-1], np.nan)
    result[reachable] = peak
    return result
