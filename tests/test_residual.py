"""The residual env, controller, policy files and training CLI (controllers.residual, eval.residual.__main__)."""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import os
import pickle
import warnings
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

pytest.importorskip("stable_baselines3", reason="the residual policy needs the rl extra (stable-baselines3)")

from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.env_checker import check_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

import controllers  # noqa: F401  (registers DeltaPickPlaceResidual-v0)
import delta_env  # noqa: F401  (registers DeltaPickPlace-v0)
from controllers.dynamics import ModelParameters
from controllers.feedforward import LagCompensatedController, model_controller
from controllers.residual import (
    DEFAULT_POLICY_PATH,
    DeltaResidualEnv,
    PolicyBase,
    ResidualConfig,
    ResidualController,
    ResidualFeatures,
    load_residual_controller,
    load_residual_policy,
    read_policy_metadata,
    read_policy_settings,
    save_residual_policy,
    shipped_base_setup,
)
from controllers.residual.actor import model_actor, read_actor
from controllers.residual.features import PREVIOUS_ACTION
from controllers.residual.policy_file import METADATA_NAME
from controllers.setup import ControllerSetup
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import preset
from eval.comparison.plots import LEARNING_CURVE_FILE
from eval.residual.__main__ import parse_args
from eval.residual.envs import (
    CALIBRATION_SEEDS,
    TRAINING_SEEDS,
    VALIDATION_SEEDS,
    EpisodeSeeds,
    ScenarioMixture,
    base_setup,
    make_env,
)
from eval.residual.hyperparameters import load_hyperparameters, override_hyperparameters
from eval.residual.resume import relabel_action_rate, resume_mismatch, reward_change, trained_config
from eval.residual.scoring import TEST_SEEDS
from eval.residual.training import train
from eval.run_folder import read_csv_rows
from tests.conftest import NOMINAL_SETUP, run_python

# Close to what identification finds on the default plant; fixed here so tests need no parameter file.
PARAMETERS = ModelParameters(rho1=1.76, rho2=0.88, viscous=(2.0, 2.4, 1.7), coulomb=(4.1, 3.4, 4.5))
SEED = 3
CONTROL_STEPS = 400


def policy_base(tare: float = 0.0, key: str = "mid_f_rls") -> PolicyBase:
    """A base row with fixed parameters (MId+F+R + RLS by default) and ``tare`` (kg)."""
    setup = ControllerSetup(
        mid=PARAMETERS, mid_f=PARAMETERS, mid_f_rods=PARAMETERS, drive_lag=(0.001, 0.001, 0.001), tares={key: tare}
    )
    return PolicyBase(key, setup)


def make_base():
    """The default base controller (MId+F+R + RLS) with fixed parameters."""
    return policy_base().controller()


def linear_policy(observation: np.ndarray) -> np.ndarray:
    """A fixed, non-trivial policy: every feature matters, actions stay inside (-1, 1)."""
    weights = np.sin(np.arange(3 * ResidualFeatures.size, dtype=np.float32)).reshape(3, ResidualFeatures.size)
    return np.tanh(0.1 * weights @ observation)


def zero_policy(observation: np.ndarray) -> np.ndarray:
    return np.zeros(3, dtype=np.float32)


