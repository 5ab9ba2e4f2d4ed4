"""The unit of work of the experiments: one episode of one registered controller, run in a process pool.

It lives in an importable module (not ``eval.__main__``) so that forkserver / spawn workers can unpickle it.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.pool import Pool
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controllers.registry import ControllerSetup, build_controller, residual_policy_path
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval.episodes import EpisodeRecord, run_episode
from eval.processes import parallel_map

if TYPE_CHECKING:
    from controllers.residual import ResidualPolicy


@dataclass(frozen=True)
class Task:
    """One episode to run.

    Attributes:
        kind: ``"episode"``, ``"calibration"`` (0 kg objects, observations kept) or ``"table2"``.
        key: Controller key.
        index: Episode index within its kind.
        seed: Episode seed.
        n_cycles: Pick-and-place cycles.
        setup: What the controller may know.
        masses: Object masses (kg) overriding the drawn ones, or None.
        scenario: The robot and the work (``n_cycles`` overrides its cycles); None is ``nominal``.
        reference: The path to follow instead of the scenario's pick-and-place (1 kHz), or None.
    """

    kind: str
    key: str
    index: int
    seed: int
    n_cycles: int
    setup: ControllerSetup
    masses: tuple[float, ...] | None = None
    scenario: Scenario | None = None
    reference: Trajectory | None = None


@functools.cache
def _loaded_policy(path: Path) -> ResidualPolicy:
    """The residual policy file at ``path``, loaded once per process: a policy holds no episode state."""
    from controllers.residual import load_residual_policy

    return load_residual_policy(path)


def run_task(task: Task) -> tuple[Task, EpisodeRecord]:
    """Run one task in a fresh env and controller (picklable: the unit of work of the process pool)."""
    env = DeltaPickPlaceEnv(n_cycles=task.n_cycles, scenario=task.scenario)
    policy = _loaded_policy(residual_policy_path(task.setup)) if task.key == "residual" else None
    controller = build_controller(task.key, task.setup, env, policy=policy)
    record = run_episode(
        env, controller, task.seed, task.masses, reference=task.reference, keep_observations=task.kind == "calibration"
    )
    env.close()
    return task, record


def run_tasks(
    tasks: Sequence[Task], workers: int, progress: Any = None, pool: Pool | None = None
) -> list[tuple[Task, EpisodeRecord]]:
    """Run ``tasks`` in order on ``workers`` processes (in this one if 1) or on ``pool``, advancing the tqdm
    bar ``progress``."""
    return parallel_map(run_task, tasks, workers, progress, pool)
