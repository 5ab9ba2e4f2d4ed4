"""DeltaPickPlace-v0: API checkers, determinism, hidden payload, bad input, divergence, rendering."""

import logging

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from numpy.testing import assert_allclose, assert_array_equal

import delta_env
from delta_env import DeltaPickPlaceEnv, RandomizationRanges
from delta_env.cycles import PLACE_ZONE
from delta_env.sensors import encoder_resolution
from tests.conftest import pd_episode


@pytest.fixture(scope="module")
def env() -> DeltaPickPlaceEnv:
    return DeltaPickPlaceEnv(n_cycles=1)


def test_registered_with_gymnasium() -> None:
    made = gym.make("DeltaPickPlace-v0", n_cycles=1)
    assert isinstance(made.unwrapped, DeltaPickPlaceEnv)
    assert made.action_space.high[0] == delta_env.TORQUE_LIMIT


def test_gymnasium_env_checker(env: DeltaPickPlaceEnv) -> None:
    gym_check_env(env, skip_render_check=True)


def test_stable_baselines3_env_checker(env: DeltaPickPlaceEnv) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    sb3_check_env(env, warn=True)


def test_same_seed_same_rollout(env: DeltaPickPlaceEnv) -> None:
    first, second = pd_episode(env, 3, max_steps=400), pd_episode(env, 3, max_steps=400)
    for a, b in zip(first, second, strict=True):
        for key in a.observation:
            assert_array_equal(a.observation[key], b.observation[key])
        assert a.reward == b.reward
        assert_array_equal(a.info["platform_position"], b.info["platform_position"])


def test_different_seeds_differ(env: DeltaPickPlaceEnv) -> None:
    first, _ = env.reset(seed=1)
    second, _ = env.reset(seed=2)
    assert not np.array_equal(first["reference_angles"], second["reference_angles"])


def test_payload_mass_changes_nothing_but_the_physics(env: DeltaPickPlaceEnv) -> None:
    """Same seed, different masses: same first observation and reference, then different motion."""
    light, _ = env.reset(seed=5, options={"payload_masses": [0.2]})
    heavy, _ = env.reset(seed=5, options={"payload_masses": [3.9]})
    for key in light:
        assert_array_equal(light[key], heavy[key])
    steps = len(env.trajectory) - 1
    light_run = pd_episode(env, 5, {"payload_masses": [0.2]}, max_steps=steps)
    heavy_run = pd_episode(env, 5, {"payload_masses": [3.9]}, max_steps=steps)
    assert light_run[-1].info["cycle"] == 0
    carrying = [i for i, step in enumerate(heavy_run) if step.info["payload_mass"] > 0.0]
    assert carrying, "the object is never carried"
    assert heavy_run[carrying[0]].info["payload_mass"] == pytest.approx(3.9)
    late = carrying[len(carrying) // 2]
    assert not np.array_equal(
        light_run[late].observation["joint_torques"], heavy_run[late].observation["joint_torques"]
    )


def test_observation_carries_no_payload_truth(env: DeltaPickPlaceEnv) -> None:
    observation, _ = env.reset(seed=0)
    assert set(observation) == {
        "joint_angles",
        "joint_velocities",
        "joint_torques",
        "reference_angles",
        "reference_velocities",
        "reference_accelerations",
        "gripper",
    }


def test_encoder_quantizes_angles(env: DeltaPickPlaceEnv) -> None:
    observation, _ = env.reset(seed=0)
    counts = observation["joint_angles"] / (2.0 * np.pi / 2**17)
    assert_array_equal(counts, np.round(counts))


def test_an_episode_starts_at_rest_at_a_place_point_and_picks_after_an_empty_move(env: DeltaPickPlaceEnv) -> None:
    assert env.start == "place"  # the default
    observation, info = env.reset(seed=4)
    trajectory = env.trajectory
    step = encoder_resolution(env.plant_config.realism.encoder_bits)
    assert_allclose(observation["joint_angles"], trajectory.theta[0], rtol=0, atol=0.5 * step * (1.0 + 1e-9))
    assert_array_equal(observation["reference_angles"], trajectory.theta[0])
    assert_array_equal(observation["reference_velocities"], 0.0)
    assert_array_equal(observation["reference_accelerations"], 0.0)
    assert_array_equal(observation["gripper"], [0.0])
    platform = env.plant.platform_position()
    assert_allclose(platform, trajectory.xyz[0], rtol=0, atol=1e-9)
    assert PLACE_ZONE.y_range[0] <= platform[1] <= PLACE_ZONE.y_range[1]  # not at the pick point
    # follow the empty move: nothing is held until the gripper closes at the first pick point (later than planned
    # by the wait for the in-position signal, which PD alone never gives: the time-out)
    first_pick = int(trajectory.pick_indices[0]) + round(env.release.settle_timeout / env.dt)
    records = pd_episode(env, 4, max_steps=first_pick)
    assert env.trajectory.pick_indices[0] == first_pick and env.settles[0].timed_out
    assert all(s.observation["gripper"][0] == 0.0 and s.info["payload_mass"] == 0.0 for s in records[:-1])
    _, observation, step_info, _ = records[-1]
    assert observation["gripper"][0] == 1.0 and step_info["payload_mass"] == info["payload_masses"][0]
    # PD alone: within millimetres of the pick point after a move of decimetres
    assert np.linalg.norm(step_info["platform_position"] - env.trajectory.xyz[first_pick]) < 5e-3


def test_pick_start_shares_the_points_and_masses_and_starts_at_the_first_pick(env: DeltaPickPlaceEnv) -> None:
    from_pick = DeltaPickPlaceEnv(n_cycles=1, start="pick")
    assert from_pick.start == "pick"
    _, info = env.reset(seed=6)
    observation, pick_info = from_pick.reset(seed=6)
    assert_array_equal(pick_info["payload_masses"], info["payload_masses"])
    place_run, pick_run = env.trajectory, from_pick.trajectory
    for name in ("pick_indices", "place_indices"):
        assert_array_equal(pick_run.xyz[getattr(pick_run, name)], place_run.xyz[getattr(place_run, name)])
    assert_allclose(pick_run.xyz[0], pick_run.xyz[pick_run.pick_indices[0]], rtol=0, atol=1e-12)
    assert_allclose(from_pick.plant.platform_position(), pick_run.xyz[0], rtol=0, atol=1e-9)
    assert_array_equal(observation["gripper"], [0.0])  # it closes half a dwell later


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.array([np.nan, 0.0, 0.0]), "nan"),
        (np.array([0.0, np.inf, 0.0]), "inf"),
        (np.array([0.0, 0.0]), r"shape \(2,\)"),
        (["1.0", "2.0", "3.0"], "'1.0'"),
        (np.array(["1.0", "2.0", "3.0"]), "'1.0'"),
        ([True, False, True], "True"),
        (np.array([1 + 2j, 0.0, 0.0]), r"1\.\+2\.j"),
        ([1.0, [2.0, 3.0], 4.0], r"\[2\.0, 3\.0\]"),
        (np.array([1.0, None, 0.0], dtype=object), "None"),
        ("abc", "'abc'"),
    ],
)
def test_bad_action_raises(env: DeltaPickPlaceEnv, action: object, message: str) -> None:
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be 3 finite real motor torques \(N m\), got .*" + message):
        env.step(action)


