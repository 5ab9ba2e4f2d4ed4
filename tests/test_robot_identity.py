"""The identification belongs to a robot: one file per robot identity, checked on reading, and controllers
built as models of the robot they were identified on."""

import dataclasses
from typing import Any

import numpy as np
import pytest

from controllers.dynamics import DeltaDynamics
from controllers.identification import IdentificationResult, ParameterFileError
from controllers.registry import build_controller, estimation_model
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.scenario import preset, with_geometry
from eval.identification import parameter_files
from eval.identification import run as identification
from tests.conftest import NOMINAL_SETUP

DESIGN = DeltaGeometry(ra=0.22, rb=0.06, l1=0.35, l2=0.90)


def fake_result(plant: Any, **provenance: Any) -> IdentificationResult:
    """An identification of ``plant`` by this version of the code, with the nominal parameters and the provenance
    entries ``provenance``."""
    setup = NOMINAL_SETUP
    return IdentificationResult(
        mid=setup.mid,
        mid_f=setup.mid_f,
        mid_f_rods=setup.mid_f_rods,
        paper_mid=setup.mid,
        paper_mid_f=setup.mid_f,
        drive_lag=setup.drive_lag,
        stribeck_excess=None,
        stribeck_velocity=None,
        standard_errors={},
        provenance={
            "plant": identification._plant_summary(plant),
            "method": {"version": identification.IDENTIFICATION_VERSION},
            **provenance,
        },
    )


def test_conditions_share_the_robots_file_and_a_new_geometry_gets_its_own() -> None:
    nominal = parameter_files.parameter_path(preset("nominal").plant)
    for name in ("worn", "randomized", "heavy", "stress-6g", "paper"):
        assert parameter_files.parameter_path(preset(name).plant) == nominal
    assert parameter_files.parameter_path(with_geometry(preset("nominal"), DESIGN).plant) != nominal


def test_each_robot_is_identified_once_and_a_file_of_another_robot_is_refused(tmp_path, monkeypatch) -> None:
    calls = []

    def identify(plant, **kwargs):
        calls.append(plant)
        return fake_result(plant)

    monkeypatch.setattr(parameter_files, "identify", identify)
    scenarios = [preset("nominal"), preset("worn"), preset("randomized"), with_geometry(preset("nominal"), DESIGN)]
    results = {s.robot_identity: parameter_files.identify_robot(s.plant, tmp_path) for s in scenarios}
    assert len(results) == 2 and len(calls) == 2  # the nominal robot and the design, each identified once
    assert calls[-1].geometry == DESIGN
    for scenario in scenarios:
        parameter_files.identify_robot(scenario.plant, tmp_path)
    assert len(calls) == 2  # the second time every robot comes from its file
    # A file copied under another robot's identity is refused, naming both robots.
    nominal_file = parameter_files.parameter_path(scenarios[0].plant, tmp_path)
    design_file = parameter_files.parameter_path(scenarios[-1].plant, tmp_path)
    design_file.write_text(nominal_file.read_text())
    with pytest.raises(ParameterFileError, match=scenarios[-1].robot_identity):
        parameter_files.identify_robot(scenarios[-1].plant, tmp_path)


def test_controllers_are_models_of_the_robot_they_were_identified_on() -> None:
    masses = DeltaMasses(m1=1.8, m2=0.18, m0=0.9)
    setup = dataclasses.replace(NOMINAL_SETUP, geometry=DESIGN, masses=masses)
    model = estimation_model(setup)
    assert model.geometry == DESIGN and model.masses == masses
    controller = build_controller("mid_f", setup)
    assert controller.controller.dynamics.geometry == DESIGN  # the model row behind its fault monitor
    theta = np.array([[0.1, -0.2, 0.3]])
    rate, acceleration = np.array([[0.5, 0.2, -0.4]]), np.array([[3.0, -2.0, 1.0]])
    expected = DeltaDynamics.of_robot(DESIGN, masses, NOMINAL_SETUP.mid_f).inverse_dynamics(theta, rate, acceleration)
    nominal = build_controller("mid_f", NOMINAL_SETUP).controller.dynamics.inverse_dynamics(theta, rate, acceleration)
    np.testing.assert_allclose(
        controller.controller.dynamics.inverse_dynamics(theta, rate, acceleration), expected, rtol=1e-12
    )
    assert np.max(np.abs(expected - nominal)) > 0.3  # N m: the design's model is not the nominal one
