"""The fault monitor's sensor checks, compiled: the encoder and torque plausibility checks of each sample on the
monitor's state record (docs/design.md section 6, "Fault monitor"; the checks are listed in the package docstring).

:data:`SENSOR_FIELDS` are the fields of the record (:data:`~controllers.monitor.step.MONITOR`) that these checks
keep; :func:`clean_encoders` and :func:`clean_torques` read a sample's readings, write its clean ones into the
record's ``clean`` rows and record what they detect with :func:`record_event`.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.compiled_model import single_sample_model
from controllers.monitor.compiled import loop_output, shift_in
from controllers.monitor.tuning import (
    DRIVE_FAULT_DRIFT,
    DRIVE_FAULT_EVIDENCE,
    DRIVE_FAULT_SAMPLES,
    DRIVE_FAULT_STEP,
    DRIVE_FAULT_WINDOW,
    STUCK_COUNTS,
    STUCK_SAMPLES,
    TORQUE_MARGIN,
    TURN_HISTORY,
)
from delta_env.faults import FAULT_KINDS
from delta_env.sensors import CONTROL_PERIOD

SENSOR_NAN, ENCODER_GLITCH, ENCODER_STUCK, TORQUE_GLITCH, DRIVE_FAULT = (
    FAULT_KINDS.index(kind)
    for kind in ("sensor_nan", "encoder_glitch", "encoder_stuck", "torque_glitch", "drive_fault")
)
"""Codes of the kinds these checks detect: their indices in :data:`~delta_env.faults.FAULT_KINDS`."""

ANGLES_REPLACED, RATES_REPLACED, TORQUES_REPLACED = 1, 2, 4
"""Bits of the checks' results: the clean row differs from the sample's reading (a new array is due)."""

SENSOR_FIELDS = [
    # the encoders: the last three clean readings (how many there are, up to 3), the last raw one (if any) and the
    # last good tracking error (rad); per joint, repeated readings in a suspect run, a stuck spell whose readings are
    # still being replaced, and whether the last reading was replaced
    ("clean_count", np.int64),
    ("last", np.float64, (3,)),
    ("before", np.float64, (3,)),
    ("earlier", np.float64, (3,)),
    ("raw_known", np.bool_),
    ("raw_previous", np.float64, (3,)),
    ("error", np.float64, (3,)),
    ("stuck", np.int64, (3,)),
    # per joint, since its reading last changed: its repeats, the tracking error (rad) where it stopped, and the
    # speed (rad/s) and travel (rad) that the torque beyond what rest absorbs gave it since
    ("rest_repeats", np.int64, (3,)),
    ("rest_error", np.float64, (3,)),
    ("rest_speed", np.float64, (3,)),
    ("rest_travel", np.float64, (3,)),
    # per joint, over the same repeats: the bounds (rad/s^2) of its acceleration at the last sample, the speed
    # (rad/s) it may have had where its reading stopped changing, and the bounds of what its acceleration since has
    # added to its speed (rad/s) and to its travel (rad) beyond that speed's; whether those bounds are known
    ("turn_acceleration", np.float64, (3, 2)),
    ("turn_speed", np.float64, (3, 2)),
    ("turn_speed_change", np.float64, (3, 2)),
    ("turn_travel", np.float64, (3, 2)),
    ("turn_known", np.uint8, (3,)),
    # the last TURN_HISTORY + 2 clean angles (rad) and whether each was replaced, and the last TURN_HISTORY + 1
    # torques (N m) the drives delivered (oldest first), how many there are
    ("turn_angles", np.float64, (TURN_HISTORY + 2, 3)),
    ("turn_replaced", np.uint8, (TURN_HISTORY + 2, 3)),
    ("turn_torques", np.float64, (TURN_HISTORY + 1, 3)),
    ("turn_samples", np.int64),
    # whether (c) may run: not on drives with backlash, whose rotors turn inside the band against their own inertia,
    # beyond the model's bounds
    ("turn_check", np.uint8),
    ("after_stuck", np.uint8, (3,)),  # flags (numba has no boolean subarrays)
    ("encoder_bad", np.uint8, (3,)),
    ("glitch_active", np.uint8, (3,)),
    ("nan_active", np.uint8, (6,)),  # the encoders', then the torques'
    # the torques (N m): the last clean reading (if any), the last measured one, the command held before the last
    # one (if any); per joint, implausible readings in a row, the last reading's implausibility, the drive-fault
    # CUSUM, implausible readings short of the prediction in a row, and a drive fault under way
    ("torque_known", np.bool_),
    ("torque_previous", np.float64, (3,)),
    ("torque_measured", np.float64, (3,)),
    ("command_known", np.bool_),
    ("command_before", np.float64, (3,)),
    ("torque_bad", np.int64, (3,)),
    ("torque_implausible", np.uint8, (3,)),
    ("shortfall", np.float64, (3,)),
    ("short_run", np.int64, (3,)),
    ("held_glitch", np.float64, (3,)),  # the deviation of a reading short of the prediction, its report held back
    ("drive_active", np.uint8, (3,)),
    ("delivering", np.int64, (3,)),  # readings in a row that meet the loop's prediction, during a drive fault
    ("drive_ended", np.bool_),  # a drive fault ended on this sample: the torque steps back to the command
    # the loop's integral check: the commands held (N m) at the last DRIVE_FAULT_WINDOW + 1 readings and their clean
    # torques (oldest first), how many there are, and per joint whether the window shows a fault (its excess went
    # beyond the evidence and has not been nil since)
    ("loop_commands", np.float64, (DRIVE_FAULT_WINDOW + 1, 3)),
    ("loop_torques", np.float64, (DRIVE_FAULT_WINDOW + 1, 3)),
    ("loop_count", np.int64),
    ("loop_over", np.uint8, (3,)),
    # constants: the encoder jump bound and stuck step (rad), the current loop's and the slowest healthy one's
    # (hold, keep) of detector.loop_response, the drive's peak torque (N m)
    ("jump_bound", np.float64),
    ("stuck_step", np.float64),
    ("loop_response", np.float64, (2, 3)),
    ("slowest_response", np.float64, (2, 3)),
    ("peak_torque", np.float64),
]
"""The fields of the monitor's record that the sensor checks keep, beside the sample's (``reference``, ``clean``,
``resynced`` and the events that :func:`record_event` adds)."""


@numba.njit(cache=True)
def record_event(state: np.record, kind: int, joint: int, magnitude: float) -> None:
    """Add a detection of this sample to ``state``'s events: ``kind`` an index in
    :data:`~delta_env.faults.FAULT_KINDS`, ``joint`` 0..2 or -1 for none, ``magnitude`` in its kind's unit
    (:class:`~controllers.monitor.DetectedFault`)."""
    count = state.event_count
    state.event_kind[count] = kind
    state.event_joint[count] = joint
    state.event_magnitude[count] = magnitude
    state.event_count = count + 1


@numba.njit(cache=True)
def _minimum(a: float, b: float) -> float:
    """np.minimum of two scalars: a NaN wins."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a <= b else b