@pytest.mark.parametrize(
    "action",
    [
        np.array([1.0, -2.0, 3.0]),
        [1.0, -2.0, 3.0],
        [1, -2, 3],
        np.array([1, -2, 3], dtype=np.int32),
        np.array([1.0, -2.0, 3.0], dtype=np.float32),
        np.array([1, 2, 3], dtype=np.uint8),
    ],
)
def test_real_actions_of_any_numeric_kind_step_alike(action: object) -> None:
    """Integer and floating actions are accepted and step exactly as the float64 array of the same values."""
    results = []
    for given in (action, np.asarray(action, dtype=float)):
        env = DeltaPickPlaceEnv(n_cycles=1, cycle="standard")
        env.reset(seed=0)
        observation, reward, *_ = env.step(given)
        results.append((observation["joint_angles"].tolist(), reward))
        env.close()
    assert results[0] == results[1]


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"payload_masses": [1.0, 2.0]}, "one mass per pick"),
        ({"payload_masses": [-1.0]}, "must lie in"),
        (
            {"payload_masses": ["a"]},
            r"must hold numbers, the object masses in kg, one per pick \(1\), each in \[0, 20.0\], got \['a'\]",
        ),
        ({"payload": 1.0}, "unknown reset options"),
        ({"reference": "25/305/25"}, "Trajectory"),
    ],
)
def test_bad_reset_options_raise(env: DeltaPickPlaceEnv, options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options=options)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_cycles": 0}, "n_cycles"),
        ({"cycle": "adept"}, "cycle"),
        ({"start": "home"}, "start must be 'place' or 'pick', got 'home'"),
        ({"payload_mass_range": (2.0, 1.0)}, "payload_mass_range"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"n_cycles": True}, "n_cycles must be an integer >= 1, got True"),
        ({"peak_acceleration": 0.0}, r"peak_acceleration must be a finite number in \(0, 294.3\] m/s\^2, got 0.0"),
        ({"peak_acceleration": 981.0}, r"peak_acceleration must be a finite number in \(0, 294.3\] m/s\^2, got 981.0"),
        ({"payload_mass_range": (0.0, 25.0)}, r"payload_mass_range must be a pair 0 <= min <= max <= 20 kg"),
        ({"plant": "realistic"}, "plant must be a PlantConfig, got str"),
        ({"divergence_penalty": -1.0}, "divergence_penalty"),
        ({"width": 0}, "width must be an integer >= 1"),
    ],
)
def test_bad_constructor_arguments_raise(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DeltaPickPlaceEnv(**kwargs)


def test_human_rendering_without_a_display_is_a_python_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(RuntimeError, match=r"no display \(neither DISPLAY nor WAYLAND_DISPLAY is set\).*rgb_array"):
        DeltaPickPlaceEnv(render_mode="human")


def test_torque_beyond_limit_is_saturated_and_flagged(env: DeltaPickPlaceEnv) -> None:
    env.reset(seed=0)
    action = np.array([1000.0, 0.0, -1000.0])
    _, _, _, _, info = env.step(action)
    assert info["torque_saturated"]
    assert np.all(np.abs(env.plant.data.ctrl) <= delta_env.TORQUE_LIMIT)
    limit = delta_env.TORQUE_LIMIT
    assert_array_equal(info["torque_command"], [limit, 0.0, -limit])  # the command the drive held, not the action
    action = np.array([5.0, -3.0, 1.0])
    _, _, _, _, info = env.step(action)
    assert not info["torque_saturated"]
    action[:] = 0.0  # the caller's array is free to change: info holds a copy
    assert_array_equal(info["torque_command"], [5.0, -3.0, 1.0])


def test_divergence_terminates_with_flag_and_finite_observation(tmp_path, monkeypatch, caplog) -> None:
    monkeypatch.chdir(tmp_path)
    env = DeltaPickPlaceEnv(n_cycles=1)  # fresh: a blow-up in the first step of the first episode counts too
    observation, _ = env.reset(seed=0)
    env.plant.data.qvel[:] = 1e12  # a blow-up, as a far too stiff controller would cause
    with caplog.at_level(logging.WARNING, logger="delta_env.plant"):
        observation, reward, terminated, _, info = env.step(np.zeros(3))
    assert terminated and info["diverged"]
    assert np.isfinite(reward)
    assert all(np.all(np.isfinite(value)) for value in observation.values())
    # MuJoCo's warning goes to the package's logger, not into a MUJOCO_LOG.TXT in the working directory
    assert "MuJoCo: Nan, Inf or huge value in QVEL" in caplog.text
    assert list(tmp_path.iterdir()) == []


def test_episode_truncates_at_end_of_reference_and_refuses_further_steps() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, cycle="standard")
    records = pd_episode(env, 0)
    assert len(records) == len(env.trajectory) - 1
    assert max(step.info["loop_gap"] for step in records) < 4e-6  # measured 2.6 um
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\): the episode has ended"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    env.step(np.zeros(3))


