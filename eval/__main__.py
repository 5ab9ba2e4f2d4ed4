"""``python -m eval``: every controller on the same seeded pick-and-place episodes (DESIGN.md section 8).

1. Loads the identified MId, MId+F and MId+F+R parameters (``controllers.identification.load_or_identify``; it
   identifies and caches them when the file is missing, about a minute).
2. Tares each payload estimator: its controller runs ``--calibration-episodes`` pick-and-place episodes
   with nothing to pick (0 kg objects, seeds of their own), and the apparent payload of the empty gripper
   is measured (``controllers.payload.tare_from_observations``).
3. Runs every controller on episodes ``seed, seed + 1, ...`` of the default env (realistic plant, 3 g
   conveyor cycles, objects drawn from U[0, 4] kg): the same paths and objects for all.
   The ``residual`` row is the learned residual policy (``--residual``, by default the shipped one) on
   the base it was trained on, rebuilt from the policy file.
4. Runs the Table 2 analogue: MId+F+R+RLS on the path of the first episode with every object 3.8 kg; the
   measured torques against MId+F+R with mp = 0 and with mp = m_hat.
5. Writes the run folder (``--out``): ``config.json`` (resolved configuration and command),
   ``episodes.csv`` and ``carries.csv`` (per episode and per carried object), ``table2.csv``,
   ``traces.npz`` and ``table2_run.npz`` (time series), ``summary.md`` and the plots made from these
   files; prints the summary. Diverged episodes are counted in the table, never dropped silently: their
   metrics cover the steps before the divergence.

Usage: python -m eval [--seed 0] [--episodes 10] [--cycles 3] [--controllers pd,mid_f_rls] [--out DIR]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.identification import DEFAULT_PARAMETER_PATH, load_or_identify
from controllers.payload import tare_from_observations
from controllers.provenance import command_line, package_versions
from controllers.residual import DEFAULT_POLICY_PATH, load_residual_policy
from delta_env.env import DeltaPickPlaceEnv
from delta_env.sensors import CONTROL_PERIOD
from eval import metrics, plots
from eval.episodes import (
    CONTROLLER_LABELS,
    ESTIMATING_KEYS,
    ESTIMATOR_REGRESSORS,
    ControllerSetup,
    EpisodeRecord,
    estimation_model,
    payload_estimator,
)
from eval.tasks import Task, run_tasks

CALIBRATION_SEED_OFFSET = 100_000
"""Calibration (tare) episodes use seeds seed + 100000 + j: paths and noise unlike the evaluation's."""

TABLE2_KEY = "mid_f_rls"
"""The controller of the Table 2 run: MId+F+R with the default payload estimator."""

TABLE2_PAYLOAD = 3.8
"""Mass of every object in the Table 2 run (kg), the paper's test payload."""

