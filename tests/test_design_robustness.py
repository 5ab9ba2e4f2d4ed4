"""The design study's merged front and convergence (eval.design.front) and its tolerance and sensitivity analysis
(eval.design.robustness)."""

import dataclasses
import math

import numpy as np
import pytest

from delta_env import kinematics
from delta_env.geometry import NOMINAL_GEOMETRY
from eval.design import front, optimize, performance, report, robustness


@pytest.fixture(scope="module")
def nominal() -> performance.Performance:
    return performance.evaluate(NOMINAL_GEOMETRY)


def _dominated(a: np.ndarray, others: np.ndarray) -> bool:
    """Whether some row of ``others`` dominates ``a`` (all objectives minimized)."""
    return bool(np.any(np.all(others <= a, axis=1) & np.any(others < a, axis=1)))


def _archive(objectives: list[list[float]], constraints: list[list[float]], performance: list) -> optimize.Archive:
    return optimize.Archive(
        x=[np.zeros(4) for _ in objectives],
        f=[np.array(f, dtype=float) for f in objectives],
        g=[np.array(g, dtype=float) for g in constraints],
        performance=list(performance),
    )


def test_merging_keeps_only_designs_no_archive_dominates():
    # archive A alone keeps its design 0; archive B's first design dominates it, and B's infeasible second design
    # (better on every objective) must not count
    first = _archive([[-1.0, 5.0, 5.0], [-0.5, 6.0, 6.0]], [[0.0] * 3] * 2, ["a0", "a1"])
    second = _archive([[-1.0, 4.0, 5.0], [-9.0, 0.0, 0.0]], [[0.0] * 3, [0.1, 0.0, 0.0]], ["b0", "b1"])
    assert first.pareto_indices().tolist() == [0]
    merged = optimize.Archive.merged([first, second])
    assert merged.performance == ["a0", "a1", "b0", "b1"]
    assert merged.pareto_indices().tolist() == [2]


def test_merged_front_is_non_dominated_against_every_run(nominal):
    merged = front.search(nominal, population=8, generations=2, seeds=[0, 1])
    assert [(run.optimizer, run.seed) for run in merged.runs] == [("NSGA-II", 0), ("NSGA-II", 1), ("GA", 0)]
    result = merged.result
    assert len(result.archive.x) == sum(len(run.archive.x) for run in merged.runs)
    members = np.array([result.archive.f[i] for i in result.front])
    for run in merged.runs:  # against each run's own evaluations, not just the merged copy
        feasible = np.array([f for f, g in zip(run.archive.f, run.archive.g, strict=True) if np.all(g <= 0.0)])
        for member in members:
            assert not _dominated(member, feasible)
        for f in feasible:  # every feasible design is matched or dominated by a member
            assert np.any(np.all(members <= f, axis=1))
    roles = optimize.design_roles(result, nominal)
    assert set(roles.values()) <= set(result.front.tolist())
    every_cost = [optimize.weighted_cost(p, nominal) for p in result.archive.performance if p.feasible]
    assert optimize.weighted_cost(result.archive.performance[roles["weighted-cost optimum"]], nominal) == min(
        every_cost
    )
    assert {merged.source(i) for i in range(len(result.archive.x))} == {(r.optimizer, r.seed) for r in merged.runs}
    rows = {(row["optimizer"], row["seed"]) for row in result.convergence}
    assert rows == {(r.optimizer, r.seed) for r in merged.runs} and len(result.convergence) == 3 * 2
    with pytest.raises(ValueError, match="distinct"):
        front.search(nominal, population=6, generations=1, seeds=[1, 1])


def _front_of(nominal, relative: list[tuple[float, float, float]]) -> optimize.ParetoResult:
    """A front of designs with the nominal robot's figures scaled by ``relative`` (workspace, torque, picks/min)."""
    designs = [
        dataclasses.replace(
            nominal,
            workspace_m3=w * nominal.workspace_m3,
            peak_torque_nm=t * nominal.peak_torque_nm,
            picks_per_min=p * nominal.picks_per_min,
        )
        for w, t, p in relative
    ]
    archive = _archive([list(optimize.objective_vector(d)) for d in designs], [[0.0] * 3] * len(designs), designs)
    return optimize.ParetoResult(archive=archive, front=np.arange(len(designs)), convergence=[])


