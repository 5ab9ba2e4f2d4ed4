"""The fast paths against their references: filterpy's Kalman filter, SB3's predict, the Python formula, one
policy load and one process pool for many episodes."""

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from numpy.testing import assert_array_equal

from controllers.dynamics import DeltaDynamics, ModelParameters, _single_sample_model
from controllers.estimation import PayloadRLS
from controllers.residual import ResidualFeatures, load_residual_controller, load_residual_policy, residual_controller
from delta_env.env import DeltaPickPlaceEnv
from eval.processes import parallel_map, process_pool


def reference_filter(forgetting_factor: float, noise_std: float, variance: float, mass: float) -> KalmanFilter:
    """RLS with forgetting as filterpy's fading-memory Kalman filter of the constant mp (the reference)."""
    kf = KalmanFilter(dim_x=1, dim_z=3)
    kf.x, kf.P = np.array([mass]), np.array([[variance]])
    kf.F, kf.Q, kf.R = np.eye(1), np.zeros((1, 1)), noise_std**2 * np.eye(3)
    kf.alpha = 1.0 / np.sqrt(forgetting_factor)
    return kf


@pytest.mark.parametrize(("forgetting_factor", "noise_std"), [(1.0, 2.0), (0.999, 1.0), (0.9, 0.5)])
def test_payload_rls_equals_filterpy_to_round_off(forgetting_factor: float, noise_std: float) -> None:
    rng = np.random.default_rng(3)
    phi = rng.normal(0.0, 10.0, (400, 3))
    phi[::7] *= 1e-3  # nearly uninformative samples, as at rest in the friction band
    y = 2.5 * phi + rng.normal(0.0, noise_std, phi.shape)
    rls = PayloadRLS(forgetting_factor=forgetting_factor, noise_std=noise_std, initial_variance=4.0, initial_mass=0.3)
    reference = reference_filter(forgetting_factor, noise_std, 4.0, 0.3)
    for n in range(len(phi)):
        if n in (150, 300):  # a pick: the covariance is restored, the estimate kept
            rls.reset_covariance()
            reference.P = np.array([[4.0]])
        reference.predict()
        reference.update(y[n], H=phi[n][:, None])
        assert rls.update(phi[n], y[n]) == pytest.approx(reference.x[0], rel=1e-12, abs=1e-14)
        assert rls.variance == pytest.approx(reference.P[0, 0], rel=1e-12)


def test_payload_rls_weighted_moments_equal_filterpy_with_per_joint_noise() -> None:
    # The estimator's path: sum w_i phi_i^2 and sum w_i phi_i y_i with w_i = 1 / sigma_i^2 is the Kalman update
    # with R = diag(sigma_i^2).
    rng = np.random.default_rng(4)
    phi, y = rng.normal(0.0, 10.0, (300, 3)), rng.normal(0.0, 20.0, (300, 3))
    sigma = rng.uniform(1.5, 40.0, (300, 3))
    rls = PayloadRLS(forgetting_factor=0.999, noise_std=1.0, initial_variance=16.0 / 3.0)
    reference = reference_filter(0.999, 1.0, 16.0 / 3.0, 0.0)
    for n in range(len(phi)):
        weights = sigma[n] ** -2
        mass = rls.update_moments(float(np.sum(weights * phi[n] ** 2)), float(np.sum(weights * phi[n] * y[n])))
        reference.predict()
        reference.update(y[n], R=np.diag(sigma[n] ** 2), H=phi[n][:, None])
        assert mass == pytest.approx(reference.x[0], rel=1e-11, abs=1e-14)


@pytest.mark.parametrize("value", [[1.0, np.nan, 0.0], [1.0, 2.0], np.ones((3, 1))])
def test_payload_rls_rejects_bad_samples(value: list) -> None:
    with pytest.raises(ValueError, match="phi must be 3 finite values"):
        PayloadRLS().update(np.asarray(value, dtype=float), np.zeros(3))


def test_residual_policy_action_is_sb3_predict_bit_for_bit() -> None:
    policy = load_residual_policy()
    observations = np.random.default_rng(5).uniform(-10.0, 10.0, (64, ResidualFeatures.size)).astype(np.float32)
    batch, _ = policy.model.predict(observations, deterministic=True)
    assert_array_equal(policy(observations), batch)
    for observation in observations[:8]:
        single, _ = policy.model.predict(observation, deterministic=True)
        action = policy(observation)
        assert action.shape == (3,) and action.dtype == single.dtype
        assert_array_equal(action, single)


@pytest.mark.parametrize("forearm_rods", [False, True])
def test_compiled_single_sample_model_equals_its_python_formula_bit_for_bit(forearm_rods: bool) -> None:
    # numba compiles without fast-math, so the compiled kernel must reproduce CPython's float arithmetic exactly.
    parameters = ModelParameters(rho1=1.1, rho2=0.95, viscous=(0.02, 0.03, 0.025), coulomb=(0.3, 0.2, 0.25))
    model = DeltaDynamics.nominal(parameters, forearm_rods=forearm_rods)
    rng = np.random.default_rng(6)
    for _ in range(200):
        theta = rng.uniform(-0.3, 1.2, 3)
        theta_dot, theta_ddot = rng.normal(0.0, 5.0, 3), rng.normal(0.0, 200.0, 3)
        theta_dot[rng.integers(3)] = 0.0  # sign(0) = 0 in the Coulomb term
        arguments = (model._single_sample_constants, *theta.tolist(), *theta_dot.tolist(), *theta_ddot.tolist())
        compiled_status, compiled = _single_sample_model(*arguments)
        python_status, python = _single_sample_model.py_func(*arguments)
        assert compiled_status == python_status == 0
        assert_array_equal(compiled, python)


def test_one_loaded_policy_serves_many_residual_controllers_like_fresh_loads() -> None:
    # The evaluation loads the policy once per worker process: it must carry nothing from one episode into
    # the next, so a controller on a used policy acts as one on a fresh load of the file.
    shared = load_residual_policy()
    env = DeltaPickPlaceEnv(n_cycles=1)
    earlier = residual_controller(shared)
    earlier.reset()
    observation, _ = env.reset(seed=7)
    for _ in range(40):  # an earlier episode on the shared policy
        observation, *_ = env.step(earlier(observation))
    reused, fresh = residual_controller(shared), load_residual_controller()
    reused.reset()
    fresh.reset()
    observation, _ = env.reset(seed=8)
    for _ in range(60):  # several policy steps
        torque = fresh(observation)
        assert_array_equal(reused(observation), torque)
        observation, *_ = env.step(torque)


def test_process_pool_serves_dependent_batches_in_order() -> None:
    with process_pool(2) as pool:
        assert pool is not None
        first = parallel_map(math.sqrt, [4.0, 9.0, 16.0], 2, pool=pool)
        second = parallel_map(math.sqrt, [x * x for x in first], 2, pool=pool)
    assert first == second == [2.0, 3.0, 4.0]
    with process_pool(1) as pool:
        assert pool is None
