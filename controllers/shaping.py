"""Input shaping of the reference against the compliant drives' mode (docs/design.md section 6, "Input shaping").

An input shaper (Singer & Seering 1990, "Preshaping command inputs to reduce system vibration", J. Dyn. Sys., Meas.,
Control 112(1), doi:10.1115/1.2894142) convolves the reference with a few impulses, amplitudes A_i summing to 1 at
delays t_i, chosen so that the vibration the impulses leave in a mode of natural frequency omega and damping ratio
zeta cancels. A unit impulse at t_i leaves exp(-zeta omega (t - t_i)) sin(omega_d (t - t_i)) with
omega_d = omega sqrt(1 - zeta^2); after the last impulse t_N the shaped reference leaves V times the vibration of the
unshaped one,

    V(omega, zeta) = exp(-zeta omega t_N) |sum_i A_i exp(zeta omega t_i) exp(i omega_d t_i)|,

the shaper's residual vibration (:meth:`Shaper.residual`). With K = exp(-zeta pi / sqrt(1 - zeta^2)):

- ZV: A = (1, K) / (1 + K) at t = (0, pi / omega_d): V = 0 at the design mode; a frequency error r = omega / omega_0
  leaves, undamped, V = |cos(pi r / 2)|.
- ZVD: A = (1, 2K, K^2) / (1 + K)^2 at t = (0, 1, 2) pi / omega_d: V and dV/domega = 0 at the design mode, undamped
  V = cos^2(pi r / 2), robust to the frequency error at the price of a second half period.

A jerk-limited timing (:class:`JerkLimitedTiming`) smooths a move's time law instead: a moving average of window w over
tau and its rates turns every step of tau_ddot into a ramp of length w (jerk at most the step over w) and, being a
convolution with a rectangle, leaves no vibration in a mode of period w (nor its harmonics): a shaper in time-law
form that costs w per move and keeps the path.

The mode follows the pose and the payload: :class:`ShapedController` shapes the reference its controller sees, each
sample from the past samples of the env's reference (a causal shaper: it delays, never looks ahead), with the
shaper designed on the first mode of the two-mass model (:func:`controllers.compliance.first_mode`) at the present
reference pose and the controller's payload estimate, redesigned every :data:`~controllers.servo.SCHEDULE_PERIOD`.
"""

from __future__ import annotations

import math
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation, payload_estimate_reader, payload_estimator_of
from controllers.compliance import DriveCompliance, DriveMode, first_mode
from controllers.dynamics import DeltaDynamics
from controllers.payload import PayloadEstimator
from controllers.registry import ControllerEntry, controller_entry
from controllers.servo import SCHEDULE_PERIOD
from controllers.setup import ControllerSetup
from delta_env import kinematics
from delta_env.geometry import DeltaGeometry
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timing import MoveTiming, TimeLaw
from delta_env.trajectories import Segment
from delta_env.validation import require_in

MAX_SHAPER_DURATION = 0.1
"""Longest shaper (s) a :class:`ShapedController` keeps the past reference for: a ZVD of a mode above 10 Hz."""

REFERENCE_KEYS = ("reference_angles", "reference_velocities", "reference_accelerations")
"""The observation's reference, which the shaper replaces."""


