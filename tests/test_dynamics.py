"""Inverse dynamics (MKH and identified forms): two derivations, energy, payload, regressors, MuJoCo."""

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import cumulative_simpson

from controllers.dynamics import DeltaDynamics, ModelParameters
from delta_env import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, kinematics

BATCH_SHAPES = [(), (7,), (4, 5)]


@pytest.fixture(scope="module")
def fast_move(joint_min_jerk_move):
    """``fast_move(dt)``: a 0.64 m platform move in 0.25 s: peaks of 6.2 g, 83 rad/s^2 and 6.8 rad/s at the joints."""

    def move(dt: float) -> tuple[np.ndarray, ...]:
        return joint_min_jerk_move(np.array([-0.3, 0.5, 0.2]), np.array([0.6, -0.2, 0.9]), 0.25, dt)

    return move


def per_joint_parameters(parameters: ModelParameters) -> np.ndarray:
    """(rho1, rho2, fv_i, fc_i) for each joint, ``(3, 4)``."""
    rho = np.broadcast_to([parameters.rho1, parameters.rho2], (3, 2))
    return np.column_stack((rho, parameters.viscous, parameters.coulomb))


@pytest.mark.parametrize("forearm_rods", [False, True])
@pytest.mark.parametrize("shape", BATCH_SHAPES)
@pytest.mark.parametrize("payload", [0.0, 3.8])
def test_lagrange_form_equals_virtual_work_form(
    random_joint_states, model_parameters, shape, payload, forearm_rods
) -> None:
    model = DeltaDynamics.nominal(model_parameters, forearm_rods=forearm_rods)
    states = random_joint_states(shape, seed=len(shape))
    torque = model.inverse_dynamics(*states, payload=payload)
    assert torque.shape == (*shape, 3)
    assert_allclose(torque, model.inverse_dynamics_virtual_work(*states, payload=payload), rtol=0, atol=1e-9)


@pytest.mark.parametrize("payload", [0.0, 3.8])
def test_lagrange_multipliers_balance_the_platform_and_give_the_torques(random_joint_states, payload) -> None:
    # Paper eqs. (4) and (5): Mt (xdd + g e_z) = 2 A^T lambda and tau = I thdd + G - 2 K lambda.
    model = DeltaDynamics.nominal()
    theta, theta_dot, theta_ddot = random_joint_states(30, seed=8)
    multipliers = model.lagrange_multipliers(theta, theta_dot, theta_ddot, payload=payload)
    xyz, _, xyz_ddot = kinematics.joint_to_cartesian(NOMINAL_GEOMETRY, theta, theta_dot, theta_ddot)
    a, k = kinematics.constraint_terms(NOMINAL_GEOMETRY, xyz, theta)
    m = NOMINAL_MASSES
    total_mass = m.m0 + payload + 3 * m.m2
    gravity = np.array([0.0, 0.0, 9.81])
    assert_allclose(2 * np.einsum("nij,ni->nj", a, multipliers), total_mass * (xyz_ddot + gravity), atol=1e-9)
    inertia, weight = (
        (m.m1 / 3 + m.m2) * NOMINAL_GEOMETRY.l1**2,
        (m.m1 / 2 + m.m2) * 9.81 * NOMINAL_GEOMETRY.l1,
    )
    expected = inertia * theta_ddot - weight * np.cos(theta) - 2 * k * multipliers
    assert_allclose(model.inverse_dynamics(theta, theta_dot, theta_ddot, payload=payload), expected, atol=1e-9)


@pytest.mark.parametrize(
    ("payload", "rho2", "expected"),
    # -g l1 (rho2 (m1/2 + m2) + Mt/3) = -3.6297 N m/kg x (rho2 1.2 + (1.4 + payload)/3) kg
    [(0.0, 1.0, -6.0495), (3.8, 1.0, -10.64712), (0.0, 1.2, -6.920628)],
)
def test_static_holding_torque_at_home(payload, rho2, expected) -> None:
    # Arms horizontal: by symmetry each forearm pair carries Mt g / 3 vertically at the lever l1
    # (its horizontal part points along the arm); the arm's weight acts at l1/2 and m2 at l1.
    model = DeltaDynamics.nominal(ModelParameters(rho1=1.5, rho2=rho2))
    torque = model.inverse_dynamics(np.zeros(3), np.zeros(3), np.zeros(3), payload=payload)
    assert_allclose(torque, np.full(3, expected), rtol=1e-6)


