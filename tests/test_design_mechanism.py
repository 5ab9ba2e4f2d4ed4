"""The pitch-screw reconfiguration linkage (eval.design.mechanism) and the search over its stroke."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import WORKING_HEIGHT
from eval.design import codesign, performance, reconfigure, report
from eval.design.mechanism import MAX_RATIO, MIN_RATIO, PitchScrewLinkage
from eval.design.reconfigure import refine


@pytest.fixture(scope="module")
def hand_case() -> PitchScrewLinkage:
    """Hinge F 0.20 m out, rocker 0.30 m, coupler 0.15 m, screw 0.47 m out, nut from 0.14 m below F; 4 mm lead."""
    return PitchScrewLinkage(
        pivot_radius=0.20,
        rocker_length=0.30,
        coupler_length=0.15,
        screw_radius=0.47,
        nut_start_height=-0.14,
        lead=0.004,
        thread_length=0.08,
        nut_length=0.04,
        branch=-1,
    )


def test_effective_radius_at_a_hand_computed_screw_position(hand_case):
    # 5 turns of a 4 mm lead: the nut rises 0.020 m, from 0.14 to 0.12 m below F. By hand, the motor axis A at
    # 0.18 m out and 0.24 m down from F closes the loop: the rocker 0.18^2 + 0.24^2 = 0.30^2 (a 3-4-5 triangle)
    # and the coupler from A to the nut (0.47 - 0.20, -0.12) = (0.27, -0.12):
    # (0.18 - 0.27)^2 + (-0.24 + 0.12)^2 = 0.0081 + 0.0144 = 0.0225 = 0.15^2 (9-12-15). So a4 = atan2(-0.24, 0.18)
    # = -53.13 deg and the effective base radius is R_f + R_r cos a4 = 0.20 + 0.18 = 0.38 m.
    travel = hand_case.travel(5.0)
    assert travel == pytest.approx(0.020, abs=1e-15)
    assert hand_case.base_radius(travel) == pytest.approx(0.38, abs=1e-12)
    assert hand_case.motor_height(travel) == pytest.approx(-0.24, abs=1e-12)
    assert hand_case.rocker_angle(travel) == pytest.approx(math.atan2(-0.24, 0.18), abs=1e-12)


def test_a_design_sits_at_mid_stroke_with_its_rocker_hanging_down():
    linkage = PitchScrewLinkage.for_design(0.2)
    mid = linkage.stroke / 2.0
    assert linkage.stroke == pytest.approx(0.20) and linkage.turns == pytest.approx(50.0)
    assert linkage.base_radius(mid) == pytest.approx(0.2, abs=1e-12)
    assert linkage.rocker_angle(mid) == pytest.approx(-math.pi / 2, abs=1e-12)
    assert linkage.height_offset(mid) == pytest.approx(0.0, abs=1e-12)
    ends = linkage.base_radius([0.0, linkage.stroke])
    assert ends[0] < 0.2 - 0.05 and ends[1] > 0.2 + 0.1  # the nut rising pulls the motors out, the long way
    assert np.all(linkage.height_offset([0.0, linkage.stroke]) > 0.005)  # the motors rise at both ends


def test_ratio_is_the_derivative_of_the_radius():
    linkage = PitchScrewLinkage.for_design(0.25)
    travel = np.linspace(0.001, linkage.stroke - 0.001, 9)
    h = 1e-6
    numeric = (linkage.base_radius(travel + h) - linkage.base_radius(travel - h)) / (2 * h)
    np.testing.assert_allclose(linkage.ratio(travel), numeric, rtol=1e-6)
    assert np.all((np.abs(numeric) >= MIN_RATIO) & (np.abs(numeric) <= MAX_RATIO))


def test_stroke_limits_and_impossible_linkages_are_refused(hand_case):
    with pytest.raises(ValueError, match=r"screw travel must be a finite number in \[0, 0.04\] m, got -0.001"):
        hand_case.base_radius(-0.001)
    with pytest.raises(ValueError, match=r"screw travel .* got 0.041"):
        hand_case.base_radius([0.01, 0.041])
    with pytest.raises(ValueError, match=r"turns must be a finite number in \[0, 10\]"):
        hand_case.travel(10.5)
    with pytest.raises(ValueError, match="thread_length"):
        PitchScrewLinkage(0.2, 0.3, 0.15, 0.47, -0.14, thread_length=0.04, nut_length=0.04, branch=-1)
    with pytest.raises(ValueError, match="cannot close"):  # a nut 0.52 m from F, rocker + coupler 0.45 m
        PitchScrewLinkage(0.2, 0.3, 0.15, 0.70, -0.14, thread_length=0.08, nut_length=0.04, branch=-1)
    with pytest.raises(ValueError, match="dead point"):  # the other branch starts at the rocker's dead point
        PitchScrewLinkage(0.2, 0.3, 0.15, 0.47, -0.14, thread_length=0.08, nut_length=0.04, branch=1)


def test_refine_finds_a_known_optimum_between_grid_points():
    grid = np.linspace(0.0, 0.2, 21)
    optimum = 0.0731

    def bowl(s: float) -> float:
        return (s - optimum) ** 2 + 3.0

    travel, value = refine(bowl, grid, np.array([bowl(s) for s in grid]), 1e-5)
    assert travel == pytest.approx(optimum, abs=2e-5)
    assert value == pytest.approx(3.0, abs=1e-9)


def test_refine_keeps_an_end_stop_and_stops_at_the_edge_of_feasibility():
    grid = np.linspace(0.0, 0.2, 11)

    def falling(s: float) -> float:
        return -s

    assert refine(falling, grid, -grid, 1e-5) == (0.2, -0.2)

    def bounded(s: float) -> float:  # better further out, infeasible beyond 0.1234
        return -s if s <= 0.1234 else math.inf

    travel, _ = refine(bounded, grid, np.array([bounded(s) for s in grid]), 1e-5)
    assert 0.1234 - 5e-5 <= travel <= 0.1234
    nothing = refine(bounded, grid, np.full(grid.shape, math.inf), 1e-5)
    assert math.isnan(nothing[0]) and nothing[1] == math.inf


def test_study_optima_beat_every_grid_setting_and_name_what_holds_them():
    study = reconfigure.study(NOMINAL_GEOMETRY, grid_settings=5)
    assert study.settings[0] == pytest.approx(study.linkage.base_radius(0.0))
    for outcome, values in zip(study.outcomes, study.values, strict=True):
        profile = outcome.profile
        grid_best = np.nanmax(values) if profile.maximized else np.nanmin(values)
        assert (outcome.best_value >= grid_best) if profile.maximized else (outcome.best_value <= grid_best)
        assert outcome.gain_percent >= 0.0
        assert 0.0 <= outcome.best_travel <= study.linkage.stroke
    heavy = study.outcomes[0]
    assert heavy.limit == "upper end stop"  # on the nominal robot a wider base always spreads the 8 kg load
    assert heavy.best_ra == pytest.approx(study.settings[-1])
    # at the end stop the motors ride 26 mm higher: the fixed belt lies that much lower in the base frame
    rise = float(study.linkage.height_offset(study.linkage.stroke))
    assert rise == pytest.approx(0.026, abs=0.001)
    design = replace(NOMINAL_GEOMETRY, ra=float(study.settings[-1]))

    def torque(belt: float) -> float:
        profile = heavy.profile
        kwargs = {"payload": profile.payload, "task_radius": profile.zone_radius, "cycles": profile.cycles(belt)}
        return performance.evaluate(design, belt_height=belt, **kwargs).peak_torque_nm

    assert heavy.best_value == pytest.approx(torque(WORKING_HEIGHT - rise), rel=1e-12)
    assert abs(torque(WORKING_HEIGHT) - heavy.best_value) > 1e-3 * heavy.best_value  # the rise matters
    # the fastest-cycle profile's pick rate is measured on that belt too, with the drive the robot was built with
    fastest = study.outcomes[2].profile
    drives = (codesign.choose_drive(NOMINAL_GEOMETRY).option,)

    def cycle_time(belt: float) -> float:
        kwargs = {"payload": fastest.payload, "task_radius": fastest.zone_radius, "cycles": fastest.cycles(belt)}
        return 60.0 / performance.evaluate(design, belt_height=belt, drives=drives, **kwargs).picks_per_min_light

    assert 60.0 / study.values[2, -1] == pytest.approx(cycle_time(WORKING_HEIGHT - rise), rel=1e-12)
    # cycle times come in whole control periods; 26 mm lower the arms are 4 periods faster (measured)
    assert cycle_time(WORKING_HEIGHT) - 60.0 / study.values[2, -1] >= 2.0 * CONTROL_PERIOD - 1e-9
    with pytest.raises(ValueError, match="objective"):
        reconfigure.TaskProfile("bad", 1.0, 0.3, "energy")
    # the report names the fixed setting, or says there is none (as on the compromise design) instead of NaNs
    assert f"At fixed ra = {study.fixed_ra:.3f} m" in report.reconfiguration_table(study)
    unserved = replace(
        study,
        fixed_travel=math.nan,
        fixed_ra=math.nan,
        outcomes=tuple(replace(o, fixed_value=math.nan, gain_percent=math.nan) for o in study.outcomes),
    )
    table = report.reconfiguration_table(unserved)
    assert "none serves every profile" in table and "nan" not in table
