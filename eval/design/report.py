"""Tables and figures of the design study, written into its run folder.

- ``pareto.png``: the Pareto front, workspace against peak torque coloured by picks/min, with the nominal
  and the chosen designs (the second paper's Fig. 10);
- ``maps_horizontal.png`` and ``maps_vertical.png``: conditioning, IMI, det A, min |k_i| and the peak
  torque to accelerate 3.8 kg at 3 g, nominal against the chosen design, on the conveyor plane z = -0.9 m
  and on the vertical plane y = 0;
- ``reconfiguration.png`` (``reconfiguration-<design>.png``): each task profile's objective against the base
  radius its pitch-screw setting gives, over the stroke.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from delta_env import workspace
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import DeltaGeometry
from delta_env.trajectories import WORKING_HEIGHT
from eval.design.codesign import LIGHT_PAYLOAD
from eval.design.optimize import PAPER_TARGETS, shared_roles, unfilled_roles
from eval.design.performance import Performance, peak_torque_map
from eval.design.reconfigure import Reconfiguration
from eval.design.verify import CONTROLLERS, Verification
from eval.metrics import markdown_table

PAPER_CHANGES = {
    "workspace": 100 * PAPER_TARGETS[0],
    "torque": -100 * PAPER_TARGETS[1],
    "speed": 100 * PAPER_TARGETS[2],
}
"""The second paper's reported changes against its nominal robot (%)."""

TORQUE_CHANGE_TOLERANCE = 0.05
"""The 5 % of "the model's predicted torque change must hold on the plant within 5 % of its value", read two
ways (:class:`TorqueChange`): the torque ratio design / nominal within 5 % of the predicted ratio, or the
change itself within 5 % of the predicted change (for a -20 % prediction: -19 % to -21 %)."""

MAP_EXTENT = 0.8
"""Half-width (m) of the slice maps: the conveyors' region and its surroundings."""

MAP_HEIGHTS = (-1.3, -0.5)
"""Heights (m) of the vertical slice maps: from below the reach of the nominal robot to above home."""


def performance_row(performance: Performance) -> dict[str, Any]:
    """One CSV row of a design's figures."""
    g, m = performance.geometry, performance.masses
    return {
        "ra": g.ra,
        "rb": g.rb,
        "l1": g.l1,
        "l2": g.l2,
        "workspace_m3": performance.workspace_m3,
        "peak_torque_nm": performance.peak_torque_nm,
        **drive_columns(performance),
        "rms_torque_nm": performance.rms_torque_nm,
        "speed_m_s": performance.speed_m_s,
        "min_conditioning": performance.min_conditioning,
        "cylinder_diameter_m": performance.cylinder_diameter_m,
        "cylinder_height_m": performance.cylinder_height_m,
        "cylinder_top_m": performance.cylinder_top_m,
        "m1_kg": m.m1,
        "m2_kg": m.m2,
        "m0_kg": m.m0,
    }


GEOMETRY_COLUMNS = ("ra", "rb", "l1", "l2")
"""The columns of :func:`performance_row` that are the design's lengths (m); the others are its figures."""


def file_slug(name: str) -> str:
    """A design's name as a file-name part: "weighted-cost optimum" -> "weighted-cost-optimum"."""
    return "-".join("".join(c if c.isalnum() else " " for c in name.lower()).split())


def design_file_name(name: str) -> str:
    """A design's geometry file name: "weighted-cost optimum" -> "design-weighted-cost-optimum.toml"."""
    return f"design-{file_slug(name)}.toml"


def design_record(name: str, performance: Performance) -> dict[str, Any]:
    """The ``[design]`` table of a design's geometry file: its name and figures (the lengths go in ``[geometry]``)."""
    row = performance_row(performance)
    return {"design": {"name": name, **{k: v for k, v in row.items() if k not in GEOMETRY_COLUMNS}}}


