"""The pick-rate data sheet's report (``python -m eval.rate``): the summary's lines (the data sheet beside ABB's
published rows, the rows in full, the targets, what the model buys) and the figure ``rate.png``, from the rows of
:mod:`eval.rate.study`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import (
    controller_label,
)
from delta_env.config import RATED_PAYLOAD, PlantConfig
from delta_env.cycles import DEFAULT_DWELL
from delta_env.geometry import GRAVITY
from delta_env.scenario import PickPlaceTask
from eval import metrics
from eval.comparison.tables import FEEDBACK_LINES
from eval.console import plural
from eval.rate.published import ABB_IRB_360, DIFFERENCES, PublishedSheet
from eval.rate.study import (
    COMPARED_PLANNERS,
    FASTEST_SEARCH,
    JERK_LIMITED,
    MIXED,
    PLACE_GOAL_MM,
    QUICK_NOTE,
    SETTLE_COLUMNS,
    TRACKING_GOAL_MM,
    RateConfig,
    cycle_terms,
    holds,
    kilograms,
    paced,
    payload_label,
)


def _settle_cell(value: float, kind: type) -> str:
    """A settle column's cell: n/a for a row that never waited in position (it follows the first's reference)."""
    if kind is float:
        return "n/a" if math.isnan(value) else f"{value:.1f}"
    return str(value)


def _pace_line(keys: Sequence[str]) -> str:
    """Who runs every row at its own pace and who follows the first's references (:func:`paced`), for the summary."""
    own, others = (list(map(controller_label, group)) for group in paced(keys))
    line = f"{' and '.join(own)} {'runs' if len(own) == 1 else 'each run'} every row at its own pace"
    if others:
        line += (
            f"; the other controllers follow {own[0]}'s references as given: they do not wait in position, and their "
            "place error is taken at its release"
        )
    return line


def summary_lines(
    config: RateConfig, rows: list[dict[str, Any]], fastest: list[dict[str, Any]], out: Path, seconds: float
) -> list[str]:
    """The summary's lines: the data sheet, the rows in full, the targets, and what the model buys."""
    loads = [payload_label(p) for p in config.payloads] + [MIXED]
    by_key = {(row["planner"], row["controller"], str(row["payload"])): row for row in rows}
    lead = controller_label(config.controllers[0])
    sheet = [
        [planner, label] + [f"{by_key[(planner, label, load)]['picks_per_min']:.1f}" for load in loads]
        for planner in config.planners
        for label in (controller_label(key) for key in config.controllers)
    ]
    settled = [(name, kind, header) for name, _, kind, header in SETTLE_COLUMNS if all(name in row for row in rows)]
    full = [
        [
            row["planner"],
            row["controller"],
            str(row["payload"]),
            f"{row['picks_per_min']:.1f}",
            f"{row['tracking_rms_mm']:.3f}",
            f"{row['path_deviation_rms_mm']:.3f}",
            f"{row['place_error_mm']:.3f}",
            *(_settle_cell(row[name], kind) for name, kind, _ in settled),
            str(row["envelope_violations"]),
            f"{row['peak_torque_ratio']:.2f}",
            f"{row['rms_torque_ratio']:.2f}",
            "yes" if holds(row) else "no",
        ]
        for row in rows
    ]
    lines = [
        f"# Pick rate, scenario {config.scenario.name}: 25/305/25 mm standard cycle, {study_line(config)}",
        "",
        *([QUICK_NOTE, ""] if config.quick else []),
        f"Planned timings use {100 * config.scenario.task.torque_share:.0f} % of the drive's envelope (after the "
        f"planner's 10 % margin) and keep its thermal rating. {_cycle_line(config.scenario.task)}",
        "",
        f"{FEEDBACK_LINES[config.servo]} Picks per minute ({_pace_line(config.controllers)}).",
        "",
        metrics.markdown_table(
            ["planner", "controller", *[f"{load} kg" if load != MIXED else load for load in loads]], sheet
        ),
        "",
        "Every row: tracking RMS and path deviation RMS (mean, mm), place error at release (worst, mm), "
        + (
            "settle time in position (mean and longest, ms), places that timed out, residual vibration at the place "
            f"(the platform's true peak to peak over {1e3 * metrics.RESIDUAL_WINDOW:.0f} ms from the in-position "
            "signal, mean and largest, um), "
            if settled
            else ""
        )
        + "envelope violations (steps), peak and RMS torque over the drive's peak and rated torque (largest); holds = "
        f"tracking <= {TRACKING_GOAL_MM} mm, place error <= {PLACE_GOAL_MM} mm, no violation, no overheating"
        + (", no settle time-out." if settled else "."),
        "",
        metrics.markdown_table(
            [
                "planner",
                "controller",
                "payload",
                "picks/min",
                "tracking",
                "path dev.",
                "place err.",
                *(header for _, _, header in settled),
                "violations",
                "peak/peak",
                "RMS/rated",
                "holds",
            ],
            full,
        ),
        "",
    ]
    lines += _published_lines(config, by_key, lead)
    lines += _targets(config, by_key, lead)
    if fastest:
        lines += _fastest_lines(fastest, by_key, lead)
    lines.append(f"Run folder: {out} ({seconds:.0f} s)")
    return lines


