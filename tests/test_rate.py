"""The pick-rate data sheet (python -m eval.rate): ABB's published rows, the row aggregation, the figure, --quick
and the console progress."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgb
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from delta_env.config import RATED_PAYLOAD
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.scenario import TIMINGS, PickPlaceTask, Scenario
from eval.rate.__main__ import main, parse_args
from eval.rate.published import ABB_IRB_360, DIFFERENCES
from eval.rate.report import (
    _cycle_line,
    _pace_line,
    _published_lines,
    compared_planner,
    rate_figure,
    summary_lines,
)
from eval.rate.study import (
    FULL_STUDY,
    JERK_LIMITED,
    MIXED,
    PLANNERS,
    QUICK_NOTE,
    QUICK_STUDY,
    RATE_TORQUE_SHARE,
    cycle_terms,
    holds,
    paced,
    planner_name,
    rate_scenario,
    summarize,
)

LEAD = "MId+F+R+RLS+lag+PD"


def test_abbs_published_rows_are_cycle_1_of_the_irb_360_specification() -> None:
    assert "3HAC079010-001" in ABB_IRB_360.source and ABB_IRB_360.cycle == "Cycle 1"
    # the same 25/305/25 mm cycle as ours, with 35 ms of air activation at each end, at 0.1 mm repeatability
    assert (ABB_IRB_360.lift, ABB_IRB_360.travel) == (STANDARD_LIFT, STANDARD_TRAVEL)
    assert ABB_IRB_360.air_activation == pytest.approx(0.035) and ABB_IRB_360.repeatability == pytest.approx(1e-4)
    published = {(row.robot, row.payload): row.picks_per_min for row in ABB_IRB_360.rows}
    assert published == {
        ("IRB 360-3/1130", 0.1): 150.0,
        ("IRB 360-8/1130", 1.0): 160.0,
        ("IRB 360-8/1130", 4.0): 140.0,
        ("IRB 360-8/1130", 8.0): 100.0,
    }
    assert ABB_IRB_360.robots == ("IRB 360-3/1130", "IRB 360-8/1130")
    assert any("3-DOF" in clause for clause in DIFFERENCES) and any("repeatability" in clause for clause in DIFFERENCES)


def episode(picks: float, place: float, **extra: float) -> dict[str, Any]:
    """The metrics of an episode (:meth:`eval.episodes.EpisodeRecord.metrics`) that a row aggregates."""
    return {
        "picks_per_min": picks,
        "cycle_time_mean_s": 60.0 / picks,
        "tracking_rms_mm": 0.3,
        "path_deviation_rms_mm": 0.2,
        "place_error_max_mm": place,
        "envelope_violations": 0,
        "peak_torque_ratio": 0.5,
        "rms_torque_ratio": 0.6,
        "thermal_exceeded": False,
        "diverged": False,
    } | extra


def test_a_row_aggregates_its_episodes_and_their_settle_times() -> None:
    settled = [
        episode(150.0, 0.08, settle_time_mean_ms=12.0, settle_time_max_ms=30.0, settle_timeouts=0),
        episode(140.0, 0.05, settle_time_mean_ms=18.0, settle_time_max_ms=55.0, settle_timeouts=2),
        episode(130.0, 0.06, settle_time_mean_ms=24.0, settle_time_max_ms=41.0, settle_timeouts=1),
    ]
    row = summarize(settled)
    assert row["picks_per_min"] == pytest.approx(140.0) and row["place_error_mm"] == pytest.approx(0.08)
    assert row["settle_time_mean_ms"] == pytest.approx(18.0)  # the mean over episodes
    assert row["settle_time_max_ms"] == pytest.approx(55.0)  # the longest
    assert row["settle_timeouts"] == 3 and isinstance(row["settle_timeouts"], int)  # summed
    assert row["episodes"] == 3 and not row["thermal_exceeded"]
    # a place that never settled in position: the row does not hold its timing, whatever its errors
    assert not holds(row) and holds(summarize([settled[0]]))
    # episodes of an env without the in-position release (or any episode without them): no settle columns
    without = summarize([episode(150.0, 0.08), settled[1]])
    assert not {"settle_time_mean_ms", "settle_time_max_ms", "settle_timeouts"} & set(without)
    assert summarize([*settled[:2], episode(150.0, 0.1, thermal_exceeded=True)])["thermal_exceeded"]


def test_a_row_aggregates_the_residual_vibration_mean_and_largest() -> None:
    rows = [
        episode(150.0, 0.05, residual_vibration_mean_um=2.0, residual_vibration_max_um=3.0),
        episode(140.0, 0.05, residual_vibration_mean_um=6.0, residual_vibration_max_um=11.0),
    ]
    row = summarize(rows)
    assert (row["residual_vibration_mean_um"], row["residual_vibration_max_um"]) == pytest.approx((4.0, 11.0))


def test_a_jerk_limited_planner_is_a_planned_timing_with_the_tasks_jerk_limit(capsys: pytest.CaptureFixture) -> None:
    base = Scenario(task=PickPlaceTask(n_cycles=2))
    row = rate_scenario(base, f"online{JERK_LIMITED}", 1.0)
    assert (row.task.timing, row.task.jerk_limited) == ("online", True) and "online+jerk" in row.name
    assert planner_name(row.task) == "online+jerk" and planner_name(rate_scenario(base, "online", 1.0).task) == "online"
    assert row.content_hash != rate_scenario(base, "online", 1.0).content_hash
    assert set(PLANNERS) == {*TIMINGS, "worst_case+jerk", "declared+jerk", "online+jerk"}
    assert compared_planner(["online+jerk", "fixed"]) == "fixed" and compared_planner(["online+jerk"]) == "online+jerk"
    compliant = parse_args(["--scenario", "compliant", "--planners", "online,online+jerk", "--no-fastest"])
    assert compliant.planners == ("online", "online+jerk")
    for argv, message in (
        (["--planners", "online+jerk"], "--planners online+jerk: a jerk-limited timing averages over the drives' mode"),
        (["--scenario", "compliant", "--planners", "fixed+jerk"], "--planners: unknown or no values ['fixed+jerk']"),
    ):
        with pytest.raises(SystemExit):
            parse_args(argv)
        assert message in capsys.readouterr().err


def test_the_cycle_ends_are_the_scenarios() -> None:
    task = PickPlaceTask(in_position_window=5e-5, air_activation=0.035)
    assert cycle_terms(task) == {"air_activation": 0.035, "in_position_window": 5e-5}
    line = _cycle_line(task)
    assert "within 0.05 mm" in line and "35 ms of air activation" in line
    timed = dataclasses.replace(task, release="timed")
    assert cycle_terms(timed) == {}
    assert _cycle_line(timed) == "The gripper switches in the middle of a 100 ms dwell at pick and place."


def test_a_rows_scenario_keeps_every_other_term_of_the_task() -> None:
    # the cycle's ends (air activation, in-position window) and the rest pass through from the scenario
    base = Scenario(task=PickPlaceTask(n_cycles=2, torque_share=0.5, fault_reaction="slow", start="pick"))
    row = rate_scenario(base, "online", 1.0)
    changed = {"cycle": "standard", "timing": "online", "payload_mass_range": (1.0, 1.0)}
    for field in dataclasses.fields(PickPlaceTask):
        expected = changed.get(field.name, getattr(base.task, field.name))
        assert getattr(row.task, field.name) == expected, field.name
    assert row.plant == base.plant and row.condition == base.condition


def rate_rows(planners: tuple[str, ...], loads: tuple[str, ...]) -> list[dict[str, Any]]:
    """Rows of the lead as :func:`eval.rate.study.run_rows` gives them: every planned timing at the same rate for
    objects of one mass (the case where lines coincide), declared and online faster on the mixed stream."""
    rows = []
    for planner in planners:
        for load in loads:
            rate = 78.2 if planner == "fixed" else 135.7
            if load == MIXED:
                rate += {"declared": 9.6, "online": 8.2}.get(planner, 0.0)
            missed = planner != "fixed"
            rows.append(
                {"planner": planner, "controller": LEAD, "payload": load}
                | summarize([episode(rate, 0.76 if missed else 0.2)])
            )
    return rows


def visible_pixels(figure: Any) -> dict[str, int]:
    """For each legend entry, the pixels of its colour inside the axes and outside the legend, as rendered."""
    figure.canvas.draw()
    image = np.asarray(figure.canvas.buffer_rgba())[..., :3].astype(float) / 255.0
    height = image.shape[0]
    (axis,) = figure.axes
    (legend,) = figure.legends
    inside = np.zeros(image.shape[:2], dtype=bool)
    box = axis.get_window_extent()
    inside[int(height - box.y1) : int(height - box.y0), int(box.x0) : int(box.x1)] = True
    box = legend.get_window_extent()
    inside[int(height - box.y1) : int(height - box.y0), int(box.x0) : int(box.x1)] = False
    counts = {}
    for handle, text in zip(legend.legend_handles, legend.get_texts(), strict=True):
        if isinstance(handle, Patch):
            color = to_rgb(handle.get_facecolor())
        elif isinstance(handle, LineCollection):
            color = to_rgb(handle.get_colors()[0])
        else:
            assert isinstance(handle, Line2D)
            color = to_rgb(handle.get_color())
        close = np.all(np.abs(image - np.array(color)) < 0.04, axis=-1)
        counts[text.get_text()] = int(np.sum(close & inside))
    return counts


def test_every_series_of_the_rate_figure_is_visible() -> None:
    import matplotlib.pyplot as plt

    planners = ("fixed", "worst_case", "declared", "online")
    rows = rate_rows(planners, ("0.1", "4", MIXED))
    fastest = [
        {"controller": "PD", "payload": "0.1", "picks_per_min": 60.0, "peak_acceleration_g": 1.5},
        {"controller": "PD", "payload": "4", "picks_per_min": math.nan, "peak_acceleration_g": math.nan},
    ]
    figure = rate_figure(rows, fastest, LEAD, "nominal")
    try:
        counts = visible_pixels(figure)
    finally:
        plt.close(figure)
    robots = [f"ABB {robot} (Cycle 1)" for robot in ABB_IRB_360.robots]
    assert set(counts) == {f"{planner} timing" for planner in planners} | {"PD, fastest fixed timing", *robots}
    # three planners give one rate at 0.1 and 4 kg, one series has a single bar, one robot a single rate: each
    # still shows hundreds of pixels of its own colour
    assert min(counts.values()) > 300, counts
    # no fastest fixed timing found at all: no legend entry for it
    figure = rate_figure(rows, fastest[1:], LEAD, "nominal")
    try:
        assert "PD, fastest fixed timing" not in visible_pixels(figure)
    finally:
        plt.close(figure)


def test_published_rows_stand_beside_ours_at_their_payloads() -> None:
    rows = rate_rows(("worst_case", "online"), ("0.1", "4", MIXED))
    by_key = {(row["planner"], row["controller"], row["payload"]): row for row in rows}
    args = argparse.Namespace(planners=["worst_case", "online"], scenario=Scenario())
    text = "\n".join(_published_lines(args, by_key, LEAD))
    assert "3HAC079010-001" in text and f"{LEAD} online" in text
    assert "| 4 | IRB 360-8/1130 | 140 | 135.7 | 0.97 | 0.76 |" in text
    assert "| 1 | IRB 360-8/1130 | 160 | not run | - | - |" in text
    assert f"| 8 | IRB 360-8/1130 | 100 | beyond our rated {RATED_PAYLOAD:g} kg | - | - |" in text
    assert all(clause in text for clause in DIFFERENCES)
    # the cycle's ends: the scenario's air activation against ABB's 35 ms
    if "air_activation" in cycle_terms(args.scenario.task):
        air = 1e3 * cycle_terms(args.scenario.task)["air_activation"]
        assert f"our air activation is {air:.0f} ms" in text or air == pytest.approx(35.0)
    else:
        assert "our cycle dwells 100 ms at pick and place, ABB's counts 35 ms of air activation" in text


def test_the_summary_shows_the_settle_columns_when_the_rows_have_them(tmp_path: Path) -> None:
    args = parse_args(["--quick", "--planners", "fixed,online", "--controllers", "mid_f_rls_lag"])
    settle = {"settle_time_mean_ms": 14.0, "settle_time_max_ms": 52.0, "settle_timeouts": 1}
    rows = rate_rows(("fixed", "online"), ("0.1", "4", MIXED))
    text = "\n".join(summary_lines(args, rows, [], tmp_path, 1.0))
    assert "settle (ms)" not in text and text.count(QUICK_NOTE) == 1 and "1 episode x 2 cycles" in text
    settled = "\n".join(summary_lines(args, [row | settle for row in rows], [], tmp_path, 1.0))
    assert "| settle (ms) | settle max | time-outs |" in settled and "| 14.0 | 52.0 | 1 |" in settled
    assert "no settle time-out" in settled and "IRB 360-3/1130" in settled


def test_controllers_that_estimate_the_payload_run_at_their_own_pace() -> None:
    # the residual and the RLS rows retime their carries on their own estimate and wait in position; PD replays
    assert paced(["mid_f_rls_lag", "pd", "residual", "mid_f_rls"]) == (
        ["mid_f_rls_lag", "residual", "mid_f_rls"],
        ["pd"],
    )
    assert paced(["pd", "mid_f_rls_lag"]) == (["pd", "mid_f_rls_lag"], [])  # the first always runs its own
    line = _pace_line(["mid_f_rls_lag", "residual", "pd"])
    assert line.startswith("MId+F+R+RLS+lag+PD and Residual + its base each run every row at its own pace; ")
    assert "the other controllers follow MId+F+R+RLS+lag+PD's references as given" in line
    assert _pace_line(["mid_f_rls_lag"]) == "MId+F+R+RLS+lag+PD runs every row at its own pace"


def test_quick_and_the_default_study_and_the_whole_envelope(capsys: pytest.CaptureFixture) -> None:
    full = parse_args([])
    assert (full.episodes, full.cycles, tuple(full.payloads), full.fastest) == (
        FULL_STUDY.episodes,
        FULL_STUDY.cycles,
        FULL_STUDY.payloads,
        True,
    )
    assert full.scenario.task.torque_share == RATE_TORQUE_SHARE == 1.0 and full.scenario.task.n_cycles == 4
    quick = parse_args(["--quick"])
    assert (quick.episodes, quick.cycles, tuple(quick.payloads), quick.fastest, quick.workers) == (
        QUICK_STUDY.episodes,
        QUICK_STUDY.cycles,
        QUICK_STUDY.payloads,
        False,
        1,
    )
    assert quick.scenario.task.n_cycles == QUICK_STUDY.cycles
    # options given explicitly still apply
    mixed = parse_args(["--quick", "--episodes", "2", "--payloads", "1", "--torque-share", "0.2", "--workers", "2"])
    assert (mixed.episodes, mixed.payloads, mixed.scenario.task.torque_share, mixed.workers) == (2, [1.0], 0.2, 2)
    assert not parse_args(["--no-fastest"]).fastest
    with pytest.raises(SystemExit):
        parse_args(["--torque-share", "0"])
    assert "--torque-share: torque_share must" in capsys.readouterr().err


@pytest.mark.slow
def test_quick_runs_end_to_end(parameter_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "rate"
    argv = ["--quick", "--parameters", str(parameter_file), "--out", str(out)]
    assert main([*argv, "--runs-dir", str(tmp_path / "runs")]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(QUICK_NOTE) and QUICK_NOTE in (out / "summary.md").read_text()
    assert "IRB 360-8/1130" in captured.out and "\r" not in captured.err
    # off a terminal: plain progress lines, the last one complete
    assert any(line.startswith("data sheet rows: 100%") and "24/24" in line for line in captured.err.splitlines())
    config = json.loads((out / "config.json").read_text())["config"]
    assert config["study"] == "quick" and config["arguments"]["quick"] is True and config["arguments"]["workers"] == 1
    assert config["arguments"]["torque_share"] == RATE_TORQUE_SHARE
    with (out / "rate.csv").open(newline="") as file:
        rows = list(csv.DictReader(file))
    assert {(row["planner"], row["payload"]) for row in rows} == {
        (planner, load)
        for planner in ("fixed", "worst_case", "declared", "online")
        for load in [*(f"{p:g}" for p in QUICK_STUDY.payloads), MIXED]
    }
    assert len(rows) == 24 and not (out / "pd_fastest.csv").exists()
    rate = {(row["planner"], row["controller"], row["payload"]): float(row["picks_per_min"]) for row in rows}
    # the whole envelope: a time-optimal cycle at the rated payload far faster than the fixed 3 g one (78 picks/min)
    assert rate[("online", LEAD, "4")] > 1.5 * rate[("fixed", LEAD, "4")]
    assert (out / "rate.png").stat().st_size > 10_000