def drive_columns(performance: Performance) -> dict[str, Any]:
    """The CSV columns of a design's pick rates and chosen drive (:mod:`eval.design.codesign`)."""
    drive = performance.drive
    rated = drive.rated if drive else None
    check = rated.check if rated else None
    return {
        "picks_per_min": performance.picks_per_min,
        "picks_per_min_light": performance.picks_per_min_light,
        "motor": rated.option.motor_name if rated else "",
        "gear_ratio": rated.option.ratio if rated else math.nan,
        "drive_peak_torque_nm": check.peak_torque if check else math.nan,
        "drive_rms_torque_nm": check.rms_torque if check else math.nan,
        "drive_max_speed_rad_s": check.max_speed if check else math.nan,
        "drive_peak_share": check.peak_share if check else math.nan,
        "drive_rms_share": check.rms_share if check else math.nan,
        "drive_speed_share": check.speed_share if check else math.nan,
        "drive_exact": rated.exact if rated else False,
    }


def _change(value: float, reference: float) -> float:
    """Change (%) of ``value`` against ``reference``."""
    return 100.0 * (value / reference - 1.0)


def summary_table(
    designs: Mapping[str, Performance], nominal: Performance, reachable: Mapping[str, tuple[float, float]]
) -> str:
    """Designs with their figures and % change against nominal, beside the paper's changes.

    Args:
        designs: Figures by design name, the nominal one included.
        nominal: The nominal design's figures.
        reachable: Reachable volume and its standard error (m^3) by design name, nominal under "nominal".
    """
    header = [
        "Design",
        "ra, rb, l1, l2 (m)",
        "Reachable volume (m³)",
        "Data-sheet cylinder ⌀ x h, top (m)",
        "Workspace (m³)",
        "Peak torque (N m)",
        f"Picks/min at {RATED_PAYLOAD:g} kg",
        f"Picks/min at {LIGHT_PAYLOAD:g} kg",
        "Drive",
        "Speed at 30 rad/s (m/s)",
        "Masses m1, m2, m0 (kg)",
    ]
    rows = []
    for name, p in designs.items():
        g, c, m = p.geometry, p.cylinder, p.masses
        volume, error = reachable[name]
        rows.append(
            [
                name,
                f"{g.ra:.3f}, {g.rb:.3f}, {g.l1:.3f}, {g.l2:.3f}",
                f"{volume:.3f} ± {error:.3f} ({_change(volume, reachable['nominal'][0]):+.1f} %)",
                f"{c.diameter:.3f} x {c.height:.3f}, {c.top:.3f}" if c else "none",
                f"{p.workspace_m3:.4f} ({_change(p.workspace_m3, nominal.workspace_m3):+.1f} %)",
                f"{p.peak_torque_nm:.1f} ({_change(p.peak_torque_nm, nominal.peak_torque_nm):+.1f} %)",
                f"{p.picks_per_min:.1f} ({_change(p.picks_per_min, nominal.picks_per_min):+.1f} %)",
                f"{p.picks_per_min_light:.1f} ({_change(p.picks_per_min_light, nominal.picks_per_min_light):+.1f} %)",
                p.drive.option.label if p.drive and p.drive.option else "none",
                f"{p.speed_m_s:.2f} ({_change(p.speed_m_s, nominal.speed_m_s):+.1f} %)",
                f"{m.m1:.2f}, {m.m2:.3f}, {m.m0:.2f}",
            ]
        )
    paper = PAPER_CHANGES
    rows.append(
        [
            "paper (Hasanlu & Siavashi 2025)",
            "not printed",
            "",
            "",
            f"{paper['workspace']:+.0f} %",
            f"{paper['torque']:+.0f} %",
            "",
            "",
            "",
            f"{paper['speed']:+.0f} % (end-effector speed)",
            "",
        ]
    )
    return markdown_table(header, rows)


def clearance_sentence(clearance: Mapping[str, tuple[float, float]]) -> str:
    """What the collision checks found: each design's smallest (arm-arm, arm-base) clearance (m) in a sentence."""
    figures = ", ".join(f"{name} {1e3 * arm:.0f} / {1e3 * base:.0f} mm" for name, (arm, base) in clearance.items())
    touching = [name for name, (arm, base) in clearance.items() if min(arm, base) <= 0.0]
    verdict = f"Links touch on: {', '.join(touching)}." if touching else "No design's links touch."
    return (
        "Smallest link clearances, arm-arm / arm-base, over each design's cylinder surface and the conveyors' region "
        f"(the plant's link capsules, delta_env.collisions): {figures}. {verdict}"
    )


