"""The Markdown tables of ``python -m eval``'s summary, from its per-episode, per-carry and Table 2 rows."""

from __future__ import annotations

from typing import Any

from eval import metrics
from eval.comparison import SETTLING_DEADLINE_MS


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


def bound_violations(episode_rows: list[dict[str, Any]], bound_label: str) -> list[str]:
    """Controllers whose mean tracking RMS is below the bound's (the bound is then not a bound), as lines."""
    means = {
        label: metrics.mean_std([row["tracking_rms_mm"] for row in group if not row["diverged"]])[0]
        for label, group in metrics.group_by(episode_rows, "controller").items()
    }
    if bound_label not in means:
        return []
    bound = means[bound_label]
    return [
        f"- {label} tracks at {mean:.3f} mm RMS, below {bound_label} at {bound:.3f} mm: the bound does not hold"
        for label, mean in means.items()
        if label != bound_label and mean < bound
    ]
