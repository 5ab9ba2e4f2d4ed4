"""Identification of compliant drives (``controllers.identification.compliance``, docs/design.md section 7,
"Compliant drives"): a known, non-default stiffness and damping per joint from the multisine logs at rest poses, the
model's first mode with them against the plant's frequency response, the optional angle columns of the log format,
the multisine itself."""

import json
from dataclasses import replace

import numpy as np
import pytest

from controllers.compliance import DriveCompliance, first_mode
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.identification import (
    DriveLog,
    IdentificationResult,
    LogFileError,
    ParameterFileError,
    load_result,
    read_log,
    save_result,
    write_log,
)
from controllers.identification.compliance import (
    MOTOR_SIDE_PARAMETER_NAMES,
    UnexplainedTorqueError,
    UnseenModeError,
    fit_compliance,
    fit_motor_side_compliance,
)
from controllers.servo import ResonanceNotch
from delta_env import kinematics
from delta_env.config import ARCMIN, RATED_PAYLOAD, PlantConfig
from delta_env.excitation import multisine_torques
from delta_env.scenario import preset, save_robot
from delta_env.sensors import CONTROL_PERIOD
from eval.identification.compliance import (
    COMPLIANCE_POSES,
    MAP_HEIGHTS,
    MAP_RADII,
    ComplianceExcitationSpec,
    measure_first_mode,
    pose_arm_inertia,
    run_compliance_excitation,
)
from eval.identification.excitation import ExcitationSpec, run_excitation
from eval.identification.report import ground_truth, render_report, save_validation_data
from eval.identification.run import identify_logs, run_identification

COMPLIANT = preset("compliant").plant


def _plant(**gearhead: object) -> PlantConfig:
    """The compliant preset with a 20-bit load-side encoder (unless given) and the gearhead changed as given."""
    compliance = replace(COMPLIANT.realism.compliance, **{"load_encoder_bits": 20, **gearhead})
    return replace(COMPLIANT, realism=replace(COMPLIANT.realism, compliance=compliance))


@pytest.fixture(scope="module")
def known_plant_logs() -> tuple[PlantConfig, list[DriveLog]]:
    """Stiffness 0.7 / 1.0 / 1.4 and damping 1.5 / 1.0 / 0.6 times the SP+ 140's, the three poses (about 6 s)."""
    plant = _plant(stiffness_scale=(0.7, 1.0, 1.4), damping_scale=(1.5, 1.0, 0.6))
    logs = [
        run_compliance_excitation(ComplianceExcitationSpec(seed=n, pose=pose), plant)
        for n, pose in enumerate(COMPLIANCE_POSES)
    ]
    return plant, logs


def test_the_traces_command_is_the_one_sent_with_its_sample(known_plant_logs) -> None:
    """DriveLog's convention: command k is sent with sample k and held until sample k + 1. The hold reads the rotor
    at the last physics step of each control period, so the trace's command changes at exactly those rows."""
    plant, logs = known_plant_logs
    substeps = round(CONTROL_PERIOD / plant.timestep)
    changes = np.flatnonzero(np.any(np.diff(logs[0].commands, axis=0) != 0.0, axis=1)) + 1
    assert len(changes) > 100
    np.testing.assert_array_equal((changes + 1) % substeps, 0)


def test_known_stiffness_and_damping_are_identified(known_plant_logs) -> None:
    """Stiffness within 1.8 % per joint (the issue's target is 5 %; measured: -0.01, +1.0, +0.5 %), damping within 25 %
    (-4, -7, -20 %: its torque is 4 % of the spring's at the mode, so a few microseconds of timing move it), the rotor
    inertia within 3.5 % (+1 to +2 %); no backlash found where there is none. The standard errors are the periods'
    noise only, far below the bias, but not zero."""
    plant, logs = known_plant_logs
    truth = plant.realism.compliance
    fit = fit_compliance(logs, torque_delay=plant.timestep)
    np.testing.assert_allclose(fit.compliance.stiffness, truth.stiffness_per_joint, rtol=0.018)
    np.testing.assert_allclose(fit.compliance.damping, truth.damping_per_joint, rtol=0.25)
    np.testing.assert_allclose(fit.compliance.rotor_inertia, truth.rotor_inertia, rtol=0.035)
    assert np.all(fit.estimate[:, 5] < 1e-5)  # backlash (rad): 0.03 arcmin
    stiffness_errors = fit.standard_errors[:, 3] / fit.estimate[:, 3]
    assert np.all((stiffness_errors > 0.0) & (stiffness_errors < 0.01))
    assert fit.periods == 8 and fit.logs == 3


