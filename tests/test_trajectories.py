"""C2 reference trajectories: continuity, timing, cycle geometry and start, events, workspace, determinism."""

from __future__ import annotations

import dataclasses
import functools
import math
import re

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.interpolate import BPoly

from delta_env import NOMINAL_GEOMETRY, cycles, excitation, kinematics
from delta_env import limits as workspace_limits
from delta_env import trajectories as tr
from delta_env.geometry import GRAVITY

G = NOMINAL_GEOMETRY
EXCITATION_SECONDS = 4.0


@functools.cache
def build(
    kind: str,
    peak_acceleration: float = tr.STANDARD_PEAK_ACCELERATION,
    dt: float = 1e-3,
    seed: int = 0,
    start: str = "place",
):
    """One trajectory of each kind, cached: the tests only read them."""
    rng = np.random.default_rng(seed)
    if kind == "standard":
        return cycles.standard_cycle(G, peak_acceleration, n_cycles=2, dt=dt, start=start)
    if kind == "conveyor":
        return cycles.conveyor_cycles(G, rng, 3, peak_acceleration, dt=dt, start=start)
    if kind == "excitation":
        return excitation.excitation_trajectory(G, rng, EXCITATION_SECONDS, peak_acceleration, dt=dt)
    raise AssertionError(kind)


@functools.cache
def long_excitation() -> tr.Trajectory:
    return excitation.excitation_trajectory(G, np.random.default_rng(3), 20.0)


ALL_KINDS = [
    ("standard", tr.STANDARD_PEAK_ACCELERATION),
    ("standard", tr.STRESS_PEAK_ACCELERATION),
    ("conveyor", tr.STANDARD_PEAK_ACCELERATION),
    ("conveyor", tr.STRESS_PEAK_ACCELERATION),
    ("excitation", tr.STRESS_PEAK_ACCELERATION),
]
CYCLE_KINDS = [case for case in ALL_KINDS if case[0] != "excitation"]
STARTS = ("place", "pick")
DWELL = 0.1  # the cycles' default rest at each station (s)


def moves(trajectory: tr.Trajectory) -> list[slice]:
    """Runs of samples between rests (where the reference velocity is exactly zero)."""
    moving = np.any(trajectory.xyz_dot != 0.0, axis=1).astype(int)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], moving, [0]))))
    return [slice(start, stop) for start, stop in zip(edges[::2], edges[1::2], strict=True)]


def check_derivatives(value: np.ndarray, first: np.ndarray, second: np.ndarray, dt: float) -> None:
    """Central differences of ``value`` and ``first`` match ``first`` and ``second``.

    A central difference errs by at most dt^2 / 6 max|f'''| while f''' stays bounded; for ``first``,
    f''' is the jerk, which jumps where a quintic blend starts, and there the error reaches dt / 2
    times the jump. The jerk bound comes from the steps of ``second``; tolerances carry a factor 2.
    """
    jerk = np.max(np.abs(np.diff(second, axis=0))) / dt
    central_first = (value[2:] - value[:-2]) / (2.0 * dt)
    assert_allclose(central_first, first[1:-1], rtol=0, atol=dt**2 * jerk / 3.0)
    central_second = (first[2:] - first[:-2]) / (2.0 * dt)
    assert_allclose(central_second, second[1:-1], rtol=0, atol=dt * jerk)
    # away from the jerk jumps the difference is second-order accurate: most samples are far closer
    error = np.max(np.abs(central_second - second[1:-1]), axis=1)
    assert np.quantile(error, 0.95) < 0.05 * dt * jerk


@pytest.mark.parametrize(("kind", "peak"), ALL_KINDS)
def test_cartesian_derivatives_match_finite_differences(kind: str, peak: float) -> None:
    trajectory = build(kind, peak)
    check_derivatives(trajectory.xyz, trajectory.xyz_dot, trajectory.xyz_ddot, trajectory.dt)


