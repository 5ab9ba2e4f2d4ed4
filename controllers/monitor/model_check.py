"""The fault monitor's model checks, compiled: the collision check (an external force on the platform) and the slip
check (payload consistency), at the smoothed joint state a smoother's lag behind the sample (docs/design.md section
6, "Fault monitor").

The state they check is a smoother's: the tracking error (the clean angles less the reference) smoothed by a
fixed-lag smoother, the reference's own state added back. The reference is known, so the smoother's motion model
(white jerk) carries only the error's jerk; a smoother of the angles themselves lags the planned jerk of time-optimal
moves. Each smoothed state is paired with its sample's torque, gripper and quiet flag, at the instant the torque was
measured.

Where the error's acceleration still steps (a controller that steps its torque, as the residual policy does every
10 ms), the smoother smears the step over its window: a step da between readings m - 1 and m leaves the estimated
sample's acceleration off by h_m da, h the smoother's response to a unit step (:func:`acceleration_step_response`).
The joint's torque steps with its acceleration (I da), so the measured torque's steps in the window give the model
torque's error variance sum_m h_m^2 (tau_m - tau_{m-1})^2 (N^2 m^2), per joint, which the slip check adds to its
residual variance. The collision check instead leaves out, per joint, the most that error can be where the
reference's own acceleration steps and the plant follows a sample or two later (:func:`lagged_step_weights`, the
steps of the model's torque along the reference): a band a push cannot widen. Where the plant's acceleration steps
at another time than the reference's (a drive faster or slower than the identified one, a feedforward that ignores
the object, a stop the plant reaches late), the collision check also takes the smoother's error off the residual:
the plant's acceleration steps with its measured torque (M da = d tau), the reference's with the model's torque
along it, so the error in torque is sum_m g_m d tau_m - sum_m h_m d tau*_m (:func:`torque_step_response`,
:func:`~controllers.monitor.compiled.tracking_step_error`). A pick or a place in the window steps the acceleration
with the mass carried instead: for those samples the part along the payload regressor that a mass the cup can hold
explains is left out.

:data:`MODEL_CHECK_FIELDS` are the fields of the monitor's record (:data:`~controllers.monitor.step.MONITOR`) that
:func:`check_sample` keeps: the smoother's window, the readings it lags behind, the CUSUMs and the mass held.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.estimation import (
    DELAYED_STATE_FIELDS,
    SMOOTHER_LAG,
    SMOOTHER_WINDOW,
    JointStateSmoother,
    delayed_state_step,
)
from controllers.monitor.compiled import (
    CORRECTION_TERMS,
    learn_scatter,
    model_residual,
    platform_force,
    reference_step_bound,
    reference_torque,
    shift_in,
    slip_moments,
    torque_step_variance,
    tracking_step_error,
)
from controllers.monitor.tuning import (
    CORRELATION_RATE,
    FORCE_EVIDENCE,
    FORCE_REFERENCE,
    HELD_MASS_STD,
    REST_FORCE_REFERENCE,
    REST_RATE,
    SCATTER_RATE,
    SLIP_EVIDENCE,
    SLIP_MASS_CONFIDENCE,
    SLIP_MIN_MASS,
    SLIP_PRECISION,
    SLIP_SETTLE,
    SLIP_WINDOW,
)
from controllers.payload import FRICTION_CORRELATION_SAMPLES, FRICTION_VELOCITY, RESIDUAL_STD
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD

SLIPPED, COLLIDED, COLLIDING = 1, 2, 4
"""Bits of :func:`check_sample`'s result: a slip detected on this sample, a collision detected on it, a collision
under way after it."""

MODEL_CHECK_FIELDS = [
    *DELAYED_STATE_FIELDS,
    # how many periods a torque reading is older than its encoder sample, the measured torques of the window and the
    # one before, and the smoother's response to a step
    ("torque_age", np.float64),
    ("torques", np.float64, (SMOOTHER_WINDOW + 1, 3)),
    ("squared_response", np.float64, (SMOOTHER_WINDOW,)),
    ("torque_response", np.float64, (SMOOTHER_WINDOW,)),
    ("acceleration_response", np.float64, (SMOOTHER_WINDOW,)),
    # the feedforward's mass (kg, the controller's payload estimate, set before each sample), the model's torque
    # with it along the reference over the window and the one before, the last torque and payload regressor, whether
    # any was valid yet, and the weights of the torque's steps in the collision check's band
    ("feedforward_mass", np.float64),
    ("reference_torques", np.float64, (SMOOTHER_WINDOW + 1, 3)),
    ("reference_regressors", np.float64, (SMOOTHER_WINDOW + 1, 3)),
    ("planned_torque", np.float64, (3,)),
    ("planned_regressor", np.float64, (3,)),
    ("reference_started", np.bool_),
    ("step_weights", np.float64, (SMOOTHER_WINDOW,)),
    ("pending_quiet", np.uint8, (SMOOTHER_LAG + 1,)),  # beside the pending readings
    # the gripper at the last sample and the sample at which it last changed: the mass carried changes there
    ("gripper_before", np.bool_),
    ("gripper_changed", np.int64),
    # what the residual takes off (the estimator's corrections of the model), the friction it charges and what a
    # joint at rest may hold, the slip check's friction band
    ("corrections", CORRECTION_TERMS),
    ("charged_coulomb", np.float64, (3,)),
    ("breakaway", np.float64, (3,)),
    ("static_friction", np.float64, (3,)),
    # the reference angles of the sample checked before (NaN before the first), and half an encoder count (rad)
    ("reference_before", np.float64, (3,)),
    ("half_count", np.float64),
    # the collision check
    ("force", np.float64, (3,)),
    ("force_magnitude", np.float64),
    ("force_evidence", np.float64),
    ("collision", np.bool_),
    ("collision_samples", np.int64),
    ("calm_samples", np.int64),
    # the slip check
    ("scatter", np.float64, (3,)),
    ("held_since", np.int64),
    ("held_known", np.bool_),
    ("held_mass", np.float64),
    ("held_information", np.float64),
    ("held_moment", np.float64),
    ("pending_information", np.float64),
    ("pending_moment", np.float64),
    # on an empty move: the sample since which, and the sums from which, its apparent mass along phi is measured (as
    # the mass held since a pick), the reference of the deviations it teaches the window statistic
    ("empty_since", np.int64),
    ("empty_information", np.float64),
    ("empty_moment", np.float64),
    ("evidence", np.float64),
    ("slip_armed", np.bool_),
    ("slip_mass", np.float64),
    ("onset_samples", np.int64),
    # the slip check's window statistic: the last samples' deviations from the known mass (phi^T W (r - m phi), kg^-1)
    # and information (kg^-2), how many of them are consecutive, the running means of their window sums' squares and
    # of the sums' information per window length, the samples learned, and the current run's log-likelihood ratios
    ("window_deviations", np.float64, (SLIP_WINDOW,)),
    ("window_informations", np.float64, (SLIP_WINDOW,)),
    ("chain", np.int64),
    ("squared_sums", np.float64, (SLIP_WINDOW,)),
    ("information_sums", np.float64, (SLIP_WINDOW,)),
    ("learned_samples", np.int64),
    ("window_ratios", np.float64, (SLIP_WINDOW,)),
    # the samples not yet learned: the last SLIP_WINDOW samples' deviations, information and whether each may be
    # learned (0: it breaks the run), oldest first, and how many of the rows hold samples
    ("unlearned_deviations", np.float64, (SLIP_WINDOW,)),
    ("unlearned_informations", np.float64, (SLIP_WINDOW,)),
    ("unlearned_valid", np.uint8, (SLIP_WINDOW,)),
    ("unlearned_count", np.int64),
    ("run_samples", np.int64),
]
"""The fields of the monitor's record that :func:`check_sample` keeps, beside ``sample`` (the sample's index since
the reset), ``reference`` (its reference angles, rates and accelerations, (3, 3)) and ``clean`` (its clean angles,
rates and torques, (3, 3)). Torques in N m, masses in kg, the force in N."""


def acceleration_step_response(smoother: JointStateSmoother) -> NDArray[np.float64]:
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


def torque_step_response(smoother: JointStateSmoother, age: float) -> NDArray[np.float64]:
    """The error (per rad/s^2) of ``smoother``'s acceleration estimate at a measured torque's instant, ``age``
    periods before its encoder sample (the estimate interpolated that far back towards the one before, as
    :func:`~controllers.monitor.compiled.model_residual` takes it), when the joint's acceleration steps by 1 rad/s^2
    with the measured torque between the torques read with readings m - 1 and m of the window, for each m (oldest
    first): the torque read with reading m is the one held over the physics step before it, so the step lies
    ``age`` periods before the middle of the two readings."""
    readings = smoother.weights.shape[1]
    estimated = smoother.history
    response = np.empty(readings)
    for m in range(readings):
        start = m - 0.5 - age  # the step's time (periods) on the window's clock (reading j at j)

        def estimate(first: int, start: float = start) -> float:
            times = np.arange(first, first + readings, dtype=float)
            angles = np.where(times > start, 0.5 * ((times - start) * CONTROL_PERIOD) ** 2, 0.0)
            return float(smoother.weights[2] @ angles)

        interpolated = (1.0 - age) * estimate(0) + age * estimate(-1)
        response[m] = interpolated - (1.0 if estimated - age > start else 0.0)
    return response


def samples_to_show(response: NDArray[np.float64], share: float) -> int:
    """Samples after a step of the acceleration enters the smoother's window (between its two newest readings) until
    the estimate of the checked sample shows at least ``share`` of it for good: until every older position m of the
    step has |h_m| <= 1 - ``share`` (``response`` h of :func:`acceleration_step_response`)."""
    unseen = np.flatnonzero(np.abs(response) > 1.0 - share)
    return int(len(response) - unseen.min()) if len(unseen) else 0


def lagged_step_weights(response: NDArray[np.float64], lags: int) -> NDArray[np.float64]:
    """Weights (per rad/s^2) of the smoother's acceleration error for a step of the reference's acceleration between
    readings m - 1 and m that the plant follows 1 to ``lags`` samples later: the tracking error's acceleration steps
    by -da at m and back by +da at m + k, so the estimate is off by da (h_{m+k} - h_m), at most
    max_k |h_{m+k} - h_m| da (``response`` h of :func:`acceleration_step_response`; no error for a step after the
    window)."""
    padded = np.concatenate((response, np.zeros(lags)))
    return np.max([np.abs(padded[k : k + len(response)] - response) for k in range(1, lags + 1)], axis=0)


@numba.njit(cache=True)
def _sliding(state: np.record, head: int) -> NDArray[np.float64]:
    """Per joint, +1 or -1 where the clean readings moved by half a count or more, that way, from the reading before the
    checked one to the reading after it (the tracking errors of the smoother's window plus their references), else
    0; and keep the checked sample's reference angles for the next sample's."""
    window = state.weights.shape[1]
    checked = state.next_slot + window - 1 - SMOOTHER_LAG  # the checked reading's row in the window's slice
    after = (head + 1) % (SMOOTHER_LAG + 1)
    sliding = np.zeros(3)
    for joint in range(3):
        moved = (state.readings[checked + 1, joint] + state.pending_reference[after, 0, joint]) - (
            state.readings[checked - 1, joint] + state.reference_before[joint]
        )
        if abs(moved) >= state.half_count:  # False for NaN
            sliding[joint] = 1.0 if moved > 0.0 else -1.0
        state.reference_before[joint] = state.pending_reference[head, 0, joint]
    return sliding


@numba.njit(cache=True)
def _restart_held(check: np.record) -> None:
    """Measure the mass held afresh from this sample on (at a pick), and end the empty move's apparent mass."""
    check.held_since = check.sample
    check.held_information = 0.0
    check.held_moment = 0.0
    check.pending_information = 0.0
    check.pending_moment = 0.0
    check.evidence = 0.0
    check.held_known = False
    check.run_samples = 0
    check.empty_since = -1


@numba.njit(cache=True)
def _mass_known(since: int, sample: int, information: float) -> bool:
    """Whether a mass measured along phi from sample ``since`` on, with ``information`` (kg^-2) summed into it, may
    serve as the reference of the slip check's deviations at ``sample``: :data:`SLIP_SETTLE` has passed and its
    standard error is under :data:`HELD_MASS_STD`."""
    return (sample - since) * CONTROL_PERIOD >= SLIP_SETTLE and information > 0.0 and information**-0.5 < HELD_MASS_STD


@numba.njit(cache=True)
def _learn_empty(
    check: np.record,
    terms: NDArray[np.float64],
    corrected: NDArray[np.float64],
    band: NDArray[np.float64],
    jerk_variance: NDArray[np.float64],
) -> None:
    """Teach the window statistic an empty move's sample: its deviation from the move's apparent mass along phi,
    measured as the mass held is on a carry (the raw residual ``terms``, weighted with the torque steps' variance
    ``jerk_variance``, from the move's start on), once known; a collision's samples, and those before the mass is
    known, break the run. The check tests a carry against the mass measured on that carry, which takes in any
    offset of the model along phi that persists over the move; measured from 0 instead, such an offset would enter
    every window's sum and make kappa_n grow with n (docs/design.md section 6, "Light slips: the residual's
    correlation")."""
    if check.empty_since < 0:
        check.empty_since = check.sample
        check.empty_information = 0.0
        check.empty_moment = 0.0
    if check.force_evidence != 0.0 or check.collision:  # a collision's force is no model error
        _defer(check, 0.0, 0.0, False)
        return
    if _mass_known(check.empty_since, check.sample, check.empty_information):
        apparent = check.empty_moment / check.empty_information
        window_information, window_moment = slip_moments(corrected, band, check.scatter)
        _defer(check, window_moment - apparent * window_information, window_information, True)
    else:
        _defer(check, 0.0, 0.0, False)
    information, moment = slip_moments(terms, band, check.scatter + jerk_variance)
    check.empty_information += information
    check.empty_moment += moment


@numba.njit(cache=True)
def _shift_scalar(values: NDArray[np.float64] | NDArray[np.uint8], value: float) -> None:
    """Shift ``value`` into ``values`` (oldest first), in place."""
    for row in range(len(values) - 1):
        values[row] = values[row + 1]
    values[len(values) - 1] = value


@numba.njit(cache=True)
def _defer(check: np.record, deviation: float, information: float, valid: bool) -> None:
    """Hold one sample's ``deviation`` and ``information`` (:func:`_learn_correlation`; ``valid`` False for a sample
    that breaks the run of consecutive samples) back from the window statistic's running means for
    :data:`SLIP_WINDOW` samples, and learn the sample that falls out: the samples a window weighs are never the
    ones its variance was learned from (a loss's own deviations, no model error, would teach kappa_n a correlation
    and slow their own test)."""
    oldest_deviation, oldest_information = check.unlearned_deviations[0], check.unlearned_informations[0]
    oldest_valid = check.unlearned_valid[0] != 0
    full = check.unlearned_count == SLIP_WINDOW
    _shift_scalar(check.unlearned_valid, 1 if valid else 0)
    _shift_scalar(check.unlearned_deviations, deviation)
    _shift_scalar(check.unlearned_informations, information)
    check.unlearned_count = min(check.unlearned_count + 1, SLIP_WINDOW)
    if full:
        if oldest_valid:
            _learn_correlation(check, oldest_deviation, oldest_information)
        else:
            check.chain = 0


@numba.njit(cache=True)
def _forget_unlearned(check: np.record) -> None:
    """Drop the samples not yet learned (a slip's: the loss's own): each breaks the run when it falls out."""
    for row in range(SLIP_WINDOW):
        check.unlearned_valid[row] = 0


@numba.njit(cache=True)
def _learn_correlation(check: np.record, deviation: float, information: float) -> None:
    """Take one sample's ``deviation`` phi^T W (r - m phi) (kg^-1, m the mass known to be held) and ``information``
    phi^T W phi (kg^-2) into the running means of the window sums' squares and information, for every window length
    the consecutive samples allow."""
    _shift_scalar(check.window_deviations, deviation)
    _shift_scalar(check.window_informations, information)
    check.chain = min(check.chain + 1, SLIP_WINDOW)
    deviations, informations = 0.0, 0.0
    for length in range(1, check.chain + 1):
        deviations += check.window_deviations[SLIP_WINDOW - length]
        informations += check.window_informations[SLIP_WINDOW - length]
        check.squared_sums[length - 1] += CORRELATION_RATE * (deviations * deviations - check.squared_sums[length - 1])
        check.information_sums[length - 1] += CORRELATION_RATE * (informations - check.information_sums[length - 1])
    check.learned_samples += 1


@numba.njit(cache=True)
def _window_evidence(check: np.record, cap: float) -> float:
    """The window statistic: the largest log-likelihood ratio of "gone" over the current run's last n samples,
    n up to :data:`SLIP_WINDOW`, each sum of the run's terms (the CUSUM's, of the corrected residual) divided by the
    window's variance inflation kappa_n = E[(sum of deviations)^2] / E[sum of information] that the residual's
    correlation gives (1 for white samples); each term capped at ``cap``. A window of n samples waits until
    n / (:data:`CORRELATION_RATE` :data:`SLIP_WINDOW`) samples have been learned: as many windows of its length as
    the running means' memory (1 / :data:`CORRELATION_RATE` samples) holds of the longest one."""
    best = 0.0
    for length in range(1, check.run_samples + 1):
        if check.learned_samples * CORRELATION_RATE * SLIP_WINDOW < length:
            break
        information = check.information_sums[length - 1]
        if not information > 0.0:  # no run of this length learned yet (numba raises on a division by zero)
            continue
        inflation = check.squared_sums[length - 1] / information
        if not inflation > 0.0:
            continue
        total = 0.0
        for row in range(SLIP_WINDOW - length, SLIP_WINDOW):
            total += min(check.window_ratios[row] / inflation, cap)
        best = max(best, total)
    return best


@numba.njit(cache=True)
def _slip_band(theta_dot: NDArray[np.float64], static_friction: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`controllers.payload.residual_std` with no nominal residual (N m): the static friction band of joints at
    ``theta_dot`` (rad/s), with libm's exp (NumPy's vectorized one may differ in the last bit)."""
    band = np.empty(3)
    for joint in range(3):
        scaled = theta_dot[joint] / FRICTION_VELOCITY
        friction = static_friction[joint] * math.exp(-(scaled**2))
        band[joint] = math.sqrt(FRICTION_CORRELATION_SAMPLES * friction**2)
    return band


@numba.njit(cache=True)
def _check_payload(
    check: np.record,
    terms: NDArray[np.float64],
    corrected: NDArray[np.float64],
    holding: bool,
    quiet: bool,
    jerk_variance: NDArray[np.float64],
    gone_force: float,
) -> int:
    """The slip check: a CUSUM of the log-likelihood ratio of "the object is gone" (r = e) against "the mass held
    since the pick is still there" (r = m phi + e), e weighted as the payload estimator weights it; r and phi are
    ``terms`` of :func:`model_residual`, m measured on the samples before the CUSUM's current run. A sample whose
    residual, with nothing held, leaves a platform force ``gone_force`` (N) beyond :data:`FORCE_REFERENCE` is no
    evidence of a loss (a push): it clears the CUSUM. No sample adds more than :data:`SLIP_EVIDENCE` over the
    record's ``onset_samples``, so that no run shorter than a push's onset (which, half shown, can look like the
    loss of a heavy object) makes a slip. Beside the CUSUM, a window statistic (:func:`_window_evidence`) weighs the
    run's last samples with the correlation of the residual ``corrected`` (``terms`` with the smoother's error at the
    torque's steps taken off, weighted without the torque steps' variance), measured on this robot's samples with a
    known mass (:func:`_learn_correlation`), a window late (:func:`_defer`): either over :data:`SLIP_EVIDENCE` makes a
    slip.
    Returns :data:`SLIPPED` or 0."""
    if quiet:
        _defer(check, 0.0, 0.0, False)
        if holding:
            check.run_samples = 0
            if check.held_since < 0:
                _restart_held(check)
                check.slip_armed = True
        else:
            check.held_since = -1
            check.held_known = False
        return 0
    band = _slip_band(terms[2], check.static_friction)
    if not holding:
        check.held_since = -1
        check.held_known = False
        # the scatter about 0 kg, not the move's own mass, which is known only some way into the move: learned on
        # those fewer samples, the first carry's scatter stayed near its start value, and a light object's mass held
        # never reached the precision the test asks (docs/measurements.md, "Light slips in the first carry")
        learn_scatter(check.scatter, terms, 0.0, FRICTION_VELOCITY, SCATTER_RATE, RESIDUAL_STD**2)
        _learn_empty(check, terms, corrected, band, jerk_variance)
        return 0
    if check.held_since < 0:
        _restart_held(check)
        check.slip_armed = True
    if not check.slip_armed:
        _defer(check, 0.0, 0.0, False)
        return 0
    if check.held_known:
        learn_scatter(check.scatter, terms, check.held_mass, FRICTION_VELOCITY, SCATTER_RATE, RESIDUAL_STD**2)
    information, moment = slip_moments(terms, band, check.scatter + jerk_variance)
    window_information, window_moment = slip_moments(corrected, band, check.scatter)
    testing = False
    if (check.sample - check.held_since) * CONTROL_PERIOD >= SLIP_SETTLE and check.held_information > 0.0:
        held = check.held_moment / check.held_information
        held_std = check.held_information**-0.5
        if _mass_known(check.held_since, check.sample, check.held_information):
            check.held_mass = held
            check.held_known = True
        # test "gone" against "held" once the mass held is known well enough to tell them apart
        if held + SLIP_MASS_CONFIDENCE * held_std >= SLIP_MIN_MASS and held_std < SLIP_PRECISION * held:
            testing = True
            ratio = held * (0.5 * held * information - moment)
            cap = SLIP_EVIDENCE / check.onset_samples
            evidence = check.evidence + min(ratio, cap)
            _shift_scalar(check.window_ratios, held * (0.5 * held * window_information - window_moment))
            check.run_samples = min(check.run_samples + 1, SLIP_WINDOW)
            window = _window_evidence(check, cap)
            pushed = gone_force > FORCE_REFERENCE
            check.evidence = evidence if evidence > 0.0 and not pushed else 0.0
            if pushed:
                check.run_samples = 0
                window = 0.0
            if check.evidence > SLIP_EVIDENCE or window > SLIP_EVIDENCE:
                check.run_samples = 0
                _forget_unlearned(check)
                check.pending_information = check.pending_moment = 0.0
                check.slip_mass = held
                check.slip_armed = False
                check.held_mass = 0.0
                check.held_known = True
                check.force_evidence = 0.0  # the force the loss left was the slip's
                return SLIPPED
    if not testing:
        check.run_samples = 0
    # a collision's force is no model error
    if check.held_known and check.force_evidence == 0.0 and not check.collision:
        _defer(check, window_moment - check.held_mass * window_information, window_information, True)
    else:
        _defer(check, 0.0, 0.0, False)
    if check.force_evidence == 0.0 and not check.collision:  # a collision's samples stay out of the mass held
        # while the CUSUM runs, its samples may be the loss's: they wait outside the mass held, which they would
        # drag towards "gone" (a light object's held mass fell below SLIP_MIN_MASS and its loss was never found),
        # and join it once the CUSUM is back at zero
        check.pending_information += information
        check.pending_moment += moment
        if check.evidence == 0.0:
            check.held_information += check.pending_information
            check.held_moment += check.pending_moment
            check.pending_information = check.pending_moment = 0.0
    return 0


@numba.njit(cache=True)
def _check_force(
    check: np.record, force: NDArray[np.float64], magnitude: float, explained: bool, quiet: bool, still: bool
) -> int:
    """The collision check: a CUSUM over :data:`FORCE_REFERENCE` (:data:`REST_FORCE_REFERENCE` on a sample where
    nothing moves, ``still``) of the platform ``force`` (N, its norm ``magnitude``) the residual leaves with the mass
    held (:func:`check_sample`). It finds a collision once over
    :data:`FORCE_EVIDENCE` on a sample that the other mass the cup may hold does not explain (``explained``: with
    it, the force is under :data:`FORCE_REFERENCE`, still or not: a loss at rest springs the arm back from the weight
    as a place does): such a sample may be the object's loss, which the slip check decides
    (a slip clears this CUSUM). Once found, the CUSUM is capped at :data:`FORCE_EVIDENCE`, and the collision is
    over when it has stayed at zero for the smoother's window. Returns :data:`COLLIDED` or 0."""
    if quiet:
        check.force_evidence = 0.0
        check.collision = False
        return 0
    check.force[:] = force
    check.force_magnitude = magnitude
    evidence = check.force_evidence + magnitude - (REST_FORCE_REFERENCE if still else FORCE_REFERENCE)
    if check.collision and evidence > FORCE_EVIDENCE:  # a detection's worth: the collision can end after the force
        evidence = FORCE_EVIDENCE
    check.force_evidence = evidence if evidence > 0.0 else 0.0
    check.collision_samples = check.collision_samples + 1 if check.force_evidence > 0.0 else 0
    if check.collision:
        check.calm_samples = check.calm_samples + 1 if check.force_evidence == 0.0 else 0
        if check.calm_samples >= SMOOTHER_WINDOW:
            check.collision = False
        return 0
    if check.force_evidence > FORCE_EVIDENCE and not explained:
        check.collision = True
        check.calm_samples = 0
        return COLLIDED
    return 0


