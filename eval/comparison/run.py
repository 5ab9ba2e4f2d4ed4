"""The controller comparison of ``python -m eval``: every controller on the same seeded episodes.

1. Prepares what the controllers know (:func:`eval.engine.prepare`): the robot's identification and the tare of
   each payload estimator (:mod:`eval.calibration`: its controller's payload-free pick-and-place episodes on seeds
   of their own, measured once per robot and setup and kept beside the identification).
2. Runs every controller on episodes ``seed, seed + 1, ...`` of the scenario (:func:`eval.work.run_grid`; by
   default ``nominal``: realistic plant, 3 g conveyor cycles, objects drawn from U[0, 4] kg): the same paths and
   objects for all.
3. Runs the Table 2 analogue, without the scenario's faults: MId+F+R+RLS on the path of the first episode with
   every object 3.8 kg (the paper's experiment when the scenario is ``paper``: standard cycles, 3.8 kg on every
   pick); the
   measured torques against MId+F+R with mp = 0 and with mp = m_hat.
4. Tabulates per episode and per carried object (:func:`tabulate`, :func:`table2_statistics`), and the
   faults injected into the episodes and detected by the controllers (:func:`tabulate_faults`); picks the first
   episode of each controller, whose time series are kept (:func:`first_episodes`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from controllers.registry import controller_entry
from delta_env.scenario import Scenario
from eval import metrics
from eval.calibration import tared_keys
from eval.console import progress_bar
from eval.engine import Prepared, grid, prepare
from eval.episodes import EpisodeRecord
from eval.fault_tables import fault_rows
from eval.work import WorkUnit, run_grid

TABLE2_KEY = "mid_f_rls"
"""The controller of the Table 2 run: MId+F+R with the default payload estimator."""

TABLE2_PAYLOAD = 3.8
"""Mass of every object in the Table 2 run (kg), the paper's test payload."""


@dataclasses.dataclass(frozen=True)
class ComparisonConfig:
    """The resolved configuration of a comparison (``python -m eval``), recorded as it is in the run's manifest
    (:func:`eval.run_folder.configuration_record`).

    Attributes:
        scenario: The scenario, on ``geometry``'s robot and released as ``release`` says.
        geometry: The geometry file of ``--geometry``, or None.
        release: ``--release``, or None (the scenario's).
        seed: Seed of the first episode.
        episodes: Episodes per controller.
        cycles: Pick-and-place cycles per episode.
        controllers: The rows' controller keys, in order.
        out: The run folder: ``--out`` until the folder is made, then the folder.
        force: Write into an existing, non-empty ``out``.
        runs_dir: ``--runs-dir``, or None.
        parameters: The identified parameter file: ``--parameters`` (None: the robot's own) until it is known.
        servo: Feedback of the model rows (:data:`controllers.setup.SERVOS`).
        calibration_episodes: Payload-free episodes of each tare.
        residual: The policy file of the rows that read one.
        workers: Processes.
        video: Film the first episode of each row.
        left_out: The sentence saying which rows were left out, or "".
        residual_base: Name of the policy's base controller, or None (none read, or a custom base).
        residual_base_moves: Whether the policy file's base carries its own empty moves.
        residual_base_servo: The policy's base's feedback, or None.
    """

    scenario: Scenario
    geometry: str | None
    release: str | None
    seed: int
    episodes: int
    cycles: int
    controllers: tuple[str, ...]
    out: Path | None
    force: bool
    runs_dir: Path | None
    parameters: Path | None
    servo: str
    calibration_episodes: int
    residual: Path
    workers: int
    video: bool
    left_out: str = ""
    residual_base: str | None = None
    residual_base_moves: bool = False
    residual_base_servo: str | None = None


def queue_order(key: str) -> tuple[bool, bool]:
    """The sort key that queues the rows whose episodes cost the most first, so that the short episodes even out the
    end of the run across the workers: a policy network's (:attr:`~controllers.registry.ControllerEntry.
    reads_policy_file`), then a bound's closed-chain inverse of the plant (``privileged``), then the others."""
    entry = controller_entry(key)
    return not entry.reads_policy_file, not entry.privileged


