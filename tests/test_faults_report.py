"""The fault report: injected faults matched to detections on synthetic episodes of known truth, the rows of
``faults.csv``, their summary, and the episode runner's record of both lists."""

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from controllers.base import PDController
from controllers.monitor import DetectedFault, ReportsFaults
from delta_env.env import DeltaPickPlaceEnv
from delta_env.faults import FaultSpec, InjectedFault, is_latent
from eval.episodes import run_episode
from eval.fault_scores import DETECTION_GRACE_S, FAULT_METRICS, fault_kind_metrics, fault_metrics, match_faults
from eval.fault_tables import (
    CONFUSION_COLUMNS,
    FAULT_COLUMNS,
    NO_FAULT,
    confusion_counts,
    confusion_rows,
    confusion_table,
    fault_rows,
    fault_summary,
    fault_table,
    sweep_fault_table,
    write_confusion_csv,
    write_fault_csv,
)

DT = 1e-3


def injected(kind: str, start_step: int, steps: int, joint: int | None = None, size: float = math.nan) -> InjectedFault:
    return InjectedFault(kind, start_step, steps, (start_step + 1) * DT, joint, size)


# An episode of known truth: a torque glitch on joint 1 at 0.101-0.106 s, detected 12 ms late; an encoder glitch at
# 0.301 s (1 step), detected 40 ms after it ended (within the grace), then reported again as a collision (a
# consequence); a collision at 0.501 s missed; a sensor_nan detected at 0.9 s with nothing under way (a false alarm).
INJECTED = [
    injected("torque_glitch", 100, 5, joint=1, size=30.0),
    injected("encoder_glitch", 300, 1, joint=0, size=0.01),
    injected("collision", 500, 20, size=200.0),
]
DETECTED = [
    DetectedFault("torque_glitch", 0.113, joint=1, magnitude=28.0),
    DetectedFault("encoder_glitch", 0.342, joint=0, magnitude=0.011),
    DetectedFault("collision", 0.343),
    DetectedFault("sensor_nan", 0.9, joint=2),
]


def test_matching_finds_detections_misses_consequences_and_false_alarms() -> None:
    episode = match_faults(INJECTED, DETECTED)
    assert [match.detection for match in episode.matches] == [DETECTED[0], DETECTED[1], None]
    assert episode.matches[0].latency_s == pytest.approx(0.012)
    assert episode.matches[1].latency_s == pytest.approx(0.041)
    assert math.isnan(episode.matches[2].latency_s)
    assert [(c.detection, c.after) for c in episode.consequences] == [(DETECTED[2], INJECTED[1])]
    assert episode.false_alarms == (DETECTED[3],)
    assert (episode.detected, episode.missed) == (2, 1)


def test_a_detection_matches_within_the_fault_and_its_grace_only() -> None:
    fault = injected("slip", 99, 10)  # acts from 0.100 s, ends at 0.110 s
    end = 0.110
    for time, matched in (
        (0.100, True),  # on the first affected observation: latency 0
        (0.099, False),  # before it: a false alarm
        (end + DETECTION_GRACE_S, True),
        (end + DETECTION_GRACE_S + 1e-3, False),
    ):
        episode = match_faults([fault], [DetectedFault("slip", time)])
        assert (episode.detected == 1) is matched
        assert len(episode.false_alarms) == (0 if matched else 1)
    # The wrong kind at the right time is a consequence; the fault is missed.
    episode = match_faults([fault], [DetectedFault("collision", 0.105)])
    assert (episode.missed, len(episode.consequences), len(episode.false_alarms)) == (1, 1, 0)


def test_each_fault_takes_its_earliest_detection_and_a_detection_serves_one_fault() -> None:
    first, second = injected("encoder_glitch", 100, 1, joint=0), injected("encoder_glitch", 110, 1, joint=0)
    late, early = DetectedFault("encoder_glitch", 0.115), DetectedFault("encoder_glitch", 0.105)
    episode = match_faults([second, first], [late, early])  # the order given is kept, matching goes by start
    assert [match.detection for match in episode.matches] == [late, early]
    assert [match.injected for match in episode.matches] == [second, first]
    # One detection for two faults: the earlier fault has it, the later one is missed.
    episode = match_faults([first, second], [late])
    assert [match.detection for match in episode.matches] == [late, None]
    # A repeated report of a detected fault is a consequence.
    episode = match_faults([first], [early, late])
    assert episode.matches[0].detection == early and [c.detection for c in episode.consequences] == [late]


