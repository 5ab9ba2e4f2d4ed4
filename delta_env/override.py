"""Speed override: slow down or stop the rest of a reference along its own path (docs/design.md section 5).

A real robot controller reacts to a fault by ramping its speed override, jerk-limited, to a lower value
("slow down") or to zero ("stop at rest", a controlled category-2 stop along the path, then holding still).
Here the reference comes from the env, so the override is a time scaling of the rest of it: from sample ``k``
on, the new reference at time t is the old one at path time s(t),

    x(t) = x_old(s),   x_dot = x_old'(s) s_dot,   x_ddot = x_old''(s) s_dot^2 + x_old'(s) s_ddot,

and likewise for the joint angles. The path rate s_dot starts at its value at ``k`` (1 on an unscaled
reference, with s_ddot = 0) and goes to the target rate along a jerk-limited ruckig profile (velocity
interface, one degree of freedom) with ``|s_ddot| <= RateLimits.acceleration`` and
``|s_dddot| <= RateLimits.jerk``. Because the ruckig profile is C2 in s and continues the state at ``k``,
the new reference is C2 at ``k``.

The old reference is known only at its samples, 1 ms apart, with position, velocity and acceleration; between
samples it is interpolated by the quintic Hermite polynomial that matches all three at both ends. That
interpolant is C2, exact for the quintic blends the moves are built of, and its derivatives give x_old' and
x_old'' consistently with x_old (error O(dt^6) in position, far below a micrometre), where separate linear
interpolations of x, x' and x'' would err by dt^2 |x''| / 8, about 4 micrometres at 3 g, and disagree with
each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig
from numpy.typing import NDArray

from delta_env.trajectories import Trajectory
from delta_env.validation import require_in, require_positive

STOP_HOLD = 0.1
"""Time (s) a stop holds the platform at rest at its stopping point before the reference ends."""

MAX_OVERRIDE_SAMPLES = 10_000_000
"""Most samples (about 2.8 h at 1 ms) a slowed reference may have; a smaller rate is refused (use 0 to stop)."""

FALLBACK_LIMITS = (10.0, 1000.0)
"""(s_ddot in 1/s, s_dddot in 1/s^2) of a reference that never moves, which has no peaks to take them from."""

_NAMES = ("xyz", "theta")  # each with its _dot and _ddot
_EPSILON = 1e-9  # in samples: path times this close to a sample are that sample


@dataclass(frozen=True)
class RateLimits:
    """Limits of the path rate's ramp.

    Attributes:
        acceleration: Largest |s_ddot| (1/s).
        jerk: Largest |s_dddot| (1/s^2).
    """

    acceleration: float
    jerk: float

    def __post_init__(self) -> None:
        require_positive("acceleration", self.acceleration, unit="1/s")
        require_positive("jerk", self.jerk, unit="1/s^2")

    @staticmethod
    def of(trajectory: Trajectory) -> RateLimits:
        """The limits under which the ramp asks no more of any joint than the reference itself does.

        The ramp adds theta'(s) s_ddot to a joint's acceleration and theta'(s) s_dddot (among smaller terms)
        to its jerk, with |theta'| at most the joint's peak speed over the reference. So
        ``acceleration = min_j max|theta_ddot_j| / max|theta_dot_j|`` and
        ``jerk = min_j max|theta_dddot_j| / max|theta_dot_j|`` (the jerk by finite differences) keep each
        added term within the reference's own peak on every joint: a stop brakes no harder than the moves
        themselves accelerate (the total, with the reference's own term x'' s_dot^2, stays within twice
        the peak). On the default 3 g conveyor cycles this gives about 11 to 13 1/s and 700 to 900 1/s^2: a stop
        from full rate takes about 0.1 s (0.05 s on the shorter moves of the 25/305/25 mm cycle).
        """
        speed = np.max(np.abs(trajectory.theta_dot), axis=0)
        moving = speed > 1e-9
        if not np.any(moving):
            return RateLimits(*FALLBACK_LIMITS)
        acceleration = np.max(np.abs(trajectory.theta_ddot), axis=0)
        jerk = (
            np.max(np.abs(np.diff(trajectory.theta_ddot, axis=0)), axis=0) / trajectory.dt
            if len(trajectory) > 1
            else np.zeros(3)
        )
        a = float(np.min(acceleration[moving] / speed[moving]))
        j = float(np.min(jerk[moving] / speed[moving]))
        fallback_a, fallback_j = FALLBACK_LIMITS
        return RateLimits(a if a > 0.0 else fallback_a, j if j > 0.0 else fallback_j)


@dataclass(frozen=True, eq=False)
class SpeedOverride:
    """A reference whose rest has been time-scaled, with its path time, so that a later override can continue it.

    Attributes:
        nominal: The reference as planned, before any override.
        trajectory: The reference to follow: its first samples as followed, then the scaled rest.
        path_time: s (s) of every sample of ``trajectory``: the time of ``nominal`` it shows, ``(N,)``.
        path_rate: s_dot, ``(N,)``.
        path_acceleration: s_ddot (1/s), ``(N,)``.
        rate: The target rate of the last override (0: a stop).
        limits: The ramp's limits.
    """

    nominal: Trajectory
    trajectory: Trajectory
    path_time: NDArray[np.float64]
    path_rate: NDArray[np.float64]
    path_acceleration: NDArray[np.float64]
    rate: float
    limits: RateLimits

    @staticmethod
    def identity(trajectory: Trajectory, limits: RateLimits | None = None) -> SpeedOverride:
        """``trajectory`` unscaled: s = t, s_dot = 1, s_ddot = 0."""
        n = len(trajectory)
        return SpeedOverride(
            trajectory,
            trajectory,
            np.arange(n) * trajectory.dt,
            np.ones(n),
            np.zeros(n),
            1.0,
            RateLimits.of(trajectory) if limits is None else limits,
        )


def scale_speed(
    trajectory: Trajectory, k: int, rate: float, *, limits: RateLimits | None = None, hold: float = STOP_HOLD
) -> Trajectory:
    """``trajectory`` with its rest from sample ``k`` run at ``rate`` (0 stops): :func:`override_speed`'s reference."""
    return override_speed(trajectory, k, rate, limits=limits, hold=hold).trajectory


