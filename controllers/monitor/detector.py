"""The fault monitor's detector: checks each observation and returns it clean (the package docstring names the
checks; docs/design.md section 6, "Fault monitor")."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.monitor.compiled import correction_terms, encoders_plausible, loop_output, torques_plausible
from controllers.monitor.events import DetectedFault
from controllers.monitor.model_check import (
    COLLIDED,
    COLLIDING,
    NOT_HEALTHY,
    SENSORS,
    SLIPPED,
    ModelCheck,
    healthy_sample,
)
from controllers.monitor.tuning import (
    ACCELERATION_FACTOR,
    BREAKAWAY_FACTOR,
    DRIVE_FAULT_DRIFT,
    DRIVE_FAULT_EVIDENCE,
    DRIVE_FAULT_SAMPLES,
    DRIVE_FAULT_STEP,
    RESYNC_QUIET,
    SENSOR_QUIET,
    SLOWEST_LAG_FACTOR,
    STUCK_COUNTS,
    STUCK_SAMPLES,
    TORQUE_MARGIN,
)
from controllers.payload import TORQUE_AGE, ModelCorrections
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
        self._model_check = ModelCheck(dynamics.parameters.coulomb)
        # the sensor state of the whole-sample fast path (healthy_sample), which holds it while readings stay clean
        self._sensor_bytes = np.zeros(1, dtype=SENSORS).view(np.uint8)
        self._sensors = self._sensor_bytes.view(SENSORS)
        self._sensors["jump_bound"], self._sensors["stuck_step"] = self._jump_bound, self._stuck_step
        self._sensors["slowest_hold"], self._sensors["slowest_keep"] = self._slowest_response
        self._sensors["peak_torque"] = self.peak_torque
        self.lag = self._model_check.lag
        """Readings between a sample and the model's checks at it (the smoother's lag)."""
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
        self._model_check.reset()
        self._quiet_until = -1
        self._sensors_fast = False  # whether the sensor state is the record's (the whole-sample fast path's)

    @property
    def force(self) -> NDArray[np.float64]:
        """The last estimate of the external force on the platform (N), (3,)."""
        return self._model_check.force

    @property
    def collision_samples(self) -> int:
        """Checked samples since the collision evidence began to grow (0 while there is none)."""
        return self._model_check.collision_samples

    @property
    def held_mass(self) -> float | None:
        """The mass (kg) the slip check believes held (see the class docstring), or None."""
        return self._model_check.held_mass

    def _detect(self, kind: str, joint: int | None, magnitude: float) -> None:
        self.events.append(DetectedFault(kind, self._k * CONTROL_PERIOD, joint, float(magnitude)))

    # -- sensors --------------------------------------------------------------------------------

    def _healthy_encoders(
        self, raw: NDArray[np.float64], rates: NDArray[np.float64], reference_rates: NDArray[np.float64]
    ) -> bool:
        """The 1 kHz fast path, compiled: nothing flagged before, and these readings finite, within the jump bound
        and not a suspect repeat (nothing is stuck while the readings are clean). Then the full check would pass
        them unchanged."""
        return (
            self._encoders_clean
            and len(self._angles) == 2
            and encoders_plausible(
                raw,
                rates,
                self._angles[0],
                self._angles[1],
                self._raw_previous,
                reference_rates,
                self._jump_bound,
                self._stuck_step,
                CONTROL_PERIOD,
            )
        )

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
            # a suspect reading is replaced like a stuck one: the error held through a stuck spell is then the
            # last one measured, not the spell's first repeats (which an integral would wind up on)
            bad |= jump | suspect
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

    def _check_model(self, angles: NDArray[np.float64], observation: Observation, torque: NDArray[np.float64]) -> None:
        """The collision and slip checks (:class:`~controllers.monitor.model_check.ModelCheck`) a smoother's lag
        behind this clean reading (rad) and torque (N m)."""
        found = self._model_check.check(
            self.dynamics.model_constants,
            self._correction_terms,
            angles,
            (
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
            ),
            torque,
            observation["gripper"].item(0) > 0.5,
            self._k <= self._quiet_until,
            self._k,
        )
        self._model_found(found)

    def _model_found(self, found: int) -> None:
        """Take the model checks' result bits (:func:`~controllers.monitor.model_check.check_sample`)."""
        self.collision = bool(found & COLLIDING)
        if found & SLIPPED:
            self._detect("slip", None, self._model_check.slip_mass)
            self.slipped = True
        if found & COLLIDED:
            self._detect("collision", None, self._model_check.force_magnitude)

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
        charged_coulomb = np.array(dynamics.parameters.coulomb) * scale
        self._model_check.set_friction(charged_coulomb, BREAKAWAY_FACTOR * np.maximum(charged_coulomb, 0.0))

    # -- the step -------------------------------------------------------------------------------

    def update(self, observation: Observation, command: NDArray[np.float64] | None) -> dict[str, NDArray[np.float64]]:
        """Check one observation given the command (N m) sent after the previous one (None at the first); return
        the clean observation (a new dict; unchanged entries shared)."""
        self._k += 1
        self.slipped = False
        self.resynced = False
        if command is not None:
            command = np.array(command, dtype=float)  # kept as the next step's command before
        if self._sensors_fast:
            clean = None if command is None else self._healthy_sample(observation, command)
            if clean is not None:
                return clean
            self._load_sensors()  # the full checks below take the sensor state back
        angles, rates = self._clean_encoders(observation)
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
        self._check_model(angles, observation, torque)
        self._sensors_fast = (
            self._encoders_clean
            and self._torques_clean
            and len(self._angles) == 2
            and self._raw_previous is not None
            and self._command_before is not None
        )
        if self._sensors_fast:
            self._store_sensors()
        clean = dict(observation)
        clean["joint_angles"], clean["joint_velocities"], clean["joint_torques"] = angles, rates, torque
        return clean

    def _healthy_sample(
        self, observation: Observation, command: NDArray[np.float64]
    ) -> dict[str, NDArray[np.float64]] | None:
        """The whole sample in one compiled call (:func:`~controllers.monitor.model_check.healthy_sample`) while the
        last one flagged nothing: its clean observation, or None (nothing changed) for readings the fast paths do not
        pass."""
        raw = np.asarray(observation["joint_angles"], dtype=float)
        rates = np.asarray(observation["joint_velocities"], dtype=float)
        torque = np.asarray(observation["joint_torques"], dtype=float)
        found = healthy_sample(
            self._sensor_bytes,
            self._model_check.state,
            self.dynamics.model_constants,
            self._correction_terms,
            raw,
            rates,
            observation["reference_angles"],
            observation["reference_velocities"],
            observation["reference_accelerations"],
            torque,
            command,
            observation["gripper"].item(0) > 0.5,
            self._k <= self._quiet_until,
            self._k,
        )
        if found == NOT_HEALTHY:
            return None
        self.faulty = self.suspect = False
        self._faulty_run = self.quiet_samples = 0
        self._model_found(found)
        clean = dict(observation)
        clean["joint_angles"], clean["joint_velocities"], clean["joint_torques"] = raw, rates, torque
        return clean

    def _store_sensors(self) -> None:
        """Hand the sensor state to the whole-sample fast path's record."""
        sensors = self._sensors
        sensors["last"], sensors["before"] = self._angles
        sensors["raw_previous"], sensors["error"] = self._raw_previous, self._error
        sensors["torque_measured"], sensors["command_before"] = self._torque_measured, self._command_before

    def _load_sensors(self) -> None:
        """Take the sensor state back from the whole-sample fast path's record, for the full checks."""
        sensors = self._sensors[0]
        self._angles = [sensors["last"].copy(), sensors["before"].copy()]
        self._raw_previous, self._error = sensors["raw_previous"].copy(), sensors["error"].copy()
        self._torque_previous = self._torque_measured = sensors["torque_measured"].copy()
        self._command_before = sensors["command_before"].copy()
        self._sensors_fast = False
