"""Estimators against known truth: payload RLS, RTS smoother and causal joint filter."""

import numpy as np
import pytest
from filterpy.common import Q_continuous_white_noise, kinematic_state_transition
from filterpy.kalman import KalmanFilter
from numpy.testing import assert_allclose

from controllers import estimation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import (
    FIXED_LAG_JERK_STD,
    JointStateFilter,
    JointStateSmoother,
    PayloadRLS,
    smooth_joint_motion,
)
from delta_env.sensors import ENCODER_NOISE_STD, ENCODER_RESOLUTION

DT = 1e-3


def textbook_rls(regressors: np.ndarray, outputs: np.ndarray, forgetting_factor: float, p0: float) -> np.ndarray:
    """Exponentially weighted RLS (Ljung), vector outputs: the estimate after each sample."""
    estimate, p, estimates = np.zeros(1), np.array([[p0]]), []
    for phi, y in zip(regressors, outputs, strict=True):
        h = phi[:, None]
        gain = p @ h.T @ np.linalg.inv(forgetting_factor * np.eye(3) + h @ p @ h.T)
        estimate = estimate + gain @ (y - h @ estimate)
        p = (p - gain @ h @ p) / forgetting_factor
        estimates.append(estimate[0])
    return np.array(estimates)


def payload_data(random_joint_states, mass: np.ndarray, noise_std: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """phi at random pick-cycle states and y = mp phi + white noise, one sample per entry of ``mass``."""
    phi = DeltaDynamics.nominal().payload_regressor(*random_joint_states(len(mass), seed=seed))
    noise = np.random.default_rng(seed + 1000).normal(0.0, noise_std, phi.shape)
    return phi, mass[:, None] * phi + noise


def run_rls(rls: PayloadRLS, phi: np.ndarray, y: np.ndarray, reset_at: int | None = None) -> np.ndarray:
    """Mass estimates (kg) after each sample; ``reset_covariance()`` before sample ``reset_at``."""
    estimates = []
    for n, (phi_n, y_n) in enumerate(zip(phi, y, strict=True)):
        if n == reset_at:
            rls.reset_covariance()
        estimates.append(rls.update(phi_n, y_n))
    return np.array(estimates)


def encoder_readings(theta: np.ndarray, seed: int) -> np.ndarray:
    """17-bit encoder angles (rad) of a motion, with half a step of noise ahead of the quantizer."""
    noise = np.random.default_rng(seed).normal(0.0, 0.5 * ENCODER_RESOLUTION, theta.shape)
    return np.round((theta + noise) / ENCODER_RESOLUTION) * ENCODER_RESOLUTION


def pick_move(joint_min_jerk_move, duration: float) -> tuple[np.ndarray, ...]:
    """A fast joint move of 0.9 rad with 100 ms at rest before and after, sampled at 1 kHz."""
    theta, theta_dot, theta_ddot = joint_min_jerk_move(
        np.array([-0.3, 0.5, 0.2]), np.array([0.6, -0.2, 0.9]), duration, DT
    )
    rest = ((100, 100), (0, 0))
    return np.pad(theta, rest, mode="edge"), np.pad(theta_dot, rest), np.pad(theta_ddot, rest)


def rms(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(error**2)))