@pytest.mark.parametrize(("kind", "peak"), ALL_KINDS)
def test_joint_derivatives_match_finite_differences(kind: str, peak: float) -> None:
    trajectory = build(kind, peak)
    check_derivatives(trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot, trajectory.dt)


@pytest.mark.parametrize("kind", ["standard", "conveyor", "excitation"])
def test_acceleration_is_continuous(kind: str) -> None:
    # C2: the largest acceleration step between samples shrinks in proportion to dt; a jump in
    # acceleration (a C1 path) would not shrink at all.
    steps = [
        np.max(np.linalg.norm(np.diff(build(kind, tr.STRESS_PEAK_ACCELERATION, dt).xyz_ddot, axis=0), axis=1))
        for dt in (1e-3, 1e-4)
    ]
    assert steps[1] < 0.12 * steps[0]
    assert steps[0] < 0.2 * tr.STRESS_PEAK_ACCELERATION


@pytest.mark.parametrize(("kind", "peak"), ALL_KINDS)
def test_joint_references_are_exact_kinematics(kind: str, peak: float) -> None:
    trajectory = build(kind, peak)
    xyz, xyz_dot, xyz_ddot = kinematics.joint_to_cartesian(
        G, trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot
    )
    assert_allclose(xyz, trajectory.xyz, rtol=0, atol=1e-10)
    assert_allclose(xyz_dot, trajectory.xyz_dot, rtol=0, atol=1e-9)
    assert_allclose(xyz_ddot, trajectory.xyz_ddot, rtol=0, atol=1e-7)


@pytest.mark.parametrize("start", STARTS)
@pytest.mark.parametrize(("kind", "peak"), CYCLE_KINDS)
def test_every_move_reaches_the_requested_peak_acceleration(kind: str, peak: float, start: str) -> None:
    trajectory = build(kind, peak, start=start)
    acceleration = np.linalg.norm(trajectory.xyz_ddot, axis=1)
    peaks = np.array([np.max(acceleration[move]) for move in moves(trajectory)])
    n_cycles = len(trajectory.pick_indices)
    # there and back per cycle, and from a place point the empty move to the first pick
    assert len(peaks) == 2 * n_cycles + (start == "place")
    assert_allclose(peaks, peak, rtol=1e-2)


def test_excitation_accelerations_are_large_varied_and_bounded() -> None:
    trajectory = long_excitation()
    acceleration = np.linalg.norm(trajectory.xyz_ddot, axis=1)
    peaks = np.array([np.max(acceleration[move]) for move in moves(trajectory)])
    assert np.max(peaks) <= tr.STRESS_PEAK_ACCELERATION * (1.0 + 1e-6)
    assert np.max(peaks) > 0.9 * tr.STRESS_PEAK_ACCELERATION
    # slow moves, timed by speed, accelerate far less than any fast one
    assert np.min(peaks) < 0.05 * GRAVITY


def test_excitation_includes_slow_and_fast_moves() -> None:
    trajectory = long_excitation()
    speed = np.linalg.norm(trajectory.xyz_dot, axis=1)
    top_speeds = np.array([np.max(speed[move]) for move in moves(trajectory)])
    assert np.any(top_speeds <= 0.1)  # slow: friction near zero speed
    assert np.any(top_speeds < 0.02)
    assert np.max(top_speeds) > 3.0  # fast
    assert len(trajectory.pick_indices) == len(trajectory.place_indices) == 0
    assert not np.any(trajectory.gripper)


