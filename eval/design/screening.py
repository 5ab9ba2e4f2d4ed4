"""The cheap path of the co-design: every drive's pick rate from time laws planned once (the optimizer's objective).

Planning every drive with the full planner (:func:`eval.design.drive_rate.planned_rate`) costs about 1 s each.
Instead, the time laws tau(t) of the cycle's two moves are planned once (per process) on the nominal robot with
:data:`REFERENCE_DRIVES` (a balanced and a speed-limited gearing) at the data-sheet placement; the shape x(tau) is
the same Cartesian path for every design, moved onto the design's belt (a law parametrizes any path, so the
reference laws serve every belt height and only the shapes move). Run k times faster, a law's joint rates scale by
k and its accelerations by k^2, so along it every design's torque is exactly a + b k + c k^2 (gravity and Coulomb;
viscous; inertia, velocity products and the armature), its lag-inverse command adds lead k d/dt of that, its
speeds k |q'|, and its RMS over the move and the dwell follows. For every drive and move a bisection finds the
largest k that keeps the planner's envelope, speed limit and the thermal limit: a feasible, slightly sub-optimal
law of that drive (each move from its best reference). :func:`eval.design.codesign.choose_drive` with
``exact=True`` then plans the best screened drives with the full planner and keeps the fastest
(tests/test_codesign.py: the two agree within 3 % near the optimum).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.payload_timing import THERMAL_MARGIN
from controllers.timing import DEFAULT_MARGIN, TimeOptimalPlanner
from delta_env import kinematics
from delta_env.catalogue import CATALOGUE, MOTORS, DriveOption
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry, DeltaMasses
from delta_env.timed_cycles import TimedCycles
from delta_env.timing import TimeLaw, move_samples
from delta_env.trajectories import WORKING_HEIGHT, Segment
from delta_env.validation import require_in
from eval.design.drive_rate import PickRate, cycle_rate, drive_timing, timed_cycle
from eval.design.model import CYCLE_DWELL, DRIVE, design_model, require_belt_height

REFERENCE_DRIVES = tuple(DriveOption("SGM7A-20A", MOTORS["SGM7A-20A"], ratio) for ratio in (50.0, 100.0))
"""Drives whose time laws on the nominal robot the cheap path scales: balanced and speed-limited (a third,
torque-limited one at 1:20 gave no drive a faster law)."""

BISECTIONS = 12
"""Bisection steps of a move's speed-up in the cheap path, per constraint (resolution 2^-12 of its upper bound)."""

SCREEN_STRIDE = 2
"""The cheap path checks the envelope at every second sample of a law (2 ms)."""

SCREEN_CHUNK = 8
"""Drive options scored together by the cheap path's branch and bound."""

MAX_SPEED_UP = 1e3
"""Upper bound of a speed-up where no joint moves (no speed limit applies)."""


@dataclass(frozen=True)
class _ScaledTiming:
    """A :class:`delta_env.timing.MoveTiming` that returns one fixed law for the carry and one for the empty move."""

    carry_law: TimeLaw
    empty_law: TimeLaw
    retimes_online: bool = False

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        return self.carry_law

    def empty(self, shape: Segment) -> TimeLaw:
        return self.empty_law

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        return None


@dataclass(frozen=True)
class _Recorder:
    """Plans every move of a cycle with one planner, carries for a fixed payload."""

    planner: TimeOptimalPlanner
    payload: float
    retimes_online: bool = False

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        return self.planner.plan(shape, self.payload)

    def empty(self, shape: Segment) -> TimeLaw:
        return self.planner.plan(shape, 0.0)

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        return None


@functools.cache
def reference_cycles(payload: float) -> tuple[TimedCycles, ...]:
    """The standard cycle on the nominal robot at the data-sheet placement planned with each of
    :data:`REFERENCE_DRIVES`, carries with ``payload`` (kg); planned once per process."""
    return tuple(
        timed_cycle(
            NOMINAL_GEOMETRY, _Recorder(drive_timing(NOMINAL_GEOMETRY, option, payload).planner, payload), payload
        )
        for option in REFERENCE_DRIVES
    )