def override_speed(
    reference: Trajectory | SpeedOverride,
    k: int,
    rate: float,
    *,
    limits: RateLimits | None = None,
    hold: float = STOP_HOLD,
) -> SpeedOverride:
    """Ramp the path rate of ``reference`` from its sample ``k`` to ``rate``, jerk-limited.

    Samples 0..k stay as they are. From k on, s_dot goes from its value at k to ``rate`` along a ruckig profile
    within ``limits``, and the reference is the nominal one at path time s (module docstring).

    - ``0 < rate <= 1`` (slow down, or back to full speed): the new reference runs to the nominal end at
      ``rate``; its last sample is the nominal last one.
    - ``rate == 0`` (stop at rest): once s_dot reaches 0 (or the nominal end is reached) the platform holds its
      stopping point at rest for ``hold`` seconds, and the reference ends.

    Gripper events the reference has not reached by sample k are moved to the first new sample whose path time
    reaches them; those a stop never reaches are dropped (its objects are never picked, or never released).

    Args:
        reference: A :class:`~delta_env.trajectories.Trajectory` (unscaled), or a :class:`SpeedOverride` to
            override again: rates are always fractions of the nominal speed, not of the current one.
        k: Sample from which to change, in [0, len - 1].
        rate: Target path rate in [0, 1].
        limits: Limits of the ramp; default :meth:`RateLimits.of` the nominal reference (a
            :class:`SpeedOverride` keeps its own).
        hold: Rest (s) at the end of a stop, >= 0.

    Raises:
        ValueError: a rate outside [0, 1], a ``k`` outside the reference, or a rate so small that the reference
            would exceed :data:`MAX_OVERRIDE_SAMPLES`.
    """
    if isinstance(reference, Trajectory):
        reference = SpeedOverride.identity(reference, limits)
    elif not isinstance(reference, SpeedOverride):
        raise ValueError(f"reference must be a Trajectory or a SpeedOverride, got {type(reference)}")
    rate = require_in("rate", rate, 0.0, 1.0)
    hold = require_in("hold", hold, 0.0, unit="s")
    current = reference.trajectory
    if not (isinstance(k, int | np.integer) and 0 <= k < len(current)):
        raise ValueError(f"k must be a sample index in [0, {len(current) - 1}], got {k!r}")
    k = int(k)
    limits = reference.limits if limits is None else limits
    nominal = reference.nominal
    dt = nominal.dt

    time, speed, acceleration = _profile(
        (reference.path_time[k], reference.path_rate[k], reference.path_acceleration[k]),
        rate,
        limits,
        dt,
        (len(nominal) - 1) * dt,
        hold,
    )
    # the new samples after k, in the nominal's sample units
    sigma = time[1:] / dt
    nearest = np.rint(sigma)
    sigma = np.where(np.abs(sigma - nearest) < _EPSILON, nearest, sigma)
    arrays = {}
    for name in _NAMES:
        x, x1, x2 = _hermite(nominal, name, sigma)
        new = (x, x1 * speed[1:, None], x2 * speed[1:, None] ** 2 + x1 * acceleration[1:, None])
        for suffix, values in zip(("", "_dot", "_ddot"), new, strict=True):
            arrays[name + suffix] = np.concatenate((getattr(current, name + suffix)[: k + 1], values))

    length = k + 1 + len(sigma)
    picks = _remap(nominal.pick_indices, current.pick_indices, k, sigma)
    places = _remap(nominal.place_indices, current.place_indices, k, sigma)
    gripper = np.zeros(length, dtype=bool)
    for c, pick in enumerate(picks):
        gripper[pick : places[c] if c < len(places) else length] = True
    trajectory = Trajectory(dt, gripper=gripper, pick_indices=picks, place_indices=places, **arrays)
    return SpeedOverride(
        nominal,
        trajectory,
        np.concatenate((reference.path_time[: k + 1], time[1:])),
        np.concatenate((reference.path_rate[: k + 1], speed[1:])),
        np.concatenate((reference.path_acceleration[: k + 1], acceleration[1:])),
        rate,
        limits,
    )


