"""The design study (eval.design): figures of merit, optimization, reconfiguration, verification, CLI."""

import csv
import functools
import json
import math

import numpy as np
import pytest

from controllers.feedforward import model_controller
from delta_env import cylinder
from delta_env.catalogue import GEAR_RATIOS
from delta_env.config import PlantRealism
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry
from delta_env.scaling import scaled_masses
from delta_env.scenario import load_geometry
from delta_env.trajectories import WORKING_HEIGHT
from eval.design import codesign, optimize, performance, report, verify
from eval.design import model as design_model
from eval.design.__main__ import QUICK, main, parse_args
from eval.identification.run import run_identification


@pytest.fixture(scope="module")
def nominal() -> performance.Performance:
    return performance.evaluate(NOMINAL_GEOMETRY)


def _dominates(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(a <= b) and np.any(a < b))


def test_nominal_design_is_feasible_with_plausible_figures(nominal):
    assert nominal.feasible, nominal.reason
    assert 0.9 < nominal.cylinder_diameter_m < 1.0  # an industrial-size data-sheet cylinder
    assert nominal.cylinder_top_m >= cylinder.REQUIRED_TOP and nominal.cylinder.bottom >= performance.TASK_BAND[0]
    assert nominal.workspace_m3 == pytest.approx(nominal.cylinder.volume)
    # 3.8 kg at 3 g, measured 76.2 N m (DESIGN's 170 N m is at 6 g); 8 kg measured 1.55 times that
    assert nominal.peak_torque_nm == pytest.approx(76.2, rel=0.1)
    assert len(nominal.cycles) == len(performance.TASK_CYCLES)
    heavier = performance.evaluate(NOMINAL_GEOMETRY, payload=8.0)
    assert heavier.peak_torque_nm > 1.4 * nominal.peak_torque_nm
    # its own catalogue drive: picks/min on the standard cycle, the light payload faster than the rated one
    assert nominal.drive.option is not None and nominal.drive.rated.check.holds
    # measured 155.0 and 165.3 picks/min
    assert nominal.picks_per_min == pytest.approx(155.0, rel=0.1)
    assert nominal.picks_per_min_light == pytest.approx(165.3, rel=0.1)
    assert nominal.picks_per_min < nominal.picks_per_min_light
    assert optimize.objective_vector(nominal)[2] == -nominal.picks_per_min
    # on the default belt the pick rate is the co-design's at the data-sheet placement
    alone = codesign.choose_drive(NOMINAL_GEOMETRY)
    assert (nominal.picks_per_min, nominal.picks_per_min_light) == (alone.picks_per_min, alone.picks_per_min_light)


def test_design_model_adds_the_same_drive_to_every_design():
    drive = design_model.DRIVE
    for geometry in (NOMINAL_GEOMETRY, DeltaGeometry(0.25, 0.03, 0.32, 1.05)):
        links = design_model.design_model(geometry, drive=None)
        model = design_model.design_model(geometry)
        assert model.inertia * model.parameters.rho1 == pytest.approx(links.inertia + drive.armature)
        theta = np.array([[0.3, 0.5, 0.4]])
        rate, acceleration = np.array([[1.0, -2.0, 0.0]]), np.array([[5.0, 0.0, -3.0]])
        difference = model.inverse_dynamics(theta, rate, acceleration) - links.inverse_dynamics(
            theta, rate, acceleration
        )
        expected = drive.armature * acceleration + drive.viscous * rate + drive.coulomb * np.sign(rate)
        np.testing.assert_allclose(difference, expected, atol=1e-9)


def test_infeasible_designs_say_why():
    short = performance.evaluate(DeltaGeometry(0.15, 0.04, 0.3, 0.72))
    assert not short.feasible and "task region" in short.reason and short.shortfall > 0.2
    low = performance.evaluate(DeltaGeometry(0.24, 0.10, 0.29, 1.36))  # its dexterous axis starts below the belt
    assert not low.feasible and "no dexterous cylinder above the belt" in low.reason
    assert low.workspace_m3 == 0.0 and low.clearance_shortfall > 0.0 and math.isnan(low.cylinder_top_m)