def _moves(cycles: TimedCycles, belt_height: float) -> list[tuple[Segment, TimeLaw, bool]]:
    """(shape, law, carries) of the carry and the empty move of a reference cycle, the shapes moved from
    :data:`WORKING_HEIGHT` onto the belt at ``belt_height`` (m, base frame)."""
    rise = np.array([0.0, 0.0, belt_height - WORKING_HEIGHT])
    moves = []
    for piece in cycles.pieces:
        if piece.law is not None:
            shape = dataclasses.replace(piece.shape, start=piece.shape.start + rise, end=piece.shape.end + rise)
            moves.append((shape, piece.law, piece.carry is not None))
    return moves


class _Drives:
    """Peak and rated torque (N m), corner and maximum speed (rad/s) and armature (kg m^2) of drive options, each
    ``(n, 1, 1)`` to broadcast over (option, sample, joint)."""

    def __init__(self, options: Sequence[DriveOption]) -> None:
        limits = [option.limits for option in options]
        self.peak, self.rated, self.corner, self.top, self.armature = (
            np.array(values, dtype=float)[:, None, None]
            for values in zip(
                *(
                    (d.peak_torque, d.rated_torque, d.corner_speed, d.max_speed, o.armature)
                    for d, o in zip(limits, options, strict=True)
                ),
                strict=True,
            )
        )

    def subset(self, index: NDArray[np.int_]) -> _Drives:
        """The drives at ``index``."""
        chosen = object.__new__(_Drives)
        for name in ("peak", "rated", "corner", "top", "armature"):
            setattr(chosen, name, getattr(self, name)[index])
        return chosen


class _MoveScaling:
    """A reference law of one move on a design, to be run k times faster by drive options (module docstring).

    Along the law the torque is a + b k + (c + J qdd) k^2 for a drive of armature J; the lag-inverse command leads
    it by dt / (1 - p) (:class:`delta_env.drive.SampledLag`'s inverse). The envelope is checked at every
    :data:`SCREEN_STRIDE`-th sample, the RMS over the move and the dwell after it exactly. Built by
    :func:`_move_scalings` from the move's joint rates ``qd`` (rad/s), joint accelerations ``qdd`` (rad/s^2) and the
    links' torque (N m) at rest (``static``) and along the law (``moving``), each ``(N, 3)``.
    """

    def __init__(
        self,
        law: TimeLaw,
        qd: NDArray[np.float64],
        qdd: NDArray[np.float64],
        static: NDArray[np.float64],
        moving: NDArray[np.float64],
    ) -> None:
        parts = (static + DRIVE.coulomb * np.sign(qd), DRIVE.viscous * qd, moving - static, qdd)
        self.law, self.dt = law, law.dt
        # Sums over the move's samples (the last one starts the dwell) of products of the parts: the squared torque.
        moving_parts = [part[:-1] for part in parts]
        self._sums = {(i, j): np.sum(moving_parts[i] * moving_parts[j], axis=0) for i in range(4) for j in range(i, 4)}
        self._resting = parts[0][-1] ** 2
        lag = DRIVE.actuator_lag
        self._lead = self.dt / (1.0 - math.exp(-self.dt / lag)) if lag > 0.0 else 0.0
        # what within checks at every SCREEN_STRIDE-th sample: the parts, their rates, the joint speeds and signs
        rates = [np.gradient(part, self.dt, axis=0) for part in parts]
        columns = (*parts, *rates, np.abs(qd), np.sign(qd))
        self._columns = np.stack([column[::SCREEN_STRIDE] for column in columns])
        self._fastest = float(np.max(np.abs(qd)))

    def cool(self, drives: _Drives) -> NDArray[np.float64]:
        """Largest k (per option) within the speed limit and the thermal limit: an upper bound of the speed-up."""
        sums, j = self._sums, drives.armature[:, :, 0]
        mixed = (sums[0, 2] + j * sums[0, 3], sums[1, 2] + j * sums[1, 3])
        inertial = sums[2, 2] + 2.0 * j * sums[2, 3] + j**2 * sums[3, 3]
        limit = ((1.0 - THERMAL_MARGIN) * drives.rated[:, :, 0]) ** 2

        def passes(k: NDArray[np.float64]) -> NDArray[np.bool_]:
            s = k[:, None]
            squared = sums[0, 0] + 2 * s * sums[0, 1] + s**2 * (sums[1, 1] + 2 * mixed[0]) + 2 * s**3 * mixed[1]
            squared = squared + s**4 * inertial
            heat = squared * self.dt / s + CYCLE_DWELL * self._resting
            return np.all(heat <= limit * (self.law.duration / s + CYCLE_DWELL), axis=1)

        speed = (1.0 - DEFAULT_MARGIN) * drives.top[:, 0, 0]
        high = speed / self._fastest if self._fastest > 0.0 else np.full(len(speed), MAX_SPEED_UP)
        return _largest(passes, high)

    def within(self, drives: _Drives, high: NDArray[np.float64]) -> NDArray[np.float64]:
        """Largest k (per option) up to ``high`` whose torque and command keep the planner's envelope: the
        bisection of :func:`_largest` in compiled code (:func:`_largest_within`), an option at a time."""
        ratings = np.stack([rating[:, 0, 0] for rating in (drives.peak, drives.top, drives.corner, drives.armature)])
        return _largest_within(self._columns, self._lead, ratings, np.asarray(high, dtype=float))