@pytest.mark.parametrize("start", STARTS)
@pytest.mark.parametrize("peak", [tr.STANDARD_PEAK_ACCELERATION, tr.STRESS_PEAK_ACCELERATION])
@pytest.mark.parametrize(("center", "heading"), [((0.0, 0.0, -0.9), math.pi / 2), ((0.1, -0.05, -0.95), 0.4)])
def test_standard_cycle_is_25_305_25_mm(peak: float, center: tuple, heading: float, start: str) -> None:
    trajectory = cycles.standard_cycle(G, peak, center=center, heading=heading, start=start)
    pick, place = trajectory.xyz[trajectory.pick_indices[0]], trajectory.xyz[trajectory.place_indices[0]]
    assert_allclose(place - pick, 0.305 * np.array([math.cos(heading), math.sin(heading), 0.0]), atol=1e-12)
    assert_allclose((pick + place) / 2.0, center, atol=1e-12)
    first = place if start == "place" else pick
    assert_allclose(trajectory.xyz[[0, -1]], [first, pick], atol=1e-12)  # and back to the pick point
    lift = trajectory.xyz[:, 2] - center[2]
    assert_allclose([np.min(lift), np.max(lift)], [0.0, 0.025], atol=1e-9)
    # the arch stays in the vertical plane through pick and place
    offset = trajectory.xyz[:, :2] - pick[:2]
    normal = np.array([-math.sin(heading), math.cos(heading)])
    assert_allclose(offset @ normal, 0.0, atol=1e-12)


def test_arch_leaves_the_conveyor_steeper_than_45_degrees() -> None:
    # the vertical blend leads the horizontal one, so a picked object is lifted, not dragged
    trajectory = build("standard")
    for move in moves(trajectory):
        xyz = trajectory.xyz[move]
        for station in (0, -1):
            travel = np.linalg.norm(xyz[:, :2] - xyz[station, :2], axis=1)
            lift = xyz[:, 2] - xyz[station, 2]
            near = travel < 0.01
            assert np.all(lift[near] >= travel[near])


@pytest.mark.parametrize("start", STARTS)
@pytest.mark.parametrize(("kind", "peak"), CYCLE_KINDS)
def test_pick_and_place_events_are_at_rest_at_the_stations(kind: str, peak: float, start: str) -> None:
    trajectory = build(kind, peak, start=start)
    picks, places = trajectory.pick_indices, trajectory.place_indices
    n_cycles = 2 if kind == "standard" else 3
    assert len(picks) == len(places) == n_cycles
    assert np.all(picks < places) and np.all(places[:-1] < picks[1:])
    events = np.concatenate((picks, places))
    assert_array_equal(trajectory.xyz_dot[events], 0.0)
    assert_array_equal(trajectory.xyz_ddot[events], 0.0)
    assert_array_equal(trajectory.theta_dot[events], 0.0)
    # at rest on either side too: the controller sees the robot still before and after each event
    assert_array_equal(trajectory.xyz_dot[events - 1], 0.0)
    assert_array_equal(trajectory.xyz_dot[events + 1], 0.0)
    assert_allclose(trajectory.xyz[events, 2], tr.WORKING_HEIGHT, atol=1e-12)
    expected = np.zeros(len(trajectory), dtype=bool)
    for pick, place in zip(picks, places, strict=True):
        expected[pick:place] = True
    assert_array_equal(trajectory.gripper, expected)


def test_conveyor_events_lie_on_their_zones() -> None:
    trajectory = cycles.conveyor_cycles(G, np.random.default_rng(5), 20)
    for zone, indices in ((cycles.PICK_ZONE, trajectory.pick_indices), (cycles.PLACE_ZONE, trajectory.place_indices)):
        points = trajectory.xyz[indices]
        assert np.all((points[:, 0] >= zone.x_range[0]) & (points[:, 0] <= zone.x_range[1]))
        assert np.all((points[:, 1] >= zone.y_range[0]) & (points[:, 1] <= zone.y_range[1]))
        assert_allclose(points[:, 2], zone.z, atol=1e-12)
        assert len(np.unique(points, axis=0)) == len(points)  # a new object each cycle
    assert np.max(trajectory.xyz[:, 2]) == pytest.approx(tr.WORKING_HEIGHT + 0.025, abs=1e-9)
    # documented draws: n_cycles + 1 pick points first; it ends at rest on the last, unpicked one
    picks = cycles.PICK_ZONE.sample(np.random.default_rng(5), 21)
    assert_allclose(trajectory.xyz[trajectory.pick_indices], picks[:-1], atol=1e-12)
    assert_allclose(trajectory.xyz[-1], picks[-1], atol=1e-12)
    assert_array_equal(trajectory.xyz_dot[-1], 0.0)


