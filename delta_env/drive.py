"""The drive: its limits (motor and gearbox as seen at the joint), and its current loop as a 1 kHz controller sees it.

**Limits** (:class:`DriveLimits`, docs/design.md section 4). A servo drive delivers its peak torque up to a
corner speed; above it the supply voltage, minus the motor's back-EMF, limits the current it can push *with*
the motion, so the torque available in the motoring quadrants falls linearly to zero at the maximum speed.
Torque *against* the motion (braking) is limited by the peak current only. Continuously the motor may deliver
its rated torque: the RMS torque over a window longer than a work cycle must stay below it (thermal limit).

**Current loop.** A first-order lag under a zero-order hold.

The plant's actuator (``dyntype="filterexact"``) integrates T dtau/dt = u - tau exactly over each physics
step h: tau_{j+1} = a tau_j + (1 - a) u_j with a = exp(-h / T), and the force that acts during step j is
tau_j, the state before the update. A command u_k held over the n = period / h steps of a control period
therefore gives, at the control instants t_k = k * period,

    tau_{k+1} = p tau_k + (1 - p) u_k,    p = a^n = exp(-period / T),

which depends on the period only. Its exact inverse is u_k = (tau*_{k+1} - p tau_k) / (1 - p): the command
that brings the drive's output to tau*_{k+1} at the next control instant. Inside the period the output
is the exponential between the two instants, tau(t_k + j h) = a^j tau_k + (1 - a^j) u_k.

**Which torque to aim at** (:meth:`SampledLag.hold_lead`, docs/design.md section 6). MuJoCo's semi-implicit step
integrates the force of each physics step, so a motion x(t) is reproduced when the force of step j is the
torque x wants at that step's start t_k + j h (positions on x, velocities half a step behind). One command per
period cannot place n forces; it can give them the right mean, which is what the velocity at the end of the
period depends on. For a wanted torque that varies linearly over the period, the targets tau*_{k+1} =
tau_wanted(t_k + L) do that when

    L = period (1 - w) + (n - 1) h / 2,    w = (1/n) sum_{j<n} (1 - a^j) / (1 - p),

w being the mean share of the step tau_{k+1} - tau_k that the output has made at the physics steps (w = 1 for
a direct torque source, whose command acts at once: L = (period - h) / 2). Aiming at t_{k+1} instead (L =
period) applies the torque (n + 1) h / 2 early on a direct drive, 0.75 ms at 1 kHz over two 0.5 ms steps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env.geometry import TORQUE_LIMIT
from delta_env.sensors import CONTROL_PERIOD
from delta_env.validation import require_in, require_positive

MAX_TIME_CONSTANT = 0.1
"""Largest lag time constant (s) accepted, as for the plant's ``actuator_lag``."""

RPM = 2.0 * math.pi / 60.0
"""One revolution per minute in rad/s."""

MAX_PEAK_TORQUE = 1.0e4
"""Largest joint peak torque (N m) accepted: 25x the default drive."""

MAX_JOINT_SPEED = 1.0e3
"""Largest joint speed limit (rad/s) accepted."""


@dataclass(frozen=True)
class ServoMotor:
    """A servo motor's data-sheet values, on its own shaft (before the gearbox).

    Attributes:
        peak_torque: Peak (intermittent) torque (N m), available up to ``corner_speed``.
        rated_torque: Rated continuous torque (N m): the thermal (RMS) limit.
        corner_speed: Speed (rad/s) up to which the peak torque is available.
        max_speed: Maximum speed (rad/s), where the motoring torque has fallen to zero.
        rotor_inertia: Rotor moment of inertia (kg m^2); 0 where the data sheet's value is not used.
    """

    peak_torque: float
    rated_torque: float
    corner_speed: float
    max_speed: float
    rotor_inertia: float = 0.0

    def __post_init__(self) -> None:
        require_positive("peak_torque", self.peak_torque, "N m")
        require_in("rated_torque", self.rated_torque, 0.0, self.peak_torque, unit="N m", low_open=True)
        require_positive("corner_speed", self.corner_speed, "rad/s")
        require_in("max_speed", self.max_speed, self.corner_speed, unit="rad/s", low_open=True)
        require_in("rotor_inertia", self.rotor_inertia, 0.0, 1.0, unit="kg m^2")


REPRESENTATIVE_MOTOR = ServoMotor(peak_torque=20.0, rated_torque=6.4, corner_speed=3000.0 * RPM, max_speed=6000.0 * RPM)
"""A 2 kW class permanent-magnet AC servo on a 400 V drive (docs/design.md section 4): rated 6.4 N m at
3000 rpm, peak about 3x rated up to 3000 rpm, 6000 rpm maximum."""

