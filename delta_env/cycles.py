"""Pick-and-place reference cycles: the industry's 25/305/25 mm cycle and random conveyor cycles.

Every cycle dwells at the pick point (the gripper closes), arches to the place point, dwells (the gripper opens)
and arches back (docs/design.md section 5). Where in the dwell the gripper switches is the ``release``: mid-dwell
(``"timed"``, a ``DEFAULT_DWELL`` rest) or at its end (``"in_position"``: the dwell is the air activation, which
the env starts only once the platform is in position, holding the reference at the dwell's start until then,
:mod:`delta_env.release`); then every move starts on a sample. An episode is a window of continuous
work: by default it starts at rest at a place point, where a previous object was released, and arches empty to
its first pick point, so that every carry follows an empty move, as in a running cell; ``start="pick"`` starts at
rest at the first pick point instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from delta_env.geometry import DeltaGeometry
from delta_env.limits import WORKSPACE_LIMITS, WorkspaceLimits, require_admissible
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timed_cycles import TimedCycles, require_stations
from delta_env.timing import MoveTiming
from delta_env.trajectories import (
    STANDARD_PEAK_ACCELERATION,
    WORKING_HEIGHT,
    Segment,
    Trajectory,
    require_peak_acceleration,
    require_sample_period,
    sample_segments,
)
from delta_env.validation import require_count, require_generator, require_in, require_interval

STANDARD_LIFT = 0.025
"""Lift and descent of the industry's 25/305/25 mm test cycle (m)."""

STANDARD_TRAVEL = 0.305
"""Horizontal travel of the industry's 25/305/25 mm test cycle (m)."""

DEFAULT_DWELL = 0.1
"""Rest (s) at each pick and place point of the timed release; the gripper closes or opens in its middle."""

DEFAULT_LIFT_FRACTION = 0.3
"""Share of a move's time spent lifting, and again descending, unless a cycle says otherwise."""

RELEASES = ("in_position", "timed")
"""Where the gripper switches in a dwell: at its end, once the platform is in position (the env's default,
:mod:`delta_env.release`), or in its middle at a fixed time (the cycles' default)."""


def require_release(release: str) -> str:
    """``release`` if it is one of :data:`RELEASES`, else ``ValueError``."""
    if release not in RELEASES:
        raise ValueError(f"release must be one of {list(RELEASES)}, got {release!r}")
    return release


@dataclass(frozen=True)
class MoveProfile:
    """The timing and shape every move of a cycle shares.

    Not checked on construction: :meth:`checked` checks the values a caller gives (:func:`standard_cycle`,
    :func:`conveyor_cycles`), and a scenario's task builds its own from fields checked as the task is made
    (:attr:`delta_env.scenario.PickPlaceTask.move_profile`), so that a value is checked once on its way down.

    Attributes:
        peak_acceleration: Peak Cartesian acceleration |xdd| of every move (m/s^2), in (0, MAX_PEAK_ACCELERATION].
        lift_height: Lift above the higher of the two stations of a move (m), >= 0.
        lift_fraction: Share of the move time spent lifting, and again descending, in (0, 0.5].
        dwell: Rest at each pick and place point (s), >= 2 dt.
        dt: Sample period (s).
        release: ``"timed"`` (the gripper switches mid-dwell) or ``"in_position"`` (at the dwell's end).
    """

    peak_acceleration: float
    lift_height: float
    lift_fraction: float
    dwell: float
    dt: float
    release: Literal["in_position", "timed"] = "timed"

    @classmethod
    def checked(
        cls,
        peak_acceleration: float,
        lift_height: float,
        lift_fraction: float,
        dwell: float,
        dt: float,
        release: Literal["in_position", "timed"],
    ) -> MoveProfile:
        """The profile of these values (as the attributes), each checked.

        Raises:
            ValueError: naming the first value out of its range.
        """
        require_release(release)
        require_sample_period(dt)
        require_peak_acceleration(peak_acceleration)
        require_in("lift_height", lift_height, 0.0, unit="m")
        require_in("lift_fraction", lift_fraction, 0.0, 0.5, low_open=True)
        require_in("dwell", dwell, 2.0 * dt, unit="s (2 dt and up)")
        return cls(peak_acceleration, lift_height, lift_fraction, dwell, dt, release)

    @property
    def switch(self) -> float:
        """Where in a dwell the gripper switches, as a fraction of it: the middle, or the end."""
        return 0.5 if self.release == "timed" else 1.0

    def rest(self, arrival: float) -> float:
        """The dwell (s) of a move that arrives at time ``arrival`` (s): ``dwell``, or with the in-position release
        the dwell to the ``dwell / dt``-th sample after the first sample at rest, so that the next move starts on
        a sample (the env holds the reference from that first sample on until the platform is in position)."""
        if self.release == "timed":
            return self.dwell
        return (math.ceil(arrival / self.dt - 1e-9) + round(self.dwell / self.dt)) * self.dt - arrival


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
            require_interval(name, getattr(self, name), unit="m")
        require_in("z", self.z, unit="m")

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
# of WORKSPACE_LIMITS (delta_env.limits) where its singularity margins hold, so every random cycle is reachable.
PICK_ZONE = ConveyorZone(x_range=(-0.3, 0.3), y_range=(-0.35, -0.15))
"""Default pick conveyor zone (m)."""