@pytest.mark.parametrize(
    ("backlash_arcmin", "stiffness_scale", "damping_scale", "seed"),
    [
        (2.0, (1.2, 0.9, 0.75), (0.8, 1.3, 1.0), 7),
        (0.5, (0.6, 1.5, 1.0), (1.0, 1.0, 2.0), 7),
        (3.0, (1.0,) * 3, (1.0,) * 3, 0),
    ],
)
def test_stiffness_and_backlash_are_identified_behind_a_backlash(
    backlash_arcmin: float, stiffness_scale: tuple, damping_scale: tuple, seed: int
) -> None:
    """Behind 0.5 to 3 arcmin of backlash the stiffness within 4 % (the issue's target is 5 %; measured within 2.3 %),
    the backlash within 10 % (within 6 %), the damping within 15 % (within 8 %)."""
    plant = _plant(stiffness_scale=stiffness_scale, damping_scale=damping_scale, backlash=backlash_arcmin * ARCMIN)
    logs = [
        run_compliance_excitation(ComplianceExcitationSpec(seed=seed + n, pose=pose), plant)
        for n, pose in enumerate(COMPLIANCE_POSES)
    ]
    truth = plant.realism.compliance
    fit = fit_compliance(logs, torque_delay=plant.timestep)
    np.testing.assert_allclose(fit.compliance.stiffness, truth.stiffness_per_joint, rtol=0.04)
    np.testing.assert_allclose(fit.estimate[:, 5], truth.backlash, rtol=0.1)
    np.testing.assert_allclose(fit.compliance.backlash, fit.estimate[:, 5], rtol=1e-12)  # what the servo is told
    np.testing.assert_allclose(fit.compliance.damping, truth.damping_per_joint, rtol=0.15)


def test_the_stiffness_needs_the_load_side_and_whole_periods(known_plant_logs) -> None:
    _, logs = known_plant_logs
    blind = replace(logs[0], load_angles=None)
    with pytest.raises(ValueError, match="load-side angle"):
        fit_compliance([blind])
    short = DriveLog(
        logs[0].angles[:1600], logs[0].torques[:1600], None, logs[0].dt, load_angles=logs[0].load_angles[:1600]
    )
    with pytest.raises(ValueError, match="periods"):
        fit_compliance([short])
    with pytest.raises(ValueError, match="whole number"):
        fit_compliance(logs, period=0.20001)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_motor_and_load_angles_round_trip_and_old_logs_still_read(known_plant_logs, tmp_path, suffix) -> None:
    _, logs = known_plant_logs
    log = replace(logs[0], commands=None)
    back = read_log(write_log(log, tmp_path / f"compliance{suffix}"), log.dt)
    np.testing.assert_array_equal(back.load_angles, log.load_angles)
    np.testing.assert_array_equal(back.motor_angles, log.motor_angles)
    np.testing.assert_array_equal(back.motor_side_angles, log.motor_angles)
    rigid = read_log(write_log(DriveLog(log.angles, log.torques, None), tmp_path / f"rigid{suffix}"))
    assert rigid.load_angles is None and rigid.motor_angles is None
    np.testing.assert_array_equal(rigid.motor_side_angles, log.angles)
    with pytest.raises(LogFileError, match="CSV or Parquet"):
        write_log(log, tmp_path / "compliance.mcap")


def test_a_partial_angle_group_is_refused(tmp_path) -> None:
    path = tmp_path / "partial.csv"
    path.write_text("time_s,theta_1,theta_2,theta_3,torque_1,torque_2,torque_3,load_angle_1\n0,0,0,0,0,0,0,0\n")
    with pytest.raises(LogFileError, match="load_angle_2, load_angle_3: give all three or none"):
        read_log(path)