@pytest.mark.parametrize(("kind", "peak"), CYCLE_KINDS)
def test_place_start_rests_half_a_dwell_open_then_moves_empty_to_the_first_pick(kind: str, peak: float) -> None:
    trajectory = build(kind, peak)
    for name in ("xyz_dot", "xyz_ddot", "theta_dot", "theta_ddot"):
        assert_array_equal(getattr(trajectory, name)[0], 0.0)
    origin = trajectory.xyz[0]
    zone = cycles.PLACE_ZONE
    assert zone.x_range[0] <= origin[0] <= zone.x_range[1] and zone.y_range[0] <= origin[1] <= zone.y_range[1]
    assert origin[2] == pytest.approx(zone.z, abs=1e-12)
    if kind == "standard":
        assert_array_equal(origin, trajectory.xyz[trajectory.place_indices[0]])
    # at rest for the second half of the dwell in which the previous object was released
    half_dwell = round(0.5 * DWELL / trajectory.dt)  # samples
    first_move = moves(trajectory)[0]
    assert first_move.start - half_dwell in (0, 1)  # the sample at 0.5 dwell is the move's start, at rest
    assert_array_equal(trajectory.xyz[: first_move.start], np.tile(origin, (first_move.start, 1)))
    # then one move, with the gripper open, to pick point 0, where it closes after half a dwell at rest
    first_pick = trajectory.pick_indices[0]
    assert not np.any(trajectory.gripper[:first_pick]) and trajectory.gripper[first_pick]
    assert first_move.stop < first_pick < moves(trajectory)[1].start
    assert_array_equal(trajectory.xyz[first_move.stop], trajectory.xyz[first_pick])
    assert abs(first_pick - first_move.stop - half_dwell) <= 1
    assert np.max(trajectory.xyz[first_move, 2]) == pytest.approx(zone.z + cycles.STANDARD_LIFT, abs=1e-9)


@pytest.mark.parametrize("start", STARTS)
@pytest.mark.parametrize("kind", ["standard", "conveyor"])
def test_from_a_place_start_every_carry_follows_an_empty_move(kind: str, start: str) -> None:
    trajectory = build(kind, start=start)
    loaded = []
    for move in moves(trajectory):
        held = trajectory.gripper[move]
        assert np.all(held) or not np.any(held)  # the gripper never switches while the platform moves
        loaded.append(bool(held[0]))
    # carry to place k, empty back to pick k + 1; from a place point an empty move comes first
    expected = [True, False] * len(trajectory.pick_indices)
    assert loaded == ([False] if start == "place" else []) + expected


@pytest.mark.parametrize("seed", [0, 7])
def test_both_starts_share_the_cycle_points_and_only_the_place_start_draws_one_more(seed: int) -> None:
    place, pick = (build("conveyor", seed=seed, start=start) for start in STARTS)
    for name in ("pick_indices", "place_indices"):
        assert_array_equal(place.xyz[getattr(place, name)], pick.xyz[getattr(pick, name)])
    assert_array_equal(place.xyz[-1], pick.xyz[-1])
    # documented draws: n_cycles + 1 pick points, n_cycles place points, then the starting place point
    rng = np.random.default_rng(seed)
    picks, places = cycles.PICK_ZONE.sample(rng, 4), cycles.PLACE_ZONE.sample(rng, 3)
    assert_allclose(pick.xyz[[*pick.pick_indices, -1]], picks, rtol=0, atol=1e-12)
    assert_allclose(pick.xyz[pick.place_indices], places, rtol=0, atol=1e-12)
    assert_allclose(pick.xyz[0], picks[0], rtol=0, atol=1e-12)
    assert_allclose(place.xyz[0], cycles.PLACE_ZONE.sample(rng, 1)[0], rtol=0, atol=1e-12)
    # the pick start draws nothing else: an episode's later draws (plant, noise) are those of earlier runs
    for start, extra in (("pick", 0), ("place", 1)):
        used, expected = np.random.default_rng(seed), np.random.default_rng(seed)
        cycles.conveyor_cycles(G, used, 3, start=start)
        cycles.PICK_ZONE.sample(expected, 4), cycles.PLACE_ZONE.sample(expected, 3 + extra)
        assert used.random() == expected.random(), start


