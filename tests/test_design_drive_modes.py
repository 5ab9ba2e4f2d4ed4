"""The first mode of a design's compliant drives (eval.design.drive_modes): the scaled gearhead and its map."""

import numpy as np
import pytest

from controllers.compliance import first_mode
from delta_env import kinematics
from delta_env.catalogue import MOTORS, DriveOption
from delta_env.config import GEARHEAD_STIFFNESS, RATED_PAYLOAD, ROTOR_INERTIA
from delta_env.geometry import NOMINAL_GEOMETRY
from eval.design.drive_modes import (
    GEARHEAD_DAMPING_RATIO,
    REFERENCE_PEAK_TORQUE,
    design_gearhead,
    drive_mode_columns,
)
from eval.design.model import design_model
from eval.identification.compliance import mode_map, workspace_grid


@pytest.mark.parametrize(("motor", "ratio"), [("SGM7A-20A", 21.0), ("SGM7A-25A", 50.0), ("SGM7J-08A", 10.0)])
def test_the_scaled_gearhead_follows_the_drives_torque_at_the_data_sheets_damping_ratio(motor: str, ratio: float):
    option = DriveOption(motor, MOTORS[motor], ratio)
    gearhead = design_gearhead(option)
    np.testing.assert_allclose(
        gearhead.stiffness, GEARHEAD_STIFFNESS * option.limits.peak_torque / REFERENCE_PEAK_TORQUE, rtol=1e-12
    )
    np.testing.assert_allclose(gearhead.rotor_inertia, option.armature, rtol=1e-12)
    ratios = np.array(gearhead.damping) / (2 * np.sqrt(np.array(gearhead.stiffness) * option.armature))
    np.testing.assert_allclose(ratios, GEARHEAD_DAMPING_RATIO, rtol=1e-12)
    assert 0.03 < GEARHEAD_DAMPING_RATIO < 0.04


def test_the_data_sheets_drive_keeps_the_data_sheets_gearhead():
    """The representative drive (the motor the SP+ 140 was sized for, behind 1:21) gets the SP+ 140 itself, within
    the catalogue motor's rounding of the peak torque."""
    gearhead = design_gearhead(DriveOption("SGM7A-20A", MOTORS["SGM7A-20A"], 21.0))
    np.testing.assert_allclose(gearhead.stiffness, GEARHEAD_STIFFNESS, rtol=0.15)
    np.testing.assert_allclose(gearhead.rotor_inertia, ROTOR_INERTIA, rtol=1e-12)


def test_a_designs_map_on_its_links_is_the_two_mass_model():
    """The map's entries are the two-mass model's first mode at each point; the rated payload lowers it."""
    option = DriveOption("SGM7A-25A", MOTORS["SGM7A-25A"], 50.0)
    links = design_model(NOMINAL_GEOMETRY, drive=None)
    points = workspace_grid(heights=(-0.9,), radii=(0.0, 0.4), azimuths=6)
    modes = mode_map(links, design_gearhead(option), points, (0.0, RATED_PAYLOAD))
    assert modes.frequency_hz.shape == (7, 2)
    theta = kinematics.inverse(NOMINAL_GEOMETRY, points[3])
    expected = first_mode(links, design_gearhead(option), theta, RATED_PAYLOAD).frequency_hz
    np.testing.assert_allclose(modes.frequency_hz[3, 1], expected, rtol=1e-12)
    assert np.all(modes.frequency_hz[:, 1] < modes.frequency_hz[:, 0])
    columns = drive_mode_columns(modes)
    assert columns["drive_mode_rated_min_hz"] == pytest.approx(modes.frequency_hz[:, 1].min())
    assert np.isnan(drive_mode_columns(None)["drive_mode_empty_max_hz"])
