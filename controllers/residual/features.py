"""The residual policy's observation, built from the 1 kHz observations between two policy steps."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.residual.config import ResidualConfig
from delta_env.sensors import CONTROL_PERIOD

FEATURE_VERSION = 1
"""Version of the observation layout of :class:`ResidualFeatures`; saved with every policy."""

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
FEATURE_CLIP = 10.0
"""Bound of every normalized feature (the observation space is [-FEATURE_CLIP, FEATURE_CLIP]^43)."""

PREVIOUS_ACTION = slice(-3, None)
"""Where the policy observation holds the previous policy action (unnormalized, in [-1, 1]): its last block
(:meth:`ResidualFeatures.policy_observation` appends it after every other feature)."""


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
        # The jerk is formed at policy steps only, from the last two reference accelerations. Like the
        # observation itself, they are kept by reference, not copied: an observation is never changed after it
        # is made (the env's reference rows are read-only views).
        self._previous_acceleration = self._acceleration
        self._acceleration = observation["reference_accelerations"]
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
        self._base_torque = base_torque  # read at the policy step of this same control step, before it can change
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
        return np.clip(vector, -FEATURE_CLIP, FEATURE_CLIP).astype(np.float32)
