"""The controller comparison of ``python -m eval``: every controller on the same seeded episodes.

1. Tares each payload estimator (:mod:`eval.calibration`): its controller runs payload-free pick-and-place
   episodes on seeds of their own.
2. Runs every controller on episodes ``seed, seed + 1, ...`` of the scenario (by default ``nominal``:
   realistic plant, 3 g conveyor cycles, objects drawn from U[0, 4] kg): the same paths and objects for all.
3. Runs the Table 2 analogue, without the scenario's faults: MId+F+R+RLS on the path of the first episode with
   every object 3.8 kg (the paper's experiment when the scenario is ``paper``: standard cycles, 3.8 kg on every
   pick); the
   measured torques against MId+F+R with mp = 0 and with mp = m_hat.
4. Tabulates per episode and per carried object (:func:`tabulate`, :func:`table2_statistics`), and the
   faults injected into the episodes and detected by the controllers (:func:`tabulate_faults`).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from controllers.registry import ControllerSetup, controller_entry
from eval import metrics
from eval.calibration import calibrated_setup, calibration_seeds, calibration_tasks, tared_keys, tares_from_results
from eval.episodes import EpisodeRecord
from eval.faults import fault_rows
from eval.processes import process_pool
from eval.tasks import Task, iterate_tasks

TABLE2_KEY = "mid_f_rls"
"""The controller of the Table 2 run: MId+F+R with the default payload estimator."""

TABLE2_PAYLOAD = 3.8
"""Mass of every object in the Table 2 run (kg), the paper's test payload."""

SLOW_KEYS = ("residual", "oracle")
"""Rows whose episodes cost the most (the residual's first episode in a process also loads torch): queued
first, so that the short episodes even out the end of the run across the workers."""


def run_all(
    args: argparse.Namespace, setup: ControllerSetup
) -> tuple[list[tuple[Task, EpisodeRecord]], dict[str, float], dict[str, float]]:
    """Calibrate the tares, then run every episode and the Table 2 run.

    Args:
        args: The parsed command line of ``python -m eval`` (seed, episodes, cycles, controllers,
            calibration_episodes, workers, scenario: the resolved Scenario).
        setup: What the controllers may know (identified parameters, gains, residual policy).

    Returns:
        The (task, record) of every run, and the tare (kg) and its spread (kg) per estimating controller.
    """
    from tqdm.auto import tqdm

    keys = args.controllers
    tared = sorted(set(tared_keys([*keys, TABLE2_KEY], args.scenario)))
    untared = [key for key in keys if key not in tared]

    def episodes(selected: list[str], task_setup: ControllerSetup) -> list[Task]:
        return [
            Task("episode", key, i, args.seed + i, args.cycles, task_setup, scenario=args.scenario)
            for key in selected
            for i in range(args.episodes)
        ]

    seeds = calibration_seeds(args.seed, args.calibration_episodes)
    calibrations = calibration_tasks(tared, setup, seeds, args.cycles, args.scenario)
    slow_first = [*(key for key in SLOW_KEYS if key in untared), *(key for key in untared if key not in SLOW_KEYS)]
    first = calibrations + episodes(slow_first, setup)
    total = len(first) + args.episodes * (len(keys) - len(untared)) + 1
    # One pool, and no barrier between the batches: the second needs the tares, which the calibrations (the
    # first results) give, and queues behind the rest of the first batch while it runs.
    with process_pool(args.workers) as pool, tqdm(total=total, desc="episodes", unit="ep") as progress:
        running = iterate_tasks(first, args.workers, progress, pool)
        results = list(itertools.islice(running, len(calibrations)))
        calibration = tares_from_results(results, setup)
        tared_setup = calibrated_setup(setup, calibration, args.scenario)
        payloads = (TABLE2_PAYLOAD,) * args.cycles
        healthy = dataclasses.replace(args.scenario, task=dataclasses.replace(args.scenario.task, faults=()))
        table2 = Task("table2", TABLE2_KEY, 0, args.seed, args.cycles, tared_setup, payloads, healthy)
        second = [*episodes([key for key in keys if key not in untared], tared_setup), table2]
        queued = iterate_tasks(second, args.workers, progress, pool)
        results += [*running, *queued]
    return results, calibration.tares, calibration.spreads


def _episodes_in_order(
    results: list[tuple[Task, EpisodeRecord]], keys: Sequence[str]
) -> list[tuple[Task, EpisodeRecord]]:
    """The comparison's episodes, by controller in the order of ``keys``, then by episode index."""
    order = {key: n for n, key in enumerate(keys)}
    episodes = ((task, record) for task, record in results if task.kind == "episode")
    return sorted(episodes, key=lambda item: (order[item[0].key], item[0].index))


def _identity(task: Task) -> dict[str, Any]:
    """The identity columns of an episode's rows: controller label and key, episode index and seed."""
    return {"controller": controller_entry(task.key).label, "key": task.key, "episode": task.index, "seed": task.seed}


def tabulate(
    results: list[tuple[Task, EpisodeRecord]], keys: Sequence[str]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, EpisodeRecord]]:
    """Per-episode rows, per-carry rows (estimating controllers) and the first episode of each controller."""
    episode_rows, carry_rows, first = [], [], {}
    for task, record in _episodes_in_order(results, keys):
        entry = controller_entry(task.key)
        identity = _identity(task)
        episode_rows.append({**identity, **record.metrics()})
        if entry.estimates_payload:
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
                        "peak_estimate_kg": carry.peak_estimate,
                    }
                )
        if task.index == 0:
            first[task.key] = record
    return episode_rows, carry_rows, first


def tabulate_faults(results: list[tuple[Task, EpisodeRecord]], keys: Sequence[str]) -> list[dict[str, Any]]:
    """The rows of ``faults.csv`` (:func:`eval.faults.fault_rows`) of the comparison's episodes, in the order of
    :func:`tabulate`: every injected fault, detected or missed, and every detection that matched none."""
    rows = []
    for task, record in _episodes_in_order(results, keys):
        rows += fault_rows(_identity(task), record.faults())
    return rows


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
