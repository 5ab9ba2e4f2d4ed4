"""Residual policy on top of a model-based controller (DESIGN.md section 6, issue 5).

A base controller (by default MId+F+R feedforward + PD with the payload RLS) runs at 1 kHz; a learned
policy adds ``residual_limit * a`` with ``a`` in [-1, 1]^3, chosen every ``action_period`` control
steps and held in between (100 Hz by default).

- :class:`DeltaResidualEnv` (``DeltaPickPlaceResidual-v0``): the environment the policy is trained in.
- :class:`ResidualController`: the same loop as a :class:`~controllers.base.Controller`, running from
  observations only (the evaluation's "residual" row).
- :func:`load_residual_controller`: the shipped policy (``controllers/policies/residual_sac.zip``)
  as a Controller; :func:`save_residual_policy` writes a policy with the settings it was trained with.

Both the env and the controller build the policy's observation with one :class:`ResidualFeatures`,
so that a policy sees exactly the same numbers in training and in evaluation.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from controllers.base import Controller, Observation, PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.payload import FRICTION_VELOCITY
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import TORQUE_LIMIT
from delta_env.sensors import CONTROL_PERIOD

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

DEFAULT_POLICY_PATH = Path(__file__).resolve().parent / "policies" / "residual_sac.zip"
"""The shipped residual policy (SAC), resolved next to this module."""

FEATURE_VERSION = 1
"""Version of the observation layout of :class:`ResidualFeatures`; saved with every policy."""

METADATA_NAME = "residual.json"
"""Member of a policy zip that holds its :class:`ResidualConfig`, algorithm and feature version."""

PolicyFunction = Callable[[NDArray[np.float32]], NDArray[np.float32]]
"""Maps one policy observation (float32, (ResidualFeatures.size,)) to an action in [-1, 1]^3."""


@dataclass(frozen=True)
class ResidualConfig:
    """Settings shared by the residual env and controller; saved with every trained policy.

    Attributes:
        residual_limit: Torque (N m) added per joint at a = +-1; 40 N m is 10 % of the 400 N m motor
            limit, against feedforward errors of a few N m (identified model, 3 g cycles).
        action_period: Control steps (1 ms each) per policy step; the action is held in between.
        reward_scale: Factor on the policy-step reward, the sum of the env's per-step rewards over the
            ``action_period`` control steps (dimensionless). With 1.0 a policy step of a base
            controller tracking within 0.4 mm RMS with 20 N m RMS torque scores about -2 at
            ``action_period`` 10.
        ripple_periods: Torque-ripple periods per joint revolution (gear datasheet, DESIGN.md
            section 4): the policy sees the ripple phase sin / cos(ripple_periods * theta).
        stribeck_velocity: Speed (rad/s) under which Stribeck friction rises (DESIGN.md section 4):
            the policy sees tanh(theta_dot_ref / stribeck_velocity).
    """

    residual_limit: float = 0.1 * TORQUE_LIMIT
    action_period: int = 10
    reward_scale: float = 1.0
    ripple_periods: int = 180
    stribeck_velocity: float = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.residual_limit) and 0.0 < self.residual_limit <= TORQUE_LIMIT):
            raise ValueError(f"residual_limit must be in (0, {TORQUE_LIMIT}] N m, got {self.residual_limit!r}")
        if not (isinstance(self.action_period, int | np.integer) and self.action_period >= 1):
            raise ValueError(f"action_period must be an integer >= 1 control steps, got {self.action_period!r}")
        if not (math.isfinite(self.reward_scale) and self.reward_scale > 0.0):
            raise ValueError(f"reward_scale must be a finite number > 0, got {self.reward_scale!r}")
        if not (isinstance(self.ripple_periods, int | np.integer) and self.ripple_periods >= 0):
            raise ValueError(f"ripple_periods must be an integer >= 0, got {self.ripple_periods!r}")
        if not (math.isfinite(self.stribeck_velocity) and self.stribeck_velocity > 0.0):
            raise ValueError(f"stribeck_velocity must be a finite speed > 0 rad/s, got {self.stribeck_velocity!r}")
        object.__setattr__(self, "action_period", int(self.action_period))
        object.__setattr__(self, "ripple_periods", int(self.ripple_periods))

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ResidualConfig:
        """The config from :func:`dataclasses.asdict` output; unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = set(values) - names
        if unknown:
            raise ValueError(f"unknown ResidualConfig fields {sorted(unknown)}; known: {sorted(names)}")
        return cls(**values)