def test_design_names_are_true_to_their_figures(nominal):
    # the --quick study's front: less workspace at less torque, more workspace at more torque
    result = _front_of(nominal, [(0.61, 0.984, 0.98), (1.24, 1.14, 0.98), (1.38, 1.195, 0.99)])
    roles = optimize.design_roles(result, nominal)
    assert "large workspace" not in roles and "low torque" not in roles  # -39 % workspace, +14 % torque
    chosen = optimize.choose_designs(roles)
    assert len(set(chosen.values())) == len(chosen)  # no design named twice
    sentence = report.roles_sentence(roles)
    assert "No low torque design" in sentence and "No large workspace design" in sentence
    assert optimize.shared_roles(roles) == {"weighted-cost optimum": "compromise"}
    assert "The compromise design is also the weighted-cost optimum design." in sentence

    # one design with more workspace at less torque fills three roles, named once by the first
    result = _front_of(nominal, [(1.10, 0.95, 1.0), (0.90, 0.80, 1.0), (1.30, 1.20, 1.0)])
    roles = optimize.design_roles(result, nominal)
    assert roles["compromise"] == roles["low torque"] == roles["large workspace"] == 0
    assert optimize.choose_designs(roles)["compromise"] == 0
    assert not {"low torque", "large workspace"} & set(optimize.choose_designs(roles))
    assert "The compromise design is also the large workspace design." in report.roles_sentence(roles)
    for role, index in roles.items():
        w, t = -result.archive.f[index][0], result.archive.f[index][1]
        if role == "low torque":
            assert t < nominal.peak_torque_nm and w >= nominal.workspace_m3
        if role == "large workspace":
            assert w > nominal.workspace_m3 and t <= nominal.peak_torque_nm


def test_convergence_summary_reads_the_last_rise(nominal):
    objectives = list(optimize.objective_vector(nominal))
    archive = _archive([objectives], [[0.0] * 3], [nominal])

    def run(seed: int, values: list[float]) -> front.SearchRun:
        return front.SearchRun(
            "NSGA-II", seed, archive, [{"generation": g, "hypervolume": v} for g, v in enumerate(values)]
        )

    ga = front.SearchRun("GA", 0, archive, [{"generation": 0, "best_cost": 1.0, "mean_cost": 1.0}])
    plateau = run(0, [1.0, 1.5, 1.8, 1.9, 1.95, 1.96, 1.962, 1.963, 1.964, 1.97])  # 10 generations: a window of 2
    flat, rising = run(1, [1.0] * 10), run(2, [1.0] * 8 + [1.01, 1.02])
    merged = front.MergedSearch((plateau, flat, rising, ga), optimize.ParetoResult(archive, np.array([0]), []))
    summaries = front.convergence_summary(merged, nominal)
    assert [s.seed for s in summaries] == [0, 1, 2]
    assert summaries[0].rise == pytest.approx(1.97 / 1.963 - 1.0) and not summaries[0].still_rising
    assert summaries[1].rise == 0.0 and not summaries[1].still_rising
    assert summaries[2].rise == pytest.approx(0.02) and summaries[2].still_rising
    # the nominal design alone, against the reference (no workspace, 2x torque, 2x time): 1 x 1 x 1
    assert summaries[0].front == pytest.approx(1.0)
    assert "still rising (> 0.5 %) in 1 of 3 seeds" in front.convergence_text(merged, nominal)


def _centre_drop(radial: float, l2: float) -> float:
    """Platform depth (m) below the elbows of a symmetric robot at the centre: sqrt(l2^2 - radial^2)."""
    return math.sqrt(l2**2 - radial**2)


def test_built_robot_without_errors_is_the_drawn_one():
    theta = np.random.default_rng(3).uniform(-0.3, 1.2, size=(40, 3))
    built = robustness.built_positions(NOMINAL_GEOMETRY, np.zeros((2, 4, 3)), theta)
    np.testing.assert_allclose(
        built, np.broadcast_to(kinematics.forward(NOMINAL_GEOMETRY, theta), built.shape), atol=1e-12
    )
    with pytest.raises(ValueError, match="no common point"):
        robustness.sphere_intersection(np.array([[0.0, 0, 0], [3, 0, 0], [0, 3, 0]]), np.ones(3))


@pytest.mark.parametrize("delta", [1e-4, -2e-3])
def test_equal_radius_and_length_errors_move_the_centre_point_as_the_geometry_says(delta):
    g = NOMINAL_GEOMETRY
    centre = np.array([[0.0, 0.0, -0.9]])
    theta = float(kinematics.inverse(g, centre)[0, 0])
    radial, drop = g.r + g.l1 * math.cos(theta), _centre_drop(g.r + g.l1 * math.cos(theta), g.l2)
    cases = {
        "ra": drop - _centre_drop(radial + delta, g.l2),  # elbows out: the forearms pull the platform up
        "rb": drop - _centre_drop(radial - delta, g.l2),  # the same as ra - delta
        "l2": drop - _centre_drop(radial, g.l2 + delta),  # longer forearms: lower
    }
    for name, rise in cases.items():
        errors = np.zeros((1, 4, 3))
        errors[0, robustness.LENGTH_NAMES.index(name), :] = delta
        shift = robustness.built_positions(g, errors, kinematics.inverse(g, centre))[0, 0] - centre[0]
        np.testing.assert_allclose(shift, [0.0, 0.0, rise], atol=1e-12, err_msg=name)
        assert robustness.position_errors(g, centre, errors)[0, 0] == pytest.approx(abs(rise), rel=1e-9)
    # chain 1's base radius alone (azimuth 0) moves the centre point in the x-z plane, away from chain 1
    errors = np.zeros((1, 4, 3))
    errors[0, 0, 0] = abs(delta)
    shift = robustness.built_positions(g, errors, kinematics.inverse(g, centre))[0, 0] - centre[0]
    assert abs(shift[1]) < 1e-12 and shift[0] > 0.0 and shift[2] > 0.0