def test_fault_metrics_count_and_time_the_episode() -> None:
    columns = fault_metrics(match_faults(INJECTED, DETECTED))
    assert tuple(columns) == FAULT_METRICS
    assert columns == {
        "faults_injected": 3,
        "faults_detected": 2,
        "faults_missed": 1,
        "faults_latent": 0,
        "detections": 4,
        "false_alarms": 1,
        "fault_consequences": 1,
        "detection_latency_median_ms": pytest.approx(26.5),
        "detection_latency_max_ms": pytest.approx(41.0),
    }
    empty = fault_metrics(match_faults([], []))
    assert empty["faults_injected"] == empty["detections"] == 0
    assert math.isnan(empty["detection_latency_median_ms"]) and math.isnan(empty["detection_latency_max_ms"])


def test_fault_rows_and_csv(tmp_path: Path) -> None:
    identity = {"controller": "MId+F+R+RLS+PD", "key": "mid_f_rls", "episode": 2, "seed": 7}
    rows = fault_rows(identity, match_faults(INJECTED, DETECTED))
    assert [row["outcome"] for row in rows] == ["detected", "detected", "missed", "consequence", "false_alarm"]
    assert all(tuple(row) == FAULT_COLUMNS for row in rows)
    hit, _, miss, consequence, alarm = rows
    assert hit["kind"] == hit["detected_kind"] == "torque_glitch"
    assert (hit["injected_at_s"], hit["detected_at_s"]) == (pytest.approx(0.101), 0.113)
    assert (hit["latency_ms"], hit["joint"], hit["size"], hit["magnitude"]) == (pytest.approx(12.0), 1, 30.0, 28.0)
    assert miss["detected_at_s"] is None and miss["latency_ms"] is None and miss["kind"] == "collision"
    assert (consequence["kind"], consequence["detected_kind"]) == ("encoder_glitch", "collision")
    assert consequence["magnitude"] is None  # NaN is a blank cell
    assert alarm["injected_at_s"] is None and alarm["kind"] == alarm["detected_kind"] == "sensor_nan"
    assert alarm["detected_joint"] == 2 and alarm["joint"] is None and alarm["ended_at_s"] is None
    assert hit["ended_at_s"] == pytest.approx(0.106)  # 5 steps of 1 ms from 0.101 s
    assert {row["seed"] for row in rows} == {7}

    path = write_fault_csv(tmp_path / "faults.csv", rows)
    with path.open() as file:
        read = list(csv.DictReader(file))
    assert tuple(read[0]) == FAULT_COLUMNS and len(read) == 5
    assert read[2]["detected_at_s"] == "" and read[4]["injected_at_s"] == ""
    # Without faults the file still has its header.
    empty = write_fault_csv(tmp_path / "empty.csv", [])
    assert empty.read_text().strip() == ",".join(FAULT_COLUMNS)
    # The summary reads the rows back from the file as it reads them in memory.
    assert fault_summary(read) == fault_summary(rows)


def test_fault_summary_per_controller_and_kind() -> None:
    a = fault_rows({"controller": "A"}, match_faults(INJECTED, DETECTED))
    late = [DetectedFault("torque_glitch", 0.131), DetectedFault("encoder_glitch", 0.302)]
    b = fault_rows({"controller": "B"}, match_faults(INJECTED[:2], late))
    summary = fault_summary(a + b, controllers=["C", "B"])
    assert [(entry.controller, entry.kind) for entry in summary] == [
        ("C", None),  # asked for, no rows: zeros
        ("B", "encoder_glitch"),  # in the order of FAULT_KINDS
        ("B", "torque_glitch"),
        ("B", None),
        ("A", "encoder_glitch"),
        ("A", "sensor_nan"),
        ("A", "torque_glitch"),
        ("A", "collision"),
        ("A", None),
    ]
    by = {(entry.controller, entry.kind): entry for entry in summary}
    assert by["C", None].injected == 0 and math.isnan(by["C", None].latency_median_ms)
    total_b = by["B", None]
    assert (total_b.injected, total_b.detected, total_b.missed, total_b.false_alarms) == (2, 2, 0, 0)
    assert total_b.latency_median_ms == pytest.approx(0.5 * (30.0 + 1.0))
    assert total_b.latency_max_ms == pytest.approx(30.0)
    total_a = by["A", None]
    assert (total_a.injected, total_a.detected, total_a.missed) == (3, 2, 1)
    assert (total_a.false_alarms, total_a.consequences) == (1, 1)
    assert total_a.latency_median_ms == pytest.approx(26.5) and total_a.latency_max_ms == pytest.approx(41.0)
    assert by["A", "sensor_nan"].false_alarms == 1 and by["A", "sensor_nan"].injected == 0
    assert by["A", "encoder_glitch"].consequences == 1  # the collision report that followed the encoder glitch
    assert (by["A", "collision"].injected, by["A", "collision"].missed) == (1, 1)

    table = fault_table(a, ["A"]).splitlines()
    assert table[0].startswith("| Controller | Fault kind | Injected | Detected | Missed |")
    assert table[-1] == "| A | all | 3 | 2 | 1 | 0 | 26.5 | 41.0 | 1 | 1 |"
    assert "| A | collision | 1 | 0 | 1 | 0 | n/a | n/a | 0 | 0 |" in table


