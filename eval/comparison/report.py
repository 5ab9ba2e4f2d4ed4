"""The sections of ``python -m eval``'s summary beside its tables (:mod:`eval.comparison.tables`): the pick rate, the
payload targets, the faults, the bound check and the residual's gain over its base."""

from __future__ import annotations

from typing import Any

from controllers.registry import controller_entry, controller_label
from eval import metrics
from eval.comparison.run import ComparisonConfig
from eval.comparison.tables import (
    BOUND_HOLDS,
    bound_violations,
    payload_target_table,
    pick_rate_table,
    place_check_words,
    residual_gain,
    unbounded_episodes,
)
from eval.fault_scores import DETECTION_GRACE_S
from eval.fault_tables import NO_FAULT, confusion_counts, confusion_table, fault_table

SKIP_COLUMNS = ("seed", "saturated_steps", "speed_exceeded_steps")
"""The columns of an episode row that the bound check's note on a skipped oracle episode names."""


def bound_section(episode_rows: list[dict[str, Any]]) -> list[str]:
    """The check of the table's invariant for each bound among the rows (a privileged entry, the oracle)
    (:func:`_bound_check`)."""
    keys = dict.fromkeys(row["key"] for row in episode_rows)
    return [line for key in keys if controller_entry(key).privileged for line in _bound_check(episode_rows, key)]


def _bound_check(episode_rows: list[dict[str, Any]], key: str) -> list[str]:
    """The check of the table's invariant: no controller tracks better than the bound ``key``, on the episodes
    where it is a bound: the drive neither clipped its commands nor let a joint exceed its speed, and no
    fault was injected (the bound knows the fault-free plant and the payloads)."""
    bound = controller_label(key)
    oracle_rows = [row for row in episode_rows if row["controller"] == bound]
    if not oracle_rows:
        return []
    skipped = unbounded_episodes(episode_rows, bound)
    note = []
    limited = [row for row in skipped if row["saturated_steps"] > 0 or row["speed_exceeded_steps"] > 0]
    if limited:
        seeds, clipped, fast = (", ".join(str(row[name]) for row in limited) for name in SKIP_COLUMNS)
        note = [
            f"Not a bound on episode(s) {seeds}: the drive clipped {bound}'s command on {clipped} steps and a joint "
            f"was beyond the drive's maximum speed on {fast} steps; the bound check skips these episodes.",
            "",
        ]
    faulted = [row for row in skipped if row.get("faults_injected", 0) > 0]
    if faulted:
        seeds, counts = (", ".join(str(row[name]) for row in faulted) for name in ("seed", "faults_injected"))
        note += [
            f"Not a bound on episode(s) {seeds}: {counts} fault(s) were injected, and {bound} knows the fault-free "
            "plant and the payloads; the bound check skips these episodes.",
            "",
        ]
    if len(skipped) == len(oracle_rows):
        return note
    violations = bound_violations(episode_rows, bound)
    if violations:
        return [*note, "## Bound violated", "", *violations, ""]
    return [*note, BOUND_HOLDS.format(bound=bound, places=place_check_words(episode_rows, bound)), ""]


def fault_section(fault_rows: list[dict[str, Any]], labels: list[str]) -> list[str]:
    """The summary's lines on the faults (:func:`eval.fault_tables.fault_table`); none when no fault was injected and
    none detected."""
    if not fault_rows:
        return []
    return [
        "## Faults",
        "",
        "Per controller and fault kind, over its episodes (faults.csv has every one). A detection matches an injected "
        f"fault of its kind from the fault's start to {1e3 * DETECTION_GRACE_S:.0f} ms after its end; latency: "
        "detection time minus the fault's start. Consequences: other detections within a fault or its grace, "
        "counted under the kind of the fault they followed. False alarms: detections with no fault under way, "
        "counted under the detected kind. Latent: drive faults whose every command stayed within what the drive "
        "kept (they changed nothing; not scored).",
        "",
        fault_table(fault_rows, labels),
        "",
        "Confusion matrix (confusion.csv): per controller, injected kind by detected kind. A cell counts the injected "
        "faults the controller reported at least once as that kind within the fault's window (its match or a "
        f"consequence), so a fault reported as two kinds counts twice; column {NO_FAULT}: faults with no detection; "
        f"row {NO_FAULT}: false alarms.",
        "",
        confusion_table(confusion_counts(fault_rows, labels)),
        "",
    ]


