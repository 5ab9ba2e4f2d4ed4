"""The ``"smoothed"`` payload regressor's compiled step and the RLS kernel against the Python and NumPy paths they
replace, bit for bit: the smoother's matrix product, the readings it lags behind, the equation, the checkpoints,
skips and rollbacks, and the RLS update."""

import collections

import numpy as np
import pytest

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import SMOOTHER_WINDOW, JointStateSmoother, PayloadRLS, rls_update
from controllers.payload import PayloadEstimator
from controllers.payload.equation import PLATFORM_MASS, estimated_state_equation
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY


def python_rls(mass: float, variance: float, information: float, moment: float, rls: PayloadRLS) -> tuple[float, float]:
    """The RLS update as Python floats (the formula :func:`rls_update` compiles)."""
    prior = variance * (1.0 / rls.forgetting_factor)
    denominator = rls.noise_variance + prior * information
    mass += prior * (moment - information * mass) / denominator
    return mass, prior * rls.noise_variance / denominator


def test_rls_kernel_is_the_python_formula_bit_for_bit_and_finds_a_known_mass() -> None:
    rls = PayloadRLS(forgetting_factor=0.999, noise_std=0.7, initial_variance=4.0, initial_mass=0.1)
    rng = np.random.default_rng(4)
    phi = rng.normal(0.0, 10.0, (300, 3))
    y = 1.75 * phi  # noise-free: the estimate goes to 1.75 kg
    mass, variance = rls.state
    # the information form: J = lambda J + phi.phi / s^2 and b = lambda b + phi.y / s^2 from J = 1 / P0, b = m0 / P0
    total_information, total_moment = 1.0 / 4.0, 0.1 / 4.0
    for h, r in zip(phi, y, strict=True):
        information, moment = float(h @ h), float(h @ r)
        mass, variance = python_rls(mass, variance, information, moment, rls)
        assert rls.update_moments(information, moment) == mass
        assert rls.state == (mass, variance)
        total_information = 0.999 * total_information + information / 0.49
        total_moment = 0.999 * total_moment + moment / 0.49
    assert mass == pytest.approx(total_moment / total_information, rel=1e-12)
    assert variance == pytest.approx(1.0 / total_information, rel=1e-12)
    state = np.array([0.5, 2.0])
    assert rls_update(state, 3.0, 4.0, 1.0, 1.0) == 0.5 + 2.0 * (4.0 - 3.0 * 0.5) / (1.0 + 2.0 * 3.0)
    assert state[1] == 2.0 / 7.0


class PythonSmoothed:
    """The former Python path of ``PayloadEstimator(regressor="smoothed")`` with checkpoints: JointStateSmoother's
    NumPy product, a deque of the readings, the compiled equation, the RLS in Python floats."""

    def __init__(self, estimator: PayloadEstimator, kept: int) -> None:
        self.estimator = estimator  # its equation and fit records, and its RLS settings (not its state)
        self.smoother = JointStateSmoother()
        self.history: collections.deque = collections.deque(maxlen=self.smoother.lag + 1)
        self.previous: np.ndarray | None = None
        self.fit = np.zeros_like(estimator._fit)
        self.fit[:] = estimator._fit
        self.rls = estimator.rls.state
        self.fits, self.states = [], []
        self.kept = kept

    def update(self, observation: dict, holding: bool, skip: bool) -> float:
        self.fits = [*self.fits, self.fit.copy()][-self.kept :]
        self.states = [*self.states, self.rls][-self.kept :]
        reference = np.array(
            (
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
            )
        )
        error = observation["joint_angles"] - reference[0]
        if self.previous is None and not self.history:
            self.smoother.reset(error)
        newest = self.smoother.update_state(error)
        self.history.append((reference, observation["joint_torques"].tolist(), holding))
        if len(self.history) > self.smoother.lag:
            delayed, torque, held = self.history[0]
            state = newest + delayed
            previous = self.previous if self.previous is not None else state
            self.previous = state
            if holding == held:
                status, used, information, moment = estimated_state_equation(
                    self.estimator.dynamics.model_constants,
                    self.estimator._equation_bytes,
                    self.fit.view(np.uint8),
                    state,
                    previous,
                    holding,
                    *torque,
                )
                assert status == kernels.VALID
                if skip:
                    self.fit[:] = self.fits[-1]
                elif used:
                    self.rls = python_rls(*self.rls, information, moment, self.estimator.rls)
        return self.rls[0] + self.fit["solution"][0][PLATFORM_MASS]

    def rollback(self, samples: int) -> None:
        self.fit[:] = self.fits[-samples]
        self.rls = self.states[-samples]
        self.fits, self.states = self.fits[:-samples], self.states[:-samples]


