"""Scores of a residual policy against its base controller on held-out episodes.

The episodes are work units of :func:`eval.work.run_grid` (two rows registered here, :data:`POLICY_BASE` and
:data:`POLICY_RESIDUAL`, as a user's controller is) and scored by :mod:`eval.metrics`, as ``python -m eval`` scores
its rows: tracking error of the platform (mm) and the motor torque that acted (N m).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.base import Controller
from controllers.registry import ControllerEntry, ControllerSetup, loaded_policy, residual_policy_path
from controllers.residual import read_policy_settings, residual_controller
from delta_env.scenario import Scenario
from eval import metrics
from eval.console import plural
from eval.episodes import EpisodeRecord
from eval.work import WorkUnit, run_grid

TEST_SEEDS = tuple(range(2_000_000, 2_000_010))
"""Held-out episodes of the final scores: never seen in training nor in model selection."""

TEST_PAYLOADS = (0.0, 1.0, 2.5, 3.8, 4.0)
"""Fixed payload masses (kg) of the extra test episodes (3.8 kg is the paper's test)."""


EPISODE_SCORES = ("tracking_rms_mm", "torque_rms_nm", "place_error_max_mm", "settle_time_mean_ms", "diverged")
"""Each episode's scores (:meth:`EpisodeRecord.metrics`) in a policy's scores: tracking and torque RMS, the worst
place error at release (mm) and the mean wait for the in-position signal (ms; NaN with the timed release)."""


def pooled_scores(records: Sequence[EpisodeRecord]) -> dict[str, float]:
    """Tracking RMS and max (mm) and torque RMS (N m) over every control step of ``records``, and the worst place
    error at release (mm) of any of them."""
    tracking_rms, tracking_max = metrics.tracking_metrics(np.concatenate([r.tracking_error for r in records]))
    torque_rms, _ = metrics.torque_metrics(np.concatenate([r.torque for r in records]))
    place_errors = np.concatenate([r.place_errors() for r in records])
    return {
        "tracking_rms_mm": tracking_rms,
        "tracking_max_mm": tracking_max,
        "torque_rms_nm": torque_rms,
        "place_error_max_mm": float(np.max(place_errors)) if place_errors.size else float("nan"),
    }


def _policy_base(setup: ControllerSetup) -> Controller:
    """The base controller recorded in the policy file of ``setup``."""
    base = read_policy_settings(residual_policy_path(setup)).base
    if base is None:
        raise ValueError(f"{residual_policy_path(setup)} was trained on a custom base controller: it records no base")
    return base.controller()


def _policy_residual(setup: ControllerSetup) -> Controller:
    """The policy of ``setup`` on the base recorded in its file (:func:`controllers.registry.loaded_policy`)."""
    return residual_controller(loaded_policy(setup))


POLICY_BASE = ControllerEntry(
    "policy_base",
    "the policy's base",
    _policy_base,
    estimates_payload=True,
    has_estimator=True,
    reads_policy_file=True,
    monitored=False,
)
"""The scores' base row: the base the policy file records, as the policy saw it in training (no fault monitor)."""

POLICY_RESIDUAL = ControllerEntry(
    "policy_residual",
    "the policy on its base",
    _policy_residual,
    estimates_payload=True,
    has_estimator=True,
    reads_policy_file=True,
    monitored=False,
)
"""The scores' residual row: the policy on the base its file records (no fault monitor)."""

ROWS = {"base": f"{__name__}:POLICY_BASE", "residual": f"{__name__}:POLICY_RESIDUAL"}
"""The two rows of the scores, by name, as registry keys (:func:`controllers.registry.controller_entry`)."""


def score_policy(
    path: str | Path,
    env_kwargs: dict[str, Any] | None = None,
    *,
    seeds: Sequence[int] = TEST_SEEDS,
    payloads: Sequence[float] = TEST_PAYLOADS,
    workers: int = 1,
    progress: Any = None,
) -> dict[str, Any]:
    """Base controller vs base + residual on held-out episodes (the same episodes for both), run by
    :func:`eval.work.run_grid`.

    Episodes: one per seed with its drawn payloads, and one per fixed payload mass (every object of
    the episode that mass) on the first seed. The summary pools every control step of every episode;
    per-episode values are listed too. Both rows know what the policy file records of its base.

    Args:
        path: The policy zip; its base must be recorded (a policy trained on a custom base is scored by its caller).
        env_kwargs: ``n_cycles`` and optionally ``scenario`` (a Scenario; None or absent is ``nominal``); None is
            3 cycles.
        seeds: Episode seeds.
        payloads: Fixed payload masses (kg) of the extra episodes.
        workers: Processes of the episodes (1: this process).
        progress: A tqdm bar; its total is set to the episodes (two per seed and payload: base and residual),
            advanced once per finished one.
    """
    env_kwargs = {"n_cycles": 3} if env_kwargs is None else env_kwargs
    if not {"n_cycles"} <= set(env_kwargs) <= {"n_cycles", "scenario"}:
        raise ValueError(f"the scores take n_cycles and scenario only, got {sorted(env_kwargs)}")
    settings = read_policy_settings(path)
    if settings.base is None:
        raise ValueError(f"{path} was trained on a custom base controller: it records no base to score against")
    n_cycles = env_kwargs["n_cycles"]
    scenario = env_kwargs.get("scenario") or Scenario()
    scenario = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, n_cycles=n_cycles))
    setup = dataclasses.replace(settings.base.setup, residual_policy=Path(path))
    episodes = [(seed, None) for seed in seeds] + [(seeds[0], (mass,) * n_cycles) for mass in payloads]
    units = [WorkUnit(scenario, key, seed, masses) for seed, masses in episodes for key in ROWS.values()]
    start = time.monotonic()
    if progress is not None:
        progress.reset(total=len(units))
    records = run_grid(units, {scenario.content_hash: setup}, workers=workers, progress=progress)
    by_row: dict[str, list[EpisodeRecord]] = {name: records[n :: len(ROWS)] for n, name in enumerate(ROWS)}
    per_episode = []
    for n, (seed, masses) in enumerate(episodes):
        entry: dict[str, Any] = {"seed": seed, "payload_masses": None if masses is None else list(masses)}
        for name, group in by_row.items():
            scores = group[n].metrics()
            entry[name] = {key: scores[key] for key in EPISODE_SCORES}
        per_episode.append(entry)
    summary: dict[str, Any] = {name: pooled_scores(group) for name, group in by_row.items()}
    for quantity in ("tracking_rms", "torque_rms"):
        unit = "mm" if quantity == "tracking_rms" else "nm"
        ratio = summary["residual"][f"{quantity}_{unit}"] / summary["base"][f"{quantity}_{unit}"]
        summary[f"{quantity}_change"] = ratio - 1.0
    changes = [e["residual"]["tracking_rms_mm"] / e["base"]["tracking_rms_mm"] - 1.0 for e in per_episode]
    summary["episodes_improved"] = f"{sum(change < 0 for change in changes)}/{len(changes)}"
    return {
        "policy": str(path),
        "base": settings.base.name,
        "residual": f"{settings.base.name} + residual",
        "env_kwargs": env_kwargs,
        "seeds": list(seeds),
        "payloads": list(payloads),
        "summary": summary,
        "episodes": per_episode,
        "wall_time_s": round(time.monotonic() - start, 1),
    }


