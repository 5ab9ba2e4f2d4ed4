"""Workspace, dexterity and singularity analysis (delta_env.workspace) and the mass-scaling rule."""

import math

import numpy as np
import pytest

from delta_env import kinematics, workspace
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.scaling import GRIPPER_MASS, scaled_masses

# Reachable-only criteria without joint, cone or skew limits: the bare inverse kinematics.
BARE = workspace.Criteria(
    theta_range=(-math.pi, math.pi), max_forearm_tilt=math.pi, min_conditioning=0.0, max_skew=math.pi / 2
)


def _random_reachable_points(geometry: DeltaGeometry, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-0.3, 1.2, size=(count, 3))
    return kinematics.forward(geometry, theta)


def _finite_difference_jacobian(geometry: DeltaGeometry, theta: np.ndarray, step: float = 1e-6) -> np.ndarray:
    columns = []
    for j in range(3):
        delta = np.zeros(3)
        delta[j] = step
        columns.append(
            (kinematics.forward(geometry, theta + delta) - kinematics.forward(geometry, theta - delta)) / 2 / step
        )
    return np.stack(columns, axis=-1)


def test_monte_carlo_volume_of_a_sphere_is_within_its_stated_error():
    radius, centre = 0.5, np.array([0.0, 0.1, -1.0])

    def inside(points):
        return np.linalg.norm(points - centre, axis=-1) <= radius

    volume, error = workspace.monte_carlo_volume(inside, (0.7, -1.6, -0.4), 200_000, seed=3)
    exact = 4.0 / 3.0 * math.pi * radius**3
    assert abs(volume - exact) < 4.0 * error
    assert 0.002 < error / exact < 0.01  # the binomial error of ~200k samples at this fill ratio


def test_reachable_volume_agrees_with_a_grid_integration_and_is_seeded():
    geometry = NOMINAL_GEOMETRY
    volume, error = workspace.reachable_volume_estimate(geometry, samples=200_000, seed=1)
    assert workspace.reachable_volume(geometry, samples=200_000, seed=1) == volume
    assert workspace.reachable_volume(geometry, samples=200_000, seed=2) != volume
    # independent: midpoint rule on a 20 mm Cartesian grid over the reach bounds
    reach, z_min, z_max = workspace.reach_bounds(geometry)
    step = 0.02
    axis = np.arange(-reach + step / 2, reach, step)
    heights = np.arange(z_min + step / 2, z_max, step)
    x, y, z = np.meshgrid(axis, axis, heights, indexing="ij")
    grid = np.stack((x, y, z), axis=-1)
    criteria = workspace.Criteria(min_conditioning=0.0)
    grid_volume = np.count_nonzero(workspace.admissible(geometry, grid, criteria)) * step**3
    assert abs(volume - grid_volume) < 4.0 * error + 0.01 * grid_volume


def test_reach_bounds_hold_every_reachable_point():
    radius, z_min, z_max = workspace.reach_bounds(NOMINAL_GEOMETRY, (-math.pi, math.pi))
    points = _random_reachable_points(NOMINAL_GEOMETRY, 2000, seed=4)
    assert np.all(np.hypot(points[:, 0], points[:, 1]) <= radius)
    assert np.all((points[:, 2] >= z_min) & (points[:, 2] <= z_max))


def test_a_higher_dexterity_threshold_only_removes_volume():
    low = workspace.reachable_volume(NOMINAL_GEOMETRY, min_conditioning=0.0, samples=50_000)
    high = workspace.reachable_volume(NOMINAL_GEOMETRY, min_conditioning=0.4, samples=50_000)
    assert 0.0 < high < low


def test_conditioning_and_imi_match_finite_difference_jacobians_of_fk():
    geometry = DeltaGeometry(0.25, 0.06, 0.4, 1.0)
    points = _random_reachable_points(geometry, 20, seed=5)
    measures = workspace.pose_measures(geometry, points)
    for point, theta, conditioning, imi in zip(
        points, measures.theta, measures.conditioning, measures.imi, strict=True
    ):
        jac = _finite_difference_jacobian(geometry, theta)
        assert kinematics.forward(geometry, theta) == pytest.approx(point, abs=1e-12)
        assert conditioning == pytest.approx(1.0 / np.linalg.cond(jac), rel=1e-6)
        assert imi == pytest.approx(1.0 / math.sqrt(np.linalg.det(jac @ jac.T)), rel=1e-6)


