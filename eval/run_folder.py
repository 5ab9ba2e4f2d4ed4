"""The run folder every command line writes: where it is and how the run was made.

Each CLI (``python -m eval``, ``python -m eval.identify``, ``python -m eval.train_residual``) creates its
folder with :func:`create_run_folder` and writes ``config.json`` with :func:`write_config`: the resolved
configuration of the run under ``"config"`` and, in the same schema for every tool, the command that
reproduces it, the package versions, the git commit of the code and the start time. Tables go in as CSV
with :func:`write_csv`.
"""

from __future__ import annotations

import csv
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

RUN_PACKAGES = (
    "numpy",
    "scipy",
    "mujoco",
    "gymnasium",
    "filterpy",
    "matplotlib",
    "stable-baselines3",
    "sb3-contrib",
    "torch",
)
"""Packages whose versions decide a run's numbers."""

RUNS_ROOT = Path("runs")
"""Where run folders go by default (relative to the working directory): ``runs/<tool>/<timestamp>``."""


def package_versions(packages: Sequence[str] = RUN_PACKAGES) -> dict[str, str]:
    """Python's and each package's version ("not installed" when absent)."""
    versions = {"python": platform.python_version()}
    for package in packages:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def command_line(module: str, argv: Sequence[str] | None = None) -> str:
    """The shell command ``python -m module args`` that reproduces this run (argv defaults to sys.argv[1:])."""
    return shlex.join(["python", "-m", module, *(sys.argv[1:] if argv is None else argv)])


def git_commit() -> str | None:
    """The commit of the code being run (with ``+dirty`` if it has uncommitted changes), or None outside git."""
    folder = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=folder
        ).stdout.strip()
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
            cwd=folder,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return f"{commit}+dirty" if status else commit


def create_run_folder(tool: str, out: Path | None = None, *, stamp: str | None = None) -> Path:
    """The run folder ``out`` or ``runs/<tool>/<local time stamp>``, created with its parents."""
    if out is None:
        stamp = stamp if stamp is not None else datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = RUNS_ROOT / tool / stamp
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def json_ready(value: Any) -> Any:
    """``value`` with numpy scalars and arrays as Python numbers and lists, paths and other objects as strings."""
    if isinstance(value, Mapping):
        return {str(key): json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def write_json(path: Path, document: Mapping[str, Any]) -> Path:
    """Write ``document`` (made JSON-ready) as indented JSON; returns the path."""
    path.write_text(json.dumps(json_ready(document), indent=2) + "\n")
    return path


def write_csv(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> Path:
    """Write dict rows as CSV with a header: the union of their keys, in order of appearance (missing cells
    empty); returns the path."""
    path = Path(path)
    fields = list(dict.fromkeys(key for row in rows for key in row))
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    return path


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file written so far by :func:`append_csv_rows` (none if it does not exist); a torn last
    line (the run died while writing it) is cut off, in the file too."""
    if not path.exists():
        return []
    text = path.read_text()
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
        path.write_text(text)
    return list(csv.DictReader(text.splitlines()))


def append_csv_rows(path: Path, columns: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Append ``rows`` to a CSV file (the header first if the file is new), synced at once so that they survive an
    interruption: the rows of a long run that resumes from what it wrote."""
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=columns, extrasaction="ignore")
        if new:
            writer.writeheader()
        writer.writerows(rows)
        file.flush()
        os.fsync(file.fileno())


def write_config(folder: Path, command: str, config: Mapping[str, Any], **extra: Any) -> Path:
    """Write ``folder/config.json``: the command, the resolved configuration and how the run was made.

    Args:
        folder: The run folder.
        command: The command line that reproduces the run (:func:`command_line`).
        config: The resolved configuration (arguments, seeds, settings).
        **extra: Further top-level entries (results known when the file is rewritten at the end of a run).
    """
    document = {
        "command": command,
        "config": dict(config),
        "versions": package_versions(),
        "git_commit": git_commit(),
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        **extra,
    }
    return write_json(folder / "config.json", document)