@pytest.mark.parametrize("payload", [0.5, 3.8, np.linspace(0.0, 4.0, 50)])
def test_torque_is_linear_in_payload(random_joint_states, model_parameters, payload) -> None:
    model = DeltaDynamics.nominal(model_parameters)
    states = random_joint_states(50, seed=3)
    phi = model.payload_regressor(*states)
    difference = model.inverse_dynamics(*states, payload=payload) - model.inverse_dynamics(*states)
    assert_allclose(difference, np.asarray(payload)[..., None] * phi, rtol=1e-12, atol=1e-11)
    # phi = J^T (xdd + g e_z), built here from the public Jacobian
    _, _, xyz_ddot = kinematics.joint_to_cartesian(NOMINAL_GEOMETRY, *states)
    expected = np.einsum(
        "nji,nj->ni", kinematics.jacobian(NOMINAL_GEOMETRY, states[0]), xyz_ddot + np.array([0.0, 0.0, 9.81])
    )
    assert_allclose(phi, expected, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("seed", range(4))
def test_identification_regressor_reproduces_inverse_dynamics(random_joint_states, seed) -> None:
    rng = np.random.default_rng(seed)
    parameters = ModelParameters(
        rho1=rng.uniform(0.8, 1.6),
        rho2=rng.uniform(0.8, 1.4),
        viscous=tuple(rng.uniform(0.0, 3.0, 3)),
        coulomb=tuple(rng.uniform(0.0, 6.0, 3)),
    )
    states = random_joint_states(100, seed=seed)
    payload = rng.uniform(0.0, 4.0, 100)
    rows, known = DeltaDynamics.nominal().identification_regressor(*states, payload=payload)
    assert rows.shape == (100, 3, 4)
    predicted = np.einsum("nik,ik->ni", rows, per_joint_parameters(parameters)) + known
    expected = DeltaDynamics.nominal(parameters).inverse_dynamics(*states, payload=payload)
    assert_allclose(predicted, expected, rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("payload", [0.0, 3.8])
def test_power_balances_energy_along_a_fast_move(fast_move, model_parameters, payload) -> None:
    # Independent of the multipliers: MId is MKH with the arm's kinetic energy scaled by rho1 and
    # its potential energy by rho2, so int tau . thd dt = d(T + V) + friction losses.
    dt = 1e-4
    theta, theta_dot, theta_ddot = fast_move(dt)
    model = DeltaDynamics.nominal(model_parameters)
    p, m, g, l1 = model.parameters, NOMINAL_MASSES, 9.81, NOMINAL_GEOMETRY.l1
    total_mass = m.m0 + payload + 3 * m.m2
    xyz, xyz_dot, _ = kinematics.joint_to_cartesian(NOMINAL_GEOMETRY, theta, theta_dot, theta_ddot)
    kinetic = 0.5 * total_mass * np.sum(xyz_dot**2, axis=1) + 0.5 * p.rho1 * (m.m1 / 3 + m.m2) * l1**2 * np.sum(
        theta_dot**2, axis=1
    )
    potential = total_mass * g * xyz[:, 2] - p.rho2 * (m.m1 / 2 + m.m2) * g * l1 * np.sum(np.sin(theta), axis=1)
    dissipated = np.sum(np.multiply(p.viscous, theta_dot**2) + np.multiply(p.coulomb, np.abs(theta_dot)), axis=1)
    power = np.sum(model.inverse_dynamics(theta, theta_dot, theta_ddot, payload=payload) * theta_dot, axis=1)
    work = cumulative_simpson(power - dissipated, dx=dt, initial=0.0)
    energy = kinetic + potential
    swing = np.ptp(energy)
    assert swing > 20.0, "the move must exchange a lot of energy for the check to mean something"
    assert_allclose(work, energy - energy[0], rtol=0, atol=1e-9 * swing)


METHODS = [
    "inverse_dynamics",
    "inverse_dynamics_virtual_work",
    "lagrange_multipliers",
    "payload_regressor",
    "identification_regressor",
]


def evaluate(model: DeltaDynamics, method: str, states: tuple, payload) -> tuple[np.ndarray, ...]:
    """A public method of the model on ``states``, its result as a tuple of arrays."""
    function = getattr(model, method)
    result = function(*states) if method == "payload_regressor" else function(*states, payload=payload)
    return result if isinstance(result, tuple) else (result,)


@pytest.mark.parametrize("method", METHODS)
def test_batch_equals_per_sample_loop(random_joint_states, identified_parameters, method) -> None:
    model = DeltaDynamics.nominal(identified_parameters)
    states = random_joint_states(20, seed=5)
    payload = np.linspace(0.0, 4.0, 20)
    batch = evaluate(model, method, states, payload)
    singles = [evaluate(model, method, tuple(s[n] for s in states), float(payload[n])) for n in range(20)]
    for part, single_parts in zip(batch, zip(*singles, strict=True), strict=True):
        assert_allclose(part, np.stack(single_parts), rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("payload", [0.0, 3.8])
def test_mkh_matches_mujoco_oracle_on_the_ideal_plant(random_joint_states, fast_move, payload) -> None:
    # Imported here so that the rest of this file runs without the plant (another engineer's files).
    from delta_env.config import PlantConfig
    from delta_env.oracle import InverseDynamicsOracle

    config = PlantConfig.ideal()
    m = config.masses
    model = DeltaDynamics(config.geometry, m1=m.m1, m2=m.m2, m0=m.m0)
    theta, theta_dot, theta_ddot = (
        np.concatenate(pair) for pair in zip(random_joint_states(20, seed=6), fast_move(dt=0.005), strict=True)
    )
    expected = InverseDynamicsOracle(config).torques(theta, theta_dot, theta_ddot, payload)
    assert np.abs(expected).max() > 100.0, "the states must load the robot"
    torque = model.inverse_dynamics(theta, theta_dot, theta_ddot, payload=payload)
    assert_allclose(torque, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("payload", [0.0, 2.0])
def test_rod_forearms_match_mujoco_on_the_realistic_mechanism(random_joint_states, fast_move, payload) -> None:
    # The realistic plant without drive effects: two thin 0.2 kg rods per chain and a hub-tube-bar upper arm.
    # With rod forearms only the upper arm is unknown, and it is exactly rho1 I thdd + rho2 G: a least squares
    # of (rho1, rho2) on MuJoCo's exact inverse dynamics must leave nothing. The lumped model cannot.
    from delta_env.config import PlantConfig, PlantRealism
    from delta_env.oracle import InverseDynamicsOracle

    states = tuple(
        np.concatenate(pair) for pair in zip(random_joint_states(60, seed=9), fast_move(dt=0.005), strict=True)
    )
    expected = InverseDynamicsOracle(PlantConfig(realism=PlantRealism.off())).torques(*states, payload)
    assert np.abs(expected).max() > 100.0, "the states must load the robot"
    residuals = {}
    for forearm_rods in (False, True):
        rows, known = DeltaDynamics.nominal(forearm_rods=forearm_rods).identification_regressor(*states, payload)
        columns, target = rows[..., :2].reshape(-1, 2), (expected - known).reshape(-1)
        rho, *_ = np.linalg.lstsq(columns, target, rcond=None)
        residuals[forearm_rods] = np.abs(target - columns @ rho).max()
    # Measured: 2.5e-4 N m with rods (rod radius, soft loop constraints), 4 N m lumped.
    assert residuals[True] < 1e-3
    assert residuals[False] > 1.0


@pytest.mark.parametrize("method", [m for m in METHODS if m != "payload_regressor"])
@pytest.mark.parametrize(
    "payload",
    [-0.1, float("nan"), np.array([1.0, -1.0])],
    ids=["negative", "nan", "negative-in-array"],
)
def test_bad_payload_raises(random_joint_states, method, payload) -> None:
    states = random_joint_states(2, seed=7)
    with pytest.raises(ValueError, match="payload"):
        evaluate(DeltaDynamics.nominal(), method, states, payload)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    ("theta", "message"),
    [
        (np.zeros(2), "theta must have a last axis of length 3"),
        (np.array([0.0, np.nan, 0.0]), "theta must be finite"),
        (np.array([0.0, 0.0, 3.0]), "no real solution"),
    ],
    ids=["two-joints", "nan", "unreachable"],
)
def test_bad_angles_raise(method, theta, message) -> None:
    zeros = np.zeros_like(theta)
    with pytest.raises(ValueError, match=message):
        evaluate(DeltaDynamics.nominal(), method, (theta, zeros, zeros), 0.0)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"rho1": 0.0}, "rho1"),
        ({"rho2": -1.0}, "rho2"),
        ({"rho1": float("nan")}, "rho1"),
        ({"viscous": (1.0, 2.0)}, "viscous"),
        ({"coulomb": (1.0, -2.0, 1.0)}, r"coulomb\[2\] must be a finite number in \[0, 400\] N m, got -2.0"),
        ({"coulomb": (1.0, 1e6, 1.0)}, r"coulomb\[2\] must be a finite number in \[0, 400\] N m, got 1000000.0"),
        ({"viscous": (1.0, 1.0, 1e4)}, r"viscous\[3\] must be a finite number in \[0, 1000\] N m s/rad, got 10000.0"),
        ({"rho1": 1001.0}, r"rho1 must be a finite number in \(0, 1000\], got 1001.0"),
        ({"rho2": 1e6}, r"rho2 must be a finite number in \(0, 1000\], got 1000000.0"),
    ],
)
def test_bad_model_parameters_raise(kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        ModelParameters(**kwargs)


def test_model_parameters_at_their_bounds_are_accepted() -> None:
    bounds = ModelParameters(rho1=10.0, rho2=10.0, viscous=(0.0, 1000.0, 1.0), coulomb=(0.0, 400.0, 4.0))
    assert bounds.coulomb == (0.0, 400.0, 4.0) and bounds.viscous == (0.0, 1000.0, 1.0)


@pytest.mark.parametrize(("kwargs", "name"), [({"m1": -2.0}, "m1"), ({"m0": 0.0}, "m0"), ({"g": np.inf}, "g")])
def test_bad_masses_raise(kwargs, name) -> None:
    arguments = {"geometry": DeltaGeometry(), "m1": 2.0, "m2": 0.2, "m0": 0.8} | kwargs
    with pytest.raises(ValueError, match=name):
        DeltaDynamics(**arguments)
