"""Sweeps: one work unit for both backends, resume by content key, failures recorded, worker deaths retried."""

import csv
import dataclasses
import functools
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from controllers.compliance import DriveCompliance
from controllers.dynamics import ModelParameters
from controllers.payload import EmptyMoveSums
from delta_env.cycles import standard_cycle
from delta_env.drive import DriveLimits
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry, DeltaMasses
from delta_env.scaling import scaled_masses
from delta_env.scenario import Scenario, preset, save_geometry
from eval.engine import Prepared
from eval.processes import import_ray
from eval.sweep import __main__ as sweep_cli
from eval.sweep import report
from eval.sweep.runner import RESULT_FIELDS, ResultsTable, run_sweep, unit_key
from eval.sweep.work import METRIC_FIELDS, ControllerSetup, run_unit, setup_digest
from eval.work import WorkUnit
from tests.conftest import NOMINAL_SETUP as SETUP
from tests.figure_checks import hidden_legend_entries, kept_figures

CODE, DIGEST = "code-under-test", "setup-under-test"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
COMPARED = ("status", "tracking_rms_mm", "tracking_max_mm", "torque_rms_nm", "energy_j", "steps", "diverged")


def tiny(name: str):
    """A preset shortened to one pick-and-place cycle."""
    scenario = preset(name)
    return dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, n_cycles=1))


def grid(controllers=("pd",), seeds=(0, 1), scenarios=("nominal", "worn")) -> list[WorkUnit]:
    return [WorkUnit(tiny(name), key, seed) for name in scenarios for key in controllers for seed in seeds]


def sweep(units: list[WorkUnit], table: ResultsTable, code: str = CODE, **kwargs) -> dict[str, int]:
    """``run_sweep`` with SETUP (digest :data:`DIGEST`) on every scenario of ``units``."""
    contents = {unit.scenario.content_hash for unit in units}
    digests = {(unit.scenario.content_hash, unit.controller): DIGEST for unit in units}
    return run_sweep(units, dict.fromkeys(contents, SETUP), table, code, digests, **kwargs)


def rows_by_key(path: Path) -> dict[str, dict[str, str]]:
    with path.open(newline="") as file:
        rows = list(csv.DictReader(file))
    by_key = {row["key"]: row for row in rows}
    assert len(by_key) == len(rows), "a unit was written twice"
    return by_key


RESULTS: dict[tuple[str, str, int], dict] = {}
"""The rows :class:`CountingWork` computed (every sweep here runs on SETUP), by scenario content, controller and
seed: a unit repeats exactly (``test_a_work_unit_is_one_row_of_metrics_and_repeats_exactly``), so a rerun of it in
another sweep reuses its row."""


class CountingWork:
    """The real work function, counting its calls; raises KeyboardInterrupt at call ``interrupt_at``."""

    def __init__(self, interrupt_at: int | None = None) -> None:
        self.calls: list[WorkUnit] = []
        self.interrupt_at = interrupt_at

    def __call__(self, unit: WorkUnit, setup: ControllerSetup) -> dict:
        if self.interrupt_at is not None and len(self.calls) + 1 == self.interrupt_at:
            raise KeyboardInterrupt
        self.calls.append(unit)
        key = (unit.scenario.content_hash, unit.controller, unit.seed)
        if key not in RESULTS:
            RESULTS[key] = run_unit(unit, setup)
        return dict(RESULTS[key])


def die_once_then_run(marker_folder: Path, unit: WorkUnit, setup: ControllerSetup) -> dict:
    """Kill the worker process the first time a seed is run (marker file per seed), then run it normally."""
    marker = marker_folder / f"seed-{unit.seed}"
    if unit.seed == 1 and not marker.exists():
        marker.touch()
        os._exit(1)
    return run_unit(unit, setup)


