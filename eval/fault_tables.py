"""The fault tables of the evaluation, from the matched faults of :mod:`eval.fault_scores`: the rows of ``faults.csv``
(:func:`fault_rows`, :data:`FAULT_COLUMNS`), the summary per controller and kind (:func:`fault_summary`,
:func:`fault_table`), a sweep's table (:func:`sweep_fault_table`) and the confusion matrix, injected kind by detected
kind (:func:`confusion_counts`, :func:`confusion_rows` for ``confusion.csv``, :func:`confusion_table`; its cells are
defined in :mod:`eval.fault_scores`)."""

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
from eval import metrics
from eval.fault_scores import EpisodeFaults, fault_end_s

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
