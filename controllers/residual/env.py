"""``DeltaPickPlaceResidual-v0``: the plant env with a base controller inside; the agent adds a torque residual."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from controllers.base import Controller, payload_estimate_reader
from controllers.residual.config import ResidualConfig, residual_gain
from controllers.residual.features import FEATURE_CLIP, ResidualFeatures
from controllers.residual.policy_file import shipped_base_setup
from delta_env.env import DeltaPickPlaceEnv


def action_rate_penalty(
    action: NDArray[np.floating], previous_action: NDArray[np.floating], config: ResidualConfig
) -> NDArray[np.float64]:
    """The action-rate term of a policy step's reward before ``reward_scale``: ``-config.action_rate_weight`` times
    the squared change of the residual torque ((N m)^2, summed over the joints) from ``previous_action`` to
    ``action`` (both in [-1, 1], the last axis the joints; any leading axes are kept: a replay buffer's)."""
    change = config.residual_limit * (np.asarray(action, dtype=float) - np.asarray(previous_action, dtype=float))
    return -config.action_rate_weight * np.sum(change**2, axis=-1)


class DeltaResidualEnv(gym.Wrapper[NDArray[np.float32], NDArray[np.float32], dict[str, Any], NDArray[np.float64]]):
    """DeltaPickPlace-v0 with a base controller inside; the agent adds a bounded, held torque residual.

    Every policy step runs ``action_period`` control steps (1 ms each) of the plant. At each one the
    base controller computes its torque from the latest observation and the env applies
    ``base + gain * residual_limit * a``, the gain of :func:`residual_gain` at the observation's reference rates (1
    unless ``config.off_at_rest`` or ``config.fade_speed`` asks otherwise). A zero action reproduces the base
    controller exactly.

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: the residual torque in units of ``residual_limit`` (N m), held for
    ``action_period`` control steps. Values beyond +-1 are clipped; non-finite values raise.

    ## Observation Space
    ``Box(-10, 10, (43,), float32)``: :class:`ResidualFeatures` (tracking errors and their window
    means, reference angles / rates / accelerations / jerk, Stribeck and ripple features, base torque,
    payload estimate and its change, gripper and time since its last event, previous action), all
    from measurements and the reference; never the plant's truth.

    ## Rewards
    ``reward_scale`` times the sum of the plant env's rewards over the control steps of this policy
    step: -(tracking error in mm^2 + ``config.plant_torque_weight`` (1e-5 (N m)^-2 by default) torque^2) per
    control step, with ``config.torque_weight`` times the squared commanded torque added; plus, once per policy
    step, ``-config.action_rate_weight`` times the squared change of the residual torque since the previous policy
    step ((N m)^2 summed over the joints; from zero at the first step; :func:`action_rate_penalty`), times
    ``reward_scale`` too. ``info`` holds the summed terms ``reward_tracking``, ``reward_torque`` and
    ``reward_action_rate``.

    ## Starting State
    The plant env's: at rest at a place point (``start="place"``, the default) or at the first pick point
    (``start="pick"``). The base controller is reset with it.

    ## Episode End
    As the plant env: truncated at the end of the reference (the last policy step may run fewer
    control steps), terminated on divergence.

    ## Info
    The plant env's info of the last control step (truth, for evaluation only) plus, over the control
    steps of this policy step: ``tracking_errors`` (m, (n,)), ``commanded_torques`` (N m, (n, 3)),
    ``base_torques`` (N m, (n, 3)), ``residual_torque`` (N m, (3,)), ``control_steps`` (n).

    ## Arguments
    Args:
        base: The base controller; None builds the base of the shipped policy (MId+F+R + RLS + drive-lag lead
            with the identified parameters, lag and tare recorded in ``controllers/policies/residual_sac.zip``), so that
            ``gym.make("DeltaPickPlaceResidual-v0")`` neither identifies nor writes files.
        config: Residual settings; None uses :class:`ResidualConfig` defaults.
        env: The plant env to wrap, its torque weight ``config.plant_torque_weight``; None builds
            ``DeltaPickPlaceEnv(**env_kwargs)`` with ``config.reward_weights()`` unless they give ``reward_weights``.
        **env_kwargs: Keyword arguments of :class:`~delta_env.env.DeltaPickPlaceEnv` (only without ``env``).
    """

    def __init__(
        self,
        base: Controller | None = None,
        config: ResidualConfig | None = None,
        env: DeltaPickPlaceEnv | None = None,
        **env_kwargs: Any,
    ) -> None:
        if env is not None and env_kwargs:
            raise ValueError(f"pass either env or DeltaPickPlaceEnv keyword arguments, not both: {sorted(env_kwargs)}")
        config = config if config is not None else ResidualConfig()
        if env is None:
            env_kwargs.setdefault("reward_weights", config.reward_weights())
            env = DeltaPickPlaceEnv(**env_kwargs)
        if env.reward_weights.torque != config.plant_torque_weight:
            raise ValueError(
                f"the plant env's torque weight {env.reward_weights.torque} is not config.plant_torque_weight "
                f"{config.plant_torque_weight}: build it with reward_weights=config.reward_weights()"
            )
        super().__init__(env)
        self.base = base if base is not None else shipped_base_setup().controller()
        if not isinstance(self.base, Controller):
            raise ValueError(f"base must implement the Controller protocol, got {type(self.base).__name__}")
        self._base_estimate = payload_estimate_reader(self.base)
        self.config = config
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.observation_space = spaces.Box(
            -FEATURE_CLIP, FEATURE_CLIP, shape=(ResidualFeatures.size,), dtype=np.float32
        )
        self._features = ResidualFeatures(self.config)
        self._base_torque = np.zeros(3)
        self._reference_velocities = np.zeros(3)
        self._previous_action = np.zeros(3)
        self._needs_reset = True

    @property
    def plant_env(self) -> DeltaPickPlaceEnv:
        """The wrapped plant env (``self.env``)."""
        return self.env

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the plant env (same seed and options) and the base controller."""
        observation, info = self.env.reset(seed=seed, options=options)
        self.base.reset()
        self._base_torque = self.base(observation)
        self._reference_velocities = observation["reference_velocities"]
        self._features.reset(observation, self._base_torque, self._base_estimate())
        self._previous_action = np.zeros(3)
        self._needs_reset = False
        return self._features.policy_observation(self._previous_action), info

    def step(self, action: NDArray[np.float32]) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode ends)")
        action = np.asarray(action, dtype=float).reshape(-1)
        if action.shape != (3,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 3 finite values in [-1, 1], got {action!r}")
        action = np.clip(action, -1.0, 1.0)
        residual = self.config.residual_limit * action
        n = self.config.action_period
        errors, commanded, base_torques = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3))
        reward_sum = reward_tracking = reward_torque = 0.0
        terminated = truncated = False
        info: dict[str, Any] = {}
        steps = 0
        while steps < n and not (terminated or truncated):
            torque = self._base_torque + residual_gain(self.config, self._reference_velocities) * residual
            base_torques[steps] = self._base_torque
            commanded[steps] = torque
            observation, reward, terminated, truncated, info = self.env.step(torque)
            errors[steps] = info["tracking_error"]
            reward_sum += reward
            reward_tracking += info["reward_tracking"]
            reward_torque += info["reward_torque"]
            steps += 1
            self._base_torque = self.base(observation)
            self._reference_velocities = observation["reference_velocities"]
            self._features.update(observation, self._base_torque, self._base_estimate())
        self._needs_reset = terminated or truncated
        scale = self.config.reward_scale
        extra_torque = -self.config.torque_weight * float(np.sum(commanded[:steps] ** 2))
        action_rate = float(action_rate_penalty(action, self._previous_action, self.config))
        reward_sum += extra_torque + action_rate
        reward_torque += extra_torque
        info.update(
            reward_tracking=scale * reward_tracking,
            reward_torque=scale * reward_torque,
            reward_action_rate=scale * action_rate,
            tracking_errors=errors[:steps],
            commanded_torques=commanded[:steps],
            base_torques=base_torques[:steps],
            residual_torque=residual,
            control_steps=steps,
        )
        self._previous_action = action
        observation = self._features.policy_observation(self._previous_action)
        return observation, scale * reward_sum, terminated, truncated, info
