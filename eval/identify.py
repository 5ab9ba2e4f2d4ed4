"""``python -m eval.identify``: identify MId, MId+F and MId+F+R on the plant and write a validation report.

The plant is the robot of ``--scenario`` (and ``--geometry``); its condition (wear) and task do not enter:
an identification belongs to the robot. Runs :func:`eval.identification.run_identification`, writes the
parameter file into the run folder and (unless ``--no-install``) to the path the controllers of that robot
load (``<runs root>/identification/<robot identity>/parameters.json``; :func:`eval.run_folder.runs_root`), the
scenario (``scenario.toml``), the manifest (``config.json``), the held-out validation data, a Markdown report and the
figures
(made from the saved data), and prints the report.

The report compares the identified friction with the plant's true values: the only place that reads
the plant's truth, labelled as ground truth for the report; the identification never sees it.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from controllers.identification import (
    FRICTION_VELOCITY_THRESHOLD,
    JOINT_PARAMETER_NAMES,
    error_table,
    fit_joint_least_squares,
    save_result,
)
from delta_env.config import PlantConfig
from delta_env.geometry import GRAVITY
from eval.identification import (
    DEFAULT_DURATION,
    DEFAULT_TRAJECTORIES,
    VALIDATION_DURATION,
    IdentificationRun,
    identification_root,
    parameter_path,
    run_identification,
)
from eval.run_folder import Run, add_runs_dir_argument, command_line, run_folder, utc_stamp
from eval.scenario_args import add_scenario_arguments, check_ranges, scenario_from_arguments

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


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m eval.identify", description=__doc__.splitlines()[0])
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of trajectories and sensor noise")
    parser.add_argument("--trajectories", type=int, default=DEFAULT_TRAJECTORIES, help="excitation trajectories")
    parser.add_argument("--duration", type=float, default=DEFAULT_DURATION, help="length of each trajectory (s)")
    parser.add_argument(
        "--validation-duration", type=float, default=VALIDATION_DURATION, help="held-out stress trajectory (s)"
    )
    parser.add_argument("--workers", type=int, default=None, help="processes (default: up to 2 cores)")
    parser.add_argument(
        "--out", type=Path, default=None, help="run folder (default <runs root>/identification/<UTC time>_seed<seed>)"
    )
    add_runs_dir_argument(parser)
    parser.add_argument(
        "--parameters",
        type=Path,
        default=None,
        help="parameter file the controllers load (default: <runs root>/identification/<robot identity>/"
        "parameters.json)",
    )
    parser.add_argument("--no-install", action="store_true", help="write the parameters to the run folder only")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    arguments = parser.parse_args(argv)
    check_ranges(parser, arguments, {"seed": 0, "trajectories": 1, "workers": 1}, ("duration", "validation_duration"))
    arguments.scenario = scenario_from_arguments(arguments, parser)
    if arguments.parameters is None:
        arguments.parameters = parameter_path(arguments.scenario.plant, identification_root(arguments.runs_dir))
    return arguments


def _ground_truth(plant: PlantConfig) -> dict[str, list[float]]:
    """The plant's true friction (ground truth for this report only)."""
    realism = plant.realism
    return {"viscous": realism.viscous_per_joint.tolist(), "coulomb": realism.coulomb_per_joint.tolist()}


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


def _parameter_lines(run: IdentificationRun, truth: dict[str, list[float]]) -> list[str]:
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
            true = truth[kind][j]
        error = result.standard_errors[f"mid_f.{name}"]
        between = spread[name]
        between_text = "n/a" if between is None else f"{between:.4f}"
        if true is None:
            truth_cells = "(no physical truth) | - | -"
        else:
            truth_cells = f"{true:.3f} | {100 * (ours - true) / true:+.1f} % | {100 * (paper - true) / true:+.1f} %"
        lines.append(
            f"| {name} | {mid} | {ours:.4f} +- {error:.4f} ({between_text}) | {paper_mid} | {paper:.4f} "
            f"| {truth_cells} |"
        )
    return lines