SETTLING_DEADLINE_MS = 150.0
"""The payload estimate should be within 5 % this long after each pick (ms)."""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m eval", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    parser.add_argument("--cycles", type=int, default=3, help="pick-and-place cycles per episode (default 3)")
    parser.add_argument(
        "--controllers",
        default=",".join(CONTROLLER_LABELS),
        help=f"comma-separated keys from {', '.join(CONTROLLER_LABELS)} (default: all)",
    )
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/eval/<timestamp>)")
    parser.add_argument(
        "--parameters",
        type=Path,
        default=DEFAULT_PARAMETER_PATH,
        help=f"identified parameter file, identified when missing (default {DEFAULT_PARAMETER_PATH})",
    )
    parser.add_argument(
        "--calibration-episodes", type=int, default=3, help="payload-free episodes of the tare (default 3)"
    )
    parser.add_argument(
        "--residual",
        type=Path,
        default=DEFAULT_POLICY_PATH,
        help=f"residual policy of the 'residual' row (default: the shipped {DEFAULT_POLICY_PATH.name})",
    )
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes (default: up to 2)")
    args = parser.parse_args(argv)
    keys = [key.strip() for key in args.controllers.split(",") if key.strip()]
    unknown = [key for key in keys if key not in CONTROLLER_LABELS]
    if unknown or not keys:
        parser.error(f"unknown or no controllers {unknown}; choose from {', '.join(CONTROLLER_LABELS)}")
    args.controllers = list(dict.fromkeys(keys))
    for name in ("episodes", "cycles", "calibration_episodes", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if "residual" in args.controllers:
        try:  # fail now, not after the other controllers have run
            load_residual_policy(args.residual)
        except (FileNotFoundError, ValueError) as error:
            parser.error(f"--residual: {error}")
    if args.out is None:
        args.out = Path("runs/eval") / datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return args


def _write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _controller_table(episode_rows: list[dict[str, Any]], carry_rows: list[dict[str, Any]]) -> str:
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


def _table2(table2_rows: list[dict[str, Any]]) -> str:
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


def _checks(episode_rows: list[dict[str, Any]], carry_rows: list[dict[str, Any]], table2_rows: list) -> list[str]:
    """One line per target of the issue, with the measured values."""
    lines = []
    groups = metrics.group_by(episode_rows, "controller")
    means, torque_means = (
        {
            label: metrics.mean_std([row[name] for row in group if not row["diverged"]])[0]
            for label, group in groups.items()
        }
        for name in ("tracking_rms_mm", "torque_rms_nm")
    )
    rls, pd, oracle, residual = (CONTROLLER_LABELS[key] for key in ("mid_f_rls", "pd", "oracle", "residual"))
    if rls in means and pd in means:
        lines.append(f"- tracking RMS {rls} / {pd} = {means[rls] / means[pd]:.3f} (target <= 0.2)")
    if rls in means and oracle in means:
        lines.append(f"- tracking RMS {rls} / {oracle} = {means[rls] / means[oracle]:.2f} (target <= 2)")
    if rls in means and residual in means:
        tracking, torque = means[residual] / means[rls] - 1.0, torque_means[residual] / torque_means[rls] - 1.0
        lines.append(
            f"- {residual} vs {rls}: tracking RMS {100 * tracking:+.1f} % (target <= -15 %), "
            f"torque RMS {100 * torque:+.1f} % (target <= +5 %)"
        )
    for label, group in metrics.group_by(carry_rows, "controller").items():
        scored = [row for row in group if row["mass_kg"] >= metrics.MIN_RELATIVE_MASS]
        settled = sum(row["settling_time_ms"] <= SETTLING_DEADLINE_MS for row in scored)
        worst = max((row["settling_time_ms"] for row in scored), key=lambda t: math.inf if math.isnan(t) else t)
        lines.append(
            f"- {label}: estimate within ±5 % by {SETTLING_DEADLINE_MS:.0f} ms after {settled}/{len(scored)} picks "
            f">= {metrics.MIN_RELATIVE_MASS} kg (worst {worst:.0f} ms; target: all)"
        )
    ratios = ", ".join(f"{row['mp_hat_std'] / row['mp_0_std']:.2f}" for row in table2_rows)
    lines.append(f"- Table 2 std(mp = m_hat) / std(mp = 0) per joint: {ratios} (target <= 0.6 each)")
    return lines


def run_all(
    args: argparse.Namespace, setup: ControllerSetup
) -> tuple[list[tuple[Task, EpisodeRecord]], dict[str, float], dict[str, float]]:
    """Calibrate the tares, then run every episode and the Table 2 run.

    Returns:
        The (task, record) of every run, and the tare (kg) and its spread (kg) per estimating controller.
    """
    from tqdm.auto import tqdm

    keys = args.controllers
    tared = sorted({key for key in keys if key in ESTIMATOR_REGRESSORS} | {TABLE2_KEY})
    untared = [key for key in keys if key not in ESTIMATOR_REGRESSORS]

    def episodes(selected: list[str], task_setup: ControllerSetup) -> list[Task]:
        return [
            Task("episode", key, i, args.seed + i, args.cycles, task_setup)
            for key in selected
            for i in range(args.episodes)
        ]

    calibrations = [
        Task("calibration", key, j, args.seed + CALIBRATION_SEED_OFFSET + j, args.cycles, setup, (0.0,) * args.cycles)
        for key in tared
        for j in range(args.calibration_episodes)
    ]
    first = calibrations + episodes(untared, setup)
    total = len(first) + args.episodes * (len(keys) - len(untared)) + 1
    with tqdm(total=total, desc="episodes", unit="ep") as progress:
        results = run_tasks(first, args.workers, progress)
        model = estimation_model(setup)
        tares, spreads = {}, {}
        for key in tared:
            observed = [rec.observations for task, rec in results if task.kind == "calibration" and task.key == key]
            tares[key], spreads[key] = tare_from_observations(payload_estimator(key, model), observed)
        tared_setup = dataclasses.replace(setup, tares=tares)
        table2 = Task("table2", TABLE2_KEY, 0, args.seed, args.cycles, tared_setup, (TABLE2_PAYLOAD,) * args.cycles)
        second = [*episodes([key for key in keys if key not in untared], tared_setup), table2]
        results += run_tasks(second, args.workers, progress)
    return results, tares, spreads


def tabulate(
    results: list[tuple[Task, EpisodeRecord]], keys: Sequence[str]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, EpisodeRecord]]:
    """Per-episode rows, per-carry rows (estimating controllers) and the first episode of each controller."""
    order = {key: n for n, key in enumerate(keys)}
    episodes = sorted(
        ((task, record) for task, record in results if task.kind == "episode"),
        key=lambda item: (order[item[0].key], item[0].index),
    )
    episode_rows, carry_rows, first = [], [], {}
    for task, record in episodes:
        label = CONTROLLER_LABELS[task.key]
        identity = {"controller": label, "key": task.key, "episode": task.index, "seed": task.seed}
        episode_rows.append({**identity, **record.metrics()})
        if task.key in ESTIMATING_KEYS:
            for n, carry in enumerate(record.carries()):
                carry_rows.append(
                    {
                        **identity,
                        "carry": n,
                        "mass_kg": carry.mass,
                        "end_estimate_kg": carry.end_estimate,
                        "end_error_kg": carry.end_error_kg,
                        "end_error_percent": carry.end_error_percent,
                        "settling_time_ms": carry.settling_time_ms,
                    }
                )
        if task.index == 0:
            first[task.key] = record
    return episode_rows, carry_rows, first


