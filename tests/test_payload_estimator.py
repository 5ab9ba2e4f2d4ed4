"""The payload estimator's update against its definitions: the RLS over the equations that :meth:`measurement` forms
is their batch least squares, skipped updates enter neither the RLS nor the correction fit, a rollback restores the
state of that many updates ago, the fit solves its normal equations with the prior, and the estimate finds a known
mass."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.payload import (
    CONSISTENT_SAMPLES,
    FRICTION_SCALE_STD,
    MASS_CORRECTION_STD,
    CorrectionFit,
    EmptyMoveSums,
    PayloadEstimator,
)
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY

DYNAMICS = DeltaDynamics.nominal(
    ModelParameters(rho1=1.05, rho2=0.97, viscous=(0.8, 0.9, 1.0), coulomb=(0.5, 0.6, 0.7))
)
MASS = 1.2
"""The payload (kg) in the torques of :func:`observations`."""


def observations(
    samples: int = 900, pick: float = 0.3, release: float = 0.8, disturbance: tuple[int, int, float] | None = None
) -> list[dict]:
    """Observations of joints that lag a sinusoidal reference by 20 ms, with the model's own torques of a
    :data:`MASS` kg payload held from ``pick`` to ``release`` (s), measured at the joints' state
    MEASURED_TORQUE_DELAY before the encoder sample, with 0.05 N m of noise: an empty move, a carry, a release.
    ``disturbance`` (first, last + 1, kg): those samples' torques carry that much more mass (a force along phi)."""
    times = np.arange(samples) * CONTROL_PERIOD
    frequency, phase = 2.0 * np.pi * np.array([1.0, 1.3, 0.7]), np.array([0.0, 1.0, 2.0])

    def states(shift: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        argument = np.outer(times + shift, frequency) + phase
        return 0.3 + 0.2 * np.sin(argument), 0.2 * frequency * np.cos(argument), -0.2 * frequency**2 * np.sin(argument)

    reference = states(0.02)
    angles = states(0.0)[0] + np.random.default_rng(5).normal(0.0, 1e-6, (samples, 3))
    measured = states(-MEASURED_TORQUE_DELAY)
    holding = (times >= pick) & (times < release)
    mass = MASS * holding
    if disturbance is not None:
        mass[disturbance[0] : disturbance[1]] += disturbance[2]
    torques = DYNAMICS.inverse_dynamics(*measured) + mass[:, None] * DYNAMICS.payload_regressor(*measured)
    torques += np.random.default_rng(6).normal(0.0, 0.05, torques.shape)
    return [
        {
            "joint_angles": angles[k],
            "joint_torques": torques[k],
            "gripper": np.array([float(holding[k])]),
            "reference_angles": reference[0][k],
            "reference_velocities": reference[1][k],
            "reference_accelerations": reference[2][k],
        }
        for k in range(samples)
    ]


def estimator_state(estimator: PayloadEstimator) -> tuple:
    """Everything an update may change in the RLS and the fit."""
    return estimator.rls.x, estimator.rls.P, estimator.fit.state.tobytes()


@pytest.mark.parametrize("regressor", ["smoothed", "reference", "filtered"])
def test_update_is_the_batch_least_squares_of_the_equations_not_skipped(regressor: str) -> None:
    # Without forgetting, the RLS over a carry is the weighted least squares of the carry's equations (those that
    # measurement() forms on the same observations) with the prior: x = (x0 / P0 + sum m) / (1 / P0 + sum i), whatever
    # the order; skipped updates are left out of it.
    estimator = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05, forgetting_factor=1.0)
    equations = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05, forgetting_factor=1.0)
    estimator.keep_checkpoints(12)
    skips = {420: 5, 500: 11, 610: 1, 700: 3}
    information = moment = 0.0
    skipping, compared = 0, 0
    for k, observation in enumerate(observations()):
        estimator.update(observation)
        equation = equations.measurement(observation)
        holding = observation["gripper"].item(0) > 0.5
        if holding and equation is not None and not skipping:
            information, moment = information + equation[0], moment + equation[1]
        skipping = max(skipping - 1, 0)
        if k in skips:
            estimator.skip(skips[k])
            skipping = max(skipping, skips[k])
        if holding and information > 0.0:
            prior = estimator.rls.initial_variance
            assert estimator.rls.x == pytest.approx((0.05 / prior + moment) / (1.0 / prior + information), rel=1e-9)
            assert estimator.rls.variance == pytest.approx(1.0 / (1.0 / prior + information), rel=1e-9)
            compared += 1
    assert compared > 400


