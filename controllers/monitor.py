"""Fault detection from what a real controller sees: encoders, measured torques, its own commands, its model.

:class:`FaultMonitor` checks every observation (docs/design.md section 6, "Fault monitor"):

- **Sensor plausibility**, at the sample itself: a NaN or inf reading; an encoder step whose second difference
  asks an acceleration no drive could give (:data:`ACCELERATION_FACTOR`); an encoder that repeats its reading while
  the joint was moving several counts per sample (:data:`STUCK_SAMPLES`); a measured torque outside what a
  first-order current loop can do between the last torque and the held command (:data:`TORQUE_MARGIN`). Measured
  torques that stay short of the prediction, or keep falling short of what the slowest healthy loop would reach (a
  CUSUM, :data:`DRIVE_FAULT_EVIDENCE`), are a drive that does not deliver its command.
- **External forces** (collisions): the residual of the identified model, measured torque minus the model's
  torque at the smoothed joint state (with the mass held, once known), mapped to a platform force F = J^-T r. Until
  the mass held is known, the residual's component along the payload regressor phi is left out (an unknown mass
  looks exactly like a force along J^T (xdd + g)).
- **Payload consistency** (slips and drops): the apparent mass of the last few samples against the mass held since
  the pick.

The monitor hands the controller a *clean* observation: a faulty encoder reading is replaced by the reference plus
the joint's last tracking error, a faulty torque by the current loop's prediction, so that one bad sample never
reaches the feedback, the model or an estimator. :class:`MonitoredController` runs any controller behind a
monitor, keeps what a fault corrupted out of its payload estimator and reacts to a detected fault.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import SMOOTHER_HISTORY, SMOOTHER_JERK_STD, SMOOTHER_LAG, JointStateSmoother
from controllers.payload import FRICTION_VELOCITY, RESIDUAL_STD, ModelCorrections, PayloadEstimator, residual_std
from delta_env.faults import FAULT_REACTIONS
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from delta_env.validation import require_in, require_positive


@dataclass(frozen=True)
class DetectedFault:
    """One fault a monitor detected.

    Attributes:
        kind: One of :data:`delta_env.faults.FAULT_KINDS`: what the monitor believes happened.
        time_s: Time (s) from the reset of the observation on which it was detected.
        joint: Joint 0..2 it concerns, or None.
        magnitude: What the monitor measured, in the unit of its kind: the estimated external force (N) for a
            collision, the implausible jump (rad) or torque (N m) of a sensor, the mass (kg) lost in a slip, the
            torque shortfall (N m) of a drive fault; NaN where none applies.
    """

    kind: str
    time_s: float
    joint: int | None = None
    magnitude: float = float("nan")


@runtime_checkable
class ReportsFaults(Protocol):
    """A controller that detects faults: the capability the evaluation records beside the injected truth."""

    @property
    def detected_faults(self) -> Sequence[DetectedFault]:
        """The faults detected since the last reset, in time order."""
        ...


ACCELERATION_FACTOR = 2.0
"""An encoder step is implausible when its second difference asks more than this many times the acceleration the
joint's own drive gives its arm at peak torque (peak / (rho1 I)): the other chains and an external force can add
to it, but not double it (a 1000 N push on the platform adds about 300 N m at a joint)."""

STUCK_COUNTS = 4.0
"""An encoder that repeats its reading is suspect when its last step, and its reference's step, were at least this
many counts."""

STUCK_SAMPLES = 3
"""Repeated readings of a suspect encoder that make it stuck."""

TORQUE_MARGIN = 6.0
"""How far (N m) a measured torque may lie outside the span between the last torque and the command held since: the
sensor's noise (0.5 N m, so about 8 standard deviations of a difference of two readings) with room."""

DRIVE_FAULT_SAMPLES = 3
"""Consecutive implausible torques of one joint, all short of the prediction, that make a drive fault rather than a
sensor glitch."""

SLOWEST_LAG_FACTOR = 2.5
"""The slowest current loop the monitor takes for healthy: this many times the identified time constant (a drive
whose loop slowed from 1 to 2.5 ms is worn, not faulty)."""

DRIVE_FAULT_DRIFT = 2.0
"""Shortfall (N m) per sample below the slowest healthy loop's step that the CUSUM forgives: the measured torque's
noise (0.5 N m on each of two readings) with room."""

