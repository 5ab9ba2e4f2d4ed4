"""C2 reference trajectories with exact joint references (DESIGN.md sections 5 and 7).

Every path is a chain of segments built from quintic minimum-jerk blends
s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, which start and end with zero velocity and acceleration, so
position, velocity and acceleration are continuous (C2) everywhere and the jerk stays bounded.

- A *move* between two stations is an arch: the horizontal motion is one quintic over the whole
  move time T; the vertical motion is a quintic up by ``lift_height`` over the first
  ``lift_fraction * T`` and a quintic down over the last ``lift_fraction * T``, overlapping the
  horizontal one. The vertical motion leads, so the object leaves the conveyor before it is
  dragged sideways. ``lift_height = 0`` with ``lift_fraction = 1`` is a straight line.
- A *dwell* holds the platform at rest. In pick cycles the suction gripper closes in the middle of
  the dwell at the pick point and opens in the middle of the dwell at the place point, so the
  robot is at rest (zero velocity and acceleration) before, at and after every event.

Each move is timed from a peak Cartesian acceleration |xdd| (vector norm): the peak of the move's
shape is found numerically at T = 1 and T is rescaled by sqrt(peak / target), since the
acceleration scales with 1/T^2. Joint references come from `kinematics.cartesian_to_joint` on the
analytically differentiated Cartesian path, so they are exact, not finite differences.
"""

from __future__ import annotations

import itertools
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.geometry import GRAVITY, DeltaGeometry
from delta_env.sensors import CONTROL_PERIOD

STANDARD_PEAK_ACCELERATION = 3.0 * GRAVITY
"""Default peak Cartesian acceleration of pick cycles (m/s^2), 3 g (DESIGN.md section 5)."""

STRESS_PEAK_ACCELERATION = 6.0 * GRAVITY
"""Stress preset and default for excitation trajectories (m/s^2), 6 g (DESIGN.md sections 4, 7)."""

WORKING_HEIGHT = -0.9
"""Height of the conveyors (m), in the middle of the work zone (DESIGN.md section 4)."""

STANDARD_LIFT = 0.025
"""Lift and descent of the industry's 25/305/25 mm test cycle (m)."""

STANDARD_TRAVEL = 0.305
"""Horizontal travel of the industry's 25/305/25 mm test cycle (m)."""

_MAX_SAMPLE_PERIOD = 0.01
_SHAPE_GRID = 4001  # samples of a unit-time move shape; locates its peak |xdd| to ~1e-6 relative
_CHECK_SPACING = 0.01  # m between admissibility checks along a candidate straight move
_MAX_DRAWS = 1000
_MIN_FAST_DISTANCE = 0.05  # m; shorter fast moves would last only a few samples
_QUINTIC_PEAK_SPEED = 1.875  # max ds/dtau of the quintic blend


# ---------------------------------------------------------------------------------------------
# Argument checks


