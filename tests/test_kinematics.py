"""Kinematics of the equivalent Delta robot: round trips, Jacobian, singularities, bad input."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from delta_env import NOMINAL_GEOMETRY, DeltaGeometry, kinematics

GEOMETRIES = [NOMINAL_GEOMETRY, DeltaGeometry(ra=0.12, rb=0.04, l1=0.25, l2=0.6)]


def reachable_points(geometry: DeltaGeometry, n: int, seed: int = 0) -> np.ndarray:
    """Random points of the lower workspace that the geometry reaches, (n, 3)."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-0.5, 1.2, size=(n, 3))
    return kinematics.forward(geometry, theta)


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_forward_inverts_inverse_over_workspace(geometry: DeltaGeometry) -> None:
    xyz = reachable_points(geometry, 2000)
    theta = kinematics.inverse(geometry, xyz)
    assert_allclose(kinematics.forward(geometry, theta), xyz, atol=1e-9)
    _, k = kinematics.constraint_terms(geometry, xyz, theta)
    assert np.all(k < 0.0), "inverse must return the elbow-out branch (k_i < 0)"


def test_home_pose_of_nominal_robot() -> None:
    g = NOMINAL_GEOMETRY
    expected_z = -np.sqrt(g.l2**2 - (g.r + g.l1) ** 2)
    assert_allclose(kinematics.forward(g, np.zeros(3)), [0.0, 0.0, expected_z], atol=1e-12)
    assert_allclose(expected_z, -0.795, atol=5e-4)
    assert_allclose(kinematics.inverse(g, [0.0, 0.0, expected_z]), np.zeros(3), atol=1e-9)


def test_positive_theta_turns_arms_down() -> None:
    z_home = kinematics.forward(NOMINAL_GEOMETRY, np.zeros(3))[2]
    assert kinematics.forward(NOMINAL_GEOMETRY, np.full(3, 0.3))[2] < z_home - 0.05


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_jacobian_matches_finite_differences(geometry: DeltaGeometry) -> None:
    theta = kinematics.inverse(geometry, reachable_points(geometry, 50, seed=1))
    step = 1e-6
    columns = [
        (kinematics.forward(geometry, theta + step * e) - kinematics.forward(geometry, theta - step * e)) / (2 * step)
        for e in np.eye(3)
    ]
    assert_allclose(kinematics.jacobian(geometry, theta), np.stack(columns, axis=-1), atol=1e-8)


def test_joint_and_cartesian_motion_round_trip() -> None:
    rng = np.random.default_rng(2)
    theta = kinematics.inverse(NOMINAL_GEOMETRY, reachable_points(NOMINAL_GEOMETRY, 500, seed=2))
    theta_dot = rng.normal(0.0, 3.0, theta.shape)
    theta_ddot = rng.normal(0.0, 100.0, theta.shape)
    xyz, xyz_dot, xyz_ddot = kinematics.joint_to_cartesian(NOMINAL_GEOMETRY, theta, theta_dot, theta_ddot)
    back = kinematics.cartesian_to_joint(NOMINAL_GEOMETRY, xyz, xyz_dot, xyz_ddot)
    assert_allclose(back[0], theta, atol=1e-10)
    assert_allclose(back[1], theta_dot, atol=1e-9)
    assert_allclose(back[2], theta_ddot, atol=1e-7)


def test_cartesian_acceleration_matches_differentiated_path() -> None:
    """xdd from joint motion equals the second derivative of FK along a smooth joint path."""
    t = np.linspace(0.0, 0.5, 5001)
    dt = t[1] - t[0]
    phase = np.array([0.0, 1.0, 2.0])
    theta = 0.3 + 0.4 * np.sin(7.0 * t[:, None] + phase)
    theta_dot = 2.8 * np.cos(7.0 * t[:, None] + phase)
    theta_ddot = -19.6 * np.sin(7.0 * t[:, None] + phase)
    xyz, xyz_dot, xyz_ddot = kinematics.joint_to_cartesian(NOMINAL_GEOMETRY, theta, theta_dot, theta_ddot)
    assert_allclose(np.gradient(xyz, dt, axis=0)[1:-1], xyz_dot[1:-1], atol=1e-5)
    assert_allclose(np.gradient(xyz_dot, dt, axis=0)[1:-1], xyz_ddot[1:-1], atol=1e-3)


