"""Scores of a residual policy against its base controller on held-out episodes.

The episodes are run by :func:`eval.episodes.run_episode` and scored by :mod:`eval.metrics`, exactly as
``python -m eval`` scores its rows: tracking error of the platform (mm) and the motor torque that acted
(N m).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.base import Controller
from controllers.residual import ResidualController, load_residual_policy
from delta_env.env import DeltaPickPlaceEnv
from eval import metrics
from eval.episodes import EpisodeRecord, run_episode

TEST_SEEDS = tuple(range(2_000_000, 2_000_010))
"""Held-out episodes of the final scores: never seen in training nor in model selection."""

TEST_PAYLOADS = (0.0, 1.0, 2.5, 3.8, 4.0)
"""Fixed payload masses (kg) of the extra test episodes (3.8 kg is the paper's test)."""


def pooled_scores(records: Sequence[EpisodeRecord]) -> dict[str, float]:
    """Tracking RMS and max (mm) and torque RMS (N m) over every control step of ``records``."""
    tracking_rms, tracking_max = metrics.tracking_metrics(np.concatenate([r.tracking_error for r in records]))
    torque_rms, _ = metrics.torque_metrics(np.concatenate([r.torque for r in records]))
    return {"tracking_rms_mm": tracking_rms, "tracking_max_mm": tracking_max, "torque_rms_nm": torque_rms}


def score_policy(
    path: str | Path,
    env_kwargs: dict[str, Any] | None = None,
    *,
    seeds: Sequence[int] = TEST_SEEDS,
    payloads: Sequence[float] = TEST_PAYLOADS,
    base_factory: Callable[[], Controller] | None = None,
) -> dict[str, Any]:
    """Base controller vs base + residual on held-out episodes (the same episodes for both).

    Episodes: one per seed with its drawn payloads, and one per fixed payload mass (every object of
    the episode that mass) on the first seed. The summary pools every control step of every episode;
    per-episode values are listed too. The base is the one stored in the policy file unless
    ``base_factory`` is given.

    Args:
        path: The policy zip.
        env_kwargs: Keyword arguments of :class:`DeltaPickPlaceEnv`; None is 3 cycles.
        seeds: Episode seeds.
        payloads: Fixed payload masses (kg) of the extra episodes.
        base_factory: Builds the base controller instead of the one in the policy file.
    """
    env_kwargs = {"n_cycles": 3} if env_kwargs is None else env_kwargs
    policy = load_residual_policy(path)
    if base_factory is None and policy.base is None:
        raise ValueError(f"{path} was trained on a custom base controller: pass base_factory")

    def base() -> Controller:
        return base_factory() if base_factory is not None else policy.base.controller()

    controllers = {"base": base(), "residual": ResidualController(base(), policy, policy.config)}
    n_cycles = env_kwargs.get("n_cycles", 3)
    episodes = [(seed, None) for seed in seeds] + [(seeds[0], [mass] * n_cycles) for mass in payloads]
    records: dict[str, list[EpisodeRecord]] = {name: [] for name in controllers}
    per_episode = []
    start = time.monotonic()
    for seed, masses in episodes:
        entry: dict[str, Any] = {"seed": seed, "payload_masses": masses}
        for name, controller in controllers.items():
            env = DeltaPickPlaceEnv(**env_kwargs)
            record = run_episode(env, controller, seed, masses)
            env.close()
            records[name].append(record)
            scores = record.metrics()
            entry[name] = {key: scores[key] for key in ("tracking_rms_mm", "torque_rms_nm", "diverged")}
        per_episode.append(entry)
    summary: dict[str, Any] = {name: pooled_scores(group) for name, group in records.items()}
    for quantity in ("tracking_rms", "torque_rms"):
        unit = "mm" if quantity == "tracking_rms" else "nm"
        ratio = summary["residual"][f"{quantity}_{unit}"] / summary["base"][f"{quantity}_{unit}"]
        summary[f"{quantity}_change"] = ratio - 1.0
    changes = [e["residual"]["tracking_rms_mm"] / e["base"]["tracking_rms_mm"] - 1.0 for e in per_episode]
    summary["episodes_improved"] = f"{sum(change < 0 for change in changes)}/{len(changes)}"
    return {
        "policy": str(path),
        "base": controllers["base"].name,
        "residual": controllers["residual"].name,
        "env_kwargs": env_kwargs,
        "seeds": list(seeds),
        "payloads": list(payloads),
        "summary": summary,
        "episodes": per_episode,
        "wall_time_s": round(time.monotonic() - start, 1),
    }
