"""One episode of one registered controller (:class:`Task`, :func:`run_task`): what every work unit of
:func:`eval.engine.run_grid` runs (:func:`eval.sweep.work.unit_record`), and what the tare calibration runs in a
process pool (:func:`run_tasks`).

It lives in an importable module (not ``eval.__main__``) so that forkserver / spawn workers can unpickle it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from controllers.base import Controller, payload_estimator_of
from controllers.payload import PayloadEstimator
from controllers.payload_timing import PayloadTiming, shared_planner
from controllers.registry import ControllerSetup, build_controller, cell_estimator, controller_entry
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval.episodes import EpisodeRecord, run_episode
from eval.processes import parallel_imap, process_pool


@dataclass(frozen=True)
class Task:
    """One episode to run.

    Attributes:
        kind: ``"episode"`` or ``"calibration"`` (0 kg objects, observations kept).
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


def timed(env: DeltaPickPlaceEnv, setup: ControllerSetup, estimator: PayloadEstimator | None = None) -> None:
    """Give ``env`` the timing its scenario asks for (:attr:`PickPlaceTask.timing`), planned on ``setup``'s model.

    An ``"online"`` timing reads ``estimator``: the controller's own payload estimator, or the cell's run beside a
    controller without one (:func:`timed_controller` chooses). A ``"fixed"`` scenario leaves ``env`` as it is.

    Raises:
        ValueError: for a timing that plans without the identified drive lag, or an online timing without
            ``estimator``.
    """
    if env.task_timing == "fixed":
        return
    if setup.drive_lag is None:
        raise ValueError(f"the {env.task_timing!r} timing plans with the identified drive lag; the setup has none")
    online = env.task_timing == "online"
    if online and estimator is None:
        raise ValueError("the 'online' timing reads a payload estimator: the controller's own or the cell's beside it")
    planner = shared_planner(
        setup.geometry, setup.masses, setup.mid_f_rods, env.plant_config.drive, tuple(setup.drive_lag)
    )
    # the thermal budget rests the task's planned dwell after each move: with the in-position release, the air
    # activation (the waits only add rest)
    env.timing = PayloadTiming(
        planner,
        env.task_timing,
        env.payload_mass_range[1],
        estimator if online else None,
        dwell=env.release.dwell,
        torque_share=env.torque_share,
        min_payload=env.payload_mass_range[0],
    )


def timed_controller(env: DeltaPickPlaceEnv, key: str, setup: ControllerSetup) -> Controller:
    """The controller of ``key`` for ``env`` (:func:`controllers.registry.build_controller`), ``env`` timed as its
    scenario asks (:func:`timed`).

    An online timing reads the controller's payload estimator when its entry declares one
    (:attr:`~controllers.registry.ControllerEntry.has_estimator`: the RLS rows', the residual's base's); else the
    cell's (:func:`controllers.registry.cell_estimator`, tared and seeded from ``setup``), which the registry runs
    beside the controller, behind its fault monitor, so that it sees clean readings too.
    """
    beside = None
    if env.task_timing == "online" and not controller_entry(key).has_estimator:
        beside = cell_estimator(setup)
    controller = build_controller(key, setup, env, cell_estimator=beside)
    timed(env, setup, beside if beside is not None else payload_estimator_of(controller))
    return controller


def task_episode(task: Task) -> tuple[DeltaPickPlaceEnv, Controller]:
    """The fresh env and controller of ``task``, the env timed as its scenario asks (:func:`timed_controller`) unless
    the task follows a reference of its own."""
    env = DeltaPickPlaceEnv(n_cycles=task.n_cycles, scenario=task.scenario)
    if task.reference is not None:
        return env, build_controller(task.key, task.setup, env)
    return env, timed_controller(env, task.key, task.setup)


def run_task(task: Task) -> tuple[Task, EpisodeRecord]:
    """Run one task in a fresh env and controller (picklable: the unit of work of the process pool)."""
    env, controller = task_episode(task)
    record = run_episode(
        env, controller, task.seed, task.masses, reference=task.reference, keep_observations=task.kind == "calibration"
    )
    env.close()
    return task, record


def run_tasks(tasks: Sequence[Task], workers: int, progress: Any = None) -> list[tuple[Task, EpisodeRecord]]:
    """Run ``tasks`` on ``workers`` processes (in this one if 1), advancing the tqdm bar ``progress`` once per task;
    the results in the order of ``tasks``."""
    results = []
    with process_pool(max(1, min(workers, len(tasks)))) as pool:  # None: in this process
        for result in parallel_imap(run_task, tasks, pool):
            results.append(result)
            if progress is not None:
                progress.update()
    return results
