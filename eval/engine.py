"""The experiment engine: what every experiment does before its episodes, once.

:func:`robot_knowledge` gives what every row knows of a scenario's robot: its identification (a given parameter
file, or the robot's own, identified once and cached per robot identity:
:func:`eval.identification.parameter_files.robot_identification`) and the :class:`~controllers.setup.ControllerSetup`
built from it with the scenario's fault reaction. :func:`prepare` adds the tares and empty-move sums of the tared
controllers, measured once on the scenario's payload-free episodes on the calibration seeds and kept beside the
identification (:func:`eval.calibration.tare_setup`, :func:`kept_tares`). :func:`grid` lays out the episodes, work units
(:class:`eval.work.WorkUnit`: a scenario, a controller, a seed), which :func:`eval.work.run_grid` runs on the one
executor (:func:`eval.processes.run_jobs`: a local process pool or Ray), returning each unit's record
(:func:`eval.work.unit_record`) or row (:func:`eval.sweep.work.run_unit`). The comparison (:mod:`eval.comparison.run`),
the sweep (:mod:`eval.sweep`, on top of it), the residual scores (:mod:`eval.residual.scoring`), the design verification
(:mod:`eval.design.verify`), the pick-rate study (:mod:`eval.rate.__main__`) and the fault campaign and soak
(``scripts/``) are its callers.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from controllers.identification import IdentificationResult
from controllers.registry import ControllerSetup
from delta_env.config import PlantConfig
from delta_env.scenario import Scenario
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, Calibration, tare_setup
from eval.console import UsageError
from eval.identification.parameter_files import identification_root, parameter_path, robot_identification, robot_setup
from eval.work import WorkUnit


class Prepared(NamedTuple):
    """What :func:`prepare` found.

    Attributes:
        setup: What the controllers know, tared on the scenario.
        parameter_file: The parameter file the identification came from.
        identification: The robot's identification.
        calibration: Tares (kg), their spreads (kg) and the empty moves' sums per tared controller.
    """

    setup: ControllerSetup
    parameter_file: Path
    identification: IdentificationResult
    calibration: Calibration


def robot_knowledge(
    scenario: Scenario, parameters: str | Path | None = None, runs_dir: str | Path | None = None, **setup_fields: Any
) -> tuple[Path, IdentificationResult, ControllerSetup]:
    """The parameter file, the identification and the untared setup of the scenario's robot, with the scenario's
    fault reaction (arguments as :func:`prepare`'s): what every row knows before the tare."""
    parameter_file, identification = robot_identification(scenario.plant, parameters, identification_root(runs_dir))
    fields = {"fault_reaction": scenario.task.fault_reaction, **setup_fields}
    setup = robot_setup(scenario.plant, identification, **fields)
    require_known_drives(scenario.plant, setup, identification)
    return parameter_file, identification, setup


def require_known_drives(plant: PlantConfig, setup: ControllerSetup, identification: IdentificationResult) -> None:
    """Refuse the servo layer (``setup.servo == "servo"``) on compliant drives it does not know: on a gearhead with
    backlash without a load-side encoder, whose band the motor side's identification does not see and whose crossing
    the servo handles on the measured twist only (docs/design.md section 6, "Backlash"); and without the drives'
    compliance (``setup.compliance`` None: a parameter file of rigid drives, or an identification that left the
    drives unidentified, its reason in ``identification``'s provenance, ``compliance.method``), where the model rows
    run the rigid servo, without notch, deflection or backlash band, which the compliant plant drives unstable.

    Raises:
        UsageError: naming the plant's ``load_encoder_bits`` and backlash, and why the drives are not known.
    """
    drives = plant.realism.compliance
    if drives is None or setup.servo != "servo":
        return
    if drives.load_encoder_bits is None and drives.backlash > 0.0:
        raise UsageError(
            f"compliant drives with backlash {drives.backlash:.4g} rad and load_encoder_bits = None: the motor side "
            "alone does not identify the backlash, and the servo crosses the band on the measured twist only; fit a "
            "load-side encoder (PlantRealism.compliance.load_encoder_bits, as the compliant preset does) or run "
            "with --servo pd"
        )
    if setup.compliance is None:
        reason = identification.provenance.get("compliance", {}).get("method")
        why = (
            "rigid drives: leave --parameters out for the robot's own identification"
            if reason is None
            else f"its identification: {reason}"
        )
        raise UsageError(
            f"compliant drives with backlash {drives.backlash:.4g} rad and load_encoder_bits = "
            f"{drives.load_encoder_bits}: the parameter file holds no drive compliance ({why}), and the model rows' "
            "servo, rigid without it, drives the gearheads unstable; give a parameter file with the drives' "
            "compliance or run with --servo pd"
        )


def kept_tares(scenario: Scenario, runs_dir: str | Path | None = None) -> Path:
    """Folder of the kept tares of ``scenario``'s robot (:func:`eval.calibration.tare_setup`): ``tares`` beside its
    identification under the runs root (:func:`eval.identification.parameter_files.parameter_path`)."""
    return parameter_path(scenario.plant, identification_root(runs_dir)).parent / "tares"


def prepare(
    scenario: Scenario,
    controllers: Iterable[str],
    *,
    parameters: str | Path | None = None,
    runs_dir: str | Path | None = None,
    calibration_episodes: int = DEFAULT_CALIBRATION_EPISODES,
    workers: int = 1,
    progress: Any = None,
    **setup_fields: Any,
) -> Prepared:
    """Identify (or load) the scenario's robot and tare ``controllers`` on the scenario.

    Args:
        scenario: The robot and the work; its faults are left out of the tare's episodes.
        controllers: Controller keys (:func:`controllers.registry.controller_entry`); the tared ones are tared.
        parameters: An existing parameter file of this robot; None: the robot's own (identified when missing), under
            the runs root (:func:`eval.identification.parameter_files.identification_root` of ``runs_dir``).
        runs_dir: The runs root (:func:`eval.run_folder.runs_root`).
        calibration_episodes: Payload-free episodes per tared controller.
        workers: Processes of the identification's and the calibration's episodes.
        progress: tqdm bar advanced once per calibration episode.
        **setup_fields: Other fields of :class:`~controllers.registry.ControllerSetup` (e.g. ``residual_policy``).

    Raises:
        UsageError: for the servo layer (``servo="servo"``, the default) on a parameter file without a drive lag.
    """
    parameter_file, identification, setup = robot_knowledge(scenario, parameters, runs_dir, **setup_fields)
    if setup.servo == "servo" and setup.drive_lag is None:
        raise UsageError(
            f"{parameter_file} has no drive lag (its logs had no commands), and the servo layer, the model rows' "
            "feedback, places its gains on it: identify the robot from logs with commands, or run with --servo pd"
        )
    setup, calibration = tare_setup(
        scenario,
        setup,
        controllers,
        episodes=calibration_episodes,
        workers=workers,
        progress=progress,
        kept=kept_tares(scenario, runs_dir),
    )
    return Prepared(setup, parameter_file, identification, calibration)


def grid(scenarios: Iterable[Scenario], controllers: Iterable[str], seeds: Iterable[int]) -> list[WorkUnit]:
    """The work units of scenarios x controllers x seeds, in that nesting order."""
    controllers, seeds = list(controllers), list(seeds)
    return [WorkUnit(scenario, key, seed) for scenario in scenarios for key in controllers for seed in seeds]
