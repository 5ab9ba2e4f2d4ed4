"""The payload estimator's kernels against the Python paths they replace, bit for bit: the RLS update."""

import numpy as np
import pytest

from controllers.estimation import PayloadRLS, rls_update


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
