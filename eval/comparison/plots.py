"""Figures of an evaluation run, made from the files it saved (never from live objects).

- ``torque_profiles.png``: motor torques of every controller over the first episode, a panel each (the paper's
  Figs. 3-5);
- ``table2_torques.png``: measured torques against MId+F+R with mp = 0 and mp = m_hat in the 3.8 kg run
  (Fig. 7);
- ``payload_estimate.png``: payload estimate against the true payload over time (Fig. 8);
- ``error_bars.png``: Table 2 means with standard deviations per joint (Fig. 6 (b)) and the tracking RMS
  of each controller with its spread over episodes;
- ``tracking_error.png``: the tracking error of each controller over the first episode, one panel per row, with
  its carries shaded;
- ``paths_3d.png``: the reference and the platform's path of each controller over the first episode, in 3-D;
- ``fault_timeline.png`` (only for a run with faults): every injected fault and every detection of every episode
  on a time axis, one lane per episode (``faults.csv``).

:func:`learning_curve_figure` draws the residual training's held-out scores (``learning_curve.csv`` of
:mod:`eval.residual.__main__`) into ``learning_curve.png``.

Every figure's title names the scenario of the run (``scenario.toml`` in the run folder). :func:`make_plots` makes
them all from a finished run folder; a :class:`Plotter` makes each as soon as the files it is made from are saved,
those of the time series in a process of its own beside the command that writes the files.
"""

from __future__ import annotations

import contextlib
import csv
import math
from collections.abc import Callable, Collection
from multiprocessing.connection import Connection
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from pathlib import Path
from types import TracebackType
from typing import Any

import matplotlib

matplotlib.use("Agg")
import tomllib

import matplotlib.pyplot as plt
import numpy as np

from eval import metrics

TRACE_FIELDS = (
    "tracking_error",
    "torque",
    "payload_mass",
    "payload_estimate",
    "platform_position",
    "pick_indices",
    "place_indices",
)
"""EpisodeRecord fields saved in ``traces.npz`` per controller key, as ``"<key>.<field>"``; beside them
``"<key>.reference_xyz"`` (:data:`REFERENCE_FIELD`)."""

REFERENCE_FIELD = "reference_xyz"
"""The reference positions (m) at the ends of the steps, ``(N, 3)`` (step n ends at reference sample n + 1), saved
per controller key in ``traces.npz`` as ``"<key>.reference_xyz"``: the platform's path is drawn against them."""

LEARNING_CURVE_FILE = "learning_curve.csv"
"""The residual training's held-out scores, beside its run folder's other files (:mod:`eval.residual.__main__`)."""

LEARNING_CURVE_COLUMNS = ("timesteps", "mean_reward", "std_reward", "min_reward", "max_reward", "episodes")
"""Columns of :data:`LEARNING_CURVE_FILE`: one row per held-out evaluation of the residual training (policy steps so
far; the mean, std, min and max return over its ``episodes`` episodes)."""

LEGEND_OUTSIDE = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0, "fontsize": "small"}
"""Where the new figures put a panel's legend: right of the panel, off its data."""

TABLE2_MODEL = "MId+F+R"
"""The model of the Table 2 run's torques, :func:`controllers.registry.estimation_model` (identified, rod forearms)."""


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


JOINT_COLOURS = ("tab:blue", "tab:orange", "tab:green")
"""The colour of joints 1, 2, 3 in every panel."""


