"""The figures of merit of one Delta geometry: workspace, torque on the standard cycle, speed.

Every design carries the masses of :func:`delta_env.scaling.scaled_masses` and is judged by the model with
rod forearms (``DeltaDynamics(..., forearm_rods=True)``), on the same task: the industry's 25/305/25 mm
cycle carrying :data:`PAYLOAD` at the places :data:`TASK_CYCLES`, which lie in the pick-and-place region of
the conveyors.

Cycle time at the torque limit: along a fixed path, slowing time by 1/s scales every velocity by s and every
acceleration by s^2, so the torque is tau = G + s^2 D with G the static (gravity) torque and D = tau - G at
the reference timing (the rod-forearm terms are quadratic in the rates too). For every sample and joint,
|G + u D| <= limit is an interval of u = s^2; the largest u in all of them gives the fastest admissible
timing exactly, with no search.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics
from delta_env import kinematics, workspace
from delta_env.geometry import TORQUE_LIMIT, DeltaGeometry, DeltaMasses
from delta_env.scaling import scaled_masses
from delta_env.trajectories import (
    PICK_ZONE,
    PLACE_ZONE,
    STANDARD_LIFT,
    STANDARD_PEAK_ACCELERATION,
    STANDARD_TRAVEL,
    WORKING_HEIGHT,
    Trajectory,
    WorkspaceLimits,
    standard_cycle,
)
from delta_env.validation import require_in, require_positive

PAYLOAD = 3.8
"""Payload of the standard cycle (kg): the test payload of the dynamic-model paper (DESIGN.md section 4)."""

CYCLE_ACCELERATION = STANDARD_PEAK_ACCELERATION
"""Peak Cartesian acceleration of the torque-rated cycle (m/s^2): the environment's default 3 g."""

JOINT_SPEED_LIMIT = 30.0
"""Joint speed limit (rad/s) of the end-effector speed figure: a 3000 rpm servo behind a 10:1 reducer."""

ANALYSIS_PERIOD = 0.002
"""Sample period (s) of the analysed cycles: peaks of the smooth quintic profiles move < 0.1 % from 1 ms."""

CYCLE_DWELL = 0.1
"""Rest at the pick and at the place point (s); process time, left out of the cycle time."""

TASK_BAND = (WORKING_HEIGHT, WORKING_HEIGHT + STANDARD_LIFT)
"""Heights (m) the task needs: the conveyors and the 25 mm lift above them."""

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

_STATIC_TORQUE_EPS = 1e-12


@dataclass(frozen=True)
class CycleFigures:
    """Torque figures of one standard cycle.

    Attributes:
        peak_torque: Largest |tau_i| over the cycle (N m).
        rms_torque: RMS of tau over samples and joints (N m).
        motion_time: Duration of the two moves at the reference acceleration (s), dwells left out.
        fastest_motion_time: Duration of the two moves at the fastest timing whose peak torque is the
            motor limit (s); inf when holding the payload at rest already exceeds it.
    """

    peak_torque: float
    rms_torque: float
    motion_time: float
    fastest_motion_time: float


@dataclass(frozen=True)
class Performance:
    """The figures of merit of one geometry; the infeasible ones say why.

    Attributes:
        geometry: The design (m).
        masses: Its masses (kg), :func:`delta_env.scaling.scaled_masses`.
        cylinder: Largest dexterous cylinder holding the task region, or None.
        shortfall: Task radius minus the dexterous radius over the task band (m), <= 0 when met.
        workspace_m3: Volume of ``cylinder`` (m^3), 0 without one.
        peak_torque_nm: Largest peak |tau| over the task cycles at :data:`CYCLE_ACCELERATION` (N m).
        rms_torque_nm: Largest RMS torque over the task cycles (N m).
        cycle_time_s: Motion time of the slowest task cycle at the torque limit (s).
        speed_m_s: Platform speed reachable in every direction over the task region at
            :data:`JOINT_SPEED_LIMIT` (m/s), its minimum over the region.
        min_conditioning: Smallest 1 / cond(J) over the task region.
        cycles: Figures of each task cycle.
        reason: Why the design is infeasible ("" when feasible).
    """

    geometry: DeltaGeometry
    masses: DeltaMasses
    cylinder: workspace.Cylinder | None
    shortfall: float
    workspace_m3: float
    peak_torque_nm: float
    rms_torque_nm: float
    cycle_time_s: float
    speed_m_s: float
    min_conditioning: float
    cycles: tuple[CycleFigures, ...] = field(default_factory=tuple)
    reason: str = ""

    @property
    def feasible(self) -> bool:
        """True if the task fits and the torque limit holds."""
        return not self.reason


def design_model(geometry: DeltaGeometry, masses: DeltaMasses | None = None) -> DeltaDynamics:
    """The rod-forearm model of a design with its scaled masses (or ``masses``)."""
    m = scaled_masses(geometry) if masses is None else masses
    return DeltaDynamics(geometry, m1=m.m1, m2=m.m2, m0=m.m0, forearm_rods=True)


def path_limits(geometry: DeltaGeometry, criteria: workspace.Criteria = workspace.DEXTEROUS) -> WorkspaceLimits:
    """Limits for paths of any design: its whole reach; the dexterity checks are the design study's own."""
    radius, z_min, z_max = workspace.reach_bounds(geometry, criteria.theta_range)
    return WorkspaceLimits(radius=radius, z_min=z_min, z_max=z_max, min_abs_k=1e-9, min_abs_det_a=1e-9)