def controller_rollout(controller, steps: int = CONTROL_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Commanded torques (N m) and tracking errors (m) of a Controller in a fresh plant env."""
    env = DeltaPickPlaceEnv(n_cycles=1)
    observation, _ = env.reset(seed=SEED)
    controller.reset()
    torques, errors = [], []
    for _ in range(steps):
        torque = controller(observation)
        observation, _, terminated, truncated, info = env.step(torque)
        torques.append(torque)
        errors.append(info["tracking_error"])
        assert not (terminated or truncated)
    return np.array(torques), np.array(errors)


def residual_env_rollout(policy, config: ResidualConfig, steps: int = CONTROL_STEPS):
    """Commanded and base torques (N m) and tracking errors (m) of the residual env (fresh) driven by ``policy``."""
    env = DeltaResidualEnv(base=make_base(), config=config, n_cycles=1)
    observation, _ = env.reset(seed=SEED)
    torques, base_torques, errors = [], [], []
    while sum(len(e) for e in errors) < steps:
        observation, _, terminated, truncated, info = env.step(policy(observation))
        torques.append(info["commanded_torques"])
        base_torques.append(info["base_torques"])
        errors.append(info["tracking_errors"])
        assert not (terminated or truncated)
    return np.concatenate(torques)[:steps], np.concatenate(base_torques)[:steps], np.concatenate(errors)[:steps]


def test_zero_action_reproduces_the_base_controller_exactly() -> None:
    base_torques, base_errors = controller_rollout(make_base())
    env_torques, _, env_errors = residual_env_rollout(zero_policy, ResidualConfig())
    assert_array_equal(env_torques, base_torques)
    assert_array_equal(env_errors, base_errors)
    controller = ResidualController(make_base(), zero_policy, ResidualConfig())
    controller_torques, controller_errors = controller_rollout(controller)
    assert_array_equal(controller_torques, base_torques)
    assert_array_equal(controller_errors, base_errors)


@pytest.mark.parametrize("action_period", [1, 7])
def test_controller_runs_the_same_loop_as_the_env(action_period: int) -> None:
    config = ResidualConfig(residual_limit=20.0, action_period=action_period)
    env_torques, env_base_torques, env_errors = residual_env_rollout(linear_policy, config)
    controller = ResidualController(make_base(), linear_policy, config)
    torques, errors = controller_rollout(controller)
    assert_array_equal(torques, env_torques)
    assert_array_equal(errors, env_errors)
    residual = env_torques - env_base_torques
    assert np.max(np.abs(residual)) > 1.0, "the policy should change the torques"
    assert np.max(np.abs(residual)) <= config.residual_limit + 1e-9
    # Held between policy steps: constant within each window of action_period control steps.
    windows = residual.reshape(-1, action_period, 3) if CONTROL_STEPS % action_period == 0 else None
    if windows is None:
        windows = residual[: CONTROL_STEPS // action_period * action_period].reshape(-1, action_period, 3)
    assert np.allclose(windows, windows[:, :1], rtol=0.0, atol=1e-9)
    env = DeltaResidualEnv(base=make_base(), config=config, n_cycles=1)
    env.reset(seed=SEED)
    _, _, _, _, info = env.step(np.array([0.5, -1.0, 0.25], dtype=np.float32))
    assert info["control_steps"] == action_period
    expected = np.tile([10.0, -20.0, 5.0], (action_period, 1))
    assert_allclose(info["commanded_torques"] - info["base_torques"], expected, rtol=0.0, atol=1e-9)


class RestRecorder:
    """Runs ``controller`` and records, per control step, whether the observation's reference was at rest."""

    def __init__(self, controller: ResidualController) -> None:
        self.controller, self.at_rest = controller, []

    def reset(self) -> None:
        self.controller.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        self.at_rest.append(not observation["reference_velocities"].any())
        return self.controller(observation)


def test_off_at_rest_leaves_the_stops_to_the_base_in_the_env_and_the_controller_alike() -> None:
    steps = 800  # the start at rest, the empty move to the first pick, the stop there and part of the carry
    config = ResidualConfig(residual_limit=20.0, off_at_rest=True)
    env_torques, env_base_torques, _ = residual_env_rollout(linear_policy, config, steps)
    recorder = RestRecorder(ResidualController(make_base(), linear_policy, config))
    torques, _ = controller_rollout(recorder, steps)
    assert_array_equal(torques, env_torques)
    residual = np.abs(env_torques - env_base_torques).max(axis=1)
    at_rest = np.array(recorder.at_rest)
    assert 20 < at_rest.sum() < steps - 300, at_rest.sum()
    assert np.all(residual[at_rest] == 0.0) and np.all(residual[~at_rest] > 0.0)
    with pytest.raises(ValueError, match="off_at_rest must be true or false"):
        ResidualConfig(off_at_rest=1)


class TorqueRecorder:
    """Runs ``controller`` and records its torques (N m) and the observations' fastest reference joint rate (rad/s)."""

    def __init__(self, controller: ResidualController) -> None:
        self.controller, self.torques, self.speeds = controller, [], []

    def reset(self) -> None:
        self.controller.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        self.speeds.append(float(np.max(np.abs(observation["reference_velocities"]))))
        self.torques.append(self.controller(observation))
        return self.torques[-1]


def test_fade_speed_ramps_the_residual_down_with_the_reference_in_the_env_and_the_controller_alike() -> None:
    steps, fade_speed = 800, 0.5
    config = ResidualConfig(residual_limit=20.0, fade_speed=fade_speed)
    env_torques, env_base_torques, _ = residual_env_rollout(linear_policy, config, steps)
    controller = ResidualController(make_base(), linear_policy, config)
    held = []
    recorder = TorqueRecorder(controller)
    env = DeltaPickPlaceEnv(n_cycles=1)
    observation, _ = env.reset(seed=SEED)
    recorder.reset()
    for _ in range(steps):
        observation = env.step(recorder(observation))[0]
        held.append(controller.residual_torque)
    assert_array_equal(np.array(recorder.torques), env_torques)
    residual = env_torques - env_base_torques
    speeds = np.array(recorder.speeds)
    gain = np.minimum(1.0, speeds / fade_speed)
    assert_allclose(residual, gain[:, None] * np.array(held), atol=1e-9)
    fading = (speeds > 0.0) & (speeds < fade_speed)
    assert 10 < fading.sum() < 200 and np.any(speeds == 0.0), (fading.sum(), speeds.min())
    assert np.all(residual[speeds == 0.0] == 0.0)
    # the arrival: the residual shrinks over the last steps of the move instead of stopping at once
    assert np.abs(residual[fading]).max() < np.abs(np.array(held)[fading]).max()
    with pytest.raises(ValueError, match="fade_speed"):
        ResidualConfig(fade_speed=-1.0)


def test_torque_weight_adds_to_the_plant_envs_torque_term() -> None:
    weight, scale = 2e-4, 0.5
    plain, charged = (
        DeltaResidualEnv(base=make_base(), config=ResidualConfig(reward_scale=scale, torque_weight=w), n_cycles=1)
        for w in (0.0, weight)
    )
    observations = [env.reset(seed=SEED)[0] for env in (plain, charged)]
    for _ in range(20):
        action = linear_policy(observations[0])
        (observation, reward, _, _, info), (_, charged_reward, _, _, charged_info) = (
            env.step(action) for env in (plain, charged)
        )
        observations = [observation, observation]
        extra = -scale * weight * np.sum(info["commanded_torques"] ** 2)
        assert extra < -1e-3
        assert charged_info["reward_torque"] == pytest.approx(info["reward_torque"] + extra, rel=1e-12)
        assert charged_reward == pytest.approx(reward + extra, rel=1e-12)
        assert charged_info["reward_tracking"] == info["reward_tracking"]


def test_plant_torque_weight_replaces_the_plant_envs_torque_term() -> None:
    envs = [
        DeltaResidualEnv(base=make_base(), config=ResidualConfig(plant_torque_weight=w), n_cycles=1)
        for w in (1e-5, 0.0)
    ]
    assert [env.plant_env.reward_weights.torque for env in envs] == [1e-5, 0.0]
    for env in envs:
        env.reset(seed=SEED)
    action = np.full(3, 0.2, dtype=np.float32)
    for _ in range(20):
        (_, reward, _, _, info), (_, tracking_only, _, _, tracking_info) = (env.step(action) for env in envs)
        torques = info["commanded_torques"]
        assert info["reward_torque"] == pytest.approx(-1e-5 * np.sum(torques**2), rel=1e-6)
        assert info["reward_torque"] < -1e-3 and reward == pytest.approx(
            info["reward_tracking"] + info["reward_torque"]
        )
        assert tracking_info["reward_torque"] == 0.0 and tracking_only == tracking_info["reward_tracking"]
        assert tracking_info["reward_tracking"] == info["reward_tracking"]  # the same episode, the same torques
    with pytest.raises(ValueError, match="plant_torque_weight"):
        DeltaResidualEnv(base=make_base(), config=ResidualConfig(plant_torque_weight=0.0), env=DeltaPickPlaceEnv())
    assert ResidualConfig.from_dict({"residual_limit": 15.0}).plant_torque_weight == 1e-5  # files before it


def test_action_rate_weight_charges_the_squared_change_of_the_residual_torque() -> None:
    weight, scale = 3e-3, 0.5
    config = ResidualConfig(residual_limit=15.0, reward_scale=scale, action_rate_weight=weight)
    envs = [
        DeltaResidualEnv(base=make_base(), config=dataclasses.replace(config, action_rate_weight=w), n_cycles=1)
        for w in (0.0, weight)
    ]
    for env in envs:
        env.reset(seed=SEED)
    # Residuals (N m) of 15 * a: (6, -3, 0) from zero, then (-3, 0, 12): squared changes 36 + 9 + 0 = 45 (N m)^2,
    # then 81 + 9 + 144 = 234 (N m)^2.
    actions = [np.array([0.4, -0.2, 0.0], dtype=np.float32), np.array([-0.2, 0.0, 0.8], dtype=np.float32)]
    for action, squared_change in zip(actions, (45.0, 234.0), strict=True):
        (_, reward, _, _, info), (_, charged_reward, _, _, charged_info) = (env.step(action) for env in envs)
        assert info["reward_action_rate"] == 0.0
        assert charged_info["reward_action_rate"] == pytest.approx(-scale * weight * squared_change, rel=1e-6)
        assert charged_reward == pytest.approx(reward + charged_info["reward_action_rate"], rel=1e-12)
        assert charged_info["reward_tracking"] == info["reward_tracking"]
        assert charged_info["reward_torque"] == info["reward_torque"]


def test_a_constant_zero_action_costs_no_action_rate() -> None:
    env = DeltaResidualEnv(base=make_base(), config=ResidualConfig(action_rate_weight=1.0), n_cycles=1)
    observation, _ = env.reset(seed=SEED)
    for _ in range(10):
        observation, _, _, _, info = env.step(np.zeros(3, dtype=np.float32))
        assert info["reward_action_rate"] == 0.0
        assert_array_equal(observation[PREVIOUS_ACTION], 0.0)


def test_relabelling_a_replay_buffer_gives_the_rewards_of_the_new_action_rate_weight() -> None:
    """Transitions of one episode and action sequence, stored under one weight and relabelled for another, carry
    the rewards the env gives under the other (the episode is the same: the term does not act on the plant)."""
    old, new = ResidualConfig(action_rate_weight=2e-3), ResidualConfig(action_rate_weight=5e-3)
    buffers = {}
    for config in (old, new):
        env = DeltaResidualEnv(base=make_base(), config=config, n_cycles=1)
        buffer = ReplayBuffer(40, env.observation_space, env.action_space, device="cpu")
        observation, _ = env.reset(seed=SEED)
        for step in range(30):
            action = np.float32(0.9) * np.cos(np.arange(3, dtype=np.float32) + step).astype(np.float32)
            next_observation, reward, _, _, info = env.step(action)
            buffer.add(observation, next_observation, action, np.array([reward]), np.array([False]), [info])
            observation = next_observation
        buffers[config] = buffer
    assert np.max(np.abs(buffers[old].rewards[:30] - buffers[new].rewards[:30])) > 0.1
    relabel_action_rate(buffers[old], old, new)
    assert_allclose(buffers[old].rewards[:30], buffers[new].rewards[:30], rtol=1e-5, atol=1e-5)
    assert_array_equal(buffers[old].rewards[30:], 0.0)
    with pytest.raises(ValueError, match="only action_rate_weight"):
        relabel_action_rate(buffers[new], new, dataclasses.replace(new, action_rate_weight=0.0, torque_weight=1e-4))


def test_sb3_check_env_passes_without_warnings() -> None:
    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, warn=True)