class ReportingPD(PDController):
    """A PD controller that "detects" a fault on its third observation: a stand-in for a monitor."""

    def __init__(self) -> None:
        super().__init__()
        self.detected_faults: list[DetectedFault] = []
        self._calls = 0

    def reset(self) -> None:
        super().reset()
        self.detected_faults = []
        self._calls = 0

    def __call__(self, observation):
        self._calls += 1
        if self._calls == 3:
            self.detected_faults.append(DetectedFault("collision", 2 * DT, magnitude=50.0))
        return super().__call__(observation)


def test_run_episode_records_injected_and_detected_faults() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    truth = injected("collision", 1, 3, size=80.0)
    original_step = env.step

    def step(action):  # the env's injection, faked: the truth appears as the fault starts
        if env._step_index == truth.start_step:
            env.injected_faults.append(truth)
        return original_step(action)

    env.step = step
    controller = ReportingPD()
    assert isinstance(controller, ReportsFaults) and not isinstance(PDController(), ReportsFaults)
    record = run_episode(env, controller, seed=3, payload_masses=[0.5])
    assert record.injected_faults == [truth]
    assert record.detected_faults == [DetectedFault("collision", 2 * DT, magnitude=50.0)]
    assert record.detected_faults is not controller.detected_faults  # a copy
    scores = record.metrics()
    assert (scores["faults_injected"], scores["faults_detected"], scores["false_alarms"]) == (1, 1, 0)
    assert scores["detection_latency_max_ms"] == pytest.approx(0.0)
    # The next episode starts without the last one's faults.
    env.step = original_step
    plain = run_episode(env, PDController(), seed=3, payload_masses=[0.5])
    assert plain.injected_faults == [] and plain.detected_faults == []
    assert np.isnan(plain.metrics()["detection_latency_median_ms"])


def test_the_comparison_summary_has_a_faults_section_only_with_faults() -> None:
    from eval.comparison.report import fault_section

    assert fault_section([], ["PD"]) == []
    rows = fault_rows({"controller": "A"}, match_faults(INJECTED, DETECTED))
    section = fault_section(rows, ["PD", "A"])
    assert section[0] == "## Faults" and "50 ms after its end" in section[2]
    table = section[4].splitlines()
    assert table[2] == "| PD | all | 0 | 0 | 0 | 0 | n/a | n/a | 0 | 0 |"  # a controller without faults is listed
    assert table[-1] == "| A | all | 3 | 2 | 1 | 0 | 26.5 | 41.0 | 1 | 1 |"
    matrix = section[8].splitlines()
    assert section[6].startswith("Confusion matrix") and matrix[0].startswith("| Controller | Injected \\ detected |")
    assert "| A | encoder_glitch | 1 | 0 | 0 | 1 | 0 | 1 |  |" in matrix
    assert "| A | none | 0 | 1 | 0 | 0 |  |  |  |" in matrix and "| PD | none | 0 | 0 | 0 | 0 |  |  |  |" in matrix


