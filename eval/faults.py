"""Faults of the evaluation: the injected truth against what a controller detected (docs/design.md section 8).

Pure functions of an episode's :class:`~delta_env.faults.InjectedFault` and
:class:`~controllers.monitor.DetectedFault` lists (:attr:`eval.episodes.EpisodeRecord.injected_faults` and
``detected_faults``), and of the rows they give.

Matching (:func:`match_faults`). An injected fault acts from ``start_s`` (its first affected observation) to its
end ``start_s + steps * dt``. A detection *matches* it if it is of the same kind and its time lies in
``[start_s, end + grace]`` (:data:`DETECTION_GRACE_S`). The injected faults are taken in order of their start,
each matching its earliest matching detection not already matched by an earlier fault (a detection is one fault's
at most). Every other detection is either

- a *consequence*, if it lies in the window ``[start_s, end + grace]`` of some injected fault of any kind (a
  collision detected while a drive fault slows a joint, a second report of the same slip): the system did see
  something wrong, just not, or not only, as what it was; counted apart, never as a false alarm;
- or a *false alarm*: it came when nothing was wrong (no injected fault, nor its grace, was under way).

An injected fault with no matching detection is *missed*. The latency of a detected fault is the detection's
time minus the fault's start (s; the tables give ms); a detection on the first affected observation has latency 0.

Tables: :func:`fault_rows` (the rows of ``faults.csv``, :data:`FAULT_COLUMNS`), :func:`fault_summary` (per
controller and kind), :func:`fault_table` (that summary as Markdown) and :func:`fault_metrics` (the flat
per-episode columns :data:`FAULT_METRICS` of ``episodes.csv`` and of a sweep's ``results.csv``).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controllers.monitor import DetectedFault
from delta_env.faults import FAULT_KINDS, InjectedFault
from delta_env.sensors import CONTROL_PERIOD
from eval import metrics

DETECTION_GRACE_S = 0.05
"""How long after an injected fault has ended (s) a detection still counts as its own: 50 ms.

A monitor recognizes a fault by its effect on what the controller sees, and that effect can outlast the fault:
a one-step encoder glitch or torque pulse kicks the arm, whose tracking error and torque residual decay over
the loop's closed-loop time constants (tens of ms at the PD gains); an observer or a windowed test (a
disturbance observer, a CUSUM over a few tens of samples) confirms a short fault only after it has gone; the
current loop (0.5 to 2 ms) delays the drive's response further. 50 ms covers a few such time constants, so a
monitor is not charged a miss and a false alarm for a late but correct detection of a short fault. It is short
against the moves (a carry lasts a few hundred ms at 3 g) and the payload's settling deadline
(:data:`eval.metrics.SETTLING_DEADLINE_MS`, 150 ms), so a detection well after a fault, when the robot has been
running normally again, is a false alarm, not a late detection."""

TIME_TOLERANCE_S = 1e-6
"""Slack (s) on the window's ends for times computed as ``steps * dt`` in different ways; far below a step."""

OUTCOMES = ("detected", "missed", "consequence", "false_alarm")
"""The ``outcome`` of a row of ``faults.csv``: an injected fault detected or missed, or a detection that matched
no injected fault: a consequence of one (during it or its grace) or a false alarm."""

FAULT_COLUMNS = (
    "controller",
    "key",
    "episode",
    "seed",
    "outcome",
    "kind",
    "injected_at_s",
    "detected_at_s",
    "latency_ms",
    "joint",
    "size",
    "detail",
    "detected_kind",
    "detected_joint",
    "magnitude",
    "ended_at_s",
)
"""Columns of ``faults.csv``, one row per injected fault and per detection that matched none:

- ``controller``, ``key``, ``episode``, ``seed``: the episode (as in ``episodes.csv``);
- ``outcome``: one of :data:`OUTCOMES`;
- ``kind``: the injected fault's kind; for a false alarm, the detected kind;
- ``injected_at_s``: the injected fault's start (s from the reset); for a consequence, the start of the fault it
  followed (the latest to start whose window holds it); blank for a false alarm;
- ``detected_at_s``: the detection's time (s); blank for a miss;
- ``latency_ms``: ``detected_at_s - injected_at_s`` (ms); blank for a miss or a false alarm;
- ``joint``, ``size``, ``detail``: the injected fault's (:class:`~delta_env.faults.InjectedFault`); blank for a
  false alarm or where the fault has none;
- ``detected_kind``, ``detected_joint``, ``magnitude``: the detection's (:class:`~controllers.monitor.
  DetectedFault`); blank for a miss or where it has none;
- ``ended_at_s``: the injected fault's end (s from the reset, :func:`fault_end_s`; a slip's is the end of its carry);
  blank for a false alarm.
"""