@pytest.mark.parametrize("fits", [True, False])
def test_smoothed_step_is_the_python_path_bit_for_bit_with_skips_and_rollbacks(fits: bool) -> None:
    dynamics = DeltaDynamics.nominal(
        ModelParameters(rho1=1.05, rho2=0.97, viscous=(0.8, 0.9, 1.0), coulomb=(0.5, 0.6, 0.7))
    )
    corrections = {} if fits else {"friction_scale_std": None, "mass_correction_std": None}
    estimator = PayloadEstimator(dynamics, regressor="smoothed", tare=0.05, **corrections)
    kept = 12
    estimator.keep_checkpoints(kept)
    estimator.reset()
    python = PythonSmoothed(estimator, kept)
    times = np.arange(900) * CONTROL_PERIOD
    frequency, phase = 2.0 * np.pi * np.array([1.0, 1.3, 0.7]), np.array([0.0, 1.0, 2.0])
    argument = np.outer(times + 0.02, frequency) + phase  # the reference leads the joints by 20 ms
    reference = np.stack(
        (0.3 + 0.2 * np.sin(argument), 0.2 * frequency * np.cos(argument), -0.2 * frequency**2 * np.sin(argument)),
        axis=1,
    )
    angles = 0.3 + 0.2 * np.sin(np.outer(times, frequency) + phase)
    angles += np.random.default_rng(5).normal(0.0, 1e-6, angles.shape)
    # torques of a 1.2 kg payload on the model at the joints' state when the torque was measured (and noise): the
    # estimate has a known answer
    argument = np.outer(times - MEASURED_TORQUE_DELAY, frequency) + phase
    states = (0.3 + 0.2 * np.sin(argument), 0.2 * frequency * np.cos(argument), -0.2 * frequency**2 * np.sin(argument))
    tau0, phi = dynamics.inverse_dynamics(*states), dynamics.payload_regressor(*states)
    holding = (times >= 0.3) & (times < 0.8)  # an empty move (the fit), a carry, a release
    torques = tau0 + 1.2 * holding[:, None] * phi
    torques += np.random.default_rng(6).normal(0.0, 0.05, torques.shape)
    skips = {150: 5, 350: 3, 500: 11, 700: 1, 850: 2}
    rollbacks, compared = {200: 6, 420: 4, 600: kept, 750: 1, 870: 3}, 0
    python_holding, remaining = False, 0
    for k in range(len(times)):
        observation = {
            "joint_angles": angles[k],
            "joint_torques": torques[k],
            "gripper": np.array([float(holding[k])]),
            "reference_angles": reference[k, 0],
            "reference_velocities": reference[k, 1],
            "reference_accelerations": reference[k, 2],
        }
        if holding[k] != python_holding:  # the estimator's edges, as PayloadEstimator.update takes them
            python_holding = holding[k]
            python.fits, python.states = [], []
            variance = estimator.rls.initial_variance
            python.rls = (python.rls[0], variance) if holding[k] else (0.05, variance)
        mass = estimator.update(observation)
        assert mass == python.update(observation, bool(holding[k]), remaining > 0)
        assert estimator.rls.state == python.rls
        assert estimator._fit.tobytes() == python.fit.tobytes()
        remaining = max(remaining - 1, 0)
        if k in skips:
            estimator.skip(skips[k])
            remaining = max(remaining, skips[k])
        if k in rollbacks:
            estimator.rollback(rollbacks[k])
            python.rollback(min(rollbacks[k], len(python.fits)))
            assert estimator.rls.state == python.rls
        compared += holding[k]
        if k == 790 and not fits:
            assert mass == pytest.approx(1.2, abs=0.002)  # the payload, on the model's own torques
    assert compared == 500
    if fits:
        assert estimator.empty_move_samples > 200 and estimator.corrections.platform_mass != 0.0
    assert estimator.joint_filter.weights.shape[1] == SMOOTHER_WINDOW


def test_smoothed_step_raises_on_a_reading_that_is_not_finite() -> None:
    estimator = PayloadEstimator(DeltaDynamics.nominal(), regressor="smoothed")
    observation = {
        "joint_angles": np.array([0.3, np.nan, 0.3]),
        "joint_torques": np.zeros(3),
        "gripper": np.array([0.0]),
        "reference_angles": np.full(3, 0.3),
        "reference_velocities": np.zeros(3),
        "reference_accelerations": np.zeros(3),
    }
    with pytest.raises(ValueError, match="tracking error must be 3 finite values"):
        estimator.update(observation)
    with pytest.raises(ValueError, match="tracking error must be 3 finite values"):
        estimator.measurement(observation)