def _targets(config: RateConfig, by_key: dict[tuple[str, str, str], dict[str, Any]], lead: str) -> list[str]:
    """The mixed stream's online capture of the declared gain, and online against the fixed timing at the
    rated payload."""
    lines = []
    mixed = {planner: by_key.get((planner, lead, MIXED)) for planner in ("worst_case", "declared", "online")}
    if all(mixed.values()):
        worst, declared, online = (mixed[p]["picks_per_min"] for p in ("worst_case", "declared", "online"))
        captured = (online - worst) / (declared - worst) if declared != worst else math.nan
        lines += [
            f"Mixed stream, {lead}: online {online:.1f} picks/min = {100 * online / declared:.1f} % of declared "
            f"({declared:.1f}); declared gains {100 * (declared / worst - 1):.1f} % over worst-case ({worst:.1f}) "
            f"and online captures {100 * captured:.0f} % of that gain.",
            "",
        ]
    rated = payload_label(RATED_PAYLOAD)
    fixed, online_rated = by_key.get(("fixed", lead, rated)), by_key.get(("online", lead, rated))
    if fixed and online_rated:
        lines += [
            f"At the rated payload ({rated} kg), {lead}: online {online_rated['picks_per_min']:.1f} picks/min against "
            f"{fixed['picks_per_min']:.1f} at the fixed {config.scenario.task.peak_acceleration / GRAVITY:.0f} g "
            "timing "
            f"({100 * (online_rated['picks_per_min'] / fixed['picks_per_min'] - 1):+.0f} %).",
            "",
        ]
    return lines


def _fastest_lines(
    fastest: list[dict[str, Any]], by_key: dict[tuple[str, str, str], dict[str, Any]], lead: str
) -> list[str]:
    """The second controller's fastest fixed timing per payload, and the lead's online rate over it."""
    table = []
    slowest = f"none down to {FASTEST_SEARCH[0] / GRAVITY:g} g"
    for row in fastest:
        online = by_key.get(("online", lead, str(row["payload"])))
        found = math.isfinite(row["picks_per_min"])
        ratio = f"{online['picks_per_min'] / row['picks_per_min']:.2f}" if online and found else "-"
        table.append(
            [
                str(row["payload"]),
                f"{row['peak_acceleration_g']:.2f}" if found else slowest,
                f"{row['picks_per_min']:.1f}" if found else "-",
                f"{online['picks_per_min']:.1f}" if online else "-",
                ratio,
            ]
        )
    label = fastest[0]["controller"]
    return [
        f"Fastest fixed timing at which {label} holds the goals (bisection over the peak acceleration), and what "
        f"the model buys: {lead} online over it.",
        "",
        metrics.markdown_table(["payload", "peak acc. (g)", f"{label} picks/min", f"{lead} online", "ratio"], table),
        "",
    ]


def study_line(config: RateConfig) -> str:
    """What a run measures: episodes, cycles, seeds and payloads."""
    return (
        f"{plural(config.episodes, 'episode')} x {plural(config.scenario.task.n_cycles, 'cycle')} per row from seed "
        f"{config.seed}, payloads "
        f"{kilograms(config.payloads).replace(',', ', ')} kg and the mixed stream"
    )