DRIVE_FAULT_STEP = 8.0
"""Largest shortfall (N m) one sample adds to the CUSUM, so that one odd reading cannot make a drive fault."""

DRIVE_FAULT_EVIDENCE = 20.0
"""Accumulated shortfall beyond the drift (N m, summed over samples) that makes a drive fault: at least four
samples that each fall short by more than 7 N m."""

FORCE_REFERENCE = 60.0
"""Platform force (N) the collision CUSUM forgives per sample: above the model's residual on healthy work (at most
52 N in 99.9 % of the samples at 6 g on randomized plants with up to 6 kg, 77 N at most)."""

FORCE_EVIDENCE = 60.0
"""Accumulated force beyond :data:`FORCE_REFERENCE` (N, summed over samples) that makes a collision: one sample of
120 N, or two of 90 N."""

SLIP_MIN_MASS = 0.3
"""Lightest mass held (kg) whose loss the consistency check looks for; below, the torque noise hides it."""

HELD_MASS_STD = 0.05
"""Standard error (kg) below which the mass held is taken out of the collision check's residual (before, the part
along phi is left out): 0.05 kg times phi is about 1 N m."""

SLIP_PRECISION = 0.1
"""The slip check starts once the standard error of the mass held is below this fraction of it: an early estimate
of a light object, biased by the static friction of the lift-off, would make "gone" and "held" hard to tell."""

SLIP_EVIDENCE = 12.0
"""Log-likelihood ratio (the CUSUM's threshold) at which "the object is gone" wins over "it is still held"."""

INITIAL_RESIDUAL_STD = 4.0
"""Standard deviation (N m) of the model's residual the slip check assumes at a reset, before it has measured its
robot's: the identified model's error on a robot whose masses and friction differ from its identification by up to
10 and 30 % (the ``randomized`` preset), at 6 g."""

SCATTER_RATE = 0.01
"""Weight of each moving sample in the running mean square of the model's residual (a memory of about 100 samples),
from which the slip check takes the residual's variance, at least the payload estimator's 1.5 N m squared."""

SLIP_SETTLE = 0.03
"""Time after the pick (s) before the mass held is trusted as a reference."""

SENSOR_QUIET = SMOOTHER_HISTORY + SMOOTHER_LAG + 1
"""Readings whose model equations (the monitor's checks, the payload estimator's) are left out after replaced
readings in a row: the smoother's window, every smoothed state that leans on them."""

RESYNC_QUIET = SMOOTHER_HISTORY + 2 * SMOOTHER_LAG + 1
"""Readings kept out of the model's equations after the clean readings step back onto an encoder that was replaced
for a while (a stuck spell): the step sits in the smoother's whole window."""

_TORQUE_AGE = MEASURED_TORQUE_DELAY / CONTROL_PERIOD