def payload_estimate(controller: Controller) -> float:
    """The controller's payload estimate (kg), or 0 if it does not estimate the payload.

    Estimating controllers expose it as ``payload_estimate`` (kg).
    """
    estimate = getattr(controller, "payload_estimate", None)
    return 0.0 if estimate is None else float(estimate)


# Normalization of the policy observation: each feature divided by a typical magnitude in 3 g
# conveyor cycles (reference rates up to 6 rad/s, accelerations up to 70 rad/s^2, jerk up to
# 5000 rad/s^3; tracking errors of the identified base near 1 mrad), then clipped.
_ANGLE_ERROR_SCALE = 1e-3  # rad
_RATE_ERROR_SCALE = 0.1  # rad/s
_ANGLE_SCALE = 1.0  # rad
_RATE_SCALE = 5.0  # rad/s
_ACCELERATION_SCALE = 50.0  # rad/s^2
_JERK_SCALE = 2000.0  # rad/s^3
_TORQUE_SCALE = 100.0  # N m
_MASS_SCALE = 4.0  # kg, the largest default payload
_MASS_CHANGE_SCALE = 1.0  # kg per policy step
_EVENT_HORIZON = 0.5  # s: time since the last pick or place, saturated here
_FEATURE_CLIP = 10.0


class ResidualFeatures:
    """The policy's observation, built from the 1 kHz observations between two policy steps.

    Layout (float32, normalized as in the module constants, clipped to +-10), per joint where (3,):

    | slice | feature |
    |---|---|
    | 0:3 | angle error th_ref - th (last sample) |
    | 3:6 | rate error thd_ref - thd (last sample; noisy: encoder differences) |
    | 6:9 | angle error, mean over the samples since the last policy step |
    | 9:12 | rate error, mean over the same samples (the encoder noise averages out) |
    | 12:15 | reference angles th_ref |
    | 15:18 | reference rates thd_ref |
    | 18:21 | reference accelerations thdd_ref |
    | 21:24 | reference jerk (thdd_ref[k] - thdd_ref[k-1]) / dt: the 1 ms actuator lag needs ~lag * dtau/dt |
    | 24:27 | tanh(thd_ref / stribeck_velocity): where Stribeck friction acts, with its sign |
    | 27:30 | sin(ripple_periods * th): torque-ripple phase |
    | 30:33 | cos(ripple_periods * th) |
    | 33:36 | base controller torque for this step |
    | 36 | payload estimate of the base controller |
    | 37 | its change since the last policy step (estimate transients after a pick) |
    | 38 | gripper state |
    | 39 | time since the last gripper event, saturated at 0.5 s (normalized to [0, 1]) |
    | 40:43 | previous policy action |

    Call :meth:`reset` with the first observation of an episode, :meth:`update` with every later one,
    and :meth:`policy_observation` at each policy step (it starts a new averaging window).
    """

    size = 43

    def __init__(self, config: ResidualConfig) -> None:
        self.config = config
        self._inverse_stribeck = 1.0 / config.stribeck_velocity
        self._ripple_periods = float(config.ripple_periods)
        self._angle_error_sum = [0.0, 0.0, 0.0]
        self._rate_error_sum = [0.0, 0.0, 0.0]
        self._window = 0
        self._observation: Observation | None = None
        self._base_torque = np.zeros(3)
        self._acceleration = np.zeros(3)
        self._previous_acceleration = np.zeros(3)
        self._payload = 0.0
        self._payload_at_last_policy_step = 0.0
        self._gripper = 0.0
        self._steps_since_event = 0

    def reset(self, observation: Observation, base_torque: NDArray[np.float64], payload: float) -> None:
        """Start an episode at its first observation, with the base torque (N m) and payload estimate (kg)."""
        self._angle_error_sum[:] = self._rate_error_sum[:] = [0.0, 0.0, 0.0]
        self._window = 0
        self._acceleration = np.asarray(observation["reference_accelerations"], dtype=float).copy()
        self._payload_at_last_policy_step = payload
        self._gripper = float(observation["gripper"][0])
        # Nothing happened before the episode: as long ago as the features can tell.
        self._steps_since_event = round(_EVENT_HORIZON / CONTROL_PERIOD)
        self._add(observation, base_torque, payload)

    def update(self, observation: Observation, base_torque: NDArray[np.float64], payload: float) -> None:
        """Add the observation of the next control step, with its base torque (N m) and payload estimate (kg)."""
        if self._observation is None:
            raise RuntimeError("ResidualFeatures.reset() must be called before update()")
        gripper = float(observation["gripper"][0])
        if gripper != self._gripper:
            self._gripper = gripper
            self._steps_since_event = 0
        else:
            self._steps_since_event += 1
        self._add(observation, base_torque, payload)

    def _add(self, observation: Observation, base_torque: NDArray[np.float64], payload: float) -> None:
        # The jerk is formed at policy steps only, from the last two reference accelerations.
        self._previous_acceleration = self._acceleration
        self._acceleration = np.array(observation["reference_accelerations"], dtype=float)
        # The sums in Python floats: at three values, cheaper than NumPy's in-place operations.
        angle_sum, rate_sum = self._angle_error_sum, self._rate_error_sum
        for joint, (reference, angle, reference_rate, rate) in enumerate(
            zip(
                observation["reference_angles"].tolist(),
                observation["joint_angles"].tolist(),
                observation["reference_velocities"].tolist(),
                observation["joint_velocities"].tolist(),
                strict=True,
            )
        ):
            angle_sum[joint] += reference - angle
            rate_sum[joint] += reference_rate - rate
        self._window += 1
        self._observation = observation
        self._base_torque = np.array(base_torque, dtype=float)
        self._payload = payload

    def policy_observation(self, previous_action: NDArray[np.float64]) -> NDArray[np.float32]:
        """The normalized observation (float32, (43,)) and the start of a new averaging window."""
        observation = self._observation
        if observation is None:
            raise RuntimeError("ResidualFeatures.reset() must be called before policy_observation()")
        reference_angles = observation["reference_angles"]
        reference_rates = observation["reference_velocities"]
        angles = observation["joint_angles"]
        ripple_phase = self._ripple_periods * angles
        event_age = min(self._steps_since_event * CONTROL_PERIOD, _EVENT_HORIZON) / _EVENT_HORIZON
        vector = np.concatenate(
            (
                (reference_angles - angles) / _ANGLE_ERROR_SCALE,
                (reference_rates - observation["joint_velocities"]) / _RATE_ERROR_SCALE,
                np.array(self._angle_error_sum) / (self._window * _ANGLE_ERROR_SCALE),
                np.array(self._rate_error_sum) / (self._window * _RATE_ERROR_SCALE),
                reference_angles / _ANGLE_SCALE,
                reference_rates / _RATE_SCALE,
                observation["reference_accelerations"] / _ACCELERATION_SCALE,
                (self._acceleration - self._previous_acceleration) / (CONTROL_PERIOD * _JERK_SCALE),
                np.tanh(reference_rates * self._inverse_stribeck),
                np.sin(ripple_phase),
                np.cos(ripple_phase),
                self._base_torque / _TORQUE_SCALE,
                (
                    self._payload / _MASS_SCALE,
                    (self._payload - self._payload_at_last_policy_step) / _MASS_CHANGE_SCALE,
                    self._gripper,
                    event_age,
                ),
                previous_action,
            )
        )
        self._angle_error_sum[:] = self._rate_error_sum[:] = [0.0, 0.0, 0.0]
        self._window = 0
        self._payload_at_last_policy_step = self._payload
        return np.clip(vector, -_FEATURE_CLIP, _FEATURE_CLIP).astype(np.float32)


