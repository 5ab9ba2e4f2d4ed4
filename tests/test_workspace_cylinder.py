"""The data-sheet workspace (delta_env.cylinder): disc radii, the axis stretch and the cylinder search."""

import math

import numpy as np
import pytest

from delta_env import cylinder, workspace
from delta_env.cycles import STANDARD_LIFT
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry
from delta_env.trajectories import WORKING_HEIGHT
from eval.design import optimize


def _fine_exits(geometry: DeltaGeometry, z: float, phi: np.ndarray, coarse: float, fine: float) -> np.ndarray:
    """First exit radius (m) of rays at azimuths ``phi`` at height ``z``: a linear scan every ``coarse`` m,
    then every ``fine`` m inside the first failing step; the last admissible radius."""
    reach = workspace.reach_bounds(geometry)[0]
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]

    def inside(r: np.ndarray) -> np.ndarray:
        return workspace.admissible(geometry, np.stack(np.broadcast_arrays(c * r, s * r, z), axis=-1))

    radii = np.arange(coarse, reach + 2 * coarse, coarse)[None]
    first = np.argmin(inside(radii), axis=1)  # the last radius lies beyond the reach: always a failure
    start = np.where(first > 0, radii[0, np.maximum(first - 1, 0)], 0.0)
    steps = start[:, None] + np.arange(1, round(coarse / fine) + 1) * fine
    ok = inside(steps)
    ok[:, -1] = False
    last = np.argmin(ok, axis=1) - 1
    return np.where(last >= 0, steps[np.arange(len(phi)), np.maximum(last, 0)], start)


def _brute_force_volume(geometry: DeltaGeometry, required_top: float = cylinder.REQUIRED_TOP) -> float:
    """The data-sheet volume (m^3) by exhaustion: every 1 mm of height from the belt up the dexterous axis,
    rays every 2 deg scanned every 10 mm then 0.25 mm, and every top of that grid over the belt."""
    axis = np.arange(WORKING_HEIGHT, workspace.reach_bounds(geometry)[2], 0.001)
    on_axis = workspace.admissible(geometry, np.column_stack((np.zeros((axis.size, 2)), axis)))
    if not on_axis[0]:
        return 0.0
    heights = axis[: axis.size if on_axis.all() else int(np.argmin(on_axis))]
    phi = np.radians(np.arange(0.0, 60.0 + 1e-9, 2.0))
    radii = np.array([_fine_exits(geometry, z, phi, 0.01, 0.00025).min() for z in heights])
    volume = math.pi * np.minimum.accumulate(radii) ** 2 * (heights - heights[0])  # standing on the belt
    volume[heights < required_top - 1e-9] = 0.0
    return float(volume.max(initial=0.0))


def _random_geometries(count: int, seed: int) -> list[DeltaGeometry]:
    """Geometries drawn uniformly within the optimizer's bounds that have a data-sheet cylinder."""
    rng = np.random.default_rng(seed)
    bounds = optimize.DEFAULT_BOUNDS
    found = []
    while len(found) < count:
        geometry = optimize.geometry_of(rng.uniform(bounds.lower, bounds.upper))
        if cylinder.data_sheet_cylinder(geometry) is not None:
            found.append(geometry)
    return found


def test_disc_radius_is_the_first_exit_over_the_whole_disc():
    # at z = -0.675 the nominal admissible set is not star-shaped: some rays leave it and enter it again
    phi = np.radians(np.arange(0.0, 60.0 + 1e-9, 0.5))
    heights = [-0.9, -0.8, -0.75, -0.675]
    exits = [_fine_exits(NOMINAL_GEOMETRY, z, phi, 0.002, 0.0001) for z in heights]
    radii = cylinder.disc_radii(NOMINAL_GEOMETRY, heights)
    for z, ray_exits, radius in zip(heights, exits, radii, strict=True):
        assert radius == pytest.approx(ray_exits.min(), abs=5e-4), z
    # a re-entry exists at -0.675 beyond the first exit, so a rim-only bisection would overstate the disc
    r = np.linspace(radii[-1] + 0.005, 0.6, 300)
    points = np.stack(np.broadcast_arrays(np.cos(phi)[:, None] * r, np.sin(phi)[:, None] * r, -0.675), axis=-1)
    assert np.any(workspace.admissible(NOMINAL_GEOMETRY, points))
    assert cylinder.disc_radii(NOMINAL_GEOMETRY, [-2.0])[0] == -math.inf  # beyond the reach


def test_the_admissible_set_has_the_symmetry_the_sector_assumes():
    rng = np.random.default_rng(11)
    points = np.column_stack((rng.uniform(-0.7, 0.7, (20000, 2)), rng.uniform(-1.1, -0.6, 20000)))
    inside = workspace.admissible(NOMINAL_GEOMETRY, points)
    assert 0.2 < inside.mean() < 0.8
    turn = 2.0 * math.pi / 3.0
    rotation = np.array([[math.cos(turn), -math.sin(turn), 0.0], [math.sin(turn), math.cos(turn), 0.0], [0, 0, 1]])
    for image in (points @ rotation.T, points * np.array([1.0, -1.0, 1.0])):
        assert np.mean(workspace.admissible(NOMINAL_GEOMETRY, image) != inside) < 1e-3  # boundary round-off only


