"""Experiments on the Delta robot and their command lines (docs/design.md section 8): one folder per experiment.

- :mod:`eval.comparison`, ``python -m eval``: every controller on the same seeded episodes (``--video`` films them);
- :mod:`eval.identification`, ``python -m eval.identification``: the robot's identification, on the simulated plant
  or on a real robot's drive logs, its report and the parameter files kept per robot;
- :mod:`eval.rate`, ``python -m eval.rate``: the pick-rate data sheet beside a published industrial robot's;
- :mod:`eval.faults`, ``python -m eval.faults`` and ``python -m eval.faults.soak``: the fault campaign and the
  false-alarm soak;
- :mod:`eval.residual`, ``python -m eval.residual``: training and scoring the residual policy (stable-baselines3);
- :mod:`eval.design`, ``python -m eval.design``: the design study;
- :mod:`eval.sweep`, ``python -m eval.sweep``: scenarios x controllers x seeds, locally or on Ray.

Beside them, the engine and the shared pieces: :mod:`eval.engine` prepares what the controllers know, every
experiment runs its episodes with :func:`eval.episodes.run_episode` on the one executor
(:func:`eval.processes.run_jobs`: a local process pool or Ray; the controllers' episodes as work units,
:mod:`eval.work`), scores them with :mod:`eval.metrics` (the faults against what was injected with
:mod:`eval.fault_scores`) and writes its run folder with :mod:`eval.run_folder`;
:mod:`eval.compare` sets run folders side by side; every command line reports a usage error or an interruption in
one line and shows its progress with :mod:`eval.console`. Importing the package imports none of its modules: the
names below load on first use.
"""

import importlib
import os
import signal
import sys
from types import FrameType
from typing import Any


def _interrupted_while_starting(signum: int, frame: FrameType | None) -> None:
    """Ctrl-C while ``python -m eval...`` imports its command: one line and exit code 130, not an import's traceback.
    Nothing has run yet to clean up, and an exception raised inside a compiled module's import would become its
    ImportError, so the process ends at once."""
    argv = getattr(sys, "orig_argv", [])
    module = argv[argv.index("-m") + 1] if "-m" in argv[:-1] else "eval"
    print(f"python -m {module}: interrupted while starting", file=sys.stderr, flush=True)
    os._exit(128 + signum)


if sys.argv[:1] == ["-m"] and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    # Python is locating a ``python -m eval...`` module: until its main runs (eval.console.command_main, which hands
    # Ctrl-C back to Python's handler), an interruption ends the command in one line.
    signal.signal(signal.SIGINT, _interrupted_while_starting)

_HOMES = {
    "EpisodeRecord": "eval.episodes",
    "UsageError": "eval.console",
    "calibrate_tares": "eval.calibration",
    "command_main": "eval.console",
    "create_run_folder": "eval.run_folder",
    "identification_root": "eval.identification.parameter_files",
    "identify_logs": "eval.identification.run",
    "load_or_identify": "eval.identification.parameter_files",
    "progress_bar": "eval.console",
    "record_episode": "eval.comparison.video",
    "run_episode": "eval.episodes",
    "run_identification": "eval.identification.run",
    "runs_root": "eval.run_folder",
}
"""The module of each name this package exports (none named as a module of the package: importing a submodule
binds its name on the package)."""

__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    """The exported names, imported on first use: ``python -m eval`` starts its worker server
    (:func:`eval.processes.start_worker_server`) before it imports the experiments."""
    if name not in _HOMES:
        raise AttributeError(f"module 'eval' has no attribute {name!r}")
    value = globals()[name] = getattr(importlib.import_module(_HOMES[name]), name)
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