@numba.njit(cache=True)
def _maximum(a: float, b: float) -> float:
    """np.maximum of two scalars: a NaN wins."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a >= b else b


@numba.njit(cache=True)
def _sign(value: float) -> float:
    """np.sign of a scalar: -1, 0 or 1, NaN for NaN."""
    if value > 0.0:
        return 1.0
    if value < 0.0:
        return -1.0
    return value if math.isnan(value) else 0.0


@numba.njit(cache=True)
def _held_joint(
    constants: NDArray[np.uint8],
    angles: NDArray[np.float64],
    rates: NDArray[np.float64],
    torques: NDArray[np.float64],
    joint: int,
    mass: float,
) -> tuple[float, float]:
    """The torque (N m) that holds ``joint`` still (its rate and acceleration 0) at ``angles`` (rad, (3,)) with
    ``mass`` (kg) held while the other joints move at ``rates`` (rad/s) under their measured ``torques`` (N m, (3,)),
    and the joint's inertia (kg m^2) against what it is pushed with beyond that; (NaN, NaN) where the model cannot
    take the state.

    With the model's tau = M u + n (rates ``rates``, the joint's 0): the others accelerate as their torques drive them,
    u_o = M_oo^-1 (tau_o - n_o - M_oj u_j), so the joint's own equation is S u_j = tau_j - h_j with
    h_j = n_j + M_jo M_oo^-1 (tau_o - n_o) and S = M_jj - M_jo M_oo^-1 M_oj (docs/design.md section 6, "Encoders")."""
    w = rates.copy()
    w[joint] = 0.0
    status, base = single_sample_model(constants, angles[0], angles[1], angles[2], w[0], w[1], w[2], 0.0, 0.0, 0.0)
    if status != 0:
        return math.nan, math.nan
    bias = base[0] + mass * base[1]
    inertia = np.empty((3, 3))
    for column in range(3):
        u = np.zeros(3)
        u[column] = 1.0
        status, unit = single_sample_model(
            constants, angles[0], angles[1], angles[2], w[0], w[1], w[2], u[0], u[1], u[2]
        )
        if status != 0:
            return math.nan, math.nan
        inertia[:, column] = unit[0] + mass * unit[1] - bias
    first, second = (1, 2) if joint == 0 else ((0, 2) if joint == 1 else (0, 1))
    # M_oo^-1 of the other two joints, written out
    a, b = inertia[first, first], inertia[first, second]
    c, d = inertia[second, first], inertia[second, second]
    determinant = a * d - b * c
    if determinant == 0.0:
        return math.nan, math.nan
    driven_first = torques[first] - bias[first]
    driven_second = torques[second] - bias[second]
    accelerations = (
        (d * driven_first - b * driven_second) / determinant,
        (a * driven_second - c * driven_first) / determinant,
    )
    held = bias[joint] + inertia[joint, first] * accelerations[0] + inertia[joint, second] * accelerations[1]
    coupled = (
        inertia[joint, first] * (d * inertia[first, joint] - b * inertia[second, joint])
        + inertia[joint, second] * (a * inertia[second, joint] - c * inertia[first, joint])
    ) / determinant
    return held, inertia[joint, joint] - coupled


@numba.njit(cache=True)
def loop_excess(
    commands: NDArray[np.float64], torques: NDArray[np.float64], slowest_hold: float, slowest_keep: float
) -> float:
    """How far (N m, summed over readings) a drive's readings depart from every first-order current loop with a lag
    from none to the slowest healthy one, over a window of readings (docs/design.md section 6, "Torques").

    Reading k of such a loop is u_k + (u_{k-1} - u_k) h + (y_{k-1} - u_{k-1}) q, (h, q) the (hold, keep) of its lag,
    so y_k - y_{k-1} = (1 - q)(u_{k-1} - y_{k-1}) + (1 - h)(u_k - u_{k-1}); summed over the window,
    D = sum_{k<n} (u_k - y_k) = (y_n - y_0 - (1 - h)(u_n - u_0)) / (1 - q), with 1 - h and 1 - q between the slowest
    loop's and 1 (no lag). Returns D less the nearest value that bound allows: 0 for a healthy loop (up to the
    readings' noise), the torque held back over the window for a drive that does not deliver its command (its sign
    the command's).

    Args:
        commands: The commands u held (N m) at the window's readings, oldest first, (n + 1,).
        torques: The clean torque readings y (N m) of the same samples, (n + 1,).
        slowest_hold: h of the slowest healthy loop.
        slowest_keep: q of the slowest healthy loop.
    """
    n = commands.shape[0] - 1
    owed = 0.0
    for k in range(n):
        owed += commands[k] - torques[k]
    change, commanded = torques[n] - torques[0], commands[n] - commands[0]
    ends = (change - commanded, change - (1.0 - slowest_hold) * commanded)
    low, high = min(ends), max(ends)
    share = 1.0 - slowest_keep
    low, high = min(low, low / share), max(high, high / share)
    if owed > high:
        return owed - high
    if owed < low:
        return owed - low
    return 0.0


@numba.njit(cache=True)
def _acceleration_bounds(
    state: np.record,
    model_constants: NDArray[np.uint8],
    angles: NDArray[np.float64],
    angles_before: NDArray[np.float64],
    delivered: NDArray[np.float64],
    joint: int,
    mass: float,
) -> tuple[float, float]:
    """The bounds (rad/s^2) of ``joint``'s acceleration at a sample of clean ``angles`` (rad, (3,)), the sample
    before's ``angles_before`` and the torques the drives ``delivered`` (N m, (3,)): (tau_i - h_i -+ 2 b_i) / S_i of
    :func:`_held_joint`, with ``mass`` (kg) held and the others' rates the backward difference of their readings. The
    joint's friction lies within +-b_i (its breakaway) at rest and in motion, and the model's error within about as
    much again (masses 10 % off, friction 30 %: docs/design.md section 6, "Encoders"). (NaN, NaN) where the model
    cannot take the state."""
    others_rate = (angles - angles_before) / CONTROL_PERIOD
    held_torque, inertia = _held_joint(model_constants, angles, others_rate, delivered, joint, mass)
    if math.isnan(held_torque) or not inertia > 0.0:
        return math.nan, math.nan
    margin = 2.0 * state.breakaway[joint]
    return (delivered[joint] - held_torque - margin) / inertia, (delivered[joint] - held_torque + margin) / inertia


@numba.njit(cache=True)
def _speeds_before(
    state: np.record, model_constants: NDArray[np.uint8], joint: int, mass: float, low: float, high: float
) -> tuple[float, float]:
    """The speeds (rad/s) ``joint`` may have had at the last sample (whose acceleration bounds are ``low`` and
    ``high``, rad/s^2) from its readings before, ``mass`` (kg) held throughout: the lowest and the highest (lowest
    at or above highest where no speed fits; -inf and inf without readings).

    Going back m samples from there, x_0 - x_-m = v_0 m T - G_m with G_m the integral of (m T - u) a(-u) over
    u in [0, m T], whose bounds follow from the acceleration's in each period (the hull of the bounds at its ends);
    both readings are quantized to a count q, so c_0 - c_-m - q < x_0 - x_-m < c_0 - c_-m + q bounds v_0. Back to
    :data:`~controllers.monitor.tuning.TURN_HISTORY` samples, and only over readings that were not replaced
    (docs/design.md section 6, "Encoders", case (c))."""
    count = state.stuck_step / STUCK_COUNTS
    period = CONTROL_PERIOD
    lowest, highest = -math.inf, math.inf
    angles, replaced, torques = state.turn_angles, state.turn_replaced, state.turn_torques
    newest = angles.shape[0] - 1
    reach = min(TURN_HISTORY, state.turn_samples - 2)
    travel_low = travel_high = change_low = change_high = 0.0
    later_low, later_high = low, high
    for back in range(1, reach + 1):
        row = newest - back
        if replaced[newest, joint] != 0 or replaced[row, joint] != 0:
            break
        earlier_low, earlier_high = _acceleration_bounds(
            state, model_constants, angles[row], angles[row - 1], torques[torques.shape[0] - 1 - back], joint, mass
        )
        if math.isnan(earlier_low):
            break
        period_low, period_high = min(earlier_low, later_low), max(earlier_high, later_high)
        travel_low += change_low * period + 0.5 * period_low * period**2
        travel_high += change_high * period + 0.5 * period_high * period**2
        change_low += period_low * period
        change_high += period_high * period
        step = angles[newest, joint] - angles[row, joint]
        lowest = max(lowest, (step - count + travel_low) / (back * period))
        highest = min(highest, (step + count + travel_high) / (back * period))
        later_low, later_high = earlier_low, earlier_high
    return lowest, highest


@numba.njit(cache=True)
def _start_turn(
    state: np.record, model_constants: NDArray[np.uint8], joint: int, mass: float, low: float, high: float
) -> None:
    """At the first repeat of ``joint``'s reading, the speeds it may have had at its last new reading
    (:func:`_speeds_before`), and nothing added since."""
    lowest, highest = _speeds_before(state, model_constants, joint, mass, low, high)
    state.turn_speed[joint, 0], state.turn_speed[joint, 1] = lowest, highest
    state.turn_speed_change[joint, 0] = state.turn_speed_change[joint, 1] = 0.0
    state.turn_travel[joint, 0] = state.turn_travel[joint, 1] = 0.0


@numba.njit(cache=True)
def _others_follow_torques(state: np.record, model_constants: NDArray[np.uint8], joint: int, mass: float) -> bool:
    """Whether the joints but ``joint`` moved as their torques allow over their last readings (some speed at the
    last sample fits them, :func:`_speeds_before`, ``mass`` kg held): a force on the platform acts on every joint,
    a stuck encoder on its own joint's readings only."""
    last, before = state.turn_angles[TURN_HISTORY + 1], state.turn_angles[TURN_HISTORY]
    delivered = state.turn_torques[TURN_HISTORY]
    for other in range(3):
        if other == joint:
            continue
        low, high = _acceleration_bounds(state, model_constants, last, before, delivered, other, mass)
        if math.isnan(low):
            return False
        lowest, highest = _speeds_before(state, model_constants, other, mass, low, high)
        if lowest >= highest:
            return False
    return True