def _require_positive(name: str, value: float, unit: str) -> None:
    if not (isinstance(value, numbers.Real) and math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0 ({unit}), got {value!r}")


def _require_sample_period(dt: float) -> None:
    if not (isinstance(dt, numbers.Real) and 0.0 < dt <= _MAX_SAMPLE_PERIOD):
        raise ValueError(f"dt must lie in (0, {_MAX_SAMPLE_PERIOD}] s, got {dt!r}")


def _require_count(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")


def _require_fraction(name: str, value: float, low_open: bool = False) -> None:
    low_ok = value > 0.0 if low_open else value >= 0.0
    if not (math.isfinite(value) and low_ok and value <= 1.0):
        raise ValueError(f"{name} must lie in {'(' if low_open else '['}0, 1], got {value!r}")


def _require_range(name: str, value: tuple[float, float], unit: str, allow_zero: bool) -> None:
    low, high = value
    low_ok = low >= 0.0 if allow_zero else low > 0.0
    if not (math.isfinite(low) and math.isfinite(high) and low_ok and low <= high):
        bound = "0 <= min" if allow_zero else "0 < min"
        raise ValueError(f"{name} must be ({bound} <= max) {unit}, got {value!r}")


def _require_cycle_arguments(
    peak_acceleration: float, lift_height: float, lift_fraction: float, dwell: float, dt: float
) -> None:
    _require_sample_period(dt)
    _require_positive("peak_acceleration", peak_acceleration, "m/s^2")
    if not (math.isfinite(lift_height) and lift_height >= 0.0):
        raise ValueError(f"lift_height must be a finite number >= 0 m, got {lift_height!r}")
    if not (0.0 < lift_fraction <= 0.5):
        raise ValueError(f"lift_fraction must lie in (0, 0.5], got {lift_fraction!r}")
    if not (math.isfinite(dwell) and dwell >= 2.0 * dt):
        raise ValueError(f"dwell must be a finite number >= 2 dt = {2.0 * dt:g} s, got {dwell!r}")


def _require_generator(rng: object) -> None:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), got {rng!r}")


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A sampled platform and joint reference with suction-gripper events.

    Sample n is at time n * dt. Arrays are read-only copies.

    Attributes:
        dt: Sample period (s).
        xyz: Platform position (m), ``(N, 3)``.
        xyz_dot: Platform velocity (m/s), ``(N, 3)``.
        xyz_ddot: Platform acceleration (m/s^2), ``(N, 3)``.
        theta: Motor angles (rad), ``(N, 3)``, exact inverse kinematics of ``xyz``.
        theta_dot: Motor rates (rad/s), ``(N, 3)``.
        theta_ddot: Motor accelerations (rad/s^2), ``(N, 3)``.
        gripper: True while the suction gripper holds an object, ``(N,)``.
        pick_indices: Samples where the gripper closes (one per cycle), ``(n_cycles,)``, int.
        place_indices: Samples where it opens, ``(n_cycles,)``, int; ``gripper[n]`` is True exactly
            for ``pick_indices[k] <= n < place_indices[k]``.
    """

    dt: float
    xyz: NDArray[np.float64]
    xyz_dot: NDArray[np.float64]
    xyz_ddot: NDArray[np.float64]
    theta: NDArray[np.float64]
    theta_dot: NDArray[np.float64]
    theta_ddot: NDArray[np.float64]
    gripper: NDArray[np.bool_]
    pick_indices: NDArray[np.int64]
    place_indices: NDArray[np.int64]

    def __post_init__(self) -> None:
        _require_sample_period(self.dt)
        length = len(np.asarray(self.xyz))
        if length < 1:
            raise ValueError("a trajectory needs at least one sample")
        for name in ("xyz", "xyz_dot", "xyz_ddot", "theta", "theta_dot", "theta_ddot"):
            self._freeze(name, np.array(getattr(self, name), dtype=float), (length, 3))
        self._freeze("gripper", np.array(self.gripper, dtype=bool), (length,))
        for name in ("pick_indices", "place_indices"):
            indices = np.array(getattr(self, name), dtype=np.int64).reshape(-1)
            if np.any((indices < 0) | (indices >= length)):
                raise ValueError(f"{name} must lie in [0, {length - 1}], got {indices.tolist()}")
            self._freeze(name, indices, indices.shape)

    def _freeze(self, name: str, array: np.ndarray, shape: tuple[int, ...]) -> None:
        if array.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
        array.setflags(write=False)
        object.__setattr__(self, name, array)

    @property
    def time(self) -> NDArray[np.float64]:
        """Sample times (s), ``(N,)``."""
        return np.arange(len(self)) * self.dt

    @property
    def duration(self) -> float:
        """Time from the first to the last sample (s)."""
        return (len(self) - 1) * self.dt

    def __len__(self) -> int:
        return len(self.xyz)


@dataclass(frozen=True)
class ConveyorZone:
    """A horizontal rectangle where objects are picked or placed (m, base frame).

    Attributes:
        x_range: (min, max) of x.
        y_range: (min, max) of y.
        z: Height of the conveyor surface the platform touches.
    """

    x_range: tuple[float, float]
    y_range: tuple[float, float]
    z: float = WORKING_HEIGHT

    def __post_init__(self) -> None:
        for name in ("x_range", "y_range"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(f"{name} must be finite (min, max) with min <= max, got {(low, high)}")
        if not math.isfinite(self.z):
            raise ValueError(f"z must be finite, got {self.z!r}")

    def sample(self, rng: np.random.Generator, count: int) -> NDArray[np.float64]:
        """Points drawn uniformly on the zone (m), ``(count, 3)``."""
        low = (self.x_range[0], self.y_range[0], self.z)
        high = (self.x_range[1], self.y_range[1], self.z)
        return rng.uniform(low, high, size=(count, 3))

    def corners(self) -> NDArray[np.float64]:
        """The four corners (m), ``(4, 3)``."""
        return np.array([(x, y, self.z) for x in self.x_range for y in self.y_range])


# Two conveyors on either side of the base's x axis, 0.3 m apart, 0.6 m long and 0.2 m wide, at the
# working height: their farthest corners are 0.46 m from the axis, well inside the 0.7 m radius
# where the singularity margins below still hold, so every random cycle is reachable.
PICK_ZONE = ConveyorZone(x_range=(-0.3, 0.3), y_range=(-0.35, -0.15))
"""Default pick conveyor zone (m)."""

PLACE_ZONE = ConveyorZone(x_range=(-0.3, 0.3), y_range=(0.15, 0.35))
"""Default place conveyor zone (m)."""


@dataclass(frozen=True)
class WorkspaceLimits:
    """The region reference paths may visit and its margins from singularities.

    The defaults bound a cylinder around the work zone (1.2 m across at z = -0.9 m, DESIGN.md
    section 4) plus a 0.1 m rim for identification. Nominal geometry values at (0, 0, -0.9) for
    scale: min |k_i| = 0.336 m^2/rad and |det A| = 0.537 m^3; both vanish at singularities and the
    margins keep them above ~45 % and ~28 % of that (Jacobian condition number below ~8).

    Attributes:
        radius: Largest distance from the base z axis (m).
        z_min: Lowest platform height (m).
        z_max: Highest platform height (m).
        min_abs_k: Serial-singularity margin: smallest allowed min_i |k_i| (m^2/rad).
        min_abs_det_a: Parallel-singularity margin: smallest allowed |det A| (m^3).
    """

    radius: float = 0.7
    z_min: float = -1.1
    z_max: float = -0.7
    min_abs_k: float = 0.15
    min_abs_det_a: float = 0.15

    def __post_init__(self) -> None:
        for name, unit in (("radius", "m"), ("min_abs_k", "m^2/rad"), ("min_abs_det_a", "m^3")):
            _require_positive(name, getattr(self, name), unit)
        if not (math.isfinite(self.z_min) and math.isfinite(self.z_max) and self.z_min < self.z_max):
            raise ValueError(f"need finite z_min < z_max, got z_min={self.z_min!r}, z_max={self.z_max!r}")


WORKSPACE_LIMITS = WorkspaceLimits()
"""Default workspace limits for the nominal geometry."""


def admissible(geometry: DeltaGeometry, xyz: ArrayLike, limits: WorkspaceLimits = WORKSPACE_LIMITS) -> NDArray:
    """Whether platform positions lie inside ``limits`` (reachable, within margins).

    Args:
        geometry: Robot geometry.
        xyz: Platform positions (m), ``(..., 3)``.
        limits: Region and singularity margins.

    Returns:
        Boolean array ``(...)``.
    """
    xyz = np.asarray(xyz, dtype=float)
    flat = xyz.reshape(-1, 3)
    inside = (np.hypot(flat[:, 0], flat[:, 1]) <= limits.radius) & (flat[:, 2] >= limits.z_min)
    inside &= flat[:, 2] <= limits.z_max
    reachable = _reachable(geometry, flat)
    theta = kinematics.inverse(geometry, flat[reachable])
    a, k = kinematics.constraint_terms(geometry, flat[reachable], theta)
    # the measures of kinematics.singularity_measures, without its SVD (this runs on whole paths)
    inside[reachable] &= np.min(np.abs(k), axis=-1) >= limits.min_abs_k
    inside[reachable] &= np.abs(np.linalg.det(a)) >= limits.min_abs_det_a
    return (inside & reachable).reshape(xyz.shape[:-1])


def concatenate(trajectories: Sequence[Trajectory]) -> Trajectory:
    """Join trajectories end to start; each junction must match in state and gripper.

    The first sample of every trajectory after the first is dropped (it repeats the junction) and
    its event indices are shifted accordingly.

    Raises:
        ValueError: if the list is empty, sample periods differ or a junction is discontinuous.
    """
    if not trajectories:
        raise ValueError("concatenate needs at least one trajectory, got none")
    first = trajectories[0]
    for previous, current in itertools.pairwise(trajectories):
        if not math.isclose(current.dt, first.dt, rel_tol=1e-12):
            raise ValueError(f"all trajectories must share dt={first.dt} s, got {current.dt} s")
        for name, tolerance in (("xyz", 1e-9), ("xyz_dot", 1e-9), ("xyz_ddot", 1e-6)):
            gap = np.max(np.abs(getattr(previous, name)[-1] - getattr(current, name)[0]))
            if gap > tolerance:
                raise ValueError(f"junction {name} differs by {gap:.3g}, allowed {tolerance:g} (SI units)")
        if previous.gripper[-1] != current.gripper[0]:
            raise ValueError("junction gripper states differ")
    # sample n of part i lands at shift_i + n: its sample 0 is the last one of part i - 1
    shifts = np.concatenate(([0], np.cumsum([len(part) - 1 for part in trajectories])))

    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(part, name)[1 if i else 0 :] for i, part in enumerate(trajectories)])

    def shifted(name: str) -> np.ndarray:
        return np.concatenate(
            [getattr(part, name) + shift for part, shift in zip(trajectories, shifts[:-1], strict=True)]
        )

    return Trajectory(
        dt=first.dt,
        **{name: joined(name) for name in ("xyz", "xyz_dot", "xyz_ddot", "theta", "theta_dot", "theta_ddot")},
        gripper=joined("gripper"),
        pick_indices=shifted("pick_indices"),
        place_indices=shifted("place_indices"),
    )


def standard_cycle(
    geometry: DeltaGeometry,
    peak_acceleration: float = STANDARD_PEAK_ACCELERATION,
    *,
    n_cycles: int = 1,
    center: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT),
    heading: float = math.pi / 2,
    dwell: float = 0.1,
    lift_fraction: float = 0.3,
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
) -> Trajectory:
    """The industry's 25/305/25 mm pick cycle: up 25 mm, across 305 mm, down 25 mm, and back.

    One cycle: dwell at the pick point (the gripper closes mid-dwell), arch to the place point,
    dwell (the gripper opens mid-dwell), arch back to the pick point. The trajectory starts and ends
    at rest at the pick point.

    Args:
        geometry: Robot geometry.
        peak_acceleration: Peak Cartesian acceleration |xdd| of every move (m/s^2), > 0.
        n_cycles: Number of pick-and-place cycles, >= 1.
        center: Midpoint between the pick and the place point (m).
        heading: Direction of travel from pick to place in the xy plane (rad from +x); the default
            travels along +y, from the pick conveyor side to the place side.
        dwell: Rest at each pick and place point (s), >= 2 dt.
        lift_fraction: Share of the move time spent lifting, and again descending, in (0, 0.5].
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).

    Raises:
        ValueError: on a bad argument or a point outside ``limits`` (named in the message).
    """
    _require_count("n_cycles", n_cycles)
    _require_cycle_arguments(peak_acceleration, STANDARD_LIFT, lift_fraction, dwell, dt)
    center_xyz = np.asarray(center, dtype=float)
    half_travel = 0.5 * STANDARD_TRAVEL * np.array([math.cos(heading), math.sin(heading), 0.0])
    pick, place = center_xyz - half_travel, center_xyz + half_travel
    return _cycles(
        geometry,
        np.tile(pick, (n_cycles + 1, 1)),
        np.tile(place, (n_cycles, 1)),
        peak_acceleration=peak_acceleration,
        lift_height=STANDARD_LIFT,
        lift_fraction=lift_fraction,
        dwell=dwell,
        limits=limits,
        dt=dt,
    )


def conveyor_cycles(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    n_cycles: int,
    peak_acceleration: float = STANDARD_PEAK_ACCELERATION,
    *,
    pick_zone: ConveyorZone = PICK_ZONE,
    place_zone: ConveyorZone = PLACE_ZONE,
    lift_height: float = STANDARD_LIFT,
    lift_fraction: float = 0.3,
    dwell: float = 0.1,
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
) -> Trajectory:
    """Pick-and-place cycles between random points on a pick and a place conveyor.

    Cycle k picks a new object at pick point k and places it at place point k (both uniform on
    their zones). Every cycle has the shape of `standard_cycle`, except that it returns to the next
    pick point; the trajectory starts at rest at pick point 0 and ends at rest at pick point
    ``n_cycles`` (drawn like the others, not picked), ready for another cycle.

    Args:
        geometry: Robot geometry.
        rng: Source of all randomness; draws n_cycles + 1 pick points, then n_cycles place points.
        n_cycles: Number of pick-and-place cycles, >= 1.
        peak_acceleration: Peak Cartesian acceleration |xdd| of every move (m/s^2), > 0.
        pick_zone: Where objects are picked.
        place_zone: Where objects are placed.
        lift_height: Lift above the higher of the two stations of a move (m), >= 0.
        lift_fraction: Share of the move time spent lifting, and again descending, in (0, 0.5].
        dwell: Rest at each pick and place point (s), >= 2 dt; the gripper switches mid-dwell.
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).

    Raises:
        ValueError: on a bad argument or a point outside ``limits`` (named in the message).
    """
    _require_generator(rng)
    _require_count("n_cycles", n_cycles)
    _require_cycle_arguments(peak_acceleration, lift_height, lift_fraction, dwell, dt)
    lifted = np.array([0.0, 0.0, lift_height])
    for name, zone in (("pick zone corner", pick_zone), ("place zone corner", place_zone)):
        _require_admissible(geometry, zone.corners(), limits, name)
        _require_admissible(geometry, zone.corners() + lifted, limits, f"lifted {name}")
    picks = pick_zone.sample(rng, n_cycles + 1)
    places = place_zone.sample(rng, n_cycles)
    return _cycles(
        geometry,
        picks,
        places,
        peak_acceleration=peak_acceleration,
        lift_height=lift_height,
        lift_fraction=lift_fraction,
        dwell=dwell,
        limits=limits,
        dt=dt,
    )


def excitation_trajectory(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    duration: float,
    peak_acceleration: float = STRESS_PEAK_ACCELERATION,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT),
    min_acceleration_fraction: float = 0.2,
    edge_fraction: float = 0.3,
    slow_fraction: float = 0.2,
    slow_speed_range: tuple[float, float] = (0.005, 0.1),
    slow_duration_range: tuple[float, float] = (0.3, 1.0),
    dwell_range: tuple[float, float] = (0.0, 0.1),
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
) -> Trajectory:
    """Random rest-to-rest straight moves over the whole admissible workspace, for identification.

    Three kinds of moves, each a straight-line quintic followed by a random dwell:
    - fast, to a point drawn uniformly in ``limits`` with a peak |xdd| drawn uniformly in
      [min_acceleration_fraction, 1] * peak_acceleration;
    - fast to the workspace edge (probability ``edge_fraction`` among fast moves): a point on the
      boundary of ``limits`` (cylinder wall or singularity margin) at a random height and azimuth;
    - slow (probability ``slow_fraction``): a short move in a random direction whose peak speed is
      drawn log-uniformly in ``slow_speed_range``, to excite friction near zero speed.
    The trajectory has no gripper events. It lasts exactly ``duration``: a move that would not fit
    is dropped and the remaining time is spent at rest.

    Args:
        geometry: Robot geometry.
        rng: Source of all randomness.
        duration: Length of the trajectory (s), > 0.
        peak_acceleration: Largest peak |xdd| of a move (m/s^2), > 0.
        start: Initial rest position (m), inside ``limits``.
        min_acceleration_fraction: Smallest peak |xdd| of a fast move, relative, in (0, 1].
        edge_fraction: Probability that a fast move ends on the workspace edge, in [0, 1].
        slow_fraction: Probability that a move is slow, in [0, 1].
        slow_speed_range: (min, max) peak speed of slow moves (m/s), 0 < min <= max.
        slow_duration_range: (min, max) duration of slow moves (s), 0 < min <= max.
        dwell_range: (min, max) rest after each move (s), 0 <= min <= max.
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).

    Raises:
        ValueError: on a bad argument or a start outside ``limits``.
    """
    _require_generator(rng)
    _require_sample_period(dt)
    _require_positive("duration", duration, "s")
    _require_positive("peak_acceleration", peak_acceleration, "m/s^2")
    _require_fraction("min_acceleration_fraction", min_acceleration_fraction, low_open=True)
    _require_fraction("edge_fraction", edge_fraction)
    _require_fraction("slow_fraction", slow_fraction)
    _require_range("slow_speed_range", slow_speed_range, "m/s", allow_zero=False)
    _require_range("slow_duration_range", slow_duration_range, "s", allow_zero=False)
    _require_range("dwell_range", dwell_range, "s", allow_zero=True)
    point = np.asarray(start, dtype=float)
    _require_admissible(geometry, point[None], limits, "start point")

    segments: list[_Segment] = []
    elapsed = 0.0
    while True:
        if rng.random() < slow_fraction:
            move_time = rng.uniform(*slow_duration_range)
            speed = math.exp(rng.uniform(math.log(slow_speed_range[0]), math.log(slow_speed_range[1])))
            target = _slow_target(geometry, rng, point, speed * move_time / _QUINTIC_PEAK_SPEED, limits)
            move = _Segment.line(point, target, move_time)
        else:
            on_edge = rng.random() < edge_fraction
            target = _fast_target(geometry, rng, point, limits, on_edge)
            acceleration = peak_acceleration * rng.uniform(min_acceleration_fraction, 1.0)
            move = _Segment.line(point, target, 1.0).timed(acceleration)
        rest = rng.uniform(*dwell_range)
        if elapsed + move.duration > duration:
            break
        segments.append(move)
        point = move.end
        elapsed += move.duration
        if rest > 0.0 and elapsed < duration:
            segments.append(_Segment.line(point, point, min(rest, duration - elapsed)))
            elapsed += segments[-1].duration
    if duration - elapsed > 0.0:
        segments.append(_Segment.line(point, point, duration - elapsed))
    return _sample(geometry, segments, dt, events=[])


# ---------------------------------------------------------------------------------------------
# Segments and sampling


def _quintic(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend s(tau) on [0, 1] (clipped outside) and its first two derivatives."""
    tau = np.clip(tau, 0.0, 1.0)
    s = tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