def test_gymnasium_env_checker_including_reset_determinism() -> None:
    from gymnasium.utils.env_checker import check_env as gym_check_env

    gym_check_env(DeltaResidualEnv(base=make_base(), n_cycles=1), skip_render_check=True)


def test_gym_make_and_spaces() -> None:
    env = gym.make("DeltaPickPlaceResidual-v0", base=make_base(), n_cycles=1)
    observation, info = env.reset(seed=0)
    assert observation.dtype == np.float32 and observation.shape == (ResidualFeatures.size,)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    assert env.observation_space.contains(observation)
    assert len(info["payload_masses"]) == 1
    _, reward, _, _, info = env.step(env.action_space.sample())
    assert_policy_step_reward(reward, info)
    env.close()


def assert_policy_step_reward(reward: float, info: dict) -> None:
    """The policy step's reward is the plant env's -(w_e |e|^2 + w_tau |tau|^2) summed over its control steps, e in
    mm (w_e = 1 per mm^2, w_tau = 1e-5 per (N m)^2), and the sum of the two terms in ``info``."""
    assert info["reward_tracking"] == pytest.approx(-np.sum((1e3 * info["tracking_errors"]) ** 2), rel=1e-9)
    assert info["reward_torque"] == pytest.approx(-1e-5 * np.sum(info["commanded_torques"] ** 2), rel=1e-9)
    assert reward == pytest.approx(info["reward_tracking"] + info["reward_torque"], rel=1e-6)  # float32 in a VecEnv


def test_episode_ends_with_the_reference() -> None:
    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    env.reset(seed=SEED)
    steps = 0
    truncated = False
    while not truncated:
        _, _, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32))
        assert not terminated
        steps += info["control_steps"]
    assert steps == len(env.plant_env.trajectory) - 1  # the reference followed, its waits for in position included
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, dtype=np.float32))