def torque_profiles(traces: np.lib.npyio.NpzFile, path: Path, scenario: str) -> None:
    """Applied motor torque over the first episode, one panel per controller (small multiples, shared axes): its
    three joints in colour over the bound's torques in grey (when the run has a bound's row: the first privileged one,
    ``traces["privileged"]``, :attr:`controllers.registry.ControllerEntry.privileged`), titled with the RMS
    of its torque's difference from the bound's (N m) while their references agree (until the first in-position wait
    that differs), so that controllers whose lines would coincide read apart."""
    dt = float(traces["dt"])
    keys, labels = [str(key) for key in traces["keys"]], [str(label) for label in traces["labels"]]
    bound_key = next((key for key, privileged in zip(keys, traces["privileged"], strict=True) if privileged), None)
    bound = None if bound_key is None else traces[f"{bound_key}.torque"]
    columns = 2 if len(keys) > 1 else 1
    rows = -(-len(keys) // columns)
    figure, axes = plt.subplots(
        rows, columns, sharex=True, sharey=True, figsize=(6 * columns, 1.2 + 2.1 * rows), squeeze=False
    )
    for axis, key, label in zip(axes.flat, keys, labels, strict=False):
        torque = traces[f"{key}.torque"]
        time = np.arange(len(torque)) * dt
        title = label
        if bound is not None and key != bound_key:
            steps = min(len(bound), len(torque))
            lines = axis.plot(time[:steps], bound[:steps], color="0.6", linewidth=1.6)
            lines[0].set_label(f"{labels[keys.index(bound_key)]}, joints 1-3")
            # compared while the two references agree: an in-position wait of either shifts the rest of its timeline
            apart = np.flatnonzero(
                np.any(
                    traces[f"{key}.{REFERENCE_FIELD}"][:steps] != traces[f"{bound_key}.{REFERENCE_FIELD}"][:steps],
                    axis=1,
                )
            )
            shared = int(apart[0]) if len(apart) else steps
            difference = float(np.sqrt(np.mean((torque[:shared] - bound[:shared]) ** 2)))
            title = f"{label}: {difference:.2f} N m RMS from the bound over its first {shared * dt:.2f} s"
        for joint, colour in enumerate(JOINT_COLOURS):
            axis.plot(time, torque[:, joint], color=colour, linewidth=0.8, label=f"joint {joint + 1}")
        axis.set_title(title, fontsize="medium")
        axis.grid(alpha=0.3)
    for axis in axes.flat[len(keys) :]:
        axis.set_visible(False)
    for axis in axes[:, 0]:
        axis.set_ylabel("torque (N m)")
    for axis in axes[-1]:
        axis.set_xlabel("time (s)")
        axis.xaxis.set_tick_params(labelbottom=True)
    handles, names = axes.flat[0].get_legend_handles_labels()
    if bound is not None and keys[0] == bound_key and len(keys) > 1:
        handles, names = axes.flat[1].get_legend_handles_labels()
    figure.suptitle(f"Motor torques, first episode (scenario {scenario})")
    top = 1 - 0.45 / figure.get_figheight()  # the legend between the title and the panels, over no data
    figure.legend(handles, names, loc="upper center", ncol=len(names), bbox_to_anchor=(0.5, top))
    figure.tight_layout(rect=(0, 0, 1, 1 - 0.75 / figure.get_figheight()))
    figure.savefig(path, dpi=120)
    plt.close(figure)


def table2_torques(run: np.lib.npyio.NpzFile, path: Path, scenario: str) -> None:
    """Measured torque against :data:`TABLE2_MODEL` with and without the estimated payload (the paper's Fig. 7)."""
    figure, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 8))
    time = run["time"]
    for joint, axis in enumerate(axes):
        axis.plot(time, run["measured"][:, joint], color="k", linewidth=0.8, label="tau measured")
        axis.plot(time, run["mp_0"][:, joint], linewidth=0.8, label=f"{TABLE2_MODEL}, mp = 0")
        axis.plot(time, run["mp_hat"][:, joint], linewidth=0.8, label=f"{TABLE2_MODEL}, mp = m_hat")
        axis.set_ylabel(f"tau {joint + 1} (N m)")
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize="small")
    axes[-1].set_xlabel("time (s)")
    figure.suptitle(f"Measured and model torques, every object 3.8 kg (scenario {scenario})")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def payload_estimate(traces: np.lib.npyio.NpzFile, run: np.lib.npyio.NpzFile, path: Path, scenario: str) -> None:
    """Payload estimate and true payload over time: first episode and the 3.8 kg run (the paper's Fig. 8)."""
    dt = float(traces["dt"])
    # The estimate formed from observation n and the true mass at observation n (one more at the end).
    panels = [
        (f"{label}, first episode", traces[f"{key}.payload_estimate"], traces[f"{key}.payload_mass"])
        for key, label, estimates in zip(traces["keys"], traces["labels"], traces["estimates_payload"], strict=True)
        if estimates
    ]
    figure, axes = plt.subplots(len(panels) + 1, 1, sharex=False, figsize=(10, 2.6 * (len(panels) + 1)))
    axes = np.atleast_1d(axes)
    for axis, (title, estimate, mass) in zip(axes, panels, strict=False):
        time = np.arange(len(estimate)) * dt
        axis.plot(time, mass[: len(estimate)], color="k", label="m_p (true)")
        axis.plot(time, estimate, label="m_hat")
        axis.set_title(title, fontsize="medium")
    axes[-1].plot(run["time"], run["mass"], color="k", label="m_p (true)")
    axes[-1].plot(run["time"], run["estimate"], label="m_hat")
    axes[-1].set_title("Table 2 run, every object 3.8 kg", fontsize="medium")
    for axis in axes:
        axis.set_ylabel("mass (kg)")
        axis.grid(alpha=0.3)
        axis.legend(fontsize="small", loc="upper right")
    axes[-1].set_xlabel("time (s)")
    figure.suptitle(f"Payload estimate (scenario {scenario})")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def error_bars(table2: list[dict[str, str]], episodes: list[dict[str, str]], path: Path, scenario: str) -> None:
    """Mean torque errors with standard deviations (Fig. 6 (b)) and tracking RMS per controller."""
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    positions = np.arange(3)
    for offset, (name, label) in zip((-0.15, 0.15), (("mp_0", "mp = 0"), ("mp_hat", "mp = m_hat")), strict=True):
        means = [float(row[f"{name}_mean"]) for row in table2]
        stds = [float(row[f"{name}_std"]) for row in table2]
        left.errorbar(positions + offset, means, yerr=stds, fmt="o", capsize=4, label=label)
    left.axhline(0.0, color="k", linewidth=0.6)
    left.set_xticks(positions, ["tau1", "tau2", "tau3"])
    left.set_ylabel(f"tau measured - tau {TABLE2_MODEL} (N m)")
    left.set_title("Table 2 analogue: mean ± std", fontsize="medium")
    left.legend(fontsize="small")
    left.grid(alpha=0.3)

    labels = list(dict.fromkeys(row["controller"] for row in episodes))
    rms = [
        [float(row["tracking_rms_mm"]) for row in episodes if row["controller"] == label and row["diverged"] == "False"]
        for label in labels
    ]
    means = [np.mean(values) if values else np.nan for values in rms]
    stds = [np.std(values, ddof=1) if len(values) > 1 else 0.0 for values in rms]
    right.bar(np.arange(len(labels)), means, yerr=stds, capsize=4, color="tab:blue", alpha=0.8)
    right.set_xticks(np.arange(len(labels)), labels, rotation=30, ha="right", fontsize="small")
    right.set_yscale("log")
    right.set_ylabel("tracking RMS (mm)")
    right.set_title("Tracking error: mean ± std over episodes", fontsize="medium")
    right.grid(alpha=0.3, axis="y")
    figure.suptitle(f"Scenario {scenario}")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def _carries(traces: np.lib.npyio.NpzFile, key: str, steps: int) -> list[tuple[int, int]]:
    """The (pick, place) step pairs of ``key``'s first episode, cut to its ``steps``."""
    picks, places = traces[f"{key}.pick_indices"], traces[f"{key}.place_indices"]
    return [(int(pick), min(int(place), steps)) for pick, place in zip(picks, places, strict=False) if pick < steps]


