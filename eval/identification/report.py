"""The Markdown validation report of an identification and its figures (``python -m eval.identification``).

The report compares every model on the held-out data (the paper's Table 1 analogue, errors by joint speed),
lists the identified parameters (against the plant's truth for a simulation: :func:`ground_truth`, read by this
report only), refits the friction at other velocity thresholds and shows the drive lag and the run time; the
figures (the paper's Fig. 3-6a) are made from the saved validation data (:func:`save_validation_data`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from controllers.compliance import DriveCompliance
from controllers.dynamics import DeltaDynamics
from controllers.identification import (
    COMPLIANCE_PARAMETER_NAMES,
    FRICTION_VELOCITY_THRESHOLD,
    JOINT_PARAMETER_NAMES,
    error_table,
    fit_joint_least_squares,
)
from delta_env.config import ARCMIN, PlantConfig
from delta_env.geometry import GRAVITY
from delta_env.kernels import STRIBECK_PEAK
from eval.identification.compliance import mode_map, mode_map_lines, workspace_grid
from eval.identification.run import IdentificationRun

FIGURES = {
    "fig3_mkh.png": "MKH",
    "fig4_mid_paper.png": "MId (paper)",
    "fig5_mid_f_paper.png": "MId+F (paper)",
    "fig5b_mid_f_joint_ls.png": "MId+F (joint LS)",
}
"""Torque-profile figures like the paper's Fig. 3-5, by file name."""

SPEED_BANDS = (
    (0.0, 0.0, "at rest"),
    (0.0, FRICTION_VELOCITY_THRESHOLD, f"0-{FRICTION_VELOCITY_THRESHOLD:g} rad/s"),
    (FRICTION_VELOCITY_THRESHOLD, np.inf, f"> {FRICTION_VELOCITY_THRESHOLD:g} rad/s"),
)
"""Speed bands (low, high, label) of |theta_dot_i| for the error breakdown; (0, 0) means exactly 0."""

THRESHOLD_SWEEP = (0.1, 0.2, 0.5, 1.0, 2.0)
"""Friction velocity thresholds (rad/s) of the report's trade-off table."""

TARGET_STD_RATIO = 0.25
"""Goal: std of the MId+F error <= this x std of the MKH error on every joint (the paper's Table 1)."""


def ground_truth(plant: PlantConfig) -> dict[str, Any]:
    """The plant's true friction (N m s/rad, N m), Stribeck excess (N m) and its decay speed (rad/s), and drive lag (s)
    per joint, and a compliant plant's gearheads (:data:`COMPLIANCE_PARAMETER_NAMES`, SI): ground truth for this
    report only."""
    realism = plant.realism
    truth = {
        "viscous": realism.viscous_per_joint.tolist(),
        "coulomb": realism.coulomb_per_joint.tolist(),
        "drive_lag": [realism.actuator_lag] * 3,
        "stribeck_excess": (realism.stribeck_excess * realism.coulomb_per_joint).tolist(),
        "stribeck_velocity": [realism.stribeck_velocity],
    }
    gearhead = realism.compliance
    if gearhead is not None:
        truth["compliance"] = [
            [gearhead.rotor_inertia] * 3,
            realism.viscous_per_joint.tolist(),
            realism.coulomb_per_joint.tolist(),
            gearhead.stiffness_per_joint.tolist(),
            gearhead.damping_per_joint.tolist(),
            [gearhead.backlash] * 3,
        ]
    return truth


COMPLIANCE_UNITS = ("kg m^2", "N m s/rad", "N m", "N m/rad", "N m s/rad", "arcmin")
"""Units of :data:`COMPLIANCE_PARAMETER_NAMES` in the report (the backlash in arcmin)."""