def test_skipped_updates_enter_neither_the_fit_nor_the_rls() -> None:
    estimator = PayloadEstimator(DYNAMICS, tare=0.05)
    estimator.keep_checkpoints(12)
    steps = observations()
    for observation in steps[:200]:  # an empty move: the fit has samples
        estimator.update(observation)
    samples = estimator.empty_move_samples
    estimator.skip(30)
    before = estimator_state(estimator)
    for observation in steps[200:230]:
        estimator.update(observation)
    assert estimator_state(estimator) == before
    estimator.update(steps[230])
    assert estimator.empty_move_samples == samples + 1  # the next update enters again
    for observation in steps[231:400]:  # into the carry
        estimator.update(observation)
    mass = estimator.rls.x
    estimator.skip(20)
    for observation in steps[400:420]:
        estimator.update(observation)
    assert estimator.rls.x == mass
    estimator.update(steps[420])
    assert estimator.rls.x != mass


@pytest.mark.parametrize("regressor", ["smoothed", "reference"])
def test_a_hold_out_leaves_out_the_equations_until_they_agree_with_the_estimate(regressor: str) -> None:
    # 40 samples of the carry weigh 5 kg more (a push along phi, or the servo's answer to one), from the hold-out on:
    # their equations, each several standard deviations off the estimate, stay out; the model's own torques then
    # agree with it, and after CONSISTENT_SAMPLES of them the equations enter again. The estimate is the one that
    # skipped exactly those samples, and near its undisturbed twin's at the place (0.3 % smoothed; 1.8 % at the
    # reference, which these joints lag by 20 ms: its equations' own error depends on which samples it keeps).
    start, end = 450, 490
    steps = observations(disturbance=(start, end, 5.0))
    twin = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05)
    held = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05)
    skipped = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05)
    exposed = PayloadEstimator(DYNAMICS, regressor=regressor, tare=0.05)
    lag = held.delay  # the equation formed at update k is of sample k - lag
    for estimator in (held, skipped, exposed):
        estimator.keep_checkpoints(12)
    place = 799  # the carry's last sample
    for observation in observations()[: place + 1]:
        twin.update(observation)
    for k, observation in enumerate(steps[: place + 1]):
        if k == start:
            held.hold_out()
            skipped.skip(end + lag - start + CONSISTENT_SAMPLES)
        for estimator in (held, skipped, exposed):
            estimator.update(observation)
        assert held.held_out == (start <= k < end + lag + CONSISTENT_SAMPLES - 1)
        assert held.rls.x == skipped.rls.x
    assert held.mass == pytest.approx(twin.mass, rel=0.03)
    assert abs(exposed.mass - twin.mass) > 0.1 * twin.mass  # the premise: taken in, the disturbance moves it
    held.hold_out()
    held.update(steps[place + 1])  # released: a hold-out ends with its carry, and none starts with the gripper open
    assert not held.held_out
    held.hold_out()
    assert not held.held_out


def test_a_slip_found_during_a_hold_out_ends_it_and_a_false_one_recovers_as_without_it() -> None:
    # A push holds the equations out, then a slip is (wrongly) found: the estimate restarts at the tare, whose
    # distance from the object still held would keep every later equation out of a hold-out that went on. It ends
    # with the restart: from there the estimate is the one of a slip found without a push before it, and the held
    # object's equations take it back towards the mass (from 0.05 to over 0.8 of 1.2 kg in 350 samples).
    pushed = PayloadEstimator(DYNAMICS, tare=0.05)
    dropped = PayloadEstimator(DYNAMICS, tare=0.05)
    for estimator in (pushed, dropped):
        estimator.keep_checkpoints(12)
    steps = observations()
    for k, observation in enumerate(steps[:800]):
        if k == 440:
            pushed.hold_out()
        if k == 451:
            for estimator in (pushed, dropped):
                estimator.drop_object()
            assert not pushed.held_out
        for estimator in (pushed, dropped):
            estimator.update(observation)
        if k >= 451:
            assert pushed.rls.x == dropped.rls.x
    assert pushed.rls.x > 0.8 * MASS


