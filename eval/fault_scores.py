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

A *latent* fault (:func:`delta_env.faults.is_latent`: a drive fault whose every command stayed within what the drive
kept) changed nothing the robot did, so nothing could see it: it is neither detected nor missed, takes no detection
and opens no window, and a detection during it is a false alarm. The truth of that is the env's record of what the
drive withheld (:attr:`~delta_env.faults.InjectedFault.withheld`).

The confusion matrix (:func:`confusion_counts`, :func:`confusion_table`, ``confusion.csv``) gives, per controller,
injected kind by detected kind. Cell (i, d) counts the injected faults of kind i that the controller reported,
within the fault's window, at least once as kind d: its matching detection (the diagonal) and its consequences
(off it: a slip raised after a collision is a slip detected for an injected collision). A fault reported as its
kind and as another counts in both cells, so a row can add up to more than its faults; column
:data:`NO_FAULT` counts the faults with no detection at all in their window (missed and unreported), row
:data:`NO_FAULT` the false alarms by detected kind.

Tables: :func:`fault_rows` (the rows of ``faults.csv``, :data:`FAULT_COLUMNS`), :func:`fault_summary` (per
controller and kind), :func:`fault_table` (that summary as Markdown), the confusion matrix from those rows
(:func:`confusion_counts`, :func:`confusion_rows` for ``confusion.csv``, :func:`confusion_table`) and
:func:`fault_metrics` (the flat per-episode columns :data:`FAULT_METRICS` of ``episodes.csv`` and of a sweep's
``results.csv``).
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
from delta_env.faults import FAULT_KINDS, InjectedFault, is_latent
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

OUTCOMES = ("detected", "missed", "latent", "consequence", "false_alarm")
"""The ``outcome`` of a row of ``faults.csv``: an injected fault detected, missed or latent (it changed nothing, not
scored), or a detection that matched no injected fault: a consequence of one (during it or its grace) or a false
alarm."""

NO_FAULT = "none"
"""The confusion matrix's row of the detections when no fault was under way (false alarms) and its column of the
faults with no detection."""

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
    "withheld_nm",
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
  blank for a false alarm;
