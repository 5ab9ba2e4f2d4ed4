"""The experiment engine: one record of what a controller knows, one kept tare per robot and setup, one grid runner
for every experiment and backend."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from controllers.compliance import DriveCompliance
from controllers.dynamics import ModelParameters
from controllers.identification import IdentificationResult
from controllers.payload import EmptyMoveSums
from controllers.setup import ControllerSetup
from delta_env.records import content_hash
from delta_env.scenario import preset
from eval import calibration
from eval.calibration import calibration_seeds, tare_setup
from eval.console import UsageError
from eval.engine import grid, kept_tares, prepare, require_known_drives
from eval.sweep.work import METRIC_FIELDS, run_unit
from eval.work import run_grid, unit_record
from tests.conftest import NOMINAL_SETUP as SETUP

SUMS = EmptyMoveSums(np.diag([1.5, 2.0, 3.0, 4.0, 5.0]) + 0.25, np.array([0.1, -0.2, 1e-9, 3.0, -4.5]))
"""Empty-move sums of a known value (symmetric information)."""


def tiny(name: str = "nominal", n_cycles: int = 1):
    scenario = preset(name)
    return dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, n_cycles=n_cycles))


def known_setup() -> ControllerSetup:
    """A setup with every kind of field set away from its default: tares, empty moves, a path, no encoder."""
    return dataclasses.replace(
        SETUP,
        drive_lag=(1.1e-3, 0.9e-3, 1.3e-3),
        tares={"mid_f_rls": 0.0123456789, "mid_f_rls_lag": -0.004},
        empty_moves={"mid_f_rls": SUMS},
        pd_gains=(2500.0, 55.5),
        residual_policy=Path("policies/some policy.zip"),
        encoder_bits=None,
        fault_reaction="slow",
    )


def test_the_setup_record_round_trips_through_its_written_form_exactly() -> None:
    setup = known_setup()
    table = json.loads(json.dumps(setup.to_table()))  # as a policy file or a kept tare stores it
    again = ControllerSetup.from_table(table)
    assert again.content_hash() == setup.content_hash() == content_hash(table)
    for field in dataclasses.fields(ControllerSetup):
        if field.name != "empty_moves":
            assert getattr(again, field.name) == getattr(setup, field.name), field.name
    np.testing.assert_array_equal(again.empty_moves["mid_f_rls"].information, SUMS.information)
    np.testing.assert_array_equal(again.empty_moves["mid_f_rls"].moment, SUMS.moment)
    assert isinstance(again.residual_policy, Path) and isinstance(again.empty_moves["mid_f_rls"], EmptyMoveSums)


def test_the_setup_hash_changes_with_any_field_even_deep_inside() -> None:
    setup = known_setup()
    moment = SUMS.moment.copy()
    moment[2] += 1e-12
    changed = [
        dataclasses.replace(setup, drive_lag=(1.1e-3, 0.9e-3, 1.31e-3)),
        dataclasses.replace(setup, empty_moves={"mid_f_rls": SUMS._replace(moment=moment)}),
        dataclasses.replace(setup, drive=dataclasses.replace(setup.drive, rated_torque=127.0)),
        dataclasses.replace(setup, encoder_bits=20),
        dataclasses.replace(setup, tares={**setup.tares, "mid_f_rls_ref": 0.0}),
    ]
    hashes = {setup.content_hash(), *(other.content_hash() for other in changed)}
    assert len(hashes) == len(changed) + 1


def test_a_setup_table_with_a_bad_field_is_refused_naming_it() -> None:
    table = known_setup().to_table()
    with pytest.raises(ValueError, match=r"empty_moves\.mid_f_rls\.moment"):
        ControllerSetup.from_table({**table, "empty_moves": {"mid_f_rls": {"information": [[1.0]], "moment": "x"}}})
    with pytest.raises(ValueError, match=r"unknown key.*gains"):
        ControllerSetup.from_table({**table, "gains": [1.0, 2.0]})
    with pytest.raises(ValueError, match=r"drive_lag\[1\] must be a finite number in \[0, 0.1\] s"):
        ControllerSetup.from_table({**table, "drive_lag": [1e-3, -1e-3, 1e-3]})


def test_a_tare_is_measured_once_and_kept_for_every_later_experiment(tmp_path: Path, monkeypatch) -> None:
    scenario = tiny()
    tared, first = tare_setup(scenario, SETUP, ["pd", "mid_f_rls"], episodes=1, kept=tmp_path)
    (kept,) = tmp_path.iterdir()
    assert kept.name.startswith("mid_f_rls-")
    # the empty gripper's apparent payload: measured 1.1 g
    assert 0.0 < abs(first.tares["mid_f_rls"]) < 0.002, "the empty gripper's apparent payload is a gram or two"

    def measure(*args, **kwargs):
        raise AssertionError("a kept tare was measured again")

    monkeypatch.setattr(calibration, "calibrate_tares", measure)
    # Another experiment on the same robot and setup (the sweep after the comparison) reads the same tare.
    again_setup, again = tare_setup(scenario, SETUP, ["mid_f_rls", "mid_f_rls"], episodes=1, kept=tmp_path)
    assert again.tares == first.tares and again_setup.tares == tared.tares
    assert np.isnan(again.spreads["mid_f_rls"]) and np.isnan(first.spreads["mid_f_rls"]), "one carry: no spread"
    np.testing.assert_array_equal(
        again.empty_moves["mid_f_rls"].information, first.empty_moves["mid_f_rls"].information
    )
    np.testing.assert_array_equal(again.empty_moves["mid_f_rls"].moment, first.empty_moves["mid_f_rls"].moment)
    # What decides a tare changes its key: other gains are another setup, measured anew.
    with pytest.raises(AssertionError, match="measured again"):
        tare_setup(
            scenario, dataclasses.replace(SETUP, pd_gains=(2000.0, 50.0)), ["mid_f_rls"], episodes=1, kept=tmp_path
        )
    with pytest.raises(AssertionError, match="measured again"):
        tare_setup(tiny(n_cycles=2), SETUP, ["mid_f_rls"], episodes=1, kept=tmp_path)
    kept.write_text("{")
    with pytest.raises(ValueError, match=f"{kept.name}: unreadable kept tare"):
        tare_setup(scenario, SETUP, ["mid_f_rls"], episodes=1, kept=tmp_path)


def test_the_comparison_and_the_sweep_use_one_kept_tare(parameter_file: Path, tmp_path: Path, monkeypatch) -> None:
    scenario = tiny()
    # The comparison: its rows and its residual policy.
    compared = prepare(
        scenario, ["mid_f_rls"], parameters=parameter_file, runs_dir=tmp_path, calibration_episodes=1,
        residual_policy=Path("policy.zip"),
    )  # fmt: skip
    folder = kept_tares(scenario, tmp_path)
    assert folder == tmp_path / "identification" / scenario.robot_identity / "tares"
    assert [path.name.split("-")[0] for path in folder.iterdir()] == ["mid_f_rls"]
    monkeypatch.setattr(calibration, "calibrate_tares", lambda *args, **kwargs: pytest.fail("measured again"))
    # The sweep of another grid of the same scenario reads it.
    swept = prepare(scenario, ["pd", "mid_f_rls"], parameters=parameter_file, runs_dir=tmp_path, calibration_episodes=1)
    assert swept.calibration.tares == compared.calibration.tares and swept.setup.tares == compared.setup.tares
    # A worn drive is the same robot (its folder) but other work for the estimator: a tare of its own.
    worn = tiny("worn")
    assert kept_tares(worn, tmp_path) == folder
    with pytest.raises(pytest.fail.Exception, match="measured again"):
        prepare(worn, ["mid_f_rls"], parameters=parameter_file, runs_dir=tmp_path, calibration_episodes=1)


def test_the_calibration_seeds_are_the_same_for_every_experiment() -> None:
    assert calibration_seeds(3) == [100_000, 100_001, 100_002]


@pytest.mark.slow
def test_run_grid_gives_the_same_rows_and_records_in_this_process_and_on_a_pool() -> None:
    scenario = tiny()
    units = grid([scenario], ["pd", "mid_f_rls"], [0, 1])
    assert [(u.controller, u.seed) for u in units] == [("pd", 0), ("pd", 1), ("mid_f_rls", 0), ("mid_f_rls", 1)]
    setups = {scenario.content_hash: SETUP}
    here = run_grid(units, setups, work=run_unit)
    pooled = run_grid(units, setups, work=run_unit, workers=2)
    for one, other in zip(here, pooled, strict=True):
        assert {name: one[name] for name in METRIC_FIELDS} == pytest.approx(
            {name: other[name] for name in METRIC_FIELDS}, rel=0, abs=0, nan_ok=True
        )
    assert here[0]["tracking_rms_mm"] != here[2]["tracking_rms_mm"], "rows in the order of the units"
    seen = []
    records = run_grid(units[:2], setups, work=unit_record, workers=2, on_result=lambda u, r: seen.append((u, r)))
    np.testing.assert_array_equal(records[1].tracking_error, unit_record(units[1], SETUP).tracking_error)
    # each unit is handed over as it finishes, with the record that the returned list holds at its place
    assert sorted((units.index(u), id(r)) for u, r in seen) == [(0, id(records[0])), (1, id(records[1]))]


def test_run_grid_raises_an_episodes_error() -> None:
    scenario = tiny()
    units = grid([scenario], ["mid_f_rls_lag"], [0])
    with pytest.raises(ValueError, match="needs the identified drive lag"):
        run_grid(units, {scenario.content_hash: dataclasses.replace(SETUP, drive_lag=None)})
    with pytest.raises(ValueError, match="no controller setup for the scenarios"):
        run_grid(units, {})


@pytest.mark.slow
def test_run_grid_records_are_identical_on_ray() -> None:
    pytest.importorskip("ray", reason="Ray is the optional 'distributed' extra")
    scenario = tiny()
    units = grid([scenario], ["mid_f_rls"], [0, 1])
    setups = {scenario.content_hash: SETUP}
    local = run_grid(units, setups)
    ray = run_grid(units, setups, backend="ray", workers=2)
    for one, other in zip(local, ray, strict=True):
        np.testing.assert_array_equal(one.tracking_error, other.tracking_error)
        np.testing.assert_array_equal(one.payload_estimate, other.payload_estimate)


def _without_load_encoder(backlash: float):
    """The compliant preset's plant with ``backlash`` (rad) per gearhead and no load-side encoder."""
    plant = preset("compliant").plant
    drives = dataclasses.replace(plant.realism.compliance, backlash=backlash, load_encoder_bits=None)
    return dataclasses.replace(plant, realism=dataclasses.replace(plant.realism, compliance=drives))