def test_rollback_restores_the_state_of_that_many_updates_ago_back_to_the_last_pick() -> None:
    estimator = PayloadEstimator(DYNAMICS, tare=0.05)
    kept = 12
    estimator.keep_checkpoints(kept)
    before, pick = {}, 300
    for k, observation in enumerate(observations(600)):
        before[k] = estimator_state(estimator)
        estimator.update(observation)
        if k in (200, 450):  # the state before update k - 4
            estimator.rollback(5)
            assert estimator_state(estimator) == before[k - 4]
        if k == 453:
            estimator.rollback(3)
            assert estimator_state(estimator) == before[451]
        if k == pick + 8:  # the smoother lags 5 samples: the carry's equations entered from update pick + 5 on
            estimator.rollback(kept)  # never behind the pick: the state as the pick reset the covariance
            x, variance, fit = estimator_state(estimator)
            assert (x, fit) == before[pick][::2] and variance == estimator.rls.initial_variance
            assert before[pick + 8][0] != before[pick][0]
    with pytest.raises(ValueError, match="samples must be in"):
        estimator.rollback(kept + 1)
    with pytest.raises(ValueError, match="size must be an integer >= 1"):
        estimator.keep_checkpoints(0)
    with pytest.raises(RuntimeError, match="keep_checkpoints"):
        PayloadEstimator(DYNAMICS).skip(1)


@pytest.mark.parametrize("mass_prior", [MASS_CORRECTION_STD, None])
def test_correction_fit_solves_its_normal_equations_with_the_prior(mass_prior: tuple | None) -> None:
    rng = np.random.default_rng(7)
    columns = rng.normal(0.0, 3.0, (40, 5))
    information, moment = columns.T @ columns, columns.T @ rng.normal(0.0, 2.0, 40)
    fit = CorrectionFit(mass_prior, FRICTION_SCALE_STD, EmptyMoveSums(information, moment))
    fitted = slice(0, 5) if mass_prior is not None else slice(2, 5)
    prior = np.array([*(MASS_CORRECTION_STD if mass_prior is not None else (1.0, 1.0)), *[FRICTION_SCALE_STD] * 3])
    expected = np.zeros(5)
    expected[fitted] = np.linalg.solve(
        information[fitted, fitted] + np.diag(prior[fitted] ** -2.0), moment[fitted]
    )  # parameters without a prior are held at 0
    corrections = fit.corrections
    assert_allclose([corrections.platform_mass, corrections.arm_mass_scale, *corrections.friction_scale], expected)
    assert fit.platform_mass == 0.0, "solved on a copy: the carries' solution is the one of the last carry's start"
    assert fit.samples == 0 and fit.fits
    with pytest.raises(ValueError, match="fits none"):
        CorrectionFit(None, None, EmptyMoveSums(information, moment))


@pytest.mark.parametrize(("regressor", "tolerance"), [("smoothed", 0.002), ("filtered", 0.003)])
def test_estimate_finds_the_payload_in_the_models_own_torques(regressor: str, tolerance: float) -> None:
    estimator = PayloadEstimator(
        DYNAMICS, regressor=regressor, tare=0.05, friction_scale_std=None, mass_correction_std=None
    )
    estimator.keep_checkpoints(12)
    # measured: 1.1 g (smoothed) and 1.9 g (filtered, its acceleration lag) from the truth; the reference regressor
    # assumes the joints at the reference, 20 ms ahead of them here
    masses = [(estimator.update(observation), estimator.mass) for observation in observations()]
    apparent, mass = masses[790]
    assert apparent == mass + 0.05 == pytest.approx(MASS, abs=tolerance)  # the apparent mass holds the tare
    assert masses[-1] == (0.05, 0.0)  # released: the object is gone


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


def test_predicted_variance_refuses_a_plan_of_the_wrong_shape_or_not_finite() -> None:
    estimator = PayloadEstimator(DYNAMICS)
    angles = np.full((5, 3), 0.3)
    with pytest.raises(ValueError, match=r"must each be \(n, 3\) of one n"):
        estimator.predicted_variance(angles, np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="must be finite"):
        estimator.predicted_variance(angles, np.full((5, 3), np.nan), np.zeros((5, 3)))
    # at rest nothing is learnt: the prior, faded by the forgetting
    variance = estimator.predicted_variance(angles, np.zeros((5, 3)), np.zeros((5, 3)))
    assert_allclose(variance, estimator.rls.initial_variance / 0.999 ** np.arange(1, 6))
