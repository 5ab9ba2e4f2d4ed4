"""The fault monitor's model checks, one compiled call per sample: the collision check (an external force on the
platform) and the slip check (payload consistency), at the smoothed joint state a smoother's lag behind the sample
(docs/design.md section 6, "Fault monitor").

:class:`ModelCheck` keeps its whole state in one record (:data:`MODEL_CHECK`) that :func:`check_sample` updates in
place: the smoother's window of tracking errors, the readings it lags behind, the CUSUMs and the mass held.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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
    encoders_plausible,
    learn_scatter,
    model_residual,
    platform_force,
    slip_moments,
    torque_step_variance,
    torques_plausible,
)
from controllers.monitor.tuning import (
    DRIVE_FAULT_DRIFT,
    DRIVE_FAULT_STEP,
    FORCE_EVIDENCE,
    FORCE_REFERENCE,
    HELD_MASS_STD,
    INITIAL_RESIDUAL_STD,
    MONITOR_JERK_STD,
    REST_RATE,
    SCATTER_RATE,
    SLIP_EVIDENCE,
    SLIP_MIN_MASS,
    SLIP_PRECISION,
    SLIP_SETTLE,
    TORQUE_MARGIN,
)
from controllers.payload import FRICTION_CORRELATION_SAMPLES, FRICTION_VELOCITY, RESIDUAL_STD, TORQUE_AGE
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD

SLIPPED, COLLIDED, COLLIDING = 1, 2, 4
"""Bits of :func:`check_sample`'s result: a slip detected on this sample, a collision detected on it, a collision
under way after it."""

MODEL_CHECK = np.dtype(
    (
        np.record,
        [
            *DELAYED_STATE_FIELDS,
            # the measured torques of the window and the one before, and the smoother's response to a step
            ("torques", np.float64, (SMOOTHER_WINDOW + 1, 3)),
            ("squared_response", np.float64, (SMOOTHER_WINDOW,)),
            ("pending_quiet", np.uint8, (SMOOTHER_LAG + 1,)),  # beside the pending readings
            # the friction the residual charges and what a joint at rest may hold, the slip check's friction band
            ("charged_coulomb", np.float64, (3,)),
            ("breakaway", np.float64, (3,)),
            ("static_friction", np.float64, (3,)),
            # the collision check
            ("force", np.float64, (3,)),
            ("force_magnitude", np.float64),
            ("force_evidence", np.float64),
            ("collision", np.bool_),
            ("collision_samples", np.int64),
            # the slip check
            ("scatter", np.float64, (3,)),
            ("held_since", np.int64),
            ("held_known", np.bool_),
            ("held_mass", np.float64),
            ("held_information", np.float64),
            ("held_moment", np.float64),
            ("evidence", np.float64),
            ("slip_armed", np.bool_),
            ("slip_mass", np.float64),
        ],
    )
)
"""The state of :func:`check_sample`, passed as the record's bytes."""


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