def base_name(forearm_rods: bool) -> str:
    """Label of the default base controller, as the ``mid_f_rls`` row of ``python -m eval`` names it."""
    return "MId+F+R+RLS+PD" if forearm_rods else "MId+F+RLS+PD"


def default_base_controller(parameters: ModelParameters | None = None, tare: float = 0.0) -> Controller:
    """The base controller of the residual: the eval's ``mid_f_rls`` row, :class:`BaseSetup`'s defaults.

    MId+F+R feedforward + PD (3000 N m/rad, 60 N m s/rad) with the payload RLS on the fixed-lag smoothed
    joint states; other bases (those of older policy files) are built by :meth:`BaseSetup.controller`.

    Args:
        parameters: Identified MId+F+R parameters; None loads them with
            ``controllers.identification.load_or_identify()`` (the project's parameter file).
        tare: Apparent payload of the empty gripper (kg), see ``controllers.payload.tare_from_observations``.
    """
    if parameters is None:
        from controllers.identification import load_or_identify

        parameters = load_or_identify().mid_f_rods
    return BaseSetup(parameters, tare).controller()


class DeltaResidualEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """DeltaPickPlace-v0 with a base controller inside; the agent adds a bounded, held torque residual.

    Every policy step runs ``action_period`` control steps (1 ms each) of the plant. At each one the
    base controller computes its torque from the latest observation and the env applies
    ``base + residual_limit * a``. A zero action reproduces the base controller exactly.

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
    step: -(tracking error in mm^2 + 1e-5 (N m)^-2 torque^2) per control step by default. ``info``
    holds the summed terms ``reward_tracking`` and ``reward_torque``.

    ## Starting State
    The plant env's: at rest at the first pick point. The base controller is reset with it.

    ## Episode End
    As the plant env: truncated at the end of the reference (the last policy step may run fewer
    control steps), terminated on divergence.

    ## Info
    The plant env's info of the last control step (truth, for evaluation only) plus, over the control
    steps of this policy step: ``tracking_errors`` (m, (n,)), ``commanded_torques`` (N m, (n, 3)),
    ``base_torques`` (N m, (n, 3)), ``residual_torque`` (N m, (3,)), ``control_steps`` (n).

    ## Arguments
    Args:
        base: The base controller; None builds :func:`default_base_controller` (MId+F+R + RLS).
        config: Residual settings; None uses :class:`ResidualConfig` defaults.
        env: The plant env to wrap; None builds ``DeltaPickPlaceEnv(**env_kwargs)``.
        **env_kwargs: Keyword arguments of :class:`~delta_env.env.DeltaPickPlaceEnv` (only without ``env``).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        base: Controller | None = None,
        config: ResidualConfig | None = None,
        env: DeltaPickPlaceEnv | None = None,
        **env_kwargs: Any,
    ) -> None:
        if env is not None and env_kwargs:
            raise ValueError(f"pass either env or DeltaPickPlaceEnv keyword arguments, not both: {sorted(env_kwargs)}")
        self.plant_env = env if env is not None else DeltaPickPlaceEnv(**env_kwargs)
        self.base = base if base is not None else default_base_controller()
        if not isinstance(self.base, Controller):
            raise ValueError(f"base must implement the Controller protocol, got {type(self.base).__name__}")
        self.config = config if config is not None else ResidualConfig()
        self.render_mode = self.plant_env.render_mode
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.observation_space = spaces.Box(
            -_FEATURE_CLIP, _FEATURE_CLIP, shape=(ResidualFeatures.size,), dtype=np.float32
        )
        self._features = ResidualFeatures(self.config)
        self._base_torque = np.zeros(3)
        self._previous_action = np.zeros(3)
        self._needs_reset = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the plant env (same seed and options) and the base controller."""
        super().reset(seed=seed)
        observation, info = self.plant_env.reset(seed=seed, options=options)
        self.base.reset()
        self._base_torque = self.base(observation)
        self._features.reset(observation, self._base_torque, payload_estimate(self.base))
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
            torque = self._base_torque + residual
            base_torques[steps] = self._base_torque
            commanded[steps] = torque
            observation, reward, terminated, truncated, info = self.plant_env.step(torque)
            errors[steps] = info["tracking_error"]
            reward_sum += reward
            reward_tracking += info["reward_tracking"]
            reward_torque += info["reward_torque"]
            steps += 1
            self._base_torque = self.base(observation)
            self._features.update(observation, self._base_torque, payload_estimate(self.base))
        self._previous_action = action
        self._needs_reset = terminated or truncated
        scale = self.config.reward_scale
        info.update(
            reward_tracking=scale * reward_tracking,
            reward_torque=scale * reward_torque,
            tracking_errors=errors[:steps],
            commanded_torques=commanded[:steps],
            base_torques=base_torques[:steps],
            residual_torque=residual,
            control_steps=steps,
        )
        observation = self._features.policy_observation(self._previous_action)
        return observation, scale * reward_sum, terminated, truncated, info

    def render(self) -> NDArray[np.uint8] | None:
        return self.plant_env.render()

    def close(self) -> None:
        self.plant_env.close()