@pytest.mark.parametrize("action", [np.zeros(2), np.array([0.0, np.nan, 0.0]), np.array([np.inf, 0.0, 0.0])])
def test_bad_actions_raise(action: np.ndarray) -> None:
    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"residual_limit": 0.0},
        {"residual_limit": 401.0},
        {"action_period": 0},
        {"reward_scale": -1.0},
        {"torque_weight": -1e-4},
        {"action_rate_weight": -1e-3},
        {"action_rate_weight": 2.0},
        {"action_rate_weight": float("nan")},
    ],
)
def test_config_rejects_bad_values(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        ResidualConfig(**kwargs)


def test_a_bad_action_rate_weight_names_the_value_and_the_range(capsys) -> None:
    with pytest.raises(
        ValueError, match=r"action_rate_weight must be a finite number in \[0, 1\] \(N m\)\^-2, got -0\.001"
    ):
        ResidualConfig(action_rate_weight=-1e-3)
    with pytest.raises(SystemExit):
        parse_args(["--action-rate-weight", "-0.001"])
    assert "action_rate_weight must be a finite number in [0, 1] (N m)^-2, got -0.001" in capsys.readouterr().err


def test_vector_envs() -> None:
    config = ResidualConfig()
    base = policy_base()
    factories = [make_env(config=config, env_kwargs={"n_cycles": 1}, base=base, rank=r) for r in range(2)]
    for vec_cls in (DummyVecEnv, SubprocVecEnv):
        vec_env = vec_cls(factories)
        vec_env.seed(0)
        observations = vec_env.reset()
        assert observations.shape == (2, ResidualFeatures.size)
        observations, rewards, dones, infos = vec_env.step(np.zeros((2, 3), dtype=np.float32))
        assert observations.shape == (2, ResidualFeatures.size) and rewards.shape == (2,) and not np.any(dones)
        for reward, info in zip(rewards, infos, strict=True):
            assert_policy_step_reward(float(reward), info)
        seeds = [info["episode_seed"] for info in vec_env.reset_infos]
        assert seeds[0] != seeds[1], "workers must draw different training episodes"
        vec_env.close()


@pytest.mark.slow  # the online carry's table of continuations: about 50 s of a core
def test_training_envs_are_timed_online_on_the_bases_own_estimate() -> None:
    # the residual's training work: the data sheet's cycle timed online, in-position release, randomized plants
    scenario = preset("pick-rate-randomized")
    assert (scenario.task.timing, scenario.task.cycle, scenario.task.release) == ("online", "standard", "in_position")
    env_kwargs = {"n_cycles": 1, "scenario": scenario}
    env = make_env(config=ResidualConfig(), env_kwargs=env_kwargs, base=policy_base(key="mid_f_rls_lag"))().env.env
    plant_env = env.plant_env
    assert plant_env.timing.mode == "online" and plant_env.timing.estimator is env.base.estimator  # no wrapper
    env.reset(seed=SEED)
    planned = len(plant_env.trajectory)
    steps, truncated = 0, False
    while not truncated:
        _, _, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32))
        assert not terminated
        steps += info["control_steps"]
    assert steps == len(plant_env.trajectory) - 1 != planned - 1  # retimed or held in position, and then ended
    assert [settle.kind for settle in plant_env.settles] == ["pick", "place"]
    with pytest.raises(ValueError, match="pass base, not base_factory"):
        make_env(config=ResidualConfig(), env_kwargs=env_kwargs, base=None, base_factory=make_base)()


def test_a_scenario_mixture_runs_each_episode_on_the_scenario_its_seed_picks(tmp_path: Path) -> None:
    randomized = {"n_cycles": 1, "scenario": preset("randomized")}
    seeds = (4, 7, 10)  # nominal, randomized, nominal
    mixed = make_env(
        config=ResidualConfig(), env_kwargs={"n_cycles": 1}, base=None, base_factory=make_base, seeds=seeds,
        mixture=[randomized],
    )()  # fmt: skip
    action = np.full(3, 0.3, dtype=np.float32)
    for seed, index in zip(seeds, (0, 1, 0), strict=True):
        _, info = mixed.reset()
        assert (info["episode_seed"], info["scenario_index"]) == (seed, index)
        alone = DeltaResidualEnv(base=make_base(), **({"n_cycles": 1} if index == 0 else randomized))
        alone.reset(seed=seed)
        for _ in range(30):
            assert_array_equal(mixed.step(action)[4]["tracking_errors"], alone.step(action)[4]["tracking_errors"])
    # the two scenarios' plants differ: the same seed and actions track differently
    errors = []
    for kwargs in ({"n_cycles": 1}, randomized):
        env = DeltaResidualEnv(base=make_base(), **kwargs)
        env.reset(seed=seeds[0])
        errors.append(np.concatenate([env.step(action)[4]["tracking_errors"] for _ in range(30)]))
    assert np.abs(errors[0] - errors[1]).max() > 1e-6
    with pytest.raises(ValueError, match="reset it with a seed"):
        ScenarioMixture([DeltaResidualEnv(base=make_base(), n_cycles=1)]).reset()
    args = parse_args(["--mix", "pick-rate-randomized", "nominal", "--cycles", "2"])
    assert [s.name for s in args.mixture] == ["pick-rate-randomized", "nominal"] and args.mixture_cycles == (2, 2)
    with pytest.raises(SystemExit):
        parse_args(["--mix", "nominal", "--score-only", str(DEFAULT_POLICY_PATH)])
    run = train(tiny_training_args(tmp_path / "mixed", 0, "--mix", "nominal"), base_factory=make_base)
    record = json.loads((run / "config.json").read_text())["config"]
    assert record["mixture"] == [{"n_cycles": 1, "scenario": "nominal"}]
    assert (run / "scenarios" / "nominal.toml").is_file() and (run / "final_policy.zip").is_file()


def test_training_and_held_out_seeds_are_disjoint() -> None:
    env = EpisodeSeeds(DeltaResidualEnv(base=make_base(), n_cycles=1), seed=0, rank=1)
    training = set()
    for _ in range(20):
        _, info = env.reset()
        training.add(info["episode_seed"])
    assert all(s in TRAINING_SEEDS for s in training)
    eval_defaults = set(range(10)) | set(range(100_000, 100_003))  # python -m eval: seeds and tare seeds
    held_out = [set(VALIDATION_SEEDS), set(TEST_SEEDS), set(CALIBRATION_SEEDS), eval_defaults]
    for i, seeds in enumerate(held_out):
        assert not any(s in TRAINING_SEEDS for s in seeds)
        assert all(not seeds & other for other in held_out[i + 1 :])
    held_out = EpisodeSeeds(DeltaResidualEnv(base=make_base(), n_cycles=1), seeds=VALIDATION_SEEDS[:2])
    seeds = [held_out.reset()[1]["episode_seed"] for _ in range(3)]
    held_out.restart()
    seeds.append(held_out.reset()[1]["episode_seed"])
    assert seeds == [VALIDATION_SEEDS[0], VALIDATION_SEEDS[1], VALIDATION_SEEDS[0], VALIDATION_SEEDS[0]]


def tiny_training_args(out: Path, seed: int, *extra: str, timesteps: int = 60, hyperparams: tuple[str, ...] = ()):
    return parse_args(
        [
            "--seed", str(seed), "--timesteps", str(timesteps), "--n-envs", "1", "--cycles", "1",
            "--hyperparams", "learning_starts:30", "batch_size:16", "buffer_size:500", "policy_kwargs.net_arch:[16,16]",
            "train_freq:1",  # steps in multiples of 30, as the checkpoints
            *hyperparams,
            "--eval-freq", "60", "--checkpoint-freq", "30", "--no-progress", "--no-score", "--out", str(out),
            *extra,
        ]
    )  # fmt: skip


