"""Experiments on the Delta robot and their command lines (docs/design.md section 8).

- ``python -m eval``: the controller comparison (:mod:`eval.comparison`, tables in :mod:`eval.tables`);
- ``python -m eval.identify``: the identification experiment and its report (:mod:`eval.identification`), on the
  simulated plant or on a real robot's drive logs;
- ``python -m eval.train_residual``: training the residual policy (stable-baselines3);
- :func:`record_episode` (:mod:`eval.video`): one episode filmed to MP4 (``python -m eval --video``).

Every experiment runs its episodes with :func:`eval.episodes.run_episode` and writes its run folder with
:mod:`eval.run_folder`; every command line reports a usage error or an interruption in one line and shows its progress
with :mod:`eval.console`. Importing the package imports none of its modules: the names below load on first use.
"""

import importlib
from typing import Any

_HOMES = {
    "EpisodeRecord": "eval.episodes",
    "UsageError": "eval.console",
    "calibrate_tares": "eval.calibration",
    "command_main": "eval.console",
    "create_run_folder": "eval.run_folder",
    "identification_root": "eval.parameter_files",
    "identify_logs": "eval.identification",
    "load_or_identify": "eval.parameter_files",
    "progress_bar": "eval.console",
    "record_episode": "eval.video",
    "run_episode": "eval.episodes",
    "run_identification": "eval.identification",
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