class ResidualController:
    """Base controller + residual policy at 1 kHz, from observations only: the "residual" row.

    Runs exactly the loop of :class:`DeltaResidualEnv`: the base torque every control step, a new
    policy action every ``config.action_period`` steps (the first at the episode's first step),
    held in between.

    Args:
        base: The base controller.
        policy: Policy observation (float32, (43,)) -> action in [-1, 1]^3.
        config: The settings the policy was trained with.
        name: Row name; by default ``"<base name> + residual"``.
    """

    def __init__(
        self, base: Controller, policy: PolicyFunction, config: ResidualConfig, name: str | None = None
    ) -> None:
        if not isinstance(base, Controller):
            raise ValueError(f"base must implement the Controller protocol, got {type(base).__name__}")
        self.base = base
        self.policy = policy
        self.config = config
        self.name = name if name is not None else f"{base.name} + residual"
        self._features = ResidualFeatures(config)
        self._step = 0
        self._action = np.zeros(3)
        self._residual = np.zeros(3)

    def reset(self) -> None:
        """Reset the base controller and start a new episode."""
        self.base.reset()
        self._step = 0
        self._action = np.zeros(3)
        self._residual = np.zeros(3)

    @property
    def payload_estimate(self) -> float:
        """The base controller's payload estimate (kg)."""
        return payload_estimate(self.base)

    @property
    def residual_torque(self) -> NDArray[np.float64]:
        """The residual torque (N m) added in this control step, (3,)."""
        return self._residual.copy()

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        base_torque = self.base(observation)
        if self._step == 0:
            self._features.reset(observation, base_torque, payload_estimate(self.base))
        else:
            self._features.update(observation, base_torque, payload_estimate(self.base))
        if self._step % self.config.action_period == 0:
            action = np.asarray(self.policy(self._features.policy_observation(self._action)), dtype=float)
            if action.shape != (3,) or not np.all(np.isfinite(action)):
                raise ValueError(f"the residual policy must return 3 finite values, got {action!r}")
            self._action = np.clip(action, -1.0, 1.0)
            self._residual = self.config.residual_limit * self._action  # held until the next policy step
        self._step += 1
        return base_torque + self._residual