def test_bad_bounds_are_named():
    with pytest.raises(ValueError, match="ra"):
        optimize.DesignBounds(ra=(0.3, 0.2))
    with pytest.raises(ValueError, match="rb max < ra min"):
        optimize.DesignBounds(rb=(0.03, 0.2))
    with pytest.raises(ValueError, match="l2 min > l1 max"):
        optimize.DesignBounds(l1=(0.3, 0.8))
    with pytest.raises(ValueError, match="population"):
        optimize.SearchSettings(population=2)


def test_impossible_constraints_give_a_clear_error(nominal):
    tiny = optimize.DesignBounds(ra=(0.12, 0.13), rb=(0.03, 0.04), l1=(0.10, 0.11), l2=(0.30, 0.31))
    with pytest.raises(RuntimeError, match=r"no feasible design.*task region shortfall"):
        optimize.pareto_front(nominal, optimize.SearchSettings(4, 1), bounds=tiny)


def test_pareto_front_is_reproducible_and_non_dominated(nominal):
    first = optimize.pareto_front(nominal, optimize.SearchSettings(10, 2, seed=5))
    again = optimize.pareto_front(nominal, optimize.SearchSettings(10, 2, seed=5))
    assert np.array_equal(np.array(first.archive.x), np.array(again.archive.x))
    assert np.array_equal(first.front, again.front)
    objectives = np.array([first.archive.f[i] for i in first.front])
    for i, a in enumerate(objectives):
        assert not any(_dominates(b, a) for j, b in enumerate(objectives) if j != i)
    # every feasible evaluation is dominated by or equal to a front member
    for f, g in zip(first.archive.f, first.archive.g, strict=True):
        if np.all(g <= 0):
            assert any(np.all(member <= f) for member in objectives)
    assert all(first.archive.performance[i].feasible for i in first.front)
    chosen = optimize.choose_designs(optimize.design_roles(first, nominal))
    assert chosen["compromise"] in first.front


def test_weighted_cost_is_one_at_nominal_and_ga_is_reproducible(nominal):
    assert optimize.weighted_cost(nominal, nominal) == pytest.approx(1.0)
    first = optimize.single_objective(nominal, optimize.SearchSettings(10, 2, seed=2))
    again = optimize.single_objective(nominal, optimize.SearchSettings(10, 2, seed=2))
    assert first.best == again.best
    best = first.archive.performance[first.best]
    costs = [optimize.weighted_cost(p, nominal) for p in first.archive.performance if p.feasible]
    assert optimize.weighted_cost(best, nominal) == pytest.approx(min(costs))


def test_a_plant_that_cannot_assemble_is_reported_not_dropped():
    design = performance.evaluate(DeltaGeometry(0.3, 0.05, 0.5, 0.72))
    result = verify.verify_design("too short", design, episodes=1)
    assert not result.feasible and "cannot be assembled" in result.reason
    assert result.episodes == ()


def test_the_two_readings_of_the_five_percent_criterion():
    close_ratio = report.TorqueChange("d", "peak", model=0.80, identified=0.82, plant=0.83)
    assert close_ratio.ratio_holds(close_ratio.model)  # 0.83 / 0.80 = 1.0375
    assert not close_ratio.change_holds(close_ratio.model)  # -17 % is not within 1 point of -20 %
    assert close_ratio.change_holds(close_ratio.identified, tolerance=0.06)  # -17 % vs -18 %: 1 point of 18
    far = report.TorqueChange("d", "peak", model=0.80, identified=0.85, plant=0.85)
    assert not far.ratio_holds(far.model) and far.ratio_holds(far.identified) and far.change_holds(far.identified)


