"""The run folder every command line writes: where it is and how the run was made.

Every command line runs inside :func:`run_folder`: it creates the folder (``--out``, else
``<runs root>/<tool>/<UTC time stamp>``) and keeps its manifest, ``config.json``, from the start of the run to its
end, in the same schema for every tool (:func:`run_folder` lists the entries). The runs root is ``--runs-dir``, else
the environment variable ``DELTA_RUNS_DIR``, else ``./runs`` (:func:`runs_root`); the cached identifications live
under it too (:func:`eval.identification.parameter_files.identification_root`). Tables go in as CSV with
:func:`write_csv`.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import datetime
import json
import os
import platform
import shlex
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator, Mapping, Sequence
from importlib import metadata
from pathlib import Path
from types import FrameType
from typing import Any, Protocol

import numpy as np

from delta_env.scenario import Scenario
from eval.console import Terminated, UsageError

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

RUNS_DIR_VARIABLE = "DELTA_RUNS_DIR"
"""Environment variable naming the runs root when ``--runs-dir`` is not given."""

DEFAULT_RUNS_ROOT = Path("runs")
"""The runs root when neither ``--runs-dir`` nor :data:`RUNS_DIR_VARIABLE` is given (relative to the working
directory)."""

MANIFEST = "config.json"
"""File name of a run folder's manifest."""

STATUSES = ("running", "finished", "failed", "interrupted")
"""Outcomes a manifest records: the run is under way, ended normally, raised (the error is recorded) or was
interrupted (Ctrl-C, or SIGTERM: :class:`~eval.console.Terminated`)."""


class _TerminationHandler:
    """SIGTERM -> :class:`Terminated` in this process while installed; the previous handler back on leaving.

    Once :meth:`hold` is called (the manifest is being written) a SIGTERM no longer raises: it is kept and delivered
    again to the previous handler by :meth:`restore` unless the run is already unwinding from the first one. A child
    forked while it is installed (which inherits it) gets the previous behaviour instead.
    """

    def __init__(self) -> None:
        self.owner = os.getpid()
        self.holding = False
        self.pending = False
        self.previous: Any = None
        # signal.signal works in the main thread only; elsewhere SIGTERM keeps its handler.
        self.installed = threading.current_thread() is threading.main_thread()
        if self.installed:
            self.previous = signal.signal(signal.SIGTERM, self)

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if os.getpid() != self.owner:  # a forked child: act as the process would without us
            self.restore()
            os.kill(os.getpid(), signum)
        elif self.holding:
            self.pending = True
        else:
            self.holding = True
            raise Terminated(signal.Signals(signum).name)

    def hold(self) -> None:
        """Keep SIGTERMs from now on instead of raising them."""
        self.holding = True

    def restore(self, *, deliver: bool = False) -> None:
        """Put the previous SIGTERM handler back (the default one if it was not set from Python); with ``deliver``,
        send it a SIGTERM that came while holding."""
        if not self.installed:
            return
        signal.signal(signal.SIGTERM, signal.SIG_DFL if self.previous is None else self.previous)
        self.installed = False
        if deliver and self.pending:
            os.kill(os.getpid(), signal.SIGTERM)


def _outcome(error: BaseException) -> tuple[str, str | None]:
    """The manifest's ``status`` and ``error`` of a run that raised ``error``."""
    if isinstance(error, Terminated):
        return "interrupted", f"Terminated: {error}"
    if isinstance(error, KeyboardInterrupt):
        return "interrupted", "KeyboardInterrupt"
    if isinstance(error, SystemExit):
        return ("finished", None) if error.code in (None, 0) else ("failed", f"SystemExit: {error.code}")
    return "failed", f"{type(error).__name__}: {error}"


def runs_root(runs_dir: str | os.PathLike[str] | None = None) -> Path:
    """The root of the run folders and of the cached identifications: ``runs_dir``, else ``$DELTA_RUNS_DIR``, else
    ``./runs``."""
    if runs_dir is not None:
        return Path(runs_dir)
    return Path(os.environ.get(RUNS_DIR_VARIABLE) or DEFAULT_RUNS_ROOT)


def add_runs_dir_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--runs-dir`` (see :func:`runs_root`) to ``parser``."""
    parser.add_argument(
        "--runs-dir",
        type=Path,
        default=None,
        help=f"root of the run folders and of the cached identifications (default: ${RUNS_DIR_VARIABLE}, else "
        f"./{DEFAULT_RUNS_ROOT})",
    )


def utc_now() -> str:
    """The current time, UTC, ISO 8601 to the second (``2025-01-31T12:00:00+00:00``)."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def utc_stamp() -> str:
    """The current time, UTC, as a folder name part (``20250131-120000Z``)."""
    return datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%SZ")