@pytest.mark.parametrize("kind", ["standard", "conveyor"])
def test_pick_start_is_the_place_start_from_its_first_pick_on(kind: str) -> None:
    peak = tr.STRESS_PEAK_ACCELERATION
    place, pick = (build(kind, peak, start=start) for start in STARTS)
    dt = pick.dt
    # the place start adds half a dwell at rest and the empty move, timed like every other move
    approach = tr.Segment(place.xyz[0], place.xyz[place.pick_indices[0]], 1.0, cycles.STANDARD_LIFT, 0.3)
    offset = 0.5 * DWELL + approach.timed(peak).duration
    assert place.duration == pytest.approx(pick.duration + offset, abs=dt)
    for name in ("pick_indices", "place_indices"):  # each event time is rounded to a sample
        assert_allclose(getattr(place, name) * dt - offset, getattr(pick, name) * dt, rtol=0, atol=dt + 1e-12)
    # The offset is not a whole number of samples: read the pick start between its samples with
    # quintic Hermite pieces through its values and first two derivatives. They reproduce a quintic
    # blend exactly and err by about dt^3 times a jerk step where a blend starts or ends.
    later = (place.time >= offset) & (place.time - offset <= pick.duration)
    assert np.count_nonzero(later) == pytest.approx(len(pick), abs=1)
    times = place.time[later] - offset
    for names, tolerance in ((("xyz", "xyz_dot", "xyz_ddot"), 1e-7), (("theta", "theta_dot", "theta_ddot"), 2e-7)):
        for axis in range(3):
            derivatives = np.stack([getattr(pick, name)[:, axis] for name in names], axis=1)
            between = BPoly.from_derivatives(pick.time, derivatives)(times)
            assert_allclose(between, getattr(place, names[0])[later, axis], rtol=0, atol=tolerance)


@pytest.mark.parametrize("start", ["home", "Place", None])
def test_a_bad_start_is_an_error_naming_it(start: object) -> None:
    message = re.escape(f"start must be 'place' or 'pick', got {start!r}")
    with pytest.raises(ValueError, match=message):
        cycles.standard_cycle(G, start=start)
    with pytest.raises(ValueError, match=message):
        cycles.conveyor_cycles(G, np.random.default_rng(0), 1, start=start)


@pytest.mark.parametrize(("kind", "peak"), ALL_KINDS)
def test_all_samples_keep_singularity_margins(kind: str, peak: float) -> None:
    trajectory = build(kind, peak)
    limits = workspace_limits.WORKSPACE_LIMITS
    measures = kinematics.singularity_measures(G, trajectory.theta)
    assert np.min(measures.min_abs_k) >= limits.min_abs_k
    assert np.min(np.abs(measures.det_a)) >= limits.min_abs_det_a
    assert np.max(measures.jacobian_condition) < 10.0
    assert np.all(workspace_limits.admissible(G, trajectory.xyz))