def _move_scalings(
    geometry: DeltaGeometry, masses: DeltaMasses | None, moves: Sequence[tuple[Segment, TimeLaw, float]]
) -> list[_MoveScaling]:
    """A :class:`_MoveScaling` of each (shape, law, load (kg)) on the design: the samples of every move joined, so
    that one inverse kinematics and one inverse dynamics (at rest and along the laws) serve them all; NumPy's
    per-sample arithmetic gives each sample the same numbers as a call of its own."""
    links = design_model(geometry, masses, dataclasses.replace(DRIVE, armature=0.0, viscous=0.0, coulomb=0.0))
    samples = [move_samples(shape, law) for shape, law, _ in moves]
    ends = np.cumsum([len(x) for x, _, _ in samples])[:-1]
    q, qd, qdd = kinematics.cartesian_to_joint(
        geometry, *(np.concatenate(columns) for columns in zip(*samples, strict=True))
    )
    load = np.concatenate([np.full(len(x), float(m)) for (x, _, _), (_, _, m) in zip(samples, moves, strict=True)])
    rest = np.zeros_like(q)
    torque = links.inverse_dynamics(
        np.concatenate((q, q)), np.concatenate((rest, qd)), np.concatenate((rest, qdd)), np.concatenate((load, load))
    )
    static, moving = np.split(torque, 2)
    per_move = zip(*(np.split(array, ends) for array in (qd, qdd, static, moving)), strict=True)
    return [
        _MoveScaling(law, *(part.copy() for part in parts)) for (_, law, _), parts in zip(moves, per_move, strict=True)
    ]


@numba.njit(cache=True)
def _largest_within(
    columns: NDArray[np.float64], lead: float, ratings: NDArray[np.float64], high: NDArray[np.float64]
) -> NDArray[np.float64]:
    """:meth:`_MoveScaling.within` by :func:`_largest`'s bisection, an option at a time: the largest k up to
    ``high`` (n,) for each option of ``ratings`` (4, n) (peak torque (N m), maximum and corner speed (rad/s),
    armature (kg m^2)) that :func:`_within_envelope` passes with the move's ``columns`` and ``lead`` (s)."""
    largest = np.empty(high.size)
    for option in range(high.size):
        upper = high[option]
        low = upper if _within_envelope(columns, lead, ratings[:, option], upper) else 0.0
        for _ in range(BISECTIONS):
            middle = 0.5 * (low + upper)
            if _within_envelope(columns, lead, ratings[:, option], max(middle, 1e-9)):
                low = middle
            else:
                upper = middle
        largest[option] = low
    return largest