def task_cycle(
    geometry: DeltaGeometry,
    centre: tuple[float, float, float],
    heading: float,
    *,
    n_cycles: int = 1,
    peak_acceleration: float = CYCLE_ACCELERATION,
    dt: float = ANALYSIS_PERIOD,
) -> Trajectory:
    """The standard 25/305/25 mm cycle of a design at ``centre`` (m) along ``heading`` (rad)."""
    return standard_cycle(
        geometry,
        peak_acceleration,
        n_cycles=n_cycles,
        center=centre,
        heading=heading,
        dwell=CYCLE_DWELL,
        limits=path_limits(geometry),
        dt=dt,
    )


def payload_profile(trajectory: Trajectory, payload: float) -> NDArray[np.float64]:
    """The carried mass (kg) at each sample: ``payload`` while the gripper holds, else 0, ``(N,)``."""
    return np.where(trajectory.gripper, payload, 0.0)


def fastest_time_scale(static: NDArray[np.float64], dynamic: NDArray[np.float64], limit: float) -> float:
    """Largest u = s^2 with |static + u dynamic| <= limit everywhere (module docstring); 0 if none.

    Args:
        static: Torques at rest (N m), any shape.
        dynamic: Torques of the motion at the reference timing minus ``static`` (N m), same shape.
        limit: Torque limit (N m), > 0.
    """
    require_positive("limit", limit, "N m")
    if np.any(np.abs(static) > limit):
        return 0.0
    moving = np.abs(dynamic) > _STATIC_TORQUE_EPS
    # the binding end of each interval: (limit - G)/D for D > 0, (-limit - G)/D for D < 0
    bound = np.where(dynamic[moving] > 0.0, limit - static[moving], -limit - static[moving]) / dynamic[moving]
    return float(np.min(bound)) if bound.size else math.inf


def cycle_figures(
    model: DeltaDynamics, trajectory: Trajectory, payload: float, limit: float = TORQUE_LIMIT
) -> CycleFigures:
    """Peak and RMS torque along ``trajectory`` and its fastest timing under ``limit``."""
    carried = payload_profile(trajectory, payload)
    torque = model.inverse_dynamics(trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot, carried)
    zero = np.zeros_like(trajectory.theta)
    static = model.inverse_dynamics(trajectory.theta, zero, zero, carried)
    moving = np.any(trajectory.theta_dot != 0.0, axis=-1) | np.any(trajectory.theta_ddot != 0.0, axis=-1)
    motion_time = float(np.count_nonzero(moving)) * trajectory.dt
    scale = fastest_time_scale(static, torque - static, limit)
    fastest = motion_time / math.sqrt(scale) if scale > 0.0 else math.inf
    return CycleFigures(
        peak_torque=float(np.max(np.abs(torque))),
        rms_torque=float(np.sqrt(np.mean(torque**2))),
        motion_time=motion_time,
        fastest_motion_time=fastest,
    )


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
) -> Performance:
    """All figures of merit of ``geometry`` (see :class:`Performance`).

    Args:
        geometry: The design.
        payload: Carried mass on the task cycles (kg), >= 0.
        criteria: Dexterity criteria of the workspace.
        task_radius: Radius (m) the dexterous cylinder must have over :data:`TASK_BAND`.
        cycles: (centre, heading) of the task cycles, inside the task region.
        masses: The design's masses; :func:`delta_env.scaling.scaled_masses` when None.
    """
    require_in("payload", payload, 0.0, math.inf, unit="kg")
    masses = scaled_masses(geometry) if masses is None else masses
    search = workspace.largest_cylinder(geometry, criteria, required_radius=task_radius, required_band=TASK_BAND)
    region = workspace.pose_measures(geometry, task_region_points(task_radius))
    reasons = []
    if search.cylinder is None:
        reasons.append(f"task region (radius {task_radius:.3f} m) not dexterous: short by {search.shortfall:.3f} m")
    if geometry.l2 < geometry.r + geometry.l1 + ASSEMBLY_MARGIN:
        reasons.append(f"l2 = {geometry.l2:.3f} m < ra - rb + l1 + {ASSEMBLY_MARGIN} m (cannot assemble)")
    model = design_model(geometry, masses)
    figures = []
    try:
        for centre, heading in cycles:
            figures.append(cycle_figures(model, task_cycle(geometry, centre, heading), payload))
    except ValueError as error:
        reasons.append(f"task cycle not reachable: {error}")
    if figures and all(math.isfinite(f.fastest_motion_time) for f in figures):
        peak = max(f.peak_torque for f in figures)
        if peak > TORQUE_LIMIT:
            reasons.append(f"peak torque {peak:.0f} N m > limit {TORQUE_LIMIT:.0f} N m")
    elif figures:
        reasons.append("holding the payload at rest exceeds the torque limit")
    speed = workspace.isotropic_speed(geometry, task_region_points(task_radius), JOINT_SPEED_LIMIT)
    return Performance(
        geometry=geometry,
        masses=masses,
        cylinder=search.cylinder,
        shortfall=search.shortfall,
        workspace_m3=search.cylinder.volume if search.cylinder else 0.0,
        peak_torque_nm=max((f.peak_torque for f in figures), default=math.inf),
        rms_torque_nm=max((f.rms_torque for f in figures), default=math.inf),
        cycle_time_s=max((f.fastest_motion_time for f in figures), default=math.inf),
        speed_m_s=float(np.min(speed)) if region.reachable.all() else 0.0,
        min_conditioning=float(np.min(np.nan_to_num(region.conditioning))),
        cycles=tuple(figures),
        reason="; ".join(reasons),
    )


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