PLACE_ZONE = ConveyorZone(x_range=(-0.3, 0.3), y_range=(0.15, 0.35))
"""Default place conveyor zone (m)."""


def standard_cycle(
    geometry: DeltaGeometry,
    peak_acceleration: float = STANDARD_PEAK_ACCELERATION,
    *,
    n_cycles: int = 1,
    center: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT),
    heading: float = math.pi / 2,
    dwell: float = DEFAULT_DWELL,
    lift_fraction: float = DEFAULT_LIFT_FRACTION,
    start: Literal["place", "pick"] = "place",
    release: Literal["in_position", "timed"] = "timed",
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
    timing: MoveTiming | None = None,
    declared_masses: Sequence[float] | None = None,
) -> Trajectory | TimedCycles:
    """The industry's 25/305/25 mm pick cycle: up 25 mm, across 305 mm, down 25 mm, and back.

    One cycle: dwell at the pick point (the gripper closes, mid-dwell or at its end: ``release``), arch to the
    place point, dwell (the gripper opens), arch back to the pick point. The trajectory starts at rest at the
    place point with the gripper open and arches back to the pick point first (``start="place"``), or starts at
    rest at the pick point (``start="pick"``); it ends at rest at the pick point.

    Args:
        geometry: Robot geometry.
        peak_acceleration: Peak Cartesian acceleration |xdd| of every move (m/s^2), in (0, MAX_PEAK_ACCELERATION].
        n_cycles: Number of pick-and-place cycles, >= 1.
        center: Midpoint between the pick and the place point (m).
        heading: Direction of travel from pick to place in the xy plane (rad from +x); the default
            travels along +y, from the pick conveyor side to the place side.
        dwell: Rest at each pick and place point (s), >= 2 dt.
        lift_fraction: Share of the move time spent lifting, and again descending, in (0, 0.5].
        start: ``"place"`` or ``"pick"``, where the trajectory starts at rest.
        release: ``"timed"``: the gripper switches mid-dwell; ``"in_position"``: at the dwell's end (the dwell is
            then the air activation, a whole number of samples, and every move starts on a sample).
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).
        timing: Times every move instead of ``peak_acceleration`` (:mod:`delta_env.timing`); the result is then
            a :class:`TimedCycles`, whose :meth:`TimedCycles.trajectory` is the reference.
        declared_masses: With ``timing``: the mass (kg) of each cycle's object, handed to ``timing.carry``.

    Raises:
        ValueError: on a bad argument or a point outside ``limits`` (named in the message).
    """
    require_count("n_cycles", n_cycles)
    require_start(start)
    profile = MoveProfile.checked(peak_acceleration, STANDARD_LIFT, lift_fraction, dwell, dt, release)
    return plan_standard_cycle(
        geometry,
        profile,
        n_cycles,
        start,
        center=center,
        heading=heading,
        limits=limits,
        timing=timing,
        declared_masses=declared_masses,
    )


