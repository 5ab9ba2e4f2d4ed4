"""Controllers: the fast single-sample model, PD + feedforward, payload RLS on the plant, and no truth access."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers.dynamics import DeltaDynamics, ModelParameters
from delta_env import NOMINAL_MASSES, DeltaGeometry
from tests.test_dynamics import IDENTIFIED, random_joint_states


@pytest.mark.parametrize("parameters", [None, IDENTIFIED])
def test_single_sample_model_equals_the_batched_model(parameters: ModelParameters | None) -> None:
    model = DeltaDynamics.nominal(parameters)
    theta, theta_dot, theta_ddot = random_joint_states(300, seed=11)
    theta_dot[:10, 1] = 0.0  # sign(0) = 0 in both paths
    tau0 = model.inverse_dynamics(theta, theta_dot, theta_ddot)
    phi = model.payload_regressor(theta, theta_dot, theta_ddot)
    for n in range(len(theta)):
        fast_tau0, fast_phi = model.torque_and_payload_regressor(theta[n], theta_dot[n], theta_ddot[n])
        assert_allclose(fast_tau0, tau0[n], rtol=0.0, atol=1e-9)
        assert_allclose(fast_phi, phi[n], rtol=0.0, atol=1e-9)


@pytest.mark.parametrize(
    ("l2", "theta", "message"),
    [
        (0.95, [np.nan, 0.0, 0.0], "finite"),
        (0.95, [0.0, 0.0], "3 values"),
        (0.4, [0.0, 0.0, 0.0], "no real solution"),  # forearms too short to meet
    ],
)
def test_single_sample_model_rejects_bad_states(l2: float, theta: list[float], message: str) -> None:
    masses = NOMINAL_MASSES
    model = DeltaDynamics(DeltaGeometry(l2=l2), m1=masses.m1, m2=masses.m2, m0=masses.m0)
    with pytest.raises(ValueError, match=message):
        model.torque_and_payload_regressor(theta, np.zeros(3), np.zeros(3))