def test_seeded_training_is_deterministic_and_resumable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = [train(tiny_training_args(tmp_path / name, seed), base_factory=make_base) for name, seed in
            (("a", 0), ("b", 0), ("c", 1))]  # fmt: skip
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1] == f"Run folder: {runs[-1]}"  # a short summary, the run folder last
    assert printed[-2].startswith("Trained SAC on randomized for 60 steps in ") and "final_policy.zip" in printed[-2]
    policies = [load_residual_policy(run / "final_policy.zip") for run in runs]
    parameters = [policy.model.policy.state_dict() for policy in policies]
    for name, tensor in parameters[0].items():
        assert_array_equal(tensor.numpy(), parameters[1][name].numpy(), err_msg=name)
    assert any(not np.array_equal(t.numpy(), parameters[2][n].numpy()) for n, t in parameters[0].items())
    observations = np.random.default_rng(0).uniform(-2, 2, (8, ResidualFeatures.size)).astype(np.float32)
    assert_array_equal(policies[0](observations), policies[1](observations))
    for name in ("config.json", "progress.csv", "evaluations.npz", "best_policy.zip"):
        assert (runs[0] / name).is_file(), name
    # The learning curve: one row per held-out evaluation, as SB3 saved it, and its figure.
    curve = read_csv_rows(runs[0] / LEARNING_CURVE_FILE)
    with np.load(runs[0] / "evaluations.npz") as evaluations:
        assert [int(row["timesteps"]) for row in curve] == evaluations["timesteps"].tolist() == [60]
        assert float(curve[0]["mean_reward"]) == pytest.approx(evaluations["results"][0].mean())
    assert (runs[0] / "learning_curve.png").is_file()
    assert policies[0].metadata["extra"]["seed"] == 0
    # Resume from the last checkpoint (with its replay buffer, the only one kept) and train further.
    checkpoints = sorted(p.name for p in (runs[0] / "checkpoints").iterdir())
    assert checkpoints == ["residual_30_steps.zip", "residual_60_steps.zip", "residual_replay_buffer_60_steps.pkl"]
    checkpoint = str(runs[0] / "checkpoints" / checkpoints[1])
    args = tiny_training_args(
        tmp_path / "resumed", 0, "--resume", checkpoint, timesteps=90, hyperparams=("learning_rate:0.0005",)
    )
    resumed = train(args, base_factory=make_base)
    model = load_residual_policy(resumed / "final_policy.zip").model
    assert model.num_timesteps == 90
    assert model.learning_rate == 0.0005, "--hyperparams apply to a resumed run"
    written = json.loads((resumed / "config.json").read_text())
    assert written["command"].startswith("python -m eval.residual") and "git_commit" in written
    assert written["config"]["scenario"]["name"] == "randomized", "domain randomization is on by default"
    resumed_from = written["config"]["resumed_from"]
    assert resumed_from["num_timesteps"] == 60
    assert resumed_from["replay_buffer"].endswith("residual_replay_buffer_60_steps.pkl")
    assert resumed_from["hyperparameters_changed"]["learning_rate"] == 0.0005


def test_saved_policy_reloads_with_identical_actions(tmp_path: Path) -> None:
    config = ResidualConfig(residual_limit=25.0, action_period=5)
    base = policy_base(tare=-0.1)
    env = DeltaResidualEnv(base=base.controller(), config=config, n_cycles=1)
    model = SAC("MlpPolicy", env, seed=1, policy_kwargs={"net_arch": [32, 32]}, device="cpu")
    path = save_residual_policy(model, tmp_path / "policy.zip", config, "sac", base=base, extra={"note": "untrained"})
    policy = load_residual_policy(path)
    assert policy.config == config and policy.base == base and policy.metadata["extra"] == {"note": "untrained"}
    observations = np.random.default_rng(1).uniform(-3, 3, (16, ResidualFeatures.size)).astype(np.float32)
    assert_allclose(policy(observations), model.predict(observations, deterministic=True)[0], rtol=0.0, atol=1e-6)
    # Without a base, the controller rebuilds the one stored in the file.
    reloaded = load_residual_controller(path)
    assert reloaded.config == config and reloaded.base.estimator.tare == -0.1
    direct = ResidualController(base.controller(), policy, config)
    torques = controller_rollout(reloaded, 100)[0]
    assert_array_equal(torques, controller_rollout(direct, 100)[0])
    assert not np.array_equal(torques, controller_rollout(base.controller(), 100)[0])


OLD_BASE = {
    "name": "MId+F+R+RLS+lag+PD",
    "parameters": json.loads(json.dumps(dataclasses.asdict(PARAMETERS))),  # as read from a file
    "tare": -0.1,
    "forearm_rods": True,
    "regressor": "smoothed",
    "friction_velocity": 1.0,
    "geometry": {"ra": 0.2, "rb": 0.05, "l1": 0.37, "l2": 0.95},
    "masses": {"m1": 2.0, "m2": 0.2, "m0": 0.8},
    "drive_lag": [1e-3, 1.2e-3, 0.9e-3],
}
"""A base as the policy files before the setup record held it (a separate record of its own)."""


def test_an_old_policy_file_loads_and_rebuilds_the_same_base(tmp_path: Path) -> None:
    config = ResidualConfig()
    model = SAC("MlpPolicy", DeltaResidualEnv(base=make_base(), n_cycles=1), seed=0, policy_kwargs={"net_arch": [8]})
    path = save_residual_policy(model, tmp_path / "old.zip", config, "sac")
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    metadata = json.loads(members[METADATA_NAME])
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, json.dumps({**metadata, "base": OLD_BASE}) if name == METADATA_NAME else data)
    base = load_residual_policy(path).base
    assert base.key == "mid_f_rls_lag" and base.name == OLD_BASE["name"]
    assert base.setup.tares == {"mid_f_rls_lag": -0.1} and base.setup.mid_f_rods == PARAMETERS
    # The controller the old record built, with the same arguments.
    old = model_controller(
        PARAMETERS, forearm_rods=True, regressor="smoothed", tare=-0.1, drive_lag=OLD_BASE["drive_lag"]
    )
    assert_array_equal(controller_rollout(base.controller(), 200)[0], controller_rollout(old, 200)[0])
    # Without a lag it was the row without the lead, with the reference regressor the (ref) row.
    assert PolicyBase.from_table({**OLD_BASE, "drive_lag": None}).key == "mid_f_rls"
    assert PolicyBase.from_table({**OLD_BASE, "regressor": "reference"}).key == "mid_f_rls_ref"