- ``withheld_nm``: for a drive fault, the most torque (N m) it withheld from the command (0: latent); else blank.
"""

FAULT_METRICS = (
    "faults_injected",
    "faults_detected",
    "faults_missed",
    "faults_latent",
    "detections",
    "false_alarms",
    "fault_consequences",
    "detection_latency_median_ms",
    "detection_latency_max_ms",
)
"""Flat fault columns of an episode (:func:`fault_metrics`): injected faults, those detected, missed and latent
(detected + missed + latent = injected), every detection the controller reported (detections = detected + false alarms +
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
        matches: One per scored (not latent) injected fault, in the order given.
        consequences: The unmatched detections within some scored fault's window, in time order.
        false_alarms: The other detections, in time order.
        latent: The latent injected faults (not scored), in the order given.
    """

    matches: tuple[FaultMatch, ...]
    consequences: tuple[Consequence, ...]
    false_alarms: tuple[DetectedFault, ...]
    latent: tuple[InjectedFault, ...] = ()

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
    latent = tuple(fault for fault in injected if is_latent(fault))
    injected = [fault for fault in injected if not is_latent(fault)]
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
    matches = tuple(found[i] for i in range(len(injected)))
    return EpisodeFaults(matches, tuple(consequences), tuple(false_alarms), latent)


def fault_metrics(episode: EpisodeFaults) -> dict[str, Any]:
    """The flat fault columns of one episode, :data:`FAULT_METRICS`."""
    latencies = [1e3 * match.latency_s for match in episode.matches if match.detection is not None]
    return {
        "faults_injected": len(episode.matches) + len(episode.latent),
        "faults_detected": episode.detected,
        "faults_missed": episode.missed,
        "faults_latent": len(episode.latent),
        "detections": episode.detected + len(episode.consequences) + len(episode.false_alarms),
        "false_alarms": len(episode.false_alarms),
        "fault_consequences": len(episode.consequences),
        "detection_latency_median_ms": float(np.median(latencies)) if latencies else math.nan,
        "detection_latency_max_ms": max(latencies) if latencies else math.nan,
    }


FAULT_KIND_METRICS = tuple(
    f"{kind}_{what}" for kind in FAULT_KINDS for what in ("injected", "detected", "latency_max_ms")
)
"""Per fault kind, the columns of a sweep's row: faults of the kind injected and scored (latent ones left out), those
detected, and the worst latency of the detected ones (ms; NaN if none)."""


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
        "withheld_nm": _blank_nan(fault.withheld),
    }


def _detected_cells(detection: DetectedFault) -> dict[str, Any]:
    return {
        "detected_at_s": detection.time_s,
        "detected_kind": detection.kind,
        "detected_joint": detection.joint,
        "magnitude": _blank_nan(detection.magnitude),
    }


def fault_rows(identity: Mapping[str, Any], episode: EpisodeFaults) -> list[dict[str, Any]]:
    """The rows of ``faults.csv`` of one episode (:data:`FAULT_COLUMNS`; None is a blank cell): one per scored
    injected fault (in the order given), one per latent one, then one per consequence and per false alarm (in time
    order).

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
    rows += [{**base, **blank, "outcome": "latent", **_injected_cells(fault)} for fault in episode.latent]
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
        injected: Injected faults of the kind: detected + missed + latent.
        detected: Those detected (matched).
        missed: Those missed.
        latent: Those latent (they changed nothing; not scored).
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
    latent: int
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
        injected=outcomes.count("detected") + outcomes.count("missed") + outcomes.count("latent"),
        detected=outcomes.count("detected"),
        missed=outcomes.count("missed"),
        latent=outcomes.count("latent"),
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
        "Latent",
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
            str(entry.latent),
            _latency(entry.latency_median_ms),
            _latency(entry.latency_max_ms),
            str(entry.false_alarms),
            str(entry.consequences),
        ]
        for entry in fault_summary(rows, controllers)
    ]
    return metrics.markdown_table(header, body)


CONFUSION_COLUMNS = ("controller", "injected_kind", "detected_kind", "count")
"""Columns of ``confusion.csv``: per controller, every cell of its confusion matrix (:func:`confusion_counts`), zeros
included; ``injected_kind`` or ``detected_kind`` :data:`NO_FAULT` for the row of false alarms and the column of
faults with no detection."""

_FAULT_IDENTITY = ("controller", "key", "episode", "seed", "kind", "injected_at_s", "joint", "detail")
"""The cells that name one injected fault in the rows of ``faults.csv``, shared by its own row and its consequences'."""


@dataclass(frozen=True)
class Confusion:
    """One controller's confusion matrix (:func:`confusion_counts`).

    Attributes:
        controller: The controller's label.
        counts: (injected kind, detected kind) -> count, :data:`NO_FAULT` for no fault or no detection; only the
            cells that are not zero.
        scored: Scored (not latent) injected faults per kind.
        latent: Latent injected faults per kind (not in the matrix).
    """

    controller: str
    counts: Mapping[tuple[str, str], int]
    scored: Mapping[str, int]
    latent: Mapping[str, int]


def _confusion(controller: str, rows: Sequence[Mapping[str, Any]]) -> Confusion:
    reported: dict[tuple[Any, ...], set[str]] = {}  # scored fault -> the kinds detected in its window
    counts: dict[tuple[str, str], int] = {}
    scored: dict[str, int] = {}
    latent: dict[str, int] = {}
    for row in rows:
        outcome, kind = row["outcome"], str(row["kind"])
        fault = tuple(row.get(column) for column in _FAULT_IDENTITY)
        if outcome == "latent":
            latent[kind] = latent.get(kind, 0) + 1
        elif outcome in ("detected", "missed"):
            scored[kind] = scored.get(kind, 0) + 1
            reported.setdefault(fault, set())
        if outcome in ("detected", "consequence"):
            reported.setdefault(fault, set()).add(str(row["detected_kind"]))
        elif outcome == "false_alarm":
            cell = (NO_FAULT, str(row["detected_kind"]))
            counts[cell] = counts.get(cell, 0) + 1
    for fault, kinds in reported.items():
        injected_kind = str(fault[_FAULT_IDENTITY.index("kind")])
        for detected_kind in kinds or {NO_FAULT}:
            cell = (injected_kind, detected_kind)
            counts[cell] = counts.get(cell, 0) + 1
    return Confusion(controller, counts, scored, latent)