REPRESENTATIVE_GEAR_RATIO = 21.0
"""Reduction of a one-stage precision planetary gearbox matched to that motor (dimensionless)."""

REPRESENTATIVE_GEAR_EFFICIENCY = 0.95
"""Torque efficiency of a one-stage planetary gearbox (dimensionless)."""

DEFAULT_THERMAL_WINDOW = 1.0
"""Window (s) of the thermal RMS torque: longer than one work cycle of the tasks (0.4-0.8 s), much shorter than
a motor winding's thermal time constant (minutes), so a cycle that stays under it is safe to repeat."""


@dataclass(frozen=True)
class DriveLimits:
    """The torque-speed envelope and thermal limit of each joint's drive (motor and gearbox, at the joint).

    The defaults are :data:`REPRESENTATIVE_MOTOR` behind :data:`REPRESENTATIVE_GEAR_RATIO` at
    :data:`REPRESENTATIVE_GEAR_EFFICIENCY`, rounded (399 N m peak, 128 N m rated, 15 and 30 rad/s):
    ``DriveLimits.of(REPRESENTATIVE_MOTOR, REPRESENTATIVE_GEAR_RATIO, REPRESENTATIVE_GEAR_EFFICIENCY)`` is the
    unrounded drive.

    Attributes:
        peak_torque: Peak torque at the joint (N m): the command is clipped to it at any speed.
        rated_torque: Rated continuous torque at the joint (N m): the RMS torque over ``thermal_window`` may
            not exceed it.
        corner_speed: Joint speed (rad/s) up to which the peak torque is available in the motoring quadrants.
        max_speed: Maximum joint speed (rad/s), where the motoring torque has fallen to zero.
        thermal_window: Window (s) of the thermal RMS torque.
    """

    peak_torque: float = TORQUE_LIMIT
    rated_torque: float = 128.0
    corner_speed: float = 15.0
    max_speed: float = 30.0
    thermal_window: float = DEFAULT_THERMAL_WINDOW

    def __post_init__(self) -> None:
        require_in("peak_torque", self.peak_torque, 0.0, MAX_PEAK_TORQUE, unit="N m", low_open=True)
        require_in("rated_torque", self.rated_torque, 0.0, self.peak_torque, unit="N m", low_open=True)
        require_in("corner_speed", self.corner_speed, 0.0, MAX_JOINT_SPEED, unit="rad/s", low_open=True)
        require_in("max_speed", self.max_speed, self.corner_speed, MAX_JOINT_SPEED, unit="rad/s", low_open=True)
        require_in("thermal_window", self.thermal_window, 0.01, 3600.0, unit="s")

    @classmethod
    def of(cls, motor: ServoMotor, gear_ratio: float, efficiency: float = 1.0, **kwargs: float) -> DriveLimits:
        """The joint-side limits of ``motor`` behind a gearbox of ``gear_ratio`` (> 0) and ``efficiency`` (0, 1]."""
        require_positive("gear_ratio", gear_ratio)
        require_in("efficiency", efficiency, 0.0, 1.0, low_open=True)
        torque = gear_ratio * efficiency
        return cls(
            peak_torque=motor.peak_torque * torque,
            rated_torque=motor.rated_torque * torque,
            corner_speed=motor.corner_speed / gear_ratio,
            max_speed=motor.max_speed / gear_ratio,
            **kwargs,
        )

    def motoring_limit(self, speed: ArrayLike) -> NDArray[np.float64]:
        """Torque (N m, >= 0) available *with* the motion at joint ``speed`` (rad/s, either sign), elementwise.

        The peak torque up to the corner speed, then falling linearly to 0 at the maximum speed (and 0 beyond).
        """
        magnitude = np.abs(np.asarray(speed, dtype=float))
        falling = self.peak_torque * (self.max_speed - magnitude) / (self.max_speed - self.corner_speed)
        return np.clip(falling, 0.0, self.peak_torque)

    def torque_bounds(self, speed: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lower, upper) torque bounds (N m) at joint ``speed`` (rad/s), elementwise.

        With the motion (the sign of the speed) the motoring limit applies; against it, the peak torque. At
        rest both directions have the peak torque.
        """
        speed = np.asarray(speed, dtype=float)
        motoring = self.motoring_limit(speed)
        upper = np.where(speed > 0.0, motoring, self.peak_torque)
        lower = np.where(speed < 0.0, -motoring, -self.peak_torque)
        return lower, upper


def clip_to_envelope(command: float, speed: float, peak: float, max_speed: float, span: float) -> tuple[float, float]:
    """``command`` (N m) clipped to the drive's bound in its direction at joint ``speed`` (rad/s), and the margin
    (N m): that bound minus |command|, negative when clipped. A zero command counts as motoring.

    The scalar form of :meth:`DriveLimits.torque_bounds`, for the env's 1 kHz step; ``span`` is
    max_speed - corner_speed.
    """
    # With the motion (or at rest): the motoring limit, the peak up to the corner speed; against it: the peak.
    bound = min(peak, max(0.0, peak * (max_speed - abs(speed)) / span)) if command * speed >= 0.0 else peak
    margin = bound - abs(command)
    if margin < 0.0:
        command = bound if command > 0.0 else -bound
    return command, margin


class SampledLag:
    """The first-order drive lag sampled at the control instants, per joint, and its exact inverse.

    The object keeps the drive output it predicts at the current control instant, so :meth:`command`
    can be called once per period with the output wanted at the next one.

    Args:
        time_constant: Lag T (s) of each joint, a scalar or shape (3,), each in [0, 0.1]; 0 is a direct
            torque source (the command acts at once).
        period: Control period (s) over which each command is held, in (0, 0.1].
    """

    def __init__(self, time_constant: ArrayLike, period: float = CONTROL_PERIOD) -> None:
        time_constant = np.broadcast_to(np.asarray(time_constant, dtype=float), (3,)).copy()
        if not np.all(np.isfinite(time_constant) & (time_constant >= 0.0) & (time_constant <= MAX_TIME_CONSTANT)):
            raise ValueError(f"time_constant must lie in [0, {MAX_TIME_CONSTANT}] s, got {time_constant.tolist()}")
        if not (math.isfinite(period) and 0.0 < period <= 0.1):
            raise ValueError(f"period must lie in (0, 0.1] s, got {period}")
        self.time_constant = time_constant
        self.period = float(period)
        with np.errstate(divide="ignore"):
            self.pole = np.where(time_constant > 0.0, np.exp(-self.period / np.maximum(time_constant, 1e-300)), 0.0)
        self._gain = 1.0 / (1.0 - self.pole)
        self.output = np.zeros(3)

    def reset(self, output: ArrayLike = 0.0) -> None:
        """Set the drive output (N m) at the current instant: 0 after the plant's reset."""
        self.output = np.broadcast_to(np.asarray(output, dtype=float), (3,)).copy()

    def command(self, target: ArrayLike) -> NDArray[np.float64]:
        """The command (N m, shape (3,)) whose lagged output equals ``target`` at the next control instant.

        Advances the predicted output to ``target``, so the next call continues from there.
        """
        target = np.asarray(target, dtype=float)
        command = (target - self.pole * self.output) * self._gain
        self.output = target.copy()
        return command

    def hold_lead(self, timestep: float) -> NDArray[np.float64]:
        """How far past the current control instant (s, per joint, shape (3,)) to take the torque aimed at for
        the next instant, on a plant whose physics step is ``timestep`` (s): L of the module docstring.

        Raises:
            ValueError: if ``timestep`` does not divide the period.
        """
        if not (math.isfinite(timestep) and 0.0 < timestep <= self.period):
            raise ValueError(f"timestep must lie in (0, {self.period}] s, got {timestep}")
        n_steps = round(self.period / timestep)
        if not math.isclose(n_steps * timestep, self.period):
            raise ValueError(f"timestep must divide the period {self.period} s, got {timestep}")
        lagging = self.time_constant > 0.0
        with np.errstate(divide="ignore"):
            step_pole = np.where(lagging, np.exp(-timestep / np.where(lagging, self.time_constant, 1.0)), 0.0)
        # the output's share of the step tau_{k+1} - tau_k at each physics step; all of it at once without a lag
        shares = [np.where(lagging, (1.0 - step_pole**j) * self._gain, 1.0) for j in range(n_steps)]
        mean_share = np.mean(shares, axis=0)
        return self.period * (1.0 - mean_share) + 0.5 * (n_steps - 1) * timestep

    def advance(self, command: ArrayLike) -> NDArray[np.float64]:
        """Hold ``command`` (N m) over one period; returns the drive output at the next instant."""
        self.output = self.pole * self.output + (1.0 - self.pole) * np.asarray(command, dtype=float)
        return self.output.copy()