def test_a_work_unit_is_one_row_of_metrics_and_repeats_exactly() -> None:
    unit = WorkUnit(tiny("paper"), "mid_f_rls", 2)
    row, again = run_unit(unit, SETUP), run_unit(unit, SETUP)
    assert row["status"] == "ok" and row["error"] == ""
    assert set(METRIC_FIELDS) <= set(row)
    assert {name: row[name] for name in METRIC_FIELDS} == {name: again[name] for name in METRIC_FIELDS}
    assert 0.0 < row["tracking_rms_mm"] < 2.0  # model feedforward with RLS on the 3.8 kg cycle: sub-millimetre
    # 3.8 kg estimated within 5 % at the end of the carry
    assert abs(row["payload_end_error_percent"]) <= row["payload_end_abs_error_percent"] < 5.0
    # the pick-rate scores of the same episode: a standard cycle of under a second, placed within a millimetre
    assert 60.0 < row["picks_per_min"] < 300.0 and row["cycle_time_max_s"] < 1.0
    assert row["place_error_max_mm"] < 1.0 and row["path_deviation_rms_mm"] <= row["tracking_rms_mm"]
    assert row["envelope_violations"] == 0 and 0.0 < row["thermal_margin"] < 1.0
    assert row["faults_injected"] == row["detections"] == row["false_alarms"] == 0  # no fault, none detected
    pd_row = run_unit(dataclasses.replace(unit, controller="pd"), SETUP)
    assert pd_row["tracking_rms_mm"] > 3.0 * row["tracking_rms_mm"]
    assert math.isnan(pd_row["payload_end_error_percent"])  # PD estimates nothing


def test_a_failing_episode_is_recorded_with_its_error_and_not_rerun(tmp_path: Path) -> None:
    units = [WorkUnit(tiny("nominal"), "pd", 0), WorkUnit(tiny("nominal"), "no_such_controller", 0)]
    table = ResultsTable(tmp_path / "results.csv")
    counts = sweep(units, table)
    assert counts == {"total": 2, "skipped": 0, "ran": 2, "failed": 1}
    rows = {row["controller"]: row for row in table.load()}
    assert rows["pd"]["status"] == "ok"
    failed = rows["no_such_controller"]
    assert failed["status"] == "failed"
    assert failed["error"].startswith("ValueError: unknown controller 'no_such_controller'")
    assert failed["tracking_rms_mm"] == "nan"
    work = CountingWork()
    assert sweep(units, table, work=work)["skipped"] == 2
    assert work.calls == []


def test_resume_after_an_interrupted_sweep_recomputes_nothing_finished(tmp_path: Path) -> None:
    units = grid()  # 4 units
    table = ResultsTable(tmp_path / "results.csv")
    first = CountingWork(interrupt_at=3)
    with pytest.raises(KeyboardInterrupt):
        sweep(units, table, work=first)
    assert len(first.calls) == 2 and len(table.load()) == 2
    # The process died while writing a third row: the torn line is dropped, that unit runs again.
    with table.path.open("a") as file:
        file.write("0123456789abcdef,nominal,trunc")
    second = CountingWork()
    counts = sweep(units, table, work=second)
    assert counts == {"total": 4, "skipped": 2, "ran": 2, "failed": 0}
    assert {id(unit) for unit in second.calls}.isdisjoint(id(unit) for unit in first.calls)
    assert len(second.calls) == 2
    keys = rows_by_key(table.path)
    assert set(keys) == {unit_key(unit, CODE, DIGEST) for unit in units}
    # A new code version is a new key: everything runs again.
    third = CountingWork()
    assert sweep(units, table, "other-code", work=third)["ran"] == 4
    assert len(third.calls) == 4


@pytest.mark.slow  # starts a process pool twice
def test_local_pool_retries_a_unit_whose_worker_died(tmp_path: Path) -> None:
    units = grid(scenarios=("nominal",))  # seeds 0 and 1; seed 1 kills its worker once
    table = ResultsTable(tmp_path / "results.csv")
    work = functools.partial(die_once_then_run, tmp_path)
    counts = sweep(units, table, workers=2, work=work)
    assert counts["ran"] == 2 and counts["failed"] == 0
    assert (tmp_path / "seed-1").exists()  # the worker did die
    reference = {unit.seed: run_unit(unit, SETUP) for unit in units}
    for row in table.load():
        assert row["status"] == "ok"
        assert float(row["tracking_rms_mm"]) == reference[int(row["seed"])]["tracking_rms_mm"]
        assert int(row["pid"]) != os.getpid()


