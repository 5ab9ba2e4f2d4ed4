"""The servo layer: each joint's position loop with integral action and friction compensation at rest (docs/design.md
section 6, "The servo layer").

A servo drive closes its position loop around the feedforward: per joint

    tau_fb = kp e + kd de/dt + ki integral(e) + fb sat(e / e_f) [reference at rest]

with e = theta_ref - theta (encoder), and de/dt the reference's rate measured as the joint rate is (its mean over the
encoder's backward difference, :class:`~controllers.drive.MeasuredReferenceRate`) minus the measured rate. The gains
come from the identified model and drive lag (:func:`servo_gains`): a triple closed-loop pole at the bandwidth w0 on
the joint's identified inertia J, kd = 3 J w0, kp = 3 J w0^2, ki = J w0^3, with w0 the largest that keeps the stated
phase margin through the loop's delay (the drive lag, half a sample of zero-order hold and half a sample of the
backward-difference rate). The integral term is clamped (anti-windup: |ki integral(e)| <= ``integral_limit``) so that
a blocked joint cannot wind it up. While the reference is at rest the model's Coulomb term fc sign(thd_ref) is zero,
and static friction would hold any error with |kp e| below the breakaway torque fb (Coulomb plus the Stribeck excess
met on the way out of rest); the servo then pushes with the identified breakaway torque in the direction of the
error, saturating at ``friction_width`` (one encoder step), which closes the stick band.

The gains are placed on one inertia, the arm's empty at home; the joint's inertia grows with the pose (1.4 times at
the conveyors) and the payload (fourfold with 4 kg there), which slows the loop and takes phase margin. A scheduled
servo (:meth:`JointServo.schedule`) scales kp, kd and ki with the inertia it is given, which keeps the triple pole and
the margin (J cancels in the open loop): the model rows give it their model's inertia at the reference's pose, without
payload, every :data:`SCHEDULE_PERIOD` (why without: docs/design.md section 6). On compliant drives (a
:class:`ResonanceNotch`) they give it the model's inertia matrix instead, and the gains become matrices: behind the
notch the loop has no margin left for the arms' coupled directions, whose inertia the diagonal overstates.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from controllers.base import Observation
from controllers.compliance import DriveCompliance
from controllers.drive import MeasuredReferenceRate
from controllers.dynamics import DeltaDynamics
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, encoder_resolution
from delta_env.validation import require_in, require_joint_vector

HOME = (0.0, 0.0, 0.0)
"""The pose (rad) of the gains' inertia: home, arms horizontal."""

DEFAULT_PHASE_MARGIN = math.radians(35.0)
"""Phase margin (rad) the servo's bandwidth keeps through the loop's delay: the best of 35, 40 and 50 degrees on the
standard cycle at 3 and 6 g (docs/measurements.md). A lag twice the identified one leaves 17 degrees; a payload,
which the schedule leaves out, about 27 with 4 kg at the conveyors (docs/design.md section 6)."""

NOTCHED_PHASE_MARGIN = math.radians(16.0)
"""Phase margin (rad) a notched servo's bandwidth keeps through the delay and the notch's lag together
(:func:`servo_gains` with a notch): the one at which the slowest closed-loop pole of the one-joint notched loop (the
preset's gearhead, arm sides 0.195 to 1 kg m^2, the 1 ms lag) is fastest, |z| 0.953 against 0.975 for the bandwidth
placed on the delay alone and 0.969 with 35 degrees through both (docs/design.md section 6). The margin formula
counts the delay crudely (a pure delay of the lag plus a period), so the loop's true margin is larger."""

DEFAULT_INTEGRAL_LIMIT = 40.0
"""Largest integral torque (N m), a tenth of the representative drive's peak: the anti-windup clamp."""

SCHEDULE_PERIOD = 0.01
"""Time (s) between two updates of a scheduled servo's inertia: the pose changes little in it, and an update costs
four evaluations of the model (:func:`model_inertia`), too much for every 1 ms sample."""

DEFAULT_FRICTION_WIDTH = encoder_resolution(ENCODER_BITS)
"""Error (rad) at which the friction compensation at rest reaches the full breakaway torque: one encoder step (17 bit),
the smallest error the servo can see."""

BAND_RATE_CUTOFF = 35.0
"""Frequency (Hz) above which a servo on gearheads with backlash damps on the arm's rate (the load encoder's) instead
of the rotor's (:meth:`JointServo.band_rates`): a lone rotor bouncing between the band's flanks rings at 150 Hz and
more (the rotor on the gearhead's spring, slowed by the band), where the loop's delay turns the derivative term into
negative damping; the arm, two to four times the rotor's inertia behind the gap, hardly follows it. Of 10, 20, 30, 35,
40, 55 and 80 Hz, the one at which the 3-arcmin plant ran fastest (docs/measurements.md); below it the damping is the
rotor's, as the loop was designed."""

DEFAULT_NOTCH_QUALITY = 0.7
"""Quality factor Q of the notch on the servo torque at a compliant drive's mode (its -3 dB width is f0 / Q): of 0.5,
0.7 and 1, the one that a linear analysis of a compliant joint under the scheduled servo keeps stable with the
stiffness 10 % off or the damping halved, and with an arm side up to five times the one the notch is placed on (a
payload it does not know; docs/design.md section 6)."""