@dataclass(frozen=True)
class Shaper:
    """Impulses the reference is convolved with.

    Attributes:
        amplitudes: A_i (dimensionless), positive, summing to 1.
        delays: t_i (s), the first 0, non-decreasing.
    """

    amplitudes: tuple[float, ...]
    delays: tuple[float, ...]

    def __post_init__(self) -> None:
        amplitudes, delays = np.asarray(self.amplitudes, dtype=float), np.asarray(self.delays, dtype=float)
        if amplitudes.ndim != 1 or amplitudes.shape != delays.shape or len(amplitudes) == 0:
            raise ValueError(f"amplitudes and delays must be 1-D of one length, got {amplitudes.shape}, {delays.shape}")
        if not (np.all(amplitudes > 0.0) and abs(amplitudes.sum() - 1.0) < 1e-9):
            raise ValueError(f"amplitudes must be positive and sum to 1, got {amplitudes.tolist()}")
        if not (np.all(np.isfinite(delays)) and delays[0] == 0.0 and np.all(np.diff(delays) >= 0.0)):
            raise ValueError(f"delays must start at 0 s and not decrease, got {delays.tolist()}")
        object.__setattr__(self, "amplitudes", tuple(float(a) for a in amplitudes))
        object.__setattr__(self, "delays", tuple(float(t) for t in delays))

    @property
    def duration(self) -> float:
        """The last impulse's delay (s): what the shaper adds to a move's time."""
        return self.delays[-1]

    def sampled(self, period: float) -> Shaper:
        """The shaper with each delay rounded to whole sample periods ``period`` (s), impulses that fall on one
        sample merged: what a sampled reference can be convolved with exactly (:class:`ReferenceHistory`)."""
        require_in("period", period, 0.0, unit="s", low_open=True)
        merged: dict[int, float] = {}
        for amplitude, delay in zip(self.amplitudes, self.delays, strict=True):
            sample = round(delay / period)
            merged[sample] = merged.get(sample, 0.0) + amplitude
        return Shaper(tuple(merged.values()), tuple(sample * period for sample in merged))

    def residual(self, frequency_hz: float, damping_ratio: float) -> float:
        """V: the vibration the shaped reference leaves in a mode of natural frequency ``frequency_hz`` (Hz) and
        ``damping_ratio`` (in [0, 1)) over the unshaped one's, after the last impulse (module docstring)."""
        require_in("frequency_hz", frequency_hz, 0.0, unit="Hz", low_open=True)
        require_in("damping_ratio", damping_ratio, 0.0, 1.0, high_open=True)
        omega = 2.0 * math.pi * frequency_hz
        omega_d = omega * math.sqrt(1.0 - damping_ratio**2)
        decay = damping_ratio * omega
        total = sum(
            a * math.exp(decay * (t - self.duration)) * complex(math.cos(omega_d * t), math.sin(omega_d * t))
            for a, t in zip(self.amplitudes, self.delays, strict=True)
        )
        return abs(total)


def _decrement(frequency_hz: float, damping_ratio: float) -> tuple[float, float]:
    """(K, half the damped period (s)) of a mode."""
    require_in("frequency_hz", frequency_hz, 0.0, unit="Hz", low_open=True)
    require_in("damping_ratio", damping_ratio, 0.0, 1.0, high_open=True)
    root = math.sqrt(1.0 - damping_ratio**2)
    return math.exp(-damping_ratio * math.pi / root), 0.5 / (frequency_hz * root)


def zv_shaper(frequency_hz: float, damping_ratio: float) -> Shaper:
    """The zero-vibration shaper of a mode of natural frequency ``frequency_hz`` (Hz) and ``damping_ratio``."""
    k, half = _decrement(frequency_hz, damping_ratio)
    return Shaper((1.0 / (1.0 + k), k / (1.0 + k)), (0.0, half))


def zvd_shaper(frequency_hz: float, damping_ratio: float) -> Shaper:
    """The zero-vibration-and-derivative shaper of a mode of natural frequency ``frequency_hz`` (Hz) and
    ``damping_ratio``."""
    k, half = _decrement(frequency_hz, damping_ratio)
    scale = (1.0 + k) ** 2
    return Shaper((1.0 / scale, 2.0 * k / scale, k * k / scale), (0.0, half, 2.0 * half))


SHAPERS: dict[str, Callable[[float, float], Shaper]] = {"zv": zv_shaper, "zvd": zvd_shaper}
"""The shaper designs by name: ``shaper(frequency_hz, damping_ratio)``."""