def tracking_error(traces: np.lib.npyio.NpzFile, path: Path, scenario: str) -> None:
    """Cartesian tracking error of each controller over the first episode, one panel per row (its own scale), with
    the episode's RMS and its carries shaded."""
    dt = float(traces["dt"])
    rows = list(zip(traces["keys"], traces["labels"], strict=True))
    figure, axes = plt.subplots(len(rows), 1, sharex=True, figsize=(11, 1.7 * len(rows) + 1.0), squeeze=False)
    for axis, (key, label) in zip(axes[:, 0], rows, strict=True):
        error_mm = 1e3 * traces[f"{key}.tracking_error"]
        time = np.arange(len(error_mm)) * dt
        for n, (pick, place) in enumerate(_carries(traces, key, len(error_mm))):
            axis.axvspan(pick * dt, place * dt, color="0.88", label="object held" if n == 0 else None)
        axis.plot(time, error_mm, color="tab:blue", linewidth=0.8, label="tracking error")
        rms, _ = metrics.tracking_metrics(traces[f"{key}.tracking_error"])
        axis.axhline(rms, color="tab:red", linestyle="--", linewidth=0.9, label=f"RMS {rms:.2f} mm")
        axis.set_ylabel("|e| (mm)")
        axis.set_title(label, fontsize="medium", loc="left")
        axis.set_ylim(bottom=0.0)
        axis.grid(alpha=0.3)
        axis.legend(**LEGEND_OUTSIDE)
    axes[-1, 0].set_xlabel("time (s)")
    figure.suptitle(f"Tracking error, first episode (scenario {scenario})")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def deviation_scale(deviation: float, largest: float = 0.03) -> int:
    """The factor by which :func:`paths_3d` magnifies the platform's deviation from the reference: the largest of
    1, 2, 5, 10, 20, 50, ... that keeps ``deviation`` (m) times it within ``largest`` (m), so that a few mm show."""
    if not deviation > 0.0 or not math.isfinite(deviation):
        return 1
    scale = 1
    for decade in range(7):
        for mantissa in (1, 2, 5):
            if mantissa * 10**decade * deviation <= largest:
                scale = mantissa * 10**decade
    return scale