@dataclass(frozen=True, eq=False)
class _Segment:
    """A C2 rest-to-rest piece: arch (or straight line) from ``start`` to ``end`` in ``duration``."""

    start: np.ndarray
    end: np.ndarray
    duration: float
    lift_height: float = 0.0
    lift_fraction: float = 1.0

    @staticmethod
    def line(start: np.ndarray, end: np.ndarray, duration: float) -> _Segment:
        return _Segment(np.asarray(start, dtype=float), np.asarray(end, dtype=float), float(duration))

    def timed(self, peak_acceleration: float) -> _Segment:
        """The same shape, retimed so that its peak |xdd| equals ``peak_acceleration``."""
        tau = np.linspace(0.0, 1.0, _SHAPE_GRID)
        unit = _Segment(self.start, self.end, 1.0, self.lift_height, self.lift_fraction)
        _, _, acceleration = _evaluate([unit], np.zeros(tau.shape, dtype=int), tau)
        unit_peak = float(np.max(np.linalg.norm(acceleration, axis=-1)))
        if unit_peak == 0.0:
            raise ValueError(f"a move from {self.start.tolist()} m to itself cannot be timed by acceleration")
        # |xdd| scales with 1 / T^2 for a fixed shape
        duration = math.sqrt(unit_peak / peak_acceleration)
        return _Segment(self.start, self.end, duration, self.lift_height, self.lift_fraction)