@pytest.mark.slow  # starts Ray
def test_ray_and_local_backends_give_identical_rows(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("ray", reason="Ray is the optional 'distributed' extra")
    # a user's controller too, importable from PYTHONPATH by the pool's and by Ray's workers
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(EXAMPLES), os.environ.get("PYTHONPATH", "")]))
    units = grid(controllers=("pd", "mid_f_rls", "my_controller:StiffPD"), seeds=(0,))
    local, ray = ResultsTable(tmp_path / "local.csv"), ResultsTable(tmp_path / "ray.csv")
    sweep(units, local, backend="local", workers=2)
    counts = sweep(units, ray, backend="ray", workers=2)
    assert counts["ran"] == len(units) and counts["failed"] == 0
    local_rows, ray_rows = rows_by_key(local.path), rows_by_key(ray.path)
    assert set(local_rows) == set(ray_rows)
    for key, row in local_rows.items():
        assert {name: row[name] for name in COMPARED} == {name: ray_rows[key][name] for name in COMPARED}
        assert ray_rows[key]["pid"] != str(os.getpid())  # ran in a Ray worker


def test_ray_backend_without_ray_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r"'distributed' extra"):
        import_ray()


def test_summary_statistics_use_the_t_interval_and_leave_out_failed_and_diverged() -> None:
    base = {"scenario": "s", "controller": "pd", "label": "PD", "status": "ok", "diverged": "False"}
    values = [1.0, 2.0, 3.0, 4.0]
    rows = [{**base, **dict.fromkeys(report.SUMMARY_METRICS, ""), "tracking_rms_mm": str(v)} for v in values]
    rows.append({**rows[0], "tracking_rms_mm": "100.0", "diverged": "True"})
    rows.append({**rows[0], "tracking_rms_mm": "nan", "status": "failed"})
    (entry,) = report.summarize(rows, ["s"], ["pd"])
    assert (entry["episodes"], entry["failed"], entry["diverged"]) == (6, 1, 1)
    assert entry["tracking_rms_mm_mean"] == pytest.approx(2.5)
    assert entry["tracking_rms_mm_std"] == pytest.approx(1.2909944)
    assert entry["tracking_rms_mm_ci95"] == pytest.approx(3.1824463 * 1.2909944 / 2.0)  # t(0.975, 3) s / sqrt(n)
    assert math.isnan(entry["energy_j_mean"])


def _summary_of(means: dict[str, tuple[float, float]]) -> list[dict]:
    """The summary of two episodes per controller whose tracking RMS (mm) are ``means[label]`` (two values) and
    torque RMS 20 and 21 N m."""
    rows = [
        {
            "scenario": "nominal",
            "controller": label.lower(),
            "label": label,
            "status": "ok",
            "diverged": "False",
            **dict.fromkeys(report.SUMMARY_METRICS, ""),
            "tracking_rms_mm": str(value),
            "torque_rms_nm": str(torque),
            "energy_j": str(100.0 * value + torque),
        }
        for label, values in means.items()
        for value, torque in zip(values, (20.0, 21.0), strict=True)
    ]
    return report.summarize(rows, ["nominal"], [label.lower() for label in means])


def test_summary_table_reads_in_words_and_rounded_numbers() -> None:
    summary = _summary_of({"PD": (5.0, 5.6), "Oracle": (0.03, 0.031)})
    table = report.markdown(summary)
    header = table.splitlines()[0]
    assert "Tracking RMS (mm)" in header and "Torque RMS (N m)" in header and "tracking_rms_mm" not in header
    pd_row = table.splitlines()[2].split(" | ")
    # two seeds: mean 5.3, half-width t(0.975, 1) 0.424 / sqrt(2) = 3.81 mm; energy 520 and 581 J: 550.5 ± 387.6
    assert pd_row[3] == "5.30 ± 3.81"
    assert pd_row[3 + report.SUMMARY_METRICS.index("energy_j")] == "550 ± 388"  # not "550 ± 3.9e+02"
    assert "e+" not in table and "e-" not in table