@dataclass(frozen=True)
class ServoGains:
    """Per-joint gains of :class:`JointServo`.

    Attributes:
        kp: Proportional gain per joint (N m/rad).
        ki: Integral gain per joint (N m/(rad s)).
        kd: Derivative gain per joint (N m s/rad).
        breakaway: Torque pushed at rest per joint (N m): the friction that starts the joint from rest, Coulomb plus
            the Stribeck excess; zero turns the compensation off.
        friction_width: Error (rad) at which the compensation at rest saturates.
        integral_limit: Largest |ki integral(e)| (N m).
        inertia: Joint inertia (kg m^2) per joint the gains are placed on (:func:`servo_gains`); None for gains that
            are not (then :meth:`JointServo.schedule` refuses them).
    """

    kp: tuple[float, float, float]
    ki: tuple[float, float, float]
    kd: tuple[float, float, float]
    breakaway: tuple[float, float, float] = (0.0, 0.0, 0.0)
    friction_width: float = DEFAULT_FRICTION_WIDTH
    integral_limit: float = DEFAULT_INTEGRAL_LIMIT
    inertia: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name, unit in (("kp", "N m/rad"), ("ki", "N m/(rad s)"), ("kd", "N m s/rad"), ("breakaway", "N m")):
            values = require_joint_vector(name, getattr(self, name), 0.0, unit=unit)
            object.__setattr__(self, name, tuple(float(v) for v in values))
        require_in("friction_width", self.friction_width, 0.0, unit="rad", low_open=True)
        require_in("integral_limit", self.integral_limit, 0.0, unit="N m")
        if self.inertia is not None:
            values = require_joint_vector("inertia", self.inertia, 0.0, unit="kg m^2", low_open=True)
            object.__setattr__(self, "inertia", tuple(float(v) for v in values))


@dataclass(frozen=True)
class ResonanceNotch:
    """A notch on the servo's torque at each joint's drive mode (docs/design.md section 6, "On a compliant
    joint"): what a servo drive does about a resonance its loop would otherwise drive.

    Each joint is taken as a two-mass drive, the rotor J_m coupled through the gearhead's stiffness k to the arm side
    J - J_m, with J the joint's inertia (rotor included, as the rigid model's is): the mode its motor-side loop sees
    rings at f = sqrt(k (1/J_m + 1/(J - J_m))) / (2 pi), which the notch follows as the servo's schedule moves J
    (with the payload, :meth:`JointServo.schedule`).

    Attributes:
        rotor_inertia: Reflected rotor inertia J_m per joint (kg m^2).
        stiffness: Gearhead stiffness k per joint (N m/rad).
        quality: The notch's quality factor Q (-3 dB width f0 / Q).
    """

    rotor_inertia: tuple[float, float, float]
    stiffness: tuple[float, float, float]
    quality: float = DEFAULT_NOTCH_QUALITY

    def __post_init__(self) -> None:
        inertia = require_joint_vector("rotor_inertia", self.rotor_inertia, 0.0, unit="kg m^2", low_open=True)
        stiffness = require_joint_vector("stiffness", self.stiffness, 0.0, unit="N m/rad", low_open=True)
        object.__setattr__(self, "rotor_inertia", tuple(float(v) for v in inertia))
        object.__setattr__(self, "stiffness", tuple(float(v) for v in stiffness))
        require_in("quality", self.quality, 0.0, 100.0, low_open=True)

    def frequency(self, inertia: ArrayLike, period: float = CONTROL_PERIOD) -> NDArray[np.float64]:
        """The notch's centre per joint (Hz), (3,), for the joints' inertia ``inertia`` (kg m^2, rotor included):
        the two-mass mode, at most :meth:`highest_frequency`."""
        rotor, stiffness = np.asarray(self.rotor_inertia), np.asarray(self.stiffness)
        arm = np.asarray(inertia, dtype=float) - rotor
        with np.errstate(divide="ignore"):
            omega = np.sqrt(stiffness * (1.0 / rotor + np.where(arm > 0.0, 1.0 / np.maximum(arm, 1e-300), np.inf)))
        return np.minimum(omega / (2.0 * math.pi), self.highest_frequency(period))

    def highest_frequency(self, period: float = CONTROL_PERIOD) -> float:
        """The highest centre (Hz) the notch takes when sampled every ``period`` (s): the one whose band, between its
        -3 dB edges f0 (sqrt(1 + 1 / (4 Q^2)) -+ 1 / (2 Q)), ends at the Nyquist rate (257 Hz at Q 0.7 and 1 kHz).
        Above it the band folds into the sampling's warp, and the notch's lag at the servo's crossover grows
        steeply instead of falling (docs/design.md section 6)."""
        half = 0.5 / self.quality
        return 0.5 / period / (math.sqrt(1.0 + half * half) + half)

    def coefficients(
        self, frequency: float, period: float = CONTROL_PERIOD
    ) -> tuple[float, float, float, float, float]:
        """(b0, b1, b2, a1, a2) of the digital notch at ``frequency`` (Hz) sampled every ``period`` (s), its -3 dB
        width ``frequency`` / Q: the bilinear transform of an analog notch prewarped so that both hold in the
        digital domain, as :func:`scipy.signal.iirnotch` designs it; unit gain at 0 and at the Nyquist rate.

        Raises:
            ValueError: for a centre above :meth:`highest_frequency`.
        """
        require_in("frequency", frequency, 0.0, self.highest_frequency(period), unit="Hz", low_open=True)
        angle = 2.0 * math.pi * frequency * period
        gain = 1.0 / (1.0 + math.tan(0.5 * angle / self.quality))
        cosine = math.cos(angle)
        return gain, -2.0 * gain * cosine, gain, -2.0 * gain * cosine, 2.0 * gain - 1.0

    def phase_lag(self, frequency: float, angular_frequency: float, period: float = CONTROL_PERIOD) -> float:
        """The phase lag (rad) of the digital notch centred at ``frequency`` (Hz) at ``angular_frequency`` (rad/s) below
        its centre: -arg H(e^{i w T}) of :meth:`coefficients`, positive below the centre."""
        b0, b1, b2, a1, a2 = self.coefficients(frequency, period)
        z = np.exp(-1j * angular_frequency * period)
        return float(-np.angle((b0 + b1 * z + b2 * z * z) / (1.0 + a1 * z + a2 * z * z)))