FAULT_METRICS = (
    "faults_injected",
    "faults_detected",
    "faults_missed",
    "detections",
    "false_alarms",
    "fault_consequences",
    "detection_latency_median_ms",
    "detection_latency_max_ms",
)
"""Flat fault columns of an episode (:func:`fault_metrics`): injected faults, those detected and missed
(detected + missed = injected), every detection the controller reported (detections = detected + false alarms +
consequences), and the median and worst latency of the detected ones (ms; NaN if none was)."""


def fault_end_s(fault: InjectedFault, dt: float = CONTROL_PERIOD) -> float:
    """The end of an injected fault (s): ``start_s + steps * dt``."""
    return fault.start_s + fault.steps * dt


@dataclass(frozen=True)
class FaultMatch:
    """An injected fault and the detection matched to it (None: missed)."""

    injected: InjectedFault
    detection: DetectedFault | None

    @property
    def latency_s(self) -> float:
        """Detection time minus the fault's start (s); NaN if missed."""
        return math.nan if self.detection is None else self.detection.time_s - self.injected.start_s


@dataclass(frozen=True)
class Consequence:
    """A detection that matched no injected fault but came during one (or its grace): ``after`` is the latest to
    start of the faults whose window holds it."""

    detection: DetectedFault
    after: InjectedFault


@dataclass(frozen=True)
class EpisodeFaults:
    """The matching of one episode (:func:`match_faults`).

    Attributes:
        matches: One per injected fault, in the order given.
        consequences: The unmatched detections within some injected fault's window, in time order.
        false_alarms: The other detections, in time order.
    """

    matches: tuple[FaultMatch, ...]
    consequences: tuple[Consequence, ...]
    false_alarms: tuple[DetectedFault, ...]

    @property
    def detected(self) -> int:
        """Injected faults detected."""
        return sum(match.detection is not None for match in self.matches)

    @property
    def missed(self) -> int:
        """Injected faults missed."""
        return len(self.matches) - self.detected


def match_faults(
    injected: Sequence[InjectedFault],
    detected: Sequence[DetectedFault],
    *,
    dt: float = CONTROL_PERIOD,
    grace_s: float = DETECTION_GRACE_S,
) -> EpisodeFaults:
    """Match one episode's detections to its injected faults (the rules are in the module docstring).

    Args:
        injected: The truth, :attr:`EpisodeRecord.injected_faults`.
        detected: What the controller detected, :attr:`EpisodeRecord.detected_faults`.
        dt: Control period (s): a fault lasts ``steps * dt``.
        grace_s: How long after its end a detection still counts as a fault's (s).
    """
    detections = sorted(range(len(detected)), key=lambda n: detected[n].time_s)
    windows = [
        (fault.start_s - TIME_TOLERANCE_S, fault_end_s(fault, dt) + grace_s + TIME_TOLERANCE_S) for fault in injected
    ]
    used: set[int] = set()
    found: dict[int, FaultMatch] = {}
    for i in sorted(range(len(injected)), key=lambda i: (injected[i].start_s, i)):
        low, high = windows[i]
        match = next(
            (
                n
                for n in detections
                if n not in used and detected[n].kind == injected[i].kind and low <= detected[n].time_s <= high
            ),
            None,
        )
        if match is not None:
            used.add(match)
        found[i] = FaultMatch(injected[i], None if match is None else detected[match])
    consequences, false_alarms = [], []
    for n in detections:
        if n in used:
            continue
        time = detected[n].time_s
        during = [i for i, (low, high) in enumerate(windows) if low <= time <= high]
        if during:
            after = max(during, key=lambda i: (injected[i].start_s, i))
            consequences.append(Consequence(detected[n], injected[after]))
        else:
            false_alarms.append(detected[n])
    return EpisodeFaults(tuple(found[i] for i in range(len(injected))), tuple(consequences), tuple(false_alarms))