def confusion_counts(rows: Sequence[Mapping[str, Any]], controllers: Sequence[str] = ()) -> list[Confusion]:
    """Per controller, its confusion matrix from the rows of ``faults.csv`` (the rules are in the module docstring).

    Args:
        rows: Rows of ``faults.csv`` (:func:`fault_rows`, or as read back: blanks ``""``).
        controllers: Labels in the order wanted; each gets its matrix even without rows. Controllers only in
            ``rows`` follow in first-seen order.
    """
    groups = metrics.group_by(rows, "controller")
    order = list(dict.fromkeys([*controllers, *groups]))
    return [_confusion(str(controller), groups.get(controller, [])) for controller in order]


def _confusion_kinds(matrices: Sequence[Confusion]) -> list[str]:
    """The fault kinds that occur in any of the matrices, injected or detected, in :data:`FAULT_KINDS` order (other
    kinds after)."""
    seen = {kind for matrix in matrices for cell in matrix.counts for kind in cell} | {
        kind for matrix in matrices for kind in (*matrix.scored, *matrix.latent)
    }
    seen.discard(NO_FAULT)
    return [kind for kind in FAULT_KINDS if kind in seen] + sorted(seen - set(FAULT_KINDS))


def confusion_rows(matrices: Sequence[Confusion]) -> list[dict[str, Any]]:
    """The rows of ``confusion.csv`` (:data:`CONFUSION_COLUMNS`): every cell of every matrix over the kinds that occur
    in any, rows then columns in :data:`FAULT_KINDS` order and :data:`NO_FAULT` last (its own cell left out)."""
    labels = (*_confusion_kinds(matrices), NO_FAULT)
    cells = [
        (injected, detected)
        for injected in labels
        for detected in labels
        if (injected, detected) != (NO_FAULT, NO_FAULT)
    ]
    return [
        {
            "controller": matrix.controller,
            "injected_kind": injected,
            "detected_kind": detected,
            "count": matrix.counts.get((injected, detected), 0),
        }
        for matrix in matrices
        for injected, detected in cells
    ]


def write_confusion_csv(path: str | Path, matrices: Sequence[Confusion]) -> Path:
    """Write ``confusion.csv``: the header :data:`CONFUSION_COLUMNS` (also with no cells), then
    :func:`confusion_rows`."""
    path = Path(path)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=CONFUSION_COLUMNS)
        writer.writeheader()
        writer.writerows(confusion_rows(matrices))
    return path


def confusion_table(matrices: Sequence[Confusion]) -> str:
    """The confusion matrices as one Markdown table: per controller a line per injected kind that occurs and one of
    false alarms (:data:`NO_FAULT`); a column per detected kind and :data:`NO_FAULT`, then the scored and the latent
    faults of the line's kind. Empty cells are zeros."""
    kinds = _confusion_kinds(matrices)
    header = ["Controller", "Injected \\ detected", *kinds, NO_FAULT, "Scored", "Latent"]
    body = []
    for matrix in matrices:
        for injected in (*kinds, NO_FAULT):
            if injected != NO_FAULT and not (matrix.scored.get(injected) or matrix.latent.get(injected)):
                continue
            cells = [matrix.counts.get((injected, detected), 0) for detected in (*kinds, NO_FAULT)]
            if injected == NO_FAULT:
                cells[-1] = None  # no fault and no detection: not counted
            body.append(
                [
                    matrix.controller,
                    injected,
                    *("" if cell is None else str(cell) for cell in cells),
                    str(matrix.scored.get(injected, "")),
                    str(matrix.latent.get(injected, "")),
                ]
            )
    return metrics.markdown_table(header, body)