def notch_sample(coefficients: tuple[float, float, float, float, float], state: list[float], value: float) -> float:
    """One sample (N m) through a notch of :meth:`ResonanceNotch.coefficients`, its two delays ``state`` updated in
    place: the biquad in transposed direct form II, y = b0 x + z1, z1' = b1 x - a1 y + z2, z2' = b2 x - a2 y."""
    b0, b1, b2, a1, a2 = coefficients
    filtered = b0 * value + state[0]
    state[0] = b1 * value - a1 * filtered + state[1]
    state[1] = b2 * value - a2 * filtered
    return filtered


def loop_delay(drive_lag: float, period: float = CONTROL_PERIOD) -> float:
    """The position loop's effective delay (s): the drive's lag, half a period of zero-order hold and half a period
    of the encoder's backward-difference rate."""
    return drive_lag + period


def _crossover_ratio() -> float:
    """The triple-pole loop's gain crossover over its pole, w_c / w0 (the docstring of :func:`phase_margin`): with
    y = (w_c / w0)^2, |L| = 1 reads y^3 - 9 y^2 - 3 y - 1 = 0, whose one real root is positive."""
    roots = np.roots([1.0, -9.0, -3.0, -1.0])
    return math.sqrt(float(roots[np.argmin(np.abs(roots.imag))].real))


CROSSOVER_RATIO = _crossover_ratio()
"""Gain crossover of the triple-pole PID loop over its closed-loop pole, w_c / w0 (dimensionless, about 3.06): the
same for every bandwidth, since the pole-placement gains make |L(j w)| a function of w / w0 alone."""

UNDELAYED_PHASE_MARGIN = math.atan2(3.0 * CROSSOVER_RATIO, 1.0 - 3.0 * CROSSOVER_RATIO**2) - math.pi / 2
"""Phase margin (rad) of the triple-pole PID loop without delay (about 71 degrees); a delay takes w_c delay of it."""


def phase_margin(bandwidth: float, delay: float) -> float:
    """Phase margin (rad) of the triple-pole PID loop at closed-loop pole ``bandwidth`` (rad/s) with a pure delay.

    The open loop is L(s) = (kd s^2 + kp s + ki) / (J s^3) e^{-s delay}; with the pole-placement gains J cancels,
    L(s) = w0 (3 s^2 + 3 w0 s + w0^2) / s^3 e^{-s delay}. It crosses over at w_c = :data:`CROSSOVER_RATIO` w0, where
    the margin is :data:`UNDELAYED_PHASE_MARGIN` - w_c delay.
    """
    return UNDELAYED_PHASE_MARGIN - CROSSOVER_RATIO * bandwidth * delay


def servo_bandwidth(
    delay: float, margin: float = DEFAULT_PHASE_MARGIN, lag: Callable[[float], float] | None = None
) -> float:
    """The largest closed-loop pole w0 (rad/s) whose loop keeps phase margin ``margin`` (rad) through ``delay`` (s):
    :func:`phase_margin` solved for w0; with ``lag``, the phase (rad) a filter in the loop takes at an angular
    frequency (rad/s) too (a notch, :meth:`ResonanceNotch.phase_lag`): then the margin left at the crossover
    :data:`CROSSOVER_RATIO` w0, :data:`UNDELAYED_PHASE_MARGIN` - w_c delay - lag(w_c), is ``margin``.

    Raises:
        ValueError: for a delay not positive or a margin outside (0, :data:`UNDELAYED_PHASE_MARGIN`).
    """
    require_in("delay", delay, 0.0, unit="s", low_open=True)
    require_in("margin", margin, 0.0, UNDELAYED_PHASE_MARGIN, unit="rad", low_open=True, high_open=True)
    undelayed = (UNDELAYED_PHASE_MARGIN - margin) / (CROSSOVER_RATIO * delay)
    if lag is None:
        return undelayed

    def excess(bandwidth: float) -> float:
        crossover = CROSSOVER_RATIO * bandwidth
        return UNDELAYED_PHASE_MARGIN - crossover * delay - lag(crossover) - margin

    # the margin falls monotonically with w0 (delay and a notch's lag below its centre both grow), from the whole
    # excess at 0 to the filter's lag short at the delay's bandwidth
    return float(scipy.optimize.brentq(excess, 1e-6 * undelayed, undelayed, xtol=1e-9 * undelayed))


def joint_inertia(
    inverse_dynamics: Callable[..., NDArray[np.float64]], theta: ArrayLike = HOME, payload: float = 0.0
) -> NDArray[np.float64]:
    """The diagonal of a model's joint-space inertia (kg m^2), (3,), at rest at ``theta`` (rad) with ``payload`` (kg):
    tau(thdd = e_i) - tau(thdd = 0), column by column.

    Args:
        inverse_dynamics: ``inverse_dynamics(theta, theta_dot, theta_ddot, payload)`` -> joint torques (N m), (3,):
            :meth:`controllers.dynamics.DeltaDynamics.inverse_dynamics` or the plant's exact
            :meth:`delta_env.oracle.InverseDynamicsOracle.torques`.
        theta: The pose (rad); home (arms horizontal) by default.
        payload: Payload (kg).
    """
    theta = np.asarray(theta, dtype=float)
    zero = np.zeros(3)
    static = inverse_dynamics(theta, zero, zero, payload)
    return np.array([inverse_dynamics(theta, zero, np.eye(3)[i], payload)[i] - static[i] for i in range(3)])