def test_a_sweeps_fault_table_counts_per_controller_and_kind() -> None:
    slip = InjectedFault("slip", 100, 50, 0.101, size=2.0)
    glitch = InjectedFault("encoder_glitch", 200, 1, 0.201, joint=1, size=0.01)
    found = match_faults([slip, glitch], [DetectedFault("slip", 0.108), DetectedFault("collision", 0.9)])
    row = {"controller": "mid_f_rls", **fault_metrics(found), **fault_kind_metrics(found)}
    assert (row["slip_injected"], row["slip_detected"], row["slip_latency_max_ms"]) == (1, 1, pytest.approx(7.0))
    assert (row["encoder_glitch_injected"], row["encoder_glitch_detected"]) == (1, 0)
    failed = {**dict.fromkeys(row, math.nan), "controller": "mid_f_rls"}
    table = sweep_fault_table([row, row, failed], {"mid_f_rls": "RLS"})
    assert "| RLS | slip | 2 | 2 | 0 | 7.0 |" in table
    assert "| RLS | encoder_glitch | 2 | 0 | 2 | n/a |" in table
    assert "| RLS | false alarms |  | 2 |  |  |" in table
    assert sweep_fault_table([failed], {"mid_f_rls": "RLS"}) == ""


# -- the confusion matrix ---------------------------------------------------------------------------


def test_a_slip_raised_after_a_collision_is_a_slip_detected_for_the_collision() -> None:
    push = injected("collision", 200, 30, size=300.0)  # acts 0.201-0.231 s; its window ends at 0.281 s
    reports = [
        DetectedFault("collision", 0.205),
        DetectedFault("slip", 0.214),  # the push taken for a slip
        DetectedFault("slip", 0.250),  # and reported again: one fault, counted once per kind
        DetectedFault("slip", 0.600),  # nothing under way: a false alarm
    ]
    rows = fault_rows({"controller": "A"}, match_faults([push], reports))
    (matrix,) = confusion_counts(rows)
    assert dict(matrix.counts) == {("collision", "collision"): 1, ("collision", "slip"): 1, (NO_FAULT, "slip"): 1}
    assert (dict(matrix.scored), dict(matrix.latent)) == ({"collision": 1}, {})
    # Taken for a slip only, the push is off the diagonal and not in the column of faults without detection.
    (only_slip,) = confusion_counts(fault_rows({"controller": "A"}, match_faults([push], reports[1:2])))
    assert dict(only_slip.counts) == {("collision", "slip"): 1}
    (unseen,) = confusion_counts(fault_rows({"controller": "A"}, match_faults([push], [])))
    assert dict(unseen.counts) == {("collision", NO_FAULT): 1}


def test_a_latent_drive_fault_is_neither_detected_nor_missed() -> None:
    kept = InjectedFault("drive_fault", 300, 50, 0.301, joint=1, size=0.3, detail="peak", withheld=0.0)
    lost = InjectedFault("drive_fault", 600, 50, 0.601, joint=2, size=0.01, detail="command", withheld=12.0)
    during = DetectedFault("drive_fault", 0.320, joint=1)  # while the latent one "acts": nothing happened
    episode = match_faults([kept, lost], [during])
    assert [match.injected for match in episode.matches] == [lost] and episode.latent == (kept,)
    assert (episode.detected, episode.missed, episode.false_alarms) == (0, 1, (during,))
    counts = fault_metrics(episode)
    assert (counts["faults_injected"], counts["faults_missed"], counts["faults_latent"]) == (2, 1, 1)
    rows = fault_rows({"controller": "A"}, episode)
    assert [row["outcome"] for row in rows] == ["missed", "latent", "false_alarm"]
    assert (rows[0]["withheld_nm"], rows[1]["withheld_nm"], rows[2]["withheld_nm"]) == (12.0, 0.0, None)
    (matrix,) = confusion_counts(rows)
    assert dict(matrix.counts) == {("drive_fault", NO_FAULT): 1, (NO_FAULT, "drive_fault"): 1}
    assert (dict(matrix.scored), dict(matrix.latent)) == ({"drive_fault": 1}, {"drive_fault": 1})
    drive = next(entry for entry in fault_summary(rows) if entry.kind == "drive_fault")
    assert (drive.injected, drive.detected, drive.missed, drive.latent, drive.false_alarms) == (2, 0, 1, 1, 1)
    # Only a drive fault can be latent, and only one that withheld nothing (NaN: not recorded).
    assert match_faults([replace(kept, withheld=0.5)], []).missed == 1
    assert match_faults([replace(kept, withheld=math.nan)], []).missed == 1
    assert match_faults([replace(kept, kind="collision")], []).missed == 1