class ReferenceHistory:
    """The env's reference over the last :data:`MAX_SHAPER_DURATION`, convolved with a shaper's impulses.

    The impulses act at whole samples (:meth:`Shaper.sampled`): the shaped sample sequence is then exactly the
    convolution of the sampled reference, so the vibration it leaves in a mode is the sampled shaper's
    :meth:`Shaper.residual` times the unshaped one's, aliases included (an interpolated delay would filter the
    reference near the Nyquist rate, where a drive's mode lies). Before the first sample the reference is at rest
    at it (an episode starts at rest).

    Args:
        period: Sample period (s).
    """

    def __init__(self, period: float = CONTROL_PERIOD) -> None:
        self.period = require_in("period", period, 0.0, unit="s", low_open=True)
        self._samples: deque[tuple[NDArray, NDArray, NDArray]] = deque(
            maxlen=math.ceil(MAX_SHAPER_DURATION / period) + 1
        )

    def reset(self) -> None:
        """Forget the reference."""
        self._samples.clear()

    def copy(self) -> ReferenceHistory:
        """A history of the same samples, to extend without changing this one."""
        history = ReferenceHistory(self.period)
        history._samples = self._samples.copy()
        return history

    def append(self, observation: Observation) -> None:
        """Keep this sample's reference."""
        angles, rates, accelerations = (np.array(observation[key], dtype=float) for key in REFERENCE_KEYS)
        if not self._samples:
            rest = (angles, np.zeros(3), np.zeros(3))
            self._samples.extend([rest] * (self._samples.maxlen - 1))
        self._samples.append((angles, rates, accelerations))

    def shaped(self, shaper: Shaper) -> tuple[NDArray, NDArray, NDArray]:
        """(angles (rad), rates (rad/s), accelerations (rad/s^2)), each (3,): the reference convolved with
        ``shaper`` sampled at the period, sum_i A_i r(n - round(t_i / period)), at the last sample.

        Raises:
            ValueError: for a shaper longer than :data:`MAX_SHAPER_DURATION`.
        """
        require_in("shaper duration", shaper.duration, 0.0, MAX_SHAPER_DURATION, unit="s")
        last = len(self._samples) - 1
        angles, rates, accelerations = np.zeros(3), np.zeros(3), np.zeros(3)
        for amplitude, delay in zip(shaper.amplitudes, shaper.delays, strict=True):
            a, r, c = self._samples[last - round(delay / self.period)]
            angles += amplitude * a
            rates += amplitude * r
            accelerations += amplitude * c
        return angles, rates, accelerations


def arm_side(setup: ControllerSetup) -> DeltaDynamics:
    """The model a shaper or a jerk-limited timing designs on: the nominal model of the robot of ``setup`` (datasheet
    masses, rod forearms), whose rho1 holds no rotor (:func:`controllers.compliance.joint_space_inertia`)."""
    return DeltaDynamics.of_robot(setup.geometry, setup.masses, None, forearm_rods=True)


def shaped_entry(base_key: str, kind: str) -> ControllerEntry:
    """The registry entry of the row ``base_key`` following its reference shaped by ``kind`` (:class:`ShapedController`,
    the shaper's mode from the nominal model's arm side and ``ControllerSetup.compliance``). Its estimator is its
    base's, with the tare and empty moves of ``base_key`` (:attr:`~controllers.registry.ControllerEntry.tares_as`),
    which the experiments measure whether or not the base row runs too. A setup without a compliance is refused
    (nothing to shape against)."""
    base = controller_entry(base_key)
    if kind not in SHAPERS:
        raise ValueError(f"kind must be one of {', '.join(SHAPERS)}, got {kind!r}")

    def factory(setup: ControllerSetup) -> ShapedController:
        if setup.compliance is None:
            raise ValueError(f"a shaped {base_key!r} needs the drives' compliance; ControllerSetup.compliance is None")
        return ShapedController(base.factory(setup), arm_side(setup), setup.compliance, kind)

    return ControllerEntry(
        f"{base_key}+{kind}",
        f"{base.label}+{kind.upper()}",
        factory,
        estimates_payload=base.estimates_payload,
        has_estimator=base.has_estimator,
        tares_as=base.tare_key,
        needs_drive_lag=base.needs_drive_lag,
    )


LAG_ZV = shaped_entry("mid_f_rls_lag", "zv")
"""MId+F+R+RLS+lag+PD on the ZV-shaped reference: ``--controllers controllers.shaping:LAG_ZV``."""

LAG_ZVD = shaped_entry("mid_f_rls_lag", "zvd")
"""MId+F+R+RLS+lag+PD on the ZVD-shaped reference: ``--controllers controllers.shaping:LAG_ZVD``."""