def test_axis_stretch_matches_the_symmetric_pose_formula():
    # on the axis all arms share theta and z(theta) = -l1 sin th - sqrt(l2^2 - (r + l1 cos th)^2)
    geometry = NOMINAL_GEOMETRY
    low, high = 0.0, 1.0
    criteria = workspace.Criteria(theta_range=(low, high), max_forearm_tilt=math.pi / 2, min_conditioning=0.0)

    def z_of(theta: float) -> float:
        elbow = geometry.r + geometry.l1 * math.cos(theta)
        return -geometry.l1 * math.sin(theta) - math.sqrt(geometry.l2**2 - elbow**2)

    middle = (z_of(high) + z_of(low)) / 2
    assert cylinder.axis_stretch(geometry, middle, criteria) == pytest.approx((z_of(high), z_of(low)), abs=2e-4)
    assert cylinder.axis_stretch(geometry, middle, criteria, floor=middle - 0.01) == pytest.approx(
        (middle - 0.01, z_of(low)), abs=2e-4
    )
    assert cylinder.axis_stretch(geometry, z_of(high) - 0.01, criteria) is None


def test_data_sheet_cylinder_agrees_with_an_exhaustive_search():
    for geometry in [NOMINAL_GEOMETRY, *_random_geometries(3, seed=21)]:
        found = cylinder.data_sheet_cylinder(geometry)
        assert found.volume == pytest.approx(_brute_force_volume(geometry), rel=0.01), geometry


def test_data_sheet_cylinder_stands_above_the_belt_and_is_admissible():
    for geometry in [NOMINAL_GEOMETRY, *_random_geometries(2, seed=5)]:
        found = cylinder.data_sheet_cylinder(geometry)
        assert found.bottom >= WORKING_HEIGHT - 1e-12
        assert found.top >= WORKING_HEIGHT + STANDARD_LIFT + cylinder.PRODUCT_CLEARANCE - 1e-12
        rng = np.random.default_rng(8)
        count = 20000
        radius = (found.diameter / 2 - 1e-3) * np.sqrt(rng.random(count))
        phi = rng.uniform(0.0, 2 * math.pi, count)
        z = rng.uniform(found.bottom, found.top, count)
        points = np.column_stack((radius * np.cos(phi), radius * np.sin(phi), z))
        assert np.all(workspace.admissible(geometry, points)), geometry


def test_nominal_data_sheet_cylinder():
    found = cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY)
    # the exhaustive search (above) gives 0.1119 m^3: the 0.475 m disc up to -0.741 m, above which the disc
    # shrinks fast
    assert found.diameter == pytest.approx(0.95, abs=0.005)
    assert found.height == pytest.approx(0.159, abs=0.003)
    assert found.bottom == pytest.approx(WORKING_HEIGHT, abs=1e-9)
    assert found.volume == pytest.approx(0.1119, rel=0.01)
    # more clearance: a taller, narrower cylinder whose top is the requirement
    tall = cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, clearance=0.2)
    assert tall.top == pytest.approx(WORKING_HEIGHT + STANDARD_LIFT + 0.2, abs=1e-9)
    assert tall.diameter < found.diameter and tall.volume < found.volume
    # a belt below the axis stretch: no cylinder
    assert cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, belt=-2.0) is None
    assert cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, clearance=0.5) is None


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, clearance=-0.01), "clearance"),
        (lambda: cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, lift=math.nan), "lift"),
        (lambda: cylinder.data_sheet_cylinder(NOMINAL_GEOMETRY, belt=math.inf), "belt"),
        (lambda: cylinder.disc_radii(NOMINAL_GEOMETRY, [-0.9, math.nan]), "heights"),
        (lambda: cylinder.axis_stretch(NOMINAL_GEOMETRY, math.nan), "through"),
        (lambda: cylinder.axis_stretch(NOMINAL_GEOMETRY, -0.9, floor=math.nan), "floor"),
    ],
)
def test_bad_arguments_are_named(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_a_height_independent_limit_does_not_multiply_the_heights(monkeypatch):
    # Forearms of 0.959 m: the parallelogram skew limit (a vertical prism, |y in the chain's frame| <= l2 sin 30 deg)
    # sets the same disc radius at every height near the belt. Those ties are no dip to refine: the search must look
    # at tens of heights, as on any geometry, not double its grid every round (it evaluated 433 heights before).
    geometry = DeltaGeometry(0.2813, 0.0588, 0.3910, 0.9594)
    plateau = cylinder.disc_radii(geometry, np.linspace(-0.9, -0.76, 8))
    np.testing.assert_allclose(plateau, geometry.l2 * math.sin(workspace.MAX_PARALLELOGRAM_SKEW), rtol=1e-3)
    measured = []
    disc_radii = cylinder.disc_radii

    def counted(geometry, heights, criteria=workspace.DEXTEROUS):
        measured.append(np.size(heights))
        return disc_radii(geometry, heights, criteria)

    monkeypatch.setattr(cylinder, "disc_radii", counted)
    found = cylinder.data_sheet_cylinder(geometry)
    assert sum(measured) < 80
    assert found.volume == pytest.approx(_brute_force_volume(geometry), rel=0.01)


def test_surface_points_lie_on_the_cylinder():
    found = cylinder.Cylinder(diameter=0.8, height=0.2, top=-0.7)
    points = found.surface_points(azimuths=12, levels=3)
    radius, z = np.hypot(points[:, 0], points[:, 1]), points[:, 2]
    on_rim = np.isclose(radius, 0.4)
    on_face = np.isclose(z, -0.9) | np.isclose(z, -0.7)
    assert np.all(on_rim | on_face) and np.all((radius <= 0.4 + 1e-12) & (z >= -0.9 - 1e-12) & (z <= -0.7 + 1e-12))
    assert points.shape == (12 * (3 + 4) + 2, 3) and np.count_nonzero(on_rim) == 36
    with pytest.raises(ValueError, match="levels"):
        found.surface_points(levels=1)