def _profile(
    start: tuple[float, float, float], rate: float, limits: RateLimits, dt: float, end: float, hold: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """s, s_dot, s_ddot every dt from ``start`` (the state at k, first row) on, until the reference ends.

    ``end`` is the nominal's last path time (s); a stop adds ``hold`` seconds at rest.
    """
    otg = ruckig.Ruckig(1)
    query = ruckig.InputParameter(1)
    query.control_interface = ruckig.ControlInterface.Velocity
    query.current_position = [float(start[0])]
    query.current_velocity = [float(start[1])]
    query.current_acceleration = [float(start[2])]
    query.target_velocity = [rate]
    query.target_acceleration = [0.0]
    query.max_velocity = [2.0]  # unused by the velocity interface, but validated
    query.max_acceleration = [limits.acceleration]
    query.max_jerk = [limits.jerk]
    ramp = ruckig.Trajectory(1)
    result = otg.calculate(query, ramp)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise RuntimeError(f"ruckig could not plan the rate ramp from {start} to {rate}: {result}")
    duration = ramp.duration
    ramp_samples = math.ceil(duration / dt - _EPSILON)  # the first sample at or past the ramp's end
    position, _, _ = ramp.at_time(duration)
    # from that sample on, the rate holds: at rest for a stop, at ``rate`` otherwise
    settled = position[0] + rate * (ramp_samples * dt - duration)
    if rate > 0.0:
        # (at least one new sample, so that a reference at its end still has a next step)
        total = max(2, ramp_samples + 1 + max(0, math.ceil((end - settled) / (rate * dt) - _EPSILON)))
    else:
        total = ramp_samples + 1 + round(hold / dt)
    if total > MAX_OVERRIDE_SAMPLES:
        raise ValueError(
            f"rate {rate:g} would make the reference {total} samples long, more than {MAX_OVERRIDE_SAMPLES}: "
            "use a larger rate, or 0 to stop"
        )
    time = settled + rate * (np.arange(total) - ramp_samples) * dt
    speed = np.full(total, rate)
    acceleration = np.zeros(total)
    for n in range(min(ramp_samples, total)):
        (time[n],), (speed[n],), (acceleration[n],) = ramp.at_time(n * dt)

    reached = np.flatnonzero(time >= end - _EPSILON * dt)
    if reached.size:
        first = int(reached[0])
        if rate > 0.0:
            first = max(first, 1)
            # the last sample is the nominal's last one, at the rate reached
            time, speed, acceleration = time[: first + 1], speed[: first + 1], acceleration[: first + 1]
            time[first] = end
        else:
            # a stop that reaches the nominal end holds it from there, then for the hold
            total = first + 1 + round(hold / dt)
            rest = total - first
            time = np.concatenate((time[:first], np.full(rest, end)))
            speed = np.concatenate((speed[:first], np.zeros(rest)))
            acceleration = np.concatenate((acceleration[:first], np.zeros(rest)))
    return time, speed, acceleration


def _hermite(
    trajectory: Trajectory, name: str, sigma: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """x, dx/ds, d2x/ds2 of ``trajectory.<name>`` at fractional samples ``sigma`` (quintic Hermite)."""
    x, v, a = (getattr(trajectory, name + suffix) for suffix in ("", "_dot", "_ddot"))
    dt = trajectory.dt
    last = len(trajectory) - 1
    sigma = np.clip(sigma, 0.0, last)
    i = np.minimum(np.floor(sigma).astype(np.int64), max(last - 1, 0))
    j = np.minimum(i + 1, last)
    u = (sigma - i)[:, None]
    # basis of p(0), p'(0) h, p''(0) h^2, p(1), p'(1) h, p''(1) h^2 on u in [0, 1], h = dt
    u2, u3, u4, u5 = u * u, u**3, u**4, u**5
    h0 = 1 - 10 * u3 + 15 * u4 - 6 * u5
    h1 = u - 6 * u3 + 8 * u4 - 3 * u5
    h2 = 0.5 * u2 - 1.5 * u3 + 1.5 * u4 - 0.5 * u5
    h3 = 10 * u3 - 15 * u4 + 6 * u5
    h4 = -4 * u3 + 7 * u4 - 3 * u5
    h5 = 0.5 * u3 - u4 + 0.5 * u5
    d0 = -30 * u2 + 60 * u3 - 30 * u4
    d1 = 1 - 18 * u2 + 32 * u3 - 15 * u4
    d2 = u - 4.5 * u2 + 6 * u3 - 2.5 * u4
    d4 = -12 * u2 + 28 * u3 - 15 * u4
    d5 = 1.5 * u2 - 4 * u3 + 2.5 * u4
    e0 = -60 * u + 180 * u2 - 120 * u3
    e1 = -36 * u + 96 * u2 - 60 * u3
    e2 = 1 - 9 * u + 18 * u2 - 10 * u3
    e4 = -24 * u + 84 * u2 - 60 * u3
    e5 = 3 * u - 12 * u2 + 10 * u3
    p0, p1 = x[i], x[j]
    v0, v1 = v[i] * dt, v[j] * dt
    a0, a1 = a[i] * dt * dt, a[j] * dt * dt
    position = h0 * p0 + h1 * v0 + h2 * a0 + h3 * p1 + h4 * v1 + h5 * a1
    # d/ds = (1 / dt) d/du; the p1 basis derivatives are minus the p0 ones
    velocity = (d0 * (p0 - p1) + d1 * v0 + d2 * a0 + d4 * v1 + d5 * a1) / dt
    accel = (e0 * (p0 - p1) + e1 * v0 + e2 * a0 + e4 * v1 + e5 * a1) / (dt * dt)
    return position, velocity, accel


def _remap(nominal: NDArray[np.int64], current: NDArray[np.int64], k: int, sigma: NDArray[np.float64]) -> list[int]:
    """Event samples of the new reference: kept if reached by k, else the first new sample reaching the nominal one.

    ``sigma`` holds the nominal samples shown by the new samples k + 1, k + 2, ...; events never reached are
    dropped (with every later one, so that the cycles stay in order).
    """
    indices = []
    for c, event in enumerate(nominal.tolist()):
        if c < len(current) and current[c] <= k:
            indices.append(int(current[c]))
            continue
        reached = np.flatnonzero(sigma >= event - _EPSILON)
        if not reached.size:
            break
        indices.append(k + 1 + int(reached[0]))
    return indices