def run_all(config: ComparisonConfig) -> tuple[Prepared, list[tuple[WorkUnit, EpisodeRecord]]]:
    """Prepare the robot's knowledge (identification and tares, :func:`eval.engine.prepare`), then run every episode
    and the Table 2 run (:func:`eval.work.run_grid`).

    Args:
        config: The comparison's configuration.

    Returns:
        What the controllers knew, and the (unit, record) of every episode: the comparison's, then the Table 2 run.
    """
    keys = config.controllers
    scenario = dataclasses.replace(
        config.scenario, task=dataclasses.replace(config.scenario.task, n_cycles=config.cycles)
    )
    tared = sorted(set(tared_keys([*keys, TABLE2_KEY], scenario)))
    with progress_bar(len(tared) * config.calibration_episodes, "tares", "ep") as progress:
        prepared = prepare(
            scenario,
            tared,
            parameters=config.parameters,
            runs_dir=config.runs_dir,
            calibration_episodes=config.calibration_episodes,
            workers=config.workers,
            progress=progress,
            residual_policy=config.residual,
            servo=config.servo,
        )
    slow_first = sorted(keys, key=queue_order)
    units = grid([scenario], slow_first, range(config.seed, config.seed + config.episodes))
    healthy = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, faults=()))
    units.append(WorkUnit(healthy, TABLE2_KEY, config.seed, (TABLE2_PAYLOAD,) * config.cycles))
    setups = {s.content_hash: prepared.setup for s in (scenario, healthy)}
    with progress_bar(len(units), "episodes", "ep") as progress:
        records = run_grid(units, setups, workers=config.workers, progress=progress)
    return prepared, list(zip(units, records, strict=True))


def _episodes_in_order(
    results: list[tuple[WorkUnit, EpisodeRecord]], keys: Sequence[str]
) -> list[tuple[WorkUnit, EpisodeRecord]]:
    """The comparison's episodes (the Table 2 run left out), by controller in the order of ``keys``, then by seed."""
    order = {key: n for n, key in enumerate(keys)}
    episodes = ((unit, record) for unit, record in results if unit.masses is None)
    return sorted(episodes, key=lambda item: (order[item[0].controller], item[0].seed))


def _identity(unit: WorkUnit, first_seed: int) -> dict[str, Any]:
    """The identity columns of an episode's rows: controller label and key, episode index (from ``first_seed``) and
    seed."""
    key = unit.controller
    return {"controller": controller_entry(key).label, "key": key, "episode": unit.seed - first_seed, "seed": unit.seed}


def tabulate(
    results: list[tuple[WorkUnit, EpisodeRecord]], keys: Sequence[str], first_seed: int
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Per-episode rows and per-carry rows (estimating controllers)."""
    episode_rows, carry_rows = [], []
    for unit, record in _episodes_in_order(results, keys):
        entry = controller_entry(unit.controller)
        identity = _identity(unit, first_seed)
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
    return episode_rows, carry_rows


def first_episodes(
    results: list[tuple[WorkUnit, EpisodeRecord]], keys: Sequence[str], first_seed: int
) -> dict[str, EpisodeRecord]:
    """The first episode (seed ``first_seed``) of each controller, by key in the order of ``keys``."""
    return {unit.controller: record for unit, record in _episodes_in_order(results, keys) if unit.seed == first_seed}


def tabulate_faults(
    results: list[tuple[WorkUnit, EpisodeRecord]], keys: Sequence[str], first_seed: int
) -> list[dict[str, Any]]:
    """The rows of ``faults.csv`` (:func:`eval.fault_tables.fault_rows`) of the comparison's episodes, in the order of
    :func:`tabulate`: every injected fault, detected or missed, and every detection that matched none."""
    rows = []
    for unit, record in _episodes_in_order(results, keys):
        rows += fault_rows(_identity(unit, first_seed), record.faults())
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