def residual_section(config: ComparisonConfig, episode_rows: list[dict[str, Any]]) -> list[str]:
    """Which policy each row that reads the policy file runs (the residual), on which base, and what it adds over that
    base's row."""
    lines = []
    for key in config.controllers:
        if controller_entry(key).reads_policy_file:
            lines += _policy_lines(config, episode_rows, controller_label(key))
    return lines


def _policy_lines(config: ComparisonConfig, episode_rows: list[dict[str, Any]], label: str) -> list[str]:
    """The lines of :func:`_residual_section` on the row labelled ``label``."""
    base = config.residual_base or "a custom base"
    moves = "has its own, from its training" if config.residual_base_moves else "does not carry"
    lines = [
        f"{label}: the policy {config.residual.name} on the base it was trained on, {base}, rebuilt from the policy "
        "file; the gain below is against this run's row of that controller (same identification; this run's "
        f"tare and, unless the plant is randomized per episode, the calibration's empty moves, which the policy "
        f"file's base {moves}).",
        "",
    ]
    if config.residual_base is not None and config.residual_base_servo != config.servo:
        lines += [
            f"No gain over its base is computed: the base's feedback is '{config.residual_base_servo}', this run's "
            f"model rows run '{config.servo}' (--servo {config.residual_base_servo} runs the same base).",
            "",
        ]
    elif config.residual_base is not None:
        lines += residual_gain(episode_rows, label, config.residual_base)
    return lines


def pick_rate_section(episode_rows: list[dict[str, Any]]) -> list[str]:
    """The summary's lines on the pick rate (:func:`eval.comparison.tables.pick_rate_table`)."""
    return [
        "## Pick rate",
        "",
        "Mean ± std over the completed episodes. Picks/min and cycle times are the reference's timing: from its "
        "arrival at rest at the first pick point to its end, at rest at the next pick point, waits for the "
        "in-position signal included. Place error: platform to place point as the gripper opens. Settle time: from "
        "the reference's arrival at a pick or place point to the cell's in-position signal, a time-out counting as "
        "the time waited; time-outs summed (episodes with any); n/a with the timed release. Path deviation: platform "
        "to the nearest segment of the reference path. Envelope violations: steps the drive clipped plus steps over "
        "the maximum joint speed, summed (episodes with any). Torque against the drive's ratings; thermal margin = "
        "1 - max RMS torque / rated torque.",
        "",
        pick_rate_table(episode_rows),
        "",
    ]


def payload_target_section(carry_rows: list[dict[str, Any]]) -> list[str]:
    """The summary's lines on the payload targets: every carry of every estimating controller counted; none
    without carries."""
    if not carry_rows:
        return []
    bound_kg, bound_fraction = metrics.OVERSHOOT_BOUND
    return [
        "## Payload targets",
        "",
        f"Every carry counted: end-of-carry estimate within ±{100 * metrics.PAYLOAD_BAND:.0f} % for objects of "
        f"{metrics.MIN_RELATIVE_MASS} kg and more and within ±{1e3 * metrics.LIGHT_OBJECT_BAND_KG:.0f} g below; "
        f"during a carry never more than max({bound_kg} kg, {100 * bound_fraction:.0f} %) above the mass; within "
        f"±{100 * metrics.PAYLOAD_BAND:.0f} % by {metrics.SETTLING_DEADLINE_MS:.0f} ms after the pick.",
        "",
        payload_target_table(carry_rows),
        "",
    ]