def joint_inertia_matrix(
    inverse_dynamics: Callable[..., NDArray[np.float64]], theta: ArrayLike = HOME, payload: float = 0.0
) -> NDArray[np.float64]:
    """A model's joint-space inertia matrix (kg m^2), (3, 3), symmetrized, at rest at ``theta`` (rad) with
    ``payload`` (kg): column i is tau(thdd = e_i) - tau(thdd = 0) (arguments as :func:`joint_inertia`'s, whose values
    are its diagonal)."""
    theta = np.asarray(theta, dtype=float)
    zero = np.zeros(3)
    static = inverse_dynamics(theta, zero, zero, payload)
    columns = np.column_stack([inverse_dynamics(theta, zero, np.eye(3)[i], payload) - static for i in range(3)])
    return 0.5 * (columns + columns.T)


def _single_sample_dynamics(dynamics: DeltaDynamics) -> Callable[..., NDArray[np.float64]]:
    """``inverse_dynamics(theta, theta_dot, theta_ddot, payload)`` of the model ``dynamics`` by its single-sample path
    (:meth:`~controllers.dynamics.DeltaDynamics.torque_and_payload_regressor`)."""

    def inverse_dynamics(
        angles: ArrayLike, rates: ArrayLike, accelerations: ArrayLike, mass: float
    ) -> NDArray[np.float64]:
        tau0, phi = dynamics.torque_and_payload_regressor(angles, rates, accelerations)
        return tau0 + mass * phi

    return inverse_dynamics


def model_inertia(dynamics: DeltaDynamics, theta: ArrayLike, payload: float) -> NDArray[np.float64]:
    """:func:`joint_inertia` of the model ``dynamics`` at ``theta`` (rad) with ``payload`` (kg), from its single-sample
    path (:meth:`~controllers.dynamics.DeltaDynamics.torque_and_payload_regressor`): tens of microseconds, cheap
    enough every :data:`SCHEDULE_PERIOD`."""
    return joint_inertia(_single_sample_dynamics(dynamics), theta, payload)


def model_inertia_matrix(dynamics: DeltaDynamics, theta: ArrayLike, payload: float) -> NDArray[np.float64]:
    """:func:`joint_inertia_matrix` of the model ``dynamics`` at ``theta`` (rad) with ``payload`` (kg), by the same
    single-sample path as :func:`model_inertia`."""
    return joint_inertia_matrix(_single_sample_dynamics(dynamics), theta, payload)


def servo_gains(
    inertia: ArrayLike,
    breakaway: ArrayLike,
    drive_lag: ArrayLike,
    *,
    margin: float | None = None,
    period: float = CONTROL_PERIOD,
    friction_width: float = DEFAULT_FRICTION_WIDTH,
    integral_limit: float = DEFAULT_INTEGRAL_LIMIT,
    notch: ResonanceNotch | None = None,
) -> ServoGains:
    """Pole-placement gains: a triple pole at :func:`servo_bandwidth` of each joint's delay on its inertia; with a
    notch in the loop, the margin kept through its lag too (centred at the drive mode of ``inertia``; docs/design.md
    section 6, "The notch's lag in the margin").

    Args:
        inertia: Each joint's inertia (kg m^2), (3,): :func:`joint_inertia` of the identified model, empty at home.
        breakaway: Friction torque pushed at rest per joint (N m), (3,) or a scalar: :attr:`ServoGains.breakaway`.
        drive_lag: Drive lag per joint (s), (3,) or a scalar.
        margin: Phase margin (rad); None: :data:`DEFAULT_PHASE_MARGIN`, or :data:`NOTCHED_PHASE_MARGIN` with a notch.
        period: Control period (s).
        friction_width: :attr:`ServoGains.friction_width` (rad).
        integral_limit: :attr:`ServoGains.integral_limit` (N m).
        notch: The notch of compliant drives the servo will run (:class:`ResonanceNotch`); None: none.
    """
    inertia = require_joint_vector("inertia", inertia, 0.0, unit="kg m^2", low_open=True)
    lag = np.broadcast_to(np.asarray(drive_lag, dtype=float), (3,))
    if margin is None:
        margin = DEFAULT_PHASE_MARGIN if notch is None else NOTCHED_PHASE_MARGIN
    if notch is None:
        w0 = np.array([servo_bandwidth(loop_delay(float(t), period), margin) for t in lag])
    else:
        centres = notch.frequency(inertia, period)
        w0 = np.array(
            [
                servo_bandwidth(
                    loop_delay(float(t), period),
                    margin,
                    lambda w, centre=float(centre): notch.phase_lag(centre, w, period),
                )
                for t, centre in zip(lag, centres, strict=True)
            ]
        )
    return ServoGains(
        kp=tuple(3.0 * inertia * w0**2),
        ki=tuple(inertia * w0**3),
        kd=tuple(3.0 * inertia * w0),
        breakaway=tuple(float(c) for c in np.broadcast_to(np.asarray(breakaway, dtype=float), (3,))),
        friction_width=friction_width,
        integral_limit=integral_limit,
        inertia=tuple(float(v) for v in inertia),
    )