def test_step_after_divergence_or_before_reset_raises() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    with pytest.raises(RuntimeError, match="no episode started"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    env.plant.data.qvel[:] = 1e12
    _, _, terminated, _, _ = env.step(np.zeros(3))
    assert terminated
    with pytest.raises(RuntimeError, match="the episode has ended"):
        env.step(np.zeros(3))


def test_dt_is_the_control_period_of_one_step(env: DeltaPickPlaceEnv) -> None:
    """Gymnasium MuJoCo convention: dt = physics timestep x substeps, the time one step advances."""
    assert env.dt == env.n_substeps * env.plant.model.opt.timestep == delta_env.CONTROL_PERIOD
    env.reset(seed=0)
    env.step(np.zeros(3))
    assert env.plant.data.time == pytest.approx(env.dt, abs=1e-15)
    coarse = DeltaPickPlaceEnv(n_cycles=1, plant=delta_env.PlantConfig(timestep=0.001))
    assert coarse.n_substeps == 1 and coarse.dt == delta_env.CONTROL_PERIOD


@pytest.mark.usefixtures("opengl_context")
def test_rgb_array_render_returns_an_image() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, render_mode="rgb_array", width=96, height=64)
    try:
        env.reset(seed=0)
        image = env.render()
    finally:
        env.close()
    assert image.shape == (64, 96, 3) and image.dtype == np.uint8
    assert image.std() > 5.0, "the frame is blank"


@pytest.mark.usefixtures("opengl_context")
def test_the_default_frame_is_960_by_720_and_the_largest_fits_the_offscreen_buffer() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, render_mode="rgb_array")
    try:
        env.reset(seed=0)
        assert env.render().shape == (720, 960, 3)
    finally:
        env.close()
    assert (env.plant.model.vis.global_.offwidth, env.plant.model.vis.global_.offheight) == (1280, 720)


def test_domain_randomization_draws_a_plant_per_seeded_episode() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, domain_randomization=RandomizationRanges())
    env.reset(seed=1)
    first = env.plant.parameters
    env.reset(seed=2)
    assert env.plant.parameters != first
    records = pd_episode(env, 1, max_steps=300)
    assert env.plant.parameters == first
    assert first != env.plant.nominal_parameters
    assert not any(step.info["diverged"] for step in records)
