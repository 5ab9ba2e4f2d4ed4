"""Drive lag identification and the lag-compensated feedforward controller."""

from dataclasses import replace
from functools import partial

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers.drive import MeasuredReferenceRate, ReferencePredictor, identify_lag, measured_lag_response
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import FeedforwardController, LagCompensatedController
from delta_env.config import PlantConfig, PlantRealism
from delta_env.cycles import conveyor_cycles
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import Trajectory


def test_lag_is_identified_from_noisy_synthetic_data() -> None:
    """Known lags, commands of a few N m per step, 0.5 N m white noise on the reported torque."""
    rng = np.random.default_rng(0)
    truth = np.array([0.0007, 0.001, 0.0016])
    commands = np.cumsum(rng.normal(0.0, 3.0, (4000, 3)), axis=0)
    measured = np.stack([measured_lag_response(commands[:, j], truth[j], 0.0) for j in range(3)], axis=1)
    noisy = measured + rng.normal(0.0, 0.5, measured.shape)
    assert_allclose(identify_lag(commands, measured), truth, rtol=1e-5)
    assert_allclose(identify_lag(commands, noisy), truth, rtol=0.03)
    # The equation-error least squares the module rejects is biased by the noise on its regressor.
    x, y = noisy[:-1] - commands[1:], noisy[1:] - commands[1:]
    equation_error = -CONTROL_PERIOD / np.log(np.sum(x * y, axis=0) / np.sum(x * x, axis=0))
    assert np.all(np.abs(equation_error / truth - 1.0) > 0.05)


