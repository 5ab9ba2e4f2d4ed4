"""The fault monitor's compiled arithmetic gives the NumPy expressions' numbers (controllers.monitor.compiled).

The kernels keep NumPy's order of operations, so on this machine (OpenBLAS with fused multiply-adds) they agree to
the last bit, and the comparison's tables and detections were checked identical end to end; the tests ask for
1e-12 relative, which any wrong term fails by orders of magnitude, so that another BLAS or CPU does not fail them
on a last bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import SMOOTHER_LAG, JointStateSmoother
from controllers.monitor.compiled import (
    correction_terms,
    encoders_plausible,
    learn_scatter,
    loop_output,
    model_residual,
    platform_force,
    slip_moments,
    torque_step_variance,
    torques_plausible,
)
from controllers.monitor.detector import loop_response
from controllers.monitor.model_check import COLLIDED, COLLIDING, ModelCheck, _slip_band
from controllers.monitor.tuning import MONITOR_JERK_STD
from controllers.payload import FRICTION_VELOCITY, RESIDUAL_STD, TORQUE_AGE, ModelCorrections, residual_std
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD

PARAMETERS = ModelParameters(rho1=1.8, rho2=0.9, viscous=(2.0, 2.4, 1.7), coulomb=(4.1, 3.4, 4.5))
TOLERANCE = 1e-12
"""Relative agreement asked of the kernels (module docstring)."""


def _same(actual: np.ndarray, expected: np.ndarray) -> None:
    np.testing.assert_allclose(actual, expected, rtol=TOLERANCE, atol=1e-12)


CORRECTIONS = ModelCorrections(platform_mass=0.3, arm_mass_scale=-0.05, friction_scale=np.array([0.1, -0.2, 0.05]))


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
    terms_bytes = correction_terms(
        corrections, dynamics.inertia, dynamics.gravity_amplitude, PARAMETERS.viscous, PARAMETERS.coulomb
    )
    viscous, coulomb = np.array(PARAMETERS.viscous), np.array(PARAMETERS.coulomb)
    for state, previous, torque in _samples(200):
        status, terms = model_residual(dynamics.model_constants, state, previous, TORQUE_AGE, torque, terms_bytes)
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
    no_corrections = correction_terms(None, 1.0, 1.0, (0.0,) * 3, (0.0,) * 3)
    status, _ = model_residual(dynamics.model_constants, state, state, TORQUE_AGE, np.zeros(3), no_corrections)
    assert status != kernels.VALID
    with pytest.raises(ValueError, match=kernels.INVALID_STATE[status]):
        dynamics.torque_regressor_and_force_map(*state)


def test_platform_force_is_the_numpy_force() -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    no_corrections = correction_terms(None, 1.0, 1.0, (0.0,) * 3, (0.0,) * 3)
    coulomb = np.array(PARAMETERS.coulomb)
    breakaway = 1.5 * coulomb
    rest_rate = 0.2
    slow_rows = 0
    for index, (state, previous, torque) in enumerate(_samples(300, seed=1)):
        if index % 2:  # rates around the friction's unknown band too
            state, previous = state.copy(), previous.copy()
            state[1] *= 0.05
            previous[1] = state[1]
        _, terms = model_residual(dynamics.model_constants, state, previous, TORQUE_AGE, torque, no_corrections)
        residual, phi, theta_dot = terms[0], terms[1], terms[2]
        slow = np.abs(theta_dot) < rest_rate
        slow_rows += int(slow.any())
        charged = coulomb * np.sign(theta_dot)
        # the map as the model gives it: its memory layout picks OpenBLAS's kernel, and so the order of the sums
        _, _, force_map = dynamics.torque_regressor_and_force_map(*(state - TORQUE_AGE * (state - previous)))
        projected = residual - (residual @ phi) / float(phi @ phi) * phi
        for held_mass, subtract, project, external in (
            (0.0, False, False, residual),
            (1.7, True, True, residual - 1.7 * phi),
            (0.0, False, True, projected),
        ):
            expected = np.where(slow, external - np.clip(external, -breakaway - charged, breakaway - charged), external)
            force, magnitude = platform_force(terms, held_mass, subtract, project, coulomb, breakaway, rest_rate)
            _same(force, force_map @ expected)
            assert magnitude == pytest.approx(float(np.linalg.norm(force_map @ expected)), rel=TOLERANCE)
    assert slow_rows > 100


def test_torque_step_variance_is_the_numpy_sum() -> None:
    rng = np.random.default_rng(4)
    squared_response = rng.uniform(0.0, 0.3, 26)
    torques = rng.normal(0.0, 30.0, (27, 3))
    expected_torques = torques.copy()
    for _ in range(40):
        torque = rng.normal(0.0, 30.0, 3)
        expected_torques = np.vstack((expected_torques[1:], torque))
        variance = torque_step_variance(torques, torque, squared_response)
        _same(torques, expected_torques)
        _same(variance, squared_response @ np.diff(expected_torques, axis=0) ** 2)


def test_scatter_and_slip_moments_are_the_numpy_ones() -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    coulomb = np.array(PARAMETERS.coulomb)
    no_corrections = correction_terms(None, 1.0, 1.0, (0.0,) * 3, (0.0,) * 3)
    scatter = np.full(3, 16.0)
    expected_scatter = scatter.copy()
    for state, previous, torque in _samples(300, seed=2):
        _, terms = model_residual(dynamics.model_constants, state, previous, TORQUE_AGE, torque, no_corrections)
        residual, phi, theta_dot = terms[0], terms[1], terms[2]
        deviation = residual - 2.5 * phi
        learned = 0.99 * expected_scatter + 0.01 * deviation * deviation
        moving = np.abs(theta_dot) > FRICTION_VELOCITY
        expected_scatter = np.where(moving, np.maximum(learned, RESIDUAL_STD**2), expected_scatter)
        learn_scatter(scatter, terms, 2.5, FRICTION_VELOCITY, 0.01, RESIDUAL_STD**2)
        _same(scatter, expected_scatter)
        band = residual_std(theta_dot, coulomb, 0.0)
        weight = 1.0 / (band * band + scatter)
        information, moment = slip_moments(terms, band, scatter)
        assert information == pytest.approx(float(np.sum(weight * phi * phi)), rel=TOLERANCE)
        assert moment == pytest.approx(float(np.sum(weight * phi * residual)), rel=TOLERANCE, abs=1e-12)


def _plausible_reference(torque, last, command, before, hold, keep, peak, margin, drift, largest) -> bool:
    """The torque fast path written in Python (min/max, NaN included): the span of the last reading and the two
    commands, and the slowest loop's two-stage output."""
    for now, previous, asked, asked_before, hold_j, keep_j in zip(
        *(np.asarray(v).tolist() for v in (torque, last, command, before, hold, keep)), strict=True
    ):
        if not np.isfinite(now):
            return False
        held, earlier = min(max(asked, -peak), peak), min(max(asked_before, -peak), peak)
        if now < min(previous, held, earlier) - margin or now > max(previous, held, earlier) + margin:
            return False
        step = held - previous
        direction = (step > 0.0) - (step < 0.0) if abs(step) > margin else (held > 0.0) - (held < 0.0)
        slowest = held + (earlier - held) * hold_j + (previous - earlier) * keep_j
        if min((slowest - now) * direction, largest) > drift:
            return False
    return True