class ModelCheck:
    """The collision and slip checks of a :class:`~controllers.monitor.FaultMonitor` (its model's residual).

    The state it checks is a smoother's: the tracking error (the angles less the reference) smoothed by a fixed-lag
    smoother, the reference's own state added back. The reference is known, so the smoother's motion model (white
    jerk) carries only the error's jerk; a smoother of the angles themselves lags the planned jerk of time-optimal
    moves. Each smoothed state is paired with its sample's torque, gripper and quiet flag, at the instant the torque
    was measured.

    Where the error's acceleration still steps (a controller that steps its torque, as the residual policy does every
    10 ms), the smoother smears the step over its window: a step da between readings m - 1 and m leaves the estimated
    sample's acceleration off by h_m da, h the smoother's response to a unit step. The joint's torque steps with its
    acceleration (I da), so the measured torque's steps in the window give the model torque's error variance
    sum_m h_m^2 (tau_m - tau_{m-1})^2 (N^2 m^2), per joint, which the slip check adds to its residual variance.

    Args:
        static_friction: The identified Coulomb friction per joint (N m): the slip check's friction band at rest.
    """

    lag = SMOOTHER_LAG
    """Readings between a sample and the checks at it (the smoother's lag)."""

    def __init__(self, static_friction: Sequence[float]) -> None:
        self.state = np.zeros(1, dtype=MODEL_CHECK).view(np.uint8)
        """The :data:`MODEL_CHECK` record's bytes (:func:`healthy_sample` takes them)."""
        self._state = self.state.view(MODEL_CHECK)
        smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
        self._state["weights"] = smoother.weights
        self._state["squared_response"] = acceleration_step_response(smoother) ** 2
        self._state["static_friction"] = static_friction
        self.reset()

    def reset(self) -> None:
        """Start an episode: an empty window, no collision, nothing held."""
        state = self._state
        for field in ("started", "has_previous", "collision", "held_known", "slip_armed"):
            state[field] = False
        for field in ("next_slot", "pending_head", "pending_count", "collision_samples"):
            state[field] = 0
        for field in ("force", "force_magnitude", "force_evidence", "held_mass", "held_information", "held_moment"):
            state[field] = 0.0
        state["evidence"] = state["slip_mass"] = 0.0
        state["held_since"] = -1
        state["scatter"] = INITIAL_RESIDUAL_STD**2

    def set_friction(self, charged_coulomb: NDArray[np.float64], breakaway: NDArray[np.float64]) -> None:
        """The Coulomb friction (N m) the residual charges per joint, and the friction up to which a joint at rest may
        hold (its breakaway, N m)."""
        self._state["charged_coulomb"] = charged_coulomb
        self._state["breakaway"] = breakaway

    def check(
        self,
        model_constants: NDArray[np.uint8],
        corrections: NDArray[np.uint8],
        angles: NDArray[np.float64],
        reference: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
        torque: NDArray[np.float64],
        holding: bool,
        quiet: bool,
        sample: int,
    ) -> int:
        """Take one clean reading (rad) with its reference's angles, rates and accelerations (rad, rad/s, rad/s^2),
        its torque (N m), gripper and quiet flag; check the state :attr:`lag` samples ago; return the bits
        :data:`SLIPPED`, :data:`COLLIDED`, :data:`COLLIDING`. ``sample`` is the reading's index since the reset.
        The readings must be finite (the monitor's clean ones are): nothing here checks them."""
        return check_sample(
            self.state, model_constants, corrections, angles, *reference, torque, holding, quiet, sample
        )

    @property
    def force(self) -> NDArray[np.float64]:
        """The last external force estimate on the platform (N), (3,)."""
        return self._state["force"][0].copy()

    @property
    def force_magnitude(self) -> float:
        """The norm of :attr:`force` (N)."""
        return float(self._state["force_magnitude"][0])

    @property
    def collision_samples(self) -> int:
        """Checked samples since the collision evidence began to grow (0 while there is none)."""
        return int(self._state["collision_samples"][0])

    @property
    def held_mass(self) -> float | None:
        """The mass (kg) believed held, once known well enough (0 after a slip); None otherwise."""
        return float(self._state["held_mass"][0]) if self._state["held_known"][0] else None

    @property
    def slip_mass(self) -> float:
        """The mass (kg) held when the last slip was detected."""
        return float(self._state["slip_mass"][0])