def _compliance_lines(run: IdentificationRun, truth: dict[str, Any] | None) -> list[str]:
    """The drives' identified parameters per joint with their SE and truth, and the first-mode map."""
    result = run.result
    if "compliance" not in result.provenance:
        return ["Rigid drives: no compliance."]
    if result.compliance is None:
        return [
            f"{result.provenance['compliance']['method'].capitalize()} (docs/design.md section 7).",
            "",
            *_mode_map_lines(run, DriveCompliance.nominal(), "the data sheet's drives"),
        ]
    fit = result.provenance["compliance"]["fit"]
    true = None if truth is None else truth.get("compliance")
    lines = [
        f"{result.provenance['compliance']['method']}.",
        "",
        "The motor's friction here leaves out its Stribeck excess and is biased by tens of per cent (the rigid fits "
        "above are the friction the controllers use); the damping's torque is a few per cent of the spring's at the "
        "mode, so it comes out within about 20 %; the stiffness and the backlash are what this fit is for. The +- are "
        "standard errors from the spread of the fits to single periods: the periods' noise only, far under the "
        "stiffness's error on plants of known stiffness (10 to 30 times from the motor side alone; a bias common to "
        "every period is not in them).",
        "",
        "| parameter | unit | joint 1 | joint 2 | joint 3 |" + (" ground truth | error (%) |" if true else ""),
        "|---|---|---|---|---|" + ("---|---|" if true else ""),
    ]
    for index, (name, unit) in enumerate(zip(COMPLIANCE_PARAMETER_NAMES, COMPLIANCE_UNITS, strict=True)):
        if name not in fit["estimate"]:
            continue  # the backlash, from the motor side alone
        scale = 1.0 / ARCMIN if name == "backlash" else 1.0
        values = scale * np.array(fit["estimate"][name])
        errors = scale * np.array(fit["standard_errors"][name])
        cells = " | ".join(f"{v:.4g} +- {e:.2g}" for v, e in zip(values, errors, strict=True))
        row = f"| {name} | {unit} | {cells} |"
        if true:
            reference = scale * np.array(true[index])
            relative = [f"{100 * (v - t) / t:+.1f}" if t else "-" for v, t in zip(values, reference, strict=True)]
            row += f" {', '.join(f'{t:.4g}' for t in reference)} | {', '.join(relative)} |"
        lines.append(row)
    return [*lines, "", *_mode_map_lines(run, result.compliance, "the identified drives")]


def _mode_map_lines(run: IdentificationRun, compliance: DriveCompliance, source: str) -> list[str]:
    """The first-mode map of the two-mass model with ``compliance`` on the robot's datasheet arm."""
    model = run.models["MKH"]
    dynamics = DeltaDynamics.of_robot(model.geometry, model.masses, forearm_rods=True)
    modes = mode_map(dynamics, compliance, workspace_grid(), source=source)
    lowest = modes.summary()["payloads_kg"]
    return [
        "### First-mode map",
        "",
        f"The two-mass model (the datasheet arm with rod forearms, {source}; docs/design.md section 4) over the "
        "workspace: the first mode's natural frequency per height and distance from the axis, its range over the "
        "azimuths, empty to rated; the damping ratio over the ring and payloads.",
        "",
        *mode_map_lines(modes),
        "",
        "Lowest first mode: "
        + "; ".join(
            f"{payload}: {row['lowest_hz']:.1f} Hz at ({', '.join(f'{v:.2f}' for v in row['lowest_at_m'])}) m"
            for payload, row in lowest.items()
        )
        + ".",
    ]


def save_validation_data(run: IdentificationRun, path: Path) -> None:
    """The held-out samples and every model's torque along them, for the figures (npz)."""
    data = run.validation
    torques = {
        f"model_{index}": model.inverse_dynamics(data.theta, data.theta_dot, data.theta_ddot)
        for index, model in enumerate(run.models.values())
    }
    np.savez_compressed(
        path,
        dt=run.result.provenance["method"]["sample_period_s"],
        theta=data.theta,
        theta_dot=data.theta_dot,
        theta_ddot=data.theta_ddot,
        torque=data.torque,
        model_names=np.array(list(run.models)),
        **torques,
    )