def test_torques_plausible_is_the_python_check_with_nan_and_infinities() -> None:
    rng = np.random.default_rng(3)
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 200.0, -200.0])
    peak, margin, drift, largest = 100.0, 2.0, 0.5, 5.0
    outcomes = []
    for _ in range(20000):
        values = rng.normal(0.0, 30.0, (6, 3))
        values[4] = rng.uniform(0.1, 0.8, 3)  # the slowest loop's hold and keep per sample (keep < hold)
        values[5] = values[4] * rng.uniform(0.3, 0.95, 3)
        mask = rng.random((4, 3)) < 0.05
        values[:4][mask] = rng.choice(special, int(mask.sum()))
        torque, last, command, before, hold, keep = values
        with np.errstate(invalid="ignore"):  # inf - inf where a special value was drawn
            clipped, clipped_before = np.clip(command, -peak, peak), np.clip(before, -peak, peak)
            healthy = loop_output(last, clipped_before, clipped, hold, keep) + rng.normal(0.0, 0.3, 3)
        torque[:] = np.where(rng.random(3) < 0.9, healthy, torque)  # mostly where a healthy loop would be
        expected = _plausible_reference(torque, last, command, before, hold, keep, peak, margin, drift, largest)
        assert torques_plausible(torque, last, command, before, hold, keep, peak, margin, drift, largest) == expected
        outcomes.append(expected)
    assert 0.05 < np.mean(outcomes) < 0.95  # both answers are exercised
    short = np.zeros(2)
    assert not torques_plausible(short, short, short, short, short, short, peak, margin, drift, largest)


def test_loop_output_is_the_first_order_loop_sampled_half_a_period_late() -> None:
    # The reading at t_k - d: from the last reading (t_{k-1} - d) towards the command before for d, then towards
    # the command held since t_{k-1}; integrated finely, against the closed form.
    lag, period, age = 1.3e-3, CONTROL_PERIOD, TORQUE_AGE
    hold, keep = (value[0] for value in loop_response([lag]))
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


def test_model_check_lags_the_smoothed_tracking_error_behind_the_reference() -> None:
    """The state the checks take is the reference a smoother's lag ago plus the JointStateSmoother estimate of the
    tracking error (its window, start and lag): the model check's record against the smoother itself."""
    rng = np.random.default_rng(8)
    check = ModelCheck(PARAMETERS.coulomb)
    check.set_friction(np.array(PARAMETERS.coulomb), 1.5 * np.array(PARAMETERS.coulomb))
    smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    corrections = correction_terms(
        None, dynamics.inertia, dynamics.gravity_amplitude, PARAMETERS.viscous, PARAMETERS.coulomb
    )
    references = []
    for k in range(60):
        reference = np.stack(
            (0.4 + 0.01 * k + rng.normal(0.0, 1e-4, 3), rng.normal(0.0, 1.0, 3), rng.normal(0.0, 9, 3))
        )
        angles = reference[0] + rng.normal(0.0, 1e-3, 3)
        if k == 0:
            smoother.reset(angles - reference[0])
        expected = smoother.update_state(angles - reference[0]).copy()
        references.append(reference)
        check.check(
            dynamics.model_constants, corrections, angles, tuple(reference), rng.normal(0, 5, 3), False, False, k
        )
        if k >= SMOOTHER_LAG:
            _same(check._state["previous"][0], references[k - SMOOTHER_LAG] + expected)


