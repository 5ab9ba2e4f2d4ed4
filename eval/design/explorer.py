"""The interactive Pareto explorer: one self-contained HTML page (``explorer.html`` in the design study's run folder).

The page shows the front (workspace against peak torque, coloured by a speed figure) and the designs' figures in
parallel coordinates (:data:`PARALLEL_COLUMNS` at first, checkboxes add or take away any other figure; brushing an
axis dims the designs outside the brush on the front). Clicking a
design, or choosing it in the list, fills a panel with its lengths and a side-view sketch of one chain, its
data-sheet table (every column of its :func:`eval.design.report.performance_row`, so new columns appear without a
change here), its joint torques and motor angles over the profile cycle (:mod:`eval.design.profiles`, the nominal
robot dashed), and a link to download its geometry file (the ``--geometry`` file of the other command lines, the
same text :func:`delta_env.scenario.save_geometry` writes).

plotly.js is embedded (``include_plotlyjs=True``), so the page works offline; the page's own script is
``explorer.js`` beside this module.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import plotly.graph_objects as go
import plotly.io as pio

from delta_env import kinematics
from delta_env.scenario import geometry_toml
from delta_env.trajectories import WORKING_HEIGHT
from eval.design.performance import Performance
from eval.design.profiles import CycleProfile, design_profile, worst_cycle
from eval.design.report import GEOMETRY_COLUMNS, design_file_name, design_record, performance_row

PROFILE_STRIDE = 2
"""Every how many samples of a profile go into the page: 4 ms, well under the 20-60 ms features of the cycle."""

UNITS = (
    ("_per_min", "/min"),
    ("_rad_s", "rad/s"),
    ("_m_s", "m/s"),
    ("_m3", "m³"),
    ("_nm", "N m"),
    ("_kg", "kg"),
    ("_s", "s"),
    ("_m", "m"),
)
"""Column-name suffixes and their units, longest first: ``cylinder_top_m`` -> "cylinder top (m)"."""

LABELS = {
    "picks_per_min": "picks/min",
    "picks_per_min_light": "picks/min, light payload",
    "rms_torque_nm": "RMS torque (N m)",
    "drive_rms_torque_nm": "drive RMS torque (N m)",
    "min_conditioning": "min 1/cond(J)",
    "drive_peak_share": "drive peak torque share",
    "drive_rms_share": "drive RMS torque share",
    "drive_speed_share": "drive speed share",
}
"""Labels of the columns whose names the rule of :data:`UNITS` does not read well."""

FRONT_X, FRONT_Y = "workspace_m3", "peak_torque_nm"
"""Columns of the front's axes."""

PARALLEL_COLUMNS = (
    *GEOMETRY_COLUMNS,
    FRONT_X,
    FRONT_Y,
    "rms_torque_nm",
    "picks_per_min",
    "speed_m_s",
    "min_conditioning",
)
"""The axes of the parallel coordinates when the page opens: the lengths and the figures the study optimizes or
reports first, few enough that their labels stand apart at 1400 px (the page's checkboxes add the others)."""


def column_label(column: str) -> str:
    """A column name in words with its unit: "peak_torque_nm" -> "peak torque (N m)", "ra" -> "ra (m)"."""
    if column in LABELS:
        return LABELS[column]
    if column in GEOMETRY_COLUMNS:
        return f"{column} (m)"
    for suffix, unit in UNITS:
        if column.endswith(suffix):
            return f"{column[: -len(suffix)].replace('_', ' ')} ({unit})"
    return column.replace("_", " ")


def _finite_or_none(value: Any) -> Any:
    """JSON has no NaN or infinity: those become null (shown as "–")."""
    if isinstance(value, float | np.floating) and not math.isfinite(value):
        return None
    return value.item() if isinstance(value, np.generic) else value


def _sketch(performance: Performance) -> dict[str, float] | None:
    """Chain 1 in its vertical plane with the platform at the conveyor's centre: base and platform joints, elbow (m);
    None when the design cannot reach that point."""
    g = performance.geometry
    try:
        theta = float(kinematics.inverse(g, np.array([0.0, 0.0, WORKING_HEIGHT]))[0])
    except ValueError:
        return None
    return {
        "ra": g.ra,
        "rb": g.rb,
        "elbow_x": g.ra + g.l1 * math.cos(theta),
        "elbow_z": -g.l1 * math.sin(theta),
        "platform_z": WORKING_HEIGHT,
    }


def _profile_data(profile: CycleProfile | None) -> dict[str, Any] | None:
    """A profile thinned to :data:`PROFILE_STRIDE` and rounded for the page (10 us, 0.01 N m, 1e-4 rad)."""
    if profile is None:
        return None
    thin = slice(None, None, PROFILE_STRIDE)
    return {
        "time": np.round(profile.trajectory.time[thin], 5).tolist(),
        "torque": np.round(profile.torque[thin].T, 2).tolist(),
        "theta": np.round(profile.trajectory.theta[thin].T, 4).tolist(),
    }


