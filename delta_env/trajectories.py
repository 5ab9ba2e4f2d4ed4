"""C2 reference trajectories with exact joint references: the sampled path and its building blocks.

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

The paths themselves are built in :mod:`delta_env.cycles` (pick-and-place, docs/design.md section 5)
and :mod:`delta_env.excitation` (identification, docs/design.md section 7), inside the region of
:mod:`delta_env.limits`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.geometry import GRAVITY, DeltaGeometry
from delta_env.validation import require_in

STANDARD_PEAK_ACCELERATION = 3.0 * GRAVITY
"""Default peak Cartesian acceleration of pick cycles (m/s^2), 3 g (docs/design.md section 5)."""

STRESS_PEAK_ACCELERATION = 6.0 * GRAVITY
"""Stress preset and default for excitation trajectories (m/s^2), 6 g (docs/design.md sections 4, 7)."""

MAX_PEAK_ACCELERATION = 30.0 * GRAVITY
"""Largest peak Cartesian acceleration (m/s^2), 30 g, accepted by the env, a scenario's task, the cycles and the
excitation trajectories (one check: :func:`require_peak_acceleration`). Beyond what any suction gripper holds,
and far beyond what the drive follows on this robot: the 400 N m torque limit caps the standard cycle with the
design payload at about 16-18 g (eval/design/performance.py), the stress preset and excitation use 6 g."""

WORKING_HEIGHT = -0.9
"""Height of the conveyors (m), in the middle of the work zone (docs/design.md section 4)."""

MAX_SAMPLE_PERIOD = 0.01
"""Largest sample period (s) of a trajectory."""

QUINTIC_PEAK_SPEED = 1.875
"""Largest ds/dtau of the quintic blend, at tau = 1/2."""

_SHAPE_GRID = 4001  # samples of a unit-time move shape; locates its peak |xdd| to ~1e-6 relative


REST_SPEED = 1e-9
"""Reference speed (m/s) at or below which the reference is at rest: the dwells of the sampled references are
exactly at rest, moves are not on any sample inside them."""


def arrivals(
    reference_velocity: ArrayLike, event_indices: Sequence[int], speed: float = REST_SPEED
) -> NDArray[np.int64]:
    """The sample at which the reference arrives at rest for each gripper event: the first sample of the rest run
    (|xyz_dot| <= ``speed``) that contains the event's index.

    Args:
        reference_velocity: Reference platform velocity (m/s), ``(M, 3)``.
        event_indices: Samples where the gripper closes or opens.
        speed: Rest threshold (m/s).

    Raises:
        ValueError: if the reference moves at an event's index.
    """
    moving = np.flatnonzero(np.linalg.norm(np.asarray(reference_velocity, dtype=float), axis=1) > speed)
    events = np.asarray(event_indices, dtype=np.int64)
    if np.isin(events, moving).any():
        raise ValueError(f"the reference moves at an event index, {events.tolist()}: an event must lie in a dwell")
    # The last moving sample before each event ends the move into its dwell; none means at rest from sample 0.
    after_move = np.append(0, moving + 1)
    return after_move[np.searchsorted(moving, events)].astype(np.int64)


def require_peak_acceleration(value: float) -> float:
    """``value`` (m/s^2) if it lies in (0, MAX_PEAK_ACCELERATION], else ``ValueError`` naming the range."""
    return require_in("peak_acceleration", value, 0.0, MAX_PEAK_ACCELERATION, unit="m/s^2", low_open=True)


def require_sample_period(dt: float) -> float:
    """``dt`` (s) if it lies in (0, MAX_SAMPLE_PERIOD], else ``ValueError``."""
    return require_in("dt", dt, 0.0, MAX_SAMPLE_PERIOD, unit="s", low_open=True)


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
        require_sample_period(self.dt)
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

    def content_hash(self) -> str:
        """Hash (16 hex digits) of the sample period and every array's name, type, shape and values: equal paths,
        equal hashes, on any platform."""
        digest = hashlib.sha256(repr(self.dt).encode())
        for name in (field.name for field in dataclasses.fields(self) if field.name != "dt"):
            array = np.ascontiguousarray(getattr(self, name))
            digest.update(f"{name} {array.dtype.str} {array.shape}".encode())
            digest.update(array.tobytes())
        return digest.hexdigest()[:16]


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


def quintic(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend s(tau) on [0, 1] (clipped outside) and its first two derivatives."""
    tau = np.clip(tau, 0.0, 1.0)
    s = tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


