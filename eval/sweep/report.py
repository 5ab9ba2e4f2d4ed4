"""Summary table and plots of a sweep, from its results rows.

Per scenario and controller: episodes, failures, divergences, and for each summarized metric the mean,
the sample standard deviation and the half-width of the 95 % confidence interval of the mean
(Student t with n - 1 degrees of freedom). Failed and diverged episodes are counted and left out of the
statistics (a diverged episode's metrics cover only the steps before the divergence).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from eval import metrics

SUMMARY_METRICS = (
    "tracking_rms_mm",
    "tracking_max_mm",
    "torque_rms_nm",
    "torque_peak_nm",
    "energy_j",
    "payload_end_abs_error_percent",
    "picks_per_min",
    "cycle_time_mean_s",
    "place_error_max_mm",
    "path_deviation_rms_mm",
    "envelope_violations",
    "peak_torque_ratio",
    "thermal_margin",
)
"""Metrics summarized per scenario and controller."""

PLOTTED_METRICS = ("tracking_rms_mm", "torque_rms_nm")
"""Metrics of ``summary.png``, a panel each."""

LOG_SPAN = 10.0
"""Ratio of the largest to the smallest mean of a panel above which its axis is logarithmic: the tracking RMS runs
from about 5 mm (PD) to 0.03 mm (the bound), and on a linear axis the small bars are invisible."""


def mean_std_ci95(values: Sequence[float]) -> tuple[float, float, float]:
    """Mean, sample std (ddof 1) and 95 % CI half-width of the mean; NaN where undefined (n < 1 or 2)."""
    data = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if data.size == 0:
        return math.nan, math.nan, math.nan
    if data.size == 1:
        return float(data[0]), math.nan, math.nan
    std = float(np.std(data, ddof=1))
    half_width = float(stats.t.ppf(0.975, data.size - 1) * std / math.sqrt(data.size))
    return float(np.mean(data)), std, half_width


def _number(value: Any) -> float:
    return float(value) if value not in ("", None) else math.nan


def _is_true(value: Any) -> bool:
    return str(value) in ("True", "true", "1", "1.0")


def summarize(rows: Sequence[dict[str, Any]], scenarios: Sequence[str], controllers: Sequence[str]) -> list[dict]:
    """One summary row per (scenario, controller) present in ``rows``, in the given orders."""
    summary = []
    for scenario in scenarios:
        for controller in controllers:
            group = [row for row in rows if row["scenario"] == scenario and row["controller"] == controller]
            if not group:
                continue
            ok = [row for row in group if row["status"] == "ok"]
            kept = [row for row in ok if not _is_true(row["diverged"])]
            entry: dict[str, Any] = {
                "scenario": scenario,
                "controller": controller,
                "label": group[0]["label"],
                "episodes": len(group),
                "failed": len(group) - len(ok),
                "diverged": len(ok) - len(kept),
            }
            for name in SUMMARY_METRICS:
                mean, std, half_width = mean_std_ci95([_number(row[name]) for row in kept])
                entry.update({f"{name}_mean": mean, f"{name}_std": std, f"{name}_ci95": half_width})
            summary.append(entry)
    return summary


def _cell(entry: dict[str, Any], name: str) -> str:
    return metrics.format_with_spread(entry[f"{name}_mean"], entry[f"{name}_ci95"])


def markdown(summary: Sequence[dict[str, Any]]) -> str:
    """The summary as a Markdown table: mean ± 95 % CI half-width per metric, 3 significant digits."""
    header = ["Scenario", "Controller", "Episodes (failed, diverged)", *map(metrics.metric_label, SUMMARY_METRICS)]
    rows = [
        [
            entry["scenario"],
            entry["label"],
            f"{entry['episodes']} ({entry['failed']}, {entry['diverged']})",
            *(_cell(entry, name) for name in SUMMARY_METRICS),
        ]
        for entry in summary
    ]
    return metrics.markdown_table(header, rows)


def plot(summary: Sequence[dict[str, Any]], path: Path) -> Path:
    """Bars of each of :data:`PLOTTED_METRICS` (a panel each, logarithmic when its means span more than
    :data:`LOG_SPAN`) per scenario (groups) and controller (bars), with 95 % CI whiskers, the legend beneath."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(entry["scenario"] for entry in summary))
    labels = list(dict.fromkeys(entry["label"] for entry in summary))
    width = 0.8 / len(labels)
    figure_width = min(2 + 1.2 * len(scenarios) * (2.5 + 0.35 * len(labels)), 20.0)  # inches: room for every bar
    figure, axes = plt.subplots(1, len(PLOTTED_METRICS), figsize=(figure_width, 5), squeeze=False)
    for axis, name in zip(axes[0], PLOTTED_METRICS, strict=True):
        means = np.array([entry[f"{name}_mean"] for entry in summary], dtype=float)
        shown = means[np.isfinite(means) & (means > 0.0)]
        logarithmic = shown.size > 0 and shown.max() > LOG_SPAN * shown.min()
        for n, label in enumerate(labels):
            entries = {e["scenario"]: e for e in summary if e["label"] == label}
            x = [i + (n - (len(labels) - 1) / 2) * width for i, s in enumerate(scenarios) if s in entries]
            heights = np.array([entries[s][f"{name}_mean"] for s in scenarios if s in entries], dtype=float)
            errors = np.nan_to_num(np.array([entries[s][f"{name}_ci95"] for s in scenarios if s in entries]))
            # on a logarithmic axis a whisker below zero has no place: the lower one stops at a tenth of the bar
            below = np.minimum(errors, 0.9 * heights) if logarithmic else errors
            axis.bar(x, heights, width, yerr=[below, errors], capsize=3, label=label, color=f"C{n % 10}")
        if logarithmic:
            axis.set_yscale("log")
        axis.set_xticks(range(len(scenarios)), scenarios)
        axis.set_ylabel(metrics.metric_label(name) + (", log scale" if logarithmic else ""))
        axis.set_title(f"{metrics.metric_label(name)}: mean and 95 % CI", fontsize="medium")
        axis.grid(axis="y", which="both" if logarithmic else "major", alpha=0.3)
    handles, names = axes[0][0].get_legend_handles_labels()
    columns = min(len(names), 5)
    figure.legend(handles, names, loc="lower center", ncol=columns, fontsize="small")
    rows = -(-len(names) // columns)
    figure.tight_layout(rect=(0, (0.2 + 0.25 * rows) / figure.get_figheight(), 1, 1))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path