def test_a_base_no_row_of_this_version_builds_is_refused_with_the_reason() -> None:
    legacy = {"name": "MId+F+RLS+PD", "parameters": dataclasses.asdict(PARAMETERS), "tare": -0.1}
    with pytest.raises(ValueError, match=r"forearm_rods=False, regressor 'filtered'.*retrain"):
        PolicyBase.from_table(legacy)
    with pytest.raises(ValueError, match=r"friction band of 0\.3 rad/s"):
        PolicyBase.from_table({**OLD_BASE, "friction_velocity": 0.3})


def test_a_policy_file_stores_the_setup_record_and_checks_its_hash(tmp_path: Path) -> None:
    base = PolicyBase("mid_f_rls_lag", dataclasses.replace(NOMINAL_SETUP, tares={"mid_f_rls_lag": 0.01}))
    table = json.loads(json.dumps(base.to_table()))
    assert table["setup"] == base.setup.to_table() and table["setup_hash"] == base.setup.content_hash()
    assert PolicyBase.from_table(table) == base
    table["setup"]["tares"]["mid_f_rls_lag"] = 0.02
    with pytest.raises(ValueError, match="edited or damaged"):
        PolicyBase.from_table(table)
    with pytest.raises(ValueError, match="a residual's base is one of"):
        PolicyBase("pd", NOMINAL_SETUP)


def test_base_setup_calibrates_a_small_tare() -> None:
    base = base_setup({"n_cycles": 1}, PARAMETERS, base="mid_f_rls", servo="pd")
    assert base.key == "mid_f_rls" and base.setup.mid_f_rods == PARAMETERS and base.setup.drive_lag is None
    # the tare is the model's small error along phi: measured -39 g
    assert 0.0 < abs(base.setup.tares["mid_f_rls"]) < 0.07
    assert "mid_f_rls" in base.setup.empty_moves, "the nominal plant is not randomized: its empty moves are kept"
    assert (
        PolicyBase.from_table(json.loads(json.dumps(base.to_table()))).setup.content_hash() == base.setup.content_hash()
    )
    assert base.controller().name == "MId+F+R+RLS+PD"


def test_lag_base_setup_round_trips_and_leads_the_drive() -> None:
    with pytest.raises(ValueError, match="drive lag"):
        base_setup({"n_cycles": 1}, PARAMETERS)
    base = base_setup({"n_cycles": 1, "scenario": preset("randomized")}, PARAMETERS, (1e-3, 1e-3, 1e-3))
    assert base.setup.drive_lag == (1e-3, 1e-3, 1e-3)
    assert base.setup.empty_moves == {}, "a randomized plant is another robot every episode: no empty moves"
    assert PolicyBase.from_table(base.to_table()) == base
    controller = base.controller()
    assert controller.name == base.name == "MId+F+R+RLS+lag+PD"
    assert isinstance(controller, LagCompensatedController)