def fault_metrics(episode: EpisodeFaults) -> dict[str, Any]:
    """The flat fault columns of one episode, :data:`FAULT_METRICS`."""
    latencies = [1e3 * match.latency_s for match in episode.matches if match.detection is not None]
    return {
        "faults_injected": len(episode.matches),
        "faults_detected": episode.detected,
        "faults_missed": episode.missed,
        "detections": episode.detected + len(episode.consequences) + len(episode.false_alarms),
        "false_alarms": len(episode.false_alarms),
        "fault_consequences": len(episode.consequences),
        "detection_latency_median_ms": float(np.median(latencies)) if latencies else math.nan,
        "detection_latency_max_ms": max(latencies) if latencies else math.nan,
    }


FAULT_KIND_METRICS = tuple(
    f"{kind}_{what}" for kind in FAULT_KINDS for what in ("injected", "detected", "latency_max_ms")
)
"""Per fault kind, the columns of a sweep's row: faults of the kind injected, those detected, and the worst latency
of the detected ones (ms; NaN if none)."""


def fault_kind_metrics(episode: EpisodeFaults) -> dict[str, Any]:
    """The :data:`FAULT_KIND_METRICS` of one episode."""
    columns: dict[str, Any] = {}
    for kind in FAULT_KINDS:
        mine = [match for match in episode.matches if match.injected.kind == kind]
        latencies = [1e3 * match.latency_s for match in mine if match.detection is not None]
        columns[f"{kind}_injected"] = len(mine)
        columns[f"{kind}_detected"] = len(latencies)
        columns[f"{kind}_latency_max_ms"] = max(latencies) if latencies else math.nan
    return columns


def sweep_fault_table(rows: Sequence[Mapping[str, Any]], labels: Mapping[str, str]) -> str:
    """Per controller (``labels``: key -> label) and fault kind, from a sweep's rows: injected, detected, missed and
    the worst latency; and per controller the false alarms. Empty when no row injected or detected a fault."""
    body = []
    for key, label in labels.items():
        mine = [row for row in rows if row["controller"] == key]
        for kind in FAULT_KINDS:
            injected = _count(mine, f"{kind}_injected")
            if injected == 0:
                continue
            detected = _count(mine, f"{kind}_detected")
            worst = [_number(row[f"{kind}_latency_max_ms"]) for row in mine]
            worst = [value for value in worst if math.isfinite(value)]
            latency = _latency(max(worst, default=math.nan))
            body.append([label, kind, str(injected), str(detected), str(injected - detected), latency])
        alarms = _count(mine, "false_alarms")
        if alarms:
            body.append([label, "false alarms", "", str(alarms), "", ""])
    if not body:
        return ""
    header = ["Controller", "Fault kind", "Injected", "Detected", "Missed", "Latency max (ms)"]
    return metrics.markdown_table(header, body)


def _count(rows: Sequence[Mapping[str, Any]], column: str) -> int:
    """The sum of a count column over rows; a failed episode's blank or NaN counts nothing."""
    values = (_number(row[column]) for row in rows)
    return int(sum(value for value in values if math.isfinite(value)))