class DriveMonitor:
    """The drive's limits as the env enforces and reports them at each control step (docs/design.md section 5):
    the command clipped to the torque-speed envelope at the joint speeds before the physics, and after it the
    speed and the thermal RMS torque over the last window against their limits.

    Scalar math on three joints: it runs in the env's 1 kHz step.

    Args:
        limits: The drive.
        period: Control period (s): one sample of the thermal window per step.
    """

    def __init__(self, limits: DriveLimits, period: float) -> None:
        self.limits = limits
        self._envelope = (
            limits.peak_torque,
            limits.corner_speed,
            limits.max_speed,
            limits.max_speed - limits.corner_speed,
        )
        self._reported_limits = (limits.max_speed, limits.rated_torque)
        self.window = max(1, round(limits.thermal_window / period))
        """Samples (control steps) of the thermal window."""
        # A ring buffer of the squared output torques of the last window and their running sums.
        self._squares: list[tuple[float, float, float]] = []
        self._sums = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        """Empty the thermal window (at the start of an episode)."""
        self._squares = [(0.0, 0.0, 0.0)] * self.window
        self._sums = (0.0, 0.0, 0.0)

    def clip(
        self, torque: NDArray[np.float64], speeds: tuple[float, float, float]
    ) -> tuple[NDArray[np.float64], tuple[float, float, float], bool]:
        """``torque`` (N m, shape (3,), finite) within the envelope at the joint ``speeds`` (rad/s): the torque the
        drive applies (``torque`` itself when nothing is clipped), each joint's margin (N m: the bound in the
        command's direction minus its magnitude, negative where clipped, :func:`clip_to_envelope`) and whether any
        joint was clipped."""
        peak, corner, max_speed, span = self._envelope
        t0, t1, t2 = torque.tolist()
        w0, w1, w2 = speeds
        if abs(w0) <= corner and abs(w1) <= corner and abs(w2) <= corner:  # the peak both ways: the usual case
            margins = (peak - abs(t0), peak - abs(t1), peak - abs(t2))
            saturated = min(margins) < 0.0
            if saturated:
                torque = np.clip(torque, -peak, peak)
            return torque, margins, saturated
        t0, m0 = clip_to_envelope(t0, w0, peak, max_speed, span)
        t1, m1 = clip_to_envelope(t1, w1, peak, max_speed, span)
        t2, m2 = clip_to_envelope(t2, w2, peak, max_speed, span)
        saturated = min(m0, m1, m2) < 0.0
        if saturated:
            torque = np.array([t0, t1, t2])
        return torque, (m0, m1, m2), saturated

    def report(
        self, step: int, speeds: tuple[float, float, float], applied: Sequence[float]
    ) -> tuple[NDArray[np.float64], bool, NDArray[np.float64], NDArray[np.float64], bool]:
        """The speed and thermal limits after control step ``step`` (>= 1 since the reset), from the joint ``speeds``
        (rad/s) and the drive's three output torques ``applied`` (N m) after it: the ``info`` entries
        ``speed_margin`` (rad/s), ``speed_exceeded``, ``thermal_rms`` (N m, over the last window, or since the reset
        while shorter), ``thermal_margin`` (N m) and ``thermal_exceeded`` (only once a full window has elapsed), in
        that order."""
        max_speed, rated = self._reported_limits
        w0, w1, w2 = speeds
        v0, v1, v2 = abs(w0), abs(w1), abs(w2)
        a0, a1, a2 = applied
        window = self.window
        squares, index = self._squares, step % window
        o0, o1, o2 = squares[index]
        squares[index] = q0, q1, q2 = a0 * a0, a1 * a1, a2 * a2
        s0, s1, s2 = self._sums
        self._sums = s0, s1, s2 = s0 + q0 - o0, s1 + q1 - o1, s2 + q2 - o2
        full = step >= window  # one sample per step since the reset
        scale = 1.0 / window if full else 1.0 / step
        # the running sums may drift below 0 by round-off
        r0 = math.sqrt((0.0 if s0 < 0.0 else s0) * scale)
        r1 = math.sqrt((0.0 if s1 < 0.0 else s1) * scale)
        r2 = math.sqrt((0.0 if s2 < 0.0 else s2) * scale)
        return (
            np.array((max_speed - v0, max_speed - v1, max_speed - v2)),
            max(v0, v1, v2) > max_speed,
            np.array((r0, r1, r2)),
            np.array((rated - r0, rated - r1, rated - r2)),
            full and max(r0, r1, r2) > rated,
        )
