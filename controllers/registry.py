"""The controllers of the experiments, by key: an open registry of entries (docs/design.md section 6).

An entry (:class:`ControllerEntry`) is a key, a label, a factory that receives what the controller may know
(:class:`~controllers.setup.ControllerSetup`; a privileged row also the plant) and its declared capabilities. The
built-in rows are entries like any other; a user's controller joins by import path (``my_module:MyController``) or
through the entry-point group :data:`ENTRY_POINT_GROUP`, and gets what a built-in gets (:func:`controller_entry`).

Every built-in controller is built from the datasheet geometry and masses of the robot it was identified on
(``ControllerSetup.geometry``, ``ControllerSetup.masses``) and the identified parameters only; the
oracle row is the labelled exception that knows the plant (and, from the evaluation, the payloads).
:func:`controllers.setup.model_row` is the one builder of a model row: :func:`build_controller` uses it for every
model row, and the residual policy file rebuilds its base with it.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from types import ModuleType

from controllers.base import Controller, EstimatesPayload, PDController, Privileged, payload_estimator_of
from controllers.dynamics import DeltaDynamics
from controllers.feedforward import OracleController
from controllers.monitor import FaultMonitor, MonitoredController
from controllers.payload import PayloadEstimator
from controllers.payload_timing import EstimatingController
from controllers.residual import DEFAULT_POLICY_PATH, ResidualPolicy, residual_controller
from controllers.setup import ESTIMATOR_REGRESSORS, MODEL_ROWS, ControllerSetup, ModelRow, model_row
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.sensors import encoder_resolution


def residual_policy_path(setup: ControllerSetup) -> Path:
    """The policy file of the ``residual`` row: ``setup.residual_policy``, or the shipped policy when None."""
    return DEFAULT_POLICY_PATH if setup.residual_policy is None else setup.residual_policy


ControllerFactory = Callable[..., Controller]
"""Builds a controller from what it may know: ``factory(setup)``, or ``factory(setup, plant)`` for a privileged
entry (``plant``: the env's :class:`~delta_env.plant.PlantConfig`)."""


@dataclass(frozen=True)
class ControllerEntry:
    """A row of the experiments: a key, a label, a factory and the capabilities the experiments rely on.

    The experiments read what a controller offers from these declarations, never from its type or its key;
    :meth:`build` checks each declaration against the controller the factory returns.

    Attributes:
        key: What command lines and tasks name it by: a built-in key, an entry point's name, or ``module:attr``.
        label: Its name in tables and plots.
        factory: :data:`ControllerFactory`.
        estimates_payload: Its controller reports ``payload_estimate`` (kg) every step
            (:class:`~controllers.base.EstimatesPayload`): the experiments score its carries and plot its estimate.
        has_estimator: Its controller runs a :class:`~controllers.payload.PayloadEstimator`, its ``estimator``
            (:class:`~controllers.base.PayloadEstimating`): the fault monitor keeps faulty samples out of it and an
            online timing reads it (a row without one gets the cell's, :func:`cell_estimator`, beside it). Implies
            ``estimates_payload``.
        tared: Its estimator reads ``setup.tares[key]`` and ``setup.empty_moves[key]``: the experiments measure both
            on payload-free episodes before they run it (implies ``has_estimator``).
        tares_as: The key of a tared row whose tare and empty moves its estimator reads instead (its base's, for a
            row that wraps another), which the experiments then tare even where that row does not run; None: none
            (implies ``has_estimator``, excludes ``tared``).
        needs_drive_lag: Its factory needs the identified drive lag (``setup.drive_lag``): a setup without one is
            refused before the factory runs.
        reads_policy_file: Its factory reads the residual policy file of the setup (:func:`residual_policy_path`):
            the command lines check the file before any episode runs, and its bytes enter the row's result keys.
        privileged: The factory receives the plant, and the episode runner gives the controller the plant's true
            parameters and payloads (:class:`~controllers.base.Privileged`): a bound, not a controller.
        monitored: The registry puts the controller behind the robot's fault monitor
            (:class:`~controllers.monitor.MonitoredController`), which reports the faults it detects
            (:class:`~controllers.monitor.ReportsFaults`); False for a controller that handles its own readings.
    """

    key: str
    label: str
    factory: ControllerFactory
    estimates_payload: bool = False
    has_estimator: bool = False
    tared: bool = False
    tares_as: str | None = None
    needs_drive_lag: bool = False
    reads_policy_file: bool = False
    privileged: bool = False
    monitored: bool = True

    def __post_init__(self) -> None:
        if not self.key or "," in self.key:
            raise ValueError(f"a controller key must be non-empty and without commas, got {self.key!r}")
        if (self.tared or self.tares_as is not None) and not self.has_estimator:
            raise ValueError(f"controller {self.key!r}: a tared controller has a payload estimator (has_estimator)")
        if self.tared and self.tares_as is not None:
            raise ValueError(
                f"controller {self.key!r}: tared on its own key or as {self.tares_as!r} (tares_as), not both"
            )
        if self.has_estimator and not self.estimates_payload:
            raise ValueError(
                f"controller {self.key!r}: a controller with a payload estimator reports its estimate "
                "(estimates_payload)"
            )

    @property
    def tare_key(self) -> str | None:
        """The key its estimator's tare is measured and kept under (``setup.tares``): its own if ``tared``, else
        ``tares_as`` (None: an untared row)."""
        return self.key if self.tared else self.tares_as

    def build(
        self,
        setup: ControllerSetup,
        plant: PlantConfig | None = None,
        *,
        cell_estimator: PayloadEstimator | None = None,
    ) -> Controller:
        """The controller of this entry for the robot of ``setup``, behind its fault monitor if it is ``monitored``.

        Args:
            setup: What the controller may know.
            plant: For a privileged entry only.
            cell_estimator: The cell's payload estimator (:func:`cell_estimator`), run beside a controller without
                an estimator of its own (:class:`~controllers.payload_timing.EstimatingController`), behind the same
                fault monitor: what an online timing reads.

        Raises:
            ValueError: for a setup or plant the declarations refuse.
            TypeError: when the controller is not what its entry declares.
        """
        if self.needs_drive_lag and setup.drive_lag is None:
            raise ValueError(
                f"controller {self.key!r} needs the identified drive lag; ControllerSetup.drive_lag is None"
            )
        if self.reads_policy_file and not residual_policy_path(setup).is_file():
            raise ValueError(
                f"controller {self.key!r} reads the residual policy file {residual_policy_path(setup)}, which does "
                "not exist"
            )
        if self.privileged:
            if plant is None:
                raise ValueError(f"controller {self.key!r} is privileged: it needs the plant it inverts")
            controller = self.factory(setup, plant)
        else:
            controller = self.factory(setup)
        self._check(controller)
        if cell_estimator is not None:
            if self.has_estimator:
                raise ValueError(f"controller {self.key!r} runs its own payload estimator: the cell's goes beside none")
            controller = EstimatingController(controller, cell_estimator)
        return monitored(controller, setup) if self.monitored else controller

    def _check(self, controller: object) -> None:
        """TypeError naming the declaration ``controller`` (the factory's) does not match."""
        if not isinstance(controller, Controller):
            raise TypeError(
                f"controller {self.key!r}: its factory returned {type(controller).__name__}, not a Controller "
                "(a name and reset() and __call__(observation) -> torques)"
            )
        if self.privileged != isinstance(controller, Privileged):
            raise TypeError(
                f"controller {self.key!r}: declared privileged={self.privileged}, but its controller "
                + ("does not take" if self.privileged else "takes")
                + " the plant's truth (set_payload_masses, set_physical_parameters): declare what it is on its "
                "ControllerEntry"
            )
        if self.estimates_payload and not isinstance(controller, EstimatesPayload):
            raise TypeError(
                f"controller {self.key!r}: declared estimates_payload, but its controller has no payload_estimate "
                "(kg) property (controllers.base.EstimatesPayload)"
            )
        runs_estimator = isinstance(payload_estimator_of(controller), PayloadEstimator)
        if self.has_estimator != runs_estimator:
            raise TypeError(
                f"controller {self.key!r}: declared has_estimator={self.has_estimator}, but its controller "
                + ("has no" if self.has_estimator else "runs a")
                + " PayloadEstimator as its 'estimator' (controllers.base.PayloadEstimating): declare what it is on "
                "its ControllerEntry"
            )


ENTRY_POINT_GROUP = "delta_pick_place.controllers"
"""Installed packages register controllers under this entry-point group: name = key, value = ``module:attr``."""


@functools.cache
def _loaded_policy(path: Path, modified_ns: int, size: int) -> ResidualPolicy:
    """The residual policy file at ``path``, loaded once per process and version of the file (its modification time
    and size), for deployment (its actor without torch when it can): a policy holds no episode state."""
    from controllers.residual import load_residual_policy

    return load_residual_policy(path, deploy=True)


def loaded_policy(setup: ControllerSetup) -> ResidualPolicy:
    """The residual policy of ``setup`` (:func:`residual_policy_path`), loaded once per process and file version."""
    path = residual_policy_path(setup).resolve()
    status = path.stat()
    return _loaded_policy(path, status.st_mtime_ns, status.st_size)


def _residual(setup: ControllerSetup) -> Controller:
    return residual_controller(loaded_policy(setup), name=CONTROLLER_LABELS["residual"])


def _oracle(setup: ControllerSetup, plant: PlantConfig) -> Controller:
    return OracleController(plant, servo=setup.servo)  # its feedback on the plant's truth (see OracleController)


def _model_entry(key: str, row: ModelRow) -> ControllerEntry:
    """The entry of the built-in model row ``key``, its capabilities those of ``row``: an RLS row estimates the
    payload with a tared estimator; the lag row needs the drive lag."""
    label = CONTROLLER_LABELS[key]
    estimates = row.regressor is not None
    return ControllerEntry(
        key,
        label,
        lambda setup: model_row(key, setup, label),
        estimates_payload=estimates,
        has_estimator=estimates,
        tared=estimates,
        needs_drive_lag=row.leads_lag,
    )


CONTROLLER_LABELS = {
    "pd": "PD",
    "mkh": "MKH+PD",
    "mid": "MId+PD",
    "mid_f": "MId+F+PD",
    "mid_f_r": "MId+F+R+PD",
    "mid_f_rls": "MId+F+R+RLS+PD",
    "mid_f_rls_ref": "MId+F+R+RLS(ref)+PD",
    "mid_f_rls_lag": "MId+F+R+RLS+lag+PD",
    "oracle": "Oracle+PD (bound)",
    "residual": "Residual + its base",
}
"""The built-in controllers' keys and labels, in the comparison's order. ``+R``: the identified model with rod forearms
(``DeltaDynamics(forearm_rods=True)``, beyond the paper), which the payload estimators use. ``mid_f_rls``
estimates the payload on the Kalman-smoothed joint states (the default estimator); ``mid_f_rls_ref`` on the
reference, for comparison. ``mid_f_rls_lag`` is ``mid_f_rls`` with its feedforward led through the
inverse of the identified drive lag (:class:`~controllers.feedforward.LagCompensatedController`). The oracle
knows the plant and the true payloads: an upper bound, not a controller. ``residual`` is the learned
residual policy (:mod:`controllers.residual`) on the base it was trained on, rebuilt from the policy file (the
policy file records its base's key and setup: :class:`~controllers.residual.PolicyBase`)."""

BUILTIN_CONTROLLERS: dict[str, ControllerEntry] = {
    "pd": ControllerEntry("pd", CONTROLLER_LABELS["pd"], lambda setup: PDController(*setup.pd_gains)),
    **{key: _model_entry(key, row) for key, row in MODEL_ROWS.items()},
    # the oracle is told the true payloads: nothing of it to score as an estimate
    "oracle": ControllerEntry("oracle", CONTROLLER_LABELS["oracle"], _oracle, privileged=True),
    # the residual runs its base's estimator, tared with the tare its policy file carries
    "residual": ControllerEntry(
        "residual",
        CONTROLLER_LABELS["residual"],
        _residual,
        estimates_payload=True,
        has_estimator=True,
        reads_policy_file=True,
    ),
}
"""Every built-in row, registered as a user's controller is (:func:`controller_entry`)."""

CELL_ESTIMATOR_KEY = "mid_f_rls"
"""The row whose payload estimator the cell runs beside a controller without one when it needs an estimate (an
online timing): :func:`cell_estimator`."""


def controller_entry(key: str) -> ControllerEntry:
    """The entry of ``key``: a built-in key (:data:`BUILTIN_CONTROLLERS`), the name of an installed entry point of
    :data:`ENTRY_POINT_GROUP`, or ``module:attr`` (the module importable in this process and in the workers, e.g.
    on ``PYTHONPATH`` or in the current directory).

    ``attr`` names a :class:`ControllerEntry` (its key becomes ``key``), a controller class constructible with no
    arguments (label: its ``name``), or a factory ``factory(setup) -> Controller`` (label: its ``label`` attribute,
    else its name). Raises ValueError naming the key and the built-in keys.
    """
    if key in BUILTIN_CONTROLLERS:
        return BUILTIN_CONTROLLERS[key]
    return _imported_entry(key)


def _import_path(key: str) -> str:
    """``module:attr`` of a key that is not built in: the key itself, or the value of its installed entry point."""
    if ":" in key:
        return key
    installed = {point.name: point.value for point in metadata.entry_points(group=ENTRY_POINT_GROUP)}
    if key not in installed:
        raise ValueError(
            f"unknown controller {key!r}: choose from {', '.join(BUILTIN_CONTROLLERS)}"
            + (f", the installed {', '.join(installed)}" if installed else "")
            + ", or name your own as module:attr (e.g. my_package.my_module:MyController)"
        )
    return installed[key]


@functools.cache
def _imported_entry(key: str) -> ControllerEntry:
    spec = _import_path(key)
    module_name, _, attr = spec.partition(":")
    try:
        target = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"controller {key!r}: cannot import {attr!r} from {module_name!r} ({error})") from error
    if isinstance(target, ControllerEntry):
        return dataclasses.replace(target, key=key)
    if isinstance(target, type):
        label = getattr(target, "name", attr)
        return ControllerEntry(key, label if isinstance(label, str) else attr, lambda setup: target())
    if callable(target):
        return ControllerEntry(key, getattr(target, "label", attr), target)
    raise ValueError(f"controller {key!r}: {spec} is a {type(target).__name__}, not a controller class or factory")