@pytest.mark.parametrize(
    ("commands", "measured", "message"),
    [
        (np.zeros((100, 2)), np.zeros((100, 2)), "commands"),
        (np.ones((100, 3)), np.ones((99, 3)), "measured"),
        (np.full((100, 3), np.nan), np.zeros((100, 3)), "finite"),
        (np.ones((100, 3)), np.ones((100, 3)), "vary"),
        (np.zeros((20, 3)), np.zeros((20, 3)), "skip"),
    ],
)
def test_bad_identification_input_raises(commands: np.ndarray, measured: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        identify_lag(commands, measured)


def cubic_reference(times: np.ndarray) -> list[dict[str, np.ndarray]]:
    """Observations of a cubic joint reference at ``times`` (s)."""
    t = np.asarray(times)[:, None]
    c = np.array([[0.1, -0.2, 0.3], [1.0, 2.0, -1.0], [5.0, -3.0, 2.0], [40.0, 10.0, -20.0]])
    theta = c[0] + c[1] * t + c[2] * t**2 + c[3] * t**3
    theta_dot = c[1] + 2.0 * c[2] * t + 3.0 * c[3] * t**2
    theta_ddot = 2.0 * c[2] + 6.0 * c[3] * t
    return [
        {"reference_angles": a, "reference_velocities": v, "reference_accelerations": w}
        for a, v, w in zip(theta, theta_dot, theta_ddot, strict=True)
    ]


@pytest.mark.parametrize("horizon", [None, 0.25e-3, 0.94e-3, 1.5e-3])
def test_reference_predictor_is_a_cubic_step(horizon: float | None) -> None:
    """On a cubic reference the prediction is exact from the second step on, at any horizon."""
    ahead = CONTROL_PERIOD if horizon is None else horizon
    steps = np.array([0.0, CONTROL_PERIOD])
    predictor = ReferencePredictor(horizon=horizon)
    for observation in cubic_reference(steps):
        predicted = predictor.next(observation)
    expected = cubic_reference(np.array([CONTROL_PERIOD + ahead]))[0]
    for value, key in zip(
        predicted, ("reference_angles", "reference_velocities", "reference_accelerations"), strict=True
    ):
        assert_allclose(value, expected[key], rtol=0.0, atol=1e-12)
    with pytest.raises(ValueError, match="horizon"):
        ReferencePredictor(horizon=3.0 * CONTROL_PERIOD)


@pytest.mark.parametrize("window", [CONTROL_PERIOD, 0.5e-3, 0.1e-3])
def test_measured_reference_rate_is_the_mean_rate_over_the_window(window: float) -> None:
    """On a cubic reference the rate from the second step on is (theta(t) - theta(t - w)) / w exactly."""
    rate = MeasuredReferenceRate(window)
    times = np.array([0.0, CONTROL_PERIOD])
    for observation in cubic_reference(times):
        measured = rate(observation)
    now, before = cubic_reference(np.array([CONTROL_PERIOD, CONTROL_PERIOD - window]))
    expected = (now["reference_angles"] - before["reference_angles"]) / window
    assert_allclose(measured, expected, rtol=0.0, atol=1e-10)
    with pytest.raises(ValueError, match="window"):
        MeasuredReferenceRate(2.0 * CONTROL_PERIOD)


def test_reference_predictor_follows_the_samples_of_a_given_reference() -> None:
    """Following a reference's samples: the sample itself one period ahead; half a period ahead, the quintic Hermite
    value against the same path sampled at 20 kHz (largest errors measured 2.6e-8 rad, 5.9e-5 rad/s and 1.2 rad/s^2,
    the last across the path's jerk steps; the Taylor step 4.5e-7, 2.7e-3 and 10.7); the Taylor step again once
    the observation is no sample k of it."""
    cycles = partial(conveyor_cycles, NOMINAL_GEOMETRY, n_cycles=1, peak_acceleration=100.0)
    trajectory = cycles(np.random.default_rng(0))
    fine = cycles(np.random.default_rng(0), dt=CONTROL_PERIOD / 20)
    followed, halfway, taylor = (
        ReferencePredictor(),
        ReferencePredictor(horizon=0.5e-3),
        ReferencePredictor(horizon=0.5e-3),
    )
    followed.follow(trajectory)
    halfway.follow(trajectory)
    samples = (trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot)
    keys = ("reference_angles", "reference_velocities", "reference_accelerations")
    error, taylor_error = np.zeros(3), np.zeros(3)
    for k in range(len(trajectory) - 3):
        observation = {key: sample[k] for key, sample in zip(keys, samples, strict=True)}
        for value, sample in zip(followed.next(observation), samples, strict=True):
            assert_allclose(value, sample[k + 1], rtol=0.0, atol=1e-9)
        truth = (fine.theta[20 * k + 10], fine.theta_dot[20 * k + 10], fine.theta_ddot[20 * k + 10])
        for i, (value, guess, true) in enumerate(
            zip(halfway.next(observation), taylor.next(observation), truth, strict=True)
        ):
            error[i] = max(error[i], np.max(np.abs(value - true)))
            taylor_error[i] = max(taylor_error[i], np.max(np.abs(guess - true)))
    assert np.all(error < [4e-8, 1e-4, 2.0]), error
    assert np.all(taylor_error > 4.0 * error), taylor_error
    off = {key: value + 1e-3 for key, value in observation.items()}
    for value, expected in zip(halfway.next(off), taylor.next(off), strict=True):
        assert_allclose(value, expected, rtol=0.0, atol=1e-12)
    with pytest.raises(ValueError, match="sample period"):
        followed.follow(fine)


def run(env: DeltaPickPlaceEnv, controller: object, seed: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Tracking RMS (mm), the commands sent (N m, (N, 3)) and the torques reported after each (N m)."""
    observation, _ = env.reset(seed=seed, options={"payload_masses": [0.0, 0.0]})
    controller.reset()
    errors, commands, reported = [], [], []
    truncated = False
    while not truncated:
        command = controller(observation)
        observation, _, terminated, truncated, info = env.step(command)
        assert not terminated
        errors.append(info["tracking_error"])
        commands.append(command)
        reported.append(observation["joint_torques"])
    return 1e3 * float(np.sqrt(np.mean(np.square(errors)))), np.array(commands), np.array(reported)


def test_identified_lag_and_its_compensation_on_the_simulator() -> None:
    """The lag is found from a closed-loop run of the default plant (exact encoders, so that the PD's reaction to
    the rate quantization does not hide what the lag costs), and leading it lowers the tracking error of the same
    identified-model feedforward (empty gripper, so that the model is all the feedforward needs).

    Measured: 1.002, 1.061, 0.965 ms for the true 1 ms; tracking 0.157 -> 0.118 mm.
    """
    env = DeltaPickPlaceEnv(plant=PlantConfig(realism=replace(PlantRealism(), encoder_bits=None)), n_cycles=2)
    parameters = ModelParameters(rho1=1.95, rho2=0.951, viscous=(2.01, 2.41, 1.71), coulomb=(3.98, 3.38, 4.59))

    def base() -> FeedforwardController:
        return FeedforwardController("MId+F+R+PD", DeltaDynamics.nominal(parameters, forearm_rods=True))

    plain_rms, commands, reported = run(env, base(), seed=3)
    identified = identify_lag(commands, reported)
    assert_allclose(identified, env.plant_config.realism.actuator_lag, rtol=0.08)
    compensated_rms, *_ = run(env, LagCompensatedController("lag", base(), identified), seed=3)
    assert compensated_rms < 0.85 * plain_rms, (compensated_rms, plain_rms)


def test_reference_jet_is_exact_on_a_quintic() -> None:
    """Following a reference's samples, the jet (angle to snap) at any horizon is that of the quintic Hermite
    interpolant, so on a reference that is one quintic in time it is the reference's own, jerk and snap included;
    predicted from the observation alone the jerk is the last period's change of the acceleration and the snap 0."""
    coefficients = np.array(
        [
            [0.1, -0.2, 0.3],
            [0.5, 0.2, -0.4],
            [3.0, -2.0, 1.0],
            [-20.0, 15.0, 8.0],
            [90.0, -40.0, 60.0],
            [-300.0, 250.0, 120.0],
        ]
    )
    times = np.arange(8) * CONTROL_PERIOD

    def derivative(t: np.ndarray, order: int) -> np.ndarray:
        powers = np.polynomial.polynomial.polyder(coefficients, order) if order else coefficients
        return np.polynomial.polynomial.polyval(t, powers).T

    zero = np.zeros((len(times), 3))
    trajectory = Trajectory(
        CONTROL_PERIOD, zero, zero, zero, *(derivative(times, n) for n in range(3)), np.zeros(len(times), bool), [], []
    )
    keys = ("reference_angles", "reference_velocities", "reference_accelerations")
    for horizon in (0.25e-3, 0.94e-3, 1.5e-3):
        followed, predicted = ReferencePredictor(horizon=horizon), ReferencePredictor(horizon=horizon)
        followed.follow(trajectory)
        for k in range(len(times) - 3):
            observation = {key: derivative(times[k : k + 1], n)[0] for n, key in enumerate(keys)}
            jet = followed.jet(observation)
            for n, value in enumerate(jet):
                truth = derivative(np.array([times[k] + horizon]), n)[0]
                # round-off grows as period^-n: the snap carries 1e-16 rad of the angles over (1 ms)^4
                assert_allclose(value, truth, rtol=1e-4, atol=1e-4 * np.max(np.abs(truth)))
            guess = predicted.jet(observation)
            expected_jerk = (
                (observation["reference_accelerations"] - derivative(times[k - 1 : k], 2)[0]) / CONTROL_PERIOD
                if k
                else np.zeros(3)
            )
            assert_allclose(guess[3], expected_jerk, rtol=1e-12, atol=1e-12)
            assert np.all(guess[4] == 0.0)
