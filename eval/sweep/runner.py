"""Run a grid of work units on a backend, appending each result to the table as it arrives.

Results table: CSV, one row per episode, appended as each episode finishes, so an interrupted sweep loses
at most the row being written (a torn last line is dropped on resume). CSV rather
than Parquet: a Parquet file cannot be appended row by row (each append is a new file or row group) and
needs pyarrow; at a sweep's size (10^4 to 10^5 rows, a few MB) CSV is small, greppable and opens
anywhere.

Setups: what the controllers know is per scenario (:data:`Setups`, by scenario content hash): the
identification of the scenario's robot and the tares measured on the scenario.

Resume: each unit has a content key, a hash of (scenario content hash, controller, seed, code version,
what the controllers know), and nothing of how it runs (backend, workers, host); a rerun skips every key already
in the table, failed ones included (a failure is a result; changing the code changes the key and so recomputes it),
whichever backend ran it.

Backends (:func:`run_units`, which :func:`eval.engine.run_grid` calls too), one work function
(:func:`eval.sweep.work.run_unit` for the sweep's rows):

- ``local``: a process pool of ``workers`` processes on this machine (forkserver or spawn, never fork:
  torch may be loaded), or this process itself when ``workers`` is 1. At most ``workers`` units are in
  flight, so when a worker dies (the pool breaks) the units it may have held are known and resubmitted
  on a new pool, up to ``max_attempts`` times each, then recorded as failed.
- ``ray``: Ray tasks; Ray resubmits a task whose worker died (``max_retries``). Without an address Ray
  starts in this process with ``workers`` CPUs; with one (``auto`` or ``ray://host:port``) it joins the
  cluster and ships this checkout's packages to it (``runtime_env`` ``py_modules``).
"""

from __future__ import annotations

import concurrent.futures
import csv
import hashlib
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from controllers.registry import controller_label, controller_packages
from eval.processes import holding_interrupts, ignore_interrupts, pool_context
from eval.sweep.work import METRIC_FIELDS, ControllerSetup, WorkUnit, run_unit

IDENTITY_FIELDS = (
    "key",
    "scenario",
    "scenario_hash",
    "robot_identity",
    "controller",
    "label",
    "seed",
    "code_version",
    "setup_digest",
)
RESULT_FIELDS = (*IDENTITY_FIELDS, "status", "error", *METRIC_FIELDS, "seconds", "cpu_seconds", "host", "pid")
"""Columns of ``results.csv``."""

DEFAULT_MAX_ATTEMPTS = 3
"""Runs of a unit whose worker died before it is recorded as failed."""

Work = Callable[[WorkUnit, ControllerSetup], Any]
"""A work function: :func:`eval.sweep.work.run_unit` (a row) or :func:`eval.sweep.work.unit_record` (a record)."""
OnResult = Callable[[WorkUnit, Any], None]
OnLost = Callable[[WorkUnit, str], None]
"""Told a unit whose worker died too often, and why; by default its row is :func:`failed_row`."""
Setups = Mapping[str, ControllerSetup]
"""What the controllers know on each scenario, by the scenario's content hash."""


def unit_key(unit: WorkUnit, code_version: str, setup_digest: str) -> str:
    """Content key (16 hex digits) of a unit: what decides its result, nothing else (names excluded)."""
    content = {
        "scenario": unit.scenario.content_hash,
        "controller": unit.controller,
        "seed": unit.seed,
        "code": code_version,
        "setup": setup_digest,
    }
    if unit.masses is not None:
        content["masses"] = list(unit.masses)
    if unit.reference is not None:
        content["reference"] = unit.reference.content_hash()
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


def identity_row(unit: WorkUnit, key: str, code_version: str, setup_digest: str) -> dict[str, Any]:
    """The identity columns of a unit's row."""
    return {
        "key": key,
        "scenario": unit.scenario.name,
        "scenario_hash": unit.scenario.content_hash,
        "robot_identity": unit.scenario.robot_identity,
        "controller": unit.controller,
        "label": _label(unit.controller),
        "seed": unit.seed,
        "code_version": code_version,
        "setup_digest": setup_digest,
    }


def _label(key: str) -> str:
    """The controller's label; its key when it cannot be resolved (its row records the error)."""
    try:
        return controller_label(key)
    except ValueError:
        return key


