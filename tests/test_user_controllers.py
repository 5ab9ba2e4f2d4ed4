"""The open controller registry: built-in rows and a user's controllers resolve, build and run the same way."""

import csv
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from controllers import registry
from controllers.base import Controller, EstimatesPayload, PDController, Privileged, payload_estimator_of
from controllers.feedforward import OracleController
from controllers.monitor import MonitoredController
from controllers.payload import PayloadEstimator
from controllers.payload_timing import EstimatingController
from controllers.registry import (
    BUILTIN_CONTROLLERS,
    ControllerEntry,
    ControllerSetup,
    build_controller,
    controller_entry,
    controller_packages,
    controller_source,
    parse_controller_keys,
)
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.faults import FaultSpec
from delta_env.scenario import PickPlaceTask, Scenario
from eval import metrics
from eval.comparison.__main__ import main as eval_main
from eval.episodes import run_episode
from eval.sweep.work import run_unit
from eval.work import WorkUnit, timed_controller
from tests.conftest import NOMINAL_SETUP

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

USER_MODULE = """
import numpy as np
from controllers.base import PDController
from controllers.feedforward import OracleController
from controllers.registry import ControllerEntry
from controllers.setup import model_row


class Soft(PDController):
    name = "Soft PD"

    def __init__(self):
        super().__init__(kp=1000.0, kd=20.0)


def zero(setup):
    class Zero:
        name = "Zero"

        def reset(self):
            pass

        def __call__(self, observation):
            return np.zeros(3)

    return Zero()


zero.label = "Zero torque"


def not_a_controller(setup):
    return 42


ENTRY = ControllerEntry("ignored", "Declared", lambda setup: Soft(), monitored=False)
NUMBER = 3


def estimating(setup):
    # a user's row that estimates the payload with the project's estimator (the RLS row's, tared as it is)
    return model_row("mid_f_rls", setup, "User RLS")


ESTIMATING = ControllerEntry("ignored", "User RLS", estimating, estimates_payload=True, has_estimator=True)
UNDECLARED = ControllerEntry("ignored", "Undeclared RLS", estimating, estimates_payload=True)


class Private:
    # the RLS row with its estimator out of sight: it reports an estimate and declares no estimator
    def __init__(self, inner):
        self.inner, self.name = inner, "Private RLS"

    @property
    def payload_estimate(self):
        return self.inner.payload_estimate

    def reset(self):
        self.inner.reset()

    def __call__(self, observation):
        return self.inner(observation)


PRIVATE = ControllerEntry("ignored", "Private RLS", lambda setup: Private(estimating(setup)), estimates_payload=True)
"""