@dataclass(frozen=True, eq=False)
class Segment:
    """A C2 rest-to-rest piece: arch (or straight line) from ``start`` to ``end`` (m) in ``duration`` (s).

    Attributes:
        start, end: End points (m), shape (3,).
        duration: Move time T (s).
        lift_height: Rise above the higher end point (m); 0 for a straight line.
        lift_fraction: Share of T spent rising, and again descending, in (0, 1].
    """

    start: np.ndarray
    end: np.ndarray
    duration: float
    lift_height: float = 0.0
    lift_fraction: float = 1.0

    @staticmethod
    def line(start: np.ndarray, end: np.ndarray, duration: float) -> Segment:
        """A straight rest-to-rest line (no lift); ``start == end`` is a dwell."""
        return Segment(np.asarray(start, dtype=float), np.asarray(end, dtype=float), float(duration))

    def unit(self) -> Segment:
        """The same shape at unit duration: its positions at local time tau in [0, 1] are the shape x(tau)."""
        return Segment(self.start, self.end, 1.0, self.lift_height, self.lift_fraction)

    def timed(self, peak_acceleration: float) -> Segment:
        """The same shape, retimed so that its peak |xdd| equals ``peak_acceleration``."""
        start, end = tuple(map(float, self.start)), tuple(map(float, self.end))
        unit_peak = _unit_peak(start, end, float(self.lift_height), float(self.lift_fraction))
        if unit_peak == 0.0:
            raise ValueError(f"a move from {self.start.tolist()} m to itself cannot be timed by acceleration")
        # |xdd| scales with 1 / T^2 for a fixed shape
        duration = math.sqrt(unit_peak / peak_acceleration)
        return Segment(self.start, self.end, duration, self.lift_height, self.lift_fraction)


@functools.lru_cache(maxsize=4096)
def _unit_peak(start: tuple[float, ...], end: tuple[float, ...], lift_height: float, lift_fraction: float) -> float:
    """Peak |xdd| (m/s^2) of a move shape at unit duration, on :data:`_SHAPE_GRID` samples; kept per process: the
    design study times the same few shapes for every design."""
    tau = np.linspace(0.0, 1.0, _SHAPE_GRID)
    unit = Segment(np.array(start), np.array(end), 1.0, lift_height, lift_fraction)
    _, _, acceleration = evaluate_segments([unit], np.zeros(tau.shape, dtype=int), tau)
    return float(np.max(np.linalg.norm(acceleration, axis=-1)))


def evaluate_segments(
    segments: Sequence[Segment], index: np.ndarray, local_time: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration of ``segments[index]`` at ``local_time`` (s), each ``(n, 3)``."""
    start = np.array([segment.start for segment in segments])[index]
    end = np.array([segment.end for segment in segments])[index]
    duration = np.array([segment.duration for segment in segments])[index]
    lift = np.array([segment.lift_height for segment in segments])[index]
    vertical_time = np.array([segment.lift_fraction for segment in segments])[index] * duration

    s, ds, dds = quintic(local_time / duration)
    delta = end - start
    position = start + delta * s[:, None]
    velocity = delta * (ds / duration)[:, None]
    acceleration = delta * (dds / duration**2)[:, None]

    # z: a quintic up to the top over the first vertical_time, a quintic down over the last one;
    # with lift 0 and vertical_time = duration the two add up to the straight line.
    z_start, z_end = start[:, 2], end[:, 2]
    top = np.maximum(z_start, z_end) + lift
    up, up_d, up_dd = quintic(local_time / vertical_time)
    down, down_d, down_dd = quintic((local_time - duration + vertical_time) / vertical_time)
    rise, fall = top - z_start, z_end - top
    position[:, 2] = z_start + rise * up + fall * down
    velocity[:, 2] = (rise * up_d + fall * down_d) / vertical_time
    acceleration[:, 2] = (rise * up_dd + fall * down_dd) / vertical_time**2
    return position, velocity, acceleration


def sample_segments(
    geometry: DeltaGeometry,
    segments: Sequence[Segment],
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
    xyz, xyz_dot, xyz_ddot = evaluate_segments(segments, index, time - starts[index])
    theta, theta_dot, theta_ddot = kinematics.cartesian_to_joint(geometry, xyz, xyz_dot, xyz_ddot)

    picks = np.array([round(pick / dt) for pick, _ in events], dtype=np.int64)
    places = np.array([round(place / dt) for _, place in events], dtype=np.int64)
    gripper = np.zeros(n_samples, dtype=bool)
    for pick, place in zip(picks, places, strict=True):
        gripper[pick:place] = True
    return Trajectory(dt, xyz, xyz_dot, xyz_ddot, theta, theta_dot, theta_ddot, gripper, picks, places)
