"""The environments of residual training and their seeds (``python -m eval.residual``).

Training episodes draw their env seeds from :data:`TRAINING_SEEDS` (per worker, :class:`EpisodeSeeds`), validation
uses :data:`VALIDATION_SEEDS` and the base controller's tare :data:`CALIBRATION_SEEDS`: disjoint sets, disjoint too
from the test seeds of :mod:`eval.residual.scoring` and from ``python -m eval``'s defaults. :func:`base_setup` makes
the base controller's setup, :func:`make_env` the picklable env factories of SB3's vector envs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.monitor import Monitor

from controllers.base import Controller, payload_estimator_of
from controllers.dynamics import ModelParameters
from controllers.registry import ControllerSetup, controller_entry
from controllers.residual import DeltaResidualEnv, PolicyBase, ResidualConfig
from controllers.setup import SERVOS
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, calibrate_tares, calibrated_setup
from eval.engine import robot_knowledge
from eval.work import timed

TRAINING_SEEDS = range(10_000_000, 20_000_000)
"""Env seeds of the training episodes (drawn at random per worker)."""

VALIDATION_SEEDS = tuple(range(1_000_000, 1_000_006))
"""Held-out episodes of the EvalCallback during training (model selection)."""

CALIBRATION_SEEDS = tuple(range(3_000_000, 3_000_000 + DEFAULT_CALIBRATION_EPISODES))
"""Payload-free episodes of the base controller's tare (as many as the eval's)."""


class EpisodeSeeds(gym.Wrapper):
    """Resets the wrapped env with seeds from a schedule, so that episode sets are disjoint by construction.

    ``seeds`` given: episodes cycle through them (held-out evaluation; :meth:`restart` rewinds).
    Otherwise episode seeds are drawn from ``TRAINING_SEEDS`` by a generator seeded with
    (``seed``, ``rank``); a reset with an explicit seed re-seeds that generator.
    """

    def __init__(self, env: gym.Env, *, seed: int = 0, rank: int = 0, seeds: Sequence[int] | None = None) -> None:
        super().__init__(env)
        if seeds is not None and len(seeds) == 0:
            raise ValueError("seeds must not be empty")
        self.fixed_seeds = None if seeds is None else tuple(int(s) for s in seeds)
        self.rank = int(rank)
        self._index = 0
        self._generator = np.random.default_rng([int(seed), self.rank])
        self.episode_seed: int | None = None

    def restart(self) -> None:
        """Start the fixed seed list again from its first seed."""
        self._index = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if self.fixed_seeds is not None:
            self.episode_seed = self.fixed_seeds[self._index % len(self.fixed_seeds)]
            self._index += 1
        else:
            if seed is not None:
                self._generator = np.random.default_rng([int(seed), self.rank])
            self.episode_seed = int(self._generator.integers(TRAINING_SEEDS.start, TRAINING_SEEDS.stop))
        observation, info = self.env.reset(seed=self.episode_seed, options=options)
        info["episode_seed"] = self.episode_seed
        return observation, info


class ScenarioMixture(gym.Env):
    """Several residual envs, one per scenario; each episode runs on the one its seed picks (seed mod their number).

    The pick is a function of the episode seed alone, so that a seed list (validation) always runs the same
    episodes, and seeds drawn at random (training) spread evenly over the scenarios. Every env must have the spaces
    of the first.

    Args:
        envs: The residual envs (:class:`DeltaResidualEnv`), at least one.
    """

    def __init__(self, envs: Sequence[DeltaResidualEnv]) -> None:
        if not envs:
            raise ValueError("a scenario mixture needs at least one env")
        self.envs = tuple(envs)
        self.observation_space = self.envs[0].observation_space
        self.action_space = self.envs[0].action_space
        for env in self.envs[1:]:
            if env.observation_space != self.observation_space or env.action_space != self.action_space:
                raise ValueError("the envs of a scenario mixture must have the same observation and action spaces")
        self.current = self.envs[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset the env the seed picks (required: it picks the scenario); ``info["scenario_index"]`` says which."""
        if seed is None:
            raise ValueError("a scenario mixture picks each episode's scenario by its seed: reset it with a seed")
        index = int(seed) % len(self.envs)
        self.current = self.envs[index]
        observation, info = self.current.reset(seed=seed, options=options)
        info["scenario_index"] = index
        return observation, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        return self.current.step(action)

    def close(self) -> None:
        for env in self.envs:
            env.close()


BASE_KEYS = ("mid_f_rls_lag", "mid_f_rls")
"""Registry keys of the base controllers a residual can be trained on; the first, the strongest, is the default."""