def _design_entry(name: str, kind: str, performance: Performance, cycle: int) -> dict[str, Any]:
    """One design of the page: its row, geometry file, sketch and profile."""
    try:
        profile = design_profile(performance, cycle)
    except ValueError:  # the cycle leaves this design's reach: the panel says there is no profile
        profile = None
    return {
        "name": name,
        "kind": kind,
        "row": {key: _finite_or_none(value) for key, value in performance_row(performance).items()},
        "file": design_file_name(name),
        "toml": geometry_toml(performance.geometry, design_record(name, performance)),
        "sketch": _sketch(performance),
        "profile": _profile_data(profile),
        "reason": performance.reason,
    }


def _require_nominal(named: Mapping[str, Performance]) -> None:
    if "nominal" not in named:
        raise ValueError(f"named designs must include 'nominal', got {sorted(named)}")


def explorer_designs(
    front: Sequence[Performance], named: Mapping[str, Performance], cycle: int
) -> list[dict[str, Any]]:
    """The page's designs: the named ones first (``named["nominal"]`` first of all), then the front's others.

    A front design with the geometry of a named one is that design; the other front designs are called
    "front design k", k their position in ``front``.
    """
    _require_nominal(named)
    order = {"nominal": named["nominal"], **named}
    entries, seen = [], set()
    for name, performance in order.items():
        if performance.geometry not in seen:
            seen.add(performance.geometry)
            entries.append(_design_entry(name, "nominal" if name == "nominal" else "named", performance, cycle))
    for k, performance in enumerate(front):
        if performance.geometry not in seen:
            seen.add(performance.geometry)
            entries.append(_design_entry(f"front design {k}", "front", performance, cycle))
    return entries


def _front_figure(designs: Sequence[Mapping[str, Any]], colour: str) -> go.Figure:
    """The front: front designs coloured by ``colour``, named designs marked, a ring on the selected one."""
    front = [i for i, d in enumerate(designs) if d["kind"] == "front"]
    named = [i for i, d in enumerate(designs) if d["kind"] != "front"]

    def column(indices: Sequence[int], key: str) -> list[Any]:
        return [designs[i]["row"][key] for i in indices]

    hover = "%{text}<br>workspace %{x:.4f} m³<br>peak torque %{y:.1f} N m<extra></extra>"
    figure = go.Figure(
        [
            go.Scatter(
                x=column(front, FRONT_X),
                y=column(front, FRONT_Y),
                customdata=front,
                text=[designs[i]["name"] for i in front],
                mode="markers",
                name="front",
                showlegend=False,  # a legend swatch has one colour; the colour bar is this trace's key
                marker={
                    "size": 10,
                    "color": column(front, colour),
                    "colorscale": "Viridis",
                    "showscale": True,
                    "colorbar": {"title": {"text": f"front designs:<br>{column_label(colour)}"}},
                },
                hovertemplate=hover,
            ),
            go.Scatter(
                x=column(named, FRONT_X),
                y=column(named, FRONT_Y),
                customdata=named,
                text=[designs[i]["name"] for i in named],
                mode="markers+text",
                textposition="top center",
                name="nominal and chosen designs",
                marker={
                    "size": 14,
                    "symbol": ["star" if designs[i]["kind"] == "nominal" else "diamond" for i in named],
                    "color": "rgba(0,0,0,0)",
                    "line": {"color": "#d62728", "width": 2},
                },
                hovertemplate=hover,
            ),
            go.Scatter(
                x=[designs[0]["row"][FRONT_X]],
                y=[designs[0]["row"][FRONT_Y]],
                mode="markers",
                name="selected",
                hoverinfo="skip",
                marker={"size": 24, "symbol": "circle-open", "color": "black", "line": {"width": 3}},
            ),
        ]
    )
    figure.update_layout(
        title="Pareto front: click a design",
        xaxis_title=column_label(FRONT_X),
        yaxis_title=column_label(FRONT_Y),
        hovermode="closest",
        clickmode="event",
        legend={"orientation": "h", "y": -0.2},
        margin={"l": 70, "r": 20, "t": 50, "b": 60},
    )
    return figure