@numba.njit(cache=True)
def _extend_turn(state: np.record, joint: int, low: float, high: float) -> None:
    """Add the period before the last sample to ``joint``'s repeats: its acceleration within the hull of the bounds
    at its ends (the last sample's ``low`` and ``high``, rad/s^2, and the one's before), and narrow the speeds it may
    have had where its reading stopped changing to those that keep it within a count of where it was there at the last
    sample too (docs/design.md section 6, "Encoders", case (c)).

    With the speed v_0 there and the travel bounds D since, x_n - x_0 lies within v_0 n T + [D_low, D_high], and both
    readings lie in one count q, so -q < x_n - x_0 < q: v_0 < (q - D_low) / (n T) and v_0 > (-q - D_high) / (n T)."""
    count = state.stuck_step / STUCK_COUNTS
    period = CONTROL_PERIOD
    bounds = (min(state.turn_acceleration[joint, 0], low), max(state.turn_acceleration[joint, 1], high))
    for side in range(2):
        state.turn_travel[joint, side] += state.turn_speed_change[joint, side] * period + 0.5 * bounds[side] * period**2
        state.turn_speed_change[joint, side] += bounds[side] * period
    elapsed = (state.rest_repeats[joint] - 1) * period  # the last sample's time since the reading stopped changing
    state.turn_speed[joint, 1] = min(state.turn_speed[joint, 1], (count - state.turn_travel[joint, 0]) / elapsed)
    state.turn_speed[joint, 0] = max(state.turn_speed[joint, 0], (-count - state.turn_travel[joint, 1]) / elapsed)