def test_model_controller_uses_the_robot_it_is_given():
    geometry = DeltaGeometry(0.25, 0.03, 0.32, 1.05)
    masses = scaled_masses(geometry)
    controller = model_controller(None, forearm_rods=True, geometry=geometry, masses=masses)
    assert controller.dynamics.geometry == geometry and controller.dynamics.masses == masses
    assert model_controller(None).dynamics.geometry == NOMINAL_GEOMETRY


@pytest.fixture(scope="module")
def short_arm() -> verify.Verification:
    """The closed-loop verification of a design unlike the nominal robot (shorter arms and forearms), one
    episode per controller: one identification of its plant for every test of it (39 s: its tests are slow)."""
    design = performance.evaluate(DeltaGeometry(0.244, 0.050, 0.318, 1.054))
    assert design.feasible, design.reason
    return verify.verify_design("short arm", design, episodes=1, seed=1)


@pytest.mark.slow
def test_verification_runs_every_controller_with_closed_loops(short_arm):
    result = short_arm
    assert result.feasible, result.reason
    assert {e.controller for e in result.episodes} == set(verify.CONTROLLERS)
    # measured: loops closed to 2.7 um (verify's limit, LOOP_GAP_LIMIT, is 0.1 mm), the RLS row at 0.026 x PD
    assert all(e.max_loop_gap_m < 5e-6 for e in result.episodes)
    assert result.mean("MId+F+R+RLS+PD", "tracking_rms_mm") < 0.045 * result.mean("PD", "tracking_rms_mm")
    # the identified model and the design model with its drives both predict the torque the plant needs (measured
    # within 0.4 and 1.2 %)
    oracle_rms = result.mean("Oracle+PD (bound)", "torque_rms_nm")
    assert result.predicted_mean("identified", 1) == pytest.approx(oracle_rms, rel=0.02)
    assert result.predicted_mean("predicted", 1) == pytest.approx(oracle_rms, rel=0.02)


@pytest.mark.slow
def test_a_design_is_identified_on_its_own_plant(short_arm):
    result = short_arm
    assert result.feasible, result.reason
    # the identified friction is the plant's drive, whatever the links (measured within 0.56 %, as on the nominal
    # robot's identification: about 1 %)
    drive = PlantRealism()
    np.testing.assert_allclose(result.parameters.viscous, drive.viscous_per_joint, rtol=0.01)
    np.testing.assert_allclose(result.parameters.coulomb, drive.coulomb_per_joint, rtol=0.01)
    # and so is the drive's current loop, identified like the nominal robot's (measured within 0.51 %)
    np.testing.assert_allclose(result.drive_lag, drive.actuator_lag, rtol=0.01)
    # rho1 holds the armature relative to this design's own arm inertia (plus the forearms' share)
    links = design_model.design_model(result.geometry, drive=None)
    assert result.parameters.rho1 == pytest.approx(1.0 + drive.armature / links.inertia, rel=0.15)


