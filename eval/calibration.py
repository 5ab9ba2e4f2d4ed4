"""Taring the payload estimators: the apparent payload of the empty gripper, measured like a scale's.

Each RLS controller runs pick-and-place episodes with nothing to pick (0 kg objects, the gripper still
closes and opens) on seeds of their own; :func:`controllers.payload.tare_from_observations` turns their
observations into the tare (kg) and its spread over the carries. ``python -m eval``, the sweep, the residual
training and the design verification (on its standard cycles, given as references) tare their estimators
with these functions.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from controllers.payload import tare_from_observations
from controllers.registry import ESTIMATOR_REGRESSORS, ControllerSetup, payload_estimator
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval.episodes import EpisodeRecord
from eval.tasks import Task, run_tasks

DEFAULT_CALIBRATION_EPISODES = 6
"""Payload-free episodes per tare: the apparent payload of an empty gripper varies by about 10 g from episode to
episode (noise and path), so six of them put the tare's own standard error near 4 g, against a +-25 g target for
light objects."""


def calibration_tasks(
    keys: Iterable[str],
    setup: ControllerSetup,
    seeds: Sequence[int],
    n_cycles: int,
    scenario: Scenario | None = None,
    references: Sequence[Trajectory] | None = None,
) -> list[Task]:
    """The payload-free episodes of every RLS controller in ``keys`` (observations kept), one per seed, on
    ``scenario`` (None: ``nominal``), following ``references[j]`` on seed ``j`` when given (else the
    scenario's pick-and-place)."""
    if references is not None and len(references) != len(seeds):
        raise ValueError(f"references must be one per seed: {len(references)} references for {len(seeds)} seeds")
    paths = [None] * len(seeds) if references is None else list(references)
    tasks = []
    for key in keys:
        if key not in ESTIMATOR_REGRESSORS:
            raise ValueError(f"{key!r} estimates no payload; RLS controllers: {sorted(ESTIMATOR_REGRESSORS)}")
        empty = (0.0,) * n_cycles
        tasks += [
            Task("calibration", key, j, seed, n_cycles, setup, empty, scenario, path)
            for j, (seed, path) in enumerate(zip(seeds, paths, strict=True))
        ]
    return tasks


def tares_from_results(
    results: Iterable[tuple[Task, EpisodeRecord]], setup: ControllerSetup, max_loop_gap: float | None = None
) -> tuple[dict[str, float], dict[str, float]]:
    """Tare (kg) and its carry-to-carry spread (kg) per RLS controller, from its calibration episodes.

    Args:
        results: Finished tasks and their records; those of kind ``"calibration"`` are used.
        setup: What the controllers know (their estimators are rebuilt from it, untared).
        max_loop_gap: Largest loop gap (m) a calibration episode may open; None accepts what the env accepts.

    Raises:
        RuntimeError: if a calibration episode diverged or opened a loop beyond ``max_loop_gap`` (its
            observations would give a meaningless tare).
    """
    observed: dict[str, list] = {}
    for task, record in results:
        if task.kind == "calibration":
            if record.diverged:
                raise RuntimeError(f"the calibration episode of {task.key!r} on seed {task.seed} diverged")
            if max_loop_gap is not None and not record.max_loop_gap <= max_loop_gap:
                raise RuntimeError(
                    f"the calibration episode of {task.key!r} on seed {task.seed} opened a loop by "
                    f"{1e3 * record.max_loop_gap:.3f} mm (limit {1e3 * max_loop_gap:.3f} mm)"
                )
            observed.setdefault(task.key, []).append(record.observations)
    tares, spreads = {}, {}
    for key, episodes in observed.items():
        tares[key], spreads[key] = tare_from_observations(payload_estimator(key, setup), episodes)
    return tares, spreads


def calibrate_tares(
    keys: Iterable[str],
    setup: ControllerSetup,
    seeds: Sequence[int],
    n_cycles: int,
    *,
    workers: int = 1,
    progress: Any = None,
    scenario: Scenario | None = None,
    references: Sequence[Trajectory] | None = None,
    max_loop_gap: float | None = None,
) -> tuple[dict[str, float], dict[str, float]]:
    """Run the calibration episodes of ``keys`` on ``scenario`` (None: ``nominal``), along ``references``
    (one per seed) if given, and return their tares and spreads (kg) by key (see :func:`tares_from_results`
    for ``max_loop_gap``)."""
    tasks = calibration_tasks(keys, setup, seeds, n_cycles, scenario, references)
    return tares_from_results(run_tasks(tasks, workers, progress), setup, max_loop_gap)
