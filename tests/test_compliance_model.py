"""The analytical model's two-mass extension (``controllers.compliance``, docs/design.md section 4, "The two-mass
model"): the arm side's inertia against the inverse dynamics, the modes against the one-joint two-mass formula and
the first one against the plant's frequency response."""

import numpy as np
import pytest

from controllers.compliance import (
    DriveCompliance,
    TwoMassLinearization,
    drive_modes,
    first_mode,
    joint_space_inertia,
    two_mass_linearization,
)
from controllers.dynamics import DeltaDynamics, ModelParameters
from delta_env import kinematics
from delta_env.config import RATED_PAYLOAD
from delta_env.scenario import preset
from eval.identification.compliance import COMPLIANCE_POSES, measure_first_mode

POSES = [np.zeros(3), np.array([0.3, 0.1, 0.5]), np.array([0.8, 0.8, 0.8]), np.array([-0.2, 0.6, 0.1])]


@pytest.mark.parametrize("theta", POSES)
@pytest.mark.parametrize("payload", [0.0, 3.8])
def test_arm_inertia_reproduces_the_inverse_dynamics(theta: np.ndarray, payload: float) -> None:
    """tau(theta, 0, a) - tau(theta, 0, 0) = M(theta, m_p) a for any a; M symmetric and positive definite."""
    dynamics = DeltaDynamics.nominal(ModelParameters(1.3, 0.9, (2.0, 2.0, 2.0), (4.0, 4.0, 4.0)), forearm_rods=True)
    inertia = joint_space_inertia(dynamics, theta, payload)
    acceleration = np.random.default_rng(0).normal(0.0, 50.0, (5, 3))
    torque = dynamics.inverse_dynamics(np.broadcast_to(theta, (5, 3)), np.zeros((5, 3)), acceleration, payload)
    rest = dynamics.inverse_dynamics(theta, np.zeros(3), np.zeros(3), payload)
    np.testing.assert_allclose(torque - rest, acceleration @ inertia.T, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(inertia, inertia.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(inertia) > 0.1)


def test_modes_of_uncoupled_joints_are_the_two_mass_formula() -> None:
    """With a diagonal arm inertia each joint is a rotor against its arm: the deflection obeys
    J q_ddot + c q_dot + k q = 0 with J = J_m J_a / (J_m + J_a), so omega = sqrt(k / J), zeta = c / (2 sqrt(k J))."""
    compliance = DriveCompliance((0.1, 0.12, 0.08), (1.5e5, 2e5, 1e5), (8.0, 12.0, 5.0))
    arm = np.array([0.2, 0.35, 0.5])
    mass = np.diag(np.concatenate([compliance.rotor_inertia, arm]))
    k, c = np.diag(compliance.stiffness), np.diag(compliance.damping)
    linear = TwoMassLinearization(mass, np.block([[c, -c], [-c, c]]), np.block([[k, -k], [-k, k]]))
    reduced = 1.0 / (1.0 / np.array(compliance.rotor_inertia) + 1.0 / arm)
    expected = np.sqrt(np.array(compliance.stiffness) / reduced) / (2 * np.pi)
    ratio = np.array(compliance.damping) / (2 * np.sqrt(np.array(compliance.stiffness) * reduced))
    order = np.argsort(expected)
    modes = linear.modes()
    assert len(modes) == 3
    np.testing.assert_allclose([m.frequency_hz for m in modes], expected[order], rtol=1e-9)
    np.testing.assert_allclose([m.damping_ratio for m in modes], ratio[order], rtol=1e-9)
    lowest = order[0]
    # rotor and arm of the lowest joint swing against each other, in the ratio of their inertias
    shape = modes[0].shape
    np.testing.assert_allclose(shape[3 + lowest] / shape[lowest], -compliance.rotor_inertia[lowest] / arm[lowest])
    assert np.all(np.abs(np.delete(shape, [lowest, 3 + lowest])) < 1e-9)


@pytest.mark.parametrize("payload", [0.0, 4.0])
def test_symmetric_mode_at_home_is_the_two_mass_formula_of_the_chain(payload: float) -> None:
    """At home M is circulant, so all rotors turned alike is a mode: the two-mass formula with the arms' symmetric
    inertia J_a = 1' M 1 / 3; it is the highest of the three (the lateral pair is lower and alike)."""
    dynamics = DeltaDynamics.nominal(forearm_rods=True)
    compliance = DriveCompliance.nominal()
    arm = np.sum(joint_space_inertia(dynamics, np.zeros(3), payload)) / 3.0
    reduced = 1.0 / (1.0 / compliance.rotor_inertia[0] + 1.0 / arm)
    modes = drive_modes(dynamics, compliance, np.zeros(3), payload)
    np.testing.assert_allclose(modes[2].frequency_hz, np.sqrt(compliance.stiffness[0] / reduced) / (2 * np.pi))
    np.testing.assert_allclose(modes[0].frequency_hz, modes[1].frequency_hz, rtol=1e-9)
    assert modes[0].frequency_hz < 0.95 * modes[2].frequency_hz
    np.testing.assert_allclose(modes[2].shape[:3], 1.0, rtol=1e-9)


def test_payload_and_stiffness_move_the_first_mode() -> None:
    """A payload lowers the first mode; a gearhead twice as stiff raises it by sqrt(2); the model's viscous
    friction on the rotor adds damping."""
    dynamics = DeltaDynamics.nominal(forearm_rods=True)
    compliance = DriveCompliance.nominal()
    theta = np.array([0.3, 0.1, 0.5])
    empty, loaded = first_mode(dynamics, compliance, theta, 0.0), first_mode(dynamics, compliance, theta, 4.0)
    assert loaded.frequency_hz < 0.97 * empty.frequency_hz
    stiffer = DriveCompliance(compliance.rotor_inertia, tuple(2 * np.array(compliance.stiffness)), compliance.damping)
    np.testing.assert_allclose(first_mode(dynamics, stiffer, theta).frequency_hz, np.sqrt(2) * empty.frequency_hz)
    rubbing = dynamics.with_parameters(ModelParameters(viscous=(5.0, 5.0, 5.0)))
    assert first_mode(rubbing, compliance, theta).damping_ratio > 1.1 * empty.damping_ratio
    linear = two_mass_linearization(dynamics, compliance, theta)
    np.testing.assert_allclose(linear.stiffness.sum(axis=1), 0.0, atol=1e-6)


def test_compliance_is_checked() -> None:
    with pytest.raises(ValueError, match="stiffness"):
        DriveCompliance((0.1,) * 3, (1e5, -1.0, 1e5), (1.0,) * 3)
    with pytest.raises(ValueError, match="rotor_inertia"):
        DriveCompliance(0.0, 1e5, 1.0)
    with pytest.raises(ValueError, match="theta"):
        joint_space_inertia(DeltaDynamics.nominal(), np.zeros(2))
    heavy = DriveCompliance(0.1, 1e3, 1000.0)
    with pytest.raises(ValueError, match="critical"):
        first_mode(DeltaDynamics.nominal(), heavy, np.zeros(3))


@pytest.mark.parametrize("pose", COMPLIANCE_POSES)
def test_the_models_first_mode_is_the_plants(pose: tuple[float, float, float]) -> None:
    """The two-mass model with the data sheet's drives (nominal arm, rod forearms) against the `compliant` preset's
    frequency response, empty and at the rated payload: within 3 % (measured within 0.2 %: the model's arm inertia,
    3 to 6 % light, and MuJoCo's explicit spring, 1.6 % fast at 0.25 ms, nearly cancel)."""
    plant = preset("compliant").plant
    dynamics = DeltaDynamics.of_robot(plant.geometry, plant.masses, forearm_rods=True)
    compliance = DriveCompliance.of_gearhead(plant.realism.compliance)
    theta = kinematics.inverse(plant.geometry, np.array(pose))
    for payload in (0.0, RATED_PAYLOAD):
        measured = measure_first_mode(plant, pose, payload)
        np.testing.assert_allclose(
            first_mode(dynamics, compliance, theta, payload).frequency_hz, measured.frequency_hz, rtol=0.03
        )
