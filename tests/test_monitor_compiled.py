"""The fault monitor's compiled kernels and checks against their definitions (controllers.monitor): the model's
equations, brute-force sums, a finely integrated current loop, and readings of known truth fed to a monitor.

Kernels that evaluate a formula are asked to agree with it to 1e-12 relative, which any wrong term fails by orders of
magnitude; the checks on readings of known truth ask for the detection, its sample and what replaced the reading."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import SMOOTHER_LAG, SMOOTHER_WINDOW, JointStateSmoother
from controllers.monitor import FaultMonitor
from controllers.monitor.compiled import (
    correction_terms,
    learn_scatter,
    loop_output,
    model_residual,
    platform_force,
    reference_step_bound,
    reference_torque,
    slip_moments,
    torque_step_variance,
    tracking_step_error,
)
from controllers.monitor.detector import loop_response
from controllers.monitor.model_check import (
    SLIPPED,
    _check_payload,
    _defer,
    _forget_unlearned,
    _learn_correlation,
    _learn_empty,
    _sliding,
    _slip_band,
    _window_evidence,
    acceleration_step_response,
    lagged_step_weights,
    samples_to_show,
)
from controllers.monitor.step import MONITOR
from controllers.monitor.tuning import (
    ACCELERATION_FACTOR,
    BREAKAWAY_FACTOR,
    CORRELATION_RATE,
    DRIVE_FAULT_DRIFT,
    DRIVE_FAULT_EVIDENCE,
    DRIVE_FAULT_STEP,
    DRIVE_FAULT_WINDOW,
    FORCE_EVIDENCE,
    FORCE_REFERENCE,
    MONITOR_JERK_STD,
    PLANT_STEP_LAG,
    PUSH_SHOWN_SHARE,
    REST_FORCE_REFERENCE,
    REST_RATE,
    SENSOR_QUIET,
    SLIP_SETTLE,
    SLIP_WINDOW,
    SLOWEST_LAG_FACTOR,
    STUCK_SAMPLES,
    TORQUE_MARGIN,
)
from controllers.payload import FRICTION_VELOCITY, RESIDUAL_STD, ModelCorrections, residual_std
from delta_env import kernels
from delta_env.config import MAX_PAYLOAD_MASS
from delta_env.sensors import CONTROL_PERIOD, ENCODER_RESOLUTION, MEASURED_TORQUE_DELAY

PARAMETERS = ModelParameters(rho1=1.8, rho2=0.9, viscous=(2.0, 2.4, 1.7), coulomb=(4.1, 3.4, 4.5))
TOLERANCE = 1e-12
"""Relative agreement asked of a kernel with the formula it evaluates (module docstring)."""
PEAK_TORQUE = 400.0  # N m
TORQUE_AGE = MEASURED_TORQUE_DELAY / CONTROL_PERIOD
"""How many control periods the default plant's torque readings are older than their encoder samples."""


def _same(actual: np.ndarray, expected: np.ndarray) -> None:
    np.testing.assert_allclose(actual, expected, rtol=TOLERANCE, atol=1e-12)


CORRECTIONS = ModelCorrections(platform_mass=0.3, arm_mass_scale=-0.05, friction_scale=np.array([0.1, -0.2, 0.05]))
NO_CORRECTIONS = correction_terms(None, 1.0, 1.0, (0.0,) * 3, (0.0,) * 3)
NO_BAND = np.zeros(3)
NOT_SLIDING = np.zeros(3)


def _samples(count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Smoothed states (3, 3) and the ones before around the workspace's middle, and measured torques (N m)."""
    rng = np.random.default_rng(seed)
    samples = []
    for _ in range(count):
        state = np.stack((rng.uniform(0.1, 0.8, 3), rng.normal(0.0, 3.0, 3), rng.normal(0.0, 60.0, 3)))
        previous = state + rng.normal(0.0, 1e-3, (3, 3))
        samples.append((state, previous, rng.normal(0.0, 40.0, 3)))
    return samples


@pytest.mark.parametrize("corrections", [None, CORRECTIONS])
@pytest.mark.parametrize("forearm_rods", [False, True])
def test_model_residual_is_the_dynamics_residual(corrections: ModelCorrections | None, forearm_rods: bool) -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS, forearm_rods=forearm_rods)
    terms_record = correction_terms(
        corrections, dynamics.inertia, dynamics.gravity_amplitude, PARAMETERS.viscous, PARAMETERS.coulomb
    )
    viscous, coulomb = np.array(PARAMETERS.viscous), np.array(PARAMETERS.coulomb)
    for state, previous, torque in _samples(200):
        status, terms = model_residual(dynamics.model_constants, state, previous, TORQUE_AGE, torque, terms_record)
        assert status == kernels.VALID
        at = state - TORQUE_AGE * (state - previous)
        tau0, phi, force_map = dynamics.torque_regressor_and_force_map(*at)
        residual = torque - tau0
        if corrections is not None:
            theta, theta_dot, theta_ddot = at
            arm = dynamics.inertia * theta_ddot + dynamics.gravity_amplitude * np.cos(theta)
            friction = viscous * theta_dot + coulomb * np.sign(theta_dot)
            residual = residual - (
                corrections.platform_mass * phi
                + corrections.arm_mass_scale * arm
                + corrections.friction_scale * friction
            )
        _same(terms[0], residual)
        _same(terms[1], phi)
        _same(terms[2], at[1])
        _same(terms[3:], force_map)


def test_model_residual_reports_a_state_the_model_cannot_take() -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    state = np.zeros((3, 3))
    state[0] = (0.3, 0.3, np.nan)
    status, _ = model_residual(dynamics.model_constants, state, state, TORQUE_AGE, np.zeros(3), NO_CORRECTIONS)
    assert status != kernels.VALID
    with pytest.raises(ValueError, match=kernels.INVALID_STATE[status]):
        dynamics.torque_regressor_and_force_map(*state)


def _moving_terms(seed: int) -> list[np.ndarray]:
    """:func:`model_residual`'s terms at states whose joints all move faster than REST_RATE."""
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    terms = []
    for state, previous, torque in _samples(100, seed=seed):
        state[1] = np.sign(state[1]) * (REST_RATE + np.abs(state[1]))
        previous[1] = state[1]
        status, sample_terms = model_residual(
            dynamics.model_constants, state, previous, TORQUE_AGE, torque, NO_CORRECTIONS
        )
        assert status == kernels.VALID
        terms.append(sample_terms)
    return terms