def test_the_confusion_matrix_in_memory_read_back_and_as_a_table(tmp_path: Path) -> None:
    rows = [
        *fault_rows({"controller": "A", "episode": 0}, match_faults(INJECTED, DETECTED)),
        *fault_rows({"controller": "A", "episode": 1}, match_faults(INJECTED, DETECTED)),
        *fault_rows({"controller": "B", "episode": 0}, match_faults([], [DetectedFault("slip", 0.5)])),
    ]
    matrices = confusion_counts(rows, ["B", "C"])
    assert [matrix.controller for matrix in matrices] == ["B", "C", "A"]
    b, c, a = matrices
    assert dict(a.counts) == {
        ("torque_glitch", "torque_glitch"): 2,
        ("encoder_glitch", "encoder_glitch"): 2,
        ("encoder_glitch", "collision"): 2,  # the collision report after the encoder glitch
        ("collision", NO_FAULT): 2,  # missed
        (NO_FAULT, "sensor_nan"): 2,  # the false alarms
    }
    assert dict(b.counts) == {(NO_FAULT, "slip"): 1} and not c.counts and not c.scored
    write_fault_csv(tmp_path / "faults.csv", rows)
    with (tmp_path / "faults.csv").open() as file:
        assert confusion_counts(list(csv.DictReader(file)), ["B", "C"]) == matrices
    cells = confusion_rows(matrices)
    kinds = 5  # slip, encoder_glitch, sensor_nan, torque_glitch, collision occur; then none
    assert len(cells) == 3 * ((kinds + 1) ** 2 - 1) and all(tuple(cell) == CONFUSION_COLUMNS for cell in cells)
    assert {"controller": "A", "injected_kind": "encoder_glitch", "detected_kind": "collision", "count": 2} in cells
    with write_confusion_csv(tmp_path / "confusion.csv", matrices).open() as file:
        assert sum(int(row["count"]) for row in csv.DictReader(file)) == 2 * 5 + 1
    table = confusion_table(matrices).splitlines()
    assert table[0] == (
        "| Controller | Injected \\ detected | slip | encoder_glitch | sensor_nan | torque_glitch | collision | none "
        "| Scored | Latent |"
    )
    assert table[2:] == [
        "| B | none | 1 | 0 | 0 | 0 | 0 |  |  |  |",
        "| C | none | 0 | 0 | 0 | 0 | 0 |  |  |  |",
        "| A | encoder_glitch | 0 | 2 | 0 | 0 | 2 | 0 | 2 |  |",
        "| A | torque_glitch | 0 | 0 | 0 | 2 | 0 | 0 | 2 |  |",
        "| A | collision | 0 | 0 | 0 | 0 | 0 | 2 | 2 |  |",
        "| A | none | 0 | 0 | 2 | 0 | 0 |  |  |  |",
    ]


@pytest.mark.parametrize("seed", range(4))
def test_a_drive_fault_is_latent_exactly_when_every_command_stayed_within_what_the_drive_kept(seed: int) -> None:
    """Against the fault-free twin's commands: a drive fault is latent iff the twin never asked its joint for more than
    the fault kept over its steps (the episodes agree until it first does); never sized on the command (the default)."""
    twin = run_episode(DeltaPickPlaceEnv(n_cycles=1), PDController(), seed=seed)
    for relative_to, size in (("peak", None), ("peak", (0.0, 0.05)), ("command", None)):
        spec = FaultSpec("drive_fault", relative_to=relative_to, size=size)
        record = run_episode(DeltaPickPlaceEnv(n_cycles=1, faults=[spec]), PDController(), seed=seed)
        (fault,) = record.injected_faults
        asked = np.abs(twin.command[fault.start_step : fault.start_step + fault.steps, fault.joint])
        kept = fault.size * record.peak_torque
        over = np.flatnonzero(asked > kept)
        assert is_latent(fault) == (over.size == 0)
        if over.size:  # the episodes agree up to the first step the fault clips, which withholds the twin's excess
            assert fault.withheld >= asked[over[0]] - kept - 1e-9
        if relative_to == "command":
            assert fault.withheld >= 0.5 * asked[0] > 0.0  # the default keeps at most half of the onset's command
        scored = match_faults(record.injected_faults, [])
        assert (scored.missed, len(scored.latent)) == ((0, 1) if is_latent(fault) else (1, 0))