def paths_3d(traces: np.lib.npyio.NpzFile, path: Path, scenario: str) -> None:
    """The reference and the platform's path of each controller over the first episode, one 3-D panel per row; the
    platform's deviation from the reference is magnified by one factor for all (:func:`deviation_scale`)."""
    rows = list(zip(traces["keys"], traces["labels"], strict=True))
    paths = {key: (traces[f"{key}.{REFERENCE_FIELD}"], traces[f"{key}.platform_position"]) for key, _ in rows}
    deviations = [np.linalg.norm(platform - reference, axis=1) for reference, platform in paths.values()]
    largest = max((float(np.nanmax(d)) for d in deviations if np.isfinite(d).any()), default=math.nan)
    scale = deviation_scale(largest)
    columns = min(3, len(rows))
    lines = -(-len(rows) // columns)
    figure = plt.figure(figsize=(4.4 * columns, 4.0 * lines + 0.9))
    handles = []
    for n, (key, label) in enumerate(rows):
        reference, platform = (1e3 * xyz for xyz in paths[key])
        shown = reference + scale * (platform - reference)
        axis = figure.add_subplot(lines, columns, n + 1, projection="3d")
        handles = [
            axis.plot(*reference.T, color="k", linewidth=0.8, label="reference")[0],
            axis.plot(*shown.T, color="tab:orange", linewidth=0.9, label=_platform_label(scale))[0],
        ]
        rms, _ = metrics.tracking_metrics(deviations[n])
        axis.set_title(f"{label}\nRMS {rms:.2f} mm", fontsize="medium")
        axis.set_xlabel("x (mm)", fontsize="small")
        axis.set_ylabel("y (mm)", fontsize="small")
        axis.set_zlabel("z (mm)", fontsize="small")
        axis.tick_params(labelsize="x-small")
    figure.legend(handles=handles, loc="lower center", ncol=2, fontsize="small", frameon=False)
    figure.suptitle(f"Reference and platform paths, first episode (scenario {scenario})")
    figure.tight_layout(rect=(0.0, 0.04, 1.0, 0.97))
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _platform_label(scale: int) -> str:
    return "platform" if scale == 1 else f"platform (deviation from the reference x {scale})"


DETECTION_MARKERS = {"detected": "v", "consequence": "o", "false_alarm": "X"}
"""The marker of a detection in the fault timeline, by the ``outcome`` of its row
(:data:`eval.fault_scores.OUTCOMES`)."""

_DETECTION_NAMES = {
    "detected": "detection of the fault",
    "consequence": "detection of a consequence",
    "false_alarm": "false alarm",
}

MIN_FAULT_WIDTH_S = 0.01
"""Shortest bar (s) of an injected fault in the timeline: a one-step glitch stays visible."""


def fault_timeline(faults: list[dict[str, str]], path: Path, scenario: str) -> None:
    """Every injected fault (a bar from its start to its end, coloured by kind; hatched when missed, a dotted outline
    when latent) and every detection (a marker by outcome, coloured by the detected kind) of every episode, one lane
    per controller and episode; no figure when ``faults`` is empty (a run without faults)."""
    if not faults:
        return
    lanes = list(dict.fromkeys((row["controller"], row["episode"]) for row in faults))
    kinds = list(dict.fromkeys(kind for row in faults for kind in (row["kind"], row["detected_kind"]) if kind))
    colours = {kind: plt.get_cmap("tab10")(n % 10) for n, kind in enumerate(kinds)}
    many = len(lanes) > 30  # e.g. ten rows of ten episodes: narrower lanes, smaller labels
    figure, axis = plt.subplots(figsize=(12, (0.28 if many else 0.45) * len(lanes) + 2.0))
    handles: dict[str, Any] = {}
    for lane, (controller, episode) in enumerate(lanes):
        for row in (row for row in faults if (row["controller"], row["episode"]) == (controller, episode)):
            if row["outcome"] in ("detected", "missed", "latent"):
                start, end = float(row["injected_at_s"]), float(row["ended_at_s"])
                span, height = [(start, max(end - start, MIN_FAULT_WIDTH_S))], (lane - 0.3, 0.6)
                if row["outcome"] == "latent":  # it changed nothing: an outline only
                    bars = axis.broken_barh(span, height, facecolors="none", edgecolor=colours[row["kind"]], ls=":")
                    handles.setdefault("latent (changed nothing; dotted)", bars)
                    continue
                bars = axis.broken_barh(span, height, facecolors=colours[row["kind"]], alpha=0.8)
                handles.setdefault(f"injected: {row['kind']}", bars)
                if row["outcome"] == "missed":
                    hatched = axis.broken_barh(span, height, facecolors="none", edgecolor="k", hatch="//")
                    handles.setdefault("missed (hatched)", hatched)
            if row["detected_at_s"]:
                kind = row["detected_kind"] or row["kind"]
                (marker,) = axis.plot(
                    float(row["detected_at_s"]),
                    lane,
                    linestyle="none",
                    marker=DETECTION_MARKERS[row["outcome"]],
                    markersize=9,
                    markerfacecolor=colours[kind],
                    markeredgecolor="k",
                )
                handles.setdefault(_DETECTION_NAMES[row["outcome"]], marker)
    for label, handle in handles.items():
        handle.set_label(label)
    axis.set_yticks(
        range(len(lanes)),
        [f"{controller}, episode {episode}" for controller, episode in lanes],
        fontsize="small" if many else "medium",
    )
    axis.set_ylim(len(lanes) - 0.5, -0.5)
    axis.set_xlabel("time from the reset (s)")
    axis.grid(alpha=0.3, axis="x")
    axis.legend(handles=list(handles.values()), labels=list(handles), **LEGEND_OUTSIDE)
    axis.set_title(
        f"Injected faults and detections (scenario {scenario}); marker colour: the detected kind", fontsize="medium"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def learning_curve(rows: list[dict[str, str]], path: Path, title: str) -> None:
    """The held-out evaluations' mean return over policy steps, with its std band and the min and max
    (``learning_curve.csv``, :data:`LEARNING_CURVE_COLUMNS`)."""
    steps = np.array([float(row["timesteps"]) for row in rows])
    mean, std, low, high = (
        np.array([float(row[name]) for row in rows])
        for name in ("mean_reward", "std_reward", "min_reward", "max_reward")
    )
    figure, axis = plt.subplots(figsize=(9, 4.5))
    axis.fill_between(steps, mean - std, mean + std, color="tab:blue", alpha=0.25, label="mean ± std")
    axis.plot(steps, mean, color="tab:blue", marker="o", markersize=3, label="mean return")
    axis.plot(steps, low, color="0.4", linestyle=":", linewidth=0.9, label="min and max")
    axis.plot(steps, high, color="0.4", linestyle=":", linewidth=0.9)
    axis.set_xlabel("policy steps")
    axis.set_ylabel(f"return over the held-out episodes ({rows[0]['episodes']} each)")
    axis.grid(alpha=0.3)
    axis.legend(**LEGEND_OUTSIDE)
    axis.set_title(title, fontsize="medium")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def learning_curve_figure(run_dir: Path) -> Path | None:
    """``learning_curve.png`` of a residual training's run folder, from its :data:`LEARNING_CURVE_FILE`; None (and no
    figure) when the training made no evaluation."""
    run_dir = Path(run_dir)
    csv_path = run_dir / LEARNING_CURVE_FILE
    rows = _read_csv(csv_path) if csv_path.is_file() else []
    if not rows:
        return None
    path = run_dir / "learning_curve.png"
    learning_curve(rows, path, f"Residual training, held-out evaluations ({run_dir.name})")
    return path


def scenario_name(run_dir: Path) -> str:
    """The scenario name recorded in the run folder's ``scenario.toml``.

    Raises:
        FileNotFoundError: if the run folder has no ``scenario.toml``.
    """
    with (Path(run_dir) / "scenario.toml").open("rb") as file:
        return str(tomllib.load(file)["name"])


def _torque_profiles(run_dir: Path, path: Path, scenario: str) -> None:
    with np.load(run_dir / "traces.npz") as traces:
        torque_profiles(traces, path, scenario)


def _table2_torques(run_dir: Path, path: Path, scenario: str) -> None:
    with np.load(run_dir / "table2_run.npz") as run:
        table2_torques(run, path, scenario)


def _payload_estimate(run_dir: Path, path: Path, scenario: str) -> None:
    with np.load(run_dir / "traces.npz") as traces, np.load(run_dir / "table2_run.npz") as run:
        payload_estimate(traces, run, path, scenario)


def _error_bars(run_dir: Path, path: Path, scenario: str) -> None:
    error_bars(_read_csv(run_dir / "table2.csv"), _read_csv(run_dir / "episodes.csv"), path, scenario)


def _tracking_error(run_dir: Path, path: Path, scenario: str) -> None:
    with np.load(run_dir / "traces.npz") as traces:
        tracking_error(traces, path, scenario)


def _paths_3d(run_dir: Path, path: Path, scenario: str) -> None:
    with np.load(run_dir / "traces.npz") as traces:
        paths_3d(traces, path, scenario)


def _fault_timeline(run_dir: Path, path: Path, scenario: str) -> None:
    fault_timeline(_read_csv(run_dir / "faults.csv"), path, scenario)


FIGURES: dict[str, tuple[tuple[str, ...], Callable[[Path, Path, str], None]]] = {
    "torque_profiles.png": (("traces.npz",), _torque_profiles),
    "table2_torques.png": (("table2_run.npz",), _table2_torques),
    "payload_estimate.png": (("traces.npz", "table2_run.npz"), _payload_estimate),
    "error_bars.png": (("table2.csv", "episodes.csv"), _error_bars),
    "tracking_error.png": (("traces.npz",), _tracking_error),
    "paths_3d.png": (("traces.npz",), _paths_3d),
    "fault_timeline.png": (("faults.csv",), _fault_timeline),
}
"""Each figure of a run folder, in the order they are made: the files it is made from (besides ``scenario.toml``)
and the function that makes it from the run folder into its path, titled with the scenario's name (the fault
timeline only when ``faults.csv`` has rows)."""

SERIES_FIGURES = (
    "torque_profiles.png",
    "table2_torques.png",
    "payload_estimate.png",
    "tracking_error.png",
    "paths_3d.png",
)
"""The figures of the time series (``.npz`` files), which a command saves before its tables: those a
:class:`Plotter` with a process context makes in that process."""


def _make_ready(run_dir: Path, saved: Collection[str], pending: list[str]) -> None:
    """Make every figure of ``pending`` (names of :data:`FIGURES`) whose files are all ``saved``, in order, and take
    it off ``pending``."""
    ready = [name for name in pending if set(FIGURES[name][0]) <= set(saved)]
    if ready:
        scenario = scenario_name(run_dir)
        for name in ready:
            FIGURES[name][1](run_dir, run_dir / name, scenario)
            pending.remove(name)


def make_plots(run_dir: Path) -> list[Path]:
    """All figures of the run in ``run_dir``, from its saved files; returns the paths of those made."""
    run_dir = Path(run_dir)
    _make_ready(run_dir, {file for files, _ in FIGURES.values() for file in files}, list(FIGURES))
    return [run_dir / name for name in FIGURES if (run_dir / name).is_file()]


def _plot_as_saved(run_dir: Path, files: Connection, figures: list[str]) -> None:
    """The work of a :class:`Plotter`'s process: make each of ``figures`` (names of :data:`FIGURES`) once the names
    of all its files have come through ``files``, reading them until the caller closes it (so that the caller never
    writes to a closed pipe).

    Raises:
        RuntimeError: if ``files`` closes before every figure is made.
    """
    saved: set[str] = set()
    while True:
        try:
            saved.update(files.recv())
        except EOFError:
            break
        _make_ready(run_dir, saved, figures)
    if figures:
        raise RuntimeError(_not_made(figures))


def _not_made(figures: list[str]) -> str:
    """The error message of ``figures`` left unmade."""
    return f"figures not made, their files were not saved: {', '.join(figures)}"


class Plotter:
    """The figures of a run folder (:data:`FIGURES`), each made as soon as the files it is made from are saved
    (:meth:`saved`): all in this process, or with a ``context`` (:func:`eval.processes.pool_context`) the
    :data:`SERIES_FIGURES` in a process of its own, on a core that the caller leaves idle while it computes and writes
    the tables, and the others here.

    A context manager: on leaving without an error, it waits for that process and raises if a figure was not made;
    on leaving with an error, it stops that process.
    """

    def __init__(self, run_dir: Path, context: BaseContext | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.context = context
        self.files: set[str] = set()
        self.here = [name for name in FIGURES if context is None or name not in SERIES_FIGURES]
        self.process: BaseProcess | None = None
        self.exitcode: int | None = None
        """The exit code of the process, once it has ended."""
        self.connection: Connection | None = None

    def __enter__(self) -> Plotter:
        if self.context is not None:
            reader, self.connection = self.context.Pipe(duplex=False)
            beside = [name for name in FIGURES if name not in self.here]
            self.process = self.context.Process(
                target=_plot_as_saved, args=(self.run_dir, reader, beside), name="plots"
            )
            try:
                self.process.start()
            except BaseException:
                self.connection.close()
                raise
            finally:
                reader.close()
        return self

    def saved(self, *names: str) -> None:
        """The files ``names`` of the run folder are saved: make the figures that now have all of theirs."""
        self.files.update(names)
        if self.connection is not None:
            with contextlib.suppress(BrokenPipeError):  # the process failed: leaving the context reports its exit code
                self.connection.send(names)
        _make_ready(self.run_dir, self.files, self.here)

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if self.process is not None and self.connection is not None:
            if error is not None:
                self.process.terminate()
            self.connection.close()
            self.process.join()
            self.exitcode = self.process.exitcode
            self.process.close()
            if error is None and self.exitcode != 0:
                raise RuntimeError(
                    f"the process making the figures of {self.run_dir} failed (exit code {self.exitcode}; "
                    "its traceback is above)"
                )
        if error is None and self.here:
            raise RuntimeError(_not_made(self.here))