def test_multisine_has_its_lines_only_and_its_rms() -> None:
    torques = multisine_torques(np.random.default_rng(3), 20.0, 0.2, (5.0, 300.0))
    assert torques.shape == (200, 3)
    np.testing.assert_allclose(np.sqrt(np.mean(torques**2, axis=0)), 20.0)
    power = np.abs(np.fft.rfft(torques, axis=0)) ** 2
    frequencies = np.fft.rfftfreq(200, 1e-3)
    inside = (frequencies >= 5.0) & (frequencies <= 300.0)
    assert np.all(power[~inside] < 1e-20 * power[inside].mean())
    np.testing.assert_allclose(power[inside] / power[inside].mean(), 1.0)
    assert abs(np.corrcoef(torques.T)[0, 1]) < 0.3
    with pytest.raises(ValueError, match="band"):
        multisine_torques(np.random.default_rng(0), 1.0, 0.2, (600.0, 700.0))


def test_the_models_first_mode_with_the_identified_drives_is_the_plants(known_plant_logs) -> None:
    """The two-mass model (nominal arm, rod forearms) with the identified compliance against the plant's frequency
    response at three poses, empty and at the rated payload: within 3 % (measured -0.26 to -0.32 %, the identified
    rotor inertia's +1 to +2 %; from the motor side alone -0.18 to -0.27 %); damping ratios within 25 % (measured -3
    to -5 %; from the motor side 0 to +1 %)."""
    plant, logs = known_plant_logs
    inertias = [pose_arm_inertia(plant, pose) for pose in COMPLIANCE_POSES]
    fits = (
        fit_compliance(logs, torque_delay=plant.timestep),
        fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep),
    )
    dynamics = DeltaDynamics.of_robot(plant.geometry, plant.masses, forearm_rods=True)
    for pose in COMPLIANCE_POSES:
        theta = kinematics.inverse(plant.geometry, np.array(pose))
        for payload in (0.0, RATED_PAYLOAD):
            measured = measure_first_mode(plant, pose, payload)
            for fit in fits:
                model = first_mode(dynamics, fit.compliance, theta, payload)
                np.testing.assert_allclose(model.frequency_hz, measured.frequency_hz, rtol=0.03)
                np.testing.assert_allclose(model.damping_ratio, measured.damping_ratio, rtol=0.25)


def test_the_parameter_file_keeps_the_compliance_and_rigid_files_stay_as_they_were(tmp_path) -> None:
    rigid = IdentificationResult(*(ModelParameters(),) * 5, None, None, None, {}, {"note": "rigid"})
    path = save_result(rigid, tmp_path / "rigid.json")
    assert "compliance" not in json.loads(path.read_text())
    assert load_result(path).compliance is None
    drives = DriveCompliance((0.11, 0.1, 0.12), (1.2e5, 1.8e5, 2.5e5), (9.0, 10.0, 11.0), (3e-4, 2.9e-4, 0.0))
    back = load_result(save_result(replace(rigid, compliance=drives), tmp_path / "compliant.json"))
    assert back.compliance == drives
    document = json.loads((tmp_path / "compliant.json").read_text())
    older = json.loads(json.dumps(document))
    del older["compliance"]["backlash_rad"]  # written before the backlash was stored
    (tmp_path / "older.json").write_text(json.dumps(older))
    assert load_result(tmp_path / "older.json").compliance == replace(drives, backlash=(0.0, 0.0, 0.0))
    document["compliance"]["stiffness_nm_per_rad"][1] = -1.0
    (tmp_path / "bad.json").write_text(json.dumps(document))
    with pytest.raises(ParameterFileError, match="stiffness"):
        load_result(tmp_path / "bad.json")


def test_a_compliant_plants_identification_reports_its_drives_and_mode_map(tmp_path) -> None:
    """``run_identification`` on a compliant plant with a load encoder (every drive effect on, stiffness x(0.7, 1,
    1.4)) identifies its drives within 5 % beside the rigid parameters; the report
    lists them against the truth and maps the first mode (about 3 s)."""
    plant = _plant(stiffness_scale=(0.7, 1.0, 1.4))
    run = run_identification(2, duration=2.0, validation_duration=2.0, plant=plant, workers=1, progress=False)
    truth = plant.realism.compliance
    np.testing.assert_allclose(run.result.compliance.stiffness, truth.stiffness_per_joint, rtol=0.05)
    assert {f"compliance.stiffness_{j}" for j in (1, 2, 3)} <= set(run.result.standard_errors)
    assert len(run.compliance_logs) == len(COMPLIANCE_POSES)
    save_validation_data(run, tmp_path / "validation.npz")
    report = render_report(run, tmp_path / "validation.npz", "test", [], ground_truth(plant))
    section = report[report.index("## Compliant drives") : report.index("## Run time")]
    assert "| stiffness | N m/rad |" in section and "### First-mode map" in section
    assert section.count("\n| -") == len(MAP_HEIGHTS) * len(MAP_RADII)