@pytest.fixture
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """A user's module, importable as ``user_rows_<n>`` (fresh per test: entries are cached per key)."""
    name = f"user_rows_{abs(hash(tmp_path)) % 10**8}"
    (tmp_path / f"{name}.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def _built(entry: ControllerEntry, setup: ControllerSetup) -> Controller:
    """``entry``'s controller for ``setup`` (a privileged one on the default plant)."""
    return entry.build(setup, PlantConfig() if entry.privileged else None)


def test_builtin_rows_behave_as_they_declare(tmp_path: Path) -> None:
    # every capability checked against what the built controller does, not against the table of declarations
    tare = 0.125
    setup = dataclasses.replace(NOMINAL_SETUP, tares=dict.fromkeys(BUILTIN_CONTROLLERS, tare))
    for key, entry in BUILTIN_CONTROLLERS.items():
        controller = _built(entry, setup)
        inner = controller.controller if entry.monitored else controller
        estimator = payload_estimator_of(inner)
        assert isinstance(controller, MonitoredController) == entry.monitored, key
        assert isinstance(inner, Privileged) == entry.privileged, key
        assert isinstance(estimator, PayloadEstimator) == entry.has_estimator, key
        if entry.estimates_payload:
            assert isinstance(inner, EstimatesPayload), key
        if entry.has_estimator and entry.monitored:
            assert controller.estimator is estimator, key  # the fault monitor guards the row's estimator
        if entry.has_estimator:  # a tared row reads its tare from the setup; the residual's comes with its file
            assert (estimator.tare == tare) == entry.tared, key
    # the drive lag: the rows on the paper's PD that still need it
    no_lag = dataclasses.replace(NOMINAL_SETUP, drive_lag=None, servo="pd")
    needing = set()
    for key, entry in BUILTIN_CONTROLLERS.items():
        try:
            _built(entry, no_lag)
        except ValueError as error:
            assert "drive lag" in str(error), key
            needing.add(key)
    assert needing == {key for key, entry in BUILTIN_CONTROLLERS.items() if entry.needs_drive_lag} == {"mid_f_rls_lag"}
    # the policy file: the rows whose factories read it fail on a file that is not a policy, and only those
    not_a_policy = tmp_path / "not_a_policy.zip"
    not_a_policy.write_bytes(b"not a zip file")
    reading = set()
    for key, entry in BUILTIN_CONTROLLERS.items():
        try:
            _built(entry, dataclasses.replace(NOMINAL_SETUP, residual_policy=not_a_policy))
        except ValueError as error:
            assert "not_a_policy.zip" in str(error), key
            reading.add(key)
    assert reading == {key for key, entry in BUILTIN_CONTROLLERS.items() if entry.reads_policy_file} == {"residual"}


def test_a_user_row_with_an_estimator_is_scored_and_guarded_like_the_builtin_one(user_module: str) -> None:
    # a 2 kg carry hit by a 400 N, 30 ms collision: the monitor undoes and skips its samples in a declared estimator
    collision = FaultSpec(
        "collision", carry_fraction=(0.5, 0.5), size=(400.0, 400.0), duration=(0.03, 0.03), target="platform"
    )
    scenario = Scenario(task=PickPlaceTask(n_cycles=1, faults=(collision,)))
    setup = dataclasses.replace(NOMINAL_SETUP, tares={"mid_f_rls": 0.05})
    scores = {}
    for key in ("mid_f_rls", f"{user_module}:ESTIMATING", f"{user_module}:PRIVATE"):
        row = run_unit(WorkUnit(scenario, key, 3, (2.0,)), setup)
        assert row["status"] == "ok" and row["faults_detected"] == 1, (key, row["error"])
        scores[key] = [row[name] for name in metrics.PAYLOAD_SCORES]
    # the same controller behind the same monitor: its carry scored (within 5 %: -2.9 %), to the same numbers
    assert abs(scores["mid_f_rls"][0]) < 5.0
    np.testing.assert_array_equal(scores[f"{user_module}:ESTIMATING"], scores["mid_f_rls"])
    # an estimator the entry does not declare is scored but not guarded: the collision's samples stay in (+69 %)
    assert scores[f"{user_module}:PRIVATE"][0] > 20.0
    # an online timing reads the user's estimator, behind its monitor, and runs no cell estimator beside it
    env = DeltaPickPlaceEnv(scenario=Scenario(task=PickPlaceTask(timing="online", n_cycles=1)))
    controller = timed_controller(env, f"{user_module}:ESTIMATING", setup)
    assert isinstance(controller, MonitoredController) and not isinstance(controller.controller, EstimatingController)
    assert env.timing.estimator is controller.estimator is payload_estimator_of(controller.controller)
    # a row that runs an estimator must say so (else the monitor and the timing would not know it)
    with pytest.raises(TypeError, match="declared has_estimator=False, but its controller runs a PayloadEstimator"):
        build_controller(f"{user_module}:UNDECLARED", setup)


def test_a_class_a_factory_and_an_entry_resolve_by_import_path(user_module: str) -> None:
    soft = controller_entry(f"{user_module}:Soft")
    assert (soft.label, soft.estimates_payload, soft.has_estimator, soft.tared, soft.privileged) == (
        "Soft PD",
        False,
        False,
        False,
        False,
    )
    built = soft.build(NOMINAL_SETUP)
    assert isinstance(built, MonitoredController) and isinstance(built.controller, PDController)
    assert built.controller.kp == 1000.0

    zero = controller_entry(f"{user_module}:zero")
    assert zero.label == "Zero torque"
    observation, _ = DeltaPickPlaceEnv(n_cycles=1).reset(seed=0)
    np.testing.assert_array_equal(build_controller(f"{user_module}:zero", NOMINAL_SETUP)(observation), np.zeros(3))

    declared = controller_entry(f"{user_module}:ENTRY")
    assert (declared.key, declared.label) == (f"{user_module}:ENTRY", "Declared")
    assert isinstance(declared.build(NOMINAL_SETUP), PDController)  # monitored=False: no monitor around it


def test_an_installed_entry_point_names_a_controller(user_module: str, monkeypatch: pytest.MonkeyPatch) -> None:
    class Point:
        name, value = "soft_pd", f"{user_module}:Soft"

    def entry_points(group: str) -> list:
        return [Point()] if group == registry.ENTRY_POINT_GROUP else []

    monkeypatch.setattr(registry.metadata, "entry_points", entry_points)
    registry._imported_entry.cache_clear()
    try:
        assert controller_entry("soft_pd").label == "Soft PD"
        with pytest.raises(ValueError, match="the installed soft_pd"):
            controller_entry("soft")
    finally:
        registry._imported_entry.cache_clear()


def test_bad_controllers_are_clear_errors(user_module: str) -> None:
    with pytest.raises(ValueError, match=r"unknown controller 'pid': choose from pd, mkh, .* module:attr"):
        controller_entry("pid")
    with pytest.raises(ValueError, match="cannot import 'Nope' from"):
        controller_entry(f"{user_module}:Nope")
    with pytest.raises(ValueError, match="cannot import 'X' from 'no_such_module_anywhere'"):
        controller_entry("no_such_module_anywhere:X")
    with pytest.raises(ValueError, match="is a int, not a controller class or factory"):
        controller_entry(f"{user_module}:NUMBER")
    with pytest.raises(TypeError, match="returned int, not a Controller"):
        build_controller(f"{user_module}:not_a_controller", NOMINAL_SETUP)
    # declarations inconsistent with each other, or with the controller
    with pytest.raises(ValueError, match="a tared controller has a payload estimator"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), estimates_payload=True, tared=True)
    with pytest.raises(ValueError, match="a controller with a payload estimator reports its estimate"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), has_estimator=True)

    class Guessing(PDController):  # reports an estimate, runs no estimator
        payload_estimate = 1.0

    with pytest.raises(TypeError, match="declared has_estimator=True, but its controller has no PayloadEstimator"):
        ControllerEntry("mine", "Mine", lambda setup: Guessing(), estimates_payload=True, has_estimator=True).build(
            NOMINAL_SETUP
        )
    with pytest.raises(TypeError, match="declared estimates_payload, but its controller has no payload_estimate"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), estimates_payload=True).build(NOMINAL_SETUP)
    with pytest.raises(ValueError, match="'mine' needs the identified drive lag"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), needs_drive_lag=True).build(
            dataclasses.replace(NOMINAL_SETUP, drive_lag=None)
        )
    missing = Path("no_such_policy.zip")
    with pytest.raises(ValueError, match=r"reads the residual policy file no_such_policy\.zip, which does not exist"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), reads_policy_file=True).build(
            dataclasses.replace(NOMINAL_SETUP, residual_policy=missing)
        )
    with pytest.raises(ValueError, match="runs its own payload estimator: the cell's goes beside none"):
        build_controller("mid_f_rls", NOMINAL_SETUP, cell_estimator=registry.cell_estimator(NOMINAL_SETUP))
    with pytest.raises(ValueError, match="needs the plant"):
        controller_entry("oracle").build(NOMINAL_SETUP)
    # the truth goes to declared bounds only, and a declared bound must take it
    oracle = OracleController(PlantConfig())
    with pytest.raises(TypeError, match="declared privileged=False, but its controller takes the plant's truth"):
        ControllerEntry("sly", "Sly", lambda setup: oracle).build(NOMINAL_SETUP)
    with pytest.raises(TypeError, match="declared privileged=True, but its controller does not take"):
        ControllerEntry("bound", "Bound", lambda setup, plant: PDController(), privileged=True).build(
            NOMINAL_SETUP, PlantConfig()
        )
    with pytest.raises(ValueError, match="no controllers in"):
        parse_controller_keys(" , ")
    assert parse_controller_keys(f"pd, {user_module}:Soft,pd") == ["pd", f"{user_module}:Soft"]


