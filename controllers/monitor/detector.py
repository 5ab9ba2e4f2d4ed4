"""The fault monitor's detector: checks each observation and returns it clean (the package docstring names the
checks; docs/design.md section 6, "Fault monitor")."""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import SMOOTHER_LAG, JointStateSmoother
from controllers.monitor.compiled import (
    correction_terms,
    learn_scatter,
    loop_output,
    model_residual,
    platform_force,
    slip_moments,
    torque_step_variance,
    torques_plausible,
)
from controllers.monitor.events import DetectedFault
from controllers.monitor.tuning import (
    ACCELERATION_FACTOR,
    BREAKAWAY_FACTOR,
    DRIVE_FAULT_DRIFT,
    DRIVE_FAULT_EVIDENCE,
    DRIVE_FAULT_SAMPLES,
    DRIVE_FAULT_STEP,
    FORCE_EVIDENCE,
    FORCE_REFERENCE,
    HELD_MASS_STD,
    INITIAL_RESIDUAL_STD,
    MONITOR_JERK_STD,
    REST_RATE,
    RESYNC_QUIET,
    SCATTER_RATE,
    SENSOR_QUIET,
    SLIP_EVIDENCE,
    SLIP_MIN_MASS,
    SLIP_PRECISION,
    SLIP_SETTLE,
    SLOWEST_LAG_FACTOR,
    STUCK_COUNTS,
    STUCK_SAMPLES,
    TORQUE_MARGIN,
)
from controllers.payload import FRICTION_VELOCITY, RESIDUAL_STD, TORQUE_AGE, ModelCorrections, residual_std
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD
from delta_env.validation import require_in, require_positive