def test_known_stiffness_is_identified_from_the_motor_side_alone(known_plant_logs) -> None:
    """From the motor encoder and the torque alone, on the datasheet model's arm with its scale fitted: stiffness
    within 1 % per joint (measured: -0.4, -0.6, -0.3 %), damping within 25 % (0, +7, +16 %), the rotor inertia within
    3 % (+1.5, +0.2, +0.5 %), the arm's scale within 0.06 of 1 (1.039: the plant's arm against the rod model). The
    stiffness's standard errors (the periods' noise only: 0.05 to 0.06 % of k, ten times under its error) under
    0.2 % of k. The load-side angles are in the logs and not read; a missing inertia per log is refused."""
    plant, logs = known_plant_logs
    truth = plant.realism.compliance
    inertias = [pose_arm_inertia(plant, pose) for pose in COMPLIANCE_POSES]
    fit = fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep)
    np.testing.assert_allclose(fit.compliance.stiffness, truth.stiffness_per_joint, rtol=0.01)
    np.testing.assert_allclose(fit.compliance.damping, truth.damping_per_joint, rtol=0.25)
    np.testing.assert_allclose(fit.compliance.rotor_inertia, truth.rotor_inertia, rtol=0.03)
    assert fit.compliance.backlash == (0.0, 0.0, 0.0) and fit.parameter_names == MOTOR_SIDE_PARAMETER_NAMES
    assert abs(fit.arm_inertia_scale[0] - 1.0) < 0.06
    stiffness_errors = fit.standard_errors[:, MOTOR_SIDE_PARAMETER_NAMES.index("stiffness")]
    assert np.all((stiffness_errors > 0.0) & (stiffness_errors < 0.002 * np.asarray(fit.compliance.stiffness)))
    with pytest.raises(ValueError, match=r"one \(3, 3\) arm-side inertia per log \(3\)"):
        fit_motor_side_compliance(logs, inertias[:2], torque_delay=plant.timestep)


def _motor_only_logs(seed: int = 0, **gearhead: object) -> tuple[PlantConfig, list[DriveLog], list[np.ndarray]]:
    """The compliance excitation's logs at the three poses on the compliant preset without a load-side encoder, the
    gearhead changed as given, with the model's arm inertia at each pose."""
    plant = _plant(load_encoder_bits=None, **gearhead)
    logs = [
        run_compliance_excitation(ComplianceExcitationSpec(seed=seed + n, pose=pose), plant)
        for n, pose in enumerate(COMPLIANCE_POSES)
    ]
    return plant, logs, [pose_arm_inertia(plant, pose) for pose in COMPLIANCE_POSES]


def test_stiff_drives_without_backlash_are_identified_from_the_motor_side() -> None:
    """At 5 to 6.4 times the SP+ 140's stiffness (the plant's stiffest; the arm's antiresonances 200 to 380 Hz, the
    rotor's resonances above the fitted 300 Hz) the motor-side fit is not refused, its residual being the friction's
    and ripple's, and the stiffness comes out within 5 % (measured -2.2, -2.9, -3.1 %; the rotor inertia +19 to
    +26 %, beyond its resonance's reach) (about 2 s)."""
    plant, logs, inertias = _motor_only_logs(stiffness_scale=(6.0, 5.0, 6.4), damping_scale=(1.0, 0.5, 2.0))
    fit = fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep)
    np.testing.assert_allclose(fit.compliance.stiffness, plant.realism.compliance.stiffness_per_joint, rtol=0.05)


def test_the_motor_side_fit_refuses_a_mode_above_its_lines(known_plant_logs) -> None:
    """Fitted on the lines up to 50 Hz, below every antiresonance of the drives (60 to 120 Hz), the stiffness is not
    seen (it came out 14 to 17 % low): refused, naming the antiresonances and the band."""
    plant, logs = known_plant_logs
    inertias = [pose_arm_inertia(plant, pose) for pose in COMPLIANCE_POSES]
    with pytest.raises(
        UnseenModeError, match=r"lowest antiresonance per log, \[.*\] Hz, is above the fitted lines \(up to 50 Hz\)"
    ):
        fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep, highest_line=50.0)