def test_singularity_measures_detect_both_types() -> None:
    g = NOMINAL_GEOMETRY
    regular = kinematics.singularity_measures(g, np.zeros(3))
    assert regular.jacobian_condition < 10.0 and regular.min_abs_k > 0.1 and abs(regular.det_a) > 0.1
    # Serial type: at the workspace boundary along chain 1, arm 1 and its forearm align (k_1 = 0).
    inside, outside = 0.0, 2.0
    for _ in range(60):
        middle = 0.5 * (inside + outside)
        try:
            theta = kinematics.inverse(g, [middle, 0.0, -0.9])
            inside = middle
        except ValueError:
            outside = middle
    theta = kinematics.inverse(g, [inside, 0.0, -0.9])
    near_serial = kinematics.singularity_measures(g, theta)
    assert near_serial.min_abs_k < 1e-2 * regular.min_abs_k
    assert near_serial.jacobian_condition > 1e2 * regular.jacobian_condition


@pytest.mark.parametrize("geometry", GEOMETRIES)
def test_inverse_either_round_trips_or_raises(geometry: DeltaGeometry) -> None:
    """Every point inverse accepts comes back through forward within 1e-9 m; every other raises, naming it."""
    points = np.random.default_rng(3).uniform(-1.5, 1.5, size=(3000, 3))
    accepted = 0
    for point in points:
        try:
            theta = kinematics.inverse(geometry, point)
        except ValueError as error:
            assert str(np.round(point, 6).tolist()) in str(error)
            assert "base plane" in str(error) or "outside the reachable workspace" in str(error)
            continue
        accepted += 1
        assert_allclose(kinematics.forward(geometry, theta), point, atol=1e-9)
    assert accepted > 50
    # a batch with one bad point raises too (no NaN rows from inverse; elbow_out_angles is the NaN form)
    batch = np.vstack((reachable_points(geometry, 5), [[0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match=r"\[0\.0, 0\.0, 1\.0\] m is on or above the base plane: z must be < 0"):
        kinematics.inverse(geometry, batch)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: kinematics.inverse(NOMINAL_GEOMETRY, [0.0, 0.0, -2.0]), "outside the reachable workspace"),
        (lambda: kinematics.inverse(NOMINAL_GEOMETRY, [0.0, 0.0, 1.0]), r"above the base plane: z must be < 0"),
        (lambda: kinematics.inverse(NOMINAL_GEOMETRY, [0.0, 0.0, 0.0]), r"above the base plane: z must be < 0"),
        (lambda: kinematics.inverse(NOMINAL_GEOMETRY, [-0.36, 0.72, -0.03]), "above the plane of the elbows"),
        (lambda: kinematics.inverse(NOMINAL_GEOMETRY, [0.0, 0.0]), "length 3"),
        (lambda: kinematics.forward(NOMINAL_GEOMETRY, [np.nan, 0.0, 0.0]), "finite"),
        (
            lambda: kinematics.forward(DeltaGeometry(ra=0.3, rb=0.01, l1=0.5, l2=0.55), np.zeros(3)),
            "no real solution",
        ),
        (lambda: DeltaGeometry(ra=0.1, rb=0.2), "rb must be < ra"),
        (lambda: DeltaGeometry(l1=-1.0), "l1 must be"),
        (lambda: DeltaGeometry(l1=1.0, l2=0.5), "l2 must be > l1"),
    ],
)
def test_bad_input_raises_clear_error(call, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()
