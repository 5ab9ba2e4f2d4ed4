"""Identification against known truth: joint LS, the paper's grid method, data preparation, file I/O."""

import dataclasses
import json
import logging
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers import identification
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.identification import (
    JOINT_PARAMETER_NAMES,
    REST_VELOCITY,
    IdentificationResult,
    MotionData,
    ParameterFileError,
    fit_joint_least_squares,
    fit_least_squares,
    fit_paper_method,
    fit_rho_least_squares,
    fit_stribeck,
    grid_search_rho,
    load_result,
    older_format,
    prepare_motion,
    save_result,
)
from delta_env import kinematics
from delta_env.config import PlantConfig
from delta_env.geometry import NOMINAL_GEOMETRY, TORQUE_LIMIT, DeltaGeometry
from delta_env.limits import WorkspaceLimits
from delta_env.scaling import scaled_masses
from delta_env.scenario import preset
from delta_env.sensors import ENCODER_RESOLUTION
from eval.identification import parameter_files
from eval.identification.excitation import ExcitationSpec, collect_excitation_data
from eval.identification.parameter_files import identify_robot, load_or_identify, outdated, parameter_path, robot_setup
from eval.identification.run import COMPLIANCE_VERSION, IDENTIFICATION_VERSION, MOTOR_SIDE_UNIDENTIFIED, identify

TRUTH = ModelParameters(rho1=1.77, rho2=0.93, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6))
OFF_GRID = ModelParameters(rho1=1.2345, rho2=1.1111, viscous=(0.3, 5.0, 1.1), coulomb=(0.5, 8.0, 2.2))


def as_vector(parameters: ModelParameters) -> np.ndarray:
    """The parameters in the order of JOINT_PARAMETER_NAMES."""
    return np.array([parameters.rho1, parameters.rho2, *parameters.viscous, *parameters.coulomb])


