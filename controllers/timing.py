"""Time-optimal, payload-aware time laws of pick-and-place moves (issue "Pick rate").

:class:`TimeOptimalPlanner` times a move's fixed shape (a :class:`~delta_env.trajectories.Segment`) as fast
as the drive allows by the model's own account, in three steps:

1. **TOPP.** Along the joint path q(s) (s = tau, the shape parameter) the model's torque is
   tau = a(s) u + b(s) x + c(s) + fv q' sqrt(x) + fc sign(q') with u = sdd, x = sd^2, and the drive's envelope
   (:class:`~delta_env.drive.DriveLimits`, shrunk by ``margin`` of the peak torque) depends on the joint speed
   |q'| sqrt(x). The sqrt(x) terms are linearized conservatively (:meth:`TimeOptimalPlanner._stages`) and
   :func:`controllers.topp.solve` (toppra) finds the fastest profile: s(t) with piecewise-constant sdd.
2. **Smoothing.** That raw profile has torque steps, which the lag-inverse command of a drive with a 1 ms
   current loop turns into spikes. The reference is the causal moving average over a window w of the raw
   profile's horizontal progress p = quintic(s) (which, unlike s, has a non-zero slope at the ends), mapped
   back to tau: p(tau(t)) = (1/w) int_{t-w}^{t} p(s(t')) dt'. It is C2 with bounded jerk, stays on the path
   (it is a time law of the same shape) and ends at rest at T_raw + w.
3. **Verification.** The sampled law is checked at every control sample with the full model (friction
   included) and the lag-inverse command (:class:`~delta_env.drive.SampledLag`) against the shrunk envelope
   at the model's joint speed. If any sample fails, the constraint bounds are scaled down by
   :data:`TIGHTENING` at the gridpoints the raw profile passed during that sample's smoothing window (only
   there: the rest of the move keeps its full envelope) and the move is planned again. A returned law
   passes by construction.

:meth:`TimeOptimalPlanner.replan` continues a planned move from one of its samples for another payload (the
online retiming of a carry once a payload estimate arrives): it keeps the raw profile up to that time, so
the past samples repeat exactly and the continuation is C2.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.topp import X_CAP, RawProfile, StageConstraints, solve
from delta_env import kinematics
from delta_env.drive import DriveLimits, SampledLag
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timing import TimeLaw, move_samples
from delta_env.trajectories import Segment, evaluate_segments, quintic, require_sample_period
from delta_env.validation import require_in

DEFAULT_MARGIN = 0.10
"""Share of the peak torque (and of the maximum speed) held back for model error, PD feedback and noise."""

DEFAULT_SMOOTHING = 0.008
"""Moving-average window (s) of the reference: paid once per move, while the lag-inverse command's overshoot
over the model torque (the torque ramps over the window) grows as it shrinks. On the standard carry with a
1 ms lag, 5 / 8 / 15 ms windows gave verified moves of 65 / 68 / 75 ms (0 kg) and 134 / 137 / 145 ms (8 kg);
8 ms keeps the acceleration ramps (bounded jerk) over eight control periods for the PD and the plant."""

GRID_INTERVALS = 400
"""Grid intervals of a whole move's shape; a remainder (replan) gets its share."""

TANGENT_PASSES = 2
"""Conservative TOPP passes after the optimistic one, each linearizing sqrt(x) at the previous solution."""

REPLAN_GRID_INTERVALS = 200
"""Grid intervals of a whole move's shape when a carry's continuation is planned from a point of its law (its
remainder gets its share)."""

REPLAN_TANGENT_PASSES = 1
"""Conservative passes of a replan: one, on the coarser :data:`REPLAN_GRID_INTERVALS` grid, so that the table of
continuations an online timing precomputes per carry shape (:meth:`controllers.payload_timing.PayloadTiming.takeovers`)
stays cheap; its law is within a sample of the finer one and passes the same check (the timings:
docs/measurements.md, "Pick rate")."""

TIGHTENING = 0.97
"""Factor on every constraint bound after a failed verification."""

MAX_TIGHTENINGS = 30
"""Verification failures before :meth:`TimeOptimalPlanner.plan` gives up (0.97^30 = 0.4 of the envelope)."""


@dataclass
class PlanStats:
    """Where a plan's wall time went (s) and how much it had to tighten.

    Attributes:
        constraints: Evaluating the path and building the linear constraints.
        toppra: toppra's reachability analysis and forward pass.
        verification: Smoothing, sampling and checking the law with the full model and the lag inverse.
        scale: Smallest factor on the constraint bounds at any gridpoint (1 if the first plan passed).
        attempts: Plans made, the verified one included.
    """

    constraints: float = 0.0
    toppra: float = 0.0
    verification: float = 0.0
    scale: float = 1.0
    attempts: int = 0


