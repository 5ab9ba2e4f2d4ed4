"""The Markdown tables of ``python -m eval``'s summary, from its per-episode, per-carry and Table 2 rows."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from eval import metrics
from eval.metrics import SETTLING_DEADLINE_MS


def controller_table(episode_rows: list[dict[str, Any]], carry_rows: list[dict[str, Any]]) -> str:
    """One row per controller: mean ± std over its episodes (diverged ones counted, left out of the means)."""
    header = [
        "Controller",
        "Episodes (diverged)",
        "Tracking RMS (mm)",
        "Tracking max (mm)",
        "Torque RMS (N m)",
        "Torque peak (N m)",
        "Energy (J)",
        "m_hat error, end of carry (%)",
        "Settling to ±5 % (ms)",
        f"Settled ≤ {SETTLING_DEADLINE_MS:.0f} ms",
    ]
    carries = metrics.group_by(carry_rows, "controller")
    rows = []
    for label, group in metrics.group_by(episode_rows, "controller").items():
        kept = [row for row in group if not row["diverged"]]

        def column(name: str, rows_: list[dict[str, Any]] = kept) -> str:
            return metrics.format_mean_std([row[name] for row in rows_])

        scored = [row for row in carries.get(label, []) if row["mass_kg"] >= metrics.MIN_RELATIVE_MASS]
        if scored:
            settled = sum(row["settling_time_ms"] <= SETTLING_DEADLINE_MS for row in scored)
            payload = [
                column("end_error_percent", scored),
                column("settling_time_ms", scored),
                f"{settled}/{len(scored)}",
            ]
        else:
            payload = ["n/a", "n/a", "n/a"]
        rows.append(
            [
                label,
                f"{len(group)} ({len(group) - len(kept)})",
                column("tracking_rms_mm"),
                column("tracking_max_mm"),
                column("torque_rms_nm"),
                column("torque_peak_nm"),
                column("energy_j"),
                *payload,
            ]
        )
    return metrics.markdown_table(header, rows)


def pick_rate_table(episode_rows: list[dict[str, Any]]) -> str:
    """One row per controller, scored like a picker's data sheet: mean ± std over its completed episodes of the
    pick rate, the cycle time, the mean and worst place error, the mean and worst settle time, the path deviation
    and the drive's use, and the settle time-outs and envelope violations summed (:mod:`eval.metrics`)."""
    header = [
        "Controller",
        "Picks/min",
        "Cycle time, mean (s)",
        "Place error, mean (mm)",
        "Place error, max (mm)",
        "Settle time, mean (ms)",
        "Settle time, max (ms)",
        "Settle time-outs (episodes)",
        "Path deviation RMS (mm)",
        "Envelope violations (episodes)",
        "Peak torque / peak rating",
        "Thermal margin",
    ]
    rows = []
    for label, group in metrics.group_by(episode_rows, "controller").items():
        kept = [row for row in group if not row["diverged"]]

        def column(name: str, digits: int, rows_: list[dict[str, Any]] = kept) -> str:
            return metrics.format_mean_std([row[name] for row in rows_], digits)

        violations = [int(row["envelope_violations"]) for row in kept]
        timeouts = [int(row["settle_timeouts"]) for row in kept]
        rows.append(
            [
                label,
                column("picks_per_min", 1),
                column("cycle_time_mean_s", 3),
                column("place_error_mean_mm", 2),
                column("place_error_max_mm", 2),
                column("settle_time_mean_ms", 1),
                column("settle_time_max_ms", 1),
                f"{sum(timeouts)} ({sum(n > 0 for n in timeouts)}/{len(kept)})",
                column("path_deviation_rms_mm", 3),
                f"{sum(violations)} ({sum(n > 0 for n in violations)}/{len(kept)})",
                column("peak_torque_ratio", 2),
                column("thermal_margin", 2),
            ]
        )
    return metrics.markdown_table(header, rows)


def carries_from_rows(carry_rows: list[dict[str, Any]]) -> list[metrics.CarryMetrics]:
    """The :class:`~eval.metrics.CarryMetrics` of per-carry rows (as ``carries.csv`` holds them)."""
    return [
        metrics.CarryMetrics(
            mass=float(row["mass_kg"]),
            end_estimate=float(row["end_estimate_kg"]),
            end_error_percent=float(row["end_error_percent"]),
            settling_time_ms=float(row["settling_time_ms"]),
            peak_estimate=float(row["peak_estimate_kg"]),
        )
        for row in carry_rows
    ]