ROLE_CLAIMS = {
    "paper targets": "beats the paper's gains over its nominal robot in all three objectives",
    "low torque": "needs less peak torque than the nominal robot with at least its workspace",
    "large workspace": "has more workspace than the nominal robot with at most its peak torque",
}
"""What a front design must show to fill each role of :func:`eval.design.optimize.design_roles` that can go
unfilled."""


def roles_sentence(roles: Mapping[str, int]) -> str:
    """Which roles of :func:`eval.design.optimize.design_roles` a design already named fills, and which no front
    design bears out, in sentences ("" when every role has a design of its own)."""
    shared = [f"The {name} design is also the {role} design." for role, name in shared_roles(dict(roles)).items()]
    unfilled = [f"No {role} design: no front design {ROLE_CLAIMS[role]}." for role in unfilled_roles(dict(roles))]
    return " ".join(shared + unfilled)


def verification_rows(verifications: Sequence[Verification]) -> list[dict[str, Any]]:
    """One CSV row per design, controller and figure."""
    rows = []
    for v in verifications:
        for controller in CONTROLLERS:
            rows.append(
                {
                    "design": v.name,
                    "feasible": v.feasible,
                    "reason": v.reason,
                    "controller": controller,
                    "tracking_rms_mm": v.mean(controller, "tracking_rms_mm"),
                    "torque_peak_nm": v.mean(controller, "torque_peak_nm"),
                    "torque_rms_nm": v.mean(controller, "torque_rms_nm"),
                    "max_loop_gap_m": max(
                        (e.max_loop_gap_m for e in v.episodes if e.controller == controller), default=math.nan
                    ),
                    "model_peak_nm": v.predicted_mean("predicted", 0),
                    "model_rms_nm": v.predicted_mean("predicted", 1),
                    "identified_peak_nm": v.predicted_mean("identified", 0),
                    "identified_rms_nm": v.predicted_mean("identified", 1),
                    "rho1": v.parameters.rho1 if v.parameters else math.nan,
                    "rho2": v.parameters.rho2 if v.parameters else math.nan,
                    "drive_lag_ms": 1e3 * float(np.mean(v.drive_lag)) if v.drive_lag else math.nan,
                    "tare_kg": v.tare_kg,
                }
            )
    return rows


def verification_table(verifications: Sequence[Verification]) -> tuple[str, list[str]]:
    """The closed-loop table (model vs plant) and one line per design on the predicted torque change."""
    header = [
        "Design",
        "Plant",
        *(f"{c}: tracking RMS (mm)" for c in CONTROLLERS),
        *(f"{c}: peak / RMS torque (N m)" for c in CONTROLLERS),
        "Model (rods, scaled masses, drives): peak / RMS (N m)",
        "Identified MId+F+R: peak / RMS (N m)",
    ]
    rows = []
    for v in verifications:
        if not v.feasible:
            rows.append([v.name, f"infeasible: {v.reason}", *[""] * (len(header) - 2)])
            continue
        rows.append(
            [
                v.name,
                f"feasible (rho1 {v.parameters.rho1:.2f}, rho2 {v.parameters.rho2:.2f})",
                *(f"{v.mean(c, 'tracking_rms_mm'):.3f}" for c in CONTROLLERS),
                *(f"{v.mean(c, 'torque_peak_nm'):.1f} / {v.mean(c, 'torque_rms_nm'):.1f}" for c in CONTROLLERS),
                f"{v.predicted_mean('predicted', 0):.1f} / {v.predicted_mean('predicted', 1):.1f}",
                f"{v.predicted_mean('identified', 0):.1f} / {v.predicted_mean('identified', 1):.1f}",
            ]
        )
    return markdown_table(header, rows), [change.sentence() for change in torque_changes(verifications)]