def plot_figures(validation_file: Path, folder: Path) -> list[Path]:
    """Torque profiles (the paper's Fig. 3-5) and error bars (Fig. 6a) from the saved validation data."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    saved = np.load(validation_file)
    names = [str(name) for name in saved["model_names"]]
    time = np.arange(len(saved["torque"])) * float(saved["dt"])
    written = []
    for file_name, model in FIGURES.items():
        estimate = saved[f"model_{names.index(model)}"]
        figure, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 7), constrained_layout=True)
        for joint, axis in enumerate(axes):
            axis.plot(time, saved["torque"][:, joint], color="0.3", linewidth=0.8, label="measured tau")
            axis.plot(time, estimate[:, joint], color="tab:red", linewidth=0.8, label=f"{model} tau_hat")
            axis.set_ylabel(f"tau{joint + 1} (N m)")
            axis.grid(alpha=0.3)
        axes[0].legend(loc="upper right")
        axes[0].set_title(f"Held-out stress trajectory: measured torque vs {model}")
        axes[-1].set_xlabel("time (s)")
        figure.savefig(folder / file_name, dpi=110)
        plt.close(figure)
        written.append(folder / file_name)

    figure, axis = plt.subplots(figsize=(9, 4), constrained_layout=True)
    width = 0.8 / len(names)
    for index, name in enumerate(names):
        errors = saved["torque"] - saved[f"model_{index}"]
        positions = np.arange(3) + (index - (len(names) - 1) / 2) * width
        axis.bar(positions, errors.mean(axis=0), width, yerr=errors.std(axis=0), capsize=3, label=name)
    axis.set_xticks(np.arange(3), [f"tau{joint + 1}" for joint in range(3)])
    axis.set_ylabel("tau - tau_hat (N m): mean and std")
    axis.axhline(0.0, color="black", linewidth=0.6)
    axis.legend(fontsize=8)
    axis.set_title("Held-out stress trajectory (the paper's Fig. 6a)")
    figure.savefig(folder / "fig6a_error_bars.png", dpi=110)
    plt.close(figure)
    written.append(folder / "fig6a_error_bars.png")
    return written


def _table1(table: dict[str, Any]) -> list[str]:
    header = "| joint | " + " | ".join(f"{name} mu | {name} sigma" for name in table) + " |"
    lines = [header, "|---" * (1 + 2 * len(table)) + "|"]
    for joint in range(3):
        cells = [f"{row['mean'][joint]:.2f} | {row['std'][joint]:.2f}" for row in table.values()]
        lines.append(f"| tau{joint + 1} (N m) | " + " | ".join(cells) + " |")
    return lines


def _std_ratio_lines(table: dict[str, Any]) -> list[str]:
    lines = ["| model | sigma / sigma_MKH, joints 1-3 | goal <= 0.25 on every joint |", "|---|---|---|"]
    reference = np.array(table["MKH"]["std"])
    for name in ("MId+F (paper)", "MId+F (joint LS)", "MId+F+R (joint LS)"):
        ratio = np.array(table[name]["std"]) / reference
        verdict = "met" if np.all(ratio <= TARGET_STD_RATIO) else "NOT met"
        lines.append(f"| {name} | {', '.join(f'{r:.3f}' for r in ratio)} | {verdict} |")
    return lines


def _speed_band_lines(validation_file: Path) -> list[str]:
    saved = np.load(validation_file)
    names = [str(name) for name in saved["model_names"]]
    speed = np.abs(saved["theta_dot"])
    bands = []
    for low, high, label in SPEED_BANDS:
        inside = speed == 0.0 if high == 0.0 else (speed > low) & (speed <= high)
        bands.append((label, inside))
    header = "| model | " + " | ".join(f"{label} ({inside.mean():.0%})" for label, inside in bands) + " |"
    lines = [header, "|---" * (1 + len(bands)) + "|"]
    for index, name in enumerate(names):
        errors = saved["torque"] - saved[f"model_{index}"]
        cells = [f"{np.sqrt(np.mean(errors[inside] ** 2)):.2f}" for _, inside in bands]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _parameter_lines(run: IdentificationRun, truth: dict[str, list[float]] | None) -> list[str]:
    result = run.result
    spread = result.provenance["mid_f_between_trajectories"]["standard_error_of_mean"]
    lines = [
        "| parameter | MId (LS) | MId+F joint LS +- SE (between-trajectory SE) | paper MId | paper MId+F "
        "| ground truth | joint LS error | paper error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for index, name in enumerate(JOINT_PARAMETER_NAMES):
        if index < 2:
            ours, paper = getattr(result.mid_f, name), getattr(result.paper_mid_f, name)
            mid, paper_mid, true = f"{getattr(result.mid, name):.4f}", f"{getattr(result.paper_mid, name):.4f}", None
        else:
            kind, joint = name.rsplit("_", 1)
            j = int(joint) - 1
            ours, paper = getattr(result.mid_f, kind)[j], getattr(result.paper_mid_f, kind)[j]
            mid = paper_mid = "-"
            true = None if truth is None else truth[kind][j]
        error = result.standard_errors[f"mid_f.{name}"]
        between = spread[name]
        between_text = "n/a" if between is None else f"{between:.4f}"
        if true is None:
            truth_cells = f"{'unknown' if truth is None else '(no physical truth)'} | - | -"
        else:
            truth_cells = f"{true:.3f} | {100 * (ours - true) / true:+.1f} % | {100 * (paper - true) / true:+.1f} %"
        lines.append(
            f"| {name} | {mid} | {ours:.4f} +- {error:.4f} ({between_text}) | {paper_mid} | {paper:.4f} "
            f"| {truth_cells} |"
        )
    return lines


def _threshold_lines(run: IdentificationRun, truth: dict[str, list[float]] | None) -> list[str]:
    """Joint LS at other friction velocity thresholds: friction error (the friction itself without a truth) vs
    held-out accuracy."""
    paper_std = np.array(run.result.provenance["torque_error_validation"]["MId+F (paper)"]["std"])
    friction = "fv error (%) | fc error (%)" if truth else "fv (N m s/rad) | fc (N m)"
    lines = [
        f"| threshold (rad/s) | {friction} | held-out sigma (N m) | sigma / paper MId+F sigma |",
        "|---|---|---|---|---|",
    ]
    number = "+.1f" if truth else ".3f"
    for threshold in THRESHOLD_SWEEP:
        try:
            parameters = fit_joint_least_squares(
                run.data, dynamics=run.models["MKH"], velocity_threshold=threshold
            ).parameters
        except ValueError as failure:
            lines.append(f"| {threshold:g} | not identifiable: {failure} | | | |")
            continue
        error = np.array([*parameters.viscous, *parameters.coulomb])
        if truth is not None:
            true = np.array([*truth["viscous"], *truth["coulomb"]])
            error = 100.0 * (error - true) / true
        model = run.models["MKH"].with_parameters(parameters)
        sigma = np.array(error_table({"ls": model}, run.validation)["ls"]["std"])
        marker = " (default)" if threshold == FRICTION_VELOCITY_THRESHOLD else ""
        lines.append(
            f"| {threshold:g}{marker} | {', '.join(f'{e:{number}}' for e in error[:3])} | "
            f"{', '.join(f'{e:{number}}' for e in error[3:])} | {', '.join(f'{v:.3f}' for v in sigma)} | "
            f"{', '.join(f'{v:.3f}' for v in sigma / paper_std)} |"
        )
    return lines


def _data_lines(provenance: dict[str, Any], command: str) -> list[str]:
    """What the identification ran on: the simulated trajectories or the log files, and the held-out one."""
    samples = provenance["samples"]
    if "logs" in provenance:
        held_out = provenance["validation_log"]
        return [
            f"`{command}` on {provenance['date']}: {len(provenance['logs'])} logs "
            f"({samples['total']} samples after resampling and trimming) of the robot of "
            f"{provenance['plant']['robot_file']} (identity {provenance['plant']['identity']}).",
            f"Held-out log: {held_out['path']}, {held_out['duration_s']:g} s ({samples['validation']} samples).",
        ]
    held_out = provenance["validation_trajectory"]
    peak_g = held_out["peak_acceleration"] / GRAVITY
    return [
        f"`{command}` on {provenance['date']}: {len(provenance['trajectories'])} excitation trajectories "
        f"({samples['total']} samples after trimming), seed {provenance['seed']}.",
        f"Held-out free-motion stress trajectory (the paper's upsilon_F): episode seed {held_out['seed']}, "
        f"{held_out['duration']:g} s, fast moves of {peak_g * held_out['min_acceleration_fraction']:g} to "
        f"{peak_g:g} g, {held_out['edge_fraction']:.0%} to the workspace edge ({samples['validation']} samples).",
    ]


def _drive_lag_lines(run: IdentificationRun, truth: dict[str, list[float]] | None) -> list[str]:
    """The identified drive lag per joint, its spread over the trajectories and the truth when known."""
    per_trajectory = np.array(run.result.provenance["drive_lag_per_trajectory_s"])
    if per_trajectory.size == 0:
        return [
            "Not identified: the logs have no commands. The parameter file holds none (null): the controllers that "
            "lead the drive lag (mid_f_rls_lag, the residual's base) and the planned timings refuse it."
        ]
    lag = 1e3 * np.array(run.result.drive_lag)
    line = (
        f"T per joint: {', '.join(f'{v:.3f}' for v in lag)} ms, the median over {len(per_trajectory)} trajectories "
        f"(spread {1e3 * per_trajectory.min():.3f} to {1e3 * per_trajectory.max():.3f} ms)"
    )
    if truth is None:
        return [line + "."]
    true = 1e3 * np.array(truth["drive_lag"])
    errors = ", ".join(f"{e:+.1f}" for e in 100.0 * (lag - true) / true) if np.all(true > 0) else "-"
    return [line + f"; ground truth {', '.join(f'{v:.3f}' for v in true)} ms, error {errors} %."]


def _stribeck_lines(run: IdentificationRun, truth: dict[str, list[float]] | None) -> list[str]:
    """The identified Stribeck excess per joint with its SE, its decay speed, the breakaway and the truth if known."""
    result = run.result
    if result.stribeck_excess is None:
        return [
            f"{run.result.provenance['method']['stribeck'].capitalize()}. The servo layer pushes the Coulomb friction "
            "at rest."
        ]
    errors = [result.standard_errors.get(f"stribeck.excess_{j}", math.nan) for j in (1, 2, 3)]
    excess = ", ".join(f"{v:.2f} (SE {e:.2f})" for v, e in zip(result.stribeck_excess, errors, strict=True))
    lines = [
        f"Excess fs per joint: {excess} "
        f"N m, decaying over vs = {result.stribeck_velocity:.3f} rad/s, fitted on "
        f"{', '.join(str(n) for n in run.result.provenance['stribeck_rows_per_joint'])} slow moving rows; "
        f"breakaway fc + fs {', '.join(f'{v:.2f}' for v in result.breakaway)} N m (what the servo pushes at rest)."
    ]
    if truth is not None:
        # what the plant's excess resists at most on the way out of rest (its smooth sign is 0 at rest)
        true = np.array(truth["coulomb"]) + STRIBECK_PEAK * np.array(truth["stribeck_excess"])
        lines.append(
            f"Ground truth: fs {', '.join(f'{v:.2f}' for v in truth['stribeck_excess'])} N m, vs "
            f"{truth['stribeck_velocity'][0]:.3f} rad/s; breakaway (fc + {STRIBECK_PEAK:.2f} fs) "
            f"{', '.join(f'{v:.2f}' for v in true)} N m, error "
            f"{', '.join(f'{e:+.1f}' for e in 100.0 * (np.array(result.breakaway) - true) / true)} %."
        )
    return lines


def render_report(
    run: IdentificationRun,
    validation_file: Path,
    command: str,
    figures: list[Path],
    truth: dict[str, list[float]] | None,
) -> str:
    """The Markdown validation report of an identification; ``truth`` is the plant's friction and drive lag
    (:func:`ground_truth`), None for logs."""
    provenance = run.result.provenance
    table = provenance["torque_error_validation"]
    times = provenance["run_time_s"]
    residuals = provenance["residuals"]
    truth_note = (
        "Ground truth: the identified plant's friction (its `PlantConfig.realism`), read by this report only."
        if truth
        else "Ground truth: unknown (identified from logs)."
    )
    lines = [
        "# Identification report",
        "",
        *_data_lines(provenance, command),
        "",
        "## Table 1 analogue: tau - tau_hat on the held-out trajectory (N m)",
        "",
        *_table1(table),
        "",
        *_std_ratio_lines(table),
        "",
        "RMS error (N m, all joints) by joint speed |theta_dot_i| on the held-out trajectory:",
        "",
        *_speed_band_lines(validation_file),
        "",
        "## Identified parameters",
        "",
        f"{truth_note} rho1 and rho2 have no physical truth (they absorb armature, the real arm and forearm inertia).",
        "SE = sigma^2 (X^T X)^-1 over rows 1 ms apart whose residuals are correlated: optimistic. "
        "The between-trajectory SE (spread of per-trajectory fits / sqrt(n)) is the honest one.",
        "",
        *_parameter_lines(run, truth),
        "",
        f"Joint LS residual RMS {residuals['mid_f']['residual_rms']:.3f} N m over "
        f"{sum(residuals['mid_f']['rows_per_joint'])} rows (per joint "
        f"{', '.join(f'{v:.3f}' for v in residuals['mid_f']['residual_rms_per_joint'])}); "
        f"rows with |theta_dot_i| <= {provenance['method']['velocity_threshold_rad_s']} rad/s left out.",
        "",
        "### Friction velocity threshold: truth of the friction vs held-out accuracy",
        "",
        "Joint LS refitted with other thresholds (rows with |theta_dot_i| <= threshold left out). Below "
        "about 1 rad/s the plant's friction is not fv thd + fc sign(thd) (Stribeck excess; MuJoCo's soft "
        "Coulomb friction reverses while a joint brakes hard at low speed): lower thresholds pull fc down, "
        "which fits those samples better and the true friction worse.",
        "",
        *_threshold_lines(run, truth),
        "",
        "## Stribeck excess and breakaway",
        "",
        *_stribeck_lines(run, truth),
        "",
        "## Drive lag",
        "",
        *_drive_lag_lines(run, truth),
        "",
        "## Compliant drives",
        "",
        *_compliance_lines(run, truth),
        "",
        "## Run time (s)",
        "",
        "| data collection + smoothing | joint LS (both fits) | paper method (grid + friction LS) | total |",
        "|---|---|---|---|",
        f"| {times['data_collection_and_smoothing']:.2f} | {times['joint_least_squares']:.3f} | "
        f"{times['paper_method']:.3f} | {times['total']:.2f} |",
        "",
        f"Fits {times['fits_timed_as']}; {provenance['workers']} worker process(es).",
        "",
        "## Figures",
        "",
        *[f"![{path.stem}]({path.name})" for path in figures],
        "",
    ]
    return "\n".join(lines)
