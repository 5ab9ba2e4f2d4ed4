"""Taring the payload estimators: the apparent payload of the empty gripper, measured like a scale's.

Each RLS controller runs pick-and-place episodes with nothing to pick (0 kg objects, the gripper still
closes and opens) on seeds of their own; :func:`controllers.payload.tare_from_observations` turns their
observations into the tare (kg) and its spread over the carries. ``python -m eval``, the sweep, the residual
training and the design verification (on its standard cycles, given as references) tare their estimators
with these functions; :func:`tare_setup` keeps each tare as a file keyed by the content hash of what decides it
(the robot and what its controllers know, the scenario's work, the seeds and the code), so that the comparison and
every seed of the sweep use one tare, measured once.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from controllers.payload import EmptyMoveSums, tare_from_observations
from controllers.registry import (
    CELL_ESTIMATOR_KEY,
    ControllerSetup,
    controller_entry,
    controller_source,
    payload_estimator,
)
from delta_env.records import content_hash, from_table, to_table
from delta_env.scenario import Scenario
from delta_env.trajectories import Trajectory
from eval.episodes import EpisodeRecord
from eval.work import WorkUnit, code_version, run_grid

CALIBRATION_SEED_OFFSET = 100_000
"""The tare's payload-free episodes use seeds ``100000 + j``: paths and noise unlike those of the experiments' episodes
(seeds below 100000 by convention), the same for every experiment, so that a tare is one fact of a robot and what
its controllers know (:func:`tare_setup` keeps it)."""

DEFAULT_CALIBRATION_EPISODES = 6
"""Payload-free episodes per tare: the apparent payload of an empty gripper varies by about 10 g from episode to
episode (noise and path), so six of them put the tare's own standard error near 4 g, against a +-25 g target for
light objects."""


def calibration_seeds(episodes: int) -> list[int]:
    """Seeds of the tare's ``episodes`` payload-free episodes: ``100000 + j``, whatever the experiment's seeds."""
    return [CALIBRATION_SEED_OFFSET + j for j in range(episodes)]


def tared_keys(controllers: Iterable[str], scenario: Scenario | None) -> list[str]:
    """The keys under which an experiment tares the estimators of ``controllers``
    (:attr:`ControllerEntry.tare_key`: a tared row's own, a wrapping row's base's), and the cell's estimator
    (:data:`controllers.registry.CELL_ESTIMATOR_KEY`) when ``scenario``'s online timing reads it beside controllers
    without one of their own."""
    tare_keys = (controller_entry(key).tare_key for key in controllers)
    keys = [key for key in dict.fromkeys(tare_keys) if key is not None]
    if scenario is not None and scenario.task.timing == "online" and CELL_ESTIMATOR_KEY not in keys:
        keys.append(CELL_ESTIMATOR_KEY)
    return keys


class Calibration(NamedTuple):
    """What the payload-free episodes tell each RLS controller (by key).

    Attributes:
        tares: Apparent payload of the empty gripper (kg).
        spreads: Its carry-to-carry standard deviation (kg).
        empty_moves: The sums of the episodes' empty moves (:class:`~controllers.payload.EmptyMoveSums`).
    """

    tares: dict[str, float]
    spreads: dict[str, float]
    empty_moves: dict[str, EmptyMoveSums]


def calibrated_setup(setup: ControllerSetup, calibration: Calibration, scenario: Scenario | None) -> ControllerSetup:
    """``setup`` with the tares of ``calibration``, the scenario's fault reaction and, if the episodes run on the robot
    it was measured on, the sums of its empty moves.

    The robot is the calibration's unless ``scenario`` randomizes the plant per episode: then every episode is
    another robot, and what the calibration's robots taught about their own mass and friction errors does not
    hold for it (each episode fits its own on its empty moves).
    """
    randomized = scenario is not None and scenario.task.domain_randomization is not None
    empty_moves = {} if randomized else dict(calibration.empty_moves)
    reaction = setup.fault_reaction if scenario is None else scenario.task.fault_reaction
    return dataclasses.replace(setup, tares=dict(calibration.tares), empty_moves=empty_moves, fault_reaction=reaction)


def _healthy(scenario: Scenario) -> Scenario:
    """``scenario`` without its faults: a tare is measured on healthy work."""
    if not scenario.task.faults:
        return scenario
    return dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, faults=()))


def calibration_units(
    keys: Iterable[str],
    seeds: Sequence[int],
    n_cycles: int,
    scenario: Scenario | None = None,
    references: Sequence[Trajectory] | None = None,
) -> list[WorkUnit]:
    """The payload-free episodes of every RLS controller in ``keys`` (observations kept), one per seed, of
    ``n_cycles`` cycles on ``scenario`` (None: ``nominal``) without its faults, following ``references[j]`` on seed
    ``j`` when given (else the scenario's pick-and-place)."""
    if references is not None and len(references) != len(seeds):
        raise ValueError(f"references must be one per seed: {len(references)} references for {len(seeds)} seeds")
    paths = [None] * len(seeds) if references is None else list(references)
    healthy = _healthy(Scenario() if scenario is None else scenario)
    healthy = dataclasses.replace(healthy, task=dataclasses.replace(healthy.task, n_cycles=n_cycles))
    empty = (0.0,) * n_cycles
    units = []
    for key in keys:
        if not controller_entry(key).tared:
            raise ValueError(f"{key!r} has no tared payload estimator (ControllerEntry.tared)")
        units += [
            WorkUnit(healthy, key, seed, empty, path, keep_observations=True)
            for seed, path in zip(seeds, paths, strict=True)
        ]
    return units


def tares_from_results(
    results: Iterable[tuple[WorkUnit, EpisodeRecord]], setup: ControllerSetup, max_loop_gap: float | None = None
) -> Calibration:
    """Tare (kg), its carry-to-carry spread (kg) and the empty moves' sums per RLS controller, from its calibration
    episodes.

    Args:
        results: The calibration's units (:func:`calibration_units`) and their records.
        setup: What the controllers know (their estimators are rebuilt from it, untared).
        max_loop_gap: Largest loop gap (m) a calibration episode may open; None accepts what the env accepts.

    Raises:
        RuntimeError: if a calibration episode diverged or opened a loop beyond ``max_loop_gap`` (its
            observations would give a meaningless tare).
    """
    observed: dict[str, list] = {}
    for unit, record in results:
        if record.diverged:
            raise RuntimeError(f"the calibration episode of {unit.controller!r} on seed {unit.seed} diverged")
        if max_loop_gap is not None and not record.max_loop_gap <= max_loop_gap:
            raise RuntimeError(
                f"the calibration episode of {unit.controller!r} on seed {unit.seed} opened a loop by "
                f"{1e3 * record.max_loop_gap:.3f} mm (limit {1e3 * max_loop_gap:.3f} mm)"
            )
        observed.setdefault(unit.controller, []).append(record.observations)
    calibration = Calibration({}, {}, {})
    for key, episodes in observed.items():
        tare = tare_from_observations(payload_estimator(key, setup), episodes)
        calibration.tares[key], calibration.spreads[key] = tare.mass, tare.spread
        calibration.empty_moves[key] = tare.empty_moves
    return calibration


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
) -> Calibration:
    """Run the calibration episodes of ``keys`` on ``scenario`` (None: ``nominal``), along ``references``
    (one per seed) if given, on ``workers`` processes (:func:`eval.work.run_grid`), and return what they tell each
    (see :func:`tares_from_results` for ``max_loop_gap``)."""
    units = calibration_units(keys, seeds, n_cycles, scenario, references)
    setups = {unit.scenario.content_hash: setup for unit in units}
    records = run_grid(units, setups, workers=workers, progress=progress)
    return tares_from_results(zip(units, records, strict=True), setup, max_loop_gap)


@dataclass(frozen=True)
class KeptTare:
    """One controller's tare as :func:`tare_setup` keeps it (written and read by :mod:`delta_env.records`).

    Attributes:
        controller: Its key.
        tare_kg: The tare (kg).
        spread_kg: Its carry-to-carry standard deviation (kg); None for a single carry.
        empty_moves: The sums of the calibration's empty moves.
        content: What decided it (:func:`tare_content`), for the reader.
    """

    controller: str
    tare_kg: float
    spread_kg: float | None
    empty_moves: EmptyMoveSums
    content: Mapping[str, str]


def tare_content(
    key: str, scenario: Scenario, setup: ControllerSetup, seeds: Sequence[int], max_loop_gap: float | None
) -> dict[str, str]:
    """What decides the tare of ``key``, as content hashes: the scenario's healthy work, what the controllers know
    (:meth:`~controllers.setup.ControllerSetup.content_hash`, without tares, empty moves or residual policy), the
    key and a user controller's source, the seeds, the loop-gap limit and the code
    (:func:`eval.work.code_version`)."""
    untared = dataclasses.replace(setup, tares={}, empty_moves={}, residual_policy=None)
    run = {"seeds": list(seeds), "max_loop_gap": max_loop_gap}
    return {
        "scenario": _healthy(scenario).content_hash,
        "setup": untared.content_hash(),
        "controller": key,
        "controller_source": hashlib.sha256(controller_source(key)).hexdigest()[:16],
        "run": content_hash(to_table(run)),
        "code": code_version(),
    }


def _read_kept(path: Path) -> Calibration:
    """The calibration of one controller kept at ``path``; ValueError naming the file if it cannot be read."""
    try:
        kept = from_table(KeptTare, json.loads(path.read_text()), "")
    except (OSError, ValueError) as error:
        raise ValueError(f"{path}: unreadable kept tare ({error}); delete it to measure the tare again") from None
    spread = math.nan if kept.spread_kg is None else kept.spread_kg
    key = kept.controller
    return Calibration({key: kept.tare_kg}, {key: spread}, {key: kept.empty_moves})


def _keep(path: Path, key: str, calibration: Calibration, content: dict[str, str]) -> None:
    """Write ``key``'s part of ``calibration`` to ``path`` (whole or not at all)."""
    spread = calibration.spreads[key]
    spread_kg = None if math.isnan(spread) else spread
    kept = KeptTare(key, calibration.tares[key], spread_kg, calibration.empty_moves[key], content)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a name of this process's own: two runs keeping the same tare at once each replace the file whole
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    partial.write_text(json.dumps(to_table(kept), indent=2) + "\n")
    partial.replace(path)


def tare_setup(
    scenario: Scenario,
    setup: ControllerSetup,
    controllers: Iterable[str],
    *,
    episodes: int = DEFAULT_CALIBRATION_EPISODES,
    workers: int = 1,
    progress: Any = None,
    references: Sequence[Trajectory] | None = None,
    max_loop_gap: float | None = None,
    kept: Path | None = None,
) -> tuple[ControllerSetup, Calibration]:
    """``setup`` tared for ``controllers`` on ``scenario`` (:func:`calibrated_setup`), and the calibration: the
    payload-free episodes of :func:`tared_keys` on the :func:`calibration_seeds` (along ``references``, one per
    calibration seed, if given). Nothing runs when no controller is tared.

    Args:
        kept: Folder of the kept tares (one file per controller, named by the hash of :func:`tare_content`): a tare
            found there is read, not measured; one measured is written there. None (or ``references`` given):
            measure every tare.
    """
    keys = tared_keys(controllers, scenario)
    seeds = calibration_seeds(episodes)
    calibration = Calibration({}, {}, {})
    files = {}
    if kept is not None and references is None:
        for key in keys:
            content = tare_content(key, scenario, setup, seeds, max_loop_gap)
            files[key] = (kept / f"{key.replace(':', '-')}-{content_hash(content)}.json", content)
    found = {key: _read_kept(path) for key, (path, _) in files.items() if path.is_file()}
    missing = [key for key in keys if key not in found]
    measured = Calibration({}, {}, {})
    if missing:
        measured = calibrate_tares(
            missing,
            setup,
            seeds,
            scenario.task.n_cycles,
            workers=workers,
            progress=progress,
            scenario=scenario,
            references=references,
            max_loop_gap=max_loop_gap,
        )
    for key in keys:
        one = found.get(key, measured)
        if key in files and key not in found:
            path, content = files[key]
            _keep(path, key, measured, content)
        calibration.tares[key], calibration.spreads[key] = one.tares[key], one.spreads[key]
        calibration.empty_moves[key] = one.empty_moves[key]
    if progress is not None:
        progress.update(episodes * len(found))
    return calibrated_setup(setup, calibration, scenario), calibration