def parallel_columns(designs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The columns that can be axes of the parallel coordinates: numeric and finite for every design."""
    return [
        key
        for key in designs[0]["row"]
        if all(isinstance(d["row"][key], int | float) and not isinstance(d["row"][key], bool) for d in designs)
    ]


def parallel_dimension(designs: Sequence[Mapping[str, Any]], column: str) -> dict[str, Any]:
    """One axis of the parallel coordinates (explorer.js builds the same for the axes added on the page)."""
    return {
        "label": column_label(column),
        "values": [d["row"][column] for d in designs],
        "tickformat": ".4~g",  # ranges and ticks with 4 significant digits: short, and distinct
    }


def _parallel_figure(designs: Sequence[Mapping[str, Any]]) -> go.Figure:
    """The :data:`PARALLEL_COLUMNS` among :func:`parallel_columns` as axes, in that order; the selected design's line
    in red."""
    columns = [c for c in parallel_columns(designs) if c in PARALLEL_COLUMNS]  # in the order of the rows
    figure = go.Figure(
        go.Parcoords(
            dimensions=[parallel_dimension(designs, c) for c in columns],
            line={"color": [1] + [0] * (len(designs) - 1), "colorscale": [[0, "#8fa9c4"], [1, "#d62728"]]},
            labelangle=0,
            labelfont={"size": 12},
            rangefont={"size": 10},
            tickfont={"size": 10},
        )
    )
    figure.update_layout(
        title="Every design's figures: drag along an axis to brush", margin={"l": 60, "r": 60, "t": 100, "b": 40}
    )
    return figure


def _script_json(value: Any) -> str:
    """``value`` as JSON safe inside a ``<script>`` element."""
    return json.dumps(value, allow_nan=False).replace("</", "<\\/")


def explorer_html(designs: Sequence[Mapping[str, Any]], colour: str, cycle_text: str) -> str:
    """The page of ``designs`` (:func:`explorer_designs`), the front coloured by column ``colour``."""
    if colour not in designs[0]["row"]:
        raise ValueError(f"colour column {colour!r} is not a design column; columns: {', '.join(designs[0]['row'])}")
    front = pio.to_html(_front_figure(designs, colour), full_html=False, include_plotlyjs=True, div_id="front")
    parallel = pio.to_html(_parallel_figure(designs), full_html=False, include_plotlyjs=False, div_id="parallel")
    data = {
        "designs": designs,
        "labels": {key: column_label(key) for key in designs[0]["row"]},
        "geometryColumns": GEOMETRY_COLUMNS,
        "parallelColumns": parallel_columns(designs),
        "cycle": cycle_text,
    }
    script = resources.files("eval.design").joinpath("explorer.js").read_text()
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Delta design explorer</title>
<style>
body {{ font-family: sans-serif; margin: 1em; }}
#top {{ display: flex; gap: 1em; align-items: flex-start; }}
#front-box {{ flex: 1 1 auto; min-width: 0; }}
#panel {{ flex: 0 0 520px; border: 1px solid #ccc; padding: 0.5em 1em; }}
#panel table {{ border-collapse: collapse; font-size: 0.9em; }}
#panel td, #panel th {{ border-bottom: 1px solid #eee; padding: 2px 8px; text-align: left; }}
.small-plot {{ height: 220px; }}
#axes label {{ display: inline-block; margin-right: 1.2em; font-size: 0.9em; }}
</style></head>
<body>
<h1>Delta design explorer</h1>
<p>Design model: rod forearms, masses scaled with the lengths, its own catalogue drive each.
Profiles: {cycle_text}.
<label>Design: <select id="design-select"></select></label></p>
<div id="top">
<div id="front-box">{front}</div>
<div id="panel">
<h2 id="design-name"></h2>
<p id="design-reason"></p>
<h3>Geometry</h3><table id="geometry-table"></table>
<div id="sketch" class="small-plot"></div>
<h3>Data sheet</h3><table id="datasheet"></table>
<div id="torque-plot" class="small-plot"></div>
<div id="angle-plot" class="small-plot"></div>
<p><a id="download" href="#">Download the geometry file</a> (for <code>--geometry</code>)</p>
</div>
</div>
{parallel}
<fieldset id="axes"><legend>Axes of the parallel coordinates</legend></fieldset>
<script>const EXPLORER = {_script_json(data)};</script>
<script>{script}</script>
</body></html>
"""


def write_explorer(
    front: Sequence[Performance],
    named: Mapping[str, Performance],
    path: Path,
    *,
    colour: str = "picks_per_min",
    cycle: int | None = None,
) -> Path:
    """Write the explorer page of ``front`` and the ``named`` designs (``"nominal"`` among them) to ``path``.

    Args:
        front: The front's designs.
        named: The nominal and chosen designs by name.
        path: The HTML file.
        colour: Column that colours the front (a speed figure).
        cycle: Task cycle of the profiles (index in :data:`eval.design.performance.TASK_CYCLES`); the nominal
            design's worst when None.

    Returns:
        ``path``.
    """
    _require_nominal(named)
    cycle = worst_cycle(named["nominal"]) if cycle is None else cycle
    designs = explorer_designs(front, named, cycle)
    profile = design_profile(named["nominal"], cycle)
    path.write_text(explorer_html(designs, colour, profile.describe()), encoding="utf-8")
    return path