@numba.njit(cache=True)
def _restart_held(check: np.record, sample: int) -> None:
    """Measure the mass held afresh from ``sample`` on (at a pick, or after a collision)."""
    check.held_since = sample
    check.held_information = 0.0
    check.held_moment = 0.0
    check.evidence = 0.0
    check.held_known = False


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
    holding: bool,
    quiet: bool,
    jerk_variance: NDArray[np.float64],
    sample: int,
) -> int:
    """The slip check: a CUSUM of the log-likelihood ratio of "the object is gone" (r = e) against "the mass held
    since the pick is still there" (r = m phi + e), e weighted as the payload estimator weights it; r and phi are
    ``terms`` of :func:`model_residual`. Returns :data:`SLIPPED` or 0."""
    if not holding:
        check.held_since = -1
        check.held_known = False
        if not quiet:
            learn_scatter(check.scatter, terms, 0.0, FRICTION_VELOCITY, SCATTER_RATE, RESIDUAL_STD**2)
        return 0
    if check.held_since < 0:
        _restart_held(check, sample)
        check.slip_armed = True
    if quiet or not check.slip_armed:
        return 0
    if check.held_known:
        learn_scatter(check.scatter, terms, check.held_mass, FRICTION_VELOCITY, SCATTER_RATE, RESIDUAL_STD**2)
    band = _slip_band(terms[2], check.static_friction)
    information, moment = slip_moments(terms, band, check.scatter + jerk_variance)
    if (sample - check.held_since) * CONTROL_PERIOD >= SLIP_SETTLE and check.held_information > 0.0:
        held = check.held_moment / check.held_information
        if check.held_information**-0.5 < HELD_MASS_STD:
            check.held_mass = held
            check.held_known = True
        # test "gone" against "held" once the mass held is known well enough to tell them apart
        if held >= SLIP_MIN_MASS and check.held_information**-0.5 < SLIP_PRECISION * held:
            evidence = check.evidence + held * (0.5 * held * information - moment)
            check.evidence = evidence if evidence > 0.0 else 0.0
            if check.evidence > SLIP_EVIDENCE:
                check.slip_mass = held
                check.slip_armed = False
                check.held_mass = 0.0
                check.held_known = True
                return SLIPPED
    if check.force_evidence == 0.0:  # a collision's samples stay out of the mass held
        check.held_information += information
        check.held_moment += moment
    return 0


@numba.njit(cache=True)
def _check_force(check: np.record, terms: NDArray[np.float64], holding: bool, quiet: bool, sample: int) -> int:
    """The collision check: a CUSUM of the platform force F = J^-T r over :data:`FORCE_REFERENCE`, r the model's
    residual (``terms`` of :func:`model_residual`) less the mass held times phi (or, before the mass is known,
    without its part along phi), less on joints slower than :data:`REST_RATE` what friction up to the breakaway
    can hold. Returns :data:`COLLIDED` or 0."""
    if quiet:
        check.force_evidence = 0.0
        check.collision = False
        return 0
    held_known = check.held_known
    force, magnitude = platform_force(
        terms,
        check.held_mass if held_known else 0.0,
        holding and held_known,
        holding,
        check.charged_coulomb,
        check.breakaway,
        REST_RATE,
    )
    check.force[:] = force
    check.force_magnitude = magnitude
    evidence = check.force_evidence + magnitude - FORCE_REFERENCE
    check.force_evidence = evidence if evidence > 0.0 else 0.0
    check.collision_samples = check.collision_samples + 1 if check.force_evidence > 0.0 else 0
    if check.force_evidence > FORCE_EVIDENCE and not check.collision:
        check.collision = True
        return COLLIDED
    if check.force_evidence == 0.0 and check.collision:
        check.collision = False
        if check.held_since >= 0 and check.slip_armed:  # what the collision left in the mass held: afresh
            _restart_held(check, sample)
    return 0


@numba.njit(cache=True)
def check_sample(
    check_bytes: NDArray[np.uint8],
    model_constants: NDArray[np.uint8],
    corrections: NDArray[np.uint8],
    angles: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
    holding: bool,
    quiet: bool,
    sample: int,
) -> int:
    """One sample of :meth:`ModelCheck.check` on the :data:`MODEL_CHECK` record ``check_bytes`` (in place); the
    model's constants of :class:`~controllers.dynamics.DeltaDynamics` and the corrections of
    :func:`~controllers.monitor.compiled.correction_terms`."""
    check = check_bytes.view(MODEL_CHECK)[0]
    first = not check.started
    # the quiet flag rides beside the pending readings, in the slot delayed_state_step fills now
    check.pending_quiet[(check.pending_head + check.pending_count) % (SMOOTHER_LAG + 1)] = quiet
    head, state, previous = delayed_state_step(
        check, angles - reference_angles, reference_angles, reference_rates, reference_accelerations, torque, holding
    )
    if first:
        for row in range(SMOOTHER_WINDOW + 1):
            check.torques[row, :] = torque
    jerk_variance = torque_step_variance(check.torques, torque, check.squared_response)
    if head < 0:
        return 0
    held_then = check.pending_holding[head] != 0
    # a faulty reading found since lies in the smoothing window too
    quiet_then = check.pending_quiet[head] != 0 or quiet
    # the torque was measured TORQUE_AGE periods (MEASURED_TORQUE_DELAY) before the encoder sample of its state
    status, terms = model_residual(
        model_constants, state, previous, TORQUE_AGE, check.pending_torque[head].copy(), corrections
    )
    if status != kernels.VALID:  # a state the model cannot take (e.g. out of reach): no check
        return COLLIDING if check.collision else 0
    found = _check_payload(check, terms, held_then, quiet_then, jerk_variance, sample)
    found |= _check_force(check, terms, held_then, quiet_then, sample)
    return found | (COLLIDING if check.collision else 0)