@numba.njit(cache=True)
def _keep_delivered(state: np.record) -> None:
    """Shift the torques the drives delivered on this sample into ``state.turn_torques``: the clean readings, but a
    drive that falls short of its command (a fault found, or short readings in a row) delivers its measured reading,
    not the loop's prediction that replaces it."""
    delivered = state.torque_previous.copy()
    for joint in range(3):
        if state.drive_active[joint] != 0 or state.short_run[joint] > 0:
            delivered[joint] = state.torque_measured[joint]
    shift_in(state.turn_torques, delivered)


@numba.njit(cache=True)
def clean_encoders(
    state: np.record, raw: NDArray[np.float64], rates: NDArray[np.float64], model_constants: NDArray[np.uint8]
) -> int:
    """Check encoder readings (rad) and their rates (rad/s) against the last clean readings and write the clean
    ones into ``state.clean`` rows 0 and 1: a NaN or inf, an implausible jump (a second difference beyond
    ``jump_bound``), a suspect repeat and a stuck run (of a moving joint; of one that left rest: its measured
    torque, with the model's inertia from ``model_constants``, moved it a count; or of one that no speed its readings
    before allow keeps within a count under the accelerations its torque allows) are detected and replaced by the
    reference plus the joint's last good tracking error, their rates by the reference's; a rate next to a replaced
    reading, or missing, is the clean backward difference. Returns :data:`ANGLES_REPLACED` and
    :data:`RATES_REPLACED` bits."""
    reference, reference_rates = state.reference[0], state.reference[1]
    bad = np.empty(3, dtype=np.bool_)
    rate_missing = np.empty(3, dtype=np.bool_)
    continued = np.zeros(3, dtype=np.bool_)
    continued_from = np.zeros(3)
    for joint in range(3):
        bad[joint] = not math.isfinite(raw[joint])
        # a NaN rate beside a finite reading follows a NaN reading (the rate is a backward difference): it is
        # recomputed below, and reported only when the reading before was finite
        rate_missing[joint] = not bad[joint] and not math.isfinite(rates[joint])
        unexplained = rate_missing[joint] and (not state.raw_known or math.isfinite(state.raw_previous[joint]))
        missing = bad[joint] or unexplained
        if missing and state.nan_active[joint] == 0:
            record_event(state, SENSOR_NAN, joint, math.nan)
        state.nan_active[joint] = missing
    if state.clean_count >= 2:
        last, before, previous = state.last, state.before, state.raw_previous
        second_difference = raw - 2.0 * last + before
        jump = np.empty(3, dtype=np.bool_)
        suspect = np.empty(3, dtype=np.bool_)
        # readings that step by two counts or more: the arm moves there (NaN steps do not)
        stepping = np.abs(raw - previous) >= 2.0 * state.stuck_step / STUCK_COUNTS
        for joint in range(3):
            # after a stuck spell, a reading that continues the one flagged before it at a plausible rate is the
            # joint's true position, not a glitch: accepted, so that the clean readings follow the joint again (a
            # glitch of several samples stays flagged: its readings continue each other but follow no stuck spell)
            repeated = raw[joint] == previous[joint]
            continues = (
                state.glitch_active[joint] != 0
                and state.after_stuck[joint] != 0
                and not repeated
                and abs(raw[joint] - previous[joint] - (last[joint] - before[joint])) <= state.jump_bound
            )
            jump[joint] = (
                math.isfinite(raw[joint]) and abs(second_difference[joint]) > state.jump_bound and not continues
            )
            state.resynced |= continues
            continued[joint] = continues
            continued_from[joint] = previous[joint]
            # a repeated reading is suspect while the joint was moving and its reference still moves several counts
            # per sample (at rest, or coming to rest, a reading repeats rightly); once stuck, a joint stays stuck
            # while its reading repeats, whatever the reference does
            commanded = abs(reference_rates[joint]) * CONTROL_PERIOD >= state.stuck_step
            # moving: the joint's next step, had it kept its last acceleration, is several counts (a joint that
            # brakes through a reversal repeats its reading rightly, whatever its reference does)
            step = last[joint] - before[joint]
            if state.clean_count == 3:
                step += last[joint] - 2.0 * before[joint] + state.earlier[joint]
            moving = abs(step) >= state.stuck_step
            suspect[joint] = repeated and ((commanded and moving) or state.stuck[joint] > 0)
            # the joint's tracking error where it stopped: at the reading before a run of repeats, or later while its
            # reference rests
            resting = abs(reference_rates[joint]) * CONTROL_PERIOD * STUCK_COUNTS < state.stuck_step
            if not repeated or resting:
                state.rest_error[joint] = state.error[joint]
            state.rest_repeats[joint] = state.rest_repeats[joint] + 1 if repeated else 0
            # a joint whose reading repeats while its reference runs is stuck once its drive's torque beyond what
            # holds it still and what rest absorbs (the friction's whole swing) has moved it, with the model's
            # inertia, by more than a count along the reference's run (b), or once no speed it may have had where its
            # reading stopped changing keeps it within that count under the accelerations its torque allows (c),
            # unless a force on the platform (a collision under way) may hold it (docs/design.md section 6,
            # "Encoders"): the repeats are then replaced from the error held where it stopped, as a stuck spell's
            # are. Where the joint lies against the reference does not matter: a PD ahead of its reference still
            # drives it on with its rate's error
            direction = _sign(reference_rates[joint])
            if repeated and state.rest_repeats[joint] == 1:
                # the joint's speed along the reference's run as its reading stopped changing: that of its last
                # step where that ran against the run (a joint turning back must first stop), else nil
                state.rest_speed[joint] = min(0.0, direction * (last[joint] - before[joint]) / CONTROL_PERIOD)
            # where nothing pushes the joint on, its friction may have stopped it (not turned it back)
            speed = min(state.rest_speed[joint], 0.0) if repeated else 0.0
            # a mass picked up and not yet known may hold the joint too: the torque that lifts it moves nothing
            unknown_load = state.gripper_before and not state.held_known
            # (c) takes a joint that a force on the platform may hold still for a stuck encoder: it asks the arm to
            # move on, another joint's reading stepping by two counts on every repeat (a force that holds the
            # platform holds every joint; the collision check speaks then). Neither (b) nor (c) needs the model at
            # rest
            others_move = False
            for other in range(3):
                others_move |= other != joint and stepping[other]
            bounded = False
            low = high = math.nan
            held = state.held_mass if state.held_known else 0.0
            turn_mass = held if state.gripper_before else 0.0
            if repeated and not (state.collision or unknown_load):
                # the bounds of the joint's acceleration at the last sample (the torques there, as the model's
                # state there; the rates of the others' clean readings)
                delivered = state.turn_torques[TURN_HISTORY]
                pushing_mass = max(state.feedforward_mass, held)
                if commanded:
                    low, high = _acceleration_bounds(
                        state, model_constants, last, before, delivered, joint, pushing_mass
                    )
                    push = low if direction > 0.0 else -high
                    if push > 0.0:  # False for NaN
                        speed = state.rest_speed[joint] + push * CONTROL_PERIOD
                # (c) holds what the cup holds: the object leaves as the gripper opens, which the slip check, a
                # smoother's lag behind, learns later (a 10 kg object released read as the joint's torque gone
                # astray), so nothing while it is open and nothing across a switch within the readings it takes
                switched = state.sample - state.gripper_changed <= TURN_HISTORY + 2
                if others_move and not switched and state.turn_check != 0:
                    if not (commanded and turn_mass == pushing_mass):
                        low, high = _acceleration_bounds(
                            state, model_constants, last, before, delivered, joint, turn_mass
                        )
                    bounded = not math.isnan(low)
                if bounded and state.rest_repeats[joint] == 1:
                    _start_turn(state, model_constants, joint, turn_mass, low, high)
                    state.turn_known[joint] = True
                elif bounded and state.turn_known[joint] != 0:
                    _extend_turn(state, joint, low, high)
                if bounded:
                    state.turn_acceleration[joint, 0], state.turn_acceleration[joint, 1] = low, high
            state.turn_known[joint] = state.turn_known[joint] != 0 and bounded and others_move
            if not repeated:
                state.rest_travel[joint] = 0.0
            else:
                state.rest_travel[joint] += 0.5 * (state.rest_speed[joint] + speed) * CONTROL_PERIOD
            state.rest_speed[joint] = speed
            must_move = state.rest_travel[joint] > state.stuck_step / STUCK_COUNTS  # beyond one count
            if state.stuck[joint] == 0 and state.rest_repeats[joint] >= STUCK_SAMPLES and must_move:
                suspect[joint] = True
                state.stuck[joint] = STUCK_SAMPLES - 1
                state.error[joint] = state.rest_error[joint]
            # (c): the readings cannot have repeated so far; the repeats already read count towards the stuck spell
            turned = state.turn_known[joint] != 0 and state.turn_speed[joint, 0] >= state.turn_speed[joint, 1]
            # and the others moved as their torques allow: a push that stops the joint at its turn acts on them too
            # (a 661 N push, nominal seed 19, was named a stuck encoder and the collision found 40 ms late)
            turned = turned and _others_follow_torques(state, model_constants, joint, turn_mass)
            if state.stuck[joint] == 0 and turned:
                suspect[joint] = True
                state.stuck[joint] = min(state.rest_repeats[joint], STUCK_SAMPLES) - 1
                state.error[joint] = state.rest_error[joint]
            state.stuck[joint] = state.stuck[joint] + 1 if suspect[joint] else 0
        for joint in range(3):
            # a reading that repeats the last while the joint moves is a stuck encoder's (its jump is the joint's
            # motion), and its step back onto the joint at the spell's end is the spell's end: neither is a glitch
            fresh = state.glitch_active[joint] == 0 and state.after_stuck[joint] == 0
            if jump[joint] and fresh and not suspect[joint]:
                record_event(state, ENCODER_GLITCH, joint, second_difference[joint])
        for joint in range(3):
            if state.stuck[joint] == STUCK_SAMPLES:
                record_event(state, ENCODER_STUCK, joint, math.nan)
        for joint in range(3):
            state.glitch_active[joint] = jump[joint]
            # a suspect reading is replaced like a stuck one: the error held through a stuck spell is then the
            # last one measured, not the spell's first repeats (which an integral would wind up on)
            bad[joint] |= jump[joint] or suspect[joint]
            after_stuck = state.after_stuck[joint] != 0 or state.stuck[joint] >= STUCK_SAMPLES
            state.after_stuck[joint] = after_stuck and bad[joint]
    state.raw_previous[:] = raw
    state.raw_known = True
    replaced = 0
    for joint in range(3):
        # a rate from a replaced reading, or against one, or missing: the reference's, else the clean backward
        # difference
        if bad[joint]:
            angle, rate = reference[joint] + state.error[joint], reference_rates[joint]
            replaced |= ANGLES_REPLACED | RATES_REPLACED
        else:
            angle, rate = raw[joint], rates[joint]
            state.error[joint] = raw[joint] - reference[joint]
            if state.encoder_bad[joint] != 0 or rate_missing[joint]:
                rate = (angle - state.last[joint]) / CONTROL_PERIOD if state.clean_count else reference_rates[joint]
                replaced |= RATES_REPLACED
        state.clean[0, joint], state.clean[1, joint] = angle, rate
        state.encoder_bad[joint] = bad[joint]
    state.earlier[:] = state.before
    state.before[:] = state.last
    state.last[:] = state.clean[0]
    for joint in range(3):
        if continued[joint]:  # the reading it continued was the joint's too: the next second difference takes it
            state.before[joint] = continued_from[joint]
    state.clean_count = min(state.clean_count + 1, 3)
    shift_in(state.turn_angles, state.clean[0])
    replaced_now = np.empty(3, dtype=np.uint8)
    for joint in range(3):
        replaced_now[joint] = state.encoder_bad[joint]
    shift_in(state.turn_replaced, replaced_now)
    state.turn_samples = min(state.turn_samples + 1, TURN_HISTORY + 2)
    return replaced


