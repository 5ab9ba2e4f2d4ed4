"""The first mode of a design's compliant drives over the task region, empty to rated (issue 36's mode map for
each reported design; docs/design-study.md).

A design's joints are its chosen drive (:mod:`eval.design.codesign`: a catalogue motor behind a planetary ratio)
behind a gearhead. The catalogue lists no gearhead, so each design's is the plant's data-sheet gearhead (the
WITTENSTEIN alpha SP+ 140, :data:`delta_env.config.GEARHEAD_STIFFNESS`, sized for the representative drive's
399 N m peak) scaled to its drive: stiffness in proportion to the drive's peak output torque (a precision gearhead
series' torsional rigidity grows about with its rated torque; an assumption, not a catalogue entry), the damping
for the same damping ratio against a locked arm as the data sheet's drive (0.035), the rotor the drive's own
reflected inertia. The arm side is the design model's links alone (its drives' armature sits on the motor side
here). The two-mass model (:mod:`controllers.compliance`) then gives the first mode at each point.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from controllers.compliance import DriveCompliance
from delta_env.catalogue import DriveOption
from delta_env.config import ARCMIN, GEARHEAD_DAMPING, GEARHEAD_STIFFNESS, RATED_PAYLOAD, ROTOR_INERTIA
from delta_env.drive import REPRESENTATIVE_GEAR_EFFICIENCY, REPRESENTATIVE_GEAR_RATIO, REPRESENTATIVE_MOTOR, DriveLimits
from eval.design.model import design_model
from eval.design.performance import TASK_BAND, TASK_RADIUS, Performance
from eval.identification.compliance import ModeMap, mode_map, workspace_grid

REFERENCE_PEAK_TORQUE = DriveLimits.of(
    REPRESENTATIVE_MOTOR, REPRESENTATIVE_GEAR_RATIO, REPRESENTATIVE_GEAR_EFFICIENCY
).peak_torque
"""Peak output torque (N m) of the drive the data sheet's gearhead was sized for (399 N m)."""

GEARHEAD_DAMPING_RATIO = GEARHEAD_DAMPING / (2.0 * math.sqrt(GEARHEAD_STIFFNESS * ROTOR_INERTIA))
"""Damping ratio of the data sheet's drive against a locked arm (0.035), kept by every scaled gearhead."""

PAYLOADS = (0.0, RATED_PAYLOAD)
"""Payloads (kg) of a design's map: empty and rated."""


def design_gearhead(option: DriveOption) -> DriveCompliance:
    """The scaled gearhead of a design's drive ``option`` (module docstring)."""
    stiffness = GEARHEAD_STIFFNESS * option.limits.peak_torque / REFERENCE_PEAK_TORQUE
    damping = 2.0 * GEARHEAD_DAMPING_RATIO * math.sqrt(stiffness * option.armature)
    return DriveCompliance(option.armature, stiffness, damping)


def design_mode_map(design: Performance) -> ModeMap | None:
    """The first mode over the task region (its axis, half and full radius, 12 azimuths, the task band's two
    heights), empty and rated; None for a design without a drive."""
    option = design.drive.option if design.drive else None
    if option is None:
        return None
    points = workspace_grid(heights=TASK_BAND, radii=(0.0, TASK_RADIUS / 2.0, TASK_RADIUS))
    links = design_model(design.geometry, design.masses, drive=None)
    return mode_map(links, design_gearhead(option), points, PAYLOADS, source=f"{option.label}, scaled SP+ 140")


DRIVE_MODE_COLUMNS = (
    "drive_mode_empty_min_hz",
    "drive_mode_empty_max_hz",
    "drive_mode_rated_min_hz",
    "drive_mode_rated_max_hz",
)
"""The CSV columns of :func:`drive_mode_columns`."""


def drive_mode_columns(modes: ModeMap | None) -> dict[str, Any]:
    """The CSV columns of a design's map: the lowest and highest first mode (Hz) empty and rated."""
    if modes is None:
        return dict.fromkeys(DRIVE_MODE_COLUMNS, math.nan)
    empty, rated = modes.frequency_hz[:, 0], modes.frequency_hz[:, -1]
    values = (empty.min(), empty.max(), rated.min(), rated.max())
    return {name: float(value) for name, value in zip(DRIVE_MODE_COLUMNS, values, strict=True)}


def drive_mode_table(designs: Mapping[str, Performance], maps: Mapping[str, ModeMap | None]) -> list[str]:
    """Markdown: per design its drive, scaled gearhead and first-mode range over the task region (Hz)."""
    lines = [
        "| design | drive | gearhead (N m/arcmin) | rotor (kg m^2) | first mode empty (Hz) | first mode rated (Hz) "
        "| damping ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, modes in maps.items():
        option = designs[name].drive.option if designs[name].drive else None
        if modes is None or option is None:
            lines.append(f"| {name} | none | - | - | - | - | - |")
            continue
        gearhead = design_gearhead(option)
        empty, rated = modes.frequency_hz[:, 0], modes.frequency_hz[:, -1]
        lines.append(
            f"| {name} | {option.label} | {gearhead.stiffness[0] * ARCMIN:.1f} | {gearhead.rotor_inertia[0]:.4f} "
            f"| {empty.min():.0f} to {empty.max():.0f} | {rated.min():.0f} to {rated.max():.0f} "
            f"| {modes.damping_ratio.min():.3f} to {modes.damping_ratio.max():.3f} |"
        )
    return lines