@dataclass(frozen=True)
class TorqueChange:
    """A design's torque against the nominal design's, as ratios (design / nominal) of the same figure.

    Attributes:
        design: Design name.
        figure: ``"peak"`` or ``"RMS"``.
        model: Ratio predicted by the design model (links, scaled masses and drives).
        identified: Ratio of the MId+F+R models identified on the two plants.
        plant: Ratio measured on the plants (the oracle controller: the torque each plant needs).
    """

    design: str
    figure: str
    model: float
    identified: float
    plant: float

    def ratio_holds(self, predicted: float, tolerance: float = TORQUE_CHANGE_TOLERANCE) -> bool:
        """Reading 1: the plant's ratio lies within ``tolerance`` (relative) of the ``predicted`` ratio."""
        return abs(self.plant / predicted - 1.0) <= tolerance

    def change_holds(self, predicted: float, tolerance: float = TORQUE_CHANGE_TOLERANCE) -> bool:
        """Reading 2: the plant's change (ratio - 1) lies within ``tolerance`` of the predicted change's size."""
        return abs((self.plant - 1.0) - (predicted - 1.0)) <= tolerance * abs(predicted - 1.0)

    def sentence(self) -> str:
        """One line of the summary: the three changes and both readings of the 5 % criterion."""

        def verdict(predicted: float) -> str:
            readings = (self.ratio_holds(predicted), self.change_holds(predicted))
            return " / ".join("holds" if held else "fails" for held in readings)

        return (
            f"- {self.design}, {self.figure} torque vs nominal: model {100 * (self.model - 1):+.1f} %, plant "
            f"(oracle) {100 * (self.plant - 1):+.1f} %, identified model {100 * (self.identified - 1):+.1f} %. "
            f"Model (ratio / change reading): {verdict(self.model)}; identified model: {verdict(self.identified)}"
        )


def torque_changes(verifications: Sequence[Verification]) -> list[TorqueChange]:
    """Peak and RMS torque changes of every feasible design against the first (nominal) verification."""
    nominal, oracle = verifications[0], CONTROLLERS[2]
    if not nominal.feasible:
        return []
    changes = []
    for v in verifications[1:]:
        if not v.feasible:
            continue
        for figure, index, metric in (("peak", 0, "torque_peak_nm"), ("RMS", 1, "torque_rms_nm")):
            changes.append(
                TorqueChange(
                    design=v.name,
                    figure=figure,
                    model=v.predicted_mean("predicted", index) / nominal.predicted_mean("predicted", index),
                    identified=v.predicted_mean("identified", index) / nominal.predicted_mean("identified", index),
                    plant=v.mean(oracle, metric) / nominal.mean(oracle, metric),
                )
            )
    return changes


def reconfiguration_table(study: Reconfiguration) -> str:
    """Best screw setting per profile, the best fixed setting and what reconfiguring gains."""
    if math.isfinite(study.fixed_ra):
        fixed = f"At fixed ra = {study.fixed_ra:.3f} m (travel {1e3 * study.fixed_travel:.1f} mm)"
    else:
        fixed = "At a fixed setting (none serves every profile)"
    header = ["Task profile", "Objective", "Best setting", "Value there", fixed, "Gain", "Held by"]
    rows = []
    for o in study.outcomes:
        p = o.profile
        if math.isnan(o.best_ra):
            rows.append([p.name, p.label, "no feasible setting", "", "", "", ""])
            continue
        rows.append(
            [
                f"{p.name} ({p.payload:g} kg, zone radius {p.zone_radius:g} m)",
                f"{p.label} ({'max' if p.maximized else 'min'})",
                f"ra = {o.best_ra:.3f} m (travel {1e3 * o.best_travel:.1f} mm)",
                f"{o.best_value:.4g} {p.unit}",
                f"{o.fixed_value:.4g} {p.unit}" if math.isfinite(o.fixed_value) else "-",
                f"{o.gain_percent:.1f} %" if math.isfinite(o.gain_percent) else "-",
                o.limit or "interior optimum",
            ]
        )
    return markdown_table(header, rows)