class FaultMonitor:
    """Checks each observation for faults and returns it cleaned; see the module docstring.

    Args:
        dynamics: The identified model (MId+F+R), for the residual and the payload regressor.
        peak_torque: The drive's peak torque (N m).
        drive_lag: The identified current-loop time constant per joint (s), for the torque prediction; None
            uses 1 ms.
        encoder_step: Encoder resolution (rad); None for ideal encoders.

    Attributes:
        events: The faults detected since the reset, in time order.
        faulty: Whether this sample's reading (any joint, encoder or torque) was replaced.
        suspect: Whether an encoder repeats a reading it should not, not yet called stuck (kept out of the checks).
        resynced: Whether the clean readings stepped back onto an encoder on this sample.
        quiet_samples: Readings from this one that the model's equations leave out (0 after a lone replaced reading).
        collision: Whether an external force is being detected now.
        force: The last estimate of the external force on the platform (N), (3,): while the gripper holds, without
            its part along the payload regressor.
        collision_samples: Checked samples since the collision evidence began to grow (0 while there is none).
        held_mass: The mass (kg) the payload-consistency check believes held, once :data:`SLIP_SETTLE` after the pick
            has passed and it is known to :data:`HELD_MASS_STD` (0 after a slip); None otherwise.
        slipped: Whether a slip was detected on this sample.
    """

    def __init__(
        self,
        dynamics: DeltaDynamics,
        peak_torque: float,
        *,
        drive_lag: Sequence[float] | None = None,
        encoder_step: float | None = None,
    ) -> None:
        require_positive("peak_torque", peak_torque, unit="N m")
        lags = (1e-3,) * 3 if drive_lag is None else tuple(drive_lag)
        for lag in lags:
            require_in("drive_lag", lag, 0.0, 0.1, unit="s")
        self.dynamics = dynamics
        self.peak_torque = float(peak_torque)
        arm_inertia = dynamics.parameters.rho1 * dynamics.inertia
        step = 0.0 if encoder_step is None else float(encoder_step)
        self.encoder_step = step
        self._jump_bound = ACCELERATION_FACTOR * peak_torque / arm_inertia * CONTROL_PERIOD**2 + 2.0 * step
        self._stuck_step = max(STUCK_COUNTS * step, 1e-9)
        self._loop_gain = np.array([1.0 - math.exp(-CONTROL_PERIOD / lag) if lag > 0 else 1.0 for lag in lags])
        self._slowest_gain_list = [
            1.0 - math.exp(-CONTROL_PERIOD / (SLOWEST_LAG_FACTOR * lag)) if lag > 0 else 1.0 for lag in lags
        ]
        self._slowest_gain = np.array(self._slowest_gain_list)
        self._delayed = _DelayedState(SMOOTHER_LAG)
        self.lag = SMOOTHER_LAG
        """Readings between a sample and the model's checks at it (the smoother's lag)."""
        self._static_friction = np.array(dynamics.parameters.coulomb)
        self._viscous = np.array(dynamics.parameters.viscous)
        self._corrections: ModelCorrections | None = None
        self.events: list[DetectedFault] = []
        self.reset()

    def reset(self) -> None:
        """Start an episode: no history, no events."""
        self.events = []
        self.faulty = False
        self.suspect = False
        self.resynced = False
        self.quiet_samples = 0
        self._faulty_run = 0
        self.collision = False
        self.slipped = False
        self.force = np.zeros(3)
        self._k = -1
        self._angles: list[NDArray[np.float64]] = []  # the last two clean readings
        self._error = np.zeros(3)  # last good tracking error per joint (rad)
        self._raw_previous: NDArray[np.float64] | None = None
        self._stuck = np.zeros(3, dtype=int)
        self._after_stuck = np.zeros(3, dtype=bool)  # a stuck spell whose readings are still being replaced
        self._encoder_bad = np.zeros(3, dtype=bool)
        self._torque_previous: NDArray[np.float64] | None = None
        self._torque_bad = np.zeros(3, dtype=int)
        self._nan_active = np.zeros(6, dtype=bool)
        self._glitch_active = np.zeros(6, dtype=bool)
        self._drive_active = np.zeros(3, dtype=bool)
        self._shortfall = np.zeros(3)
        self._short_run = np.zeros(3, dtype=int)
        self._torque_measured = np.zeros(3)
        self._torque_implausible = np.zeros(3, dtype=bool)
        self._encoders_clean = self._torques_clean = False  # the scalar fast paths: nothing flagged on the last sample
        self._delayed.reset()
        self._quiet_until = -1
        self._force_evidence = 0.0
        self.collision_samples = 0
        self._held_since: int | None = None
        self.held_mass: float | None = None
        self._held_information = self._held_moment = 0.0
        self._evidence = 0.0
        self._slip_armed = False
        self._scatter = np.full(3, INITIAL_RESIDUAL_STD**2)

    def _detect(self, kind: str, joint: int | None, magnitude: float) -> None:
        self.events.append(DetectedFault(kind, self._k * CONTROL_PERIOD, joint, float(magnitude)))

    # -- sensors --------------------------------------------------------------------------------

    def _healthy_encoders(self, raw: NDArray[np.float64], rates: NDArray[np.float64]) -> bool:
        """The 1 kHz fast path, in scalars: nothing flagged before, and these readings finite, within the jump bound
        and not a suspect repeat. Then the full check would pass them unchanged."""
        if not self._encoders_clean or len(self._angles) < 2:
            return False
        r0, r1, r2 = raw.tolist()
        v0, v1, v2 = rates.tolist()
        if not math.isfinite(r0 + r1 + r2 + v0 + v1 + v2):
            return False
        (l0, l1, l2), (b0, b1, b2) = self._angles[0].tolist(), self._angles[1].tolist()
        bound = self._jump_bound
        if abs(r0 - 2.0 * l0 + b0) > bound or abs(r1 - 2.0 * l1 + b1) > bound or abs(r2 - 2.0 * l2 + b2) > bound:
            return False
        p0, p1, p2 = self._raw_previous.tolist()
        return r0 != p0 and r1 != p1 and r2 != p2  # a repeat: the full check decides whether it is suspect

    def _clean_encoders(self, observation: Observation) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raw = np.asarray(observation["joint_angles"], dtype=float)
        rates = np.asarray(observation["joint_velocities"], dtype=float)
        reference = observation["reference_angles"]
        if self._healthy_encoders(raw, rates):
            self._raw_previous = raw
            self._error = raw - reference
            self._angles = [raw, self._angles[0]]
            return raw, rates
        bad = ~np.isfinite(raw)
        # a NaN rate beside a finite reading follows a NaN reading (the rate is a backward difference): it is
        # recomputed below, and reported only when the reading before was finite
        rate_missing = ~bad & ~np.isfinite(rates)
        unexplained = rate_missing & (True if self._raw_previous is None else np.isfinite(self._raw_previous))
        for joint in np.flatnonzero((bad | unexplained) & ~self._nan_active[:3]):
            self._detect("sensor_nan", int(joint), math.nan)
        self._nan_active[:3] = bad | unexplained
        if len(self._angles) == 2:
            last, before = self._angles
            second_difference = raw - 2.0 * last + before
            # after a stuck spell, a reading that continues the one flagged before it at a plausible rate is the
            # joint's true position, not a glitch: accepted, so that the clean readings follow the joint again (a
            # glitch of several samples stays flagged: its readings continue each other but follow no stuck spell)
            repeated = raw == self._raw_previous
            continues = (
                self._glitch_active[:3]
                & self._after_stuck
                & ~repeated
                & (np.abs(raw - self._raw_previous - (last - before)) <= self._jump_bound)
            )
            jump = np.isfinite(raw) & (np.abs(second_difference) > self._jump_bound) & ~continues
            self.resynced = bool(continues.any())
            # a repeated reading is suspect while the joint was moving and its reference still moves several counts
            # per sample (at rest, or coming to rest, a reading repeats rightly)
            commanded = np.abs(observation["reference_velocities"]) * CONTROL_PERIOD >= self._stuck_step
            moving = np.abs(last - before) >= self._stuck_step
            # once stuck, a joint stays stuck while its reading repeats, whatever the reference does
            suspect = repeated & ((commanded & moving) | (self._stuck > 0))
            self._stuck = np.where(suspect, self._stuck + 1, 0)
            stuck = self._stuck >= STUCK_SAMPLES
            for joint in np.flatnonzero(jump & ~self._glitch_active[:3] & ~stuck):
                self._detect("encoder_glitch", int(joint), second_difference[joint])
            for joint in np.flatnonzero(self._stuck == STUCK_SAMPLES):
                self._detect("encoder_stuck", int(joint), math.nan)
            self._glitch_active[:3] = jump
            bad |= jump | stuck
            self._after_stuck = (self._after_stuck | stuck) & bad
        self._raw_previous = raw
        clean = np.where(bad, reference + self._error, raw)
        if bad.any() or self._encoder_bad.any() or rate_missing.any():
            # a rate from a replaced reading, or against one, or missing: the reference's, else the clean backward
            # difference
            reference_rates = observation["reference_velocities"]
            difference = (clean - self._angles[0]) / CONTROL_PERIOD if self._angles else reference_rates
            rederived = np.where(self._encoder_bad | rate_missing, difference, rates)
            rates = np.where(bad, reference_rates, rederived)
        else:
            self._error = raw - reference
        self._error = np.where(bad, self._error, clean - reference)
        self._encoder_bad = bad
        self._angles = [clean, *self._angles[:1]]
        self._encoders_clean = not (
            bad.any() or self._glitch_active[:3].any() or self._stuck.any() or self._nan_active[:3].any()
        )
        return clean, rates

    def _healthy_torques(self, torque: NDArray[np.float64], command: NDArray[np.float64]) -> bool:
        """The 1 kHz fast path, in scalars: nothing flagged before, and these torques finite, within the current
        loop's span and adding nothing to the drive-fault CUSUM. Then the full check would pass them unchanged."""
        if not self._torques_clean:
            return False
        peak, margin = self.peak_torque, TORQUE_MARGIN
        for now, last, asked, slowest_gain in zip(
            torque.tolist(), self._torque_measured.tolist(), command.tolist(), self._slowest_gain_list, strict=True
        ):
            if not math.isfinite(now):
                return False
            held = min(max(asked, -peak), peak)
            if now < min(last, held) - margin or now > max(last, held) + margin:
                return False
            step = held - last
            direction = (step > 0.0) - (step < 0.0) if abs(step) > margin else (held > 0.0) - (held < 0.0)
            if min((last + slowest_gain * step - now) * direction, DRIVE_FAULT_STEP) > DRIVE_FAULT_DRIFT:
                return False
        return True

    def _clean_torques(self, observation: Observation, command: NDArray[np.float64] | None) -> NDArray[np.float64]:
        torque = np.asarray(observation["joint_torques"], dtype=float)
        if command is not None and self._healthy_torques(torque, command):
            self._torque_previous = self._torque_measured = torque
            return torque
        finite = np.isfinite(torque)
        for joint in np.flatnonzero(~finite & ~self._nan_active[3:]):
            self._detect("sensor_nan", int(joint), math.nan)
        self._nan_active[3:] = ~finite
        previous = self._torque_previous
        if previous is None or command is None:
            clean = np.where(finite, torque, 0.0 if previous is None else previous)
            self._torque_previous = self._torque_measured = clean
            self._torques_clean = bool(finite.all())
            return clean
        held = np.clip(command, -self.peak_torque, self.peak_torque)
        predicted = previous + self._loop_gain * (held - previous)
        low = np.minimum(previous, held) - TORQUE_MARGIN
        high = np.maximum(previous, held) + TORQUE_MARGIN
        implausible = finite & ((torque < low) | (torque > high))
        self._torque_bad = np.where(implausible, self._torque_bad + 1, 0)
        for joint in np.flatnonzero(self._torque_bad == 1):
            self._detect("torque_glitch", int(joint), torque[joint] - predicted[joint])
        # A drive that does not deliver its command: implausible torques in a row, all short of the prediction (a
        # large loss), or a CUSUM of how far each reading falls short of what the slowest plausible current loop
        # would reach from the last reading (a loss too small for the span check); a span-implausible reading or
        # its successor adds nothing to the CUSUM.
        raw_previous = self._torque_measured
        direction = np.where(np.abs(held - raw_previous) > TORQUE_MARGIN, np.sign(held - raw_previous), np.sign(held))
        slowest = raw_previous + self._slowest_gain * (held - raw_previous)
        shortfall = np.minimum((slowest - torque) * direction, DRIVE_FAULT_STEP)
        usable = finite & ~implausible & ~self._torque_implausible
        self._shortfall = np.where(usable, np.maximum(0.0, self._shortfall + shortfall - DRIVE_FAULT_DRIFT), 0.0)
        self._short_run = np.where(implausible & (np.abs(torque) < np.abs(predicted)), self._short_run + 1, 0)
        large = self._short_run >= DRIVE_FAULT_SAMPLES
        for joint in np.flatnonzero((large | (self._shortfall > DRIVE_FAULT_EVIDENCE)) & ~self._drive_active):
            self._detect("drive_fault", int(joint), abs(predicted[joint]) - abs(torque[joint]))
            self._drive_active[joint] = True
        self._drive_active &= (self._shortfall > 0.0) | (self._torque_bad > 0)
        self._torque_implausible = implausible
        self._torque_measured = np.where(finite, torque, raw_previous)
        self._torques_clean = not (
            self._torque_bad.any()
            or self._nan_active[3:].any()
            or self._shortfall.any()
            or self._drive_active.any()
            or self._short_run.any()
        )
        clean = np.where(finite & ~implausible, torque, predicted)
        self._torque_previous = clean
        return clean

    # -- the model's residual -------------------------------------------------------------------

    def _check_model(self, angles: NDArray[np.float64], torque: NDArray[np.float64], holding: bool) -> None:
        delayed = self._delayed.update(angles, torque, holding, self._k <= self._quiet_until)
        if delayed is None:
            return
        state, torque_then, held_then, quiet = delayed
        try:
            tau0, phi, force_map = self.dynamics.torque_regressor_and_force_map(*state)
        except ValueError:  # a state the model cannot take (e.g. out of reach): no check
            return
        residual = torque_then - tau0
        if self._corrections is not None:
            residual = residual - self._correction(state, phi)
        self._check_payload(residual, phi, state[1], held_then, quiet)
        self._check_force(force_map, residual, phi, held_then, quiet)

    def set_corrections(self, corrections: ModelCorrections | None) -> None:
        """Take the model's corrections to this robot (fitted by a payload estimator on its empty moves) into the
        residual from now on; None uses the identified model as it is."""
        self._corrections = corrections

    def _correction(self, state: NDArray[np.float64], phi: NDArray[np.float64]) -> NDArray[np.float64]:
        """What the corrections add to the model's torque at ``state`` (N m), as :class:`ModelCorrections` says."""
        theta, theta_dot, theta_ddot = state
        dynamics, corrections = self.dynamics, self._corrections
        arm = dynamics.inertia * theta_ddot + dynamics.gravity_amplitude * np.cos(theta)
        friction = self._viscous * theta_dot + self._static_friction * np.sign(theta_dot)
        return (
            corrections.platform_mass * phi + corrections.arm_mass_scale * arm + corrections.friction_scale * friction
        )

    def _check_force(
        self,
        force_map: NDArray[np.float64],
        residual: NDArray[np.float64],
        phi: NDArray[np.float64],
        holding: bool,
        quiet: bool,
    ) -> None:
        """The collision check: a CUSUM of the platform force F = J^-T r over :data:`FORCE_REFERENCE`, r the model's
        residual less the mass held times phi (or, before the mass is known, without its part along phi)."""
        if quiet:
            self._force_evidence = 0.0
            self.collision = False
            return
        if holding and self.held_mass is not None:
            residual = residual - self.held_mass * phi
        elif holding:  # the mass is not known yet: leave out the part an unknown mass would explain
            information = float(phi @ phi)
            if information > 0.0:
                residual = residual - (residual @ phi) / information * phi
        force = force_map @ residual
        self.force = force
        magnitude = float(np.linalg.norm(force))
        self._force_evidence = max(0.0, self._force_evidence + magnitude - FORCE_REFERENCE)
        self.collision_samples = self.collision_samples + 1 if self._force_evidence > 0.0 else 0
        if self._force_evidence > FORCE_EVIDENCE and not self.collision:
            self._detect("collision", None, magnitude)
            self.collision = True
        elif self._force_evidence == 0.0 and self.collision:
            self.collision = False
            if self._held_since is not None and self._slip_armed:  # what the collision left in the mass held: afresh
                self._restart_held()

    def _check_payload(
        self,
        residual: NDArray[np.float64],
        phi: NDArray[np.float64],
        theta_dot: NDArray[np.float64],
        holding: bool,
        quiet: bool,
    ) -> None:
        """The slip check: a CUSUM of the log-likelihood ratio of "the object is gone" (r = e) against "the mass held
        since the pick is still there" (r = m phi + e), e weighted as the payload estimator weights it."""
        if not holding:
            self._held_since = None
            self.held_mass = None
            if not quiet:
                self._learn_scatter(residual, theta_dot)
            return
        if self._held_since is None:
            self._restart_held()
            self._slip_armed = True
        if quiet or not self._slip_armed:
            return
        if self.held_mass is not None:
            self._learn_scatter(residual - self.held_mass * phi, theta_dot)
        band = residual_std(theta_dot, self._static_friction, 0.0)
        weight = 1.0 / (band * band + self._scatter)
        information = float(np.sum(weight * phi * phi))
        moment = float(np.sum(weight * phi * residual))
        if (self._k - self._held_since) * CONTROL_PERIOD >= SLIP_SETTLE and self._held_information > 0.0:
            held = self._held_moment / self._held_information
            if self._held_information**-0.5 < HELD_MASS_STD:
                self.held_mass = held
            # test "gone" against "held" once the mass held is known well enough to tell them apart
            if held >= SLIP_MIN_MASS and self._held_information**-0.5 < SLIP_PRECISION * held:
                self._evidence = max(0.0, self._evidence + held * (0.5 * held * information - moment))
                if self._evidence > SLIP_EVIDENCE:
                    self._detect("slip", None, held)
                    self.slipped = True
                    self._slip_armed = False
                    self.held_mass = 0.0
                    return
        if self._force_evidence == 0.0:  # a collision's samples stay out of the mass held
            self._held_information += information
            self._held_moment += moment

    def _restart_held(self) -> None:
        """Measure the mass held afresh from this sample on (at a pick, or after a collision)."""
        self._held_since = self._k
        self._held_information = self._held_moment = self._evidence = 0.0
        self.held_mass = None

    def _learn_scatter(self, deviation: NDArray[np.float64], theta_dot: NDArray[np.float64]) -> None:
        """Follow the model's residual variance per joint while moving (N^2 m^2), at least the nominal's."""
        moving = np.abs(theta_dot) > FRICTION_VELOCITY
        learned = (1.0 - SCATTER_RATE) * self._scatter + SCATTER_RATE * deviation * deviation
        self._scatter = np.where(moving, np.maximum(learned, RESIDUAL_STD**2), self._scatter)

    # -- the step -------------------------------------------------------------------------------

    def update(self, observation: Observation, command: NDArray[np.float64] | None) -> dict[str, NDArray[np.float64]]:
        """Check one observation given the command (N m) sent after the previous one (None at the first); return
        the clean observation (a new dict; unchanged entries shared)."""
        self._k += 1
        self.slipped = False
        self.resynced = False
        angles, rates = self._clean_encoders(observation)
        torque = self._clean_torques(observation, command)
        self.faulty = bool(self._encoder_bad.any() or self._torque_bad.any() or self._nan_active.any())
        self.suspect = bool(self._stuck.any())
        self._faulty_run = self._faulty_run + 1 if self.faulty else 0
        # A lone replaced reading is as good as the reading (the reference plus the tracking error a millisecond ago,
        # or the current loop's prediction): the model's equations keep it. Replacements in a row drift from the
        # joint (a stuck encoder: the joint runs on its feedforward), so they and the smoother's lag after them are
        # left out, as is a repeated reading not yet called stuck, and the smoother's window after a step back.
        if self.resynced:
            self.quiet_samples = RESYNC_QUIET
        elif self.suspect or self._faulty_run > 1:
            self.quiet_samples = SENSOR_QUIET
        else:
            self.quiet_samples = 0
        if self.quiet_samples:
            self._quiet_until = max(self._quiet_until, self._k + self.quiet_samples)
        holding = observation["gripper"].item(0) > 0.5
        self._check_model(angles, torque, holding)
        clean = dict(observation)
        clean["joint_angles"], clean["joint_velocities"], clean["joint_torques"] = angles, rates, torque
        return clean