def payload_target_table(carry_rows: list[dict[str, Any]]) -> str:
    """One row per estimating controller: its carries counted against the payload targets
    (:func:`eval.metrics.payload_targets`)."""
    low = metrics.MIN_RELATIVE_MASS
    bound_kg, bound_fraction = metrics.OVERSHOOT_BOUND
    header = [
        "Controller",
        f"End within ±{100 * metrics.PAYLOAD_BAND:.0f} % (≥ {low} kg)",
        f"End within ±{1e3 * metrics.LIGHT_OBJECT_BAND_KG:.0f} g (< {low} kg)",
        f"End error < {low} kg (g): min, max",
        f"Carries over max({bound_kg} kg, {100 * bound_fraction:.0f} %)",
        f"Settled ≤ {SETTLING_DEADLINE_MS:.0f} ms (≥ {low} kg)",
    ]

    def count(pair: tuple[int, int]) -> str:
        done, total = pair
        return f"{done}/{total} ({100.0 * done / total:.0f} %)" if total else "n/a"

    rows = []
    for label, group in metrics.group_by(carry_rows, "controller").items():
        targets = metrics.payload_targets(carries_from_rows(group))
        low_error, high_error = targets.light_error_range_kg
        light_range = f"{1e3 * low_error:+.0f}, {1e3 * high_error:+.0f}" if targets.light_within_band[1] else "n/a"
        rows.append(
            [
                str(label),
                count(targets.end_within_band),
                count(targets.light_within_band),
                light_range,
                count(targets.overshoots),
                count(targets.settled),
            ]
        )
    return metrics.markdown_table(header, rows)


def table2_table(table2_rows: list[dict[str, Any]]) -> str:
    """The Table 2 analogue: mean and std of tau_measured - tau_model per joint for each payload hypothesis."""
    header = ["Joint", "mp = 0: mean", "std", "mp = m_hat: mean", "std", "std ratio", "m_hat + tare: mean", "std"]
    rows = [
        [
            f"tau{row['joint']} (N m)",
            f"{row['mp_0_mean']:.2f}",
            f"{row['mp_0_std']:.2f}",
            f"{row['mp_hat_mean']:.2f}",
            f"{row['mp_hat_std']:.2f}",
            f"{row['mp_hat_std'] / row['mp_0_std']:.2f}",
            f"{row['apparent_mean']:.2f}",
            f"{row['apparent_std']:.2f}",
        ]
        for row in table2_rows
    ]
    return metrics.markdown_table(header, rows)


def unbounded_episodes(episode_rows: list[dict[str, Any]], bound_label: str) -> list[dict[str, Any]]:
    """The bound's episodes that are not a bound: the drive clipped one of its commands (``saturated_steps``), a
    joint went beyond the drive's maximum speed (``speed_exceeded_steps``) or a fault was injected
    (``faults_injected``: the oracle knows the fault-free plant and the payloads, not the fault)."""
    return [
        row
        for row in episode_rows
        if row["controller"] == bound_label
        and (row["saturated_steps"] > 0 or row["speed_exceeded_steps"] > 0 or row.get("faults_injected", 0) > 0)
    ]


FEEDBACK_LINES = {
    "servo": "Feedback: the model rows and the bound run the servo layer (integral action, friction compensation at "
    "rest; --servo pd gives the paper's fixed PD); their labels keep '+PD'.",
    "pd": "Feedback: the model rows run the paper's fixed PD (--servo pd) and the bound its own PD.",
}
"""The summaries' line on what feedback the model rows ran, per :data:`controllers.setup.SERVOS` value."""

BOUND_HOLDS = "Bound check: no controller tracks better than {bound}, in the mean or on any episode{places}."
"""The summary's line when :func:`bound_violations` finds none (``{bound}``: the bound's label; ``{places}``:
:func:`place_check_words`)."""


def bound_violations(episode_rows: list[dict[str, Any]], bound_label: str) -> list[str]:
    """Where a controller does better than the bound (which is then not a bound), as lines: a mean tracking RMS
    below the bound's, an episode tracked better than the bound tracked the same episode (same seed), or a mean
    place error (at release) significantly below the bound's (:func:`closer_places`). Diverged episodes do not
    count, nor do the episodes (seeds) on which the bound was not a bound (:func:`unbounded_episodes`),
    for any controller."""
    groups = checked_groups(episode_rows, bound_label)
    if bound_label not in groups:
        return []
    means = {label: metrics.mean_std([row["tracking_rms_mm"] for row in group])[0] for label, group in groups.items()}
    bound = means[bound_label]
    lines = [
        f"- {label} tracks at {mean:.3f} mm RMS, below {bound_label} at {bound:.3f} mm: the bound does not hold"
        for label, mean in means.items()
        if label != bound_label and mean < bound
    ]
    bound_by_seed = {row["seed"]: row["tracking_rms_mm"] for row in groups[bound_label]}
    lines += [
        f"- {label} tracks episode {row['seed']} at {row['tracking_rms_mm']:.3f} mm RMS, below {bound_label} at "
        f"{bound_by_seed[row['seed']]:.3f} mm on the same episode"
        for label, group in groups.items()
        if label != bound_label
        for row in group
        if row["seed"] in bound_by_seed and row["tracking_rms_mm"] < bound_by_seed[row["seed"]]
    ]
    lines += [
        f"- {label} places at {mean:.3f} mm on average, closer than {bound_label} at {bound_mean:.3f} mm on the "
        f"same {count} episodes (one-sided paired t-test, p = {p_value:.3g}): the bound does not hold"
        for label, (mean, bound_mean, count, p_value) in closer_places(groups, bound_label).items()
    ]
    return lines