def plot_pareto(
    front: Sequence[Performance], nominal: Performance, marked: Mapping[str, Performance], path: Path, dpi: int = 110
) -> None:
    """Workspace against peak torque of the front, coloured by picks per minute (the paper's Fig. 10)."""
    figure, axis = plt.subplots(figsize=(7, 5))
    points = axis.scatter(
        [p.workspace_m3 for p in front],
        [p.peak_torque_nm for p in front],
        c=[p.picks_per_min for p in front],
        cmap="viridis",
        s=22,
    )
    figure.colorbar(points, label=f"picks/min at {RATED_PAYLOAD:g} kg, own drive")
    axis.plot(nominal.workspace_m3, nominal.peak_torque_nm, "k*", ms=14, label="nominal")
    for (name, p), marker in zip(marked.items(), "oDs^v", strict=False):
        axis.plot(p.workspace_m3, p.peak_torque_nm, marker, mfc="none", mec="red", ms=11, mew=1.8, label=name)
    axis.set(
        xlabel="data-sheet cylinder above the belt (m³)",
        ylabel="peak torque, 3.8 kg standard cycles at 3 g (N m)",
    )
    # two short lines: one line of this length is wider than the axes and was clipped at both ends
    axis.set_title("Pareto front, every run merged\n(design model: rod forearms, scaled masses, own drives)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=dpi)
    plt.close(figure)


def _map_fields(geometry: DeltaGeometry, plane: str) -> tuple[workspace.SliceMap, dict[str, np.ndarray]]:
    if plane == "horizontal":
        slice_ = workspace.slice_map(
            geometry, plane, WORKING_HEIGHT, (-MAP_EXTENT, MAP_EXTENT), (-MAP_EXTENT, MAP_EXTENT)
        )
    else:
        slice_ = workspace.slice_map(geometry, plane, 0.0, (-MAP_EXTENT, MAP_EXTENT), MAP_HEIGHTS)
    m = slice_.measures
    fields = {
        "1 / cond(J)": m.conditioning,
        "IMI (rad³/m³)": m.imi,
        "|det A| (m³)": np.abs(m.det_a),
        "min |k_i| (m²/rad)": m.min_abs_k,
        "peak torque, 3.8 kg at 3 g (N m)": peak_torque_map(geometry, slice_.points),
    }
    admissible = m.admissible(workspace.REACHABLE)
    return slice_, {name: np.where(admissible, value, np.nan) for name, value in fields.items()}


def plot_maps(designs: Mapping[str, DeltaGeometry], plane: str, path: Path) -> None:
    """Slice maps of each design (rows) and measure (columns); the dexterous boundary drawn in white."""
    names = list(designs)
    figure, axes = plt.subplots(len(names), 5, figsize=(20, 3.8 * len(names)), squeeze=False)
    maps = {name: _map_fields(designs[name], plane) for name in names}
    for column in range(5):
        key = list(maps[names[0]][1])[column]
        values = np.concatenate([maps[name][1][key].ravel() for name in names])
        low, high = np.nanpercentile(values, 1), np.nanpercentile(values, 99)
        for row, name in enumerate(names):
            slice_, fields = maps[name]
            axis = axes[row, column]
            image = axis.pcolormesh(slice_.axis_u, slice_.axis_v, fields[key], vmin=low, vmax=high, shading="auto")
            dexterous = slice_.measures.admissible(workspace.DEXTEROUS).astype(float)
            axis.contour(slice_.axis_u, slice_.axis_v, dexterous, levels=[0.5], colors="white", linewidths=1.0)
            axis.set_aspect("equal")
            axis.set_title(f"{name}: {key}", fontsize=9)
            axis.set_xlabel("x (m)")
            axis.set_ylabel("y (m)" if plane == "horizontal" else "z (m)")
            figure.colorbar(image, ax=axis, shrink=0.8)
    level = f"z = {WORKING_HEIGHT} m" if plane == "horizontal" else "y = 0"
    threshold = workspace.DEXTEROUS_CONDITIONING
    figure.suptitle(f"Slice {level}; white: boundary of the dexterous region (1/cond >= {threshold})")
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def plot_reconfiguration(study: Reconfiguration, path: Path) -> None:
    """Each profile's objective against the base radius its screw setting gives, over the whole stroke."""
    profiles = [o.profile for o in study.outcomes]
    figure, axes = plt.subplots(1, len(profiles), figsize=(4.5 * len(profiles), 3.6), squeeze=False)
    for axis, profile, values, outcome in zip(axes[0], profiles, study.values, study.outcomes, strict=True):
        axis.plot(study.settings, values, "o-", ms=3)
        if not math.isnan(outcome.best_ra):
            axis.plot(outcome.best_ra, outcome.best_value, "g*", ms=12, label="best for this task")
        if not math.isnan(study.fixed_ra):
            axis.axvline(study.fixed_ra, color="grey", ls=":", label="best fixed")
        for end in study.settings[[0, -1]]:
            axis.axvline(end, color="black", lw=0.8)
        label = f"{profile.label} ({profile.unit})"
        axis.set(xlabel="base radius ra (m); black: screw end stops", ylabel=label, title=profile.name)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