def controller_label(key: str) -> str:
    """The label of the controller ``key`` in tables and plots."""
    return controller_entry(key).label


def build_controller(
    key: str,
    setup: ControllerSetup,
    env: DeltaPickPlaceEnv | None = None,
    *,
    cell_estimator: PayloadEstimator | None = None,
) -> Controller:
    """The controller of ``key`` (:func:`controller_entry`) for the robot of ``setup``, behind its fault monitor.

    Args:
        key: Controller key.
        setup: What the controller may know.
        env: For a privileged controller only (the oracle), which inverts the env's plant; never given to the others.
        cell_estimator: The cell's payload estimator to run beside a controller without one
            (:meth:`ControllerEntry.build`).
    """
    entry = controller_entry(key)
    plant = env.plant_config if entry.privileged and env is not None else None
    return entry.build(setup, plant, cell_estimator=cell_estimator)


def fault_monitor(setup: ControllerSetup) -> FaultMonitor:
    """A fault monitor on the identified model (MId+F+R) of the robot of ``setup``, with its drive, encoders and
    gearheads' backlash."""
    return FaultMonitor(
        estimation_model(setup),
        setup.drive.peak_torque,
        drive_lag=setup.drive_lag,
        encoder_step=None if setup.encoder_bits is None else encoder_resolution(setup.encoder_bits),
        torque_delay=setup.torque_delay,
        drive_backlash=setup.compliance is not None and any(setup.compliance.resolved_backlash > 0.0),
    )