def _cycle_line(task: PickPlaceTask) -> str:
    """How the scenario's cycle ends at pick and place (:func:`cycle_terms`)."""
    terms = cycle_terms(task)
    if not terms:
        return f"The gripper switches in the middle of a {1e3 * DEFAULT_DWELL:.0f} ms dwell at pick and place."
    return (
        f"Cycle ends: the gripper switches once the platform is within {1e3 * terms['in_position_window']:g} mm; "
        f"{1e3 * terms['air_activation']:.0f} ms of air activation at pick and place."
    )


def compared_planner(planners: Sequence[str]) -> str:
    """The planner whose rows stand beside the published ones (:data:`COMPARED_PLANNERS`)."""
    return next(planner for planner in COMPARED_PLANNERS if planner in planners)


def _published_lines(
    config: RateConfig,
    by_key: dict[tuple[str, str, str], dict[str, Any]],
    lead: str,
    sheet: PublishedSheet = ABB_IRB_360,
) -> list[str]:
    """The published rows of ``sheet`` beside the lead's at the same payloads, and what differs."""
    planner = compared_planner(config.planners)
    table = []
    for published in sheet.rows:
        ours = by_key.get((planner, lead, payload_label(published.payload)))
        if ours is not None:
            cells = [
                f"{ours['picks_per_min']:.1f}",
                f"{ours['picks_per_min'] / published.picks_per_min:.2f}",
                f"{ours['place_error_mm']:.2f}",
            ]
        else:
            missing = f"beyond our rated {RATED_PAYLOAD:g} kg" if published.payload > RATED_PAYLOAD else "not run"
            cells = [missing, "-", "-"]
        table.append([f"{published.payload:g}", published.robot, f"{published.picks_per_min:.0f}", *cells])
    plant: PlantConfig = config.scenario.plant
    drive, geometry = plant.drive, plant.geometry
    air = cycle_terms(config.scenario.task).get("air_activation")
    if air is None:
        ends = [
            f"our cycle dwells {1e3 * DEFAULT_DWELL:.0f} ms at pick and place, {sheet.maker}'s counts "
            f"{1e3 * sheet.air_activation:.0f} ms of air activation"
        ]
    elif not math.isclose(air, sheet.air_activation):
        ends = [f"our air activation is {1e3 * air:.0f} ms, {sheet.maker}'s {1e3 * sheet.air_activation:.0f} ms"]
    else:
        ends = []
    clauses = [*DIFFERENCES, *ends]
    return [
        f"Beside {sheet.maker}'s published rates ({sheet.source}, {sheet.cycle}: {1e3 * sheet.lift:g}/"
        f"{1e3 * sheet.travel:g}/{1e3 * sheet.lift:g} mm, {1e3 * sheet.air_activation:.0f} ms air activation at "
        f"each end, repeatability {1e3 * sheet.repeatability:g} mm), {lead} with {planner} timing (place error: "
        "worst at release, mm):",
        "",
        metrics.markdown_table(
            ["payload (kg)", "robot", "picks/min", f"{lead} {planner}", "ours / theirs", "place error"], table
        ),
        "",
        "What differs:",
        "",
        *(f"- {clause};" for clause in clauses[:-1]),
        f"- {clauses[-1]}.",
        "",
        f"Our robot: {drive.peak_torque:g} N m peak and {drive.rated_torque:g} N m rated torque at each joint, arms "
        f"{1e3 * geometry.l1:.0f}/{1e3 * geometry.l2:.0f} mm, base and platform radii {1e3 * geometry.ra:.0f}/"
        f"{1e3 * geometry.rb:.0f} mm, rated payload {RATED_PAYLOAD:g} kg.",
        "",
    ]


PLANNER_COLORS = {
    "fixed": "tab:blue",
    "worst_case": "tab:orange",
    "declared": "tab:green",
    "online": "tab:red",
    f"worst_case{JERK_LIMITED}": "tab:olive",
    f"declared{JERK_LIMITED}": "tab:cyan",
    f"online{JERK_LIMITED}": "tab:pink",
}
"""The colour of each planner's bars in ``rate.png``."""

FASTEST_COLOR = "tab:gray"
"""The colour of the second controller's fastest fixed timing in ``rate.png``."""