class ShapedController:
    """A controller that follows the env's reference shaped against the drives' first mode (module docstring).

    Every :data:`~controllers.servo.SCHEDULE_PERIOD` the shaper is designed again on the two-mass model's first mode
    at the shaped reference's pose and the controller's payload estimate (0 for one that makes none): the shaper
    follows the mode along the path and with the load.

    Args:
        controller: The controller that receives the observation with the shaped reference.
        dynamics: The model of the arm side (its rho1 must hold no rotor: the nominal model,
            :func:`controllers.compliance.joint_space_inertia`).
        compliance: The drives' compliance as the controller knows it.
        kind: The shaper, one of :data:`SHAPERS`.
        period: Control period (s).
    """

    def __init__(
        self,
        controller: Controller,
        dynamics: DeltaDynamics,
        compliance: DriveCompliance,
        kind: str = "zvd",
        period: float = CONTROL_PERIOD,
    ) -> None:
        if kind not in SHAPERS:
            raise ValueError(f"kind must be one of {', '.join(SHAPERS)}, got {kind!r}")
        self.controller = controller
        self.dynamics = dynamics
        self.compliance = compliance
        self.kind = kind
        self.name = f"{controller.name}+{kind.upper()}"
        self.history = ReferenceHistory(period)
        self._design = SHAPERS[kind]
        self._payload = payload_estimate_reader(controller)
        self._redesign = max(1, round(SCHEDULE_PERIOD / period))
        self._samples = 0
        self.mode: DriveMode | None = None
        self.shaper: Shaper | None = None

    @property
    def payload_estimate(self) -> float:
        """The wrapped controller's payload estimate (kg), 0 if it makes none."""
        return self._payload()

    @property
    def estimator(self) -> PayloadEstimator | None:
        """The wrapped controller's payload estimator, or None."""
        return payload_estimator_of(self.controller)

    def reset(self) -> None:
        self.controller.reset()
        self.history.reset()
        self._samples = 0
        self.mode = self.shaper = None

    def _designed(self, history: ReferenceHistory, observation: Observation) -> tuple[DriveMode, Shaper] | None:
        """The mode and shaper the call with ``observation`` designs (``history`` holds it last), or None when the
        call keeps the present ones (a redesign every :data:`~controllers.servo.SCHEDULE_PERIOD`)."""
        if self._samples % self._redesign != 0:
            return None
        pose = observation["reference_angles"] if self.shaper is None else history.shaped(self.shaper)[0]
        mode = first_mode(self.dynamics, self.compliance, pose, max(0.0, self._payload()))
        return mode, self._design(mode.frequency_hz, mode.damping_ratio).sampled(history.period)

    def followed_reference(self, observation: Observation) -> NDArray[np.float64]:
        """The shaped reference angles (rad), shape (3,), the next call, with ``observation``, will follow (the
        same design, the same history); nothing is kept (:class:`~controllers.base.ShapesReference`)."""
        history = self.history.copy()
        history.append(observation)
        designed = self._designed(history, observation)
        return history.shaped(self.shaper if designed is None else designed[1])[0]

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        self.history.append(observation)
        designed = self._designed(self.history, observation)
        if designed is not None:
            self.mode, self.shaper = designed
        self._samples += 1
        angles, rates, accelerations = self.history.shaped(self.shaper)
        shaped = dict(observation)
        shaped.update(reference_angles=angles, reference_velocities=rates, reference_accelerations=accelerations)
        return self.controller(shaped)


def jerk_limited(law: TimeLaw, samples: int) -> TimeLaw:
    """``law`` averaged over a moving window of ``samples`` samples (>= 1): tau, tau_dot and tau_ddot each the mean
    of the last ``samples`` samples (the move at rest before its start and after its end), longer by ``samples`` - 1
    samples. A tau_ddot step becomes a ramp over the window: the jerk is bounded."""
    if not (isinstance(samples, int) and samples >= 1):
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    window = np.full(samples, 1.0 / samples)
    tail = np.ones(samples - 1)
    tau = np.minimum(np.convolve(np.concatenate([law.tau, tail]), window)[: len(law) + samples - 1], 1.0)
    tau[-1] = 1.0
    rates = [np.convolve(values, window) for values in (law.tau_dot, law.tau_ddot)]
    return TimeLaw(law.dt, tau, *rates)


