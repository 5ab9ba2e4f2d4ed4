"""The joint states a payload equation is formed at, one class per choice (``PayloadEstimator(regressor=...)``).

Each turns an observation into this step's weighted payload equation (:mod:`controllers.payload.equation`): it
decides at which joint state tau0 and phi are evaluated and which measured torque goes with them. The package
docstring gives the reasons for each.
"""

from __future__ import annotations

import collections
import copy
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import JointStateFilter, JointStateSmoother
from controllers.payload.equation import estimated_state_equation, reference_equation
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD


class Regressor(Protocol):
    """What the estimator needs of a regressor, built from the model and the bytes of the estimator's
    :data:`~controllers.payload.equation.EQUATION` and :data:`~controllers.payload.equation.FIT` records.

    Attributes:
        joint_filter: The joint-state estimator it runs, or None.
        delay: Control periods between the newest observation and the sample whose equation is formed.
    """

    joint_filter: JointStateSmoother | JointStateFilter | None
    delay: int

    def reset(self) -> None:
        """Forget the episode: the next observation is the first."""

    def moments(
        self,
        observation: Observation,
        holding: bool,
        reference_torque: NDArray[np.float64] | None,
        reference_regressor: NDArray[np.float64] | None,
    ) -> tuple[float, float] | None:
        """This step's equation (:meth:`~controllers.payload.estimator.PayloadEstimator.measurement`), or None."""


class ReferenceRegressor:
    """tau0 and phi on the reference, interpolated back to the torque's instant: no lag and no noise, but it assumes
    the robot is where the reference is (``regressor="reference"``)."""

    def __init__(self, dynamics: DeltaDynamics, equation: NDArray[np.uint8], fit: NDArray[np.uint8]) -> None:
        self.dynamics = dynamics
        self._equation, self._fit = equation, fit
        self.joint_filter = None
        self.delay = 0
        # (2, 5, 3): the reference's tau0, phi, theta, rates and accelerations of this step and the previous one.
        self._references = np.zeros((2, 5, 3))
        self._slot = 0
        self._has_previous = False

    def reset(self) -> None:
        self._has_previous = False

    def moments(
        self,
        observation: Observation,
        holding: bool,
        reference_torque: NDArray[np.float64] | None,
        reference_regressor: NDArray[np.float64] | None,
    ) -> tuple[float, float] | None:
        """The equation at this step's reference; ``reference_torque`` and ``reference_regressor`` (tau0, N m, and
        phi, N m/kg, there) if the caller has them already, computed otherwise."""
        if reference_torque is None or reference_regressor is None:
            reference_torque, reference_regressor = self.dynamics.torque_and_payload_regressor(
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
            )
        # Two buffers used in turn: this step's reference and the previous step's.
        self._slot = 1 - self._slot
        current = self._references[self._slot]
        current[0], current[1] = reference_torque, reference_regressor
        current[2] = observation["reference_angles"]
        current[3] = observation["reference_velocities"]
        current[4] = observation["reference_accelerations"]
        previous = self._references[1 - self._slot] if self._has_previous else current
        self._has_previous = True
        # The torque was measured MEASURED_TORQUE_DELAY before the encoders and the reference of this step.
        used, information, moment = reference_equation(
            self._equation, self._fit, holding, current, previous, *observation["joint_torques"].tolist()
        )
        return (information, moment) if used else None