@pytest.mark.slow
def test_quick_cli_writes_the_run_folder(tmp_path, monkeypatch):
    # The identification's accuracy and the verification's figures are checked above (short_arm); here a small
    # identification (two 2 s runs) and a tare of two episodes feed the verification, whose plumbing into the run
    # folder is what this test checks.
    monkeypatch.setattr(
        verify, "run_identification", functools.partial(run_identification, 2, duration=2.0, validation_duration=2.0)
    )
    monkeypatch.setattr(verify, "DEFAULT_CALIBRATION_EPISODES", 2)
    out = tmp_path / "run"
    assert main(["--quick", "--seed", "3", "--workers", "1", "--out", str(out)]) == 0
    with (out / "pareto.csv").open() as file:
        rows = list(csv.DictReader(file))
    for column in ("ra", "rb", "l1", "l2", "workspace_m3", "peak_torque_nm", "picks_per_min", "picks_per_min_light"):
        assert column in rows[0]
    objectives = np.array(
        [[-float(r["workspace_m3"]), float(r["peak_torque_nm"]), -float(r["picks_per_min"])] for r in rows]
    )
    for i, a in enumerate(objectives):
        assert not any(_dominates(b, a) for j, b in enumerate(objectives) if j != i)
    with (out / "designs.csv").open() as file:
        rows_by_design = {row["design"]: row for row in csv.DictReader(file)}
    # every chosen design is on the merged front, non-dominated against every evaluation (test_design_robustness.py)
    on_front = {tuple(r[k] for k in ("ra", "rb", "l1", "l2")) for r in rows}
    for name, row in rows_by_design.items():
        assert name == "nominal" or tuple(row[k] for k in ("ra", "rb", "l1", "l2")) in on_front, name
    with (out / "robustness.csv").open() as file:
        assert {row["design"] for row in csv.DictReader(file)} >= {"nominal", "compromise"}
    # each design named once, and by what its figures bear out
    lengths = [tuple(row[k] for k in ("ra", "rb", "l1", "l2")) for row in rows_by_design.values()]
    assert len(set(lengths)) == len(lengths)
    nominal_row = {k: float(rows_by_design["nominal"][k]) for k in ("workspace_m3", "peak_torque_nm")}
    if "low torque" in rows_by_design:
        assert float(rows_by_design["low torque"]["peak_torque_nm"]) < nominal_row["peak_torque_nm"]
    if "large workspace" in rows_by_design:
        assert float(rows_by_design["large workspace"]["workspace_m3"]) > nominal_row["workspace_m3"]
    # strict JSON: a design with no fixed screw setting for every profile must not write a bare NaN
    config = json.loads((out / "config.json").read_text(), parse_constant=lambda name: pytest.fail(f"{name} written"))
    assert config["command"] == "python -m eval.design --quick --seed 3 --workers 1 --out " + str(out)
    assert config["config"]["drive"]["gear_ratios"] == list(GEAR_RATIOS)
    assert "git_commit" in config and "versions" in config
    compromise = load_geometry(out / "design-compromise.toml")  # the file --geometry reads
    assert compromise == DeltaGeometry(*(float(rows_by_design["compromise"][k]) for k in ("ra", "rb", "l1", "l2")))
    assert 20.0 < float(rows_by_design["nominal"]["first_natural_frequency_hz"]) < 40.0  # 27 Hz at 4 kg
    for name, row in rows_by_design.items():  # no chosen design's links touch in its cylinder or the task region
        assert float(row["arm_clearance_m"]) > 0.0 and float(row["base_clearance_m"]) > 0.0, name
        # and its cylinder stands on the belt and reaches the lift and the product clearance above it
        bottom = float(row["cylinder_top_m"]) - float(row["cylinder_height_m"])
        assert bottom == pytest.approx(WORKING_HEIGHT, abs=1e-9), name
        assert float(row["cylinder_top_m"]) >= cylinder.REQUIRED_TOP - 1e-9, name
    with (out / "torque_changes.csv").open() as file:
        changes = list(csv.DictReader(file))
    assert {row["figure"] for row in changes} == {"peak", "RMS"}  # the nominal and one chosen design verified
    with (out / "reconfiguration.csv").open() as file:
        assert {row["design"] for row in csv.DictReader(file)} == {"nominal", "compromise"}
    names = (
        "convergence.png",
        "robustness.png",
        "convergence.csv",
        "pareto.png",
        "maps_horizontal.png",
        "maps_vertical.png",
        "verification.csv",
    )
    names += ("profiles_joints.png", "profiles_end_effector.png", "profiles_torque.png", "explorer.html")
    names += ("reconfiguration.png", "reconfiguration-compromise.png")
    for name in (*names, "summary.md"):
        assert (out / name).stat().st_size > 0
    assert math.isfinite(config["seconds"]["total"])


def test_design_arguments_are_checked_and_quick_keeps_the_explicit_ones(capsys):
    for flag in ("--screw-settings", "--mass-samples"):
        with pytest.raises(SystemExit):
            parse_args([flag, "1"])
        assert flag in capsys.readouterr().err
    args = parse_args(["--quick", "--screw-settings", "7"])
    assert args.screw_settings == 7 and args.mass_samples == QUICK["mass_samples"]
