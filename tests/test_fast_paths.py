"""The fast paths against their references: filterpy's Kalman filter, SB3's predict, the Python formula, one
policy load and one process pool for many episodes."""

import dataclasses
import math
import os

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from numpy.testing import assert_allclose, assert_array_equal

from controllers.compiled_model import single_sample_model
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import JointStateSmoother, PayloadRLS
from controllers.payload import FRICTION_SCALE_STD, MASS_CORRECTION_STD, REST_RATE, PayloadEstimator, residual_std
from controllers.residual import ResidualFeatures, load_residual_controller, load_residual_policy, residual_controller
from delta_env.env import DeltaPickPlaceEnv
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from eval.processes import DEFAULT_WORKERS, run_jobs, runs_a_pool
from tests.conftest import run_python


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


def test_residual_policy_action_is_sb3_predict_to_float32_round_off() -> None:
    policy = load_residual_policy()
    assert policy.actor is not None, "the shipped SAC actor is a plain MLP: it runs as NumPy matrix products"
    observations = np.random.default_rng(5).uniform(-10.0, 10.0, (64, ResidualFeatures.size)).astype(np.float32)
    batch, _ = policy.model.predict(observations, deterministic=True)
    # Observations at the feature clip drive the last layer's sums to about 100 before tanh: float32 rounds them to
    # about 1e-5 (measured: both paths within 1e-5 of a float64 forward pass), and the two paths sum in other orders.
    # A wrong layer, bias or activation moves actions by 1e-2 or more.
    round_off = 5e-5
    assert_allclose(policy(observations), batch, rtol=0.0, atol=round_off)
    for observation in observations[:8]:
        single, _ = policy.model.predict(observation, deterministic=True)
        action = policy(observation)
        assert action.shape == (3,) and action.dtype == single.dtype
        assert_allclose(action, single, rtol=0.0, atol=round_off)
    torch_path = dataclasses.replace(policy, actor=None)
    assert_array_equal(torch_path(observations), batch)  # the torch path is SB3's arithmetic bit for bit


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
        joint_state = (*theta.tolist(), *theta_dot.tolist(), *theta_ddot.tolist())
        compiled_status, compiled = single_sample_model(model.model_constants, *joint_state)
        python_status, python = single_sample_model.py_func(model.model_constants, *joint_state)
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


class Finished:
    """A stand-in for a tqdm bar (counts its updates) that also records each finished item and its output."""

    def __init__(self) -> None:
        self.n = 0
        self.outputs: list[tuple[int, float]] = []

    def update(self, n: int = 1) -> None:
        self.n += n

    def record(self, index: int, output: float) -> None:
        self.outputs.append((index, output))


def test_the_executor_returns_the_outputs_in_the_order_of_the_items_here_and_on_a_pool() -> None:
    items = [4.0, 9.0, 16.0, 25.0, 36.0]
    for workers in (1, 2):
        finished = Finished()
        outputs = run_jobs(math.sqrt, items, workers=workers, progress=finished, on_result=finished.record)
        assert outputs == [2.0, 3.0, 4.0, 5.0, 6.0] and finished.n == len(items)
        assert sorted(finished.outputs) == list(enumerate(outputs))  # each handed over once, with its index
    assert run_jobs(math.sqrt, items, workers=2, keep=False) is None
    assert run_jobs(math.sqrt, [], workers=2) == []


def test_the_executor_refuses_an_unknown_backend_and_an_address_without_ray() -> None:
    with pytest.raises(ValueError, match="backend must be one of \\('local', 'ray'\\), got 'dask'"):
        run_jobs(math.sqrt, [4.0], backend="dask")
    with pytest.raises(ValueError, match="address is for the ray backend only"):
        run_jobs(math.sqrt, [4.0], address="auto")
    with pytest.raises(ValueError, match="workers"):
        run_jobs(math.sqrt, [4.0], workers=0)


def exit_worker(_: float) -> float:
    """Kill the process that runs it (a worker dying mid-item)."""
    os._exit(1)


def test_an_item_whose_worker_died_too_often_is_given_up() -> None:
    outputs = run_jobs(exit_worker, [1.0, 2.0], workers=2, max_attempts=1, on_lost=lambda i, error: (i, error))
    died = "its worker died on each of its 1 attempts"
    assert outputs == [(0, died), (1, died)]
    with pytest.raises(RuntimeError, match=rf"item [01] of 2 was not run: {died}"):
        run_jobs(exit_worker, [1.0, 2.0], workers=2, max_attempts=1)


def test_the_worker_server_starts_before_the_project_is_imported() -> None:
    # python -m eval starts it first, so that its imports overlap the command's own: eval.processes must stay light.
    code = (
        "import math, sys; from eval.processes import pool_context, start_worker_server; "
        "loaded = [m for m in sys.modules if m.split('.')[0] in ('delta_env', 'controllers') or m == 'eval.work']; "
        "assert not loaded, loaded; start_worker_server(); "
        "pool = pool_context().Pool(1); print(pool.apply(math.sqrt, (16.0,))); pool.close(); pool.join()"
    )
    assert run_python(code).split() == ["4.0"]