@numba.njit(cache=True)
def check_sample(
    state: np.record, model_constants: NDArray[np.uint8], angles: NDArray[np.float64], holding: bool, quiet: bool
) -> int:
    """The model checks of one sample on the monitor's record ``state`` (in place): its arms' clean ``angles``
    (rad), its clean torque (N m) in ``state.clean``, its reference in ``state.reference``, its gripper
    (``holding``) and whether its reading is kept out of the model's equations (``quiet``) go into the smoother; the
    checks run at the state :data:`~controllers.estimation.SMOOTHER_LAG` samples ago, with the model's constants of
    :class:`~controllers.dynamics.DeltaDynamics`. Returns the bits :data:`SLIPPED`, :data:`COLLIDED`,
    :data:`COLLIDING`."""
    torque, reference = state.clean[2], state.reference
    first = not state.started
    if holding != state.gripper_before:
        state.gripper_changed = state.sample
    state.gripper_before = holding
    # the quiet flag rides beside the pending readings, in the slot delayed_state_step fills now
    state.pending_quiet[(state.pending_head + state.pending_count) % (SMOOTHER_LAG + 1)] = quiet
    head, smoothed, previous = delayed_state_step(
        state, angles - reference[0], reference[0], reference[1], reference[2], torque, holding
    )
    valid = reference_torque(model_constants, reference, state.planned_torque, state.planned_regressor)
    planned = state.planned_torque + state.feedforward_mass * state.planned_regressor
    if first:
        for row in range(SMOOTHER_WINDOW + 1):
            state.torques[row, :] = torque
    if valid and not state.reference_started:  # the windows start at the first pose the model can take
        state.reference_started = True
        for row in range(SMOOTHER_WINDOW + 1):
            state.reference_torques[row, :] = planned
            state.reference_regressors[row, :] = state.planned_regressor
    jerk_variance = torque_step_variance(state.torques, torque, state.squared_response)
    # the reference's windows shift with the measured torques' from the first sample, so that their rows align
    model_band = reference_step_bound(state.reference_torques, planned, state.step_weights)
    shift_in(state.reference_regressors, state.planned_regressor)
    if head < 0:
        return 0
    held_then = state.pending_holding[head] != 0
    sliding = _sliding(state, head)
    # the mass the checks take off the checked sample's residual (none while it is not known), and the other mass
    # the cup may hold: none (the object gone) until a slip, then the one it lost (a slip that was not)
    held_known = held_then and state.held_known
    held = state.held_mass if held_known else 0.0
    other = 0.0 if state.slip_armed else state.slip_mass
    # a faulty reading found since lies in the smoothing window too
    quiet_then = state.pending_quiet[head] != 0 or quiet
    # the torque was measured torque_age periods (the plant's physics step) before the encoder sample of its state
    status, terms = model_residual(
        model_constants, smoothed, previous, state.torque_age, state.pending_torque[head].copy(), state.corrections
    )
    if status != kernels.VALID:  # a state the model cannot take (e.g. out of reach): no check
        return COLLIDING if state.collision else 0
    # a pick or a place in the smoothing window steps the acceleration with the mass carried, not with the torque:
    # the smoothed state mixes both masses, and the force along phi is any admissible mass's (0 to the most the cup
    # can hold)
    straddles = state.sample - state.gripper_changed < SMOOTHER_WINDOW
    # the collision check's residual without the smoother's error where the tracking error's acceleration stepped:
    # the plant's with its measured torque, the reference's with the model's torque along it, with the mass the
    # check takes off
    checked_mass = held if held_known and not straddles else state.feedforward_mass
    corrected = terms.copy()
    steps = tracking_step_error(
        state.torques,
        state.torque_response,
        state.reference_torques,
        state.reference_regressors,
        state.acceleration_response,
        checked_mass - state.feedforward_mass,
    )
    for joint in range(3):
        corrected[0, joint] += steps[joint]
    # the platform force the residual leaves with the mass held (or, before it is known, less the mass the cup
    # can hold that explains most of it along phi),
    # and with the other mass; each less what the model's own error explains (platform_force)
    force, magnitude = platform_force(
        corrected,
        held,
        held_known and not straddles,
        held_then or straddles,
        state.charged_coulomb,
        state.breakaway,
        model_band,
        sliding,
    )
    other_magnitude = math.inf  # the other mass only while the gripper holds
    if held_then:
        _, other_magnitude = platform_force(
            corrected, other, True, False, state.charged_coulomb, state.breakaway, model_band, sliding
        )
    found = _check_payload(state, terms, corrected, held_then, quiet_then, jerk_variance, other_magnitude)
    if found & SLIPPED:
        # this sample's force was taken with the mass the slip check has just found gone: it is the loss's, and the
        # collision check takes none of it (kept, it made the next sample, with the lost mass as the other one, a
        # collision)
        state.force[:] = force
        state.force_magnitude = magnitude
        state.collision_samples = 0
        return found | (COLLIDING if state.collision else 0)
    explained = held_then and other_magnitude <= FORCE_REFERENCE
    # nothing moves: the reference still at the checked sample, every joint slower than REST_RATE, and no load let go
    # within the smoothing window (a place: the arm springs back from the weight its drives held)
    still = not np.any(state.pending_reference[head, 1:]) and not (straddles and not holding)
    for joint in range(3):
        still = still and abs(terms[2, joint]) < REST_RATE
    found |= _check_force(state, force, magnitude, explained, quiet_then, still)
    return found | (COLLIDING if state.collision else 0)
