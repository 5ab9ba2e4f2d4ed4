"""python -m eval.compare: run folders side by side, the differences from the first, and the folders it refuses."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from eval import compare
from eval.run_folder import read_csv_rows, write_csv


def _run(folder: Path, tool: str, status: str = "finished") -> Path:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"tool": tool, "command": f"python -m {tool}", "status": status}))
    return folder


def _eval_run(folder: Path, episodes: list[tuple[str, float, float, bool]]) -> Path:
    """A ``python -m eval`` run folder whose episodes are (controller, tracking RMS mm, torque RMS N m, diverged)."""
    _run(folder, "eval")
    rows = [
        {"controller": c, "key": c.lower(), "tracking_rms_mm": t, "torque_rms_nm": q, "diverged": d}
        for c, t, q, d in episodes
    ]
    write_csv(folder / "episodes.csv", rows)
    return folder


@pytest.fixture
def two_runs(tmp_path: Path) -> tuple[Path, Path]:
    baseline = _eval_run(
        tmp_path / "before",
        [("PD", 5.0, 20.0, False), ("PD", 6.0, 22.0, False), ("PD", 100.0, 90.0, True), ("RLS", 0.4, 19.0, False)],
    )
    after = _eval_run(
        tmp_path / "after", [("PD", 4.4, 21.0, False), ("RLS", 0.5, 19.0, False), ("Mine", 1.0, 20.0, False)]
    )
    return baseline, after


def test_rows_side_by_side_with_their_differences(two_runs, tmp_path: Path, capsys) -> None:
    baseline, after = two_runs
    out = tmp_path / "comparison.csv"
    assert compare.main([str(baseline), str(after), "--out", str(out)]) == 0
    with out.open(newline="") as file:
        rows = {(row["row"], row["metric"]): row for row in csv.DictReader(file)}
    pd = rows["PD", "tracking_rms_mm"]
    # the baseline's mean leaves out the diverged episode: 5.5 mm; then 4.4 mm, -1.1 mm, -20 %
    assert float(pd["run_1"]) == pytest.approx(5.5) and float(pd["run_2"]) == pytest.approx(4.4)
    assert float(pd["difference_2"]) == pytest.approx(-1.1) and float(pd["change_percent_2"]) == pytest.approx(-20.0)
    rls = rows["RLS", "tracking_rms_mm"]
    assert float(rls["difference_2"]) == pytest.approx(0.1) and float(rls["change_percent_2"]) == pytest.approx(25.0)
    assert float(rows["PD", "torque_rms_nm"]["difference_2"]) == pytest.approx(0.0)
    assert pd["metric_label"] == "Tracking RMS (mm)"
    assert [key[0] for key in rows][::2] == ["PD", "RLS", "Mine"]  # the baseline's rows first, then the new ones
    printed = capsys.readouterr().out
    lines = {line.split(" | ")[0].lstrip("| "): line for line in printed.splitlines() if line.startswith("| ")}
    assert "| 5.50 | 4.40 (-1.10, -20 %) | 21.0 | 21.0 (0, 0 %) |" in lines["PD"]
    assert "| 0.400 | 0.500 (+0.100, +25 %) |" in lines["RLS"]
    assert lines["Mine"].startswith("| Mine | - | 1.00 | - | 20.0 |")  # not in the baseline: no difference
    assert f"1 (baseline): {baseline}" in printed and f"2: {after}" in printed


def test_three_runs_and_sweep_folders(tmp_path: Path, capsys) -> None:
    folders = []
    for name, value in (("a", 2.0), ("b", 1.0), ("c", 3.0)):
        folder = _run(tmp_path / name, "sweep")
        write_csv(
            folder / "summary.csv",
            [{"scenario": "nominal", "controller": "pd", "label": "PD", "tracking_rms_mm_mean": value}],
        )
        folders.append(str(folder))
    assert compare.main([*folders, "--metrics", "tracking_rms_mm"]) == 0
    printed = capsys.readouterr().out
    assert "| nominal / PD | 2.00 | 1.00 (-1.00, -50 %) | 3.00 (+1.00, +50 %) |" in printed


def _refused(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        compare.main(argv)
    assert exit_info.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.splitlines()  # one line
    return line


def test_folders_of_different_kinds_are_refused(two_runs, tmp_path: Path, capsys) -> None:
    sweep = _run(tmp_path / "sweep", "sweep")
    line = _refused([str(two_runs[0]), str(sweep)], capsys)
    assert "different kinds" in line and "'eval'" in line and "'sweep'" in line and str(sweep) in line


def _not_a_run(path: Path, case: str) -> Path:
    """A path that is not a run folder: missing, a file, a folder without a manifest or with another JSON file."""
    if case == "a file":
        path.write_text("a file")
    elif case != "missing":
        path.mkdir()
        if case == "not a manifest":
            (path / "config.json").write_text('{"epochs": 3}')
    return path


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("missing", "no such directory"),
        ("a file", "not a directory"),
        ("no manifest", "it has no config.json"),
        ("not a manifest", "not a run manifest"),
    ],
)
def test_a_path_that_is_not_a_run_folder_is_refused(two_runs, tmp_path: Path, capsys, case, expected) -> None:
    path = _not_a_run(tmp_path / "other", case)
    line = _refused([str(two_runs[0]), str(path)], capsys)
    assert f"{path} is not a run folder" in line and expected in line


def test_runs_without_controller_rows_and_bad_arguments_are_refused(two_runs, tmp_path: Path, capsys) -> None:
    designs = [str(_run(tmp_path / name, "design")) for name in ("d1", "d2")]
    line = _refused(designs, capsys)
    assert "'design' run" in line and "'eval', 'sweep'" in line
    failed = _run(tmp_path / "failed", "eval", status="failed")  # died before it wrote its episodes
    assert "has no episodes.csv" in _refused([str(two_runs[0]), str(failed)], capsys)
    assert "two run folders or more" in _refused([str(two_runs[0])], capsys)
    line = _refused([*map(str, two_runs), "--metrics", "tracking_rms_mm,speed"], capsys)
    assert "unknown speed" in line and "tracking_rms_mm" in line
    line = _refused([*map(str, two_runs), "--metrics", "energy_j"], capsys)  # not in these folders
    assert "energy_j not in every run folder" in line


def test_two_real_runs_of_python_m_eval(parameter_file: Path, tmp_path: Path, capsys) -> None:
    from eval.comparison.__main__ import main as eval_main

    argv = ["--controllers", "pd", "--episodes", "1", "--cycles", "1", "--workers", "1"]
    argv += ["--parameters", str(parameter_file), "--runs-dir", str(tmp_path / "runs")]
    for seed, name in ((0, "first"), (1, "second")):
        assert eval_main([*argv, "--seed", str(seed), "--out", str(tmp_path / name)]) == 0
    capsys.readouterr()
    out = tmp_path / "comparison.csv"
    assert compare.main([str(tmp_path / "first"), str(tmp_path / "second"), "--out", str(out)]) == 0
    with out.open(newline="") as file:
        rows = {row["metric"]: row for row in csv.DictReader(file) if row["row"] == "PD"}
    episodes = [read_csv_rows(tmp_path / name / "episodes.csv")[0] for name in ("first", "second")]
    for metric in ("tracking_rms_mm", "torque_rms_nm", "energy_j", "picks_per_min"):
        first, second = (float(episode[metric]) for episode in episodes)
        assert float(rows[metric]["difference_2"]) == pytest.approx(second - first)
    assert "| PD |" in capsys.readouterr().out


def test_an_unwritable_out_file_is_a_usage_error(two_runs, capsys) -> None:
    baseline, after = two_runs
    line = _refused([str(baseline), str(after), "--out", "/proc/nope/compare.csv"], capsys)
    assert line.startswith("python -m eval.compare: error: --out /proc/nope/compare.csv: cannot write it")
