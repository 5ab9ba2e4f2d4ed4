"""The experiments' unit of work and its runner: one episode of one controller on one scenario (:class:`WorkUnit`).

:func:`unit_record` runs a unit in a fresh env and controller (:func:`unit_episode`) and returns its
:class:`~eval.episodes.EpisodeRecord`; :func:`run_grid` runs many on the one executor (:func:`eval.processes.run_jobs`:
a local process pool or Ray), each with what its controller knows. Every experiment's episodes are work units: the
comparison's, the tare calibration's (:mod:`eval.calibration`, observations kept), the sweep's (which reduces each to
a row: :func:`eval.sweep.work.run_unit`), the pick-rate study's, the residual scores', the design verification's and
the fault scripts'. :func:`eval.engine.prepare` gives what the controllers know.

It lives in an importable module (not a ``__main__``) so that forkserver, spawn and Ray workers can unpickle it.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controllers.base import Controller, payload_estimator_of
from controllers.payload import PayloadEstimator
from controllers.payload_timing import PayloadTiming, shared_planner
from controllers.registry import (
    ControllerSetup,
    build_controller,
    cell_estimator,
    controller_entry,
    controller_packages,
)
from controllers.shaping import JerkLimitedTiming, arm_side, mode_period
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval.episodes import EpisodeRecord, run_episode
from eval.processes import run_jobs
from eval.run_folder import package_versions

_CODE_PACKAGES = ("delta_env", "controllers", "eval")
_CODE_DEPENDENCIES = ("mujoco", "numpy", "scipy", "filterpy", "gymnasium")


@dataclass(frozen=True)
class WorkUnit:
    """One episode of an experiment.

    Attributes:
        scenario: The robot and the work (its ``task.n_cycles`` cycles).
        controller: Controller key (:func:`controllers.registry.controller_entry`).
        seed: Episode seed: the same seed gives every controller the same path and objects.
        masses: Object masses (kg) instead of the drawn ones (one per cycle), or None.
        reference: A path (1 kHz) to follow instead of the scenario's pick-and-place cycles, or None; it is not timed.
        keep_observations: Keep every observation in the record (the tare calibration reads them).
    """

    scenario: Scenario
    controller: str
    seed: int
    masses: tuple[float, ...] | None = None
    reference: Trajectory | None = None
    keep_observations: bool = False


Work = Callable[[WorkUnit, ControllerSetup], Any]
"""A work function of :func:`run_grid`: :func:`unit_record` (a record) or :func:`eval.sweep.work.run_unit` (a row)."""
Setups = Mapping[str, ControllerSetup]
"""What the controllers know on each scenario, by the scenario's content hash."""