def _blank_nan(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else value


def _injected_cells(fault: InjectedFault) -> dict[str, Any]:
    return {
        "kind": fault.kind,
        "injected_at_s": fault.start_s,
        "ended_at_s": fault_end_s(fault),
        "joint": fault.joint,
        "size": _blank_nan(fault.size),
        "detail": fault.detail or None,
    }


def _detected_cells(detection: DetectedFault) -> dict[str, Any]:
    return {
        "detected_at_s": detection.time_s,
        "detected_kind": detection.kind,
        "detected_joint": detection.joint,
        "magnitude": _blank_nan(detection.magnitude),
    }


def fault_rows(identity: Mapping[str, Any], episode: EpisodeFaults) -> list[dict[str, Any]]:
    """The rows of ``faults.csv`` of one episode (:data:`FAULT_COLUMNS`; None is a blank cell): one per injected
    fault (in the order given), then one per consequence and per false alarm (in time order).

    Args:
        identity: The episode's ``controller``, ``key``, ``episode`` and ``seed`` (missing ones blank).
        episode: Its matching (:func:`match_faults`).
    """
    base = {column: identity.get(column) for column in FAULT_COLUMNS[:4]}
    blank = dict.fromkeys(FAULT_COLUMNS[4:])
    rows = []
    for match in episode.matches:
        row = {**base, **blank, "outcome": "missed", **_injected_cells(match.injected)}
        if match.detection is not None:
            row.update(outcome="detected", latency_ms=1e3 * match.latency_s, **_detected_cells(match.detection))
        rows.append(row)
    events = [(c.detection, c.after) for c in episode.consequences] + [(d, None) for d in episode.false_alarms]
    for detection, after in sorted(events, key=lambda event: event[0].time_s):
        row = {**base, **blank, **_detected_cells(detection)}
        if after is None:
            row.update(outcome="false_alarm", kind=detection.kind)
        else:
            row.update(
                outcome="consequence", latency_ms=1e3 * (detection.time_s - after.start_s), **_injected_cells(after)
            )
        rows.append(row)
    return rows


def write_fault_csv(path: str | Path, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write ``faults.csv``: the header :data:`FAULT_COLUMNS` (also with no rows), then the rows (None blank)."""
    path = Path(path)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=FAULT_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return path


def _number(value: Any) -> float:
    """A cell as a float: NaN for a blank (None or ``""``, as read back from a CSV file)."""
    return math.nan if value is None or value == "" else float(value)


@dataclass(frozen=True)
class FaultSummary:
    """One row of the fault summary: a controller's faults of one kind (``kind`` None: all kinds).

    Attributes:
        controller: The controller's label.
        kind: The fault kind, or None for the controller's totals.
        injected: Injected faults of the kind.
        detected: Those detected (matched).
        missed: Those missed.
        latency_median_ms: Median latency of the detected ones (ms), NaN if none.
        latency_max_ms: Worst latency of the detected ones (ms), NaN if none.
        false_alarms: False alarms detected as this kind (all kinds for the totals).
        consequences: Consequences of faults of this kind (all for the totals).
    """

    controller: str
    kind: str | None
    injected: int
    detected: int
    missed: int
    latency_median_ms: float
    latency_max_ms: float
    false_alarms: int
    consequences: int


def _summarize(controller: str, kind: str | None, rows: Sequence[Mapping[str, Any]]) -> FaultSummary:
    outcomes = [row["outcome"] for row in rows]
    latencies = [_number(row["latency_ms"]) for row in rows if row["outcome"] == "detected"]
    return FaultSummary(
        controller=controller,
        kind=kind,
        injected=outcomes.count("detected") + outcomes.count("missed"),
        detected=outcomes.count("detected"),
        missed=outcomes.count("missed"),
        latency_median_ms=float(np.median(latencies)) if latencies else math.nan,
        latency_max_ms=max(latencies) if latencies else math.nan,
        false_alarms=outcomes.count("false_alarm"),
        consequences=outcomes.count("consequence"),
    )


def fault_summary(rows: Sequence[Mapping[str, Any]], controllers: Sequence[str] = ()) -> list[FaultSummary]:
    """Per controller: a row per fault kind that occurs in its rows (in :data:`FAULT_KINDS` order, other kinds after),
    then its totals (``kind`` None).

    Args:
        rows: Rows of ``faults.csv`` (:func:`fault_rows`, or as read back: blanks ``""``).
        controllers: Labels in the order wanted; each gets its totals even without rows (no fault and no
            detection). Controllers only in ``rows`` follow in first-seen order.
    """
    groups = metrics.group_by(rows, "controller")
    order = list(dict.fromkeys([*controllers, *groups]))
    summary = []
    for controller in order:
        group = groups.get(controller, [])
        seen = {row["kind"] for row in group}
        kinds = [kind for kind in FAULT_KINDS if kind in seen] + sorted(seen - set(FAULT_KINDS))
        by_kind = metrics.group_by(group, "kind")
        summary += [_summarize(str(controller), kind, by_kind[kind]) for kind in kinds]
        summary.append(_summarize(str(controller), None, group))
    return summary


def _latency(value: float) -> str:
    return f"{value:.1f}" if math.isfinite(value) else "n/a"


def fault_table(rows: Sequence[Mapping[str, Any]], controllers: Sequence[str] = ()) -> str:
    """:func:`fault_summary` as a Markdown table: per controller, a line per fault kind and one of its totals."""
    header = [
        "Controller",
        "Fault kind",
        "Injected",
        "Detected",
        "Missed",
        "Latency median (ms)",
        "Latency max (ms)",
        "False alarms",
        "Consequences",
    ]
    body = [
        [
            entry.controller,
            entry.kind or "all",
            str(entry.injected),
            str(entry.detected),
            str(entry.missed),
            _latency(entry.latency_median_ms),
            _latency(entry.latency_max_ms),
            str(entry.false_alarms),
            str(entry.consequences),
        ]
        for entry in fault_summary(rows, controllers)
    ]
    return metrics.markdown_table(header, body)