def compliant_servo(
    inertia: ArrayLike,
    breakaway: ArrayLike,
    drive_lag: ArrayLike,
    compliance: DriveCompliance,
    *,
    friction_width: float = DEFAULT_FRICTION_WIDTH,
    rate_window: float = CONTROL_PERIOD,
    period: float = CONTROL_PERIOD,
    rotor_friction: ArrayLike = 0.0,
) -> JointServo:
    """The servo layer on compliant drives (docs/design.md section 6): a notch at each joint's drive mode, gains
    placed on each joint's ``inertia`` (kg m^2, rotor included) with the margin kept through the drive lag
    ``drive_lag`` (s) and the notch's lag, the ``breakaway`` torque (N m) pushed at rest, the gains on the rotor
    alone inside the backlash's band, and at rest the torque held on the loaded flank against the rotors' Coulomb
    ``rotor_friction`` (N m). The model rows build it on the identified ``compliance``, the bound on the plant's
    own; ``rate_window`` (s) and ``friction_width`` (rad) as :class:`JointServo` and :class:`ServoGains`."""
    notch = ResonanceNotch(compliance.rotor_inertia, compliance.stiffness)
    gains = servo_gains(inertia, breakaway, drive_lag, period=period, friction_width=friction_width, notch=notch)
    return JointServo(
        gains,
        period,
        rate_window=rate_window,
        notch=notch,
        backlash=compliance.resolved_backlash,
        rotor_friction=rotor_friction,
    )