def test_a_user_controller_source_is_hashed_and_single_files_cannot_go_to_a_cluster(user_module: str) -> None:
    assert controller_source("pd") == b""
    assert b"class Soft(PDController)" in controller_source(f"{user_module}:Soft")
    assert controller_packages(["pd", "mid_f_rls"]) == []
    with pytest.raises(ValueError, match="into a package"):
        controller_packages([f"{user_module}:Soft"])


def test_a_user_controller_runs_an_episode_like_a_builtin_one(user_module: str) -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    ours = run_episode(env, build_controller(f"{user_module}:Soft", NOMINAL_SETUP), 3, [1.0])
    monitored = MonitoredController(PDController(1000.0, 20.0), registry.fault_monitor(NOMINAL_SETUP))
    builtin = run_episode(env, monitored, 3, [1.0])
    np.testing.assert_array_equal(ours.tracking_error, builtin.tracking_error)


def test_eval_compares_the_example_controllers_beside_the_builtin_rows(
    parameter_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    # As the README runs it: the example module importable from PYTHONPATH, in this process and in the workers.
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(EXAMPLES), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "run"
    controllers = "pd,my_controller:computed_torque,my_controller:StiffPD,oracle"
    argv = ["--controllers", controllers, "--episodes", "1", "--cycles", "1", "--calibration-episodes", "1"]
    argv += ["--runs-dir", str(tmp_path / "runs")]
    assert eval_main([*argv, "--workers", "2", "--parameters", str(parameter_file), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    with (out / "episodes.csv").open(newline="") as file:
        rows = {row["key"]: row for row in csv.DictReader(file)}
    assert list(rows) == controllers.split(",")
    assert rows["my_controller:StiffPD"]["controller"] == "Stiff PD (example)"
    assert "| Computed torque (example) | 1 (0) |" in printed and "| Stiff PD (example) | 1 (0) |" in printed
    # twice the stiffness, half the tracking error or better; and the bound holds for the user's rows too
    assert float(rows["my_controller:StiffPD"]["tracking_rms_mm"]) < 0.6 * float(rows["pd"]["tracking_rms_mm"])
    # PD's stiffness on the identified model's inertia, the model's dynamics cancelled: the error less than halved
    # (10 episodes of 3 cycles: 2.18 against 5.60 mm)
    assert float(rows["my_controller:computed_torque"]["tracking_rms_mm"]) < 0.5 * float(rows["pd"]["tracking_rms_mm"])
    assert "Bound check: no controller tracks better than Oracle+PD (bound)" in printed
    assert sys.modules["my_controller"].__file__.startswith(str(EXAMPLES))
