"""Base controller + residual policy at 1 kHz, from observations only: the evaluation's "residual" row."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation, payload_estimate_reader, payload_estimator_of
from controllers.residual.config import ResidualConfig, residual_gain
from controllers.residual.features import ResidualFeatures

if TYPE_CHECKING:
    from controllers.payload import PayloadEstimator

PolicyFunction = Callable[[NDArray[np.float32]], NDArray[np.float32]]
"""Maps one policy observation (float32, (ResidualFeatures.size,)) to an action in [-1, 1]^3."""


class ResidualController:
    """Base controller + residual policy at 1 kHz, from observations only: the "residual" row.

    Runs exactly the loop of :class:`DeltaResidualEnv`: the base torque every control step, a new
    policy action every ``config.action_period`` steps (the first at the episode's first step),
    held in between, scaled by :func:`residual_gain` (``config.off_at_rest``, ``config.fade_speed``).

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
        self._base_estimate = payload_estimate_reader(base)
        self._base_estimator = payload_estimator_of(base)
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
        return self._base_estimate()

    @property
    def estimator(self) -> PayloadEstimator | None:
        """The base controller's payload estimator, or None: a fault monitor keeps faulty samples out of it."""
        return self._base_estimator

    @property
    def residual_torque(self) -> NDArray[np.float64]:
        """The residual torque (N m) added in this control step, (3,)."""
        return self._residual.copy()

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        base_torque = self.base(observation)
        if self._step == 0:
            self._features.reset(observation, base_torque, self._base_estimate())
        else:
            self._features.update(observation, base_torque, self._base_estimate())
        if self._step % self.config.action_period == 0:
            action = np.asarray(self.policy(self._features.policy_observation(self._action)), dtype=float)
            if action.shape != (3,) or not np.all(np.isfinite(action)):
                raise ValueError(f"the residual policy must return 3 finite values, got {action!r}")
            self._action = np.clip(action, -1.0, 1.0)
            self._residual = self.config.residual_limit * self._action  # held until the next policy step
        self._step += 1
        return base_torque + residual_gain(self.config, observation["reference_velocities"]) * self._residual