def mode_period(
    dynamics: DeltaDynamics, compliance: DriveCompliance, geometry: DeltaGeometry
) -> Callable[[Segment, float], float]:
    """The window (s) of a :class:`JerkLimitedTiming` that leaves none of the drives' first mode at a move's end:
    ``window(shape, payload)``, one period of the two-mass model's first mode at ``shape.end`` (m, through the
    inverse kinematics of ``geometry``) carrying ``payload`` (kg), the place where the ring would hold the platform.

    Args:
        dynamics: The model of the arm side (the nominal model, whose rho1 holds no rotor).
        compliance: The drives' compliance as the controllers know it.
        geometry: The geometry the moves are planned on.
    """

    def window(shape: Segment, payload: float) -> float:
        theta = kinematics.inverse(geometry, shape.end)
        return 1.0 / first_mode(dynamics, compliance, theta, payload).frequency_hz

    return window


class JerkLimitedTiming:
    """A :class:`~delta_env.timing.MoveTiming` whose laws are another timing's averaged over a window
    (:func:`jerk_limited`): with the window one period of the drives' mode (:func:`mode_period`), the moving average
    leaves none of it.

    An online timing's retimed carry is averaged too: the moving average is causal, so the averaged continuation
    repeats the samples already followed (they are copied from the law followed, bit for bit, as
    :meth:`~delta_env.timing.MoveTiming.retime` requires).

    Args:
        timing: The timing whose laws are smoothed.
        window: The averaging window (s) of a move, ``window(shape, payload)`` with the payload (kg) it carries
            (:func:`mode_period`); rounded to whole samples of the laws (at least one), at most
            :data:`MAX_SHAPER_DURATION`.
        carried_payload: The payload (kg) a carry's window is designed for (the task's heaviest object: a timing
            that does not weigh its objects knows no other); an empty move's is 0.
    """

    def __init__(self, timing: MoveTiming, window: Callable[[Segment, float], float], carried_payload: float) -> None:
        self.timing = timing
        self.window = window
        self.carried_payload = require_in("carried_payload", carried_payload, 0.0, unit="kg")
        self.retimes_online = timing.retimes_online
        # each smoothed law given out -> the timing's law it smooths, while the reference that follows it keeps it
        # (the env plans every move of an episode at its reset, episode after episode)
        self._inner: weakref.WeakKeyDictionary[TimeLaw, TimeLaw] = weakref.WeakKeyDictionary()

    def _smoothed(self, shape: Segment, law: TimeLaw, payload: float) -> TimeLaw:
        window = require_in("window", self.window(shape, payload), 0.0, MAX_SHAPER_DURATION, unit="s", low_open=True)
        return jerk_limited(law, max(1, round(window / law.dt)))

    def _given(self, smoothed: TimeLaw, law: TimeLaw) -> TimeLaw:
        """``smoothed``, the average of the timing's ``law``, remembered for :meth:`retime` if the timing retimes."""
        if self.retimes_online:
            self._inner[smoothed] = law
        return smoothed

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        law = self.timing.carry(shape, declared_mass)
        return self._given(self._smoothed(shape, law, self.carried_payload), law)

    def empty(self, shape: Segment) -> TimeLaw:
        law = self.timing.empty(shape)
        return self._given(self._smoothed(shape, law, 0.0), law)

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        """The timing's retimed law, averaged, for the carry that follows the averaged ``law``, or None."""
        inner = self._inner.get(law)
        continued = None if inner is None else self.timing.retime(shape, inner, index)
        if continued is None:
            return None
        smoothed = self._smoothed(shape, continued, self.carried_payload)
        followed = index + 1
        rates = [
            np.concatenate((getattr(law, name)[:followed], getattr(smoothed, name)[followed:]))
            for name in ("tau", "tau_dot", "tau_ddot")
        ]
        return self._given(TimeLaw(law.dt, *rates), continued)
