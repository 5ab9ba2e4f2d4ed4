"""Experiments on the Delta robot and their command lines (docs/design.md section 8).

- ``python -m eval``: the controller comparison (:mod:`eval.comparison`, tables in :mod:`eval.tables`);
- ``python -m eval.identify``: the identification experiment and its report (:mod:`eval.identification`), on the
  simulated plant or on a real robot's drive logs;
- ``python -m eval.train_residual``: training the residual policy (stable-baselines3).

Every experiment runs its episodes with :func:`eval.episodes.run_episode` and writes its run folder with
:mod:`eval.run_folder`. This package imports neither matplotlib nor torch; the modules that need them do.
"""

from eval.calibration import calibrate_tares
from eval.episodes import EpisodeRecord, run_episode
from eval.identification import identify_logs, run_identification
from eval.parameter_files import identification_root, load_or_identify
from eval.run_folder import create_run_folder, run_folder, runs_root

__all__ = [
    "EpisodeRecord",
    "calibrate_tares",
    "create_run_folder",
    "identification_root",
    "identify_logs",
    "load_or_identify",
    "run_episode",
    "run_folder",
    "run_identification",
    "runs_root",
]