def plan_standard_cycle(
    geometry: DeltaGeometry,
    profile: MoveProfile,
    n_cycles: int,
    start: Literal["place", "pick"],
    *,
    center: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT),
    heading: float = math.pi / 2,
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    timing: MoveTiming | None = None,
    declared_masses: Sequence[float] | None = None,
) -> Trajectory | TimedCycles:
    """:func:`standard_cycle` of a profile, a cycle count and a start already checked (a scenario's task:
    :attr:`delta_env.scenario.PickPlaceTask.move_profile`); the other arguments as there.

    Raises:
        ValueError: for a point outside ``limits`` (named in the message).
    """
    center_xyz = np.asarray(center, dtype=float)
    half_travel = 0.5 * STANDARD_TRAVEL * np.array([math.cos(heading), math.sin(heading), 0.0])
    pick, place = center_xyz - half_travel, center_xyz + half_travel
    origin = place if start == "place" else None
    picks, places = np.tile(pick, (n_cycles + 1, 1)), np.tile(place, (n_cycles, 1))
    if timing is not None:
        return TimedCycles.plan(geometry, picks, places, profile, limits, origin, timing, declared_masses)
    return _cycles(geometry, picks, places, profile, limits, origin)


def conveyor_cycles(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    n_cycles: int,
    peak_acceleration: float = STANDARD_PEAK_ACCELERATION,
    *,
    pick_zone: ConveyorZone = PICK_ZONE,
    place_zone: ConveyorZone = PLACE_ZONE,
    lift_height: float = STANDARD_LIFT,
    lift_fraction: float = DEFAULT_LIFT_FRACTION,
    dwell: float = DEFAULT_DWELL,
    start: Literal["place", "pick"] = "place",
    release: Literal["in_position", "timed"] = "timed",
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
    timing: MoveTiming | None = None,
    declared_masses: Sequence[float] | None = None,
) -> Trajectory | TimedCycles:
    """Pick-and-place cycles between random points on a pick and a place conveyor.

    Cycle k picks a new object at pick point k and places it at place point k (both uniform on
    their zones). Every cycle has the shape of `standard_cycle`, except that it returns to the next
    pick point. The trajectory starts at rest at a place point drawn like the others, where a previous object
    was released, and arches empty to pick point 0 (``start="place"``), or starts at rest at pick point 0
    (``start="pick"``). It ends at rest at pick point ``n_cycles`` (drawn like the others, not picked), ready
    for another cycle.

    Args:
        geometry: Robot geometry.
        rng: Source of all randomness; draws n_cycles + 1 pick points, then n_cycles place points, then (with
            ``start="place"`` only) the starting place point: ``start="pick"`` draws what it drew before the
            option existed, so earlier seeded runs repeat.
        n_cycles: Number of pick-and-place cycles, >= 1.
        peak_acceleration: Peak Cartesian acceleration |xdd| of every move (m/s^2), in (0, MAX_PEAK_ACCELERATION].
        pick_zone: Where objects are picked.
        place_zone: Where objects are placed.
        lift_height: Lift above the higher of the two stations of a move (m), >= 0.
        lift_fraction: Share of the move time spent lifting, and again descending, in (0, 0.5].
        dwell: Rest at each pick and place point (s), >= 2 dt.
        start: ``"place"`` or ``"pick"`` (see above).
        release: Where the gripper switches in a dwell (as in :func:`standard_cycle`).
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).
        timing: Times every move instead of ``peak_acceleration``; the result is then a :class:`TimedCycles`
            (as in :func:`standard_cycle`). It draws nothing from ``rng``.
        declared_masses: With ``timing``: the mass (kg) of each cycle's object, handed to ``timing.carry``.

    Raises:
        ValueError: on a bad argument or a point outside ``limits`` (named in the message).
    """
    require_generator(rng)
    require_count("n_cycles", n_cycles)
    require_start(start)
    profile = MoveProfile.checked(peak_acceleration, lift_height, lift_fraction, dwell, dt, release)
    return plan_conveyor_cycles(
        geometry,
        rng,
        n_cycles,
        profile,
        start,
        pick_zone=pick_zone,
        place_zone=place_zone,
        limits=limits,
        timing=timing,
        declared_masses=declared_masses,
    )