class _EstimatedStateRegressor(ABC):
    """tau0 and phi on a joint-state estimate of sample k - D, with the torque measured with that sample."""

    def __init__(
        self,
        dynamics: DeltaDynamics,
        equation: NDArray[np.uint8],
        fit: NDArray[np.uint8],
        joint_filter: JointStateSmoother | JointStateFilter,
        delay: int,
    ) -> None:
        self.dynamics = dynamics
        self._model, self._equation, self._fit = dynamics.model_constants, equation, fit
        self.joint_filter = joint_filter
        self.delay = delay
        # (what the joint state of the sample is formed from, measured torque, gripper holding) of the last D + 1.
        self._history: collections.deque[tuple[NDArray, list[float], bool]] = collections.deque(maxlen=delay + 1)
        self._started = False
        self._previous_state: NDArray[np.float64] | None = None  # (3, 3): theta, theta_dot, theta_ddot

    def reset(self) -> None:
        self._started = False
        self._previous_state = None
        self._history.clear()

    @abstractmethod
    def _observe(self, observation: Observation) -> tuple[NDArray, NDArray]:
        """Update the joint filter: its newest output and what to keep of this sample in the history."""

    @abstractmethod
    def _state(self, newest: NDArray, delayed: NDArray) -> NDArray[np.float64]:
        """The (3, 3) joint state of sample k - D from the filter's newest output and that sample's history entry."""

    def moments(
        self,
        observation: Observation,
        holding: bool,
        reference_torque: NDArray[np.float64] | None,
        reference_regressor: NDArray[np.float64] | None,
    ) -> tuple[float, float] | None:
        """The equation at the estimated state of sample k - D (the reference's tau0 and phi are not used)."""
        newest, kept = self._observe(observation)
        self._history.append((kept, observation["joint_torques"].tolist(), holding))
        if len(self._history) <= self.delay:
            return None
        delayed, torque, held = self._history[0]
        state = self._state(newest, delayed)
        previous_state = self._previous_state if self._previous_state is not None else state
        self._previous_state = state
        if holding != held:
            return None
        # The torque of sample k - D was measured MEASURED_TORQUE_DELAY before its encoder sample.
        status, used, information, moment = estimated_state_equation(
            self._model, self._equation, self._fit, state, previous_state, holding, *torque
        )
        if status != kernels.VALID:
            raise ValueError(f"{kernels.INVALID_STATE[status]}: joint state estimate {state!r}")
        return (information, moment) if used else None


class SmoothedRegressor(_EstimatedStateRegressor):
    """The fixed-lag smoother's estimate of sample k - L (``regressor="smoothed"``): it smooths the tracking error
    theta - theta_ref, and the reference's exact derivatives at sample k - L are added back."""

    def __init__(self, dynamics: DeltaDynamics, equation: NDArray[np.uint8], fit: NDArray[np.uint8]) -> None:
        smoother = JointStateSmoother()
        super().__init__(dynamics, equation, fit, smoother, smoother.lag)

    def _observe(self, observation: Observation) -> tuple[NDArray, NDArray]:
        angles = observation["joint_angles"]
        reference = np.array(
            (
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
            )
        )
        if not self._started:
            self.joint_filter.reset(angles - reference[0])
            self._started = True
        return self.joint_filter.update_state(angles - reference[0]), reference

    def _state(self, newest: NDArray, delayed: NDArray) -> NDArray[np.float64]:
        return newest + delayed


class FilteredRegressor(_EstimatedStateRegressor):
    """The causal Kalman filter's estimate (``regressor="filtered"``): angle and rate of sample k - D with the
    acceleration estimated at sample k, D its acceleration lag (:func:`acceleration_lag`) in samples."""

    def __init__(self, dynamics: DeltaDynamics, equation: NDArray[np.uint8], fit: NDArray[np.uint8]) -> None:
        joint_filter = JointStateFilter()
        delay = round(acceleration_lag(joint_filter) / CONTROL_PERIOD)
        super().__init__(dynamics, equation, fit, joint_filter, delay)

    def _observe(self, observation: Observation) -> tuple[NDArray, NDArray]:
        angles = observation["joint_angles"]
        if not self._started:
            self.joint_filter.reset(angles)
            self._started = True
        estimate = self.joint_filter.update(angles)
        return estimate, estimate

    def _state(self, newest: NDArray, delayed: NDArray) -> NDArray[np.float64]:
        return np.array((delayed[0], delayed[1], newest[2]))


REGRESSORS: dict[str, Callable[[DeltaDynamics, NDArray[np.uint8], NDArray[np.uint8]], Regressor]] = {
    "smoothed": SmoothedRegressor,
    "filtered": FilteredRegressor,
    "reference": ReferenceRegressor,
}
"""The regressor of each ``PayloadEstimator(regressor=...)`` name (a :class:`Regressor` factory)."""


def acceleration_lag(joint_filter: JointStateFilter, dt: float = CONTROL_PERIOD) -> float:
    """Steady-state lag (s) of a joint filter's acceleration estimate behind a constant-jerk motion.

    A copy of the filter is run on theta = j t^3 / 6 until its error settles; the acceleration error over
    the jerk is the lag. The constant-acceleration model tracks angle and rate of such a motion without
    lag (below 0.02 ms at the default settings), so the acceleration is the one to align.
    """
    probe = copy.deepcopy(joint_filter)
    probe.reset(np.zeros(3))
    jerk, samples = 1000.0, 500
    for n in range(1, samples + 1):
        _, _, theta_ddot = probe.update(np.full(3, jerk * (n * dt) ** 3 / 6.0))
    return float(jerk * samples * dt - theta_ddot[0]) / jerk