SENSORS = np.dtype(
    (
        np.record,
        [
            ("last", np.float64, (3,)),
            ("before", np.float64, (3,)),
            ("raw_previous", np.float64, (3,)),
            ("error", np.float64, (3,)),
            ("torque_measured", np.float64, (3,)),
            ("command_before", np.float64, (3,)),
            ("jump_bound", np.float64),
            ("stuck_step", np.float64),
            ("slowest_hold", np.float64, (3,)),
            ("slowest_keep", np.float64, (3,)),
            ("peak_torque", np.float64),
        ],
    )
)
"""The sensor checks' state that :func:`healthy_sample` reads and writes: the last two clean readings, the last raw
one and the tracking error after it (rad), the last measured torque and the command held before the last one
(N m); and their constants: the encoder jump bound and stuck step (rad), the slowest healthy current loop's
:func:`~controllers.monitor.detector.loop_response`, the drive's peak torque (N m)."""

NOT_HEALTHY = -1
""":func:`healthy_sample`'s result for a sample whose readings its fast paths do not pass: nothing was changed."""


@numba.njit(cache=True)
def healthy_sample(
    sensor_bytes: NDArray[np.uint8],
    check_bytes: NDArray[np.uint8],
    model_constants: NDArray[np.uint8],
    corrections: NDArray[np.uint8],
    raw: NDArray[np.float64],
    rates: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
    command: NDArray[np.float64],
    holding: bool,
    quiet: bool,
    sample: int,
) -> int:
    """A whole sample of a :class:`~controllers.monitor.FaultMonitor` whose last sample flagged nothing, if its
    readings pass the encoder and torque fast paths (:func:`~controllers.monitor.compiled.encoders_plausible`,
    :func:`~controllers.monitor.compiled.torques_plausible`): the :data:`SENSORS` record ``sensor_bytes`` takes them
    as the clean ones (in place), and the model checks run on them (:func:`check_sample`'s bits). Else
    :data:`NOT_HEALTHY`, and neither record changes."""
    sensors = sensor_bytes.view(SENSORS)[0]
    if not encoders_plausible(
        raw,
        rates,
        sensors.last,
        sensors.before,
        sensors.raw_previous,
        reference_rates,
        sensors.jump_bound,
        sensors.stuck_step,
        CONTROL_PERIOD,
    ):
        return NOT_HEALTHY
    if not torques_plausible(
        torque,
        sensors.torque_measured,
        command,
        sensors.command_before,
        sensors.slowest_hold,
        sensors.slowest_keep,
        sensors.peak_torque,
        TORQUE_MARGIN,
        DRIVE_FAULT_DRIFT,
        DRIVE_FAULT_STEP,
    ):
        return NOT_HEALTHY
    sensors.before[:] = sensors.last
    sensors.last[:] = raw
    sensors.raw_previous[:] = raw
    sensors.error[:] = raw - reference_angles
    sensors.torque_measured[:] = torque
    sensors.command_before[:] = command
    return check_sample(
        check_bytes,
        model_constants,
        corrections,
        raw,
        reference_angles,
        reference_rates,
        reference_accelerations,
        torque,
        holding,
        quiet,
        sample,
    )