PUBLISHED_STYLES = (("tab:purple", "-"), ("tab:brown", "--"))
"""Colour and line style of each published robot's rates in ``rate.png``, in the order of
:attr:`PublishedSheet.robots`."""


def rate_figure(
    rows: Sequence[Mapping[str, Any]],
    fastest: Sequence[Mapping[str, Any]],
    lead: str,
    name: str,
    sheet: PublishedSheet = ABB_IRB_360,
) -> Any:
    """Picks/min per payload like a data sheet's chart, as a matplotlib figure: a group of bars per payload (and the
    mixed stream), one bar per planner with the lead controller (hatched where the row misses the goals) and one for
    the second controller's fastest fixed timing, and across each group a line at a published robot's rate.

    Bars side by side stay visible where planners give the same rate (every planned timing does with objects of
    one mass). The legend sits outside the axes and lists only what has data.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = [row for row in rows if row["controller"] == lead]
    found = [row for row in fastest if math.isfinite(row["picks_per_min"])]
    ours = {str(row["payload"]) for row in [*own, *found]}
    masses = {float(load) for load in ours if load != MIXED} | {published.payload for published in sheet.rows}
    loads = [payload_label(mass) for mass in sorted(masses)] + [MIXED]
    position = {load: n for n, load in enumerate(loads)}
    planners = list(dict.fromkeys(row["planner"] for row in own))
    series = [
        (f"{planner} timing", PLANNER_COLORS[planner], [row for row in own if row["planner"] == planner])
        for planner in planners
    ]
    if found:
        series.append((f"{found[0]['controller']}, fastest fixed timing", FASTEST_COLOR, found))
    width = 0.8 / max(len(series), 1)

    figure, axis = plt.subplots(figsize=(10.0, 4.8), layout="constrained")
    for n, (label, color, members) in enumerate(series):
        x = [position[str(row["payload"])] + (n - 0.5 * (len(series) - 1)) * width for row in members]
        bars = axis.bar(x, [row["picks_per_min"] for row in members], width, color=color, label=label)
        for bar, row in zip(bars, members, strict=True):
            if "tracking_rms_mm" in row and not holds(row):
                bar.set_hatch("//")
    for robot, (color, style) in zip(sheet.robots, PUBLISHED_STYLES, strict=False):
        published = [p for p in sheet.rows if p.robot == robot]
        centres = np.array([position[payload_label(p.payload)] for p in published], dtype=float)
        axis.hlines(
            [p.picks_per_min for p in published],
            centres - 0.45,
            centres + 0.45,
            colors=color,
            linestyles=style,
            linewidth=3.0,
            zorder=3,
            label=f"{sheet.maker} {robot} ({sheet.cycle})",
        )

    def tick(load: str) -> str:
        if load == MIXED:
            return f"U[0, {RATED_PAYLOAD:g}]"
        if float(load) > RATED_PAYLOAD:
            return f"{load}\n(beyond our rating)"
        return load + (" (rated)" if float(load) == RATED_PAYLOAD else "") + ("" if load in ours else "\n(not run)")

    axis.set_xticks(range(len(loads)), [tick(load) for load in loads])
    axis.set_xlabel("payload (kg); the last group: the mixed stream")
    axis.set_ylabel("picks per minute, 25/305/25 mm cycle")
    rates = [row["picks_per_min"] for row in [*own, *found]] + [p.picks_per_min for p in sheet.rows]
    axis.set_ylim(0.0, 1.12 * max(rates))
    axis.set_title(f"{lead} on {name}; hatched: misses the goals", fontsize="medium")
    axis.grid(True, axis="y", alpha=0.3)
    axis.set_axisbelow(True)
    figure.legend(loc="outside right upper", fontsize=8)
    return figure


def save_rate_figure(
    path: Path, rows: Sequence[Mapping[str, Any]], fastest: Sequence[Mapping[str, Any]], lead: str, name: str
) -> None:
    """:func:`rate_figure` saved to ``path`` (PNG, 120 dpi)."""
    import matplotlib.pyplot as plt

    figure = rate_figure(rows, fastest, lead, name)
    figure.savefig(path, dpi=120)
    plt.close(figure)