@dataclass(frozen=True, eq=False)
class PlannedLaw(TimeLaw):
    """A smoothed time-optimal law that keeps the raw profile it came from, so it can be replanned.

    Attributes:
        raw: The raw (TOPP) profile s(t), from t = 0.
        smoothing: Moving-average window (s).
        payload: Payload (kg) the law was planned and verified for.
        stats: Wall time spent on the plan.
    """

    raw: RawProfile
    smoothing: float
    payload: float
    stats: PlanStats = field(default_factory=PlanStats)


class TimeOptimalPlanner:
    """The fastest rest-to-rest time laws of move shapes within the drive's envelope, by the model's account.

    Args:
        dynamics: The model (e.g. MId+F+R: ``forearm_rods=True`` with identified parameters); its friction
            (viscous fv q', Coulomb fc sign q') is part of the constraints.
        drive: The drive's torque-speed envelope at the joints.
        drive_lag: Current-loop time constant (s), scalar or per joint, in [0, 0.1].
        margin: Share of the peak torque held back at every speed, and of the maximum speed, in [0, 0.5).
        smoothing: Moving-average window of the reference (s), in [0, 0.1]; 0 returns the raw profile.
        dt: Control period (s) the laws are sampled at.
    """

    def __init__(
        self,
        dynamics: DeltaDynamics,
        drive: DriveLimits,
        drive_lag: float | tuple[float, float, float] = 0.0,
        margin: float = DEFAULT_MARGIN,
        smoothing: float = DEFAULT_SMOOTHING,
        dt: float = CONTROL_PERIOD,
    ) -> None:
        self.dynamics = dynamics
        self.drive = drive
        self.margin = require_in("margin", margin, 0.0, 0.5, high_open=True)
        self.smoothing = require_in("smoothing", smoothing, 0.0, 0.1, unit="s")
        self.dt = require_sample_period(dt)
        SampledLag(drive_lag, self.dt)  # validates the lag
        self.drive_lag = drive_lag
        parameters = dynamics.parameters
        self._rigid = dynamics.with_parameters(ModelParameters(rho1=parameters.rho1, rho2=parameters.rho2))
        self._viscous = np.array(parameters.viscous)
        self._coulomb = np.array(parameters.coulomb)

    @property
    def speed_limit(self) -> float:
        """Largest joint speed (rad/s) a plan may reach: the drive's maximum shrunk by the margin."""
        return (1.0 - self.margin) * self.drive.max_speed

    def plan(self, shape: Segment, payload: float, torque_scale: float = 1.0) -> PlannedLaw:
        """The fastest verified rest-to-rest law of ``shape`` (used at unit duration) with ``payload`` (kg).

        ``torque_scale`` in (0, 1] plans within that share of the shrunk envelope (and of the speed limit): a
        slower law, e.g. to keep the RMS torque within the drive's rating.
        """
        require_in("payload", payload, 0.0, unit="kg")
        grid = np.linspace(0.0, 1.0, GRID_INTERVALS + 1)
        scale = np.full(len(grid), _torque_scale(torque_scale))
        return self._planned(shape, payload, grid, None, 0, scale, TANGENT_PASSES)

    def replan(
        self,
        shape: Segment,
        law: TimeLaw,
        index: int,
        payload: float,
        torque_scale: float = 1.0,
        braking: tuple[float, float] | None = None,
    ) -> PlannedLaw:
        """``law`` up to its sample ``index``, then the fastest verified continuation with ``payload`` (kg).

        Samples 0 .. ``index`` are ``law``'s own; the continuation starts from the raw profile's state at
        ``index * dt``, so the law stays C2. ``torque_scale`` as in :meth:`plan`; ``braking`` = (tau, share), if
        given, plans the shape from tau on within at most that share of the envelope (its braking into the end).

        Raises:
            ValueError: if ``law`` is not a :class:`PlannedLaw` of this planner's period, ``index`` is outside
                it, or no continuation is feasible from that state (e.g. a much heavier payload).
        """
        require_in("payload", payload, 0.0, unit="kg")
        if not isinstance(law, PlannedLaw) or law.dt != self.dt or law.smoothing != self.smoothing:
            raise ValueError("replan needs a PlannedLaw of this planner (same dt and smoothing)")
        if not 0 <= index < len(law):
            raise ValueError(f"index must lie in [0, {len(law) - 1}], got {index}")
        cut = index * self.dt
        if cut >= law.raw.duration:  # the raw profile is over: what is left is its average, already fixed
            return law
        prefix = law.raw.until(cut)
        start = float(prefix.s[-1])
        count = max(math.ceil((1.0 - start) * REPLAN_GRID_INTERVALS), 20)
        grid = np.linspace(start, 1.0, count + 1)
        scale = np.full(len(grid), _torque_scale(torque_scale))
        if braking is not None:
            braking_from, braking_share = braking
            scale[grid >= braking_from] = np.minimum(scale[grid >= braking_from], _torque_scale(braking_share))
        return self._planned(shape, payload, grid, (prefix, law), index, scale, REPLAN_TANGENT_PASSES)

    def model_torque(
        self, shape: Segment, law: TimeLaw, payload: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The model's joint torques (N m), ``(n, 3)``, and joint rates (rad/s), along ``shape`` timed by ``law``."""
        x, velocity, acceleration = move_samples(shape, law)
        q, qd, qdd = kinematics.cartesian_to_joint(self.dynamics.geometry, x, velocity, acceleration)
        return self.dynamics.inverse_dynamics(q, qd, qdd, payload), qd

    def utilisation(self, shape: Segment, law: TimeLaw, payload: float) -> NDArray[np.float64]:
        """Worst share of the shrunk envelope used at each sample and joint, ``(n, 3)``; a law passes if all <= 1.

        At each sample: the full model's torque and speed, and the lag-inverse command held until the next
        sample (against the bounds at both samples' speeds), each over its allowed bound.
        """
        torque, qd = self.model_torque(shape, law, payload)
        lag = SampledLag(self.drive_lag, self.dt)
        lag.reset(torque[0])  # at rest before the move, the drive already holds the static torque
        command = np.array([lag.command(target) for target in torque[1:]])
        lower, upper = self._allowed(qd)
        command_lower = np.maximum(lower[:-1], lower[1:])
        command_upper = np.minimum(upper[:-1], upper[1:])
        shares = np.maximum(_share(torque, lower, upper), np.abs(qd) / self.speed_limit)
        shares[:-1] = np.maximum(shares[:-1], _share(command, command_lower, command_upper))
        return shares

    def _allowed(self, speed: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lower, upper) torque (N m) the plan may use at joint ``speed`` (rad/s): the envelope less the margin."""
        lower, upper = self.drive.torque_bounds(speed)
        held = self.margin * self.drive.peak_torque
        return lower + held, upper - held

    def _planned(
        self,
        shape: Segment,
        payload: float,
        grid: NDArray[np.float64],
        continuation: tuple[RawProfile, PlannedLaw] | None,
        index: int,
        scale: NDArray[np.float64],
        passes: int,
    ) -> PlannedLaw:
        """Plan on ``grid`` within ``scale`` of the envelope at each grid point (from the prefix's end state if
        continuing), smooth, verify, tighten until it passes."""
        stats = PlanStats()
        clock = time.perf_counter()
        q, dq, ddq = self._joint_path(shape, grid)
        terms = self._path_terms(q, dq, ddq, payload)
        stats.constraints += time.perf_counter() - clock
        sd_start = float(continuation[0].sd[-1]) if continuation else 0.0
        scale = scale.copy()
        for _ in range(MAX_TIGHTENINGS):
            raw = self._raw(grid, dq, terms, scale, sd_start, stats, passes)
            if continuation:
                raw = continuation[0].then(raw)
            clock = time.perf_counter()
            tau, tau_dot, tau_ddot = self._smoothed(raw)
            if continuation:
                past = continuation[1]
                tau[: index + 1], tau_dot[: index + 1] = past.tau[: index + 1], past.tau_dot[: index + 1]
                tau_ddot[: index + 1] = past.tau_ddot[: index + 1]
            stats.scale, stats.attempts = float(scale.min()), stats.attempts + 1
            law = PlannedLaw(self.dt, tau, tau_dot, tau_ddot, raw, self.smoothing, float(payload), stats)
            failed = np.flatnonzero(np.max(self.utilisation(shape, law, payload)[index:], axis=1) > 1.0) + index
            stats.verification += time.perf_counter() - clock
            if len(failed) == 0:
                return law
            scale[self._touched(raw, grid, failed)] *= TIGHTENING
        raise ValueError(f"no verified law after {MAX_TIGHTENINGS} tightenings (bounds scaled to {scale.min():.3f})")

    def _touched(self, raw: RawProfile, grid: NDArray[np.float64], samples: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Gridpoints the raw profile passes while it shapes ``samples``: the window before each sample and,
        for its lag-inverse command, the next sample; one grid step more on either side."""
        t = samples * self.dt
        first, _ = raw.state(t - self.smoothing - self.dt)
        last, _ = raw.state(t + 2.0 * self.dt)
        step = grid[1] - grid[0]
        low, high = first[:, None] - step, last[:, None] + step
        return np.any((grid >= low) & (grid <= high), axis=0)

    def _raw(
        self,
        grid: NDArray[np.float64],
        dq: NDArray[np.float64],
        terms: tuple[NDArray[np.float64], ...],
        scale: NDArray[np.float64],
        sd_start: float,
        stats: PlanStats,
        passes: int,
    ) -> RawProfile:
        """The TOPP profile with bounds scaled by ``scale`` per gridpoint: one optimistic pass, then conservative
        tangent passes."""
        x0 = None
        for _ in range(passes + 1):
            clock = time.perf_counter()
            stages = self._stages(grid, dq, terms, scale, x0)
            stats.constraints += time.perf_counter() - clock
            clock = time.perf_counter()
            raw = solve(stages, sd_start)
            stats.toppra += time.perf_counter() - clock
            x = raw.sd**2
            x0 = np.maximum(x, 1e-4 * np.median(x))
        return raw

    def _joint_path(self, shape: Segment, s: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """q(s), dq/ds, d^2q/ds^2 (rad), each ``(len(s), 3)``, from the exact shape and inverse kinematics."""
        unit = shape.unit()
        x, dx, ddx = evaluate_segments([unit], np.zeros(len(s), dtype=int), s)
        return kinematics.cartesian_to_joint(self.dynamics.geometry, x, dx, ddx)

    def _path_terms(
        self, q: NDArray[np.float64], dq: NDArray[np.float64], ddq: NDArray[np.float64], payload: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """a(s), b(s), c(s) (N m) of the rigid torque a u + b x + c, as toppra's SecondOrderConstraint."""
        zero = np.zeros_like(q)
        c = self._rigid.inverse_dynamics(q, zero, zero, payload)
        a = self._rigid.inverse_dynamics(q, zero, dq, payload) - c
        b = self._rigid.inverse_dynamics(q, dq, ddq, payload) - c
        return a, b, c

    def _stages(
        self,
        grid: NDArray[np.float64],
        dq: NDArray[np.float64],
        terms: tuple[NDArray[np.float64], ...],
        scale: NDArray[np.float64],
        x0: NDArray[np.float64] | None,
    ) -> StageConstraints:
        """The linear constraints at every gridpoint: for each joint and direction sigma = +-1, sigma tau below
        the (scaled, shrunk) peak and, on the motoring side, below the falling speed-dependent limit.

        With y = sqrt(x) and d = q'_j, a row reads sigma (a u + b x + c) + e + K y <= G: Coulomb e = +-fc,
        K y collects the viscous friction (+-fv |d| y) and, on the motoring side, the envelope's fall
        P |d| y / (v_max - v_corner) moved to the left. y is concave in x, so

        - K > 0: K y <= K (sqrt(x0) / 2 + x / (2 sqrt(x0))), the tangent at x0 (a concave function lies below
          its tangents): the linear row implies the true one for every x. Tangents at the previous pass's
          solution make it tight where the plan runs.
        - K < 0: K y <= K x / sqrt(x_max), the secant of y over [0, x_max] (a concave function lies above its
          chords there), and x <= x_max is itself a constraint.

        The first pass (``x0`` None) uses the secant for K > 0 too: optimistic, only to find x0.
        Where q'_j changes sign within a grid step (or is 0) the direction of motion is unknown: both sides
        get +fc, +fv |d| y and the motoring limit, the worst case of either sign.
        """
        a, b, c = terms
        drive, peak = self.drive, self.drive.peak_torque
        held = self.margin * peak
        fall = peak / (drive.max_speed - drive.corner_speed)  # N m per rad/s above the corner speed
        sign = np.sign(dq)
        unknown = (sign == 0.0) | (np.roll(sign, 1, axis=0) != sign) | (np.roll(sign, -1, axis=0) != sign)
        unknown[0] |= sign[0] == 0.0
        speed = np.abs(dq)
        scale = scale[:, None]
        with np.errstate(divide="ignore"):
            x_max = np.min(np.where(speed > 0.0, (scale * self.speed_limit / speed) ** 2, X_CAP), axis=1)
        x_max = np.minimum(x_max, X_CAP)
        rows_a, rows_b, rows_g = [], [], []
        for sigma in (1.0, -1.0):
            motoring = unknown | (sign == sigma)
            coulomb = np.where(motoring, self._coulomb, -self._coulomb)
            viscous = np.where(motoring, 1.0, -1.0) * self._viscous * speed
            peak_row = (viscous, scale * (peak - held) - sigma * c - coulomb)
            falling = (viscous + scale * fall * speed, scale * (fall * drive.max_speed - held) - sigma * c - coulomb)
            for k, g in (peak_row, np.where(motoring, falling, peak_row)):
                slope, offset = _linearized_sqrt(k, x0, x_max)
                rows_a.append(sigma * a)
                rows_b.append(sigma * b + slope)
                rows_g.append(g - offset)
        return StageConstraints(grid, np.hstack(rows_a), np.hstack(rows_b), np.hstack(rows_g), x_max)

    def _smoothed(self, raw: RawProfile) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """tau, tau_dot, tau_ddot of the moving average of ``raw`` over the window, sampled at dt to rest.

        The average is taken of the progress p = quintic(tau) (the horizontal share of the move), not of tau:
        the shape is degenerate in tau at its ends (x' = x'' = 0), where a time-optimal tau(t) is steep
        (tau ~ t^(2/3)), and averaging that would carry the steep ends into the move's middle. x(p) has a
        non-zero slope everywhere, so p(t) of the raw profile is as regular as the platform's motion and its
        average is the platform's motion smoothed. Back in tau: tau_dot = p_dot / quintic'(tau), and at
        tau = 0 or 1 (quintic' = 0) tau_dot and tau_ddot are set to 0, where x' = x'' = 0 makes them idle.
        """
        w = self.smoothing
        count = math.ceil((raw.duration + w) / self.dt - 1e-9) + 1
        t = np.arange(count) * self.dt
        if w == 0.0:
            s, sd = raw.state(t)
            index = np.clip(np.searchsorted(raw.time, t, side="right") - 1, 0, len(raw.sdd) - 1)
            tau, tau_dot, tau_ddot = s, sd, np.where(t < raw.time[-1], raw.sdd[index], 0.0)
        else:

            def progress_state(time: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
                s, sd = raw.state(time)
                p, dp, _ = quintic(s)
                return p, dp * sd

            def progress(s: NDArray[np.float64]) -> NDArray[np.float64]:
                return quintic(s)[0]

            # Before t = 0 the move rests at p = 0, so the integrals there are 0.
            p = (raw.integral(t, progress) - raw.integral(np.maximum(t - w, 0.0), progress)) / w
            (p_now, v_now), (p_late, v_late) = progress_state(t), progress_state(t - w)
            p_dot, p_ddot = (p_now - p_late) / w, (v_now - v_late) / w
            tau = _inverse_quintic(np.clip(p, 0.0, 1.0))
            _, slope, curvature = quintic(tau)
            inner = slope > 1e-6
            safe = np.where(inner, slope, 1.0)
            tau_dot = np.where(inner, p_dot / safe, 0.0)
            tau_ddot = np.where(inner, (p_ddot - curvature * tau_dot**2) / safe, 0.0)
        tau = np.maximum.accumulate(np.clip(tau, 0.0, 1.0))
        tau[0], tau[-1], tau_dot[0], tau_dot[-1] = 0.0, 1.0, 0.0, 0.0
        return tau, np.maximum(tau_dot, 0.0), tau_ddot


def _torque_scale(value: float) -> float:
    """``value`` if it is a share of the envelope in (0, 1], else ValueError."""
    return require_in("torque_scale", value, 0.0, 1.0, low_open=True)


def _inverse_quintic(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """tau in [0, 1] with quintic(tau) = p, by bisection (the quintic rises monotonically); p in [0, 1]."""
    low, high = np.zeros_like(p), np.ones_like(p)
    for _ in range(60):
        middle = 0.5 * (low + high)
        below = quintic(middle)[0] < p
        low, high = np.where(below, middle, low), np.where(below, high, middle)
    return 0.5 * (low + high)


def _linearized_sqrt(
    k: NDArray[np.float64], x0: NDArray[np.float64] | None, x_max: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(slope, offset) with k sqrt(x) <= slope x + offset on [0, x_max], elementwise (see ``_stages``)."""
    chord = k / np.sqrt(x_max)[:, None]
    if x0 is None:
        return chord, np.zeros_like(k)
    root = np.sqrt(x0)[:, None]
    upper = k > 0.0
    return np.where(upper, k / (2.0 * root), chord), np.where(upper, 0.5 * k * root, 0.0)


def _share(torque: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64]) -> NDArray[np.float64]:
    """torque over the bound on its side (lower < 0 < upper): 1 at the bound."""
    return np.where(torque >= 0.0, torque / upper, torque / lower)