PLACE_BOUND_SIGNIFICANCE = 0.05
"""Level of the place-error bound check's one-sided paired t-test: a row that places closer than the bound by less
than this significance is within what the encoders' quantization scatters (one count is tens of µm at the platform)."""


def checked_groups(episode_rows: list[dict[str, Any]], bound_label: str) -> dict[str, list[dict[str, Any]]]:
    """The episode rows the bound check compares, by controller: not diverged, and not on an episode (seed) on which
    the bound was not a bound (:func:`unbounded_episodes`)."""
    skipped = {row["seed"] for row in unbounded_episodes(episode_rows, bound_label)}
    kept = [row for row in episode_rows if not row["diverged"] and row["seed"] not in skipped]
    return metrics.group_by(kept, "controller")


def _places(group: list[dict[str, Any]]) -> dict[int, float]:
    """Mean place error (mm) by seed of the rows of ``group`` that placed."""
    return {
        row["seed"]: row["place_error_mean_mm"]
        for row in group
        if math.isfinite(row.get("place_error_mean_mm", math.nan))
    }


def place_check_words(episode_rows: list[dict[str, Any]], bound_label: str) -> str:
    """What :data:`BOUND_HOLDS` says of the place check: that no row places significantly closer, or, on fewer than
    two of the bound's episodes with a place, that the check needs two."""
    if len(_places(checked_groups(episode_rows, bound_label).get(bound_label, []))) < 2:
        return "; the place error needs two episodes to be checked (paired, one-sided t-test)"
    return (
        ", nor places closer on average (paired over the episodes, one-sided t-test at "
        f"{PLACE_BOUND_SIGNIFICANCE:.0%} significance)"
    )


def closer_places(
    groups: dict[str, list[dict[str, Any]]], bound_label: str
) -> dict[str, tuple[float, float, int, float]]:
    """The rows whose mean place error (at release) is significantly below the bound's on the same episodes, as
    (row's mean, bound's mean (mm), episodes, p-value), by label.

    A place error below an encoder count at the platform is set by where within a count each arm rests, on the bound
    and the rows alike: a difference of means on a few places is noise. The check pairs the episodes (same seed,
    same objects) and names a row when, over two episodes at least, a one-sided paired t-test finds it closer at
    :data:`PLACE_BOUND_SIGNIFICANCE`, or every episode is closer by the same amount (no scatter).
    """
    bound_places = _places(groups[bound_label])
    closer = {}
    for label, group in groups.items():
        places = _places(group)
        seeds = [seed for seed in places if seed in bound_places]
        if label == bound_label or len(seeds) < 2:
            continue
        row_places = np.array([places[seed] for seed in seeds])
        bound_of_row = np.array([bound_places[seed] for seed in seeds])
        differences = row_places - bound_of_row
        if np.mean(differences) >= 0.0:
            continue
        if np.ptp(differences) == 0.0:
            p_value = 0.0
        else:
            p_value = float(stats.ttest_rel(row_places, bound_of_row, alternative="less").pvalue)
        if p_value < PLACE_BOUND_SIGNIFICANCE:
            closer[label] = (float(np.mean(row_places)), float(np.mean(bound_of_row)), len(seeds), p_value)
    return closer


RESIDUAL_GOAL = (-15.0, 5.0)
"""What a residual policy must add over its base: tracking RMS at least 15 % lower (%), torque RMS at most 5 %
higher (%)."""


def residual_gain(episode_rows: list[dict[str, Any]], residual_label: str, base_label: str) -> list[str]:
    """The residual row against its base row on the same episodes, as summary lines (none if either is absent).

    Changes are of the means over the episodes neither controller diverged on (%), against
    :data:`RESIDUAL_GOAL`.
    """
    by_label = metrics.group_by(episode_rows, "controller")
    if residual_label not in by_label or base_label not in by_label:
        return []
    diverged = {row["seed"] for label in (residual_label, base_label) for row in by_label[label] if row["diverged"]}

    def mean(label: str, name: str) -> float:
        return metrics.mean_std([row[name] for row in by_label[label] if row["seed"] not in diverged])[0]

    tracking, torque = (
        100.0 * (mean(residual_label, name) / mean(base_label, name) - 1.0)
        for name in ("tracking_rms_mm", "torque_rms_nm")
    )
    met = tracking <= RESIDUAL_GOAL[0] and torque <= RESIDUAL_GOAL[1]
    return [
        f"Residual over its base ({base_label}): tracking RMS {tracking:+.1f} %, torque RMS {torque:+.1f} % "
        f"(goal: <= {RESIDUAL_GOAL[0]:+.0f} % at <= {RESIDUAL_GOAL[1]:+.0f} %; {'met' if met else 'not met'}).",
        "",
    ]