def test_isotropic_speed_matches_a_search_over_directions():
    geometry = NOMINAL_GEOMETRY
    point = np.array([0.3, -0.2, -0.95])
    theta = kinematics.inverse(geometry, point)
    inverse_jacobian = np.linalg.inv(kinematics.jacobian(geometry, theta))
    directions = np.random.default_rng(6).normal(size=(200_000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    worst = np.max(np.abs(directions @ inverse_jacobian.T))  # largest joint rate per unit platform speed
    speed = workspace.isotropic_speed(geometry, point, 10.0)
    assert speed == pytest.approx(10.0 / worst, rel=2e-3)
    assert speed <= 10.0 / worst + 1e-12


def test_serial_singularity_at_the_reach_boundary():
    # along +x, an arm and its forearm align (k_i = 0) where the point leaves that chain's reach
    geometry = NOMINAL_GEOMETRY
    low, high = 0.0, 1.5
    for _ in range(60):
        middle = (low + high) / 2
        reachable = workspace.pose_measures(geometry, np.array([middle, 0.0, -0.9])).reachable
        low, high = (middle, high) if reachable else (low, middle)
    edge = workspace.pose_measures(geometry, np.array([low, 0.0, -0.9]))
    inside = workspace.pose_measures(geometry, np.array([low - 0.05, 0.0, -0.9]))
    assert edge.min_abs_k < 1e-6 < 0.05 < inside.min_abs_k
    assert edge.conditioning < 1e-5
    assert abs(edge.det_a) > 0.02  # not a parallel singularity


def test_parallel_singularity_where_the_forearms_are_coplanar():
    # all forearms horizontal (platform at elbow height): r + l1 cos th = l2 on the axis, det A = 0
    geometry = DeltaGeometry(0.2, 0.05, 0.5, 0.55)
    theta = math.acos((geometry.l2 - geometry.r) / geometry.l1)
    point = np.array([0.0, 0.0, -geometry.l1 * math.sin(theta)])
    singular = workspace.pose_measures(geometry, point)
    assert singular.theta == pytest.approx([theta] * 3, abs=1e-6)
    assert abs(singular.det_a) < 1e-9
    assert singular.conditioning < 1e-6
    assert singular.min_abs_k > 0.1  # not a serial singularity
    near = workspace.pose_measures(geometry, point + np.array([0.0, 0.0, -0.01]))
    assert abs(near.det_a) > 1e-4 and near.conditioning > 1e-3


def test_unreachable_points_are_nan_and_never_admissible():
    measures = workspace.pose_measures(NOMINAL_GEOMETRY, np.array([[0.0, 0.0, -3.0], [0.0, 0.0, -0.9]]))
    assert list(measures.reachable) == [False, True]
    assert np.isnan(measures.conditioning[0]) and np.isnan(measures.det_a[0])
    assert list(measures.admissible(BARE)) == [False, True]


def test_slice_maps_have_the_grid_shape_and_nominal_centre_values():
    slice_ = workspace.slice_map(NOMINAL_GEOMETRY, "horizontal", -0.9, (-0.5, 0.5), (-0.5, 0.5), resolution=21)
    assert slice_.points.shape == (21, 21, 3) and slice_.measures.det_a.shape == (21, 21)
    centre = slice_.measures
    assert centre.det_a[10, 10] == pytest.approx(-0.537, abs=1e-3)  # WorkspaceLimits' nominal scale
    assert centre.min_abs_k[10, 10] == pytest.approx(0.336, abs=1e-3)
    vertical = workspace.slice_map(NOMINAL_GEOMETRY, "vertical", 0.0, (-0.5, 0.5), (-1.2, -0.6), resolution=11)
    assert np.all(vertical.points[..., 1] == 0.0)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: workspace.Criteria(theta_range=(1.0, 0.0)), "theta_range"),
        (lambda: workspace.Criteria(min_conditioning=1.5), "min_conditioning"),
        (lambda: workspace.Criteria(max_forearm_tilt=0.0), "max_forearm_tilt"),
        (lambda: workspace.reachable_volume(NOMINAL_GEOMETRY, samples=10), "samples"),
        (lambda: workspace.slice_map(NOMINAL_GEOMETRY, "oblique", 0.0, (0, 1), (0, 1)), "plane"),
        (lambda: workspace.isotropic_speed(NOMINAL_GEOMETRY, [0, 0, -0.9], -1.0), "joint_speed_limit"),
        (lambda: workspace.pose_measures(NOMINAL_GEOMETRY, [0.0, 0.0]), "xyz"),
    ],
)
def test_bad_arguments_are_named(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_scaled_masses_follow_the_stated_rule():
    assert scaled_masses(NOMINAL_GEOMETRY) == NOMINAL_MASSES
    longer = scaled_masses(DeltaGeometry(0.2, 0.1, 0.74, 1.9))
    assert longer.m1 == pytest.approx(2**2.5 * NOMINAL_MASSES.m1)  # constant tip stiffness: l1^(5/2)
    assert longer.m2 == pytest.approx(4 * NOMINAL_MASSES.m2)  # constant axial stiffness: l2^2
    assert longer.m0 == pytest.approx(GRIPPER_MASS + 4 * (NOMINAL_MASSES.m0 - GRIPPER_MASS))
    with pytest.raises(ValueError, match=r"reference_masses\.m0"):
        scaled_masses(NOMINAL_GEOMETRY, reference_masses=DeltaMasses(m1=2.0, m2=0.2, m0=0.2))


@pytest.mark.parametrize(
    "criteria",
    [workspace.DEXTEROUS, workspace.REACHABLE, workspace.Criteria(min_conditioning=0.35, max_skew=0.3)],
    ids=["dexterous", "reachable", "strict"],
)
def test_admissible_is_the_pose_measures_test(criteria: workspace.Criteria) -> None:
    # admissible computes only what its test reads, in stages; it must answer as the full measures do
    rng = np.random.default_rng(4)
    geometry = DeltaGeometry(0.25, 0.06, 0.42, 1.1)
    points = np.column_stack((rng.uniform(-1, 1, 20000), rng.uniform(-1, 1, 20000), rng.uniform(-1.6, -0.1, 20000)))
    inside = workspace.admissible(geometry, points, criteria)
    assert 0.01 < np.mean(inside) < 0.95
    np.testing.assert_array_equal(inside, workspace.pose_measures(geometry, points).admissible(criteria))
    assert workspace.admissible(geometry, np.zeros((0, 3)), criteria).shape == (0,)
