"""Motion and actuator torques of a design over one standard cycle: the analogues of the second paper's Figs. 3-6.

A profile is one 25/305/25 mm cycle of :func:`eval.design.performance.task_cycle` carrying
:data:`eval.design.performance.PAYLOAD` from pick to place, judged by the same design model as the figures of merit
(:func:`eval.design.model.design_model`: rod forearms, the design's masses and drives). The cycle is given in
Cartesian space, so the platform's motion is the same for every design and only the joint motion and the torques
differ. :func:`plot_profiles` writes into the run folder

- ``profiles_joints.png``: motor angle, rate and acceleration of each joint (the paper's Fig. 3, "angular
  directions");
- ``profiles_end_effector.png``: the platform's path in the cycle's vertical plane and its position, velocity and
  acceleration along x, y, z (its Figs. 4 and 5, "Cartesian directions" and "position, velocity and acceleration of
  the end effector");
- ``profiles_torque.png``: each actuator's torque, the carry shaded (its Fig. 6, "actuator torques").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.geometry import GRAVITY, DeltaGeometry, DeltaMasses
from delta_env.trajectories import Trajectory
from delta_env.validation import require_count, require_in
from eval.design.model import design_model, payload_profile
from eval.design.performance import PAYLOAD, TASK_CYCLES, Performance, task_cycle

AXES = ("x", "y", "z")
"""Names of the Cartesian components."""


@dataclass(frozen=True)
class CycleProfile:
    """Time profiles of one standard cycle of a design (SI units, one row per sample).

    Attributes:
        trajectory: The cycle's samples from rest at the pick point: motor angles, rates and accelerations,
            platform position, velocity and acceleration, and their times (``trajectory.time``).
        torque: Actuator torques of the design model (N m), ``(N, 3)``.
        payload: Carried mass (kg), ``(N,)``: the payload between pick and place, else 0.
        centre: Centre of the cycle (m).
        heading: Direction of the travel (rad, from the x axis).
    """

    trajectory: Trajectory
    torque: NDArray[np.float64]
    payload: NDArray[np.float64]
    centre: tuple[float, float, float]
    heading: float

    def describe(self) -> str:
        """The cycle in words: "25/305/25 mm cycle at (x, y, z) m, heading h°, 3.8 kg"."""
        centre = ", ".join(f"{c:g}" for c in self.centre)
        return (
            f"{1e3 * STANDARD_LIFT:g}/{1e3 * STANDARD_TRAVEL:g}/{1e3 * STANDARD_LIFT:g} mm cycle at ({centre}) m, "
            f"heading {math.degrees(self.heading):g}°, {np.max(self.payload):g} kg"
        )


def cycle_profile(
    geometry: DeltaGeometry,
    centre: tuple[float, float, float],
    heading: float,
    *,
    payload: float = PAYLOAD,
    masses: DeltaMasses | None = None,
) -> CycleProfile:
    """The profiles of one standard cycle of ``geometry`` at ``centre`` (m) along ``heading`` (rad).

    Args:
        geometry: The design (m).
        centre: Centre of the cycle (m), as in :data:`eval.design.performance.TASK_CYCLES`.
        heading: Direction of the travel (rad).
        payload: Carried mass (kg), >= 0.
        masses: The design's masses (kg); :func:`delta_env.scaling.scaled_masses` when None.

    Raises:
        ValueError: if the cycle leaves the design's reach or the payload is negative.
    """
    require_in("payload", payload, 0.0, math.inf, unit="kg")
    trajectory = task_cycle(geometry, centre, heading)
    carried = payload_profile(trajectory, payload)
    torque = design_model(geometry, masses).inverse_dynamics(
        trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot, carried
    )
    return CycleProfile(
        trajectory=trajectory,
        torque=torque,
        payload=carried,
        centre=tuple(float(c) for c in centre),
        heading=float(heading),
    )


def worst_cycle(design: Performance) -> int:
    """Index in :data:`eval.design.performance.TASK_CYCLES` of the design's cycle with the largest peak torque.

    Raises:
        ValueError: if the design has no cycle figures (its cycles left its reach).
    """
    if not design.cycles:
        raise ValueError(f"design {design.geometry} has no task-cycle figures: {design.reason}")
    return int(np.argmax([figures.peak_torque for figures in design.cycles]))


def design_profile(design: Performance, cycle: int) -> CycleProfile:
    """The profiles of ``design`` (its geometry and masses) on task cycle ``cycle`` at :data:`PAYLOAD`.

    Args:
        design: The design's figures.
        cycle: Index in :data:`eval.design.performance.TASK_CYCLES`.
    """
    require_count("cycle", cycle, 0, len(TASK_CYCLES) - 1)
    centre, heading = TASK_CYCLES[cycle]
    return cycle_profile(design.geometry, centre, heading, masses=design.masses)


def _shade_carry(axis: plt.Axes, profile: CycleProfile) -> None:
    """Shade the samples where the payload is carried."""
    held = profile.payload > 0.0
    if np.any(held):
        axis.axvspan(
            profile.trajectory.time[held][0], profile.trajectory.time[held][-1], color="orange", alpha=0.12, lw=0
        )


def _plot_joints(profiles: Mapping[str, CycleProfile], path: Path) -> None:
    figure, axes = plt.subplots(3, 3, figsize=(13, 8), sharex=True)
    rows = (("theta", "angle (rad)"), ("theta_dot", "rate (rad/s)"), ("theta_ddot", "acceleration (rad/s²)"))
    for row, (field, label) in enumerate(rows):
        for joint in range(3):
            axis = axes[row, joint]
            for name, profile in profiles.items():
                axis.plot(profile.trajectory.time, getattr(profile.trajectory, field)[:, joint], lw=1.2, label=name)
            axis.set(ylabel=f"joint {joint + 1} {label}")
            axis.grid(alpha=0.3)
    for axis in axes[-1]:
        axis.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7)
    first = next(iter(profiles.values()))
    figure.suptitle(f"Joint motion over one {first.describe()} (the paper's Fig. 3)")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _plot_end_effector(profile: CycleProfile, path: Path) -> None:
    figure, axes = plt.subplots(2, 3, figsize=(13, 7))
    direction = np.array([math.cos(profile.heading), math.sin(profile.heading), 0.0])
    along = (profile.trajectory.xyz - np.asarray(profile.centre)) @ direction
    path_axis = axes[0, 0]
    path_axis.plot(1e3 * along, 1e3 * (profile.trajectory.xyz[:, 2] - profile.centre[2]), "k-")
    path_axis.set(xlabel="along the travel (mm)", ylabel="height above the conveyor (mm)", title="path (side view)")
    path_axis.set_aspect("equal", adjustable="datalim")
    quantities = (
        ("xyz", 1e3, "position (mm)"),
        ("xyz_dot", 1.0, "velocity (m/s)"),
        ("xyz_ddot", 1.0, "acceleration (m/s²)"),
    )
    for axis, (field, scale, label) in zip((axes[0, 1], axes[0, 2], axes[1, 0]), quantities, strict=True):
        values = getattr(profile.trajectory, field)
        for component, name in enumerate(AXES):
            axis.plot(profile.trajectory.time, scale * values[:, component], label=name)
        axis.set(xlabel="time (s)", ylabel=label, title=label.split(" (")[0])
        axis.legend(fontsize=8)
    speed_axis, magnitude_axis = axes[1, 1], axes[1, 2]
    speed_axis.plot(profile.trajectory.time, np.linalg.norm(profile.trajectory.xyz_dot, axis=1), "k-")
    speed_axis.set(xlabel="time (s)", ylabel="|v| (m/s)", title="speed")
    magnitude_axis.plot(profile.trajectory.time, np.linalg.norm(profile.trajectory.xyz_ddot, axis=1) / GRAVITY, "k-")
    magnitude_axis.set(xlabel="time (s)", ylabel="|a| (g)", title="acceleration magnitude")
    for axis in axes.ravel():
        axis.grid(alpha=0.3)
        if axis is not path_axis:
            _shade_carry(axis, profile)
    figure.suptitle(
        f"Platform motion over one {profile.describe()}\nthe same for every design (the paper's Figs. 4 and 5); "
        "shaded: carrying"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _plot_torques(profiles: Mapping[str, CycleProfile], path: Path) -> None:
    figure, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for joint, axis in enumerate(axes):
        for name, profile in profiles.items():
            peak = np.max(np.abs(profile.torque))
            axis.plot(profile.trajectory.time, profile.torque[:, joint], lw=1.2, label=f"{name} (peak {peak:.1f} N m)")
        axis.set(ylabel=f"joint {joint + 1} torque (N m)")
        axis.grid(alpha=0.3)
        _shade_carry(axis, next(iter(profiles.values())))
    axes[-1].set_xlabel("time (s)")
    axes[0].legend(fontsize=7)
    first = next(iter(profiles.values()))
    figure.suptitle(
        f"Actuator torques over one {first.describe()}\ndesign model; shaded: carrying (the paper's Fig. 6)"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def plot_profiles(profiles: Mapping[str, CycleProfile], folder: Path) -> list[Path]:
    """Write the three profile figures (module docstring) of ``profiles`` (by design name) into ``folder``.

    Every profile must run the same cycle, so that the designs compare on one task.

    Returns:
        The paths written.

    Raises:
        ValueError: for no profiles, or profiles of different cycles.
    """
    if not profiles:
        raise ValueError("plot_profiles needs at least one profile")
    first = next(iter(profiles.values()))
    for name, profile in profiles.items():
        if profile.centre != first.centre or profile.heading != first.heading:
            raise ValueError(f"profile {name!r} runs another cycle ({profile.describe()}) than {first.describe()}")
    paths = [folder / f"profiles_{kind}.png" for kind in ("joints", "end_effector", "torque")]
    _plot_joints(profiles, paths[0])
    _plot_end_effector(first, paths[1])
    _plot_torques(profiles, paths[2])
    return paths