def _evaluate(
    segments: Sequence[_Segment], index: np.ndarray, local_time: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration of ``segments[index]`` at ``local_time`` (s), each ``(n, 3)``."""
    start = np.array([segment.start for segment in segments])[index]
    end = np.array([segment.end for segment in segments])[index]
    duration = np.array([segment.duration for segment in segments])[index]
    lift = np.array([segment.lift_height for segment in segments])[index]
    vertical_time = np.array([segment.lift_fraction for segment in segments])[index] * duration

    s, ds, dds = _quintic(local_time / duration)
    delta = end - start
    position = start + delta * s[:, None]
    velocity = delta * (ds / duration)[:, None]
    acceleration = delta * (dds / duration**2)[:, None]

    # z: a quintic up to the top over the first vertical_time, a quintic down over the last one;
    # with lift 0 and vertical_time = duration the two add up to the straight line.
    z_start, z_end = start[:, 2], end[:, 2]
    top = np.maximum(z_start, z_end) + lift
    up, up_d, up_dd = _quintic(local_time / vertical_time)
    down, down_d, down_dd = _quintic((local_time - duration + vertical_time) / vertical_time)
    rise, fall = top - z_start, z_end - top
    position[:, 2] = z_start + rise * up + fall * down
    velocity[:, 2] = (rise * up_d + fall * down_d) / vertical_time
    acceleration[:, 2] = (rise * up_dd + fall * down_dd) / vertical_time**2
    return position, velocity, acceleration


def _sample(
    geometry: DeltaGeometry,
    segments: Sequence[_Segment],
    dt: float,
    events: Sequence[tuple[float, float]],
) -> Trajectory:
    """Sample segments at dt from t = 0 through their end; ``events`` are (pick, place) times (s)."""
    durations = np.array([segment.duration for segment in segments])
    starts = np.concatenate(([0.0], np.cumsum(durations)[:-1]))
    n_samples = math.ceil(float(np.sum(durations)) / dt - 1e-9) + 1
    time = np.arange(n_samples) * dt
    index = np.clip(np.searchsorted(starts, time, side="right") - 1, 0, len(segments) - 1)
    # past the last segment the clipped blend holds its end point at rest
    xyz, xyz_dot, xyz_ddot = _evaluate(segments, index, time - starts[index])
    theta, theta_dot, theta_ddot = kinematics.cartesian_to_joint(geometry, xyz, xyz_dot, xyz_ddot)

    picks = np.array([round(pick / dt) for pick, _ in events], dtype=np.int64)
    places = np.array([round(place / dt) for _, place in events], dtype=np.int64)
    gripper = np.zeros(n_samples, dtype=bool)
    for pick, place in zip(picks, places, strict=True):
        gripper[pick:place] = True
    return Trajectory(dt, xyz, xyz_dot, xyz_ddot, theta, theta_dot, theta_ddot, gripper, picks, places)


def _cycles(
    geometry: DeltaGeometry,
    picks: np.ndarray,
    places: np.ndarray,
    *,
    peak_acceleration: float,
    lift_height: float,
    lift_fraction: float,
    dwell: float,
    limits: WorkspaceLimits,
    dt: float,
) -> Trajectory:
    """Dwell, arch to place k, dwell, arch to pick k + 1, for every k; events mid-dwell."""
    lifted = np.array([0.0, 0.0, lift_height])
    for name, points in (("pick point", picks), ("place point", places)):
        _require_admissible(geometry, points, limits, name)
        _require_admissible(geometry, points + lifted, limits, f"lifted {name}")

    segments: list[_Segment] = []
    events: list[tuple[float, float]] = []
    elapsed = 0.0
    for pick, place, next_pick in zip(picks[:-1], places, picks[1:], strict=True):
        there = _Segment(pick, place, 1.0, lift_height, lift_fraction).timed(peak_acceleration)
        back = _Segment(place, next_pick, 1.0, lift_height, lift_fraction).timed(peak_acceleration)
        segments += [_Segment.line(pick, pick, dwell), there, _Segment.line(place, place, dwell), back]
        events.append((elapsed + 0.5 * dwell, elapsed + dwell + there.duration + 0.5 * dwell))
        elapsed += 2.0 * dwell + there.duration + back.duration
    trajectory = _sample(geometry, segments, dt, events)
    _require_admissible(geometry, trajectory.xyz, limits, "path point")
    return trajectory


# ---------------------------------------------------------------------------------------------
# Workspace


def _reachable(geometry: DeltaGeometry, flat_xyz: np.ndarray) -> NDArray[np.bool_]:
    """Whether each point ``(n, 3)`` has an inverse kinematics solution, ``(n,)``."""
    try:
        kinematics.inverse(geometry, flat_xyz)
    except ValueError:
        if len(flat_xyz) == 1:
            return np.zeros(1, dtype=bool)
        # kinematics.inverse rejects a whole batch: bisect to find the unreachable points
        half = len(flat_xyz) // 2
        return np.concatenate((_reachable(geometry, flat_xyz[:half]), _reachable(geometry, flat_xyz[half:])))
    return np.ones(len(flat_xyz), dtype=bool)


def _why_not_admissible(geometry: DeltaGeometry, point: np.ndarray, limits: WorkspaceLimits) -> str:
    """Why one point (m) is outside ``limits``, for error messages; '' if it is inside."""
    if math.hypot(point[0], point[1]) > limits.radius:
        return f"farther than {limits.radius} m from the z axis"
    if not limits.z_min <= point[2] <= limits.z_max:
        return f"outside z in [{limits.z_min}, {limits.z_max}] m"
    try:
        theta = kinematics.inverse(geometry, point)
    except ValueError:
        return "unreachable"
    measures = kinematics.singularity_measures(geometry, theta)
    if measures.min_abs_k < limits.min_abs_k:
        return f"near a serial singularity: min |k_i| = {measures.min_abs_k:.3g} m^2/rad < {limits.min_abs_k}"
    if abs(measures.det_a) < limits.min_abs_det_a:
        return f"near a parallel singularity: |det A| = {abs(measures.det_a):.3g} m^3 < {limits.min_abs_det_a}"
    return ""


def _require_admissible(geometry: DeltaGeometry, points: np.ndarray, limits: WorkspaceLimits, what: str) -> None:
    inside = admissible(geometry, points, limits).reshape(-1)
    if not np.all(inside):
        point = points.reshape(-1, 3)[np.argmin(inside)]
        reason = _why_not_admissible(geometry, point, limits)
        raise ValueError(f"{what} {(np.round(point, 4) + 0.0).tolist()} m is not admissible: {reason} ({limits})")


def _segment_admissible(geometry: DeltaGeometry, start: np.ndarray, end: np.ndarray, limits: WorkspaceLimits) -> bool:
    count = max(2, math.ceil(float(np.linalg.norm(end - start)) / _CHECK_SPACING) + 1)
    points = start + np.linspace(0.0, 1.0, count)[:, None] * (end - start)
    return bool(np.all(admissible(geometry, points, limits)))


def _edge_point(geometry: DeltaGeometry, rng: np.random.Generator, limits: WorkspaceLimits) -> np.ndarray | None:
    """A point on the boundary of ``limits`` along a random horizontal ray from the z axis, or None."""
    z = rng.uniform(limits.z_min, limits.z_max)
    direction = np.array([*_unit_circle(rng.uniform(0.0, 2.0 * math.pi)), 0.0])
    axis_point = np.array([0.0, 0.0, z])
    if not admissible(geometry, axis_point, limits):
        return None
    if admissible(geometry, axis_point + limits.radius * direction, limits):
        return axis_point + limits.radius * direction
    inside, outside = 0.0, limits.radius
    while outside - inside > 1e-4:
        middle = 0.5 * (inside + outside)
        if admissible(geometry, axis_point + middle * direction, limits):
            inside = middle
        else:
            outside = middle
    return axis_point + inside * direction


def _fast_target(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    point: np.ndarray,
    limits: WorkspaceLimits,
    on_edge: bool,
) -> np.ndarray:
    for _ in range(_MAX_DRAWS):
        if on_edge:
            target = _edge_point(geometry, rng, limits)
        else:
            radius = limits.radius * math.sqrt(rng.random())
            xy = radius * np.array(_unit_circle(rng.uniform(0.0, 2.0 * math.pi)))
            target = np.array([*xy, rng.uniform(limits.z_min, limits.z_max)])
        if (
            target is not None
            and np.linalg.norm(target - point) >= _MIN_FAST_DISTANCE
            and _segment_admissible(geometry, point, target, limits)
        ):
            return target
    raise ValueError(f"found no admissible move from {point.tolist()} m in {_MAX_DRAWS} draws; limits {limits}")


def _slow_target(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    point: np.ndarray,
    distance: float,
    limits: WorkspaceLimits,
) -> np.ndarray:
    for _ in range(_MAX_DRAWS):
        direction = rng.normal(size=3)
        target = point + distance * direction / np.linalg.norm(direction)
        if _segment_admissible(geometry, point, target, limits):
            return target
    raise ValueError(f"found no admissible slow move from {point.tolist()} m in {_MAX_DRAWS} draws")


def _unit_circle(angle: float) -> tuple[float, float]:
    return math.cos(angle), math.sin(angle)
