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

The confusion matrix (:func:`eval.fault_tables.confusion_counts`, :func:`eval.fault_tables.confusion_table`,
``confusion.csv``) gives, per controller, injected kind by detected kind. Cell (i, d) counts the injected faults of
kind i that the controller reported, within the fault's window, at least once as kind d: its matching detection (the
diagonal) and its consequences (off it: a slip raised after a collision is a slip detected for an injected collision).
A fault reported as its kind and as another counts in both cells, so a row can add up to more than its faults; column
:data:`eval.fault_tables.NO_FAULT` counts the faults with no detection at all in their window (missed and unreported),
row :data:`eval.fault_tables.NO_FAULT` the false alarms by detected kind.

The tables made of the matched faults (the rows of ``faults.csv``, the summaries and the confusion matrix's counts)
are :mod:`eval.fault_tables`; here are the matching and :func:`fault_metrics` (the flat per-episode columns
:data:`FAULT_METRICS` of ``episodes.csv`` and of a sweep's ``results.csv``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from controllers.monitor import DetectedFault
from delta_env.faults import FAULT_KINDS, InjectedFault, is_latent
from delta_env.sensors import CONTROL_PERIOD

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
