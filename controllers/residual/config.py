"""Settings shared by the residual env and controller, saved with every trained policy."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from delta_env.config import PlantRealism
from delta_env.env import RewardWeights
from delta_env.geometry import TORQUE_LIMIT
from delta_env.validation import require_count, require_in, require_positive

_DATASHEET = PlantRealism()
"""The drive's datasheet values that the policy's features are built from (ripple order, Stribeck speed)."""


@dataclass(frozen=True)
class ResidualConfig:
    """Settings shared by the residual env and controller; saved with every trained policy.

    Attributes:
        residual_limit: Torque (N m) added per joint at a = +-1: 15 N m, the scale of the identified model's
            feedforward errors (a few N m on 3 g cycles), so that the policy's exploration is too; with 40 N m
            training took several times longer to the same gain (docs/measurements.md). A policy file keeps the
            limit it was trained with (the shipped one: 40 N m).
        action_period: Control steps (1 ms each) per policy step; the action is held in between.
        reward_scale: Factor on the policy-step reward, the sum of the env's per-step rewards over the
            ``action_period`` control steps (dimensionless). With 1.0 a policy step of a base
            controller tracking within 0.4 mm RMS with 20 N m RMS torque scores about -2 at
            ``action_period`` 10.
        ripple_periods: Torque-ripple periods per joint revolution (gear datasheet, docs/design.md
            section 4): the policy sees the ripple phase sin / cos(ripple_periods * theta).
        stribeck_velocity: Speed (rad/s) under which Stribeck friction rises (docs/design.md section 4):
            the policy sees tanh(theta_dot_ref / stribeck_velocity).
        torque_weight: Weight ((N m)^-2) of the squared commanded torque per control step (the torque the policy
            sets, before the drive's envelope clips it), besides the plant env's own term (``RewardWeights.torque``,
            1e-5, on the applied torque). With the plant's alone a percent of torque RMS costs a few
            per mille of the tracking term, so a policy buys its last tenths of a millimetre with it; at 1.5e-4 a
            percent of torque RMS (about 20 (N m)^2 per step at 20 N m per joint) costs about half the tracking
            term of a 0.07 mm RMS controller. 0 (the default) leaves the plant env's reward.
        action_rate_weight: Weight ((N m)^-2) of the squared change of the residual torque between successive
            policy steps, summed over the joints, once per policy step (the first step's change is from zero).
            It prices the step-to-step jitter of the residual, which the tracking does not need but the torque RMS
            pays for; a change that follows the reference's slow errors costs little. 0 (the default) leaves it
            unpriced.
        off_at_rest: Whether the residual is zero on every control step whose reference is at rest (all reference
            joint rates zero: the waits for the in-position signal, the air activation, the dwells), where the base's
            servo layer holds the place. Without it a policy trained on the tracking reward kept pushing at the stops:
            on time-optimal cycles it held the platform outside the 0.05 mm in-position window until the wait timed
            out and released 0.25-0.35 mm off (docs/measurements.md). False (the default) is every policy trained
            before it.
        fade_speed: Reference speed (rad/s) under which the residual fades out: on every control step it is scaled
            by ``min(1, max_j |thd_ref_j| / fade_speed)`` (:func:`residual_gain`), so that it ramps down with the
            reference as a move comes to rest and is zero at rest, with no torque step at the arrival for the servo
            to absorb (the hard gate of ``off_at_rest`` left one: long settles, docs/measurements.md). 0 (the
            default, every policy trained before it) does not fade.
        plant_torque_weight: The plant env's weight ((N m)^-2) of the squared applied torque per control step
            (``RewardWeights.torque``) in the reward the residual is trained on: 1e-5, the plant env's default. On
            the servo base at 3 g that term (about 0.013 per control step at 20 N m RMS per joint) is five times the
            tracking term (0.0025 at 0.05 mm), and varies with the state far more than a residual of a few N m can
            change it: with it a policy gained 4 % tracking RMS in 10 minutes, without it (0) 16 %
            (docs/measurements.md). ``torque_weight`` and ``action_rate_weight`` still price the residual's torque.
    """

    residual_limit: float = 15.0
    action_period: int = 10
    reward_scale: float = 1.0
    ripple_periods: int = field(default=_DATASHEET.ripple_periods)
    stribeck_velocity: float = field(default=_DATASHEET.stribeck_velocity)
    torque_weight: float = 0.0
    action_rate_weight: float = 0.0
    off_at_rest: bool = False
    fade_speed: float = 0.0
    plant_torque_weight: float = field(default=RewardWeights().torque)

    def __post_init__(self) -> None:
        require_in("residual_limit", self.residual_limit, 0.0, TORQUE_LIMIT, unit="N m", low_open=True)
        require_count("action_period", self.action_period)
        require_positive("reward_scale", self.reward_scale)
        require_count("ripple_periods", self.ripple_periods, minimum=0)
        require_positive("stribeck_velocity", self.stribeck_velocity, unit="rad/s")
        require_in("torque_weight", self.torque_weight, 0.0, 1.0, unit="(N m)^-2")
        require_in("plant_torque_weight", self.plant_torque_weight, 0.0, 1.0, unit="(N m)^-2")
        require_in("action_rate_weight", self.action_rate_weight, 0.0, 1.0, unit="(N m)^-2")
        require_in("fade_speed", self.fade_speed, 0.0, math.inf, unit="rad/s")
        object.__setattr__(self, "action_period", int(self.action_period))
        object.__setattr__(self, "ripple_periods", int(self.ripple_periods))
        if not isinstance(self.off_at_rest, bool):
            raise ValueError(f"off_at_rest must be true or false, got {self.off_at_rest!r}")

    def reward_weights(self) -> RewardWeights:
        """The plant env's reward weights of the residual's training: the default tracking weight and
        ``plant_torque_weight``."""
        return RewardWeights(torque=self.plant_torque_weight)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ResidualConfig:
        """The config from :func:`dataclasses.asdict` output; unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = set(values) - names
        if unknown:
            raise ValueError(f"unknown ResidualConfig fields {sorted(unknown)}; known: {sorted(names)}")
        return cls(**values)


def residual_gain(config: ResidualConfig, reference_velocities: NDArray[np.floating]) -> float:
    """The factor (0 to 1) on the residual torque of a control step whose reference joint rates (rad/s, (3,)) are
    ``reference_velocities``: 0 at rest with ``config.off_at_rest``, the fade of ``config.fade_speed``, else 1."""
    if config.fade_speed > 0.0:
        return min(1.0, float(np.max(np.abs(reference_velocities))) / config.fade_speed)
    if config.off_at_rest and not reference_velocities.any():
        return 0.0
    return 1.0