def monitored(controller: Controller, setup: ControllerSetup) -> MonitoredController:
    """``controller`` behind the :func:`fault_monitor` of ``setup``, reacting as ``setup.fault_reaction`` says; the
    monitor takes the model's corrections to this robot from the controller's own payload estimator if it forms its
    equations at the measured state, else from the :func:`cell_estimator` run beside it (the corrections fitted on
    the reference absorb the robot's lag behind it, and without any the identified model is off on another robot)."""
    own = payload_estimator_of(controller)
    corrections_fit = None if isinstance(own, PayloadEstimator) and own.measures_state else cell_estimator(setup)
    return MonitoredController(controller, fault_monitor(setup), setup.fault_reaction, corrections_fit)


def payload_estimator(key: str, setup: ControllerSetup) -> PayloadEstimator:
    """A fresh, untared payload estimator of the tared controller ``key`` (the one its controller runs), without
    seeded empty moves."""
    if not controller_entry(key).tared:
        raise ValueError(f"{key!r} has no tared payload estimator; built-in ones: {', '.join(ESTIMATOR_REGRESSORS)}")
    return payload_estimator_of(build_controller(key, dataclasses.replace(setup, tares={}, empty_moves={})))


def cell_estimator(setup: ControllerSetup) -> PayloadEstimator:
    """The cell's payload estimator: that of the row :data:`CELL_ESTIMATOR_KEY`, tared and seeded from ``setup``, to
    run beside a controller without one (:meth:`ControllerEntry.build`'s ``cell_estimator``)."""
    return payload_estimator_of(build_controller(CELL_ESTIMATOR_KEY, setup))