@pytest.fixture(scope="module")
def motions() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Exact joint motions of three 3 s excitation trajectories (rad, rad/s, rad/s^2)."""
    references = [ExcitationSpec(seed=seed, duration=3.0).reference() for seed in (11, 12, 13)]
    return [(r.theta, r.theta_dot, r.theta_ddot) for r in references]


def synthetic(motion: tuple[np.ndarray, ...], parameters: ModelParameters, noise_std: float = 0.0, seed: int = 0):
    """MotionData whose torque is DeltaDynamics with ``parameters`` plus white noise (N m)."""
    torque = DeltaDynamics.nominal(parameters).inverse_dynamics(*motion)
    torque = torque + np.random.default_rng(seed).normal(0.0, noise_std, torque.shape)
    return MotionData(*motion, torque=torque)


@pytest.mark.parametrize("parameters", [TRUTH, OFF_GRID])
@pytest.mark.parametrize("threshold", [0.0, 1.0])
def test_joint_least_squares_recovers_parameters_from_noise_free_data(motions, parameters, threshold) -> None:
    data = [synthetic(motion, parameters) for motion in motions]
    fit = fit_joint_least_squares(data, velocity_threshold=threshold)
    assert fit.names == JOINT_PARAMETER_NAMES
    assert_allclose(fit.estimate, as_vector(parameters), rtol=1e-9)
    assert_allclose(as_vector(fit.parameters), as_vector(parameters), rtol=1e-9)
    assert fit.residual_rms_total < 1e-9
    # rows: the samples moving faster than the threshold (rest is left out: static friction)
    theta_dot = np.concatenate([motion[1] for motion in motions])
    expected_rows = np.sum(np.abs(theta_dot) > threshold, axis=0)
    assert fit.rows == tuple(expected_rows)


def test_joint_least_squares_is_unbiased_and_its_standard_errors_hold_under_white_noise(motions) -> None:
    # White torque noise and exact motion: the estimate is unbiased and sigma^2 (X^T X)^-1 is its covariance.
    noise_std, draws = 0.5, 40
    fits = [
        fit_joint_least_squares(
            [synthetic(motion, TRUTH, noise_std, seed=len(motions) * draw + k) for k, motion in enumerate(motions)]
        )
        for draw in range(draws)
    ]
    estimates = np.array([fit.estimate for fit in fits])
    reported = np.mean([fit.standard_errors for fit in fits], axis=0)
    assert np.all(np.abs(estimates.mean(axis=0) - as_vector(TRUTH)) < 4.0 * reported / math.sqrt(draws))
    # the spread over draws matches the reported standard errors (11 % sampling error at 40 draws)
    assert_allclose(estimates.std(axis=0, ddof=1), reported, rtol=0.35)
    assert_allclose([fit.residual_rms_total for fit in fits], noise_std, rtol=0.05)


def test_rho_least_squares_recovers_rho_without_friction(motions) -> None:
    parameters = ModelParameters(rho1=2.05, rho2=0.81)
    fit = fit_rho_least_squares([synthetic(motion, parameters) for motion in motions])
    assert fit.names == ("rho1", "rho2")
    assert_allclose(fit.estimate, [2.05, 0.81], rtol=1e-9)
    assert fit.parameters == ModelParameters(rho1=fit.estimate[0], rho2=fit.estimate[1])


def test_fit_least_squares_equals_the_two_separate_fits(motions) -> None:
    data = [synthetic(motion, TRUTH, noise_std=0.5, seed=3) for motion in motions]
    rho_fit, joint_fit = fit_least_squares(data)
    assert rho_fit == fit_rho_least_squares(data)
    assert joint_fit == fit_joint_least_squares(data)


@pytest.mark.parametrize(
    ("rho1", "rho2", "tolerance"),
    [(1.73, 0.91, 1e-12), (0.95, 1.37, 1e-12), (1.7654, 0.9321, 0.01)],
    ids=["on-grid", "on-grid-2", "off-grid"],
)
def test_grid_search_finds_rho_to_the_grid_resolution(motions, rho1, rho2, tolerance) -> None:
    data = synthetic(motions[0], ModelParameters(rho1=rho1, rho2=rho2))
    found = grid_search_rho(data)
    assert_allclose(found, (rho1, rho2), atol=tolerance)


def test_grid_search_minimises_the_rms_torque_error_over_the_grid(motions) -> None:
    # eq. (7) by brute force on a coarse grid: recompute the torques for every grid point
    data = synthetic(motions[1], TRUTH, noise_std=2.0, seed=5)
    grid1, grid2 = (1.5, 2.0, 0.05), (0.7, 1.2, 0.05)
    best = grid_search_rho(data, rho1_grid=grid1, rho2_grid=grid2)
    rms = {
        (r1, r2): np.sqrt(np.mean(identification.torque_errors(ModelParameters(rho1=r1, rho2=r2), data) ** 2))
        for r1 in identification.rho_grid(grid1)
        for r2 in identification.rho_grid(grid2)
    }
    assert best == min(rms, key=rms.get)


def test_paper_method_without_friction_finds_rho_and_no_friction(motions) -> None:
    data = [synthetic(motion, ModelParameters(rho1=1.73, rho2=0.91)) for motion in motions]
    paper = fit_paper_method(data)
    assert_allclose(paper.rho, np.tile([1.73, 0.91], (3, 1)), atol=1e-12)
    assert_allclose(as_vector(paper.mid), [1.73, 0.91, 0, 0, 0, 0, 0, 0], atol=1e-12)
    assert_allclose(as_vector(paper.mid_f), as_vector(paper.mid), atol=1e-9)


def test_paper_friction_least_squares_recovers_friction_at_the_true_rho(motions) -> None:
    data = synthetic(motions[2], TRUTH)
    viscous, coulomb = identification.fit_friction_per_joint(data, TRUTH.rho1, TRUTH.rho2)
    assert_allclose(viscous, TRUTH.viscous, rtol=1e-9)
    assert_allclose(coulomb, TRUTH.coulomb, rtol=1e-9)


def test_paper_grid_is_biased_by_friction_that_the_joint_fit_models(motions) -> None:
    # Why ours fits everything at once: the grid ignores friction, which leaks into each trajectory's rho.
    data = [synthetic(motion, TRUTH) for motion in motions]
    paper = fit_paper_method(data)
    assert np.max(np.abs(paper.rho - [TRUTH.rho1, TRUTH.rho2])) > 0.1
    assert_allclose(fit_joint_least_squares(data).estimate, as_vector(TRUTH), rtol=1e-9)


@pytest.mark.parametrize(
    ("moving_joints", "threshold", "message"),
    [
        ((), 1.0, r"0 rows cannot determine 8 parameters"),
        ((0, 1, 2), 100.0, r"0 rows cannot determine 8 parameters"),
        ((0,), 0.0, r"the data do not excite \['viscous_2', 'viscous_3', 'coulomb_2', 'coulomb_3'\]"),
    ],
    ids=["at rest", "threshold above every rate", "joints 2 and 3 held"],
)
def test_joint_least_squares_refuses_data_that_do_not_excite_friction(
    motions, moving_joints, threshold, message
) -> None:
    theta, theta_dot, theta_ddot = motions[0]
    held = [joint for joint in range(3) if joint not in moving_joints]
    theta_dot, theta_ddot = theta_dot.copy(), theta_ddot.copy()
    theta_dot[:, held] = theta_ddot[:, held] = 0.0
    data = synthetic((theta, theta_dot, theta_ddot), TRUTH)
    with pytest.raises(ValueError, match=f"joint least squares: {message}"):
        fit_joint_least_squares([data], velocity_threshold=threshold)


def test_negative_friction_estimates_are_clipped_with_a_warning(motions, caplog) -> None:
    without_viscous_2 = dataclasses.replace(TRUTH, viscous=(2.0, 0.0, 1.7))
    data = []
    for motion in motions:
        torque = DeltaDynamics.nominal(without_viscous_2).inverse_dynamics(*motion)
        torque[:, 1] -= 0.7 * motion[1][:, 1]  # fv_2 = -0.7 N m s/rad
        data.append(MotionData(*motion, torque=torque))
    with caplog.at_level(logging.WARNING, logger="controllers.identification"):
        fit = fit_joint_least_squares(data)
    assert fit.estimate[3] == pytest.approx(-0.7, rel=1e-9)
    assert fit.parameters.viscous == pytest.approx((2.0, 0.0, 1.7), rel=1e-9)
    assert "negative viscous friction [-0.7] on joint(s) [2] clipped to 0" in caplog.text


@pytest.mark.parametrize(("excess", "velocity"), [((2.0, 1.7, 2.3), 0.05), ((0.5, 4.0, 1.0), 0.1)])
def test_stribeck_fit_recovers_the_excess_and_its_decay_speed(motions, excess, velocity) -> None:
    """Torques of the model plus fs exp(-(v / vs)^2) sign(v) and 0.5 N m of white noise, rates under REST_VELOCITY
    zeroed as prepared data are: fs within 5 % and four standard errors (measured: 0.4 %, 4.1 % and 1.1 %, 2.6 of
    them at most), vs within 5 % (0.7 %)."""
    data = []
    for seed, (theta, theta_dot, theta_ddot) in enumerate(motions):
        rates = np.where(np.abs(theta_dot) < REST_VELOCITY, 0.0, theta_dot)
        torque = DeltaDynamics.nominal(TRUTH).inverse_dynamics(theta, rates, theta_ddot)
        torque += np.array(excess) * np.exp(-((rates / velocity) ** 2)) * np.sign(rates)
        torque += np.random.default_rng(seed).normal(0.0, 0.5, torque.shape)
        data.append(MotionData(theta, rates, theta_ddot, torque))
    fit = fit_stribeck(data, TRUTH, DeltaDynamics.nominal(TRUTH))
    assert_allclose(fit.excess, excess, rtol=0.05)
    assert np.all(np.abs(np.array(fit.excess) - excess) < 4.0 * np.array(fit.standard_errors))
    assert fit.velocity == pytest.approx(velocity, rel=0.05)
    assert min(fit.rows) >= 50 and max(fit.standard_errors) < 0.05
    # No excess: the fit finds none (clipped at 0 or within its noise).
    quiet = [
        dataclasses.replace(
            d, torque=d.torque - np.array(excess) * np.exp(-((d.theta_dot / velocity) ** 2)) * np.sign(d.theta_dot)
        )
        for d in data
    ]
    assert max(fit_stribeck(quiet, TRUTH, DeltaDynamics.nominal(TRUTH)).excess) < 0.1


def test_stribeck_fit_refuses_data_without_slow_motion(motions) -> None:
    theta, theta_dot, theta_ddot = motions[0]
    fast = np.where(np.abs(theta_dot) < 0.5, 0.0, theta_dot)
    data = [MotionData(theta, fast, theta_ddot, DeltaDynamics.nominal(TRUTH).inverse_dynamics(theta, fast, theta_ddot))]
    with pytest.raises(ValueError, match=r"moving rows per joint slower than 0\.2 rad/s"):
        fit_stribeck(data, TRUTH, DeltaDynamics.nominal(TRUTH))


def test_prepare_motion_smooths_aligns_trims_and_zeroes_rest_rates() -> None:
    reference = ExcitationSpec(seed=21, duration=2.0).reference()
    torques = np.arange(3.0 * len(reference)).reshape(-1, 3)
    raw = prepare_motion(reference.theta, torques, 1e-3, trim=50, torque_delay=0.25e-3, rest_velocity=0.0)
    assert len(raw) == len(reference) - 100
    assert_allclose(raw.torque, torques[50:-50], rtol=0, atol=0)
    # the motion at t_k - 0.25 ms: the smoother is within 1.3e-5 rad and 4.7e-3 rad/s of it, a delay of 0 or
    # 0.5 ms would be off by 2.1e-3 rad and 0.03 rad/s
    time = np.arange(len(reference)) * 1e-3
    for smoothed, exact, tolerance in (
        (raw.theta, reference.theta, 3e-5),
        (raw.theta_dot, reference.theta_dot, 1e-2),
    ):
        delayed = np.column_stack([np.interp(time - 0.25e-3, time, column) for column in exact.T])
        assert_allclose(smoothed, delayed[50:-50], rtol=0, atol=tolerance)
    data = prepare_motion(reference.theta, torques, 1e-3, trim=50, torque_delay=0.25e-3, rest_velocity=0.02)
    assert_allclose(data.theta_dot, np.where(np.abs(raw.theta_dot) < 0.02, 0.0, raw.theta_dot), rtol=0, atol=0)
    at_rest = reference.theta_dot[50:-50] == 0.0
    assert np.mean(data.theta_dot[at_rest] == 0.0) > 0.9


def test_collect_excitation_data_records_encoder_angles_and_measured_torques() -> None:
    (record,) = collect_excitation_data([ExcitationSpec(seed=5, duration=0.3)])
    assert record.angles.shape == record.torques.shape == (301, 3)
    # 17-bit encoder readings, not the simulator's continuous angles
    assert_allclose(record.angles / ENCODER_RESOLUTION, np.round(record.angles / ENCODER_RESOLUTION), atol=1e-6)
    # 0.5 N m white noise on the measured torque: large sample-to-sample jumps at rest at the start
    assert np.std(np.diff(record.torques[1:100], axis=0)) > 0.5


RESULT = IdentificationResult(
    mid=ModelParameters(rho1=1.79, rho2=0.94),
    mid_f=TRUTH,
    mid_f_rods=ModelParameters(rho1=1.95, rho2=0.95, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6)),
    paper_mid=ModelParameters(rho1=1.8, rho2=0.935),
    paper_mid_f=OFF_GRID,
    drive_lag=(0.00101, 0.00098, 0.00104),
    stribeck_excess=(1.9, 1.6, 2.2),
    stribeck_velocity=0.052,
    standard_errors={name: 0.001 * (k + 1) for k, name in enumerate(f"mid_f.{n}" for n in JOINT_PARAMETER_NAMES)},
    provenance={"seed": 7, "trajectories": [{"seed": 1, "duration": 8.0}], "date": "2026-01-01T00:00:00+00:00"},
)


def test_save_load_round_trip(tmp_path) -> None:
    path = save_result(RESULT, tmp_path / "nested" / "parameters.json")
    assert path == tmp_path / "nested" / "parameters.json"
    assert load_result(path) == RESULT
    assert list(path.parent.iterdir()) == [path]  # no temporary file left behind


def test_save_converts_numpy_values_in_the_provenance(tmp_path) -> None:
    result = dataclasses.replace(RESULT, provenance={"rms": np.float64(1.5), "rows": np.array([3, 4])})
    assert load_result(save_result(result, tmp_path / "p.json")).provenance == {"rms": 1.5, "rows": [3, 4]}


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def mutate(document):
        target = document
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
        return document

    return mutate


def _delete(*keys):
    def mutate(document):
        target = document
        for key in keys[:-1]:
            target = target[key]
        del target[keys[-1]]
        return document

    return mutate


CORRUPTIONS = {
    "missing model": (_delete("mid_f"), "missing key 'mid_f' in the file"),
    "missing rho1": (_delete("mid", "rho1"), "missing key 'rho1' in mid"),
    "rho as text": (_set("paper_mid", "rho2", "0.9"), "paper_mid.rho2 must be a finite number"),
    "rho as bool": (_set("mid", "rho1", True), "mid.rho1 must be a finite number"),
    "rho not finite": (_set("mid", "rho2", math.nan), "mid.rho2 must be a finite number"),
    "rho zero": (_set("paper_mid_f", "rho1", 0.0), "paper_mid_f: rho1 must be a finite number in (0, 1000], got 0.0"),
    "rho too large": (_set("mid", "rho2", 5000.0), "mid: rho2 must be a finite number in (0, 1000], got 5000.0"),
    "two joints": (_set("mid_f", "viscous", [1.0, 2.0]), "mid_f.viscous must be a list of 3 numbers"),
    "negative coulomb": (
        _set("mid_f", "coulomb", [4.0, 3.4, -1.0]),
        "mid_f: coulomb[3] must be a finite number in [0, 400] N m, got -1.0",
    ),
    "coulomb of 1e6 N m": (
        _set("mid_f", "coulomb", [4.0, 1e6, 4.6]),
        "mid_f: coulomb[2] must be a finite number in [0, 400] N m, got 1000000.0",
    ),
    "viscous too large": (
        _set("paper_mid_f", "viscous", [2.0, 2.0, 5000.0]),
        "paper_mid_f: viscous[3] must be a finite number in [0, 1000] N m s/rad, got 5000.0",
    ),
    "friction as text": (_set("mid_f", "coulomb", [4.0, "3.4", 4.6]), "mid_f.coulomb[1] must be a finite number"),
    "negative standard error": (
        _set("standard_errors", "mid_f.rho1", -0.1),
        "standard_errors['mid_f.rho1'] must be a finite number in [0, inf)",
    ),
    "standard errors not an object": (_set("standard_errors", [0.1]), "standard_errors must be a JSON object"),
    "provenance not an object": (_set("provenance", "none"), "provenance must be a JSON object"),
    "missing provenance": (_delete("provenance"), "missing key 'provenance'"),
    "wrong version": (_set("format_version", 2), "format_version 2 is not 4; delete the file or run"),
    "missing Stribeck excess": (_delete("stribeck_excess_nm"), "missing key 'stribeck_excess_nm' in the file"),
    "negative Stribeck excess": (
        _set("stribeck_excess_nm", [1.0, -0.1, 1.0]),
        "stribeck_excess_nm[1] must be a finite number in [0, 400]",
    ),
    "Stribeck excess without its speed": (
        _set("stribeck_velocity_rad_s", None),
        "stribeck_excess_nm and stribeck_velocity_rad_s must both be null or not",
    ),
    "missing lag": (_delete("drive_lag_s"), "missing key 'drive_lag_s' in the file"),
    "lag of two joints": (_set("drive_lag_s", [0.001, 0.001]), "drive_lag_s must be a list of 3 numbers"),
    "negative lag": (_set("drive_lag_s", [0.001, -0.001, 0.001]), "drive_lag_s[1] must be a finite number in [0"),
    "lag too long": (_set("drive_lag_s", [0.001, 0.001, 0.5]), "drive_lag_s[2] must be a finite number in [0"),
    "top level list": (lambda document: [document], "the file must be a JSON object"),
}


@pytest.mark.parametrize(("mutate", "message"), CORRUPTIONS.values(), ids=CORRUPTIONS.keys())
def test_load_rejects_a_corrupt_file_naming_path_and_problem(tmp_path, mutate, message) -> None:
    path = save_result(RESULT, tmp_path / "parameters.json")
    path.write_text(json.dumps(mutate(json.loads(path.read_text()))))
    with pytest.raises(ParameterFileError) as error:
        load_result(path)
    assert str(path) in str(error.value)
    assert message in str(error.value)


@pytest.mark.parametrize(
    "text", ["", "{not json", '{"format_version": 1,', "\xff\xfe"], ids=["empty", "garbage", "truncated", "binary"]
)
def test_load_rejects_text_that_is_not_json(tmp_path, text) -> None:
    path = tmp_path / "parameters.json"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(ParameterFileError, match="not valid JSON") as error:
        load_result(path)
    assert str(path) in str(error.value)


def test_load_of_a_missing_file_says_how_to_create_it(tmp_path) -> None:
    path = tmp_path / "absent.json"
    with pytest.raises(FileNotFoundError) as error:
        load_result(path)
    assert str(path) in str(error.value) and "python -m eval.identification" in str(error.value)


def test_load_or_identify_loads_an_existing_file_without_identifying(tmp_path, monkeypatch) -> None:
    path = save_result(RESULT, tmp_path / "parameters.json")
    monkeypatch.setattr(parameter_files, "identify", pytest.fail)
    assert load_or_identify(path) == RESULT


def test_load_or_identify_identifies_and_saves_when_the_file_is_missing(tmp_path, monkeypatch) -> None:
    calls = []

    def fake_identify(**kwargs):
        calls.append(kwargs)
        return RESULT

    monkeypatch.setattr(parameter_files, "identify", fake_identify)
    path = tmp_path / "runs" / "parameters.json"
    assert load_or_identify(path, seed=4, n_trajectories=3) == RESULT
    assert calls == [{"seed": 4, "n_trajectories": 3}]
    assert load_result(path) == RESULT


def test_load_or_identify_never_replaces_a_corrupt_file(tmp_path, monkeypatch) -> None:
    path = tmp_path / "parameters.json"
    path.write_text("{corrupt")
    monkeypatch.setattr(parameter_files, "identify", pytest.fail)
    with pytest.raises(ParameterFileError):
        load_or_identify(path)
    assert path.read_text() == "{corrupt"


def test_a_cache_of_another_identification_version_is_identified_again(tmp_path, monkeypatch) -> None:
    """The cache key (the robot's identity) does not change with the identification's code: a robot's file written
    by another version, or before the version was recorded, is identified again and replaced, and so is one whose
    compliant drives (fitted or refused) another version of their identification made; a current one and one from
    logs are read as they are."""
    plant = preset("compliant").plant

    def versioned(version: object) -> IdentificationResult:
        return dataclasses.replace(RESULT, provenance={"method": {"version": version}})

    current, older = versioned(IDENTIFICATION_VERSION), versioned(IDENTIFICATION_VERSION - 1)
    from_logs = dataclasses.replace(RESULT, provenance={"plant": {"source": "logs"}})
    assert outdated(older) and outdated(RESULT) and not outdated(current) and not outdated(from_logs)

    def with_drives(compliance: dict) -> IdentificationResult:
        return dataclasses.replace(current, provenance={**current.provenance, "compliance": compliance})

    refused = f"{MOTOR_SIDE_UNIDENTIFIED}: the two-mass model does not explain the drive"
    assert not outdated(with_drives({"method": refused, "version": COMPLIANCE_VERSION}))
    assert not outdated(with_drives({"method": "fitted", "version": COMPLIANCE_VERSION}))
    # a refusal by an older criterion, and drives left unidentified before the motor-side fit, are identified again
    assert outdated(with_drives({"method": refused, "version": COMPLIANCE_VERSION - 1}))
    assert outdated(with_drives({"method": "not identified: compliant drives without a load-side encoder"}))
    path = save_result(older, parameter_path(plant, tmp_path))
    monkeypatch.setattr(parameter_files, "identify", lambda **kwargs: current)
    monkeypatch.setattr(parameter_files, "check_identity", lambda *args: None)
    monkeypatch.setattr(parameter_files, "check_settings", lambda *args: None)
    assert identify_robot(plant, tmp_path) == current and load_result(path) == current
    monkeypatch.setattr(parameter_files, "identify", pytest.fail)
    assert identify_robot(plant, tmp_path) == current


def test_load_or_identify_identifies_again_over_a_cache_of_an_older_format(tmp_path, monkeypatch, caplog) -> None:
    path = save_result(RESULT, tmp_path / "parameters.json")
    document = json.loads(path.read_text())
    document["format_version"] = 3
    del document["stribeck_excess_nm"], document["stribeck_velocity_rad_s"]
    path.write_text(json.dumps(document))
    assert older_format(path)
    monkeypatch.setattr(parameter_files, "identify", lambda **kwargs: RESULT)
    with caplog.at_level(logging.WARNING):
        assert load_or_identify(path) == RESULT
    assert "older version" in caplog.text and load_result(path) == RESULT


def test_identify_end_to_end_on_two_short_trajectories(tmp_path) -> None:
    result = identify(n_trajectories=2, seed=3, duration=2.5, progress=False, workers=2, validation_duration=2.5)
    provenance = result.provenance
    seeds = [spec["seed"] for spec in provenance["trajectories"]] + [provenance["validation_trajectory"]["seed"]]
    assert len(set(seeds)) == 3
    assert provenance["samples"]["per_trajectory"] == [2401, 2401]
    assert set(result.standard_errors) == {
        f"{m}.{n}" for m in ("mid", "mid_f", "mid_f_rods") for n in JOINT_PARAMETER_NAMES[: 2 if m == "mid" else 8]
    } | {f"stribeck.excess_{j}" for j in (1, 2, 3)}
    table = provenance["torque_error_validation"]
    assert np.all(np.array(table["MId+F (joint LS)"]["std"]) < 0.5 * np.array(table["MKH"]["std"]))
    assert np.all(np.array(table["MId+F (paper)"]["std"]) < 0.5 * np.array(table["MKH"]["std"]))
    # The rod forearms are the plant's mechanism: measured 0.82 against 1.52 N m residual RMS on 96 s of data.
    residuals = provenance["residuals"]
    assert residuals["mid_f_rods"]["residual_rms"] < 0.8 * residuals["mid_f"]["residual_rms"]
    # 5 s of data. MId+F+R is the plant's mechanism: its friction within 2.0 % of the plant's and the drive lag
    # within 2.0 % (measured on seeds 3-5; here 2.0 % and 1.0 %). MId+F's friction absorbs the forearms' rod
    # inertia, which short data do not average out: 6.6 % here, 11 % and 31 % on seeds 4 and 5.
    assert_allclose(result.mid_f_rods.viscous, (2.0, 2.4, 1.7), rtol=0.03)
    assert_allclose(result.mid_f_rods.coulomb, (4.0, 3.4, 4.6), rtol=0.03)
    assert_allclose(result.drive_lag, PlantConfig().realism.actuator_lag, rtol=0.04)
    assert_allclose(result.mid_f.viscous, (2.0, 2.4, 1.7), rtol=0.25)
    assert_allclose(result.mid_f.coulomb, (4.0, 3.4, 4.6), rtol=0.25)
    # rho near what 96 s of data give (1.76, 0.92)
    assert result.mid_f.rho1 == pytest.approx(1.76, rel=0.1)
    assert result.mid_f.rho2 == pytest.approx(0.92, rel=0.2)
    assert load_result(save_result(result, tmp_path / "parameters.json")) == result


def test_command_line_writes_parameters_configuration_report_and_figures(tmp_path, capsys) -> None:
    from eval.identification import __main__ as cli
    from eval.identification.report import FIGURES

    folder, installed = tmp_path / "run", tmp_path / "installed" / "parameters.json"
    arguments = ["--trajectories", "2", "--duration", "2", "--validation-duration", "2", "--seed", "5"]
    cli.main([*arguments, "--out", str(folder), "--parameters", str(installed), "--no-progress", "--workers", "1"])
    expected = {"parameters.json", "config.json", "report.md", "validation.npz", "scenario.toml"}
    expected |= {*FIGURES, "fig6a_error_bars.png"}
    assert {path.name for path in folder.iterdir()} == expected
    assert load_result(folder / "parameters.json") == load_result(installed)
    config = json.loads((folder / "config.json").read_text())
    assert config["config"]["trajectories"] == 2
    assert config["config"]["scenario"] == "nominal"
    assert load_result(installed).provenance["plant"]["identity"] == config["config"]["robot_identity"]
    assert config["command"].startswith("python -m eval.identification --trajectories 2")
    report = (folder / "report.md").read_text()
    assert report in capsys.readouterr().out
    for heading in ("## Table 1 analogue", "## Identified parameters", "## Run time", "coulomb_3"):
        assert heading in report


def test_excitation_record_holds_the_commands_and_fits_the_plants_drive_lag() -> None:
    (record,) = collect_excitation_data([ExcitationSpec(seed=5, duration=1.5)])
    assert record.commands.shape == (len(record.torques) - 1, 3)
    assert np.all(np.abs(record.commands) <= TORQUE_LIMIT)
    # The plant's current loop: 1 ms on every joint; the fit sees the 0.5 N m torque noise and the ripple. From one
    # 1.5 s run: 1.022, 0.988, 1.089 ms (seeds 6-9: within 5.9 %); 12 runs of 8 s give about 1 %, tested below.
    assert_allclose(record.log.drive_lag(), PlantConfig().realism.actuator_lag, rtol=0.1)


@pytest.mark.slow
def test_default_identification_meets_the_accuracy_the_readme_states() -> None:
    # 12 runs of 8 s (about 20 s): MId+F+R friction and the drive lag within 0.7 % of the plant's on seeds 0, 1, 2
    # (here 0.62 % and 0.56 %), so 1 % fails an error twice as large.
    result = identify(seed=1, progress=False, workers=1)
    assert_allclose(result.mid_f_rods.viscous, (2.0, 2.4, 1.7), rtol=0.01)
    assert_allclose(result.mid_f_rods.coulomb, (4.0, 3.4, 4.6), rtol=0.01)
    assert_allclose(result.drive_lag, PlantConfig().realism.actuator_lag, rtol=0.01)


def test_excitation_runs_on_the_plants_own_geometry_inside_the_given_region() -> None:
    geometry = DeltaGeometry(ra=0.24, rb=0.03, l1=0.32, l2=1.05)
    region = WorkspaceLimits(radius=0.3, z_min=-1.1, z_max=-0.8, min_abs_k=0.1, min_abs_det_a=0.1)
    spec = ExcitationSpec(seed=8, duration=1.5, start=(0.0, 0.0, -0.95), limits=region)
    plant = PlantConfig(geometry=geometry, masses=scaled_masses(geometry))
    (record,) = collect_excitation_data([spec], plant=plant)
    # the encoder angles, mapped through the design's kinematics, stay in the region (3 mm of tracking error)
    platform = kinematics.forward(geometry, record.angles)
    assert np.max(np.hypot(platform[:, 0], platform[:, 1])) < region.radius + 3e-3
    assert region.z_min - 3e-3 < platform[:, 2].min() and platform[:, 2].max() < region.z_max + 3e-3
    assert_allclose(record.angles, spec.reference(geometry).theta, atol=1e-2)  # PD + MKH at up to 6 g
    assert 0.0 < record.max_loop_gap < 2e-5  # measured 11 um
    # the default is the nominal robot's trajectory, as before
    default = ExcitationSpec(seed=8, duration=1.5)
    assert_allclose(default.reference().theta, default.reference(NOMINAL_GEOMETRY).theta, rtol=0, atol=0)


def test_load_or_identify_refuses_an_older_identification_from_logs(tmp_path, monkeypatch) -> None:
    path = save_result(dataclasses.replace(RESULT, provenance={"plant": {"source": "logs"}}), tmp_path / "p.json")
    document = json.loads(path.read_text())
    document["format_version"] = 3
    path.write_text(json.dumps(document))
    monkeypatch.setattr(parameter_files, "identify", pytest.fail)
    with pytest.raises(ParameterFileError, match="identification from logs in an older file format"):
        load_or_identify(path)


def test_the_controllers_take_a_log_identified_robots_torque_age_from_its_file() -> None:
    """A robot identified from logs knows its torque readings' age only from the file (``--torque-age``); a
    simulated one has its plant's physics step, whatever its file says."""
    plant = preset("compliant").plant
    from_logs = dataclasses.replace(
        RESULT, provenance={"plant": {"source": "logs"}, "method": {"torque_sample_delay_s": 0.0003}}
    )
    simulated = dataclasses.replace(RESULT, provenance={"method": {"torque_sample_delay_s": 0.0003}})
    assert robot_setup(plant, from_logs).torque_delay == 0.0003
    assert robot_setup(plant, simulated).torque_delay == plant.timestep == 0.00025