def table2_statistics(model_torques: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Mean and std of tau_measured - tau_model per joint for each payload hypothesis, one row per joint."""
    statistics = {
        name: metrics.torque_error_statistics(model_torques["measured"], model_torques[name])
        for name in ("mp_0", "mp_hat", "apparent")
    }
    rows = []
    for joint in range(3):
        row: dict[str, Any] = {"joint": joint + 1}
        for name, (mean, std) in statistics.items():
            row[f"{name}_mean"], row[f"{name}_std"] = float(mean[joint]), float(std[joint])
        rows.append(row)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    args = parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    identification = load_or_identify(args.parameters)
    identified_time = time.perf_counter() - started
    setup = ControllerSetup(
        mid=identification.mid,
        mid_f=identification.mid_f,
        mid_f_rods=identification.mid_f_rods,
        residual_policy=args.residual,
    )
    keys = args.controllers
    results, tares, tare_spreads = run_all(args, setup)
    episode_rows, carry_rows, traces = tabulate(results, keys)
    table2_record = next(record for task, record in results if task.kind == "table2")
    model_torques = table2_record.model_torques(estimation_model(setup), tares[TABLE2_KEY])
    table2_rows = table2_statistics(model_torques)

    _write_csv(out / "episodes.csv", episode_rows)
    if carry_rows:
        _write_csv(out / "carries.csv", carry_rows)
    _write_csv(out / "table2.csv", table2_rows)
    np.savez_compressed(
        out / "traces.npz",
        dt=CONTROL_PERIOD,
        keys=np.array(list(traces)),
        labels=np.array([CONTROLLER_LABELS[key] for key in traces]),
        **{f"{key}.{name}": getattr(record, name) for key, record in traces.items() for name in plots.TRACE_FIELDS},
    )
    np.savez_compressed(out / "table2_run.npz", **model_torques)

    total_time = time.perf_counter() - started
    env = DeltaPickPlaceEnv(n_cycles=args.cycles)
    config = {
        "command": command_line("eval", argv),
        "arguments": {key: str(value) if isinstance(value, Path) else value for key, value in vars(args).items()},
        "episode_seeds": [args.seed + i for i in range(args.episodes)],
        "calibration_seeds": [args.seed + CALIBRATION_SEED_OFFSET + j for j in range(args.calibration_episodes)],
        "env": {
            "id": "DeltaPickPlace-v0",
            "n_cycles": args.cycles,
            "cycle": "conveyor",
            "peak_acceleration_m_s2": env.peak_acceleration,
            "payload_mass_range_kg": list(env.payload_mass_range),
            "plant": repr(env.plant_config),
        },
        "controllers": {key: CONTROLLER_LABELS[key] for key in keys},
        "pd_gains": {"kp_nm_per_rad": setup.pd_gains[0], "kd_nm_s_per_rad": setup.pd_gains[1]},
        "identification": {
            "path": str(args.parameters),
            "mid": dataclasses.asdict(identification.mid),
            "mid_f": dataclasses.asdict(identification.mid_f),
            "mid_f_rods": dataclasses.asdict(identification.mid_f_rods),
            "provenance": identification.provenance,
        },
        "tare_kg": tares,
        "tare_spread_kg": tare_spreads,
        "table2": {"controller": CONTROLLER_LABELS[TABLE2_KEY], "seed": args.seed, "payload_kg": TABLE2_PAYLOAD},
        "seconds": {"identification_or_load": identified_time, "total": total_time},
        "versions": package_versions(),
    }
    (out / "config.json").write_text(json.dumps(config, indent=2, default=float) + "\n")

    summary = "\n".join(
        [
            f"# Controller comparison: {args.episodes} episodes x {args.cycles} cycles from seed {args.seed}",
            "",
            "Mean ± std over episodes (diverged ones counted, their metrics cover the steps before divergence and "
            "are left out of the means). Payload columns: objects >= 0.5 kg. The oracle knows the plant and the "
            "payloads: a bound, not a controller.",
            "",
            _controller_table(episode_rows, carry_rows),
            "",
            f"## Table 2 analogue: {CONTROLLER_LABELS[TABLE2_KEY]}, every object {TABLE2_PAYLOAD} kg, "
            "tau_measured - tau_MId+F+R",
            "",
            _table2(table2_rows),
            "",
            "Tare (apparent payload of the empty gripper): "
            + ", ".join(f"{CONTROLLER_LABELS[k]} {tares[k]:+.3f} kg (spread {tare_spreads[k]:.3f})" for k in tares),
            "",
            "## Checks",
            "",
            *_checks(episode_rows, carry_rows, table2_rows),
            "",
            f"Run folder: {out} ({total_time:.0f} s)",
        ]
    )
    (out / "summary.md").write_text(summary + "\n")
    plots.make_plots(out)
    print(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