MONITOR_JERK_STD = SMOOTHER_JERK_STD
"""Jerk standard deviation (rad/s^3) of the monitor's fixed-lag smoother of the clean angles: the offline smoother's,
a third of the payload estimator's (:data:`~controllers.estimation.FIXED_LAG_JERK_STD`). The residual force and the
slip check sum evidence over many samples, which a sample's lag at a jerk step hardly moves, while the acceleration
noise of a higher value enters the force through the whole inertia; the monitor's thresholds were set, and its
campaigns and soak measured, with this value (docs/measurements.md, "Faults")."""


class _DelayedState:
    """A joint-state smoother with the readings it lags behind: pairs each smoothed state with its sample's torque,
    gripper and quiet flag, at the instant the torque was measured."""

    def __init__(self, lag: int) -> None:
        self._smoother = JointStateSmoother(lag=lag, jerk_std=MONITOR_JERK_STD)
        self.lag = lag
        self.reset()

    def reset(self) -> None:
        self._started = False
        self._previous: NDArray[np.float64] | None = None
        self._pending: collections.deque[tuple[NDArray[np.float64], bool, bool]] = collections.deque()

    def update(
        self, angles: NDArray[np.float64], torque: NDArray[np.float64], holding: bool, quiet: bool
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], bool, bool] | None:
        """Take one reading; return (state (3, 3) at the torque's instant, torque, holding, quiet) of the reading
        ``lag`` samples ago, or None while the smoother fills."""
        if not self._started:
            self._smoother.reset(angles)
            self._started = True
        # the smoother's buffers alternate: the previous call's state holds through this call
        state = self._smoother.update_state(angles)
        previous, self._previous = self._previous, state
        self._pending.append((torque, holding, quiet))
        if len(self._pending) <= self.lag:
            return None
        torque_then, held_then, quiet_then = self._pending.popleft()
        quiet_then = quiet_then or quiet  # a faulty reading found since also lies in this state's smoothing window
        # the torque was measured MEASURED_TORQUE_DELAY before the encoder sample of its state
        at_torque = state if previous is None else state - _TORQUE_AGE * (state - previous)
        return at_torque, torque_then, held_then, quiet_then