class ResultsTable:
    """The append-only CSV of a sweep (:data:`RESULT_FIELDS`)."""

    def __init__(self, path: Path, sync_interval: float = 1.0) -> None:
        self.path = Path(path)
        self.sync_interval = sync_interval
        self._last_sync = -math.inf

    def load(self) -> list[dict[str, str]]:
        """Rows already written; a torn last line (the process died while writing it) is cut off the file.

        Raises:
            ValueError: if the file has other columns (a table of another code version of the sweep).
        """
        if not self.path.exists():
            return []
        text = self.path.read_text()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
            self.path.write_text(text)
        lines = text.splitlines()
        if not lines:
            return []
        header = next(csv.reader(lines[:1]))
        if tuple(header) != RESULT_FIELDS:
            raise ValueError(f"{self.path} has the columns {header}, not {list(RESULT_FIELDS)}: use another --out")
        return list(csv.DictReader(lines))

    def drop(self, keys: Collection[str]) -> None:
        """Remove the rows of ``keys`` (to run them again), the file replaced whole."""
        rows = self.load()
        if not any(row["key"] in keys for row in rows):
            return
        partial = self.path.with_name(f".{self.path.name}.partial")
        with partial.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=RESULT_FIELDS)
            writer.writeheader()
            writer.writerows(row for row in rows if row["key"] not in keys)
        partial.replace(self.path)

    def append(self, row: dict[str, Any]) -> None:
        """Write one row (header first if the file is new).

        Each row reaches the operating system at once, so it survives the death of this process; the file
        is synced to the disk at most every ``sync_interval`` seconds (an fsync per row would cap the row rate).
        """
        new = not self.path.exists() or self.path.stat().st_size == 0
        with self.path.open("a", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=RESULT_FIELDS)
            if new:
                writer.writeheader()
            writer.writerow(row)
            file.flush()
            if time.monotonic() - self._last_sync >= self.sync_interval:
                os.fsync(file.fileno())
                self._last_sync = time.monotonic()


def failed_row(error: str) -> dict[str, Any]:
    """The work-function part of a row for a unit that never returned (its worker died)."""
    return {"status": "failed", "error": error, **dict.fromkeys((*METRIC_FIELDS, "seconds", "cpu_seconds"), math.nan)}


def run_local(
    units: Sequence[WorkUnit],
    setups: Setups,
    workers: int,
    on_result: OnResult,
    work: Work = run_unit,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    on_lost: OnLost | None = None,
) -> None:
    """Run ``units`` on a local process pool (in this process if ``workers`` is 1), in any order."""
    lost = on_lost or _lost_row(on_result)
    if workers == 1:
        for unit in units:
            on_result(unit, work(unit, setups[unit.scenario.content_hash]))
        return
    queue = list(reversed(units))
    attempts = dict.fromkeys(range(len(units)), 0)
    index = {id(unit): n for n, unit in enumerate(units)}
    while queue:
        with concurrent.futures.ProcessPoolExecutor(
            workers, mp_context=pool_context(), initializer=ignore_interrupts
        ) as pool:
            running: dict[concurrent.futures.Future, WorkUnit] = {}
            broken = False
            try:
                while (queue or running) and not broken:
                    with holding_interrupts():  # a submit may start a worker
                        while queue and len(running) < workers:
                            unit = queue.pop()
                            attempts[index[id(unit)]] += 1
                            running[pool.submit(work, unit, setups[unit.scenario.content_hash])] = unit
                    done, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                    for future in done:
                        unit = running.pop(future)
                        try:
                            on_result(unit, future.result())
                        except BrokenProcessPool:
                            broken = True
                            _retry_or_fail(unit, attempts[index[id(unit)]], max_attempts, queue, lost)
            except BaseException:
                # Ctrl-C, SIGTERM or an error: stop the episodes under way, which the executor would wait for
                # (it has no public way to stop its workers before Python 3.14's terminate_workers).
                for process in list(pool._processes.values()):
                    process.terminate()
                pool.shutdown(wait=False, cancel_futures=True)
                raise
            if broken:  # the other units in flight died with the pool
                for future, unit in running.items():
                    if future.done() and not future.exception():
                        on_result(unit, future.result())
                    else:
                        _retry_or_fail(unit, attempts[index[id(unit)]], max_attempts, queue, lost)


def _lost_row(on_result: OnResult) -> OnLost:
    """Record a lost unit as a :func:`failed_row`."""
    return lambda unit, error: on_result(unit, failed_row(error))


def _retry_or_fail(unit: WorkUnit, attempts: int, max_attempts: int, queue: list, on_lost: OnLost) -> None:
    if attempts < max_attempts:
        queue.append(unit)
    else:
        on_lost(unit, f"worker died {attempts} times running this unit")