@numba.njit(cache=True)
def clean_torques(
    state: np.record, torque: NDArray[np.float64], command: NDArray[np.float64], has_command: bool
) -> int:
    """Check torque readings (N m) against the current loop driven, for the reading's age past the last reading, by
    the command held before the last one, then by the last ``command`` (:func:`loop_output`; none at the first
    sample, ``has_command`` False), and write the clean ones into ``state.clean`` row 2: a NaN, a reading outside
    the span of the last reading and the two commands by :data:`TORQUE_MARGIN` (replaced by the loop's prediction)
    and a drive that does not deliver its command are detected. Returns the :data:`TORQUES_REPLACED` bit."""
    finite = np.empty(3, dtype=np.bool_)
    for joint in range(3):
        finite[joint] = math.isfinite(torque[joint])
        if not finite[joint] and state.nan_active[3 + joint] == 0:
            record_event(state, SENSOR_NAN, joint, math.nan)
        state.nan_active[3 + joint] = not finite[joint]
    replaced = 0
    if not state.torque_known or not has_command:
        for joint in range(3):
            if finite[joint]:
                value = torque[joint]
            else:
                value = state.torque_previous[joint] if state.torque_known else 0.0
                replaced = TORQUES_REPLACED
            state.clean[2, joint] = state.torque_previous[joint] = state.torque_measured[joint] = value
        state.torque_known = True
        state.command_before[:] = command
        state.command_known = has_command
        state.loop_count = 0  # the integral check's window starts again: a reading without its command owes unknown
        _keep_delivered(state)
        return replaced
    peak = state.peak_torque
    hold, keep = state.loop_response[0], state.loop_response[1]
    slowest_hold, slowest_keep = state.slowest_response[0], state.slowest_response[1]
    if not state.command_known:  # the first command: nothing held before it
        state.command_before[:] = command
    held, before = np.empty(3), np.empty(3)
    predicted, implausible = np.empty(3), np.empty(3, dtype=np.bool_)
    for joint in range(3):
        held[joint] = _maximum(_minimum(command[joint], peak), -peak)  # np.clip: a NaN stays
        before[joint] = _maximum(_minimum(state.command_before[joint], peak), -peak)
        previous = state.torque_previous[joint]
        predicted[joint] = loop_output(previous, before[joint], held[joint], hold[joint], keep[joint])
        low = _minimum(_minimum(previous, held[joint]), before[joint]) - TORQUE_MARGIN
        high = _maximum(_maximum(previous, held[joint]), before[joint]) + TORQUE_MARGIN
        implausible[joint] = finite[joint] and (torque[joint] < low or torque[joint] > high)
        state.torque_bad[joint] = state.torque_bad[joint] + 1 if implausible[joint] else 0
    # A glitch is reported at its reading, unless the reading falls short of the prediction on the command's side:
    # a drive's loss reads so too, so its report waits for the next reading (a glitch if that one is plausible
    # again, else the run goes on to the drive-fault check)
    for joint in range(3):
        if state.torque_bad[joint] == 1:
            deviation = torque[joint] - predicted[joint]
            if _sign(torque[joint]) == _sign(predicted[joint]) and abs(torque[joint]) < abs(predicted[joint]):
                state.held_glitch[joint] = deviation
            else:
                record_event(state, TORQUE_GLITCH, joint, deviation)
        elif state.torque_bad[joint] == 0 and not math.isnan(state.held_glitch[joint]):
            record_event(state, TORQUE_GLITCH, joint, state.held_glitch[joint])
            state.held_glitch[joint] = math.nan
    # A drive that does not deliver its command: implausible torques in a row, all short of the prediction (a large
    # loss), or a CUSUM of how far each reading falls short of what the slowest plausible current loop would reach
    # from the last reading (a loss too small for the span check); a span-implausible reading or its successor adds
    # nothing to the CUSUM.
    for joint in range(3):
        measured = state.torque_measured[joint]
        step = held[joint] - measured
        direction = _sign(step) if abs(step) > TORQUE_MARGIN else _sign(held[joint])
        slowest = loop_output(measured, before[joint], held[joint], slowest_hold[joint], slowest_keep[joint])
        if finite[joint] and not implausible[joint] and state.torque_implausible[joint] == 0:
            shortfall = _minimum((slowest - torque[joint]) * direction, DRIVE_FAULT_STEP)
            state.shortfall[joint] = _maximum(0.0, state.shortfall[joint] + shortfall - DRIVE_FAULT_DRIFT)
        else:
            state.shortfall[joint] = 0.0
        short = implausible[joint] and abs(torque[joint]) < abs(predicted[joint])
        state.short_run[joint] = state.short_run[joint] + 1 if short else 0
    for joint in range(3):
        large = state.short_run[joint] >= DRIVE_FAULT_SAMPLES
        if (large or state.shortfall[joint] > DRIVE_FAULT_EVIDENCE) and state.drive_active[joint] == 0:
            record_event(state, DRIVE_FAULT, joint, abs(predicted[joint]) - abs(torque[joint]))
            state.held_glitch[joint] = math.nan  # its first reading was the drive's, not a glitch
            state.drive_active[joint] = True
    # A drive fault ends when its drive has delivered the loop's prediction again for DRIVE_FAULT_SAMPLES readings
    # (its torque stepped back onto the command; a lone one may be a command that dipped under the drive's limit),
    # or when its evidence is gone
    state.drive_ended = False
    for joint in range(3):
        delivers = finite[joint] and abs(torque[joint] - predicted[joint]) <= TORQUE_MARGIN
        state.delivering[joint] = state.delivering[joint] + 1 if delivers and state.drive_active[joint] else 0
        recovered = state.delivering[joint] >= DRIVE_FAULT_SAMPLES
        evident = (state.shortfall[joint] > 0.0 or state.torque_bad[joint] > 0) and not recovered
        evident = evident or state.loop_over[joint] != 0
        if state.drive_active[joint] != 0 and not evident:
            state.drive_ended = True
            state.shortfall[joint] = 0.0
        state.drive_active[joint] = state.drive_active[joint] != 0 and evident
        state.torque_implausible[joint] = implausible[joint]
        if finite[joint]:
            state.torque_measured[joint] = torque[joint]
        if finite[joint] and not implausible[joint]:
            value = torque[joint]
        else:
            value = predicted[joint]
            replaced = TORQUES_REPLACED
        state.clean[2, joint] = state.torque_previous[joint] = value
    # The loop's integral check over the window of clean readings (a glitch, replaced by the loop's prediction, owes
    # nothing): a drive that holds its torque short of the command by less than the CUSUM's drift still falls
    # short on every reading, and the sum gathers it while the readings' noise averages out
    shift_in(state.loop_commands, held)
    shift_in(state.loop_torques, state.clean[2])
    state.loop_count = min(state.loop_count + 1, DRIVE_FAULT_WINDOW + 1)
    if state.loop_count > DRIVE_FAULT_WINDOW:
        for joint in range(3):
            excess = loop_excess(
                state.loop_commands[:, joint], state.loop_torques[:, joint], slowest_hold[joint], slowest_keep[joint]
            )
            over = abs(excess) > DRIVE_FAULT_EVIDENCE
            if over and state.loop_over[joint] == 0 and state.drive_active[joint] == 0:
                record_event(state, DRIVE_FAULT, joint, excess * _sign(held[joint]) / DRIVE_FAULT_WINDOW)
                state.held_glitch[joint] = math.nan
                state.drive_active[joint] = True
            # once beyond the evidence, the window shows the fault until its readings fit a healthy loop again (a
            # drive that withholds only the peaks of its command falls short again and again: one fault)
            state.loop_over[joint] = over or (state.loop_over[joint] != 0 and excess != 0.0)
    state.command_before[:] = command
    state.command_known = True
    _keep_delivered(state)
    return replaced