@pytest.mark.parametrize(
    ("backlash_arcmin", "stiffness_scale"), [(0.1, (1.0, 1.0, 1.0)), (1.0, (1.0, 1.0, 1.0)), (0.1, (6.0, 6.0, 6.0))]
)
def test_the_motor_side_fit_refuses_drives_behind_a_backlash(backlash_arcmin: float, stiffness_scale: tuple) -> None:
    """Behind the smallest backlash the controllers act on (0.1 arcmin) at the preset's stiffness and six times it,
    and behind 1 arcmin, the two-mass model leaves 0.2 to 0.6 of the torque up to 200 Hz unexplained (the stiffness
    would come out 11 to 70 % low); the fit refuses, naming the shares and the limit (about 2 s each)."""
    plant, logs, inertias = _motor_only_logs(backlash=backlash_arcmin * ARCMIN, stiffness_scale=stiffness_scale)
    message = r"the two-mass model does not explain the drive: it leaves \[.*\] of the torque .* \(at most 0\.15\)"
    with pytest.raises(UnexplainedTorqueError, match=message):
        fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep)


def test_without_a_load_encoder_the_drives_are_identified_from_the_motor_side(tmp_path) -> None:
    """Compliant drives read by motor encoders only (stiffness 1.5 / 0.6 / 1.0 times the SP+ 140's, damping 0.5 / 2 /
    1 times): the identification fits them from the motor side (measured: stiffness +0.5, -1.6, -0.3 %), the report
    lists them without a backlash row and maps their first mode (about 9 s)."""
    motor_only = replace(
        COMPLIANT.realism.compliance,
        load_encoder_bits=None,
        stiffness_scale=(1.5, 0.6, 1.0),
        damping_scale=(0.5, 2.0, 1.0),
    )
    plant = replace(COMPLIANT, realism=replace(COMPLIANT.realism, compliance=motor_only))
    run = run_identification(1, duration=1.5, validation_duration=1.5, plant=plant, workers=1, progress=False)
    np.testing.assert_allclose(run.result.compliance.stiffness, motor_only.stiffness_per_joint, rtol=0.03)
    assert all(log.load_angles is None for log in run.compliance_logs)
    assert "from the motor side alone" in run.result.provenance["compliance"]["method"]
    assert "compliance.arm_inertia_scale" in run.result.standard_errors
    save_validation_data(run, tmp_path / "validation.npz")
    report = render_report(run, tmp_path / "validation.npz", "test", [], ground_truth(plant))
    section = report[report.index("## Compliant drives") : report.index("## Run time")]
    assert "| stiffness | N m/rad |" in section and "| backlash |" not in section
    assert section.count("\n| -") == len(MAP_HEIGHTS) * len(MAP_RADII)


def test_compliant_drives_are_identified_from_log_files(known_plant_logs, tmp_path) -> None:
    """The compliance excitation's logs written as files and read back identify the same drives as the arrays; without
    their load-side columns they identify them from the motor side alone (stiffness within 2 %); a mix is refused."""
    plant, logs = known_plant_logs
    paths = [write_log(log, tmp_path / f"compliance_{n:02d}.csv") for n, log in enumerate(logs)]
    rigid = [tmp_path / "excitation_01.csv", tmp_path / "validation.csv"]
    run = run_identification(1, duration=1.5, validation_duration=1.5, plant=COMPLIANT, workers=1, progress=False)
    for log, path in zip(run.logs, rigid, strict=True):
        write_log(log, path)
    robot = save_robot(plant.geometry, plant.masses, tmp_path / "robot.toml")
    # read at their own sample period (the physics step, four times the control period's rate) by default
    from_files = identify_logs(rigid, robot, compliance_paths=paths, torque_delay=plant.timestep)
    expected = fit_compliance(logs, torque_delay=plant.timestep).compliance
    np.testing.assert_allclose(from_files.result.compliance.stiffness, expected.stiffness, rtol=1e-12)
    assert len(from_files.result.provenance["compliance"]["logs"]) == len(paths)
    with pytest.raises(ValueError, match=r"compliance log .*a\.mcap is a ROS 2 bag"):
        identify_logs(rigid, robot, compliance_paths=[tmp_path / "a.mcap"])
    # without the load-side columns, from the motor side alone, on the inertia at each log's mean angles
    motor_only = [
        write_log(replace(log, load_angles=None), tmp_path / "motor" / f"compliance_{n:02d}.csv")
        for n, log in enumerate(logs)
    ]
    from_motor = identify_logs(rigid, robot, compliance_paths=motor_only, torque_delay=plant.timestep)
    truth = plant.realism.compliance.stiffness_per_joint
    np.testing.assert_allclose(from_motor.result.compliance.stiffness, truth, rtol=0.02)
    assert "from the motor side alone" in from_motor.result.provenance["compliance"]["method"]
    with pytest.raises(ValueError, match=r"all have load_angle columns or none"):
        identify_logs(rigid, robot, compliance_paths=[*paths[:1], *motor_only[1:]], torque_delay=plant.timestep)