def test_missing_or_corrupt_policy_files_raise_naming_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "missing.zip"
    with pytest.raises(FileNotFoundError, match=r"missing\.zip"):
        load_residual_controller(missing, base=make_base())
    garbage = tmp_path / "garbage.zip"
    garbage.write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match=r"garbage\.zip"):
        load_residual_controller(garbage, base=make_base())
    plain = tmp_path / "plain_sb3.zip"
    SAC("MlpPolicy", DeltaResidualEnv(base=make_base(), n_cycles=1), policy_kwargs={"net_arch": [8]}).save(plain)
    with pytest.raises(ValueError, match=r"plain_sb3\.zip"):
        load_residual_controller(plain, base=make_base())
    truncated = tmp_path / "truncated.zip"
    config = ResidualConfig()
    model = SAC("MlpPolicy", DeltaResidualEnv(base=make_base(), n_cycles=1), policy_kwargs={"net_arch": [8]})
    save_residual_policy(model, truncated, config, "sac")
    with zipfile.ZipFile(truncated) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(truncated, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data[: len(data) // 2] if name == "policy.pth" else data)
    with pytest.raises(ValueError, match=r"truncated\.zip"):
        load_residual_controller(truncated, base=make_base())


def test_shipped_policy_loads_and_beats_its_base_on_a_held_out_episode() -> None:
    assert DEFAULT_POLICY_PATH.is_file(), f"the shipped policy is missing: {DEFAULT_POLICY_PATH}"
    assert DEFAULT_POLICY_PATH.stat().st_size < 5_000_000
    policy = load_residual_policy()
    assert policy.algo == "sac" and policy.base is not None
    # Trained on the eval's mid_f_rls_lag row, stored as the setup record (old records: test_an_old_policy_file_...).
    assert policy.base.key == "mid_f_rls_lag" and "setup" in read_policy_metadata()["base"]
    controller = load_residual_controller(name="residual")
    assert controller.name == "residual"
    # A test seed of the training CLI, one cycle: never trained on, never used for model selection.
    env_kwargs = {"n_cycles": 1}
    seed = TEST_SEEDS[-1]
    rms = {}
    for key, candidate in (("base", policy.base.controller()), ("residual", controller)):
        env = DeltaPickPlaceEnv(**env_kwargs)
        observation, _ = env.reset(seed=seed)
        candidate.reset()
        errors = []
        while True:
            observation, _, terminated, truncated, info = env.step(candidate(observation))
            errors.append(info["tracking_error"])
            if terminated or truncated:
                break
        assert not terminated
        rms[key] = float(np.sqrt(np.mean(np.square(errors))))
    assert rms["residual"] < 0.85 * rms["base"], rms


def test_gym_make_runs_the_shipped_base_without_identifying_or_writing_files(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    env = gym.make("DeltaPickPlaceResidual-v0", n_cycles=1)
    residual_env = env.get_wrapper_attr("base")
    shipped = shipped_base_setup()
    assert residual_env.estimator.tare == shipped.setup.tares[shipped.key]
    assert residual_env.dynamics.parameters == shipped.setup.mid_f_rods
    env.reset(seed=0)
    env.step(np.zeros(3, dtype=np.float32))
    env.close()
    assert list(tmp_path.iterdir()) == [], "making and stepping the env wrote files"


def test_residual_env_is_a_wrapper_of_the_plant_env() -> None:
    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    assert isinstance(env, gym.Wrapper) and isinstance(env.unwrapped, DeltaPickPlaceEnv)
    assert env.plant_env is env.env


def test_shipped_base_setup_is_the_policy_files_base() -> None:
    setup = shipped_base_setup()
    assert setup == load_residual_policy(DEFAULT_POLICY_PATH).base
    assert setup.controller().name == "MId+F+R+RLS+lag+PD", "the shipped policy's base leads the drive lag"


def test_policy_settings_are_read_and_the_row_runs_without_torch(tmp_path: Path) -> None:
    # python -m eval checks --residual with these settings in its main process; a worker runs the row on the actor
    # read from the file: neither imports torch.
    code = (
        "import sys; from controllers.residual import read_policy_settings; "
        "settings = read_policy_settings(); assert 'torch' not in sys.modules, 'torch imported'; "
        "from controllers.registry import build_controller; "
        "from delta_env.env import DeltaPickPlaceEnv; from eval.episodes import run_episode; "
        "setup = settings.base.setup; "
        "record = run_episode(DeltaPickPlaceEnv(n_cycles=1), build_controller('residual', setup), 0); "
        "assert 'torch' not in sys.modules, 'torch imported'; "
        "print(settings.algo, settings.base.name, record.metrics()['tracking_rms_mm'] < 0.2)"
    )
    assert run_python(code).split() == ["sac", load_residual_policy().base.name, "True"]
    with zipfile.ZipFile(DEFAULT_POLICY_PATH) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    metadata = json.loads(members[METADATA_NAME])
    for field, value, message in (("feature_version", -1, "feature version"), ("algo", "dqn", "algo")):
        broken = tmp_path / f"{field}.zip"
        with zipfile.ZipFile(broken, "w") as archive:
            for name, data in members.items():
                archive.writestr(name, json.dumps({**metadata, field: value}) if name == METADATA_NAME else data)
        with pytest.raises(ValueError, match=rf"{field}\.zip.*{message}"):
            read_policy_settings(broken)


def test_hyperparameters_come_from_the_toml_file() -> None:
    sac, ppo = load_hyperparameters("sac"), load_hyperparameters("ppo")
    assert sac["gamma"] == ppo["gamma"] == 0.95 and sac["policy_kwargs"] == {"net_arch": [256, 256]}
    assert ppo["policy_kwargs"]["log_std_init"] == -2.0
    sac["gamma"] = 0.5  # a copy: the next read is unchanged
    assert load_hyperparameters("sac")["gamma"] == 0.95
    with pytest.raises(ValueError, match=r"no \[a2c\] table"):
        load_hyperparameters("a2c")


def test_hyperparams_override_any_key_with_toml_values() -> None:
    sac = load_hyperparameters("sac")
    items = ["learning_rate:1e-3", "train_freq:4", "ent_coef:auto_0.1", "policy_kwargs.net_arch:[64, 64]"]
    overridden = override_hyperparameters(sac, items, "sac")
    assert overridden["learning_rate"] == 1e-3 and overridden["train_freq"] == 4
    assert overridden["ent_coef"] == "auto_0.1"
    assert overridden["policy_kwargs"] == {"net_arch": [64, 64]}
    assert sac["policy_kwargs"] == {"net_arch": [256, 256]}, "the loaded table is left as it was"
    whole = override_hyperparameters(sac, ["policy_kwargs:{ net_arch = [8], log_std_init = -1.0 }"], "sac")
    assert whole["policy_kwargs"] == {"net_arch": [8], "log_std_init": -1.0}
    crossq = override_hyperparameters(
        load_hyperparameters("crossq"), ["policy_kwargs.net_arch.qf:[128, 128]"], "crossq"
    )
    assert crossq["policy_kwargs"]["net_arch"] == {"pi": [256, 256], "qf": [128, 128]}
    assert parse_args(["--hyperparams", "gamma:0.9", "batch_size:64"]).hyperparams == ("gamma:0.9", "batch_size:64")


@pytest.mark.parametrize(
    ("items", "algo", "message"),
    [
        (["learning_rate=1e-3"], "sac", r"key:value, got 'learning_rate=1e-3'"),
        (["n_epochs:3"], "sac", r"n_epochs.*not an argument of sac"),
        (["policy_delay:2"], "tqc", r"policy_delay.*not an argument of tqc"),
        (["learning_rate:[1e-3"], "sac", r"learning_rate: '\[1e-3' is not a TOML value"),
        (["gamma:"], "sac", r"key:value"),
        (["gamma.x:1"], "sac", r"gamma.x: 'gamma' is 0.95, not a table"),
        (["ent_coef.a.b:1"], "sac", r"ent_coef.a.b: 'ent_coef' is 'auto', not a table"),
        (["policy_kwargs..x:1"], "sac", r"name between the dots"),
        (["use_sde:False"], "sac", r"'False' is not a TOML value \(TOML writes true and false in lower case\)"),
        (["gamma:O.95"], "sac", r"gamma: 'O.95' is not a TOML value"),
        (["learning_rate:nan"], "sac", r"learning_rate: 'nan' must be a finite number"),
        (["seed:1"], "sac", r"'seed' is set by the tool \(--seed"),
    ],
)
def test_bad_hyperparams_name_the_key_and_value(items: list[str], algo: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        override_hyperparameters(load_hyperparameters(algo), items, algo)


def test_bad_hyperparams_are_a_command_line_error(capsys) -> None:
    with pytest.raises(SystemExit):
        parse_args(["--hyperparams", "learning_rat:1e-3"])
    assert "'learning_rat' is not an argument of sac" in capsys.readouterr().err


def test_tensorboard_without_the_package_is_a_command_line_error(capsys, monkeypatch) -> None:
    import eval.residual.__main__ as tool

    monkeypatch.setattr(tool, "HAS_TENSORBOARD", False)
    with pytest.raises(SystemExit):
        parse_args(["--tensorboard", "tb"])
    assert "--tensorboard needs the tensorboard package" in capsys.readouterr().err


@pytest.mark.parametrize("algo", ["tqc", "crossq"])
def test_sb3_contrib_algorithms_train_save_and_reload(algo: str, tmp_path: Path) -> None:
    pytest.importorskip("sb3_contrib", reason="TQC and CrossQ need sb3-contrib (the rl extra)")
    args = tiny_training_args(tmp_path / algo, 0, "--algo", algo, hyperparams=("policy_kwargs.net_arch:[16, 16]",))
    run = train(args, base_factory=make_base)
    policy = load_residual_policy(run / "final_policy.zip")
    assert policy.algo == algo and policy.model.num_timesteps == 60
    assert (policy.actor is not None) == (algo == "tqc"), "TQC's actor is SAC's plain MLP, CrossQ's is not"
    observations = np.random.default_rng(0).uniform(-2, 2, (4, ResidualFeatures.size)).astype(np.float32)
    expected, _ = policy.model.predict(observations, deterministic=True)
    assert_allclose(policy(observations), expected, atol=1e-5)
    deployed = load_residual_policy(run / "final_policy.zip", deploy=True)  # read without torch for TQC only
    assert (deployed.model is None) == (algo == "tqc")
    assert_array_equal(deployed(observations), policy(observations))
    checkpoints = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert "residual_replay_buffer_60_steps.pkl" in checkpoints, "off-policy checkpoints keep the replay buffer"


def test_residual_features_use_the_drives_datasheet_values() -> None:
    from delta_env.config import PlantRealism

    realism, config = PlantRealism(), ResidualConfig()
    assert (config.ripple_periods, config.stribeck_velocity) == (realism.ripple_periods, realism.stribeck_velocity)


def test_a_missing_shipped_policy_says_how_to_get_a_base(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"pass base=.*python -m eval\.identification"):
        shipped_base_setup(tmp_path / "absent.zip")


def test_only_a_plain_relu_mlp_actor_runs_as_numpy_layers(tmp_path: Path) -> None:
    import torch

    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    plain = SAC("MlpPolicy", env, seed=2, policy_kwargs={"net_arch": [16, 8]}, device="cpu")
    actor = model_actor(plain)
    assert [w.shape for w, _ in actor.layers] == [(16, ResidualFeatures.size), (8, 16), (3, 8)]
    plain.save(tmp_path / "plain.zip")
    read = read_actor(tmp_path / "plain.zip")  # the same actor from the file, without torch
    for (weight, bias), (read_weight, read_bias) in zip(actor.layers, read.layers, strict=True):
        assert_array_equal(read_weight, weight)
        assert_array_equal(read_bias, bias)
    assert_array_equal(read.low, actor.low) and assert_array_equal(read.high, actor.high)
    tanh_layers = {"policy_kwargs": {"net_arch": [16], "activation_fn": torch.nn.Tanh}}
    for kwargs in (tanh_layers, {"policy_kwargs": {"net_arch": [16]}, "use_sde": True}):
        other = SAC("MlpPolicy", env, seed=2, device="cpu", **kwargs)
        assert model_actor(other) is None, kwargs
        other.save(tmp_path / "other.zip")
        assert read_actor(tmp_path / "other.zip") is None, kwargs


def test_a_damaged_policy_archive_is_named(tmp_path: Path) -> None:
    damaged = tmp_path / "damaged.zip"
    damaged.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"damaged\.zip"):
        read_actor(damaged)


def _rewritten(source: Path, target: Path, member: str, content: bytes) -> Path:
    """A copy of the zip ``source`` at ``target`` with ``member`` replaced by ``content``."""
    with zipfile.ZipFile(source) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(target, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, content if name == member else data)
    return target


class _Marker:
    """Unpickled, it would create the folder ``path``: what a hostile policy file could run."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple:
        return os.mkdir, (str(self.path),)


def test_the_actor_reader_declines_what_it_does_not_know_and_runs_no_code(tmp_path: Path) -> None:
    env = DeltaResidualEnv(base=make_base(), n_cycles=1)
    SAC("MlpPolicy", env, seed=2, policy_kwargs={"net_arch": [8]}, device="cpu").save(tmp_path / "plain.zip")
    plain = tmp_path / "plain.zip"
    with zipfile.ZipFile(plain) as archive:
        data, policy = json.loads(archive.read("data")), archive.read("policy.pth")
    with zipfile.ZipFile(io.BytesIO(policy)) as inner:  # torch's tensors in another byte order
        members = {name: inner.read(name) for name in inner.namelist()}
    swapped = io.BytesIO()
    with zipfile.ZipFile(swapped, "w") as inner:
        for name, content in members.items():
            inner.writestr(name, b"big" if name.endswith("/byteorder") else content)
    assert read_actor(_rewritten(plain, tmp_path / "big.zip", "policy.pth", swapped.getvalue())) is None
    hostile = dict(
        data, action_space={":serialized:": base64.b64encode(pickle.dumps(_Marker(tmp_path / "ran"))).decode()}
    )
    assert read_actor(_rewritten(plain, tmp_path / "hostile.zip", "data", json.dumps(hostile).encode())) is None
    assert not (tmp_path / "ran").exists(), "the action space's pickle ran code"


def test_resuming_under_another_scenario_or_base_is_named(tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    checkpoint = run / "checkpoints" / "residual_10_steps.zip"
    record = {"config": {"arguments": {"scenario": "nominal", "base": "mid_f_rls"}}}
    (run / "config.json").write_text(json.dumps(record))
    assert resume_mismatch(checkpoint, "nominal", "mid_f_rls") is None
    message = resume_mismatch(checkpoint, "randomized", "mid_f_rls_lag")
    assert "scenario nominal -> randomized" in message and "base mid_f_rls -> mid_f_rls_lag" in message
    assert resume_mismatch(tmp_path / "elsewhere.zip", "randomized", "mid_f_rls_lag") is None


def test_a_changed_reward_is_named_so_the_old_replay_buffer_is_left(tmp_path: Path) -> None:
    checkpoint = tmp_path / "checkpoints" / "residual_60_steps.zip"
    checkpoint.parent.mkdir()
    record = {"config": {"residual_config": {"residual_limit": 15.0, "action_period": 10, "reward_scale": 1.0}}}
    (tmp_path / "config.json").write_text(json.dumps(record))  # a run from before torque_weight existed
    assert reward_change(checkpoint, ResidualConfig()) is None
    changed = reward_change(checkpoint, ResidualConfig(torque_weight=1e-4, reward_scale=2.0))
    assert "torque_weight 0.0 -> 0.0001" in changed and "reward_scale 1.0 -> 2.0" in changed
    assert "action_rate_weight 0.0 -> 0.001" in reward_change(checkpoint, ResidualConfig(action_rate_weight=1e-3))
    assert trained_config(checkpoint) == ResidualConfig()  # fields the record predates take their defaults
    assert reward_change(tmp_path / "a" / "b" / "x.zip", ResidualConfig(torque_weight=1e-4)) is None