SLOW_RATE = 0.5
"""Speed override (of the reference's speed) a ``"slow"`` reaction (:data:`~delta_env.faults.FAULT_REACTIONS`)
asks for."""

ROLLBACK_SAMPLES = 10
"""How far back (samples beyond the monitor's lag) a detected collision can undo the payload estimator's updates."""

REACTING_KINDS = ("collision", "slip", "drive_fault")
"""The detected faults a reaction answers; sensor faults are replaced and the work goes on."""


class MonitoredController:
    """Any controller behind a :class:`FaultMonitor`: it sees clean observations only, its payload estimator leaves
    out the equations that lean on drifting replacements or a collision and forgets the object on a slip, and a
    detected fault may ask the cell to slow down or stop.

    Args:
        controller: The controller to protect.
        monitor: Its monitor.
        reaction: One of :data:`FAULT_REACTIONS`.

    Attributes:
        requested_speed: The speed override (a fraction of the reference's speed) the controller asks the cell for:
            1 until a reaction asks for less.
    """

    def __init__(
        self,
        controller: Controller,
        monitor: FaultMonitor,
        reaction: Literal["continue", "slow", "stop"] = "continue",
    ) -> None:
        if reaction not in FAULT_REACTIONS:
            raise ValueError(f"reaction must be one of {list(FAULT_REACTIONS)}, got {reaction!r}")
        self.controller = controller
        self.monitor = monitor
        self.reaction = reaction
        self.name = controller.name
        self.requested_speed = 1.0
        self._command: NDArray[np.float64] | None = None
        self._holding = False
        self._checkpoints = monitor.lag + ROLLBACK_SAMPLES
        if self.estimator is not None:
            self.estimator.keep_checkpoints(self._checkpoints)

    @property
    def detected_faults(self) -> Sequence[DetectedFault]:
        return self.monitor.events

    @property
    def payload_estimate(self) -> float:
        return getattr(self.controller, "payload_estimate", 0.0)

    @property
    def estimator(self) -> PayloadEstimator | None:
        """The inner controller's payload estimator, or None."""
        return getattr(self.controller, "estimator", None)

    def reset(self) -> None:
        self.controller.reset()
        self.monitor.reset()
        self.requested_speed = 1.0
        self._command = None
        self._holding = False
        self.monitor.set_corrections(None)

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        monitor = self.monitor
        seen = len(monitor.events)
        estimator = self.estimator
        holding = observation["gripper"].item(0) > 0.5
        if holding and not self._holding and estimator is not None and estimator.fits_corrections:
            monitor.set_corrections(estimator.corrections)  # what the empty moves so far say of this robot
        self._holding = holding
        clean = monitor.update(observation, self._command)
        new = monitor.events[seen:]
        if estimator is not None:
            if any(event.kind == "collision" for event in new):
                # the collision's first samples entered before it was detected: undo them
                undo = min(self._checkpoints, monitor.lag - estimator.delay + monitor.collision_samples + 1)
                if undo > 0:
                    estimator.rollback(undo)
            if monitor.quiet_samples:
                estimator.skip(monitor.quiet_samples)
            if monitor.collision:
                estimator.skip(SENSOR_QUIET)
            if monitor.slipped:
                estimator.drop_object()
        if self.reaction != "continue" and any(event.kind in REACTING_KINDS for event in new):
            self.requested_speed = min(self.requested_speed, SLOW_RATE if self.reaction == "slow" else 0.0)
        self._command = np.asarray(self.controller(clean), dtype=float)
        return self._command