def timed(env: DeltaPickPlaceEnv, setup: ControllerSetup, estimator: PayloadEstimator | None = None) -> None:
    """Give ``env`` the timing its scenario asks for (:attr:`PickPlaceTask.timing`), planned on ``setup``'s model, its
    laws averaged over one period of the drives' first mode if the task is ``jerk_limited``
    (:class:`~controllers.shaping.JerkLimitedTiming`: the mode of the two-mass model of ``setup.compliance`` at each
    move's end, carries designed for the task's heaviest object, as the shaped rows design theirs on the nominal
    model's arm side).

    An ``"online"`` timing reads ``estimator``: the controller's own payload estimator, or the cell's run beside a
    controller without one (:func:`timed_controller` chooses). A ``"fixed"`` scenario leaves ``env`` as it is.

    Raises:
        ValueError: for a timing that plans without the identified drive lag, an online timing without
            ``estimator``, or a jerk-limited one on a setup without the drives' compliance.
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
    timing = PayloadTiming(
        planner,
        env.task_timing,
        env.payload_mass_range[1],
        estimator if online else None,
        dwell=env.release.dwell,
        torque_share=env.torque_share,
        min_payload=env.payload_mass_range[0],
    )
    if env.jerk_limited:
        if setup.compliance is None:
            raise ValueError("a jerk-limited timing averages over the drives' mode; the setup knows no compliance")
        window = mode_period(arm_side(setup), setup.compliance, env.plant_config.geometry)
        timing = JerkLimitedTiming(timing, window, env.payload_mass_range[1])
    env.timing = timing


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


def unit_episode(unit: WorkUnit, setup: ControllerSetup) -> tuple[DeltaPickPlaceEnv, Controller]:
    """The fresh env of ``unit`` and its controller knowing ``setup``, the env timed as its scenario asks
    (:func:`timed_controller`) unless the unit follows a reference of its own."""
    env = DeltaPickPlaceEnv(scenario=unit.scenario)
    if unit.reference is not None:
        return env, build_controller(unit.controller, setup, env)
    return env, timed_controller(env, unit.controller, setup)


def unit_record(unit: WorkUnit, setup: ControllerSetup) -> EpisodeRecord:
    """Run the episode of ``unit`` with what its controller knows (``setup``) and return its record (picklable: the
    default work function of :func:`run_grid`)."""
    env, controller = unit_episode(unit, setup)
    try:
        return run_episode(
            env,
            controller,
            unit.seed,
            unit.masses,
            reference=unit.reference,
            keep_observations=unit.keep_observations,
        )
    finally:
        env.close()


def _run_work(work: Work, job: tuple[WorkUnit, ControllerSetup]) -> Any:
    """``work`` on one unit and its setup (the function :func:`run_grid` maps)."""
    return work(*job)


def run_grid(
    units: Sequence[WorkUnit],
    setups: Setups,
    *,
    work: Work = unit_record,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    progress: Any = None,
    on_result: Callable[[WorkUnit, Any], None] | None = None,
    on_lost: Callable[[WorkUnit, str], Any] | None = None,
    keep: bool = True,
) -> list[Any] | None:
    """``work(unit, setups[unit.scenario.content_hash])`` of every unit (:func:`eval.engine.grid` builds a product),
    on the one executor (:func:`eval.processes.run_jobs`), in the order of ``units``.

    Args:
        units: The episodes.
        setups: What the controllers know, by scenario content hash (:func:`eval.engine.prepare`'s setup of each
            scenario).
        work: :func:`unit_record` (the episode's record; an episode's error is raised) or
            :func:`eval.sweep.work.run_unit` (its row of metrics; an error is recorded in the row).
        backend: ``"local"`` (a process pool of ``workers``, this process if 1) or ``"ray"``.
        workers: Local processes, or the CPUs of a Ray started here.
        address: Ray cluster to join (``ray`` only); a user's controllers' packages are shipped to it.
        progress: tqdm bar advanced once per finished unit.
        on_result: Called with each unit and its result as it finishes, in the order they finish (a long run writes
            them as they come, so an interruption loses only the units still running).
        on_lost: Gives the result of a unit whose worker died too often, from the unit and why; None raises a
            RuntimeError naming the unit.
        keep: Return the results; False keeps none and returns None (each goes to ``on_result`` only).

    Raises:
        ValueError: for a unit whose scenario has no setup (and as :func:`eval.processes.run_jobs`).
    """
    missing = sorted({unit.scenario.name for unit in units if unit.scenario.content_hash not in setups})
    if missing:
        raise ValueError(f"no controller setup for the scenarios {missing}")

    def lost(index: int, error: str) -> Any:
        unit = units[index]
        if on_lost is None:
            episode = f"the episode of {unit.controller!r} on seed {unit.seed} ({unit.scenario.name})"
            raise RuntimeError(f"{episode}: {error}")
        return on_lost(unit, error)

    return run_jobs(
        functools.partial(_run_work, work),
        [(unit, setups[unit.scenario.content_hash]) for unit in units],
        backend=backend,
        workers=workers,
        address=address,
        progress=progress,
        on_result=None if on_result is None else lambda index, result: on_result(units[index], result),
        on_lost=lost,
        ray_folders=controller_packages({unit.controller for unit in units}) if address is not None else (),
        keep=keep,
    )


def code_version() -> str:
    """Content hash (16 hex digits) of the project's Python sources and the versions of Python and of the
    libraries that decide an episode's numbers: any change of either gives new keys to the sweep's rows and the kept
    tares."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for package in _CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    digest.update(json.dumps(package_versions(_CODE_DEPENDENCIES), sort_keys=True).encode())
    return digest.hexdigest()[:16]
