"""Run a grid of work units on a backend, appending each result to the table as it arrives.

Results table: CSV, one row per episode, appended as each episode finishes, so an interrupted sweep loses
at most the row being written (a torn last line is dropped on resume). CSV rather
than Parquet: a Parquet file cannot be appended row by row (each append is a new file or row group) and
needs pyarrow; at a sweep's size (10^4 to 10^5 rows, a few MB) CSV is small, greppable and opens
anywhere.

Setups: what the controllers know is per scenario (:data:`eval.work.Setups`, by scenario content hash): the
identification of the scenario's robot and the tares measured on the scenario.

Resume: each unit has a content key, a hash of (scenario content hash, controller, seed, code version,
what the controllers know), and nothing of how it runs (backend, workers, host); a rerun skips every key already
in the table, failed ones included (a failure is a result; changing the code changes the key and so recomputes it),
whichever backend ran it.

Backends: those of the one executor (:func:`eval.processes.run_jobs`, by :func:`eval.work.run_grid`): a local process
pool or Ray. A unit whose worker died too often is recorded as failed (:func:`failed_row`).
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import time
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path
from typing import Any

from controllers.registry import controller_label
from eval.sweep.work import METRIC_FIELDS, run_unit
from eval.work import Setups, Work, WorkUnit, run_grid

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
        code_version: :func:`eval.work.code_version`.
        setup_digests: :func:`eval.sweep.work.setup_digest` of each controller's setup, by (scenario content hash,
            controller key).
        backend: ``"local"`` or ``"ray"`` (:func:`eval.processes.run_jobs`).
        workers: Local processes, or CPUs of an in-process Ray.
        address: Ray cluster address (``ray`` backend only).
        work: The work function (the default in production; tests count its calls).
        progress: A tqdm bar updated per finished unit, or None.

    Returns:
        ``{"total", "skipped", "ran", "failed"}`` unit counts.
    """
    units = list(units)
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

    run_grid(
        pending,
        setups,
        work=work,
        backend=backend,
        workers=workers,
        address=address,
        on_result=on_result,
        on_lost=lambda unit, error: failed_row(error),
        keep=False,
    )
    return counts