@pytest.mark.parametrize(
    ("argv", "pool"),
    [
        ([], DEFAULT_WORKERS > 1),
        (["--seed", "3", "--episodes", "2"], DEFAULT_WORKERS > 1),
        (["--help"], False),
        (["--episodes", "2", "-h"], False),
        (["--workers", "1"], False),
        (["--workers=3"], True),
        (["--workers", "2", "--workers", "1"], False),
        (["--workers", "two"], False),
    ],
)
def test_the_worker_server_starts_only_for_a_command_line_that_runs_a_pool(argv: list[str], pool: bool) -> None:
    assert runs_a_pool(argv) == pool


def test_compiled_payload_equation_equals_the_weighted_least_squares_it_implements() -> None:
    # The estimator's compiled path against the equations written with NumPy: the smoother's state of the tracking
    # error plus the reference's exact state, interpolated to the torque's instant, tau0 and phi there,
    # w_i = 1 / residual_std^2, the least squares of the model's corrections on the empty move (mp = 0 known:
    # tau_i - tau0_i = dm phi_i + d_arm (I thdd_i + G cos th_i) + kappa_i f_i, with its prior) and their removal
    # from the carry's moments.
    parameters = ModelParameters(rho1=1.9, rho2=0.95, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6))
    dynamics = DeltaDynamics.nominal(parameters, forearm_rods=True)
    estimator = PayloadEstimator(dynamics, regressor="smoothed", tare=0.05)
    smoother = JointStateSmoother()
    age = MEASURED_TORQUE_DELAY / CONTROL_PERIOD
    prior = np.diag([MASS_CORRECTION_STD[0] ** -2, MASS_CORRECTION_STD[1] ** -2, *[FRICTION_SCALE_STD**-2] * 3])
    rng = np.random.default_rng(9)
    times = np.arange(400) * CONTROL_PERIOD
    frequency, phase = 2.0 * np.pi * np.array([1.0, 1.3, 0.7]), np.array([0.0, 1.0, 2.0])
    angles = 0.3 + 0.2 * np.sin(np.outer(times, frequency) + phase)
    # the reference leads the joints by 20 ms: a tracking error of up to 35 mrad to smooth
    argument = np.outer(times + 0.02, frequency) + phase
    reference = np.stack(
        (0.3 + 0.2 * np.sin(argument), 0.2 * frequency * np.cos(argument), -0.2 * frequency**2 * np.sin(argument)),
        axis=1,
    )  # (N, 3 derivatives, 3 joints)
    torques = rng.normal(0.0, 30.0, angles.shape)
    holding = times >= 0.2  # open first: the fit of the corrections, then a carry
    information_fit, moment_fit = np.zeros((5, 5)), np.zeros(5)
    history, previous, compared, empty = [], None, 0, 0
    for k in range(len(times)):
        observation = {
            "joint_angles": angles[k],
            "joint_torques": torques[k],
            "gripper": np.array([float(holding[k])]),
            "reference_angles": reference[k, 0],
            "reference_velocities": reference[k, 1],
            "reference_accelerations": reference[k, 2],
        }
        moments = estimator.measurement(observation)
        if k == 0:
            smoother.reset(angles[0] - reference[0, 0])
        error = np.array(smoother.update(angles[k] - reference[k, 0]))
        history.append((torques[k], holding[k]))
        if k < smoother.lag:
            assert moments is None
            continue
        torque, held = history[k - smoother.lag]
        state = error + reference[k - smoother.lag]
        previous = state if previous is None else previous
        theta, theta_dot, theta_ddot = state - age * (state - previous)
        previous = state
        if held != holding[k] or np.all(np.abs(theta_dot) < REST_RATE):
            assert moments is None
            continue
        empty += not held
        tau0, phi = dynamics.torque_and_payload_regressor(theta, theta_dot, theta_ddot)
        weight = residual_std(theta_dot, parameters.coulomb) ** -2.0
        friction = np.array(parameters.viscous) * theta_dot + np.array(parameters.coulomb) * np.sign(theta_dot)
        # Columns per joint (rows): dm, d_arm, kappa_1..3.
        columns = np.zeros((3, 5))
        columns[:, 0] = phi
        columns[:, 1] = dynamics.inertia * theta_ddot + dynamics.gravity_amplitude * np.cos(theta)
        columns[:, 2:] = np.diag(friction)
        if not held:
            information_fit += columns.T @ (weight[:, None] * columns)
            moment_fit += columns.T @ (weight * (torque - tau0))
            assert moments is None
            continue
        solution = np.linalg.solve(information_fit + prior, moment_fit)
        corrections = estimator.corrections
        assert [corrections.platform_mass, corrections.arm_mass_scale, *corrections.friction_scale] == pytest.approx(
            solution, rel=1e-10
        )
        assert moments == pytest.approx(
            (np.sum(weight * phi**2), np.sum(weight * phi * (torque - tau0 - columns @ solution))), rel=1e-10
        )
        compared += 1
    assert compared > 100 and np.all(np.abs(solution) > 1e-3)
    assert estimator.empty_move_samples == empty > 100


def test_smoother_update_state_equals_update_and_holds_until_the_next_call_but_one() -> None:
    fast, reference = JointStateSmoother(), JointStateSmoother()
    rng = np.random.default_rng(10)
    readings = np.cumsum(rng.normal(0.0, 1e-3, (60, 3)), axis=0)
    fast.reset(readings[0])
    reference.reset(readings[0])
    earlier = None
    for reading in readings:
        state = fast.update_state(reading)
        expected = np.array(reference.update(reading))
        assert_array_equal(state, expected)
        if earlier is not None:
            assert_array_equal(earlier[1], earlier[0])  # the previous call's state is still intact
        earlier = (state, expected)