def run_ray(
    units: Sequence[WorkUnit],
    setups: Setups,
    workers: int,
    on_result: OnResult,
    work: Work = run_unit,
    address: str | None = None,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    on_lost: OnLost | None = None,
) -> None:
    """Run ``units`` as Ray tasks, in any order: on a Ray started here with ``workers`` CPUs, or on the
    cluster at ``address`` (``"auto"``, ``"ray://host:port"``)."""
    ray = import_ray()
    lost = on_lost or _lost_row(on_result)
    started_here = not ray.is_initialized()
    if started_here:
        # ray.init installs its own SIGTERM handler (sys.exit); the run folder's records the run as interrupted
        handler = signal.getsignal(signal.SIGTERM)
        if address is None:
            # "local": a new instance even when the machine runs (or ran) another cluster.
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            import controllers
            import delta_env
            import eval as eval_package

            folders = [str(Path(package.__file__).parent) for package in (controllers, delta_env, eval_package)]
            folders += controller_packages({unit.controller for unit in units})
            ray.init(address=address, runtime_env={"py_modules": folders}, log_to_driver=False)
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)
    try:
        remote = ray.remote(num_cpus=1, max_retries=max_attempts - 1)(work)
        setup_refs = {content: ray.put(setup) for content, setup in setups.items()}
        window = 4 * max(1, int(ray.cluster_resources().get("CPU", workers)))
        queue = list(reversed(units))
        running: dict[Any, WorkUnit] = {}
        while queue or running:
            while queue and len(running) < window:
                unit = queue.pop()
                running[remote.remote(unit, setup_refs[unit.scenario.content_hash])] = unit
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                unit = running.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayTaskError:  # the work function raised: the caller's error
                    raise
                except ray.exceptions.RayError as error:  # the worker died max_attempts times, or Ray failed
                    lost(unit, f"{type(error).__name__}: {error}")
                else:
                    on_result(unit, result)
    finally:
        if started_here:
            ray.shutdown()


def import_ray() -> Any:
    """The ``ray`` module, or an ImportError naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise ImportError(
            "--backend ray needs Ray: install the 'distributed' extra (pip install '.[distributed]')"
        ) from None
    return ray


def _check_run(units: Sequence[WorkUnit], setups: Setups, backend: str, address: str | None) -> None:
    """ValueError for an unknown backend, an address without Ray, or a unit whose scenario has no setup."""
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if address is not None and backend != "ray":
        raise ValueError("address is for the ray backend only")
    missing = sorted({unit.scenario.name for unit in units if unit.scenario.content_hash not in setups})
    if missing:
        raise ValueError(f"no controller setup for the scenarios {missing}")


def run_units(
    units: Sequence[WorkUnit],
    setups: Setups,
    on_result: OnResult,
    *,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    work: Work = run_unit,
    on_lost: OnLost | None = None,
) -> None:
    """Run ``work`` on every unit with its scenario's setup on ``backend`` (``"local"`` or ``"ray"``; ``address``:
    the Ray cluster to join), in any order, calling ``on_result(unit, result)`` as each finishes and ``on_lost(unit,
    error)`` for a unit whose worker died too often (None: its result is a :func:`failed_row`)."""
    _check_run(units, setups, backend, address)
    if not units:
        return
    if backend == "local":
        run_local(units, setups, workers, on_result, work, on_lost=on_lost)
    else:
        run_ray(units, setups, workers, on_result, work, address, on_lost=on_lost)


def run_sweep(
    units: Iterable[WorkUnit],
    setups: Setups,
    table: ResultsTable,
    code_version: str,
    setup_digests: Mapping[tuple[str, str], str],
    *,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    work: Work = run_unit,
    progress: Any = None,
) -> dict[str, int]:
    """Run the units whose key is not in ``table`` yet, appending each row as it arrives.

    Args:
        units: The grid.
        setups: What the controllers know, by scenario content hash.
        table: The results table (read for resume, appended to).
        code_version: :func:`eval.sweep.work.code_version`.
        setup_digests: :func:`eval.sweep.work.setup_digest` of each controller's setup, by (scenario content hash,
            controller key).
        backend: ``"local"`` or ``"ray"``.
        workers: Local processes, or CPUs of an in-process Ray.
        address: Ray cluster address (``ray`` backend only).
        work: The work function (the default in production; tests count its calls).
        progress: A tqdm bar updated per finished unit, or None.

    Returns:
        ``{"total", "skipped", "ran", "failed"}`` unit counts.
    """
    units = list(units)
    _check_run(units, setups, backend, address)
    keys = [unit_key(unit, code_version, setup_digests[unit.scenario.content_hash, unit.controller]) for unit in units]
    if len(set(keys)) != len(keys):
        raise ValueError("the grid holds the same unit twice (same scenario content, controller, seed, masses, path)")
    finished = {row["key"] for row in table.load()}
    pending = [unit for unit, key in zip(units, keys, strict=True) if key not in finished]
    key_of = {id(unit): key for unit, key in zip(units, keys, strict=True)}
    counts = {"total": len(units), "skipped": len(units) - len(pending), "ran": 0, "failed": 0}
    if progress is not None:
        progress.update(counts["skipped"])

    def on_result(unit: WorkUnit, result: dict[str, Any]) -> None:
        digest = setup_digests[unit.scenario.content_hash, unit.controller]
        row = {**identity_row(unit, key_of[id(unit)], code_version, digest), **result}
        table.append(row)
        counts["ran"] += 1
        counts["failed"] += row["status"] != "ok"
        if progress is not None:
            progress.update()

    if pending:
        run_units(pending, setups, on_result, backend=backend, workers=workers, address=address, work=work)
    return counts