def plan_conveyor_cycles(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    n_cycles: int,
    profile: MoveProfile,
    start: Literal["place", "pick"],
    *,
    pick_zone: ConveyorZone = PICK_ZONE,
    place_zone: ConveyorZone = PLACE_ZONE,
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    timing: MoveTiming | None = None,
    declared_masses: Sequence[float] | None = None,
) -> Trajectory | TimedCycles:
    """:func:`conveyor_cycles` of a generator, a cycle count, a profile and a start already checked (a scenario's
    task: :attr:`delta_env.scenario.PickPlaceTask.move_profile`); the other arguments as there.

    Raises:
        ValueError: for a zone the robot does not reach within ``limits`` or a point outside them.
    """
    lifted = np.array([0.0, 0.0, profile.lift_height])
    for name, zone in (("pick zone corner", pick_zone), ("place zone corner", place_zone)):
        require_admissible(geometry, zone.corners(), limits, name)
        require_admissible(geometry, zone.corners() + lifted, limits, f"lifted {name}")
    picks = pick_zone.sample(rng, n_cycles + 1)
    places = place_zone.sample(rng, n_cycles)
    origin = place_zone.sample(rng, 1)[0] if start == "place" else None
    if timing is not None:
        return TimedCycles.plan(geometry, picks, places, profile, limits, origin, timing, declared_masses)
    return _cycles(geometry, picks, places, profile, limits, origin)


def require_start(start: str) -> None:
    """Raise ValueError unless ``start`` is ``"place"`` or ``"pick"``, where an episode starts at rest."""
    if start not in ("place", "pick"):
        raise ValueError(f"start must be 'place' or 'pick', got {start!r}")


def _cycles(
    geometry: DeltaGeometry,
    picks: np.ndarray,
    places: np.ndarray,
    profile: MoveProfile,
    limits: WorkspaceLimits,
    origin: np.ndarray | None = None,
) -> Trajectory:
    """The sampled cycles through ``picks`` and ``places`` (m), gripper events mid-dwell or at its end.

    From ``origin`` (m, if given): the rest of the dwell in which the previous object was released (half a dwell,
    none with the in-position release) and an empty arch to pick 0. Then, for every k: dwell at pick k, arch to
    place k, dwell, arch to pick k + 1.
    """
    require_stations(geometry, picks, places, origin, profile.lift_height, limits)
    lift_height, lift_fraction, switch = profile.lift_height, profile.lift_fraction, profile.switch
    segments: list[Segment] = []
    events: list[tuple[float, float]] = []
    elapsed = 0.0
    if origin is not None:
        # The rest of the place dwell in which the previous object was released, then the move back.
        approach = Segment(origin, picks[0], 1.0, lift_height, lift_fraction).timed(profile.peak_acceleration)
        rest = (1.0 - switch) * profile.dwell
        segments += [Segment.line(origin, origin, rest), approach] if rest else [approach]
        elapsed = rest + approach.duration
    for pick, place, next_pick in zip(picks[:-1], places, picks[1:], strict=True):
        there = Segment(pick, place, 1.0, lift_height, lift_fraction).timed(profile.peak_acceleration)
        back = Segment(place, next_pick, 1.0, lift_height, lift_fraction).timed(profile.peak_acceleration)
        pick_dwell = profile.rest(elapsed)
        place_dwell = profile.rest(elapsed + pick_dwell + there.duration)
        segments += [Segment.line(pick, pick, pick_dwell), there, Segment.line(place, place, place_dwell), back]
        events.append((elapsed + switch * pick_dwell, elapsed + pick_dwell + there.duration + switch * place_dwell))
        elapsed += pick_dwell + there.duration + place_dwell + back.duration
    trajectory = sample_segments(geometry, segments, profile.dt, events)
    require_admissible(geometry, trajectory.xyz, limits, "path point")
    return trajectory