def test_summary_plot_shows_every_controller_on_a_log_axis_when_they_span_decades(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    summary = _summary_of({"PD": (5.0, 5.6), "RLS": (0.3, 0.35), "Oracle": (0.03, 0.031)})
    with kept_figures(monkeypatch) as figures:
        report.plot(summary, tmp_path / "summary.png")
        (figure,) = figures
        tracking, torque = figure.axes
        assert tracking.get_yscale() == "log" and torque.get_yscale() == "linear"  # 20 and 21 N m: one decade
        assert hidden_legend_entries(figure) == []
        # every bar stands out of its axis's bottom by a visible part of the axis's height
        bottom, top = (np.log10(limit) for limit in tracking.get_ylim())
        heights = [np.log10(bar.get_height()) for bar in tracking.patches]
        assert min(heights) - bottom > 0.05 * (top - bottom)


def test_cli_writes_the_run_folder_and_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.setattr(sweep_cli, "prepare", lambda scenario, *args, **kwargs: Prepared(SETUP, Path(), None, None))
    out = tmp_path / "run"
    argv = ["--scenarios", "nominal,paper", "--controllers", "pd", "--seed", "0", "--episodes", "2", "--cycles", "1"]
    argv += ["--workers", "1", "--out", str(out)]
    assert sweep_cli.main(argv) == 0
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [tuple(rows[0])] == [RESULT_FIELDS] and len(rows) == 4
    assert {(row["scenario"], row["seed"]) for row in rows} == {
        (s, str(n)) for s in ("nominal", "paper") for n in (0, 1)
    }
    summary = list(csv.DictReader((out / "summary.csv").open()))
    assert [(row["scenario"], row["episodes"]) for row in summary] == [("nominal", "2"), ("paper", "2")]
    assert (out / "plots" / "summary.png").stat().st_size > 10_000
    stored = Scenario.load(out / "scenarios" / "paper.toml")
    assert (stored.task.payload_mass_range, stored.task.n_cycles) == ((3.8, 3.8), 1)
    assert "eval.sweep" in (out / "config.json").read_text()
    assert "paper" in capsys.readouterr().out
    assert sweep_cli.main(argv) == 0
    assert len(list(csv.DictReader((out / "results.csv").open()))) == 4
    assert "Ran 0 episodes (0 failed), 4 already in the table" in capsys.readouterr().out
    assert len((out / "commands.log").read_text().splitlines()) == 2


def test_geometry_puts_every_scenario_on_that_robot_with_scaled_masses(tmp_path: Path, capsys) -> None:
    design = DeltaGeometry(ra=0.24, rb=0.035, l1=0.42, l2=1.1)
    path = save_geometry(design, tmp_path / "wide.toml")
    args = sweep_cli.parse_args(["--scenarios", "nominal,worn", "--geometry", str(path)])
    nominal = preset("nominal")
    expected_masses = scaled_masses(design, nominal.plant.geometry, nominal.plant.masses)
    assert [s.name for s in args.scenarios] == ["nominal+wide", "worn+wide"]
    for scenario, name in zip(args.scenarios, ("nominal", "worn"), strict=True):
        assert scenario.plant == dataclasses.replace(preset(name).plant, geometry=design, masses=expected_masses)
        assert (scenario.condition, scenario.task) == (preset(name).condition, preset(name).task)
    assert expected_masses.m1 > nominal.plant.masses.m1  # the longer arm is heavier
    assert args.out != sweep_cli.parse_args(["--scenarios", "nominal,worn"]).out  # another robot, another folder
    (tmp_path / "short.toml").write_text("[geometry]\nra = 0.2\nrb = 0.05\nl1 = 0.37\n")
    with pytest.raises(SystemExit):
        sweep_cli.parse_args(["--geometry", str(tmp_path / "short.toml")])
    assert "short.toml" in capsys.readouterr().err


def test_the_setup_digest_covers_every_field_a_controller_knows_and_nothing_of_the_others(tmp_path: Path) -> None:
    sums = EmptyMoveSums(np.eye(5), np.zeros(5))
    policy = tmp_path / "policy.zip"
    policy.write_bytes(b"weights")
    changed = {
        "mid": ModelParameters(rho1=1.9, rho2=0.9),
        "mid_f": ModelParameters(rho1=1.9, rho2=0.9),
        "mid_f_rods": ModelParameters(rho1=1.9, rho2=0.9),
        "drive_lag": (0.001, 0.001, 0.0011),
        "stribeck_excess": (2.0, 1.7, 2.3),
        "tares": {"mid_f_rls_lag": 0.01},
        "empty_moves": {"mid_f_rls_lag": sums},
        "pd_gains": (3000.0, 61.0),
        "servo": "pd",
        "geometry": DeltaGeometry(ra=0.21, rb=0.05, l1=0.37, l2=0.95),
        "masses": DeltaMasses(m1=2.1, m2=0.2, m0=0.8),
        "drive": DriveLimits(peak_torque=300.0),
        "encoder_bits": 20,
        "fault_reaction": "stop",
        "compliance": DriveCompliance.nominal(),
        "torque_delay": 0.00025,
    }
    assert {*changed, "residual_policy"} == {field.name for field in dataclasses.fields(SETUP)}
    base = setup_digest(SETUP, "mid_f_rls_lag")
    for name, value in changed.items():
        assert setup_digest(dataclasses.replace(SETUP, **{name: value}), "mid_f_rls_lag") != base, name
    moved = EmptyMoveSums(np.eye(5), np.full(5, 1e-9))
    assert setup_digest(dataclasses.replace(SETUP, empty_moves={"mid_f_rls_lag": moved}), "mid_f_rls_lag") != (
        setup_digest(dataclasses.replace(SETUP, empty_moves={"mid_f_rls_lag": sums}), "mid_f_rls_lag")
    )
    # another row's tare is not what PD knows (the cell's estimator's is: an online timing runs it beside PD)
    pd = setup_digest(SETUP, "pd")
    assert setup_digest(dataclasses.replace(SETUP, tares={"mid_f_rls_lag": 0.01}), "pd") == pd
    assert setup_digest(dataclasses.replace(SETUP, tares={"mid_f_rls": 0.01}), "pd") != pd
    # the residual policy counts by its bytes, and for the residual row only
    copy = tmp_path / "elsewhere" / "policy.zip"
    copy.parent.mkdir()
    copy.write_bytes(policy.read_bytes())
    with_policy, with_copy = (dataclasses.replace(SETUP, residual_policy=path) for path in (policy, copy))
    assert setup_digest(with_policy, "pd") == pd
    assert setup_digest(with_policy, "residual") == setup_digest(with_copy, "residual")
    copy.write_bytes(b"other weights")
    assert setup_digest(with_policy, "residual") != setup_digest(with_copy, "residual")


def test_a_unit_that_follows_a_given_path_is_keyed_by_that_path() -> None:
    path = standard_cycle(NOMINAL_GEOMETRY, n_cycles=1, start="pick")
    same = standard_cycle(NOMINAL_GEOMETRY, n_cycles=1, start="pick")
    turned = standard_cycle(NOMINAL_GEOMETRY, n_cycles=1, start="pick", heading=0.0)
    scenario = tiny("nominal")
    keys = [unit_key(WorkUnit(scenario, "pd", 0, None, p), CODE, DIGEST) for p in (None, path, same, turned)]
    assert keys[1] == keys[2] and len({keys[0], keys[1], keys[3]}) == 3
    # and the episode follows it: its record's reference is the given path, untimed
    row = run_unit(WorkUnit(scenario, "pd", 0, None, turned), SETUP)
    assert row["status"] == "ok", row["error"]
    assert row["steps"] == len(turned) - 1