@pytest.mark.slow
def test_the_command_line_identifies_compliant_drives_from_saved_logs(tmp_path) -> None:
    """``--save-logs`` on the compliant preset writes the compliance excitation's logs beside the rigid ones and prints
    the command that reads them back; that command (``--compliance-log``, ``--torque-age`` the physics step)
    identifies the same drives and drive lag as the simulation, from the files alone (about 40 s)."""
    from eval.identification import __main__ as cli

    logs, quiet = tmp_path / "logs", ["--no-progress", "--workers", "1", "--no-install"]
    short = ["--trajectories", "1", "--duration", "1.5", "--validation-duration", "1.5"]
    cli.main(["--scenario", "compliant", *short, *quiet, "--out", str(tmp_path / "sim"), "--save-logs", str(logs)])
    rigid = [logs / "excitation_01.csv", logs / "validation.csv"]
    compliance = sorted(logs.glob("compliance_*.csv"))
    assert len(compliance) == len(COMPLIANCE_POSES)
    arguments = ["--log", *map(str, rigid), "--robot", str(logs / "robot.toml"), "--compliance-log"]
    out = ["--out", str(tmp_path / "fromlogs")]
    cli.main([*arguments, *map(str, compliance), "--torque-age", f"{COMPLIANT.timestep:g}", *quiet[:-1], *out])
    simulated = load_result(tmp_path / "sim" / "parameters.json")
    logged = load_result(tmp_path / "fromlogs" / "parameters.json")
    for name in ("rotor_inertia", "stiffness", "damping"):
        np.testing.assert_allclose(getattr(logged.compliance, name), getattr(simulated.compliance, name), rtol=1e-9)
    np.testing.assert_allclose(logged.drive_lag, simulated.drive_lag, rtol=1e-9)


def test_compliance_options_belong_to_log_files(capsys) -> None:
    from eval.identification import __main__ as cli

    with pytest.raises(SystemExit):
        cli.parse_args(["--scenario", "compliant", "--torque-age", "0.00025"])
    assert "--torque-age: only for --log files" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # the default's value too: a simulation takes none
        cli.parse_args(["--scenario", "compliant", "--torque-age", "0.0005"])
    with pytest.raises(SystemExit):
        cli.parse_args(["--log", "a.csv", "b.csv", "--robot", "r.toml", "--torque-age", "0.002"])
    assert "torque_delay must be a finite number in (0, 0.001] s, got 0.002" in capsys.readouterr().err
    config = cli.parse_args(["--log", "a.csv", "b.csv", "--robot", "r.toml"])
    assert config.torque_age == 0.0005


def test_the_excitation_notches_the_drive_mode_it_would_otherwise_ring_at() -> None:
    """The rigid excitation's PD on compliant drives: without a notch the loop rings at the drive mode (the
    angles' second difference 100x the rigid plant's); with the notch at the identified mode (here the data sheet's
    compliance, the known truth) it moves as smoothly as on rigid drives, so the rigid model's fit sees the motion."""
    spec = ExcitationSpec(seed=1, duration=1.5)
    rigid = run_excitation(spec, preset("nominal").plant)
    compliance = DriveCompliance.of_gearhead(COMPLIANT.realism.compliance)
    notched = run_excitation(spec, COMPLIANT, ResonanceNotch(compliance.rotor_inertia, compliance.stiffness))
    ringing = run_excitation(spec, COMPLIANT)

    def roughness(record) -> np.ndarray:
        return np.sqrt(np.mean(np.diff(record.angles, 2, axis=0) ** 2, axis=0))

    assert np.all(roughness(notched) < 1.5 * roughness(rigid))
    assert np.all(roughness(ringing) > 20.0 * roughness(rigid))