def _threshold_lines(run: IdentificationRun, truth: dict[str, list[float]]) -> list[str]:
    """Joint LS at other friction velocity thresholds: friction error vs held-out accuracy."""
    true = np.array([*truth["viscous"], *truth["coulomb"]])
    paper_std = np.array(run.result.provenance["torque_error_validation"]["MId+F (paper)"]["std"])
    lines = [
        "| threshold (rad/s) | fv error (%) | fc error (%) | held-out sigma (N m) | sigma / paper MId+F sigma |",
        "|---|---|---|---|---|",
    ]
    for threshold in THRESHOLD_SWEEP:
        try:
            parameters = fit_joint_least_squares(
                run.data, dynamics=run.models["MKH"], velocity_threshold=threshold
            ).parameters
        except ValueError as failure:
            lines.append(f"| {threshold:g} | not identifiable: {failure} | | | |")
            continue
        error = 100.0 * (np.array([*parameters.viscous, *parameters.coulomb]) - true) / true
        model = run.models["MKH"].with_parameters(parameters)
        sigma = np.array(error_table({"ls": model}, run.validation)["ls"]["std"])
        marker = " (default)" if threshold == FRICTION_VELOCITY_THRESHOLD else ""
        lines.append(
            f"| {threshold:g}{marker} | {', '.join(f'{e:+.1f}' for e in error[:3])} | "
            f"{', '.join(f'{e:+.1f}' for e in error[3:])} | {', '.join(f'{v:.3f}' for v in sigma)} | "
            f"{', '.join(f'{v:.3f}' for v in sigma / paper_std)} |"
        )
    return lines


def render_report(
    run: IdentificationRun, validation_file: Path, command: str, figures: list[Path], plant: PlantConfig
) -> str:
    """The Markdown validation report of the identification of ``plant``."""
    provenance = run.result.provenance
    table = provenance["torque_error_validation"]
    times = provenance["run_time_s"]
    residuals = provenance["residuals"]
    held_out = provenance["validation_trajectory"]
    truth = _ground_truth(plant)
    peak_g = held_out["peak_acceleration"] / GRAVITY
    lines = [
        "# Identification report",
        "",
        f"`{command}` on {provenance['date']}: {len(provenance['trajectories'])} excitation trajectories "
        f"({provenance['samples']['total']} samples after trimming), seed {provenance['seed']}.",
        f"Held-out free-motion stress trajectory (the paper's upsilon_F): episode seed {held_out['seed']}, "
        f"{held_out['duration']:g} s, fast moves of {peak_g * held_out['min_acceleration_fraction']:g} to "
        f"{peak_g:g} g, "
        f"{held_out['edge_fraction']:.0%} to the workspace edge ({provenance['samples']['validation']} samples).",
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
        "Ground truth: the identified plant's friction (its `PlantConfig.realism`), read by this report only. "
        "rho1 and rho2 have no physical truth (they absorb armature, the real arm and forearm inertia).",
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


def main(argv: list[str] | None = None) -> int:
    arguments = parse_arguments(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command = command_line("eval.identify", argv)
    scenario = arguments.scenario
    config = {**vars(arguments), "scenario": scenario.name, "robot_identity": scenario.robot_identity}
    with run_folder(
        "identification",
        command,
        config,
        out=arguments.out,
        runs_dir=arguments.runs_dir,
        scenarios=[scenario],
        stamp=f"{utc_stamp()}_seed{arguments.seed}",
    ) as run_dir:
        run_dir.record(config={**config, "out": run_dir.folder})
        identify_into(arguments, run_dir, command)
    return 0


def identify_into(arguments: argparse.Namespace, run_dir: Run, command: str) -> None:
    """Identify the robot of ``arguments`` (:func:`parse_arguments`) and write the parameters, the validation data,
    the figures and the report into the run folder, the method into its manifest; print the report."""
    scenario, folder = arguments.scenario, run_dir.folder
    run = run_identification(
        arguments.trajectories,
        arguments.seed,
        arguments.duration,
        validation_duration=arguments.validation_duration,
        progress=not arguments.no_progress,
        workers=arguments.workers,
        plant=scenario.plant,
    )
    save_result(run.result, folder / "parameters.json")
    if not arguments.no_install:
        save_result(run.result, arguments.parameters)
    run_dir.record(method=run.result.provenance["method"])

    validation_file = folder / "validation.npz"
    save_validation_data(run, validation_file)
    figures = plot_figures(validation_file, folder)
    report = render_report(run, validation_file, command, figures, scenario.plant)
    (folder / "report.md").write_text(report)
    print(report)
    installed = "" if arguments.no_install else f" and {arguments.parameters}"
    print(f"Wrote {folder}/ (parameters.json, config.json, report.md, figures){installed}.")


if __name__ == "__main__":
    sys.exit(main())