def test_platform_force_recovers_a_known_force_less_the_mass_held_or_what_a_possible_mass_explains() -> None:
    # A force F on the platform gives the joint torques r = J^T F, which the force map J^-T takes back to F; a mass
    # held adds m phi, which the check takes off once the mass is known, and before only the part along phi that a
    # mass the cup can hold (0 to MAX_PAYLOAD_MASS) explains: beyond, the rest of it is a force.
    rng = np.random.default_rng(1)
    coulomb = np.array(PARAMETERS.coulomb)
    for terms in _moving_terms(seed=1):
        force = rng.normal(0.0, 100.0, 3)
        external = np.linalg.solve(terms[3:], force)
        phi = terms[1]
        terms[0] = external
        found, magnitude = platform_force(terms, 0.0, False, False, coulomb, 1.5 * coulomb, NO_BAND, NOT_SLIDING)
        np.testing.assert_allclose(found, force, rtol=1e-9, atol=1e-9)
        assert magnitude == pytest.approx(np.linalg.norm(force), rel=1e-9)
        terms[0] = external + 2.5 * phi
        found, _ = platform_force(terms, 2.5, True, True, coulomb, 1.5 * coulomb, NO_BAND, NOT_SLIDING)
        np.testing.assert_allclose(found, force, rtol=1e-9, atol=1e-9)
        # unknown mass: a residual along phi that a possible mass explains is invisible, one across it is the force
        across = external - (external @ phi) / (phi @ phi) * phi
        terms[0] = across + rng.uniform(0.0, MAX_PAYLOAD_MASS) * phi
        found, _ = platform_force(terms, 0.0, False, True, coulomb, 1.5 * coulomb, NO_BAND, NOT_SLIDING)
        np.testing.assert_allclose(found, terms[3:] @ across, rtol=1e-9, atol=1e-9)
        terms[0] = 3.0 * phi
        found, magnitude = platform_force(terms, 0.0, False, True, coulomb, 1.5 * coulomb, NO_BAND, NOT_SLIDING)
        assert magnitude < 1e-9 * np.linalg.norm(terms[3:] @ phi)
        # beyond the masses the cup can hold, by 2 kg either way: 2 kg's force along phi is left
        for mass, beyond in ((-2.0, -2.0), (MAX_PAYLOAD_MASS + 2.0, 2.0)):
            terms[0] = across + mass * phi
            found, _ = platform_force(terms, 0.0, False, True, coulomb, 1.5 * coulomb, NO_BAND, NOT_SLIDING)
            np.testing.assert_allclose(found, terms[3:] @ (across + beyond * phi), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("rate", [0.05, -0.05, 0.0])
def test_platform_force_leaves_out_what_friction_at_rest_can_hold(rate: float) -> None:
    # A joint slower than REST_RATE: its friction may be anything within +-b, where the model charged fc sign(rate),
    # so of its residual only what lies beyond [-b - fc s, b - fc s] is external; a moving joint keeps its residual.
    coulomb = np.array(PARAMETERS.coulomb)
    breakaway = 1.5 * coulomb
    terms = _moving_terms(seed=2)[0]
    terms[2, 1] = rate
    charged = coulomb[1] * np.sign(rate)
    low, high = -breakaway[1] - charged, breakaway[1] - charged
    for residual_1, external_1 in ((high + 2.0, 2.0), (low - 3.0, -3.0), (0.5 * (low + high), 0.0), (high, 0.0)):
        terms[0] = (7.0, residual_1, -4.0)
        force, _ = platform_force(terms, 0.0, False, False, coulomb, breakaway, NO_BAND, NOT_SLIDING)
        np.testing.assert_allclose(force, terms[3:] @ np.array([7.0, external_1, -4.0]), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("rate", [0.05, -0.05, 0.0])
def test_platform_force_takes_a_sliding_joints_friction_as_resisting_its_motion(rate: float, direction: float) -> None:
    # A slow joint whose readings moved has kinetic friction, which resists the motion: within direction [0, b], so
    # a residual beyond the resisting side is external from 0 on (not from -b); on the other side as at rest.
    coulomb = np.array(PARAMETERS.coulomb)
    breakaway = 1.5 * coulomb
    terms = _moving_terms(seed=2)[0]
    terms[2, 1] = rate
    sliding = np.array([0.0, direction, 0.0])
    charged = coulomb[1] * np.sign(rate)
    low, high = sorted((-charged, direction * breakaway[1] - charged))
    cases = ((high + 2.0, 2.0), (low - 3.0, -3.0), (0.5 * (low + high), 0.0), (low, 0.0), (high, 0.0))
    for residual_1, external_1 in cases:
        terms[0] = (7.0, residual_1, -4.0)
        force, _ = platform_force(terms, 0.0, False, False, coulomb, breakaway, NO_BAND, sliding)
        np.testing.assert_allclose(force, terms[3:] @ np.array([7.0, external_1, -4.0]), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_a_joint_slides_where_its_readings_move_across_the_checked_one(direction: float) -> None:
    # The window's tracking errors plus their references, from the reading before the checked one to the one after:
    # joint 0 moves a count there; joint 1 a count later (after the checked reading's neighbour); joint 2's error
    # moves back by the count its reference moved (the joint stays put).
    count = 1e-3
    record = np.zeros(1, dtype=MONITOR)
    state = record[0]
    state.half_count = 0.5 * count
    checked = SMOOTHER_WINDOW - 1 - SMOOTHER_LAG
    errors = np.zeros((SMOOTHER_WINDOW, 3))
    errors[checked + 1 :, 0] = direction * count
    errors[checked + 2 :, 1] = direction * count
    errors[checked + 1 :, 2] = -direction * count
    state.next_slot = 7  # the window's oldest reading, each written twice
    for reading in range(SMOOTHER_WINDOW):
        row = (state.next_slot + reading) % SMOOTHER_WINDOW
        state.readings[row] = state.readings[row + SMOOTHER_WINDOW] = errors[reading]
    head = 4  # the checked sample's slot among the pending readings; its reference's angles are zero
    state.pending_reference[(head + 1) % (SMOOTHER_LAG + 1), 0, 2] = direction * count
    state.reference_before[:] = 0.0
    np.testing.assert_array_equal(_sliding(state, head), [direction, 0.0, 0.0])
    np.testing.assert_array_equal(state.reference_before, 0.0)  # the checked reference, kept for the next sample
    state.reference_before[:] = np.nan  # before the first checked sample: no motion known
    np.testing.assert_array_equal(_sliding(state, head), 0.0)


@pytest.mark.parametrize("rate", [1.0, 0.05])
def test_platform_force_leaves_out_what_the_model_band_can_explain(rate: float) -> None:
    # The smoother's acceleration error may put up to +-w_i into each joint's residual: only what lies beyond it is
    # external, on a moving joint and on top of the friction's interval on a joint at rest.
    coulomb = np.array(PARAMETERS.coulomb)
    breakaway = 1.5 * coulomb
    band = np.array([4.0, 9.0, 2.5])
    terms = _moving_terms(seed=3)[0]
    terms[2, 1] = rate
    resting = abs(rate) < REST_RATE
    charged = coulomb[1] * np.sign(rate) if resting else 0.0
    low = -band[1] - (breakaway[1] + charged if resting else 0.0)
    high = band[1] + (breakaway[1] - charged if resting else 0.0)
    for residual_1, external_1 in ((high + 2.0, 2.0), (low - 3.0, -3.0), (0.5 * (low + high), 0.0), (low, 0.0)):
        terms[0] = (7.0, residual_1, -1.0)
        force, _ = platform_force(terms, 0.0, False, False, coulomb, breakaway, band, NOT_SLIDING)
        np.testing.assert_allclose(force, terms[3:] @ np.array([3.0, external_1, 0.0]), rtol=1e-9, atol=1e-9)


def test_reference_step_bound_is_the_brute_force_sum() -> None:
    rng = np.random.default_rng(5)
    weights = rng.uniform(0.0, 0.9, 26)
    torques = rng.normal(0.0, 30.0, (27, 3))
    window = list(torques.copy())
    for _ in range(30):
        torque = rng.normal(0.0, 30.0, 3)
        window = [*window[1:], torque]
        bound = reference_step_bound(torques, torque, weights)
        _same(torques, np.array(window))
        np.testing.assert_allclose(bound, weights @ np.abs(np.diff(np.array(window), axis=0)), rtol=1e-12)


def test_tracking_step_error_is_the_brute_force_sum() -> None:
    rng = np.random.default_rng(7)
    plant_response, reference_response = rng.normal(0.0, 0.3, 26), rng.normal(0.0, 0.3, 26)
    torques, reference_torques, regressors = (rng.normal(0.0, 30.0, (27, 3)) for _ in range(3))
    error = tracking_step_error(torques, plant_response, reference_torques, regressors, reference_response, 2.5)
    planned = np.diff(reference_torques, axis=0) + 2.5 * np.diff(regressors, axis=0)
    expected = plant_response @ np.diff(torques, axis=0) - reference_response @ planned
    np.testing.assert_allclose(error, expected, rtol=1e-12, atol=1e-9)


def test_reference_torque_is_the_models_at_zero_rates() -> None:
    # The band's torque is the inertial and gravity part: the model's at the reference's pose and acceleration with
    # the rates zero, so that friction's sign and the rates' terms add no step of their own.
    rng = np.random.default_rng(6)
    torque, regressor = np.zeros(3), np.zeros(3)
    for _ in range(20):
        reference = np.stack((rng.uniform(0.1, 0.8, 3), rng.normal(0.0, 3.0, 3), rng.normal(0.0, 300.0, 3)))
        assert reference_torque(DYNAMICS.model_constants, reference, torque, regressor)
        expected_torque, expected_regressor = DYNAMICS.torque_and_payload_regressor(
            reference[0], np.zeros(3), reference[2]
        )
        np.testing.assert_allclose(torque, expected_torque, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(regressor, expected_regressor, rtol=1e-9, atol=1e-9)
    before = torque.copy()
    assert not reference_torque(DYNAMICS.model_constants, np.full((3, 3), np.nan), torque, regressor)
    _same(torque, before)


@pytest.mark.parametrize("lag", [1, 2])
def test_the_band_weights_bound_the_smoothers_error_for_a_step_the_plant_follows_late(lag: int) -> None:
    # The reference's acceleration steps by da between readings m - 1 and m and the plant follows ``lag`` samples
    # later: the tracking error's acceleration is -da over [m, m + lag). The smoother's estimate at its estimated
    # reading, less the true error acceleration there, is what the band must cover: at most the weight times da,
    # reached for the worst lag.
    smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
    weights = lagged_step_weights(acceleration_step_response(smoother), PLANT_STEP_LAG)
    readings, estimated = smoother.weights.shape[1], smoother.history
    times = (np.arange(readings) - estimated) * CONTROL_PERIOD

    def ramp(start_index: int) -> np.ndarray:  # the angle of a unit acceleration step between readings
        start = (start_index - estimated - 0.5) * CONTROL_PERIOD
        return np.where(times > start, 0.5 * (times - start) ** 2, 0.0)

    worst = np.zeros(readings)
    for m in range(readings):
        error = -ramp(m) + ramp(m + lag)
        true = -1.0 if m <= estimated < m + lag else 0.0
        miss = abs(smoother.weights[2] @ error - true)
        assert miss <= weights[m] + 1e-9
        worst[m] = miss
    assert np.max(worst) > 0.5  # the step the smoother spreads most is off by more than half of itself


def test_torque_step_variance_is_the_brute_force_sum() -> None:
    rng = np.random.default_rng(4)
    squared_response = rng.uniform(0.0, 0.3, 26)
    torques = rng.normal(0.0, 30.0, (27, 3))
    window = list(torques.copy())
    for _ in range(40):
        torque = rng.normal(0.0, 30.0, 3)
        window = [*window[1:], torque]
        variance = torque_step_variance(torques, torque, squared_response)
        _same(torques, np.array(window))
        expected = [
            sum(squared_response[m] * (window[m + 1][joint] - window[m][joint]) ** 2 for m in range(26))
            for joint in range(3)
        ]
        _same(variance, np.array(expected))


def test_scatter_is_a_running_mean_square_and_the_slip_moments_weighted_sums() -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    coulomb = np.array(PARAMETERS.coulomb)
    scatter = np.full(3, 16.0)
    expected_scatter = scatter.copy()
    for state, previous, torque in _samples(300, seed=2):
        _, terms = model_residual(dynamics.model_constants, state, previous, TORQUE_AGE, torque, NO_CORRECTIONS)
        residual, phi, theta_dot = terms[0], terms[1], terms[2]
        for joint in range(3):  # the mean square of r - m phi, weight 0.01, on moving joints, at least RESIDUAL_STD^2
            if abs(theta_dot[joint]) > FRICTION_VELOCITY:
                deviation = residual[joint] - 2.5 * phi[joint]
                learned = 0.99 * expected_scatter[joint] + 0.01 * deviation**2
                expected_scatter[joint] = max(learned, RESIDUAL_STD**2)
        learn_scatter(scatter, terms, 2.5, FRICTION_VELOCITY, 0.01, RESIDUAL_STD**2)
        _same(scatter, expected_scatter)
        band = residual_std(theta_dot, coulomb, 0.0)
        weights = [1.0 / (band[joint] ** 2 + scatter[joint]) for joint in range(3)]
        information, moment = slip_moments(terms, band, scatter)
        assert information == pytest.approx(sum(w * p * p for w, p in zip(weights, phi, strict=True)), rel=TOLERANCE)
        expected_moment = sum(w * p * r for w, p, r in zip(weights, phi, residual, strict=True))
        assert moment == pytest.approx(expected_moment, rel=TOLERANCE, abs=1e-12)


def test_the_window_statistic_is_the_largest_window_ratio_over_the_measured_variance_inflation() -> None:
    # Deviations of a moving average of white noise (positively correlated) in runs broken twice: the running means
    # of every window's squared sum and information against a brute-force sum over the runs, then the statistic
    # of a run of ratios against its definition, max_n sum_{last n} min(l_j / kappa_n, cap).
    rng = np.random.default_rng(11)
    record = np.zeros(1, dtype=MONITOR)
    state = record[0]
    noise = rng.normal(size=700)
    deviations = np.convolve(noise, np.ones(4) / 2.0, mode="same")
    informations = rng.uniform(0.5, 3.0, size=700)
    breaks = {250, 251, 480}
    squared_sums, information_sums = np.zeros(SLIP_WINDOW), np.zeros(SLIP_WINDOW)
    run: list[int] = []
    for sample in range(700):
        if sample in breaks:
            state.chain = 0
            run = []
            continue
        _learn_correlation(state, deviations[sample], informations[sample])
        run.append(sample)
        for length in range(1, min(len(run), SLIP_WINDOW) + 1):
            window = run[-length:]
            squared_sums[length - 1] += CORRELATION_RATE * (deviations[window].sum() ** 2 - squared_sums[length - 1])
            information_sums[length - 1] += CORRELATION_RATE * (
                informations[window].sum() - information_sums[length - 1]
            )
    np.testing.assert_allclose(state.squared_sums, squared_sums, rtol=1e-10)
    np.testing.assert_allclose(state.information_sums, information_sums, rtol=1e-10)
    assert state.learned_samples == 700 - len(breaks)
    inflation = squared_sums / information_sums
    # the moving average's correlation: a sum of 4 has 11/4 times the variance of 4 white samples (kappa 1.6 vs 0.6)
    assert inflation[3] > 2.0 * inflation[0]
    ratios = rng.normal(0.3, 1.0, size=SLIP_WINDOW)
    state.window_ratios[:] = ratios
    cap = 1.5
    for run_samples in (1, 7, SLIP_WINDOW):
        state.run_samples = run_samples
        expected = max(
            0.0,
            *(np.minimum(ratios[SLIP_WINDOW - n :] / inflation[n - 1], cap).sum() for n in range(1, run_samples + 1)),
        )
        assert _window_evidence(state, cap) == pytest.approx(expected, rel=1e-12)
    # a window of n samples waits for n / (CORRELATION_RATE SLIP_WINDOW) learned samples (10 n): after 100, the
    # windows of up to 10 samples; after none, no evidence
    state.learned_samples = 100
    longest = int(100 * CORRELATION_RATE * SLIP_WINDOW)
    assert longest == 10
    expected = max(
        0.0, *(np.minimum(ratios[SLIP_WINDOW - n :] / inflation[n - 1], cap).sum() for n in range(1, longest + 1))
    )
    assert _window_evidence(state, cap) == pytest.approx(expected, rel=1e-12)
    state.learned_samples = 0
    assert _window_evidence(state, cap) == 0.0


def test_the_window_statistic_learns_each_sample_a_window_late_and_a_slip_drops_the_samples_still_waiting() -> None:
    # Deviations 1, 2, 3, ... with a break at the fifth: nothing is learned over the first SLIP_WINDOW samples, then
    # each sample exactly SLIP_WINDOW samples after it came (the break too); a slip's drop leaves none of the waiting
    # samples to be learned.
    state = np.zeros(1, dtype=MONITOR)[0]
    for sample in range(SLIP_WINDOW):
        _defer(state, float(sample + 1), 1.0, sample != 4)
        assert state.learned_samples == 0
    _defer(state, 100.0, 1.0, True)
    assert state.learned_samples == 1 and state.window_deviations[-1] == 1.0
    for _ in range(4):
        _defer(state, 100.0, 1.0, True)
    assert state.learned_samples == 4 and state.chain == 0  # the fifth sample's break, learned in its turn
    _defer(state, 100.0, 1.0, True)
    assert state.learned_samples == 5 and state.window_deviations[-1] == 6.0 and state.chain == 1
    _forget_unlearned(state)
    for _ in range(SLIP_WINDOW):
        _defer(state, 100.0, 1.0, True)
    assert state.learned_samples == 5 and state.chain == 0
    _defer(state, 7.0, 1.0, True)
    assert state.learned_samples == 6 and state.window_deviations[-1] == 100.0  # the first sample after the drop


def test_an_empty_moves_offset_along_phi_does_not_inflate_the_window_statistics_correlation() -> None:
    # White residuals r = offset phi + e (e ~ N(0, 1) N m, the scatter 1 N^2 m^2, no friction band): about the move's
    # apparent mass the deviations are e's whatever the offset, so kappa_n is white samples' 1 (within the running
    # means' scatter) for every n. Measured from 0, a 0.2 kg offset enters every window's sum and makes kappa_52
    # about 1 + 52 offset^2 I, about 12 with the mean information I about 5 kg^-2 of these phi.
    def learned(offset: float, from_zero: bool) -> NDArray[np.float64]:
        rng = np.random.default_rng(3)
        state = np.zeros(1, dtype=MONITOR)[0]
        state.empty_since = -1
        state.scatter[:] = 1.0
        for sample in range(6000):
            state.sample = sample
            terms = np.zeros((6, 3))
            terms[1] = rng.uniform(1.0, 1.6, size=3) * rng.choice((-1.0, 1.0), size=3)
            terms[0] = offset * terms[1] + rng.normal(size=3)
            terms[2] = 3.0
            if from_zero:
                _learn_correlation(state, float(terms[0] @ terms[1]), float(terms[1] @ terms[1]))
            else:
                _learn_empty(state, terms, terms, np.zeros(3), np.zeros(3))
        return state.squared_sums / state.information_sums

    white = learned(0.0, from_zero=False)
    np.testing.assert_allclose(learned(0.2, from_zero=False), white, rtol=1e-9)
    assert white[0] == pytest.approx(1.0, abs=0.25)
    assert white[SLIP_WINDOW - 1] < 2.5
    assert learned(0.2, from_zero=True)[SLIP_WINDOW - 1] > 6.0


def test_a_slip_found_within_a_window_teaches_the_window_statistic_none_of_the_losss_samples() -> None:
    # A carry of 2 kg (r = 2 phi + e), then the object gone (r = e) until the check finds the slip: every sample
    # learned by then came before the loss (its deviation about the mass held is e's, small; a loss sample's is
    # -2 phi^T W phi, at least 2 kg^-1 here), and none of the loss's is learned after it either.
    rng = np.random.default_rng(5)
    state = np.zeros(1, dtype=MONITOR)[0]
    state.held_since = state.empty_since = -1
    state.scatter[:] = 1.0
    state.onset_samples = 4
    loss = 400

    def carry(sample: int) -> int:
        state.sample = sample
        terms = np.zeros((6, 3))
        terms[1] = rng.uniform(1.0, 1.6, size=3) * rng.choice((-1.0, 1.0), size=3)
        terms[0] = (2.0 if sample < loss else 0.0) * terms[1] + 0.1 * rng.normal(size=3)
        terms[2] = 3.0
        return _check_payload(state, terms, terms, True, False, np.zeros(3), 0.0)

    assert not any(carry(sample) for sample in range(loss))
    learned_before = state.learned_samples
    # learned: the carry's samples from the one the mass held was known at (after SLIP_SETTLE) to a window ago
    assert 0 < learned_before <= loss - SLIP_WINDOW - round(SLIP_SETTLE / CONTROL_PERIOD)
    found = next(sample for sample in range(loss, loss + SLIP_WINDOW) if carry(sample) == SLIPPED)
    assert found < loss + SLIP_WINDOW // 2
    learned = state.learned_samples - learned_before
    assert learned == found - loss  # those that came a window before each sample, all before the loss
    assert np.all(state.window_deviations[SLIP_WINDOW - learned :] > -1.0)
    for sample in range(found + 1, found + 2 * SLIP_WINDOW):
        carry(sample)
    assert state.learned_samples == learned_before + learned


def test_loop_output_is_the_first_order_loop_sampled_half_a_period_late() -> None:
    # The reading at t_k - d: from the last reading (t_{k-1} - d) towards the command before for d, then towards
    # the command held since t_{k-1}; integrated finely, against the closed form.
    lag, period, age = 1.3e-3, CONTROL_PERIOD, TORQUE_AGE
    hold, keep = (value[0] for value in loop_response([lag], TORQUE_AGE))
    output, substeps = 12.0, 10000
    for target, duration in ((-40.0, age * period), (25.0, (1.0 - age) * period)):
        for _ in range(substeps):
            output += (target - output) * (1.0 - math.exp(-duration / substeps / lag))
    assert loop_output(12.0, -40.0, 25.0, hold, keep) == pytest.approx(output, abs=1e-9)
    assert loop_output(12.0, 25.0, 25.0, hold, keep) == pytest.approx(25.0 + (12.0 - 25.0) * math.exp(-period / lag))


def test_slip_band_is_the_payload_residual_std_without_its_nominal_part() -> None:
    rng = np.random.default_rng(7)
    static_friction = np.array([4.1, 3.4, 4.5])
    for _ in range(200):
        theta_dot = rng.normal(0.0, 1.0, 3) * 10.0 ** rng.uniform(-4.0, 1.0)
        # libm's exp against NumPy's vectorized one: they may differ in the last bit
        _same(_slip_band(theta_dot, static_friction), residual_std(theta_dot, static_friction, 0.0))


# -- the monitor on readings of known truth ----------------------------------------------------------------------

DYNAMICS = DeltaDynamics.nominal(PARAMETERS)
ERROR = np.array([1e-4, -2e-4, 5e-5])
"""The tracking error (rad) of the streams' arm: its angles less the reference's."""
RATE_NOISE = np.array([0.01, -0.02, 0.015])
"""What the streams' rate readings (rad/s) add to the reference's rates: noise of the encoders' difference."""
MOVING = ((0.5, 0.6, 0.4), (40.0, 50.0, 30.0))
"""A reference from 0.4 rad at these rates (rad/s), at these accelerations (rad/s^2): joint torques of 10-30 N m."""
STEADY = ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
"""A reference from 0.4 rad at 1 rad/s."""
AT_REST = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
JUMP_BOUND = ACCELERATION_FACTOR * PEAK_TORQUE / (PARAMETERS.rho1 * DYNAMICS.inertia) * CONTROL_PERIOD**2
"""The largest second difference (rad) of a plausible encoder reading of ideal encoders (docs/design.md)."""


def _monitor(encoder_step: float | None = None, drive_backlash: bool = False) -> FaultMonitor:
    return FaultMonitor(
        DYNAMICS, PEAK_TORQUE, drive_lag=(1e-3,) * 3, encoder_step=encoder_step, drive_backlash=drive_backlash
    )


def _stream(
    samples: int,
    motion: tuple[tuple[float, ...], tuple[float, ...]],
    force: np.ndarray | None = None,
    force_from: int = 0,
) -> list[dict[str, np.ndarray]]:
    """Observations of an arm that follows the reference (``motion``: initial rates, accelerations) with the
    tracking error :data:`ERROR`, its drives delivering the model's torque, plus J^T ``force`` against a force on
    the platform (N) from sample ``force_from`` on; the gripper open."""
    rates, accelerations = (np.array(values) for values in motion)

    def reference(k: float) -> np.ndarray:
        t = k * CONTROL_PERIOD
        return np.stack((0.4 + rates * t + 0.5 * accelerations * t**2, rates + accelerations * t, accelerations))

    observations = []
    for k in range(samples):
        state = reference(k)
        # the torque is measured TORQUE_AGE periods before its encoder sample
        at = reference(k - TORQUE_AGE) + np.stack((ERROR, np.zeros(3), np.zeros(3)))
        torque, _, force_map = DYNAMICS.torque_regressor_and_force_map(*at)
        if force is not None and k >= force_from:
            torque = torque + np.linalg.solve(force_map, force)
        observations.append(
            {
                "joint_angles": state[0] + ERROR,
                "joint_velocities": state[1] + RATE_NOISE,
                "joint_torques": np.array(torque.tolist()),  # a plain float64 array, as the env's
                "reference_angles": state[0],
                "reference_velocities": state[1],
                "reference_accelerations": state[2],
                "gripper": np.zeros(1),
            }
        )
    return observations


def _run(
    monitor: FaultMonitor, observations: list[dict[str, np.ndarray]], missing: tuple[int, ...] = ()
) -> list[dict[str, np.ndarray]]:
    """The clean observations; the command sent before each sample is the torque its drive then delivers (none at
    the first and at ``missing`` samples)."""
    cleans = []
    for k, observation in enumerate(observations):
        command = None if k == 0 or k in missing else observation["joint_torques"].copy()
        cleans.append(monitor.update(observation, command))
    return cleans


def _found(monitor: FaultMonitor, *, collisions: bool = False) -> list[tuple[str, int | None, int]]:
    """(kind, joint, sample) of the detections (without collisions unless asked)."""
    return [
        (event.kind, event.joint, round(event.time_s / CONTROL_PERIOD))
        for event in monitor.events
        if collisions or event.kind != "collision"
    ]


@pytest.mark.parametrize("motion", [MOVING, AT_REST], ids=["moving", "at_rest"])
@pytest.mark.parametrize("missing", [(), (60, 61, 90)], ids=["commands", "missing_commands"])
def test_healthy_readings_pass_unchanged_with_or_without_a_command(
    motion: tuple[tuple[float, ...], tuple[float, ...]], missing: tuple[int, ...]
) -> None:
    # At rest, quantized readings repeat: rightly, so they pass too.
    monitor = _monitor(encoder_step=1e-4)
    observations = _stream(120, motion)
    cleans = _run(monitor, observations, missing)
    assert monitor.events == []
    for observation, clean in zip(observations, cleans, strict=True):
        for key in ("joint_angles", "joint_velocities", "joint_torques"):
            assert clean[key] is observation[key]
    assert (monitor.faulty, monitor.suspect, monitor.quiet_samples, monitor.collision) == (False, False, 0, False)
    assert monitor.held_mass is None and np.linalg.norm(monitor.force) < 1.0


def test_an_encoder_jump_beyond_the_bound_is_a_glitch_replaced_by_the_reference_plus_the_last_error() -> None:
    observations = _stream(100, MOVING)
    true_angle = observations[50]["joint_angles"][1]
    observations[50]["joint_angles"] = observations[50]["joint_angles"] + np.array([0.0, 1.02 * JUMP_BOUND, 0.0])
    monitor = _monitor()
    cleans = _run(monitor, observations)
    assert _found(monitor, collisions=True) == [("encoder_glitch", 1, 50)]
    # the jump on top of the reference's own second difference
    second_difference = 1.02 * JUMP_BOUND + MOVING[1][1] * CONTROL_PERIOD**2
    assert monitor.events[0].magnitude == pytest.approx(second_difference, rel=1e-6)
    assert cleans[50]["joint_angles"][1] == pytest.approx(true_angle, abs=1e-12)
    assert cleans[50]["joint_velocities"][1] == observations[50]["reference_velocities"][1]
    # the rate against the replaced reading is the clean backward difference
    difference = (observations[51]["joint_angles"][1] - true_angle) / CONTROL_PERIOD
    assert cleans[51]["joint_velocities"][1] == pytest.approx(difference, rel=1e-9)


def test_an_encoder_step_within_the_bound_passes() -> None:
    observations = _stream(100, MOVING)
    for observation in observations[50:]:
        observation["joint_angles"] = observation["joint_angles"] + np.array([0.0, 0.98 * JUMP_BOUND, 0.0])
    monitor = _monitor()
    cleans = _run(monitor, observations)
    assert [event for event in monitor.events if event.kind.startswith("encoder")] == []
    assert all(clean["joint_angles"] is seen["joint_angles"] for clean, seen in zip(cleans, observations, strict=True))


def test_a_reading_that_repeats_while_the_joint_moves_is_stuck_after_its_third_repeat() -> None:
    # The reference moves 10 counts per sample, more than the four that make a repeat suspect; the readings
    # replaced step away from the repeats by less than the jump bound until the joint is called stuck.
    step = 1e-4
    observations = _stream(100, STEADY)
    frozen = observations[49]["joint_angles"][0]
    for observation in observations[50:60]:
        observation["joint_angles"] = np.array([frozen, *observation["joint_angles"][1:]])
    monitor = _monitor(encoder_step=step)
    quiet = []
    cleans = []
    for k, observation in enumerate(observations):
        cleans.append(monitor.update(observation, None if k == 0 else observation["joint_torques"].copy()))
        quiet.append(monitor.quiet_samples)
    # the third repeat makes it stuck; every repeat is replaced, and from the second on (replacements in a row) kept
    # out of the model's equations, the first kept as a lone replaced reading is; the clean readings follow the
    # joint again when it reads true, without a glitch
    assert _found(monitor, collisions=True) == [("encoder_stuck", 0, 50 + STUCK_SAMPLES - 1)]
    for k in range(50, 60):
        assert cleans[k]["joint_angles"][0] == pytest.approx(observations[k]["reference_angles"][0] + ERROR[0])
        assert quiet[k] == (0 if k == 50 else SENSOR_QUIET)
    assert quiet[60] == 0 and cleans[60]["joint_angles"] is observations[60]["joint_angles"]


def _joint_stream(
    samples: int, arm: Callable[[float], np.ndarray], reference: Callable[[float], np.ndarray]
) -> list[dict[str, np.ndarray]]:
    """Observations of an arm at ``arm(k)`` ((3, 3): angles, rates, accelerations at sample k) whose drives deliver
    the model's torque for it, following ``reference(k)``; the gripper open."""
    observations = []
    for k in range(samples):
        state, planned = arm(k), reference(k)
        torque, _, _ = DYNAMICS.torque_regressor_and_force_map(*arm(k - TORQUE_AGE))
        observations.append(
            {
                "joint_angles": state[0].copy(),
                "joint_velocities": state[1].copy(),
                "joint_torques": np.array(torque.tolist()),
                "reference_angles": planned[0],
                "reference_velocities": planned[1],
                "reference_accelerations": planned[2],
                "gripper": np.zeros(1),
            }
        )
    return observations


def _start(k: float, start: int, acceleration: np.ndarray) -> np.ndarray:
    """A reference at rest at 0.4 rad that starts at sample ``start`` with ``acceleration`` (rad/s^2), (3, 3)."""
    t = max(k - start, 0.0) * CONTROL_PERIOD
    moving = acceleration if k >= start else np.zeros(3)
    return np.stack((0.4 + 0.5 * acceleration * t**2, acceleration * t, moving))


def test_an_encoder_stuck_as_its_joint_leaves_rest_is_stuck_within_five_samples_and_no_collision() -> None:
    # The reading freezes at rest as the move starts: the joint was not moving, so only its torque, which accelerates
    # it from sample 50 by far more than its friction can hold, and its reference moving away tell that it moves.
    step, acceleration = 1e-4, np.array([200.0, -150.0, 100.0])
    observations = _joint_stream(100, lambda k: _start(k, 50, acceleration), lambda k: _start(k, 50, acceleration))
    frozen = observations[49]["joint_angles"][0]
    for observation in observations[50:80]:
        observation["joint_angles"] = np.array([frozen, *observation["joint_angles"][1:]])
    monitor = _monitor(encoder_step=step)
    cleans = _run(monitor, observations)
    ((kind, joint, sample),) = _found(monitor, collisions=True)
    assert (kind, joint) == ("encoder_stuck", 0) and 50 + STUCK_SAMPLES - 1 <= sample <= 55
    # from then on the joint is read from its reference and its error where it stopped (nil here)
    for k in range(sample, 80):
        assert cleans[k]["joint_angles"][0] == pytest.approx(observations[k]["reference_angles"][0], abs=1e-12)


def test_a_reading_that_repeats_at_rest_while_the_reference_starts_is_not_stuck() -> None:
    # The joint's friction holds it for 10 samples while its reference starts and its torque rises to 3 N m beyond
    # what rest absorbs (twice the breakaway) in the last two: too short to move it a count, a healthy start, not a
    # stuck encoder.
    step, acceleration = 1e-4, np.array([200.0, 0.0, 0.0])
    breakaway = BREAKAWAY_FACTOR * PARAMETERS.coulomb[0]
    observations = _joint_stream(100, lambda k: _start(k, 1000, acceleration), lambda k: _start(k, 50, acceleration))
    held = observations[49]["joint_torques"][0]
    for k, observation in enumerate(observations[50:60]):
        observation["joint_torques"][0] = held + (2.0 * breakaway + 0.5 * TORQUE_MARGIN) * k / 9
    monitor = _monitor(encoder_step=step)
    _run(monitor, observations[:60])
    assert [event for event in monitor.events if event.kind.startswith("encoder")] == []
    assert not monitor.suspect


def test_a_joint_that_brakes_through_a_reversal_repeats_its_reading_rightly() -> None:
    # Joint 0 brakes at 500 rad/s^2 through a stop half-way between samples 51 and 52, which read the same, while its
    # reference runs away at 5 rad/s (a PD that lost its reference): its last step (5 counts) was a suspect's, but
    # braking on, the step it was to make was nil, so the repeat is plausible and nothing is replaced (replaced from
    # the reference, the joint's next readings made encoder glitches and fed the PD false readings).
    step = 1e-4
    braking = np.array([500.0, 0.0, 0.0])

    def arm(k: float) -> np.ndarray:
        t = (k - 51.5) * CONTROL_PERIOD
        return np.stack((0.4 + 0.5 * braking * t**2, braking * t, braking))

    def reference(k: float) -> np.ndarray:
        rates = np.array([5.0, 0.0, 0.0])
        return np.stack((0.4 + rates * (k - 40) * CONTROL_PERIOD, rates, np.zeros(3)))

    observations = _joint_stream(70, arm, reference)
    assert observations[52]["joint_angles"][0] == observations[51]["joint_angles"][0]
    monitor = _monitor(encoder_step=step)
    cleans = _run(monitor, observations)
    assert [event for event in monitor.events if event.kind.startswith("encoder")] == []
    assert all(clean["joint_angles"] is seen["joint_angles"] for clean, seen in zip(cleans, observations, strict=True))


def _turning(k: float) -> np.ndarray:
    """An arm whose joint 0 turns back through a reversal at sample 52.3, at 60 rad/s^2 (three counts a sample at
    sample 50), while joints 1 and 2 run on at 1 and -0.8 rad/s, (3, 3)."""
    t = (k - 52.3) * CONTROL_PERIOD
    accelerations, rates = np.array([60.0, 0.0, 0.0]), np.array([0.0, 1.0, -0.8])
    return np.stack((0.4 + rates * t + 0.5 * accelerations * t**2, rates + accelerations * t, accelerations))


@pytest.mark.parametrize("stuck", [True, False], ids=["stuck", "healthy"])
def test_an_encoder_stuck_as_its_joint_turns_through_a_reversal_is_stuck_within_five_samples(stuck: bool) -> None:
    # Joint 0 turns back slowly (its reference, which it follows, under four counts a sample for 3 ms either side of
    # the turn): its reading stopped changing can be a healthy turn, so neither its last step nor its reference
    # moving away tells. Its torque does: the speeds its readings before allow, under the accelerations its torque
    # allows, take it a count away within a few samples. Quantized to the 17-bit encoders' count; healthy, the same
    # turn repeats its reading for two samples and raises nothing.
    step = ENCODER_RESOLUTION
    observations = _joint_stream(100, _turning, _turning)
    for observation in observations:
        observation["joint_angles"] = np.floor(observation["joint_angles"] / step) * step
    if stuck:
        frozen = observations[49]["joint_angles"][0]
        for observation in observations[50:80]:
            observation["joint_angles"] = np.array([frozen, *observation["joint_angles"][1:]])
    monitor = _monitor(encoder_step=step)
    _run(monitor, observations)
    if not stuck:
        assert monitor.events == []
        return
    ((kind, joint, sample),) = _found(monitor, collisions=True)
    assert (kind, joint) == ("encoder_stuck", 0) and 50 + STUCK_SAMPLES - 1 <= sample <= 53


def test_on_drives_with_backlash_a_turning_joints_repeats_are_not_held_to_the_models_bounds() -> None:
    # The stream above, on drives whose gearheads have backlash: inside the band the rotor, which the encoder reads,
    # turns against its own inertia alone, beyond the rigid model's bounds of its acceleration (3 healthy turns named
    # stuck in 96 carries of the 1-arcmin plant), so the repeats are not taken against them. The stuck encoder is
    # still found, from its joint's reference running away, later.
    step = ENCODER_RESOLUTION
    observations = _joint_stream(100, _turning, _turning)
    for observation in observations:
        observation["joint_angles"] = np.floor(observation["joint_angles"] / step) * step
    frozen = observations[49]["joint_angles"][0]
    for observation in observations[50:80]:
        observation["joint_angles"] = np.array([frozen, *observation["joint_angles"][1:]])
    monitor = _monitor(encoder_step=step, drive_backlash=True)
    _run(monitor, observations)
    ((kind, joint, sample),) = _found(monitor, collisions=True)
    assert (kind, joint) == ("encoder_stuck", 0) and sample > 53


@pytest.mark.parametrize("reading", ["joint_angles", "joint_velocities"])
def test_a_nan_encoder_reading_or_rate_is_detected_once_and_replaced(reading: str) -> None:
    observations = _stream(100, MOVING)
    for observation in observations[50:52]:
        observation[reading] = np.array([*observation[reading][:2], np.nan])
    monitor = _monitor()
    cleans = _run(monitor, observations)
    assert _found(monitor, collisions=True) == [("sensor_nan", 2, 50)]
    for k in (50, 51):
        clean = cleans[k]
        if reading == "joint_angles":  # the reference plus the last good error, at the reference's rate
            assert clean["joint_angles"][2] == pytest.approx(observations[k]["reference_angles"][2] + ERROR[2])
            assert clean["joint_velocities"][2] == observations[k]["reference_velocities"][2]
        else:  # the clean backward difference
            difference = (observations[k]["joint_angles"][2] - observations[k - 1]["joint_angles"][2]) / CONTROL_PERIOD
            assert clean["joint_angles"][2] == observations[k]["joint_angles"][2]
            assert clean["joint_velocities"][2] == pytest.approx(difference, rel=1e-9)


@pytest.mark.parametrize("offset", [TORQUE_MARGIN - 1.0, TORQUE_MARGIN + 1.0, -TORQUE_MARGIN - 1.0])
def test_a_torque_outside_the_current_loops_span_by_the_margin_is_a_glitch_replaced_by_its_prediction(
    offset: float,
) -> None:
    # At rest the command is steady, so the loop's prediction is the command itself.
    observations = _stream(100, AT_REST)
    steady = observations[50]["joint_torques"].copy()
    observations[50]["joint_torques"] = steady + np.array([offset, 0.0, 0.0])
    monitor = _monitor()
    commands = [None if k == 0 else steady for k in range(len(observations))]
    cleans = [monitor.update(observation, command) for observation, command in zip(observations, commands, strict=True)]
    if abs(offset) > TORQUE_MARGIN:
        assert _found(monitor) == [("torque_glitch", 0, 50)]
        assert monitor.events[0].magnitude == pytest.approx(offset)
        np.testing.assert_allclose(cleans[50]["joint_torques"], steady, rtol=1e-12)
    else:
        assert _found(monitor) == []
        assert cleans[50]["joint_torques"] is observations[50]["joint_torques"]


def test_a_drive_that_delivers_a_tenth_of_its_command_is_a_drive_fault_on_the_third_reading_not_a_glitch() -> None:
    observations = _stream(100, MOVING)
    commands = [None] + [observation["joint_torques"].copy() for observation in observations[1:]]
    for observation in observations[50:60]:
        observation["joint_torques"] = observation["joint_torques"] * np.array([1.0, 0.1, 1.0])
    monitor = _monitor()
    cleans = [monitor.update(observation, command) for observation, command in zip(observations, commands, strict=True)]
    assert abs(commands[50][1]) > 2.0 * TORQUE_MARGIN
    # its first reading, short of the command on its side, is held back as a glitch until the next one: not a glitch
    assert _found(monitor)[:1] == [("drive_fault", 1, 52)]
    assert "torque_glitch" not in [kind for kind, *_ in _found(monitor)]
    # the torque lost, replaced by the current loop's prediction (about the command)
    assert monitor.events[0].magnitude == pytest.approx(0.9 * abs(commands[52][1]), rel=0.05)
    assert cleans[52]["joint_torques"][1] == pytest.approx(commands[52][1], rel=0.05)


@pytest.mark.parametrize(("scale", "reported"), [(0.1, 51), (-1.0, 50), (2.0, 50)])
def test_a_lone_torque_glitch_is_reported_at_its_reading_or_the_next_when_it_reads_like_a_drives_loss(
    scale: float, reported: int
) -> None:
    # short of the command on its side (a tenth), a glitch reads like a drive's first lost sample: reported at the
    # next, plausible, reading; beyond the command or of the other sign, at its own
    observations = _stream(100, MOVING)
    commands = [None] + [observation["joint_torques"].copy() for observation in observations[1:]]
    glitch = observations[50]["joint_torques"][1] * (scale - 1.0)
    observations[50]["joint_torques"] = observations[50]["joint_torques"] + np.array([0.0, glitch, 0.0])
    monitor = _monitor()
    for observation, command in zip(observations, commands, strict=True):
        monitor.update(observation, command)
    assert _found(monitor) == [("torque_glitch", 1, reported)]
    assert monitor.events[0].magnitude == pytest.approx(glitch, abs=0.1 * abs(glitch))


def test_a_drive_that_does_not_follow_a_small_step_is_found_by_the_loops_integral_before_the_cusum() -> None:
    # The command of joint 2 steps up by 12 N m at sample 50 and its readings stay where they were: within the span
    # of the last reading and the commands, so no glitch. Over the window, the command less the readings sums to
    # 12 N m per sample since the step; any healthy loop (a lag up to the slowest's) owes at most what its output's
    # change allows, (dy - (1 - h) du) / (1 - q) with dy = 0 and du = 12 N m: -12 (1 - h) N m. The excess passes
    # DRIVE_FAULT_EVIDENCE two samples after the step; the CUSUM of the shortfall, at most DRIVE_FAULT_STEP per
    # sample less DRIVE_FAULT_DRIFT, would have needed 11 (docs/design.md section 6, "Torques").
    observations = _stream(100, AT_REST)
    steady = observations[0]["joint_torques"]
    stepped = steady + np.array([0.0, 0.0, 12.0])
    commands = [None] + [steady if k < 50 else stepped for k in range(1, 100)]
    monitor = _monitor()
    for observation, command in zip(observations, commands, strict=True):
        monitor.update(observation, command)
    hold, keep = (value[0] for value in loop_response([SLOWEST_LAG_FACTOR * 1e-3], TORQUE_AGE))
    window = next(k for k in range(50, 100) if 12.0 * (k - 50) + 12.0 * (1.0 - hold) > DRIVE_FAULT_EVIDENCE)
    evidence, cusum = 0.0, 50
    while evidence <= DRIVE_FAULT_EVIDENCE:
        before = steady[2] if cusum == 50 else stepped[2]
        slowest = loop_output(steady[2], before, stepped[2], hold, keep)
        evidence = max(0.0, evidence + min(slowest - steady[2], DRIVE_FAULT_STEP) - DRIVE_FAULT_DRIFT)
        cusum += 1
    assert (window, cusum - 1) == (52, 61)
    assert _found(monitor) == [("drive_fault", 2, window)]
    # the torque held back over the window, per reading: 12 N m on the two readings since the step, less the bound
    assert monitor.events[0].magnitude == pytest.approx((24.0 + 12.0 * (1.0 - hold)) / DRIVE_FAULT_WINDOW, rel=1e-9)


def _dithered_drive(lag: float, kept: float, seed: int = 0) -> tuple[list[dict[str, np.ndarray]], list]:
    """An arm at rest whose joint 1 is asked 8 N m plus a PD's dither (+-2 N m, uniform, every sample) and whose
    drive, a first-order loop of time constant ``lag`` (s) read TORQUE_AGE periods before the encoders, holds at
    most ``kept`` N m; the readings carry the sensor's noise (0.5 N m). Returns the observations and the commands
    (None at the first)."""
    rng = np.random.default_rng(seed)
    observations = _stream(400, AT_REST)
    steady = observations[0]["joint_torques"].copy()
    hold, keep = (value[0] for value in loop_response([lag], TORQUE_AGE))
    commands: list = [None]
    output, before = steady[1], steady[1]
    for k in range(1, 400):
        asked = steady + np.array([0.0, 8.0 + rng.uniform(-2.0, 2.0), 0.0]) if k >= 100 else steady.copy()
        held = min(asked[1], steady[1] + kept) if k >= 100 else asked[1]
        output = loop_output(output, before, held, hold, keep)
        before = held
        observations[k]["joint_torques"] = steady + np.array([0.0, output - steady[1] + rng.normal(0.0, 0.5), 0.0])
        commands.append(asked)
    return observations, commands


@pytest.mark.parametrize("lag", [0.0, 1e-3, SLOWEST_LAG_FACTOR * 1e-3])
def test_a_drive_that_withholds_a_few_n_m_of_a_dithered_command_is_found_within_the_window(lag: float) -> None:
    # The drive keeps 5 N m of the 8 +- 2 N m asked from sample 100 on: each reading falls short of what the slowest
    # healthy loop would reach from the last by about 1 N m, under the CUSUM's drift, so only the loop's integral
    # finds it; the same command delivered in full by a loop with no lag, the identified one or the slowest healthy
    # one raises nothing.
    for kept, found in ((5.0, True), (math.inf, False)):
        observations, commands = _dithered_drive(lag, kept)
        monitor = _monitor()
        for observation, command in zip(observations, commands, strict=True):
            monitor.update(observation, command)
        drives = [(joint, sample) for kind, joint, sample in _found(monitor, collisions=True) if kind == "drive_fault"]
        if found:
            # 3 N m short on every reading; the bound lets the slowest loop owe its output's 5 N m rise over
            # 1 - q = 0.33 of it, 15 N m: the excess passes the evidence after (20 + 15) / 3, 12 samples (a window
            # or an evidence twice as large would take 17 or more)
            assert len(drives) == 1 and drives[0][0] == 1 and 100 < drives[0][1] <= 113
        else:
            assert monitor.events == []


@pytest.mark.parametrize("magnitude", [50.0, 80.0, 100.0])
def test_a_known_force_on_the_moving_platform_is_estimated_and_found_when_its_cusum_passes_the_evidence(
    magnitude: float,
) -> None:
    # From sample 40 on, the drives also push against a force F on the platform: the joint torques J^T F (the force
    # map's inverse). The check sees F a smoother's lag later, less the little the reference's own torque steps can
    # explain (the model band: this reference accelerates steadily, so a few tenths of a newton); its CUSUM gathers
    # |F| - FORCE_REFERENCE per sample and calls a collision once past FORCE_EVIDENCE (docs/design.md); below the
    # reference it never does.
    direction = np.array([0.6, -0.48, 0.64])
    force = magnitude * direction / np.linalg.norm(direction)
    observations = _stream(100, MOVING, force, force_from=40)
    monitor = _monitor()
    estimates = []
    for k, observation in enumerate(observations):
        monitor.update(observation, None if k == 0 else observation["joint_torques"].copy())
        estimates.append(monitor.force)
    # the torque J^T F changes slowly along the move; the check takes the part of each change that the smoother's
    # lag would have put into the acceleration (the tracking error's steps) off the residual, a few hundredths of a
    # newton here
    found = np.linalg.norm(estimates[60])
    assert 0.98 * magnitude < found < 1.002 * magnitude
    np.testing.assert_allclose(estimates[60] / found, force / magnitude, atol=0.01)
    assert 0.98 * magnitude < np.linalg.norm(estimates[80]) < 1.002 * magnitude
    # These drives step their torque with the force while the arm's acceleration does not change (a drive stiffer
    # than any servo: a real push accelerates the arm first, the torque follows). The check reads a torque step as
    # the arm's (it takes the smoother's lag error g_m d tau off the residual), so for the samples whose estimate
    # leans on readings just after the step (g = -0.52, -0.37, -0.24, ...) it sees part of this force explained:
    # the CUSUM passes the evidence 3 samples later than a steady force's share would.
    samples = math.floor(FORCE_EVIDENCE / (found - FORCE_REFERENCE)) + 1 if found > FORCE_REFERENCE else None
    expected = [] if samples is None else [("collision", None, 40 + SMOOTHER_LAG + samples - 1 + 3)]
    assert _found(monitor, collisions=True) == expected


def _resting_push(seen: float) -> np.ndarray:
    """The force (N) along a fixed direction that the collision check sees as ``seen`` N on the resting arm at the
    streams' pose, beyond what the joints' friction at rest may hold (+-b_i, the smoothed rates nil)."""
    direction = np.array([0.6, -0.48, 0.64]) / np.linalg.norm([0.6, -0.48, 0.64])
    pose = 0.4 + ERROR
    _, _, force_map = DYNAMICS.torque_regressor_and_force_map(pose, np.zeros(3), np.zeros(3))
    joint_torque = np.linalg.solve(force_map, direction)  # per N along the direction
    breakaway = BREAKAWAY_FACTOR * np.array(PARAMETERS.coulomb)

    def seen_force(size: float) -> float:
        torque = size * joint_torque
        return float(np.linalg.norm(force_map @ (torque - np.clip(torque, -breakaway, breakaway))))

    low, high = 0.0, 1000.0
    for _ in range(60):  # bisection: the seen force grows with the size
        low, high = ((low + high) / 2, high) if seen_force((low + high) / 2) < seen else (low, (low + high) / 2)
    return low * direction


@pytest.mark.parametrize(("seen", "found"), [(32.0, False), (50.0, True)])
def test_a_steady_force_on_the_resting_arm_counts_over_the_resting_drift(seen: float, found: bool) -> None:
    # Where nothing moves the CUSUM forgives REST_FORCE_REFERENCE (40 N) a sample, not the moving arm's
    # FORCE_REFERENCE (60 N), so 50 N is a collision (over the moving arm's drift it never was) and 32 N is not.
    assert 32.0 < REST_FORCE_REFERENCE < 50.0 < FORCE_REFERENCE
    observations = _stream(120, AT_REST, _resting_push(seen), force_from=40)
    monitor = _monitor()
    _run(monitor, observations)
    assert np.linalg.norm(monitor.force) == pytest.approx(seen, rel=0.01)
    assert [event.kind for event in monitor.events] == (["collision"] if found else [])


def test_the_resting_drift_waits_for_a_place_to_leave_the_smoothing_window() -> None:
    # The gripper lets go at sample 40 (an empty cup: the drives' torque unchanged) as a steady 50 N comes on. A
    # place springs the arm back from the weight its drives held, so within the smoother's window of the gripper's
    # change the moving arm's 60 N drift holds, and the evidence starts once the place has left the window.
    push = _resting_push(50.0)

    def first_collision(place: bool) -> int:
        observations = _stream(160, AT_REST, push, force_from=40)
        for observation in observations[:40] if place else ():
            observation["gripper"] = np.ones(1)
        monitor = _monitor()
        _run(monitor, observations)
        (found,) = _found(monitor, collisions=True)
        assert found[0] == "collision"
        return found[2]

    window_end = 40 + SMOOTHER_WINDOW  # the first sample whose smoothing window no longer holds the place
    assert first_collision(place=False) < window_end < first_collision(place=True)


def test_the_resting_drift_needs_a_still_reference() -> None:
    # The joints creep at 0.05 rad/s, a quarter of REST_RATE, on a reference that moves: the model's errors of motion
    # are the moving arm's, so the 60 N drift holds and a force the check sees at 40-60 N is no collision.
    creep = ((0.05, 0.05, 0.05), (0.0, 0.0, 0.0))
    assert max(creep[0]) < REST_RATE
    observations = _stream(120, creep, _resting_push(50.0), force_from=40)
    monitor = _monitor()
    _run(monitor, observations)
    assert REST_FORCE_REFERENCE < np.linalg.norm(monitor.force) < FORCE_REFERENCE
    assert monitor.events == []


def test_a_push_that_repeats_a_moving_joints_reading_once_is_found_as_soon_as_without_the_repeat() -> None:
    # A push that stops a moving joint for a sample repeats its encoder reading once: a suspect repeat, replaced by
    # the reference plus the last error. A lone replaced reading is kept in the model's equations; leaving the
    # smoother's window out from the first repeat on (SENSOR_QUIET) hid the campaign's 830-1000 N pushes for 32 ms.
    direction = np.array([0.6, -0.48, 0.64])
    force = 100.0 * direction / np.linalg.norm(direction)

    def detections(repeat: bool) -> tuple[list[tuple[str, int | None, int]], list[int]]:
        observations = _stream(100, STEADY, force, force_from=40)
        if repeat:
            observations[40]["joint_angles"][1] = observations[39]["joint_angles"][1]
        monitor = _monitor(encoder_step=1e-5)
        quiet = []
        for k, observation in enumerate(observations):
            monitor.update(observation, None if k == 0 else observation["joint_torques"].copy())
            quiet.append(monitor.quiet_samples if k != 40 or monitor.suspect else -1)
        return _found(monitor, collisions=True), quiet

    plain, _ = detections(repeat=False)
    repeated, quiet = detections(repeat=True)
    assert quiet == [0] * 100  # the repeat at 40 was suspect, and nothing was left out
    assert [kind for kind, _, _ in repeated] == ["collision"] and repeated == plain
    assert repeated[0][2] - 40 <= SMOOTHER_LAG + 5


def test_an_arm_whose_acceleration_steps_with_its_torque_off_the_reference_shows_no_force() -> None:
    # From sample 40 on the arm accelerates 200 rad/s^2 more than its reference at every joint, its drives delivering
    # the model's torque for it (M da = d tau: a drive faster than the identified one, a feedforward that ignores
    # the object). No force acts. The smoother's acceleration at the checked samples around the step is off by up
    # to half the step (h_m); the check takes off what the torque's step did to it: 1.1 N at most is left, where
    # without it the check saw 217 N and a collision.
    step = np.array([200.0, 200.0, 200.0])
    rates, accelerations = (np.array(values) for values in MOVING)

    def state(k: float) -> np.ndarray:
        # the step at reading 39, the last instant before the torque read with reading 40 (held from 39.5 on)
        t, late = k * CONTROL_PERIOD, max(k - 39.0, 0.0) * CONTROL_PERIOD
        reference = np.stack((0.4 + rates * t + 0.5 * accelerations * t**2, rates + accelerations * t, accelerations))
        departure = np.stack((ERROR + 0.5 * step * late**2, step * late, step * (late > 0.0)))
        return reference, reference + departure

    monitor = _monitor()
    forces = []
    for k in range(90):
        reference, arm = state(k)
        torque = DYNAMICS.torque_regressor_and_force_map(*state(k - TORQUE_AGE)[1])[0]
        observation = {
            "joint_angles": arm[0],
            "joint_velocities": arm[1] + RATE_NOISE,
            "joint_torques": np.array(torque.tolist()),
            "reference_angles": reference[0],
            "reference_velocities": reference[1],
            "reference_accelerations": reference[2],
            "gripper": np.zeros(1),
        }
        monitor.update(observation, None if k == 0 else observation["joint_torques"].copy())
        forces.append(np.linalg.norm(monitor.force))
    assert monitor.events == []
    assert max(forces) < 2.0


def test_a_force_at_rest_is_detected_a_smoothers_lag_later_and_again_after_replaced_readings() -> None:
    # 150 N m more on joint 0 from sample 40 on (commanded and measured: a force holds the platform); two NaN
    # readings in a row at 70 and 71 keep the model's equations out for SENSOR_QUIET samples from 71, and the
    # smoother's lag after: the collision evidence is cleared then and the force found again at once.
    observations = _stream(160, AT_REST)
    for observation in observations[40:]:
        observation["joint_torques"] = observation["joint_torques"] + np.array([150.0, 0.0, 0.0])
    for observation in observations[70:72]:
        observation["joint_angles"] = np.array([np.nan, *observation["joint_angles"][1:]])
    monitor = _monitor()

    def run() -> list[tuple[str, int | None, int]]:
        monitor.reset()
        _run(monitor, observations)
        return _found(monitor, collisions=True)

    first = run()
    found_again = 71 + SENSOR_QUIET + SMOOTHER_LAG + 1
    # a torque step that does not move the arm shows a sample before the checked state reaches it: the smoother's
    # estimate there already leans a third on the reading after the step (torque_step_response), which the arm did
    # not follow
    found = 40 + SMOOTHER_LAG - 1
    assert first == [("collision", None, found), ("sensor_nan", 0, 70), ("collision", None, found_again)]
    assert monitor.events[0].magnitude > 100.0 and monitor.collision
    state = monitor._state_bytes.tobytes()
    assert run() == first and monitor._state_bytes.tobytes() == state


def test_the_model_checks_lag_the_smoothed_tracking_error_behind_the_reference() -> None:
    """The state the checks take is the reference a smoother's lag ago plus the JointStateSmoother estimate of the
    tracking error (its window, start and lag)."""
    rng = np.random.default_rng(8)
    monitor = _monitor()
    smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
    references = []
    for k in range(60):
        reference = np.stack((0.4 + 0.01 * k * np.ones(3), rng.normal(0.0, 1.0, 3), rng.normal(0.0, 9, 3)))
        angles = reference[0] + rng.normal(0.0, 1e-4, 3)
        if k == 0:
            smoother.reset(angles - reference[0])
        expected = smoother.update_state(angles - reference[0]).copy()
        references.append(reference)
        torque = rng.normal(0, 5, 3)
        observation = {
            "joint_angles": angles,
            "joint_velocities": reference[1],
            "joint_torques": torque,
            "reference_angles": reference[0],
            "reference_velocities": reference[1],
            "reference_accelerations": reference[2],
            "gripper": np.zeros(1),
        }
        clean = monitor.update(observation, None if k == 0 else torque)
        assert clean["joint_angles"] is angles
        if k >= SMOOTHER_LAG:
            _same(monitor._field["previous"][0], references[k - SMOOTHER_LAG] + expected)


def test_readings_that_are_not_three_vectors_are_refused() -> None:
    observation = _stream(1, AT_REST)[0]
    observation["joint_torques"] = np.zeros(2)
    with pytest.raises(ValueError, match="must be 3-vectors"):
        _monitor().update(observation, None)


def test_samples_to_show_counts_the_samples_until_every_older_position_shows_the_share() -> None:
    # a step entering at the newest position m = 5 moves one position older per sample; |h_m| <= 1 - share for good
    # from position 2 on (position 3, 0.4, is the oldest beyond it), so 5 - 2 = 3 samples
    response = np.array([0.0, 0.05, -0.1, 0.4, 0.2, 0.01])
    assert samples_to_show(response, 0.75) == 3
    assert samples_to_show(response, 0.95) == 4  # |h_2| = 0.1 > 0.05: to position 1
    assert samples_to_show(np.zeros(4), 0.9) == 0
    # the monitor's own smoother: 8 samples until 7/8 of a step shows (the slip check's cap, PUSH_SHOWN_SHARE)
    smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
    assert samples_to_show(acceleration_step_response(smoother), PUSH_SHOWN_SHARE) == 8