def base_setup(
    env_kwargs: dict[str, Any],
    parameters: ModelParameters | None = None,
    drive_lag: tuple[float, float, float] | None = None,
    *,
    base: str = BASE_KEYS[0],
    runs_dir: Path | None = None,
    servo: str = SERVOS[0],
) -> PolicyBase:
    """The base controller's row and what it knows: the identification of the scenario's robot and the base's tare
    (and, unless the scenario randomizes the plant, its empty moves) calibrated on the scenario
    (:func:`eval.calibration.calibrated_setup`), as the eval's rows know them.

    Args:
        env_kwargs: Keyword arguments of the calibration episodes' :class:`DeltaPickPlaceEnv`: ``n_cycles``
            and optionally ``scenario`` (a Scenario; None or absent is ``nominal``).
        parameters: Identified MId+F+R parameters; None loads (or identifies) those of the scenario's robot
            (:func:`eval.engine.robot_knowledge`, kept under the runs root of ``runs_dir``,
            :func:`eval.run_folder.runs_root`), and with them its drive lag.
        drive_lag: Identified drive lag T (s) per joint, with ``parameters``.
        base: Registry key of the base: ``mid_f_rls_lag`` (the feedforward leads the identified drive lag)
            or ``mid_f_rls``.
        runs_dir: The runs root of the identification.
        servo: The base's feedback, one of :data:`controllers.setup.SERVOS`.
    """
    if base not in BASE_KEYS:
        raise ValueError(f"base must be one of {BASE_KEYS}, got {base!r}")
    if not {"n_cycles"} <= set(env_kwargs) <= {"n_cycles", "scenario"}:
        raise ValueError(f"the tare calibration takes n_cycles and scenario only, got {sorted(env_kwargs)}")
    scenario = env_kwargs.get("scenario") or Scenario()
    if parameters is None:
        setup = robot_knowledge(scenario, runs_dir=runs_dir, servo=servo)[2]
    else:  # the base uses the MId+F+R set only, on the scenario's drive and encoders (no drive compliance)
        robot = scenario.plant
        setup = ControllerSetup(
            mid=parameters,
            mid_f=parameters,
            mid_f_rods=parameters,
            drive_lag=drive_lag,
            geometry=robot.geometry,
            masses=robot.masses,
            drive=robot.drive,
            encoder_bits=robot.realism.encoder_bits,
            torque_delay=robot.timestep,
            fault_reaction=scenario.task.fault_reaction,
            servo=servo,
        )
    if controller_entry(base).needs_drive_lag and setup.drive_lag is None:
        raise ValueError(f"the {base} base needs the identified drive lag: pass drive_lag with parameters")
    calibration = calibrate_tares([base], setup, CALIBRATION_SEEDS, env_kwargs["n_cycles"], scenario=scenario)
    return PolicyBase(base, calibrated_setup(setup, calibration, scenario))


def make_env(
    *,
    config: ResidualConfig,
    env_kwargs: dict[str, Any],
    base: PolicyBase | None,
    seed: int = 0,
    rank: int = 0,
    seeds: Sequence[int] | None = None,
    base_factory: Callable[[], Controller] | None = None,
    mixture: Sequence[dict[str, Any]] = (),
) -> Callable[[], gym.Env]:
    """A picklable env factory for SB3 vector envs (one torch thread per worker: the machine is shared).

    The plant env is timed as its scenario asks (:func:`eval.work.timed`): a planned timing plans on ``base``'s
    model, and an online one retimes the carries on the base's own payload estimate, as in the evaluation.

    Args:
        config: Residual settings.
        env_kwargs: Keyword arguments of :class:`DeltaPickPlaceEnv`.
        base: The base controller's row and setup (None: ``base_factory`` must be given).
        seed: Seed of the training episode seeds.
        rank: Worker index.
        seeds: Fixed held-out seeds instead of drawn training seeds.
        base_factory: Builds the base controller instead of ``base`` (tests; fixed timing only).
        mixture: Keyword arguments of more plant envs (other scenarios of the same robot): each episode runs on the
            one of ``env_kwargs`` and these that its seed picks (:class:`ScenarioMixture`), all with the same base.
    """

    def residual_env(kwargs: dict[str, Any]) -> DeltaResidualEnv:
        plant_env = DeltaPickPlaceEnv(**kwargs, reward_weights=config.reward_weights())
        if base_factory is not None:
            controller = base_factory()
            if plant_env.task_timing != "fixed":
                raise ValueError(
                    f"the {plant_env.task_timing!r} timing plans on the base's setup: pass base, not base_factory"
                )
        else:
            # the base row estimates the payload itself, so the online timing reads its estimator and no wrapper
            controller = base.controller()
            timed(plant_env, base.setup, payload_estimator_of(controller))
        return DeltaResidualEnv(base=controller, config=config, env=plant_env)

    def factory() -> gym.Env:
        torch.set_num_threads(1)
        envs = [residual_env(kwargs) for kwargs in (env_kwargs, *mixture)]
        env = envs[0] if len(envs) == 1 else ScenarioMixture(envs)
        return Monitor(EpisodeSeeds(env, seed=seed, rank=rank, seeds=seeds))

    return factory