def test_the_servo_layer_on_drives_it_does_not_know_is_refused_naming_the_encoder() -> None:
    """Behind a backlash without a load encoder the servo layer is refused for the backlash first, whatever the
    parameter file holds (the motor-side fit refuses such drives, so the file holds none); without the drives'
    compliance it is refused naming why (rigid drives in the file, or the identification's reason); with the drives
    known and no backlash it is allowed; with the paper's PD, or on rigid drives, it is never refused."""
    known = dataclasses.replace(SETUP, compliance=DriveCompliance.nominal())
    refused = "not identified: the two-mass model does not explain the drive"
    rigid_file = IdentificationResult(*(ModelParameters(),) * 5, None, None, None, {}, {})
    unidentified = dataclasses.replace(rigid_file, provenance={"compliance": {"method": refused}})
    backlash = _without_load_encoder(2.908882e-4)
    for setup, identification in ((SETUP, unidentified), (SETUP, rigid_file), (known, rigid_file)):
        with pytest.raises(UsageError, match=r"backlash 0.0002909 rad and load_encoder_bits = None: the motor side"):
            require_known_drives(backlash, setup, identification)
    without_backlash = _without_load_encoder(0.0)
    with pytest.raises(UsageError, match=rf"no drive compliance \(its identification: {refused}\)"):
        require_known_drives(without_backlash, SETUP, unidentified)
    with pytest.raises(UsageError, match=r"no drive compliance \(rigid drives: leave --parameters out"):
        require_known_drives(without_backlash, SETUP, rigid_file)
    with pytest.raises(UsageError, match=r"load_encoder_bits = 20: the parameter file holds no drive compliance"):
        require_known_drives(preset("compliant").plant, SETUP, rigid_file)
    for plant in (backlash, without_backlash):
        require_known_drives(plant, dataclasses.replace(SETUP, servo="pd"), unidentified)
    require_known_drives(without_backlash, known, rigid_file)
    require_known_drives(preset("compliant").plant, known, rigid_file)
    require_known_drives(preset("nominal").plant, SETUP, rigid_file)