@numba.njit(cache=True, inline="always")
def _within_envelope(columns: NDArray[np.float64], lead: float, rating: NDArray[np.float64], s: float) -> bool:
    """Whether the move run ``s`` times faster keeps one drive's envelope (``rating``: peak torque, maximum and
    corner speed, armature): the torque a + b s + (c + J w) s^2 and its lag-inverse command (plus ``lead`` (s) s
    times the same sum of the parts' rates) at every sample, with the samples' joint speeds (rad/s) and rate
    signs; ``columns`` (10, N, 3): a, b, c, w, their rates, the speeds and the signs. NumPy's operations of the
    same order on each element."""
    a, b, c, w, a_rate, b_rate, c_rate, w_rate, speed, sign = columns
    peak, top, corner, armature = rating
    held = DEFAULT_MARGIN * peak
    for i in range(a.shape[0]):
        for j in range(3):
            inertial = c[i, j] + armature * w[i, j]
            torque = a[i, j] + b[i, j] * s + inertial * (s * s)
            inertial_rate = c_rate[i, j] + armature * w_rate[i, j]
            command = torque + lead * s * (a_rate[i, j] + b_rate[i, j] * s + inertial_rate * (s * s))
            motoring = min(max(peak * (top - s * speed[i, j]) / (top - corner), 0.0), peak) - held
            for tau in (torque, command):
                if not abs(tau) <= (motoring if tau * sign[i, j] >= 0.0 else peak - held):
                    return False
    return True


def _largest(passes: Callable[[NDArray[np.float64]], NDArray[np.bool_]], high: NDArray[np.float64]) -> NDArray:
    """The largest k in [0, ``high``] (elementwise) that ``passes``, by bisection that keeps its low end passing;
    0 where nothing tried passes."""
    low = np.where(passes(high), high, 0.0)
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        passed = passes(np.maximum(middle, 1e-9))
        low, high = np.where(passed, middle, low), np.where(passed, high, middle)
    return low


def _scaled(law: TimeLaw, k: float) -> TimeLaw:
    """``law`` run about k times faster, on whole samples: tau_k(t) = tau(k' t) with the k' <= k that ends on one."""
    samples = math.ceil(law.duration / k / law.dt - 1e-9)
    k = law.duration / (samples * law.dt)
    time = np.minimum(np.arange(samples + 1) * law.dt * k, law.duration)
    reference = np.arange(len(law)) * law.dt
    tau = np.interp(time, reference, law.tau)
    tau_dot = k * np.interp(time, reference, law.tau_dot)
    tau_ddot = k**2 * np.interp(time, reference, law.tau_ddot)
    tau[-1], tau_dot[-1] = 1.0, 0.0
    return TimeLaw(law.dt, tau, tau_dot, tau_ddot)


@dataclass(frozen=True)
class Screen:
    """The cheap path's outcome for drive options.

    Attributes:
        rates: Picks per minute of each option (0: cannot run; NaN: not evaluated, beaten by ``keep`` others).
        laws: Per evaluated option, the (reference law, speed-up) of each move.
    """

    rates: NDArray[np.float64]
    laws: dict[int, list[tuple[TimeLaw, float]]]


