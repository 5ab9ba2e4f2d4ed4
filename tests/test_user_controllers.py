"""The open controller registry: built-in rows and a user's controllers resolve, build and run the same way."""

import csv
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from controllers import registry
from controllers.base import PDController
from controllers.feedforward import OracleController
from controllers.monitor import MonitoredController
from controllers.registry import (
    BUILTIN_CONTROLLERS,
    ESTIMATOR_REGRESSORS,
    ControllerEntry,
    build_controller,
    controller_entry,
    controller_packages,
    controller_source,
    parse_controller_keys,
)
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from eval.__main__ import main as eval_main
from eval.episodes import run_episode
from tests.conftest import NOMINAL_SETUP

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

USER_MODULE = """
import numpy as np
from controllers.base import PDController
from controllers.feedforward import OracleController
from controllers.registry import ControllerEntry


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
"""


@pytest.fixture
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """A user's module, importable as ``user_rows_<n>`` (fresh per test: entries are cached per key)."""
    name = f"user_rows_{abs(hash(tmp_path)) % 10**8}"
    (tmp_path / f"{name}.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_builtin_rows_declare_their_capabilities() -> None:
    tared = {key for key, entry in BUILTIN_CONTROLLERS.items() if entry.tared}
    assert tared == set(ESTIMATOR_REGRESSORS)
    estimating = {key for key, entry in BUILTIN_CONTROLLERS.items() if entry.estimates_payload}
    assert estimating == {*ESTIMATOR_REGRESSORS, "residual"}  # the oracle is told the payloads
    assert [key for key, entry in BUILTIN_CONTROLLERS.items() if entry.privileged] == ["oracle"]
    assert all(entry.monitored for entry in BUILTIN_CONTROLLERS.values())


def test_a_class_a_factory_and_an_entry_resolve_by_import_path(user_module: str) -> None:
    soft = controller_entry(f"{user_module}:Soft")
    assert (soft.label, soft.estimates_payload, soft.tared, soft.privileged) == ("Soft PD", False, False, False)
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
    with pytest.raises(TypeError, match="declared tared but has no PayloadEstimator"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), estimates_payload=True, tared=True).build(
            NOMINAL_SETUP
        )
    with pytest.raises(ValueError, match="a tared controller estimates the payload"):
        ControllerEntry("mine", "Mine", lambda setup: PDController(), tared=True)
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
