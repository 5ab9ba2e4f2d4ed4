"""The drive's envelope: its shape, the env's clipping and margins, the thermal RMS, and scenario files."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from delta_env.config import PlantConfig
from delta_env.drive import (
    REPRESENTATIVE_GEAR_EFFICIENCY,
    REPRESENTATIVE_GEAR_RATIO,
    REPRESENTATIVE_MOTOR,
    DriveLimits,
    clip_to_envelope,
)
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario, preset

DRIVE = DriveLimits()  # 400 N m peak, 15 rad/s corner, 30 rad/s maximum
FALLEN = 400.0 * (30.0 - 20.0) / (30.0 - 15.0)  # motoring torque (N m) at 20 rad/s: 266.7


def test_representative_drive_rounds_to_the_defaults() -> None:
    exact = DriveLimits.of(REPRESENTATIVE_MOTOR, REPRESENTATIVE_GEAR_RATIO, REPRESENTATIVE_GEAR_EFFICIENCY)
    assert exact.peak_torque == pytest.approx(399.0)
    assert exact.rated_torque == pytest.approx(127.68)
    assert exact.corner_speed == pytest.approx(math.pi * 100.0 / 21.0)  # 3000 rpm / 21 = 14.96 rad/s
    assert exact.max_speed == pytest.approx(math.pi * 200.0 / 21.0)
    for name in ("peak_torque", "rated_torque", "corner_speed", "max_speed"):
        assert getattr(DRIVE, name) == pytest.approx(getattr(exact, name), rel=0.01)


@pytest.mark.parametrize(
    ("speed", "lower", "upper"),
    [
        (0.0, -400.0, 400.0),  # at rest: the peak both ways
        (10.0, -400.0, 400.0),  # below the corner: the peak in both quadrants
        (20.0, -400.0, FALLEN),  # forward: motoring (+) falls, braking (-) keeps the peak
        (-20.0, -FALLEN, 400.0),  # backward: motoring (-) falls, braking (+) keeps the peak
        (15.0, -400.0, 400.0),  # at the corner
        (30.0, -400.0, 0.0),  # at the maximum speed nothing is left with the motion
        (-45.0, 0.0, 400.0),  # and beyond it
    ],
)
def test_envelope_in_all_four_quadrants(speed: float, lower: float, upper: float) -> None:
    low, high = DRIVE.torque_bounds(speed)
    assert_allclose([low, high], [lower, upper], rtol=1e-12, atol=1e-12)


def test_scalar_clip_of_the_env_is_the_envelope() -> None:
    peak, span = DRIVE.peak_torque, DRIVE.max_speed - DRIVE.corner_speed
    for speed in np.linspace(-40.0, 40.0, 33):
        lower, upper = DRIVE.torque_bounds(speed)
        for command in (-1000.0, -300.0, -50.0, 0.0, 50.0, 300.0, 1000.0):
            clipped, margin = clip_to_envelope(command, speed, peak, DRIVE.max_speed, span)
            assert clipped == pytest.approx(np.clip(command, lower, upper), abs=1e-9)
            bound = upper if command > 0.0 else -lower if command < 0.0 else min(upper, -lower)
            assert margin == pytest.approx(bound - abs(command), abs=1e-9)


def test_env_clips_a_command_at_speed_to_the_envelope() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    env.reset(seed=0)
    env.plant.assemble(env.plant.joint_angles(), [20.0, -20.0, 5.0])
    _, _, _, _, info = env.step(np.array([390.0, 390.0, -390.0]))
    # Joint 1 motors above the corner: clipped to 266.7 N m; joint 2 brakes and joint 3 is below the corner.
    assert_allclose(info["torque_command"], [FALLEN, 390.0, -390.0], rtol=1e-12)
    assert_allclose(info["torque_margin"], [FALLEN - 390.0, 10.0, 10.0], rtol=1e-9)
    assert info["torque_saturated"]
    assert info["speed_margin"].shape == (3,) and not info["speed_exceeded"]


def test_beyond_the_maximum_speed_the_drive_cannot_push_and_says_so() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    env.reset(seed=0)
    env.plant.assemble(env.plant.joint_angles(), [34.0, 0.0, 0.0])
    _, _, _, _, info = env.step(np.array([100.0, 0.0, 0.0]))
    assert info["torque_command"][0] == 0.0 and info["torque_margin"][0] == pytest.approx(-100.0)
    assert info["speed_exceeded"]
    speed = abs(env.plant.joint_velocities()[0])
    assert speed > DRIVE.max_speed
    assert info["speed_margin"][0] == pytest.approx(DRIVE.max_speed - speed, rel=1e-12)


def test_no_clip_at_rest_within_the_peak() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([150.0, -20.0, 0.0]))
    assert not info["torque_saturated"]
    assert_allclose(info["torque_margin"], [250.0, 380.0, 400.0], rtol=1e-12)


def test_thermal_rms_of_a_constant_torque_and_its_window() -> None:
    """A direct torque source (no lag) so the output is the command; a 10-step window, 100 N m rated."""
    drive = DriveLimits(rated_torque=100.0, thermal_window=0.01)
    env = DeltaPickPlaceEnv(plant=PlantConfig.ideal(drive=drive), n_cycles=1)
    env.reset(seed=0)
    torque = np.array([150.0, -150.0, 150.0])
    for step in range(1, 11):
        _, _, _, _, info = env.step(torque)
        assert_allclose(info["applied_torque"], torque, rtol=1e-12)
        assert_allclose(info["thermal_rms"], 150.0, rtol=1e-12)  # since the reset while shorter than the window
        assert_allclose(info["thermal_margin"], -50.0, rtol=1e-9)
        assert info["thermal_exceeded"] == (step == 10)  # only once a full window has elapsed
    for step in range(1, 7):  # the window forgets the old torque: RMS 150 sqrt((10 - step) / 10)
        _, _, _, _, info = env.step(np.zeros(3))
        assert_allclose(info["thermal_rms"], 150.0 * math.sqrt((10 - step) / 10), rtol=1e-9)
        assert info["thermal_exceeded"] == (step <= 5)  # 106 N m after 5 steps, 95 N m after 6
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.full(3, 30.0))
    assert_allclose(info["thermal_rms"], 30.0, rtol=1e-12)  # the reset forgets the history


def test_non_default_drive_round_trips_and_is_another_robot(tmp_path) -> None:
    drive = DriveLimits(peak_torque=300.0, rated_torque=90.0, corner_speed=12.0, max_speed=25.0, thermal_window=2.0)
    nominal = preset("nominal")
    scenario = Scenario(name="small-drive", plant=PlantConfig(drive=drive))
    text = scenario.to_toml()
    assert "[plant.drive]" in text and "peak_torque = 300.0" in text
    loaded = Scenario.load(scenario.save(tmp_path / "small-drive.toml"))
    assert loaded == scenario and loaded.plant.drive == drive
    assert loaded.robot_identity != nominal.robot_identity
    assert loaded.content_hash == scenario.content_hash
    # The default drive written out is the nominal robot, and a scenario file may leave it out.
    assert Scenario.from_toml(nominal.to_toml()).robot_identity == nominal.robot_identity
    env = DeltaPickPlaceEnv(scenario=loaded, n_cycles=1)
    assert env.action_space.high.tolist() == [300.0] * 3
    assert_allclose(env.plant.model.actuator_ctrlrange, [[-300.0, 300.0]] * 3)


def test_bad_drive_fields_name_the_field() -> None:
    text = "[plant.drive]\nmax_speed = 10.0\n"  # below the 15 rad/s corner
    with pytest.raises(ValueError, match=r"plant\.drive: max_speed must be a finite number in \(15"):
        Scenario.from_toml(text)
    with pytest.raises(ValueError, match="drive must be a DriveLimits"):
        PlantConfig(drive=400.0)