class JointServo:
    """Each joint's position servo: PID with a clamped integral, and the breakaway torque pushed at rest.

    Args:
        gains: :class:`ServoGains`.
        period: Control period (s), the integral's step.
        rate_window: The window (s) whose mean rate the observed joint rate is
            (:func:`delta_env.sensors.rate_window`: one period with an encoder).
        notch: A notch on the torque at each joint's drive mode (:class:`ResonanceNotch`), for a compliant drive;
            None: none (a rigid drive). It needs gains placed on an inertia.
        backlash: The gearheads' backlash b per joint (rad), (3,), for compliant drives with a load encoder (the
            observation's ``load_angles``): while a joint's measured twist (motor encoder minus load encoder) lies
            within b / 2 of zero its rotor is alone, and the gains are placed on the rotor's inertia
            (:meth:`band_inertia`; docs/design.md section 6, "Backlash"), and outside it the derivative term takes the
            arm's rate above :data:`BAND_RATE_CUTOFF` (:meth:`band_rates`); at rest the torque is held where it would
            pull the rotor off its loaded flank (:meth:`flank_floor`). None or zeros: none. It needs the notch
            (whose rotor inertia and stiffness it takes).
        rotor_friction: The rotors' Coulomb friction per joint (N m), (3,) or a scalar: what a sliding rotor meets
            in :meth:`flank_floor`.
    """

    def __init__(
        self,
        gains: ServoGains,
        period: float = CONTROL_PERIOD,
        rate_window: float = CONTROL_PERIOD,
        notch: ResonanceNotch | None = None,
        backlash: ArrayLike | None = None,
        rotor_friction: ArrayLike = 0.0,
    ) -> None:
        self.gains = gains
        self.period = require_in("period", period, 0.0, unit="s", low_open=True)
        if notch is not None and gains.inertia is None:
            raise ValueError("a notch at the drive mode needs servo gains placed on an inertia (ServoGains.inertia)")
        self.notch = notch
        self.half_band: NDArray[np.float64] | None = None
        if backlash is not None and np.any(np.asarray(backlash, dtype=float) > 0.0):
            if notch is None:
                raise ValueError("the servo's backlash needs the notch of the compliant drives (its rotor inertia)")
            self.half_band = 0.5 * require_joint_vector("backlash", backlash, 0.0, unit="rad")
        self.rotor_friction = require_joint_vector(
            "rotor_friction", np.broadcast_to(np.asarray(rotor_friction, dtype=float), (3,)), 0.0, unit="N m"
        )
        # the rotor's rate (rad/s) above which it slides: two encoder steps over the rate window
        self._sliding_rate = 2.0 * gains.friction_width / rate_window
        self._notch_state = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]  # the biquad's two delays per joint (N m)
        self._notch_coefficients: list[tuple[float, float, float, float, float]] = []
        self.reference_rate = MeasuredReferenceRate(rate_window, period)
        self._integral = [0.0, 0.0, 0.0]  # ki * integral(e) per joint (N m)
        self._error = [0.0, 0.0, 0.0]  # the last sample's e and de/dt per joint (rad, rad/s), for a bumpless schedule
        self._rate_error = [0.0, 0.0, 0.0]
        self._schedule_samples = max(1, round(SCHEDULE_PERIOD / self.period))
        self._deflections: list[list[float]] = []  # the last two samples' rotor deflections (rad), newest last
        self._load_angles: list[float] | None = None  # the last sample's load encoder angles (rad), for band_rates
        self._twist_rate_error = [0.0, 0.0, 0.0]  # the low-passed twist rate error of band_rates (rad/s)
        self._samples = 0  # samples since the reset, for follow_inertia
        self._unscheduled()

    @property
    def scheduled(self) -> bool:
        """Whether the gains are placed on an inertia, which :meth:`schedule` can follow."""
        return self.gains.inertia is not None

    @property
    def current_gains(self) -> tuple[list[float], list[float], list[float]]:
        """(kp, ki, kd) per joint in use: the gains' own, or scaled by the last :meth:`schedule` (placed on a
        matrix: the diagonals of the gain matrices)."""
        if self._gain_matrices is not None:
            kp, ki, kd = self._gain_matrices
            return list(np.diag(kp)), list(np.diag(ki)), list(np.diag(kd))
        return list(self._kp), list(self._ki), list(self._kd)

    def schedule(self, inertia: ArrayLike, loaded_inertia: ArrayLike | None = None) -> None:
        """Place the gains on each joint's ``inertia`` (kg m^2) now: kp, kd and ki scaled by it over the inertia they
        were placed on, which keeps the closed loop's triple pole and phase margin. Bumpless: the integral term,
        stored as torque, takes up the change of kp e + kd de/dt at the last sample's errors, so the command does not
        step (a step would shake the arm, and the payload estimate with it). The notch, if any, is centred on the
        mode of ``loaded_inertia`` (the joints' inertia with the payload, kg m^2), or of ``inertia`` if None.

        ``inertia`` is the joints' inertias, (3,), or the joint-space inertia matrix M, (3, 3), symmetric positive
        definite: then the gains become matrices, K = S M S with S = diag(sqrt(k_j / J_j)) (each joint's gain per
        unit of the inertia it was placed on), which give every direction of the coupled arm, not only each joint
        alone, the triple pole (docs/design.md section 6, "Gains on the inertia matrix").

        Raises:
            ValueError: for gains not placed on an inertia (:attr:`ServoGains.inertia` None).
        """
        if self.gains.inertia is None:
            raise ValueError("these servo gains are not placed on an inertia (ServoGains.inertia is None)")
        gains, limit = self.gains, self.gains.integral_limit
        matrix = np.asarray(inertia, dtype=float)
        self._inertia_matrix = matrix if matrix.ndim == 2 else np.diag(matrix)
        if np.ndim(inertia) == 2:
            self._schedule_matrix(np.asarray(inertia, dtype=float))
            diagonal = np.diag(np.asarray(inertia, dtype=float))
            self._tune_notch(diagonal if loaded_inertia is None else loaded_inertia)
            return
        for joint in range(3):
            scale = float(inertia[joint]) / gains.inertia[joint]
            kp, kd = gains.kp[joint] * scale, gains.kd[joint] * scale
            change = (kp - self._kp[joint]) * self._error[joint] + (kd - self._kd[joint]) * self._rate_error[joint]
            self._integral[joint] = min(max(self._integral[joint] - change, -limit), limit)
            self._kp[joint], self._kd[joint], self._ki[joint] = kp, kd, gains.ki[joint] * scale
        self._tune_notch(inertia if loaded_inertia is None else loaded_inertia)

    def _schedule_matrix(self, inertia: NDArray[np.float64]) -> None:
        """Gain matrices on the joint-space inertia matrix ``inertia`` (kg m^2), (3, 3), bumpless (:meth:`schedule`)."""
        limit = self.gains.integral_limit
        kp, ki, kd = self._gains_on(inertia)
        old_kp, _, old_kd = (
            self._gain_matrices
            if self._gain_matrices is not None
            else (np.diag(self._kp), np.diag(self._ki), np.diag(self._kd))
        )
        change = (kp - old_kp) @ np.array(self._error) + (kd - old_kd) @ np.array(self._rate_error)
        self._integral = np.clip(np.array(self._integral) - change, -limit, limit).tolist()
        self._gain_matrices = (kp, ki, kd)

    def follow_inertia(
        self, inertia: Callable[[], ArrayLike], loaded_inertia: Callable[[], ArrayLike] | None = None
    ) -> None:
        """Call once per sample before :meth:`feedback`: every :data:`SCHEDULE_PERIOD` from the reset on,
        :meth:`schedule` the gains on ``inertia()`` (kg m^2, per joint) and the notch on ``loaded_inertia()`` (with
        the payload; None: ``inertia()``), which are evaluated only then."""
        if self._samples % self._schedule_samples == 0:
            self.schedule(inertia(), None if loaded_inertia is None else loaded_inertia())
        self._samples += 1

    def _unscheduled(self) -> None:
        self._kp, self._ki, self._kd = list(self.gains.kp), list(self.gains.ki), list(self.gains.kd)
        self._gain_matrices: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None
        self._inertia_matrix = None if self.gains.inertia is None else np.diag(self.gains.inertia)
        if self.gains.inertia is not None:
            self._tune_notch(self.gains.inertia)

    def _tune_notch(self, inertia: ArrayLike) -> None:
        """Centre the notch (if any) on the drive modes of the joints' ``inertia`` (kg m^2); its delays carry over."""
        if self.notch is not None:
            self._notch_frequency = self.notch.frequency(inertia, self.period)
            self._notch_coefficients = [self.notch.coefficients(float(f), self.period) for f in self._notch_frequency]

    @property
    def notch_frequency(self) -> NDArray[np.float64] | None:
        """The notch's centre per joint (Hz) in use, (3,); None without a notch."""
        return None if self.notch is None else self._notch_frequency.copy()

    @property
    def integral(self) -> NDArray[np.float64]:
        """The integral term ki integral(e) (N m), (3,)."""
        return np.array(self._integral)

    def reset(self) -> None:
        """Zero the integral, forget the last reference and return to the gains' own inertia."""
        self._integral = [0.0, 0.0, 0.0]
        self._error = [0.0, 0.0, 0.0]
        self._rate_error = [0.0, 0.0, 0.0]
        self._samples = 0
        self._notch_state = [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
        self._deflections = []
        self._load_angles = None
        self._twist_rate_error = [0.0, 0.0, 0.0]
        self.reference_rate.reset()
        self._unscheduled()

    def feedback(self, observation: Observation, deflection: ArrayLike | None = None) -> NDArray[np.float64]:
        """The servo torque (N m), (3,); on gearheads with backlash, held at rest on the loaded flank
        (:meth:`flank_floor`).

        Args:
            observation: The step's observation: the reference and the encoders' angles and rates.
            deflection: On compliant drives, the gearheads' deflection phi - theta (rad), (3,), that the arms'
                reference asks of the rotors the encoders read (:func:`controllers.compliance.static_deflection`):
                the servo holds the rotors at the reference plus it, its rate taken over the measured rate's window
                (docs/design.md section 6, "The deflection feedforward"). None: the encoders read the arms.
        """
        if self.half_band is None or deflection is None:
            return self._loop_torque(observation, deflection)
        integral = list(self._integral)
        torque = self._loop_torque(observation, deflection)
        return self.flank_floor(observation, np.asarray(deflection, dtype=float), torque, integral)

    def _loop_torque(self, observation: Observation, deflection: ArrayLike | None) -> NDArray[np.float64]:
        """:meth:`feedback`'s loop: PID, the push at rest, the band's gains and rates, the notch."""
        gains, period, kp, ki, kd = self.gains, self.period, self._kp, self._ki, self._kd
        limit, width = gains.integral_limit, gains.friction_width
        reference, angles = observation["reference_angles"].tolist(), observation["joint_angles"].tolist()
        reference_rates, rates = observation["reference_velocities"].tolist(), observation["joint_velocities"].tolist()
        # Like rates: the measured rate is a mean over the window, so the reference's is taken over the same window
        # (the instantaneous one would leave kd w thdd_ref / 2 of torque on the reference itself).
        measured_reference_rates = self.reference_rate.rates(observation)
        arm_reference_rates = list(measured_reference_rates)
        if deflection is not None:
            offset = np.asarray(deflection, dtype=float).tolist()
            offset_rate = self._deflection_rate(offset)
            reference = [reference[j] + offset[j] for j in range(3)]
            measured_reference_rates = [measured_reference_rates[j] + offset_rate[j] for j in range(3)]
        if self.half_band is not None:
            in_band = self.in_band(observation)
            rates, measured_reference_rates = self.band_rates(
                observation, in_band, rates, arm_reference_rates, measured_reference_rates
            )
            if in_band.any():
                # A rotor free of its arm: the loop's gains on the inertia it drives now (docs/design.md section 6).
                band_gains = self._gains_on(self.band_inertia(in_band))
                return self._matrix_feedback(
                    reference, angles, reference_rates, rates, measured_reference_rates, band_gains
                )
        if self._gain_matrices is not None:
            return self._matrix_feedback(reference, angles, reference_rates, rates, measured_reference_rates)
        torque = [0.0, 0.0, 0.0]
        # Per joint in Python floats: at three values, cheaper than NumPy's operations.
        for joint in range(3):
            error = reference[joint] - angles[joint]
            rate_error = measured_reference_rates[joint] - rates[joint]
            self._error[joint], self._rate_error[joint] = error, rate_error
            # Anti-windup: the integral torque is clamped, so a blocked joint holds at most `limit` of it.
            integral = min(max(self._integral[joint] + ki[joint] * error * period, -limit), limit)
            self._integral[joint] = integral
            value = kp[joint] * error + kd[joint] * rate_error + integral
            if reference_rates[joint] == 0.0:
                # At rest the model's fc sign(thd_ref) is 0: push the breakaway torque in the error's direction.
                value += gains.breakaway[joint] * min(max(error / width, -1.0), 1.0)
            torque[joint] = value
        if self.notch is not None:
            for joint in range(3):
                torque[joint] = notch_sample(self._notch_coefficients[joint], self._notch_state[joint], torque[joint])
        return np.array(torque)

    def _deflection_rate(self, deflection: list[float]) -> list[float]:
        """The mean rate (rad/s) of the rotors' ``deflection`` (rad) over the measured rate's window w ending now, from
        this and the last two samples' (remembered here): the backward difference d1 over the period T is the mean
        over T, and the mean over w < T is d1 + (T - w) d2 / 2 to first order, d2 the second difference over T^2;
        0 before the second sample."""
        history = self._deflections
        history.append(deflection)
        if len(history) > 3:
            del history[0]
        if len(history) == 1:
            return [0.0, 0.0, 0.0]
        period, shortfall = self.period, self.period - self.reference_rate.window
        rates = [(history[-1][j] - history[-2][j]) / period for j in range(3)]
        if len(history) == 3 and shortfall > 0.0:
            for j in range(3):
                second = (history[2][j] - 2.0 * history[1][j] + history[0][j]) / period**2
                rates[j] += 0.5 * shortfall * second
        return rates

    def band_rates(
        self,
        observation: Observation,
        in_band: NDArray[np.bool_],
        rates: list[float],
        arm_reference_rates: list[float],
        rotor_reference_rates: list[float],
    ) -> tuple[list[float], list[float]]:
        """The measured and reference rates (rad/s) the derivative term compares on gearheads with backlash, per joint:
        outside the band the arm's (the load encoder's backward difference over one period) plus the
        twist rate error low-passed at :data:`BAND_RATE_CUTOFF`, e = (w_ref - w_load) + LP[(w_ref + d_dot) - w_rotor
        - (w_ref - w_load)]: below the cutoff the rotor's rate error, as designed, above it the arm's, which the
        rotor's rattle in the band does not reach (docs/design.md section 6, "Through a torque reversal"). Inside the
        band, and without a load encoder or before its second reading, ``rates`` and ``rotor_reference_rates``
        unchanged.

        Args:
            observation: The step's observation, with ``load_angles`` for the arm's rate.
            in_band: Per joint, whether its rotor is inside the band (:meth:`in_band`).
            rates: The rotor encoders' rates (rad/s).
            arm_reference_rates: The arms' reference rates over the window (rad/s).
            rotor_reference_rates: The rotors' reference rates (rad/s): the arms' plus the deflection's.
        """
        if "load_angles" not in observation:
            return rates, rotor_reference_rates
        load_angles = np.asarray(observation["load_angles"], dtype=float).tolist()
        last, self._load_angles = self._load_angles, load_angles
        if last is None:
            return rates, rotor_reference_rates
        smoothing = 1.0 - math.exp(-2.0 * math.pi * BAND_RATE_CUTOFF * self.period)
        rates, reference_rates = list(rates), list(rotor_reference_rates)
        for joint in range(3):
            load_rate = (load_angles[joint] - last[joint]) / self.period
            twist_error = (rotor_reference_rates[joint] - rates[joint]) - (arm_reference_rates[joint] - load_rate)
            self._twist_rate_error[joint] += smoothing * (twist_error - self._twist_rate_error[joint])
            if not in_band[joint]:
                rates[joint] = load_rate
                reference_rates[joint] = arm_reference_rates[joint] + self._twist_rate_error[joint]
        return rates, reference_rates

    def flank_floor(
        self,
        observation: Observation,
        deflection: NDArray[np.float64],
        torque: NDArray[np.float64],
        integral: list[float],
    ) -> NDArray[np.float64]:
        """The servo torque (N m), (3,), held at rest where it would pull a rotor off the flank its static load
        presses faster than the load lets the arm follow (docs/design.md section 6, "At rest on a light load").

        With the rotor on flank s (the sign of ``deflection``, the rotors' rest deflection phi - theta in rad, (3,))
        the gearhead passes the arm's static load |g| = k |deflection - s b / 2|. Pulled back by the servo, the lone
        rotor accelerates at s (tau - f) / J_m, the arm behind it under its load alone at -|g| / J_a; the rotor stays
        on the flank while s tau >= s f - |g| J / J_a, f the rotor's friction (Coulomb, against its measured rate;
        against a pull from rest, its sliding value). At rest, each joint's torque below that floor is raised to it
        and its integral kept as it was (anti-windup); in motion, and on a joint whose reference moves, nothing.

        Args:
            observation: The step's observation (its reference rates and the rotors' measured rates).
            deflection: The rotors' deflection past the arms' reference (rad), (3,).
            torque: The servo torque (N m), (3,), of this sample.
            integral: The integral term (N m) before this sample, restored on a held joint.
        """
        at_rest = np.asarray(observation["reference_velocities"]) == 0.0
        if not at_rest.any():
            return torque
        flank = np.sign(deflection)
        load = np.abs(np.asarray(self.notch.stiffness) * (deflection - flank * self.half_band))
        inertia = np.diag(self._inertia_matrix)
        rotor = np.asarray(self.notch.rotor_inertia)
        rising = flank * np.asarray(observation["joint_velocities"]) > self._sliding_rate
        friction = np.where(rising, self.rotor_friction, -self.rotor_friction)
        floor = friction - load * inertia / np.maximum(inertia - rotor, 1e-12)
        held = at_rest & (flank != 0.0) & (flank * torque < floor)
        if not held.any():
            return torque
        self._integral = [integral[j] if held[j] else self._integral[j] for j in range(3)]
        return np.where(held, flank * floor, torque)

    def in_band(self, observation: Observation) -> NDArray[np.bool_]:
        """Per joint (3,), whether its gearhead's measured twist, the motor encoder's angle minus the load encoder's,
        lies inside the backlash's band (its rotor free of the arm); all False without a backlash or a load
        encoder."""
        if self.half_band is None or "load_angles" not in observation:
            return np.zeros(3, dtype=bool)
        twist = np.asarray(observation["joint_angles"]) - np.asarray(observation["load_angles"])
        return np.abs(twist) < self.half_band

    def band_inertia(self, in_band: ArrayLike) -> NDArray[np.float64]:
        """The joint-space inertia (kg m^2), (3, 3), the motors drive with the joints ``in_band`` (3 bools) free of
        their arms: the scheduled matrix with each such joint's row and column replaced by its rotor's inertia
        alone."""
        inertia = self._inertia_matrix.copy()
        for joint in np.flatnonzero(in_band):
            inertia[joint, :] = inertia[:, joint] = 0.0
            inertia[joint, joint] = self.notch.rotor_inertia[joint]
        return inertia

    def _gains_on(
        self, inertia: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(kp, ki, kd) matrices on the joint-space ``inertia`` (kg m^2), (3, 3): K = S M S (:meth:`schedule`)."""
        gains, placed = self.gains, np.asarray(self.gains.inertia)
        scales = (np.sqrt(np.asarray(per_joint) / placed) for per_joint in (gains.kp, gains.ki, gains.kd))
        kp, ki, kd = (scale[:, None] * inertia * scale[None, :] for scale in scales)
        return kp, ki, kd

    def _matrix_feedback(
        self,
        reference: list[float],
        angles: list[float],
        reference_rates: list[float],
        rates: list[float],
        measured_reference_rates: ArrayLike,
        gain_matrices: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None,
    ) -> NDArray[np.float64]:
        """:meth:`feedback` with gain matrices (:meth:`schedule` on an inertia matrix, or ``gain_matrices``): the same
        law, its P, I and D terms coupled."""
        kp, ki, kd = self._gain_matrices if gain_matrices is None else gain_matrices
        gains, limit = self.gains, self.gains.integral_limit
        error = np.array(reference) - np.array(angles)
        rate_error = np.asarray(measured_reference_rates, dtype=float) - np.array(rates)
        self._error, self._rate_error = error.tolist(), rate_error.tolist()
        integral = np.clip(np.array(self._integral) + (ki @ error) * self.period, -limit, limit)
        self._integral = integral.tolist()
        torque = kp @ error + kd @ rate_error + integral
        at_rest = np.array(reference_rates) == 0.0
        push = np.asarray(gains.breakaway) * np.clip(error / gains.friction_width, -1.0, 1.0)
        torque = torque + np.where(at_rest, push, 0.0)
        if self.notch is not None:
            torque = np.array(
                [notch_sample(self._notch_coefficients[j], self._notch_state[j], float(torque[j])) for j in range(3)]
            )
        return torque

    def __call__(self, observation: Observation, deflection: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.feedback(observation, deflection)