def loop_response(lags: Sequence[float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(hold, keep) per joint of a first-order current loop of time constant ``lags`` (s; 0 for none) over one
    control period whose torque reading is :data:`~controllers.payload.TORQUE_AGE` periods old: the reading lags
    the command's change by that much, so the loop ran that long towards the command held before, then the rest of
    the period towards the one held since (:func:`loop_output`). hold = exp(-(1 - age) T / lag), keep =
    exp(-T / lag)."""
    hold = [math.exp(-(1.0 - TORQUE_AGE) * CONTROL_PERIOD / lag) if lag > 0 else 0.0 for lag in lags]
    keep = [math.exp(-CONTROL_PERIOD / lag) if lag > 0 else 0.0 for lag in lags]
    return np.array(hold), np.array(keep)


class FaultMonitor:
    """Checks each observation for faults and returns it cleaned; see :mod:`controllers.monitor`.

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
        self._loop_response = loop_response(lags)
        self._slowest_response = loop_response([SLOWEST_LAG_FACTOR * lag for lag in lags])
        self._delayed = _DelayedState(SMOOTHER_LAG)
        self.lag = SMOOTHER_LAG
        """Readings between a sample and the model's checks at it (the smoother's lag)."""
        self._static_friction = np.array(dynamics.parameters.coulomb)
        self.set_corrections(None)
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
        self._command_before: NDArray[np.float64] | None = None  # the command held before the last one
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

    def _healthy_encoders(
        self, raw: NDArray[np.float64], rates: NDArray[np.float64], reference_rates: NDArray[np.float64]
    ) -> bool:
        """The 1 kHz fast path, in scalars: nothing flagged before, and these readings finite, within the jump bound
        and not a suspect repeat. Then the full check would pass them unchanged."""
        if not self._encoders_clean or len(self._angles) < 2:
            return False
        r0, r1, r2 = raw.tolist()
        v0, v1, v2 = rates.tolist()
        if not math.isfinite(r0 + r1 + r2 + v0 + v1 + v2):
            return False
        last, before = self._angles[0].tolist(), self._angles[1].tolist()
        (l0, l1, l2), (b0, b1, b2) = last, before
        bound = self._jump_bound
        if abs(r0 - 2.0 * l0 + b0) > bound or abs(r1 - 2.0 * l1 + b1) > bound or abs(r2 - 2.0 * l2 + b2) > bound:
            return False
        previous = self._raw_previous.tolist()
        if r0 != previous[0] and r1 != previous[1] and r2 != previous[2]:
            return True
        # a repeat is suspect (the full check's) while the joint was moving and its reference moves several counts
        # per sample; nothing is stuck while the readings are clean
        step = self._stuck_step
        for reading, previous_reading, angle, angle_before, reference_rate in zip(
            (r0, r1, r2), previous, last, before, reference_rates.tolist(), strict=True
        ):
            if (
                reading == previous_reading
                and abs(reference_rate) * CONTROL_PERIOD >= step
                and abs(angle - angle_before) >= step
            ):
                return False
        return True

    def _clean_encoders(self, observation: Observation) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raw = np.asarray(observation["joint_angles"], dtype=float)
        rates = np.asarray(observation["joint_velocities"], dtype=float)
        reference = observation["reference_angles"]
        if self._healthy_encoders(raw, rates, observation["reference_velocities"]):
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

    def _healthy_torques(
        self, torque: NDArray[np.float64], command: NDArray[np.float64], before: NDArray[np.float64]
    ) -> bool:
        """The 1 kHz fast path, compiled: nothing flagged before, and these torques finite, within the current
        loop's span and adding nothing to the drive-fault CUSUM. Then the full check would pass them unchanged."""
        return self._torques_clean and torques_plausible(
            torque,
            self._torque_measured,
            command,
            before,
            *self._slowest_response,
            self.peak_torque,
            TORQUE_MARGIN,
            DRIVE_FAULT_DRIFT,
            DRIVE_FAULT_STEP,
        )

    def _clean_torques(
        self, observation: Observation, command: NDArray[np.float64] | None, before: NDArray[np.float64] | None
    ) -> NDArray[np.float64]:
        """The torque readings, checked against the current loop driven by ``before`` (N m) for the reading's age
        (:data:`~controllers.payload.TORQUE_AGE`) past the last reading, then by ``command`` (:func:`loop_output`);
        faulty ones replaced by the loop's prediction."""
        torque = np.asarray(observation["joint_torques"], dtype=float)
        if command is not None and self._healthy_torques(torque, command, before):
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
            self._torques_clean = bool(finite.all()) and not self._torque_bad.any()
            return clean
        held = np.clip(command, -self.peak_torque, self.peak_torque)
        before = np.clip(before, -self.peak_torque, self.peak_torque)
        predicted = loop_output(previous, before, held, *self._loop_response)
        low = np.minimum(np.minimum(previous, held), before) - TORQUE_MARGIN
        high = np.maximum(np.maximum(previous, held), before) + TORQUE_MARGIN
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
        slowest = loop_output(raw_previous, before, held, *self._slowest_response)
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

    def _check_model(
        self, angles: NDArray[np.float64], reference: NDArray[np.float64], torque: NDArray[np.float64], holding: bool
    ) -> None:
        delayed = self._delayed.update(angles, reference, torque, holding, self._k <= self._quiet_until)
        if delayed is None:
            return
        state, previous, torque_then, held_then, quiet, jerk_variance = delayed
        # the torque was measured TORQUE_AGE periods (MEASURED_TORQUE_DELAY) before the encoder sample of its state
        status, terms = model_residual(
            self.dynamics.model_constants, state, previous, TORQUE_AGE, torque_then, self._correction_terms
        )
        if status != kernels.VALID:  # a state the model cannot take (e.g. out of reach): no check
            return
        self._check_payload(terms, held_then, quiet, jerk_variance)
        self._check_force(terms, held_then, quiet)

    def set_corrections(self, corrections: ModelCorrections | None) -> None:
        """Take the model's corrections to this robot (fitted by a payload estimator on its empty moves) into the
        residual from now on; None uses the identified model as it is."""
        dynamics = self.dynamics
        self._correction_terms = correction_terms(
            corrections,
            dynamics.inertia,
            dynamics.gravity_amplitude,
            dynamics.parameters.viscous,
            dynamics.parameters.coulomb,
        )
        # the Coulomb friction the residual charges (the corrections scale the model's friction by 1 + s_i), and
        # the breakaway friction a joint at rest may hold
        scale = 1.0 if corrections is None else 1.0 + np.asarray(corrections.friction_scale, dtype=float)
        self._charged_coulomb = np.array(dynamics.parameters.coulomb) * scale
        self._breakaway = BREAKAWAY_FACTOR * np.maximum(self._charged_coulomb, 0.0)

    def _check_force(self, terms: NDArray[np.float64], holding: bool, quiet: bool) -> None:
        """The collision check: a CUSUM of the platform force F = J^-T r over :data:`FORCE_REFERENCE`, r the model's
        residual (``terms`` of :func:`model_residual`) less the mass held times phi (or, before the mass is known,
        without its part along phi), less on joints slower than :data:`REST_RATE` what friction up to the breakaway
        can hold."""
        if quiet:
            self._force_evidence = 0.0
            self.collision = False
            return
        held_mass = self.held_mass
        self.force, magnitude = platform_force(
            terms,
            0.0 if held_mass is None else held_mass,
            holding and held_mass is not None,
            holding,
            self._charged_coulomb,
            self._breakaway,
            REST_RATE,
        )
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
        self, terms: NDArray[np.float64], holding: bool, quiet: bool, jerk_variance: NDArray[np.float64]
    ) -> None:
        """The slip check: a CUSUM of the log-likelihood ratio of "the object is gone" (r = e) against "the mass held
        since the pick is still there" (r = m phi + e), e weighted as the payload estimator weights it; r and phi
        are ``terms`` of :func:`model_residual`."""
        if not holding:
            self._held_since = None
            self.held_mass = None
            if not quiet:
                self._learn_scatter(terms, 0.0)
            return
        if self._held_since is None:
            self._restart_held()
            self._slip_armed = True
        if quiet or not self._slip_armed:
            return
        if self.held_mass is not None:
            self._learn_scatter(terms, self.held_mass)
        band = residual_std(terms[2], self._static_friction, 0.0)
        information, moment = slip_moments(terms, band, self._scatter + jerk_variance)
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

    def _learn_scatter(self, terms: NDArray[np.float64], held_mass: float) -> None:
        """Follow the model's residual variance per joint while moving (N^2 m^2), at least the nominal's: of r -
        ``held_mass`` phi (kg; 0 for the residual itself), r and phi ``terms`` of :func:`model_residual`."""
        learn_scatter(self._scatter, terms, held_mass, FRICTION_VELOCITY, SCATTER_RATE, RESIDUAL_STD**2)

    # -- the step -------------------------------------------------------------------------------

    def update(self, observation: Observation, command: NDArray[np.float64] | None) -> dict[str, NDArray[np.float64]]:
        """Check one observation given the command (N m) sent after the previous one (None at the first); return
        the clean observation (a new dict; unchanged entries shared)."""
        self._k += 1
        self.slipped = False
        self.resynced = False
        angles, rates = self._clean_encoders(observation)
        if command is not None:
            command = np.array(command, dtype=float)  # kept as the next step's command before
        torque = self._clean_torques(
            observation, command, command if self._command_before is None else self._command_before
        )
        self._command_before = command
        if self._encoders_clean and self._torques_clean:  # nothing replaced, missing or repeated: no array to scan
            self.faulty = self.suspect = False
        else:
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
        reference = np.array(
            (
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
            )
        )
        self._check_model(angles, reference, torque, holding)
        clean = dict(observation)
        clean["joint_angles"], clean["joint_velocities"], clean["joint_torques"] = angles, rates, torque
        return clean


class _DelayedState:
    """A joint-state smoother with the readings it lags behind: pairs each smoothed state with its sample's torque,
    gripper and quiet flag, at the instant the torque was measured, and with the variance its acceleration's error
    puts into the model's torque.

    It smooths the tracking error, the angles less the reference, and adds the reference's own state back: the
    reference is known, so the smoother's motion model (white jerk) carries only the error's jerk; a smoother of the
    angles themselves lags the planned jerk of time-optimal moves (docs/design.md section 6, "Fault monitor").

    Where the error's acceleration still steps (a controller that steps its torque, as the residual policy does every
    10 ms), the smoother smears the step over its window: a step da between readings m - 1 and m leaves the
    estimated sample's acceleration off by h_m da, h the smoother's response to a unit step. The joint's torque steps
    with its acceleration (I da), so the measured torque's steps in the window give the model torque's error variance
    sum_m h_m^2 (tau_m - tau_{m-1})^2 (N^2 m^2), per joint.
    """

    def __init__(self, lag: int) -> None:
        self._smoother = JointStateSmoother(lag=lag, jerk_std=MONITOR_JERK_STD)
        self.lag = lag
        self._squared_response = _acceleration_step_response(self._smoother) ** 2
        self._torques = np.zeros((len(self._squared_response) + 1, 3))  # the window's torques and the one before
        self.reset()

    def reset(self) -> None:
        self._started = False
        self._previous: NDArray[np.float64] | None = None
        self._pending: collections.deque[tuple[NDArray[np.float64], NDArray[np.float64], bool, bool]] = (
            collections.deque()
        )

    def update(
        self,
        angles: NDArray[np.float64],
        reference: NDArray[np.float64],
        torque: NDArray[np.float64],
        holding: bool,
        quiet: bool,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], bool, bool, NDArray[np.float64]] | None:
        """Take one reading (rad) with its reference's state (3, 3) (rows angle, rate, acceleration: rad, rad/s,
        rad/s^2) and its measured torque (N m); return (smoothed state (3, 3), the one before (itself at the first),
        torque, holding, quiet, the variance (N^2 m^2, (3,)) of the model torque's error from the acceleration's
        steps) of the reading ``lag`` samples ago, or None while the smoother fills."""
        error = angles - reference[0]
        torques = self._torques
        if not self._started:
            self._smoother.reset(error)
            torques[:] = torque
            self._started = True
        smoothed_error = self._smoother.update_state(error)
        jerk_variance = torque_step_variance(torques, torque, self._squared_response)
        self._pending.append((reference, torque, holding, quiet))
        if len(self._pending) <= self.lag:
            return None
        reference_then, torque_then, held_then, quiet_then = self._pending.popleft()
        state = reference_then + smoothed_error
        previous, self._previous = self._previous, state
        quiet_then = quiet_then or quiet  # a faulty reading found since also lies in this state's smoothing window
        return state, state if previous is None else previous, torque_then, held_then, quiet_then, jerk_variance


def _acceleration_step_response(smoother: JointStateSmoother) -> NDArray[np.float64]:
    """The error of ``smoother``'s acceleration estimate (per rad/s^2) when the acceleration steps by 1 rad/s^2
    between readings m - 1 and m of its window, for each m (oldest first; m = 0 steps before the window)."""
    readings = smoother.weights.shape[1]
    estimated = smoother.history  # the window's reading whose state the smoother returns
    times = (np.arange(readings) - estimated) * CONTROL_PERIOD
    response = np.empty(readings)
    for m in range(readings):
        start = (m - estimated - 0.5) * CONTROL_PERIOD
        angles = np.where(times > start, 0.5 * (times - start) ** 2, 0.0)
        response[m] = smoother.weights[2] @ angles - (1.0 if estimated >= m else 0.0)
    return response