def estimation_model(setup: ControllerSetup) -> DeltaDynamics:
    """MId+F+R: the identified model with rod forearms, of the payload estimators and their feedforward."""
    return DeltaDynamics.of_robot(setup.geometry, setup.masses, setup.mid_f_rods, forearm_rods=True)


def parse_controller_keys(text: str) -> list[str]:
    """The controller keys of a comma-separated list (``--controllers``), each resolved now (a user's module is
    imported here, so that a typo fails before any episode runs), without repeats, in order.

    Raises:
        ValueError: for an empty list or a key :func:`controller_entry` cannot resolve.
    """
    keys = list(dict.fromkeys(key.strip() for key in text.split(",") if key.strip()))
    if not keys:
        raise ValueError(f"no controllers in {text!r}; choose from {', '.join(BUILTIN_CONTROLLERS)} or module:attr")
    for key in keys:
        controller_entry(key)
    return keys


def controllers_help(default: str) -> str:
    """The help text of a ``--controllers`` option: the built-in keys beside their labels, and how to add one's own."""
    builtins = ", ".join(f"{key} = {label}" for key, label in CONTROLLER_LABELS.items())
    return (
        f"comma-separated controller keys (default {default}). Built-in: {builtins}. Your own: module:attr, a "
        "Controller class constructible without arguments, a factory(setup) or a ControllerEntry, importable from "
        "the current directory or PYTHONPATH; or an installed entry point of the group "
        f"{ENTRY_POINT_GROUP}"
    )