# -- saving and loading -----------------------------------------------------------------------------

ALGORITHMS = ("sac", "ppo")


def algorithm_class(algo: str) -> type[BaseAlgorithm]:
    """The SB3 class of ``algo`` (``"sac"`` or ``"ppo"``); SB3 is imported only when a policy is used."""
    from stable_baselines3 import PPO, SAC

    classes: dict[str, type[BaseAlgorithm]] = {"sac": SAC, "ppo": PPO}
    if algo not in classes:
        raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    return classes[algo]


def save_residual_policy(
    model: BaseAlgorithm,
    path: str | Path,
    config: ResidualConfig,
    algo: str,
    *,
    base: BaseSetup | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Save an SB3 model with its residual settings inside the zip (member ``residual.json``).

    Args:
        model: The trained SAC or PPO model.
        path: Target ``.zip`` path.
        config: The settings the model was trained with.
        algo: ``"sac"`` or ``"ppo"``.
        base: The default base controller's setup it was trained on (None: a custom base).
        extra: JSON-serializable notes stored beside the settings (e.g. the training command).

    Returns:
        The path written.
    """
    algorithm_class(algo)
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"a residual policy is a .zip file, got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    metadata = {
        "algo": algo,
        "feature_version": FEATURE_VERSION,
        "config": asdict(config),
        "base": None if base is None else base.to_dict(),
        "extra": extra or {},
    }
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr(METADATA_NAME, json.dumps(metadata, indent=2))
    return path


_LEGACY_BASE = {"forearm_rods": False, "regressor": "filtered", "friction_velocity": 0.1}
"""The base settings of policy files written before these keys existed: the lumped model, the causal
filter and a 0.1 rad/s friction band."""


@dataclass(frozen=True)
class BaseSetup:
    """What the default base controller was built from: model, identified parameters, estimator and tare.

    Attributes:
        parameters: Identified parameters of the model.
        tare: Apparent payload of the empty gripper (kg).
        forearm_rods: MId+F+R (True) or the paper's lumped MId+F.
        regressor: Joint states of the payload estimator.
        friction_velocity: The estimator's friction band (rad/s).
    """

    parameters: ModelParameters
    tare: float = 0.0
    forearm_rods: bool = True
    regressor: Literal["smoothed", "filtered", "reference"] = "smoothed"
    friction_velocity: float = FRICTION_VELOCITY

    def controller(self) -> Controller:
        """A fresh base controller with these settings: model feedforward + PD with the payload RLS."""
        from controllers.feedforward import FeedforwardController
        from controllers.payload import PayloadEstimator

        dynamics = DeltaDynamics.nominal(self.parameters, forearm_rods=self.forearm_rods)
        estimator = PayloadEstimator(
            dynamics, regressor=self.regressor, tare=self.tare, friction_velocity=self.friction_velocity
        )
        return FeedforwardController(base_name(self.forearm_rods), dynamics, pd=PDController(), estimator=estimator)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": base_name(self.forearm_rods),
            "parameters": asdict(self.parameters),
            "tare": self.tare,
            "forearm_rods": self.forearm_rods,
            "regressor": self.regressor,
            "friction_velocity": self.friction_velocity,
        }

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> BaseSetup:
        values = {**_LEGACY_BASE, **values}
        parameters = values["parameters"]
        return cls(
            parameters=ModelParameters(
                rho1=parameters["rho1"],
                rho2=parameters["rho2"],
                viscous=tuple(parameters["viscous"]),
                coulomb=tuple(parameters["coulomb"]),
            ),
            tare=float(values["tare"]),
            forearm_rods=bool(values["forearm_rods"]),
            regressor=values["regressor"],
            friction_velocity=float(values["friction_velocity"]),
        )


@dataclass(frozen=True)
class ResidualPolicy:
    """A loaded residual policy: the SB3 model, the settings and the base it was trained with."""

    model: BaseAlgorithm
    config: ResidualConfig
    algo: str
    base: BaseSetup | None
    metadata: dict[str, Any]

    def __call__(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The deterministic action (mean of the policy) for one observation ``(43,)`` or a batch ``(N, 43)``.

        For SAC (without gSDE) the arithmetic of SB3's ``predict(observation, deterministic=True)``, the same
        torch modules on the same float32 input, without its per-call input checks and distribution objects,
        which cost three times the network: tanh of the actor's mean, unscaled to the action space.
        """
        policy = self.model.policy
        if self.algo != "sac" or policy.actor.use_sde:
            action, _ = self.model.predict(observation, deterministic=True)
            return action
        import torch

        actor = policy.actor
        with torch.no_grad():
            features = actor.features_extractor(torch.as_tensor(observation).reshape(-1, ResidualFeatures.size))
            action = policy.unscale_action(torch.tanh(actor.mu(actor.latent_pi(features))).numpy())
        return action if np.ndim(observation) == 2 else action[0]


def load_residual_policy(path: str | Path = DEFAULT_POLICY_PATH) -> ResidualPolicy:
    """Load a policy written by :func:`save_residual_policy` (on the CPU).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if ``path`` is not a valid residual policy (corrupt zip, missing or incompatible
            settings, unreadable model); the message names the path.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"residual policy file not found: {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            metadata = json.loads(archive.read(METADATA_NAME))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not a residual policy written by save_residual_policy: {error}") from error
    try:
        if metadata["feature_version"] != FEATURE_VERSION:
            raise ValueError(f"feature version {metadata['feature_version']}, this code reads {FEATURE_VERSION}")
        config = ResidualConfig.from_dict(metadata["config"])
        base = None if metadata["base"] is None else BaseSetup.from_dict(metadata["base"])
        algo = metadata["algo"]
        model = algorithm_class(algo).load(path, device="cpu")
        model.policy.set_training_mode(False)
    except Exception as error:  # SB3 and torch raise many kinds on a damaged archive
        raise ValueError(f"could not load the residual policy {path}: {error}") from error
    expected = (ResidualFeatures.size,)
    if model.observation_space.shape != expected or model.action_space.shape != (3,):
        raise ValueError(
            f"{path}: policy spaces {model.observation_space.shape} -> {model.action_space.shape} do not match "
            f"the residual observation {expected} -> (3,)"
        )
    return ResidualPolicy(model=model, config=config, algo=algo, base=base, metadata=metadata)


def load_residual_controller(
    path: str | Path = DEFAULT_POLICY_PATH, base: Controller | None = None, name: str | None = None
) -> Controller:
    """The shipped (or any saved) residual policy on top of ``base`` as a 1 kHz Controller.

    Args:
        path: A policy zip written by :func:`save_residual_policy`.
        base: The base controller the policy corrects. None rebuilds the base it was trained on from the
            file (model, identified parameters, estimator and tare), so no parameter file is needed.
        name: Row name; by default ``"<base name> + residual"``.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if the file is not a valid residual policy (the message names the path), or if
            ``base`` is None for a policy trained on a custom base.
    """
    policy = load_residual_policy(path)
    if base is None:
        if policy.base is None:
            raise ValueError(f"{path} was trained on a custom base controller: pass base=")
        base = policy.base.controller()
    return ResidualController(base, policy, policy.config, name=name)