def _encoders_reference(
    raw: np.ndarray,
    rates: np.ndarray,
    last: np.ndarray,
    before: np.ndarray,
    previous: np.ndarray,
    reference_rates: np.ndarray,
    bound: float,
    step: float,
) -> bool:
    """The encoder fast path's conditions in NumPy (FaultMonitor's full check passes such readings unchanged)."""
    with np.errstate(invalid="ignore"):
        if not (np.isfinite(raw).all() and np.isfinite(rates).all()):
            return False
        if (np.abs(raw - 2.0 * last + before) > bound).any():
            return False
        suspect = (
            (raw == previous) & (np.abs(reference_rates) * CONTROL_PERIOD >= step) & (np.abs(last - before) >= step)
        )
        return not suspect.any()


def test_encoders_plausible_is_the_numpy_check_with_repeats_jumps_and_nan() -> None:
    rng = np.random.default_rng(9)
    bound, step = 2e-3, 4e-5
    outcomes = []
    for _ in range(20000):
        before = rng.uniform(0.1, 0.8, 3)
        last = before + rng.normal(0.0, 1e-3, 3) * rng.choice([0.0, 1.0], 3)
        raw = 2.0 * last - before + rng.normal(0.0, 1.2e-3, 3)
        previous = np.where(rng.random(3) < 0.3, raw, last)
        rates = rng.normal(0.0, 1.0, 3)
        reference_rates = rng.normal(0.0, 0.05, 3)
        if rng.random() < 0.05:
            (raw if rng.random() < 0.5 else rates)[rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf])
        expected = _encoders_reference(raw, rates, last, before, previous, reference_rates, bound, step)
        actual = encoders_plausible(raw, rates, last, before, previous, reference_rates, bound, step, CONTROL_PERIOD)
        assert actual == expected
        outcomes.append(expected)
    assert 0.2 < np.mean(outcomes) < 0.8  # both answers are exercised


def _rest_inputs(offset_from: int, samples: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(angles, reference (3, 3), torque) of an arm at rest at 0.4 rad holding its model torque, with 150 N m more on
    joint 0 from sample ``offset_from`` on (a force on the platform)."""
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    corrections = correction_terms(None, dynamics.inertia, dynamics.gravity_amplitude, (0, 0, 0), (0, 0, 0))
    reference = np.stack((np.full(3, 0.4), np.zeros(3), np.zeros(3)))
    status, terms = model_residual(dynamics.model_constants, reference, reference, TORQUE_AGE, np.zeros(3), corrections)
    assert status == kernels.VALID
    holding = -terms[0]  # the model torque at rest
    inputs = []
    for sample in range(samples):
        torque = holding + (np.array([150.0, 0.0, 0.0]) if sample >= offset_from else 0.0)
        inputs.append((reference[0].copy(), reference, torque))
    return inputs


def test_model_check_detects_a_force_once_clears_it_when_quiet_and_repeats_after_a_reset() -> None:
    dynamics = DeltaDynamics.nominal(PARAMETERS)
    corrections = correction_terms(
        None, dynamics.inertia, dynamics.gravity_amplitude, PARAMETERS.viscous, PARAMETERS.coulomb
    )
    check = ModelCheck(PARAMETERS.coulomb)
    check.set_friction(np.array(PARAMETERS.coulomb), 1.5 * np.array(PARAMETERS.coulomb))
    inputs = _rest_inputs(offset_from=40, samples=80)

    def run() -> list[int]:
        found = []
        for sample, (angles, reference, torque) in enumerate(inputs):
            quiet = sample == 70  # e.g. a replaced reading: no check on this sample
            found.append(
                check.check(
                    dynamics.model_constants, corrections, angles, tuple(reference), torque, False, quiet, sample
                )
            )
        return found

    first = run()
    collided = [sample for sample, bits in enumerate(first) if bits & COLLIDED]
    # found a smoother's lag after the force starts; a quiet sample clears the evidence at its own check and again
    # when its reading reaches the checked state, and the force, still there, is found on the next sample
    assert collided == [40 + SMOOTHER_LAG, 71, 70 + SMOOTHER_LAG + 1]
    assert not any(bits & COLLIDING for bits in first[: collided[0]])
    assert all(bits & COLLIDING for bits in first[collided[0] : 70])
    assert not first[70] & COLLIDING and not first[70 + SMOOTHER_LAG] & COLLIDING
    assert check.force_magnitude > 100.0
    state = check._state.tobytes()
    check.reset()
    assert run() == first and check._state.tobytes() == state