def score_summary(scores: dict[str, Any]) -> str:
    """The scores of :func:`eval.residual.scoring.score_policy` as a few lines of rounded numbers: each row's pooled
    tracking and torque RMS and worst place error, the residual's change over its base and the episodes it improved."""
    summary = scores["summary"]
    rows = {"base": scores["base"], "residual": scores["residual"]}
    width = max(map(len, rows.values()))
    lines = [
        f"Scores of {Path(scores['policy']).name} on {plural(len(scores['episodes']), 'held-out episode')} "
        f"({plural(len(scores['seeds']), 'seed')}, {plural(len(scores['payloads']), 'fixed payload')}), pooled over "
        "every control step:"
    ]
    for name, label in rows.items():
        row = summary[name]
        lines.append(
            f"  {label:<{width}}  tracking RMS {row['tracking_rms_mm']:.3f} mm (max {row['tracking_max_mm']:.2f} mm), "
            f"torque RMS {row['torque_rms_nm']:.2f} N m, place error at most {row['place_error_max_mm']:.3f} mm"
        )
    improved, total = summary["episodes_improved"].split("/")
    lines.append(
        f"  residual vs base: tracking {100 * summary['tracking_rms_change']:+.1f} %, torque "
        f"{100 * summary['torque_rms_change']:+.1f} %; better on {improved} of {plural(int(total), 'episode')}"
    )
    return "\n".join(lines)