def test_position_error_vanishes_without_tolerance_and_scales_with_it(nominal):
    points = robustness.cylinder_points(nominal.cylinder)
    assert len(points) == 3 * (1 + 4 * 12)
    assert np.max(np.hypot(points[:, 0], points[:, 1])) == pytest.approx(nominal.cylinder.diameter / 2)
    assert points[:, 2].min() == pytest.approx(nominal.cylinder.bottom) and points[:, 2].max() == nominal.cylinder.top
    unit = robustness.length_errors(1e-4, 50, np.random.default_rng(1))
    assert np.all(np.abs(unit) <= 1e-4) and np.std(unit) == pytest.approx(1e-4 / math.sqrt(3), rel=0.1)
    once = robustness.position_errors(nominal.geometry, points, unit)
    assert np.all(robustness.position_errors(nominal.geometry, points, 0.0 * unit) < 1e-12)  # round-off
    # a 0.1 mm band gives errors of its order; twice the errors, twice the position errors (to first order)
    assert 2e-5 < np.sqrt(np.mean(once**2)) < 1e-3
    np.testing.assert_allclose(robustness.position_errors(nominal.geometry, points, 2.0 * unit), 2.0 * once, rtol=1e-2)


def test_mass_sensitivity_is_monotone_and_linear_in_the_masses(nominal):
    assert robustness.with_masses(nominal, (1.0, 1.0, 1.0)).peak_torque_nm == nominal.peak_torque_nm
    torque, speed = nominal.peak_torque_nm, robustness.speed_figure(nominal)
    for k in range(3):
        up = robustness.with_masses(nominal, 1.0 + 0.1 * (np.arange(3) == k))
        half = robustness.with_masses(nominal, 1.0 + 0.05 * (np.arange(3) == k))
        down = robustness.with_masses(nominal, 1.0 - 0.1 * (np.arange(3) == k))
        assert down.peak_torque_nm < torque < up.peak_torque_nm, k
        # picks/min fall with mass, in steps of the cycle's 1 ms samples (0.26 % at 155/min): +-10 % of one
        # mass may not move them, +30 % must
        assert robustness.speed_figure(up) <= speed <= robustness.speed_figure(down), k
        assert robustness.speed_figure(robustness.with_masses(nominal, 1.0 + 0.3 * (np.arange(3) == k))) < speed, k
        # inverse dynamics is linear in the masses: at a fixed peak sample, the change doubles with the step
        assert up.peak_torque_nm - torque == pytest.approx(2.0 * (half.peak_torque_nm - torque), rel=0.02), k
        assert 0.001 < up.peak_torque_nm / torque - 1.0 < 0.1, k  # a share of the torque, never more than 10 %


def test_analysis_spreads_follow_the_tolerances(nominal):
    fixed = robustness.analyse(nominal, length_tolerance=0.0, mass_tolerance=0.0, length_samples=5, mass_samples=2)
    assert fixed.rms_error.high < 1e-12 and fixed.max_error.high < 1e-12
    assert fixed.peak_torque.std == 0.0 and fixed.peak_torque.mean == pytest.approx(nominal.peak_torque_nm)
    assert fixed.speed.mean == pytest.approx(robustness.speed_figure(nominal))
    result = robustness.analyse(nominal, seed=2, length_samples=200, mass_samples=6)
    for spread in (result.rms_error, result.max_error, result.peak_torque, result.speed):
        assert spread.low <= spread.p5 <= spread.mean <= spread.p95 <= spread.high
    assert 0.0 < result.rms_error.mean < result.max_error.mean
    assert (
        result.peak_torque.low > 0.85 * nominal.peak_torque_nm
        and result.peak_torque.high < 1.15 * nominal.peak_torque_nm
    )
    assert set(result.torque_change) == {"m1", "m2", "m0"} and all(v > 0 for v in result.torque_change.values())
    rows = robustness.rows({"nominal": result})
    assert [row["figure"] for row in rows] == [label for _, label, _, _ in robustness.FIGURES]
    assert rows[0]["mean"] == pytest.approx(1e3 * result.rms_error.mean)  # mm
    with pytest.raises(ValueError, match="length_tolerance"):
        robustness.analyse(nominal, length_tolerance=-1e-4)
    with pytest.raises(ValueError, match="mass_samples"):
        robustness.analyse(nominal, mass_samples=0)