def package_versions(packages: Sequence[str] = RUN_PACKAGES) -> dict[str, str]:
    """Python's and each package's version ("not installed" when absent)."""
    versions = {"python": platform.python_version()}
    for package in packages:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def command_line(program: str, argv: Sequence[str] | None = None) -> str:
    """The shell command that reproduces this run: ``python -m program args``, or ``python program args`` for a
    script path (``*.py``); ``argv`` defaults to ``sys.argv[1:]``."""
    head = ["python", program] if program.endswith(".py") else ["python", "-m", program]
    return shlex.join([*head, *(sys.argv[1:] if argv is None else argv)])


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


def create_run_folder(
    tool: str,
    out: str | os.PathLike[str] | None = None,
    *,
    runs_dir: Path | None = None,
    stamp: str | None = None,
    reuse: bool = False,
) -> Path:
    """The run folder ``out``, or a new ``<runs root>/<tool>/<stamp>`` (by default the UTC time stamp; ``-2``,
    ``-3``, ... appended when a run of the same second has it), created with its parents.

    Args:
        tool: The tool's folder under the runs root.
        out: The folder the user chose (``--out``), or None.
        runs_dir: ``--runs-dir`` (:func:`runs_root`).
        stamp: Folder name instead of the UTC time stamp.
        reuse: Write into ``out`` even if it exists and holds files: ``--force``, or a tool that resumes there.

    Raises:
        UsageError: if ``out`` exists and is not an empty folder (unless ``reuse``), or the folder cannot be created.
    """
    if out is not None:
        folder = Path(out)
        if folder.exists() and not folder.is_dir():
            raise UsageError(f"--out {folder}: a file, not a folder; choose a folder")
        if not reuse and folder.is_dir() and any(folder.iterdir()):
            raise UsageError(
                f"--out {folder}: the folder exists and is not empty; choose a new folder, or pass --force to "
                "write into it (files of the same names are replaced)"
            )
        _make_folder(folder, "--out")
        return folder
    base = runs_root(runs_dir) / tool / (stamp if stamp is not None else utc_stamp())
    _make_folder(base.parent, f"the runs root {runs_root(runs_dir)} (--runs-dir or ${RUNS_DIR_VARIABLE})")
    folder, attempt = base, 1
    while True:
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            attempt += 1
            folder = base.with_name(f"{base.name}-{attempt}")


def _make_folder(folder: Path, option: str) -> None:
    """Create ``folder`` and its parents; a :class:`UsageError` naming ``option`` if the system refuses."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UsageError(
            f"{option}: cannot create the folder {folder} ({error.strerror or error}); choose a writable place"
        ) from None


def add_force_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--force`` (write into an existing, non-empty ``--out``: :func:`create_run_folder`) to ``parser``."""
    parser.add_argument(
        "--force",
        action="store_true",
        help="write into --out even if it exists and holds files (those of the same names are replaced)",
    )


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


def configuration_record(config: Any) -> dict[str, Any]:
    """A command line's resolved configuration (a dataclass) as its manifest records it: every field as it is, a
    scenario by its name (its file is beside, :func:`run_folder`), scenarios by their names, another dataclass (a
    settings record) as its table."""

    def recorded(value: Any) -> Any:
        if isinstance(value, Scenario):
            return value.name
        if isinstance(value, tuple) and value and all(isinstance(item, Scenario) for item in value):
            return [item.name for item in value]
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return dataclasses.asdict(value)
        return value

    return {field.name: recorded(getattr(config, field.name)) for field in dataclasses.fields(config)}


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


class Run:
    """An open run folder and its manifest (:func:`run_folder`)."""

    def __init__(self, folder: Path, manifest: dict[str, Any]) -> None:
        self.folder = folder
        self.manifest = manifest

    def record(self, **entries: Any) -> None:
        """Add or replace top-level entries of the manifest (``config`` once resolved, results) and write it."""
        self.manifest.update(entries)
        self.write()

    def write(self) -> Path:
        """Write the manifest, whole or not at all (a new file renamed over the old one)."""
        path = self.folder / MANIFEST
        partial = path.with_name(f".{MANIFEST}.partial")
        write_json(partial, self.manifest)
        partial.replace(path)
        return path

    def end(self, status: str, error: str | None = None) -> None:
        """Record the outcome (one of :data:`STATUSES` but ``running``) and the end time."""
        self.record(status=status, error=error, ended=utc_now())