def _top_module(key: str) -> ModuleType:
    """The top-level module or package of the user's controller ``key``, imported (or an error naming the key)."""
    controller_entry(key)
    return importlib.import_module(_import_path(key).partition(":")[0].partition(".")[0])


def controller_source(key: str) -> bytes:
    """The source code of a user's controller ``key`` (its module's file, or every ``.py`` file of its top-level
    package), for content hashes of results; empty for a built-in, whose code is the project's."""
    if key in BUILTIN_CONTROLLERS:
        return b""
    top = _top_module(key)
    if getattr(top, "__path__", None):
        files = sorted(path for folder in top.__path__ for path in Path(folder).rglob("*.py"))
    else:
        files = [Path(top.__file__)] if getattr(top, "__file__", None) else []
    return b"".join(path.as_posix().encode() + path.read_bytes() for path in files)


def controller_packages(keys: Iterable[str]) -> list[str]:
    """The folders of the top-level packages of the user's controllers among ``keys``: what a remote worker must be
    sent to import them (built-in ones and installed entry points' packages excepted).

    Raises:
        ValueError: for a user controller in a single-file module, which a remote worker cannot be sent as a package.
    """
    folders = []
    for key in keys:
        if key in BUILTIN_CONTROLLERS or ":" not in key:  # an entry point's package is installed on the nodes
            continue
        top = _top_module(key)
        if not getattr(top, "__path__", None):
            raise ValueError(
                f"controller {key!r}: a remote Ray cluster imports user controllers from packages; move "
                f"{top.__name__}.py into a package (a folder with __init__.py) or install it on the cluster's nodes"
            )
        folders += [str(Path(folder)) for folder in top.__path__ if str(Path(folder)) not in folders]
    return folders