@pytest.mark.parametrize("forgetting_factor", [1.0, 0.99, 0.9])
def test_payload_rls_is_textbook_rls_with_forgetting(forgetting_factor) -> None:
    rng = np.random.default_rng(0)
    phi, y = rng.normal(0.0, 10.0, (300, 3)), rng.normal(0.0, 20.0, (300, 3))
    rls = PayloadRLS(forgetting_factor=forgetting_factor, noise_std=2.0, initial_variance=4.0)
    estimates = run_rls(rls, phi, y)
    # The Kalman filter's P is the RLS matrix P scaled by the noise variance.
    assert_allclose(estimates, textbook_rls(phi, y, forgetting_factor, p0=4.0 / 2.0**2), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("forgetting_factor", [1.0, 0.999])
def test_payload_rls_is_the_batch_least_squares_of_its_rows(forgetting_factor) -> None:
    # After n samples, RLS with forgetting is the weighted least squares of every row so far with the prior (mass
    # 0.3 kg, variance 4 kg^2), sample k weighted by lambda^(n - k) and the prior by lambda^n; with lambda = 1 the
    # plain batch least squares of the same rows.
    rng = np.random.default_rng(8)
    phi = rng.normal(0.0, 10.0, (500, 3))
    y = 2.5 * phi + rng.normal(0.0, 2.0, phi.shape)
    rls = PayloadRLS(forgetting_factor=forgetting_factor, noise_std=2.0, initial_variance=4.0, initial_mass=0.3)
    for n in range(1, len(phi) + 1):
        rls.update(phi[n - 1], y[n - 1])
        weights = forgetting_factor ** np.arange(n - 1, -1, -1.0)
        information = forgetting_factor**n / 4.0 + np.sum(weights[:, None] * phi[:n] ** 2) / 2.0**2
        moment = forgetting_factor**n * 0.3 / 4.0 + np.sum(weights[:, None] * phi[:n] * y[:n]) / 2.0**2
        assert rls.x == pytest.approx(moment / information, rel=1e-10)
        assert rls.variance == pytest.approx(1.0 / information, rel=1e-10)


def test_payload_rls_update_is_the_closed_form_of_one_sample() -> None:
    # one sample of phi.phi = 3 and phi.y = 4 from x = 0.5, P = 2, R = 1: P+ = 1 / (1/2 + 3) and
    # x+ = x + P+ (4 - 3 x)
    rls = PayloadRLS(forgetting_factor=1.0, noise_std=1.0, initial_variance=2.0, initial_mass=0.5)
    assert rls.update_moments(3.0, 4.0) == pytest.approx(0.5 + 2.0 / 7.0 * 2.5, rel=1e-15)
    assert rls.variance == pytest.approx(2.0 / 7.0, rel=1e-15)
    rls.reset(1.0, 0.01)
    assert (rls.mass, rls.variance) == (1.0, 0.01)
    rls.reset_covariance()
    assert (rls.x, rls.P) == (1.0, 2.0)


@pytest.mark.parametrize("forgetting_factor", [1.0, 0.99])
def test_payload_rls_normalized_innovation_has_unit_variance_where_the_model_holds(
    random_joint_states, forgetting_factor: float
) -> None:
    # y = phi mp + e with e ~ N(0, R I) and mp off the estimate by N(0, P-), P- = P / lambda: the score
    # phi.y - phi.phi x has the variance phi.phi R + (phi.phi)^2 P-, so the normalized innovation is a standard normal;
    # a sample whose mass lies 10 standard deviations of its score away reads 10
    rng = np.random.default_rng(3)
    noise_std, variance = 2.0, 0.04
    rls = PayloadRLS(forgetting_factor=forgetting_factor, noise_std=noise_std, initial_variance=variance)
    rls.reset(1.5)
    phi = DeltaDynamics.nominal().payload_regressor(*random_joint_states(20000, seed=4))
    mass = 1.5 + rng.normal(0.0, np.sqrt(variance / forgetting_factor), len(phi))
    y = mass[:, None] * phi + rng.normal(0.0, noise_std, phi.shape)
    information, moment = np.sum(phi * phi, axis=1), np.sum(phi * y, axis=1)
    innovations = np.array([rls.normalized_innovation(i, m) for i, m in zip(information, moment, strict=True)])
    assert np.std(innovations) == pytest.approx(1.0, abs=0.03) and abs(np.mean(innovations)) < 0.03
    score_std = np.sqrt(information[0] * (noise_std**2 + information[0] * variance / forgetting_factor))
    assert rls.normalized_innovation(information[0], information[0] * 1.5 + 10.0 * score_std) == pytest.approx(10.0)
    assert rls.normalized_innovation(0.0, 0.0) == 0.0
    assert (rls.x, rls.P) == (1.5, variance)  # it reads the state and changes nothing


@pytest.mark.parametrize("mass", [0.5, 3.8])
@pytest.mark.parametrize("forgetting_factor", [1.0, 0.999])
def test_payload_rls_converges_to_the_mass(random_joint_states, mass, forgetting_factor) -> None:
    noise_std = 2.0
    phi, y = payload_data(random_joint_states, np.full(2000, mass), noise_std, seed=1)
    rls = PayloadRLS(forgetting_factor=forgetting_factor, noise_std=noise_std, initial_variance=4.0)
    run_rls(rls, phi, y)
    assert abs(rls.mass - mass) < 4.0 * np.sqrt(rls.variance)
    assert np.sqrt(rls.variance) < 0.01, "2000 samples at 2 N m of noise pin the mass to grams"
    if forgetting_factor == 1.0:
        # Without forgetting, P is the least-squares covariance with the prior.
        assert_allclose(rls.variance, 1.0 / (1.0 / 4.0 + np.sum(phi**2) / noise_std**2), rtol=1e-9)


def test_payload_rls_variance_describes_its_error(random_joint_states) -> None:
    noise_std, runs = 2.0, 40
    z_scores = []
    for seed in range(runs):
        phi, y = payload_data(random_joint_states, np.full(200, 2.0), noise_std, seed=seed)
        rls = PayloadRLS(forgetting_factor=1.0, noise_std=noise_std, initial_variance=4.0)
        run_rls(rls, phi, y)
        z_scores.append((rls.mass - 2.0) / np.sqrt(rls.variance))
    assert abs(np.mean(z_scores)) < 3.0 / np.sqrt(runs)
    assert 0.7 < np.std(z_scores) < 1.3


def test_reset_covariance_tracks_a_pick_faster_than_forgetting(random_joint_states) -> None:
    mass = np.repeat([0.0, 3.8], 1000)
    phi, y = payload_data(random_joint_states, mass, noise_std=2.0, seed=2)

    def samples_to_within_5_percent(reset_at: int | None) -> int:
        estimates = run_rls(PayloadRLS(forgetting_factor=0.999), phi, y, reset_at=reset_at)
        outside = np.flatnonzero(np.abs(estimates[1000:] - 3.8) > 0.05 * 3.8)
        return int(outside[-1]) + 1 if outside.size else 0

    with_reset, without_reset = samples_to_within_5_percent(1000), samples_to_within_5_percent(None)
    assert with_reset <= 5
    assert without_reset > 20 * max(with_reset, 1)


@pytest.mark.parametrize("duration", [0.25, 0.4])
def test_smoother_beats_central_differences(joint_min_jerk_move, duration) -> None:
    theta, theta_dot, theta_ddot = pick_move(joint_min_jerk_move, duration)
    angles = encoder_readings(theta, seed=3)
    smooth, smooth_dot, smooth_ddot = smooth_joint_motion(angles, DT)
    inner = slice(1, -1)
    difference_dot = (angles[2:] - angles[:-2]) / (2 * DT)
    difference_ddot = (angles[2:] - 2 * angles[1:-1] + angles[:-2]) / DT**2
    velocity_factor = rms(difference_dot - theta_dot[inner]) / rms(smooth_dot[inner] - theta_dot[inner])
    acceleration_factor = rms(difference_ddot - theta_ddot[inner]) / rms(smooth_ddot[inner] - theta_ddot[inner])
    # Measured: about 9 and 90 (0.002 rad/s and 0.75 rad/s^2 against 0.02 rad/s and 67 rad/s^2).
    assert velocity_factor > 5.0
    assert acceleration_factor > 40.0
    assert rms(smooth - theta) < 0.5 * rms(angles - theta)


def filter_estimates(angles: np.ndarray) -> np.ndarray:
    """JointStateFilter's posterior (theta, theta_dot, theta_ddot) after each reading, ``(N, 9)``."""
    joint_filter = JointStateFilter()
    joint_filter.reset(angles[0])
    estimates = np.array([np.concatenate(joint_filter.update(z)) for z in angles])
    assert_allclose(joint_filter.x, estimates[-1])
    return estimates


def test_joint_state_filter_converges_to_the_true_rates() -> None:
    # A sinusoid already moving at up to 4.7 rad/s when the filter starts at rest.
    t = np.arange(500)[:, None] * DT
    omega = 2 * np.pi * np.array([1.5, 2.0, 2.5])
    theta = 0.3 + 0.3 * np.sin(omega * t)
    theta_dot, theta_ddot = 0.3 * omega * np.cos(omega * t), -0.3 * omega**2 * np.sin(omega * t)
    estimates = filter_estimates(encoder_readings(theta, seed=4))
    assert np.abs(estimates[0, 3:6] - theta_dot[0]).max() > 1.0, "the filter must start wrong"
    settled = slice(50, None)
    # Measured: 0.014 rad/s and 4.6 rad/s^2 RMS, the noise floor of the readings.
    assert rms(estimates[settled, 3:6] - theta_dot[settled]) < 0.025
    assert rms(estimates[settled, 6:] - theta_ddot[settled]) < 0.1 * np.abs(theta_ddot).max()


def test_joint_state_filter_tracks_a_pick_move(
    joint_min_jerk_move,
) -> None:
    theta, theta_dot, theta_ddot = pick_move(joint_min_jerk_move, 0.25)
    estimates = filter_estimates(encoder_readings(theta, seed=5))
    # Measured: 0.014 rad/s and 5 rad/s^2 RMS, lag (3 ms on the acceleration) and noise together.
    assert rms(estimates[:, 3:6] - theta_dot) < 0.005 * np.abs(theta_dot).max()
    assert rms(estimates[:, 6:] - theta_ddot) < 0.1 * np.abs(theta_ddot).max()


def test_joint_state_smoother_is_filterpys_rts_smoother_over_its_window() -> None:
    smoother = JointStateSmoother(lag=4, history=12)
    window = 17
    readings = 0.2 + np.cumsum(np.random.default_rng(6).normal(0.0, 1e-3, (window + 9, 3)), axis=0)
    smoother.reset(readings[0])
    for z in readings[1:]:
        estimate = np.array(smoother.update(z))  # (derivative, joint)
    # The same smoother written out with filterpy on the last `window` readings, joint by joint.
    kf = KalmanFilter(dim_x=3, dim_z=1)
    kf.F = kinematic_state_transition(order=2, dt=DT)
    kf.Q = Q_continuous_white_noise(dim=3, dt=DT, spectral_density=FIXED_LAG_JERK_STD**2 * DT)
    kf.H, kf.R = np.array([[1.0, 0.0, 0.0]]), np.array([[ENCODER_NOISE_STD**2]])
    for joint in range(3):
        kf.x, kf.P = np.zeros(3), np.diag([1.0, 1.0 / DT**2, 1.0 / DT**4])
        means, covariances, _, _ = kf.batch_filter(readings[-window:, joint])
        expected = kf.rts_smoother(means, covariances)[0][12]
        assert_allclose(estimate[:, joint], expected, rtol=1e-7, atol=1e-9)


def test_smoothers_of_one_model_share_their_read_only_weights() -> None:
    first, second = JointStateSmoother(lag=4, history=12), JointStateSmoother(lag=4, history=12)
    assert second.weights is first.weights and not first.weights.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        first.weights[0, 0] = 1.0
    # another model has weights of its own: a stiffer one smooths less, weighting the estimated sample's reading more
    stiffer = JointStateSmoother(lag=4, history=12, jerk_std=10.0 * FIXED_LAG_JERK_STD)
    assert stiffer.weights is not first.weights and stiffer.weights[0, 12] > 1.5 * first.weights[0, 12]


def test_joint_state_smoother_beats_the_causal_filter_on_a_pick_move(
    joint_min_jerk_move,
) -> None:
    theta, theta_dot, theta_ddot = pick_move(joint_min_jerk_move, 0.25)
    angles = encoder_readings(theta, seed=5)
    smoother = JointStateSmoother()
    smoother.reset(angles[0])
    smoothed = np.array([np.concatenate(smoother.update(z)) for z in angles])[smoother.lag :]
    truth = slice(0, len(angles) - smoother.lag)  # estimate n belongs to sample n - lag
    filtered = filter_estimates(angles)
    # Measured: 0.0015 rad/s and 1.1 rad/s^2 RMS against the filter's 0.014 rad/s and 5 rad/s^2.
    assert rms(smoothed[:, 3:6] - theta_dot[truth]) < 0.3 * rms(filtered[:, 3:6] - theta_dot)
    assert rms(smoothed[:, 6:] - theta_ddot[truth]) < 0.4 * rms(filtered[:, 6:] - theta_ddot)


def test_joint_state_filter_needs_a_reset() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        JointStateFilter().update(np.zeros(3))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"forgetting_factor": 0.0}, "forgetting_factor"),
        ({"forgetting_factor": 1.01}, "forgetting_factor"),
        ({"forgetting_factor": float("nan")}, "forgetting_factor"),
        ({"noise_std": 0.0}, "noise_std"),
        ({"initial_variance": -1.0}, "initial_variance"),
        ({"initial_mass": float("inf")}, "initial_mass"),
    ],
)
def test_bad_rls_parameters_raise(kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        PayloadRLS(**kwargs)


@pytest.mark.parametrize(
    ("phi", "y", "name"),
    [(np.ones(2), np.ones(3), "phi"), (np.ones(3), np.array([0.0, np.nan, 0.0]), "y")],
)
def test_bad_rls_samples_raise(phi, y, name) -> None:
    with pytest.raises(ValueError, match=name):
        PayloadRLS().update(phi, y)


@pytest.mark.parametrize(
    ("angles", "kwargs", "name"),
    [
        (np.zeros((10, 2)), {}, "angles"),
        (np.zeros((1, 3)), {}, "angles"),
        (np.full((10, 3), np.nan), {}, "angles"),
        (np.zeros((10, 3)), {"dt": 0.0}, "dt"),
        (np.zeros((10, 3)), {"measurement_std": -1.0}, "measurement_std"),
        (np.zeros((10, 3)), {"jerk_std": float("nan")}, "jerk_std"),
    ],
)
def test_bad_smoother_inputs_raise(angles, kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        smooth_joint_motion(angles, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "theta", "name"),
    [
        ({"dt": -1e-3}, np.zeros(3), "dt"),
        ({"jerk_std": 0.0}, np.zeros(3), "jerk_std"),
        ({}, np.zeros(2), "theta0"),
        ({}, np.array([0.0, np.inf, 0.0]), "theta0"),
    ],
)
def test_bad_filter_inputs_raise(kwargs, theta, name) -> None:
    with pytest.raises(ValueError, match=name):
        JointStateFilter(**kwargs).reset(theta)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"lag": -1}, "lag"), ({"lag": 2.0}, "lag"), ({"history": 1}, "history"), ({"jerk_std": 0.0}, "jerk_std")],
)
def test_bad_smoother_settings_raise(kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        JointStateSmoother(**kwargs)


def test_joint_state_smoother_needs_a_reset() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        JointStateSmoother().update(np.zeros(3))


@pytest.mark.parametrize("samples", [80, 150])
def test_smoothed_motion_is_filterpys_batch_filter_and_rts_smoother_bit_for_bit(
    samples: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The gains are computed once per record length (kept up to CACHED_GAINS_LENGTH, here 100: one record of each
    # kind); only the state recursion runs per record. filterpy's own functions on the same filter are the truth.
    monkeypatch.setattr(estimation, "CACHED_GAINS_LENGTH", 100)
    rng = np.random.default_rng(samples)
    time = np.arange(samples) * DT
    angles = 0.3 * np.sin(np.outer(time, [4.0, 5.0, 6.0])) + rng.normal(0.0, 1e-4, (samples, 3))
    for jerk_std in (1000.0, 50.0):  # a second filter: the kept gains are per model, not per length only
        kf = estimation._joint_kalman_filter(DT, 1e-4, jerk_std, angles[0])
        means, covariances, _, _ = kf.batch_filter(angles)
        expected, _, _, _ = kf.rts_smoother(means, covariances)
        smoothed = np.hstack(smooth_joint_motion(angles, DT, measurement_std=1e-4, jerk_std=jerk_std))
        np.testing.assert_array_equal(smoothed, expected)