@contextlib.contextmanager
def run_folder(
    tool: str,
    command: str,
    config: Mapping[str, Any],
    *,
    out: str | os.PathLike[str] | None = None,
    runs_dir: Path | None = None,
    scenarios: Sequence[Scenario] = (),
    stamp: str | None = None,
    reuse: bool = False,
) -> Iterator[Run]:
    """Run a command line inside its run folder (:func:`create_run_folder`), its manifest written as it starts and
    as it ends.

    The manifest, ``config.json``: ``tool``, ``command`` (the command line that reproduces the run,
    :func:`command_line`), ``config`` (the resolved configuration; a tool may record a fuller one once known),
    ``scenarios`` (name, file, content hash and robot identity of each; their TOML files are written beside:
    ``scenario.toml`` for one, ``scenarios/<name>.toml`` for several), ``runs_root``, ``versions``
    (:func:`package_versions`), ``git_commit``, ``started`` and ``ended`` (UTC, ISO 8601; ``ended`` is null while
    the run is under way), ``status`` (:data:`STATUSES`) and ``error`` (the exception of a failed run); then the
    entries the tool records (:meth:`Run.record`: results, timings).

    Args:
        tool: The tool's name: the folder is ``<runs root>/<tool>/<stamp>`` unless ``out`` is given.
        command: :func:`command_line`.
        config: The resolved configuration known at the start.
        out: The run folder (``--out``), or None.
        runs_dir: ``--runs-dir`` (:func:`runs_root`).
        scenarios: The scenarios the run works on.
        stamp: Folder name instead of the UTC time stamp.
        reuse: Write into an existing, non-empty ``out`` (``--force``, or a tool that resumes there); else that is
            a :class:`~eval.console.UsageError`.

    Yields:
        The open run: its ``folder``, and :meth:`Run.record` to add to the manifest. On leaving, ``status``
        becomes ``finished``, ``failed`` (any exception, or a non-zero ``SystemExit``) or ``interrupted``
        (``KeyboardInterrupt``, or SIGTERM, which raises :class:`Terminated` inside the run while it is under way);
        ``ended`` is stamped and the exception goes on, with a note naming the folder and the outcome
        (:func:`eval.console.command_main` prints it). What the run wrote before stays (tables appended as they
        grow, :func:`append_csv_rows`, are whole up to the last row). The SIGTERM handler in place before is put back
        on leaving.
    """
    folder = create_run_folder(tool, out, runs_dir=runs_dir, stamp=stamp, reuse=reuse)
    single = len(scenarios) == 1
    files = {s.name: "scenario.toml" if single else f"scenarios/{s.name}.toml" for s in scenarios}
    for scenario in scenarios:
        scenario.save(folder / files[scenario.name])
    run = Run(
        folder,
        {
            "tool": tool,
            "command": command,
            "status": "running",
            "error": None,
            "started": utc_now(),
            "ended": None,
            "config": dict(config),
            "scenarios": [
                {
                    "name": s.name,
                    "file": files[s.name],
                    "content_hash": s.content_hash,
                    "robot_identity": s.robot_identity,
                }
                for s in scenarios
            ],
            "runs_root": runs_root(runs_dir).resolve(),
            "versions": package_versions(),
            "git_commit": git_commit(),
        },
    )
    termination = _TerminationHandler()
    try:
        run.write()
        yield run
    except BaseException as error:
        termination.hold()
        status, message = _outcome(error)
        try:
            run.end(status, message)
        finally:
            termination.restore()
        if status != "finished":
            error.add_note(f"run folder {folder}, marked {status}")
        raise
    termination.hold()
    try:
        run.end("finished")
    finally:
        termination.restore(deliver=True)


class RunOptions(Protocol):
    """The run-folder options of a command line (``--out``, ``--runs-dir``, ``--force``): its parsed arguments or
    its resolved configuration."""

    @property
    def out(self) -> Path | None: ...

    @property
    def runs_dir(self) -> Path | None: ...

    @property
    def force(self) -> bool: ...


def command_run_folder(
    tool: str,
    program: str,
    argv: Sequence[str] | None,
    options: RunOptions,
    config: Mapping[str, Any],
    *,
    scenarios: Sequence[Scenario] = (),
    stamp: str | None = None,
    reuse: bool = False,
) -> contextlib.AbstractContextManager[Run]:
    """The :func:`run_folder` of the command line ``python -m program argv`` (:func:`command_line`), placed by its
    ``options``: ``--out``, ``--runs-dir``, and ``--force`` (or ``reuse``, a tool that resumes in its folder) to
    write into a non-empty one.

    Args:
        tool: The tool's folder under the runs root.
        program: The module run (``eval.rate.__main__``).
        argv: The command line's arguments (None: ``sys.argv[1:]``).
        options: Its parsed arguments or resolved configuration.
        config: The resolved configuration known at the start, as the manifest records it.
        scenarios: The scenarios the run works on.
        stamp: Folder name instead of the UTC time stamp.
        reuse: Write into an existing, non-empty ``--out`` even without ``--force``.
    """
    return run_folder(
        tool,
        command_line(program, argv),
        config,
        out=options.out,
        runs_dir=options.runs_dir,
        scenarios=scenarios,
        stamp=stamp,
        reuse=reuse or options.force,
    )