def screen_drives(
    geometry: DeltaGeometry,
    options: Sequence[DriveOption],
    payload: float,
    masses: DeltaMasses | None,
    keep: int | None = None,
    belt_height: float = WORKING_HEIGHT,
) -> Screen:
    """Picks per minute of the options by the cheap path on the belt at ``belt_height`` (m, base frame). With
    ``keep``, options are scored in order of their upper bound (speed and thermal limits alone) in chunks of
    :data:`SCREEN_CHUNK`, until ``keep`` options are known to be the best: branch and bound, the same best options
    as scoring all."""
    belt_height = require_belt_height(belt_height)
    references = [_moves(cycles, belt_height) for cycles in reference_cycles(float(payload))]
    by_move = list(zip(*references, strict=True))  # by_move[move][reference]
    scalings = iter(
        _move_scalings(
            geometry,
            masses,
            [(shape, law, payload if carries else 0.0) for move in by_move for shape, law, carries in move],
        )
    )
    moves = [[next(scalings) for _ in move] for move in by_move]
    drives = _Drives(options)
    bounds = [[scaling.cool(drives) for scaling in move] for move in moves]

    def rate(speed_ups: list[list[NDArray[np.float64]]]) -> NDArray[np.float64]:
        total = 2.0 * CYCLE_DWELL
        for move, ks in zip(moves, speed_ups, strict=True):
            with np.errstate(divide="ignore"):
                total = total + np.min(
                    [np.where(k > 0.0, s.law.duration / k, math.inf) for s, k in zip(move, ks, strict=True)], axis=0
                )
        return 60.0 / total

    upper = rate(bounds)
    rates, laws = np.full(len(options), math.nan), {}
    order = np.argsort(-upper, kind="stable")
    for start in range(0, len(order), SCREEN_CHUNK):
        chunk = order[start : start + SCREEN_CHUNK]
        known = np.sort(rates[np.isfinite(rates)])[::-1]
        if keep is not None and len(known) >= keep and upper[chunk[0]] <= known[keep - 1]:
            break
        subset = drives.subset(chunk)
        speed_ups = [
            [s.within(subset, bound[chunk]) for s, bound in zip(move, move_bounds, strict=True)]
            for move, move_bounds in zip(moves, bounds, strict=True)
        ]
        rates[chunk] = rate(speed_ups)
        for position, index in enumerate(chunk):
            laws[int(index)] = []
            for move, ks in zip(moves, speed_ups, strict=True):
                best = int(np.argmax([k[position] / s.law.duration for s, k in zip(move, ks, strict=True)]))
                laws[int(index)].append((move[best].law, float(ks[best][position])))
    return Screen(rates, laws)


def screened_rates(
    geometry: DeltaGeometry,
    options: Sequence[DriveOption] = CATALOGUE,
    payload: float = RATED_PAYLOAD,
    masses: DeltaMasses | None = None,
    belt_height: float = WORKING_HEIGHT,
) -> NDArray[np.float64]:
    """Picks per minute of each drive option with ``payload`` (kg) on the belt at ``belt_height`` (m, base frame)
    by the cheap path (module docstring), ``(n,)``; 0 for a drive that cannot run the payload's moves at any
    speed."""
    require_in("payload", payload, 0.0, unit="kg")
    if not options:
        raise ValueError("screened_rates needs at least one drive option")
    return screen_drives(geometry, options, payload, masses, belt_height=belt_height).rates


def scaled_rate(
    geometry: DeltaGeometry,
    option: DriveOption,
    payload: float,
    laws: list[tuple[TimeLaw, float]],
    masses: DeltaMasses | None,
    belt_height: float = WORKING_HEIGHT,
) -> PickRate:
    """The standard cycle of ``option`` on the belt at ``belt_height`` (m, base frame) with its moves' reference
    laws run at their speed-ups (:attr:`Screen.laws` of :func:`screen_drives` at the same belt height)."""
    (carry, carry_k), (empty, empty_k) = laws
    timing = _ScaledTiming(_scaled(carry, carry_k), _scaled(empty, empty_k))
    cycles = timed_cycle(geometry, timing, payload, belt_height)
    return cycle_rate(geometry, option, payload, cycles, False, masses)


def screened_rate(
    geometry: DeltaGeometry,
    option: DriveOption,
    payload: float,
    masses: DeltaMasses | None = None,
    belt_height: float = WORKING_HEIGHT,
) -> PickRate | None:
    """The standard cycle of ``option`` with ``payload`` (kg) on the belt at ``belt_height`` (m, base frame) timed
    by the cheap path, or None if it cannot run it."""
    require_in("payload", payload, 0.0, unit="kg")
    scored = screen_drives(geometry, [option], payload, masses, belt_height=belt_height)
    if scored.rates[0] <= 0.0:
        return None
    return scaled_rate(geometry, option, payload, scored.laws[0], masses, belt_height)