def test_admissible_is_the_limits_written_with_the_kinematics_module() -> None:
    # The compiled test against its definition in NumPy: the cylinder, then every chain reachable with |k_i| and
    # |det A| (kinematics.constraint_terms) above their margins. Points fill the workspace's box and beyond, with
    # unreachable ones; both answers occur often.
    limits = workspace_limits.WORKSPACE_LIMITS
    rng = np.random.default_rng(11)
    points = rng.uniform((-0.8, -0.8, -1.5), (0.8, 0.8, -0.3), (60_000, 3))
    inside = (np.hypot(points[:, 0], points[:, 1]) <= limits.radius) & (points[:, 2] >= limits.z_min)
    inside &= points[:, 2] <= limits.z_max
    theta = kinematics.elbow_out_angles(G, points)
    reachable = np.all(np.isfinite(theta), axis=-1)
    a, k = kinematics.constraint_terms(G, points[reachable], theta[reachable])
    inside[reachable] &= (np.min(np.abs(k), axis=-1) >= limits.min_abs_k) & (
        np.abs(np.linalg.det(a)) >= limits.min_abs_det_a
    )
    expected = inside & reachable
    assert 0.1 < expected.mean() < 0.9
    assert_array_equal(workspace_limits.admissible(G, points), expected)
    assert workspace_limits.admissible(G, points.reshape(200, 300, 3)).shape == (200, 300)


def test_excitation_covers_the_workspace_up_to_its_edges() -> None:
    limits = workspace_limits.WORKSPACE_LIMITS
    trajectory = long_excitation()
    measures = kinematics.singularity_measures(G, trajectory.theta)
    radius = np.hypot(trajectory.xyz[:, 0], trajectory.xyz[:, 1])
    assert np.max(radius) > 0.99 * limits.radius
    assert np.min(measures.min_abs_k) < 1.05 * limits.min_abs_k or np.min(np.abs(measures.det_a)) < (
        1.05 * limits.min_abs_det_a
    )
    assert np.ptp(trajectory.xyz[:, 2]) > 0.6 * (limits.z_max - limits.z_min)
    for axis in (0, 1):
        assert np.min(trajectory.xyz[:, axis]) < -0.5 and np.max(trajectory.xyz[:, axis]) > 0.5


def test_excitation_lasts_exactly_the_requested_duration_and_ends_at_rest() -> None:
    trajectory = build("excitation", tr.STRESS_PEAK_ACCELERATION)
    assert len(trajectory) == round(EXCITATION_SECONDS / 1e-3) + 1
    assert trajectory.duration == pytest.approx(EXCITATION_SECONDS)
    assert_array_equal(trajectory.xyz_dot[[0, -1]], 0.0)
    assert_allclose(trajectory.xyz[0], (0.0, 0.0, tr.WORKING_HEIGHT))


@pytest.mark.parametrize(
    "peak", [0.0, -1.0, math.nan, 100.0 * GRAVITY, math.nextafter(tr.MAX_PEAK_ACCELERATION, math.inf)]
)
@pytest.mark.parametrize("kind", ["standard", "conveyor", "excitation"])
def test_a_peak_acceleration_beyond_the_limit_is_an_error_naming_the_range(kind: str, peak: float) -> None:
    message = re.escape(f"peak_acceleration must be a finite number in (0, {tr.MAX_PEAK_ACCELERATION:g}] m/s^2")
    with pytest.raises(ValueError, match=message):
        build.__wrapped__(kind, peak)


def test_the_peak_acceleration_limit_admits_every_preset() -> None:
    assert tr.MAX_PEAK_ACCELERATION == 30.0 * GRAVITY
    for peak in (tr.STANDARD_PEAK_ACCELERATION, tr.STRESS_PEAK_ACCELERATION, tr.MAX_PEAK_ACCELERATION):
        assert tr.require_peak_acceleration(peak) == peak
    assert cycles.standard_cycle(G, tr.MAX_PEAK_ACCELERATION, start="pick").duration > 0.0


def test_content_hash_follows_the_samples():
    path = cycles.standard_cycle(G, n_cycles=1)
    assert path.content_hash() == cycles.standard_cycle(G, n_cycles=1).content_hash()
    moved = dataclasses.replace(path, xyz=path.xyz + np.array([0.0, 0.0, 1e-9]))
    assert moved.content_hash() != path.content_hash()
    assert dataclasses.replace(path, dt=2 * path.dt).content_hash() != path.content_hash()
