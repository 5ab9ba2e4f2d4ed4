"""The joint states a payload equation is formed at, one class per choice (``PayloadEstimator(regressor=...)``).

Each turns an observation into this step's weighted payload equation (:mod:`controllers.payload.equation`): it
decides at which joint state tau0 and phi are evaluated and which measured torque goes with them. The package
docstring gives the reasons for each.
"""

from __future__ import annotations

import collections
import copy
import math
from collections.abc import Callable
from typing import Protocol

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import DELAYED_STATE_FIELDS, JointStateFilter, JointStateSmoother, delayed_state_step
from controllers.payload.equation import estimated_state_equation, reference_equation
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD


class Regressor(Protocol):
    """What the estimator needs of a regressor, built from the model and the bytes of the estimator's
    :data:`~controllers.payload.equation.EQUATION` and :data:`~controllers.payload.equation.FIT` records (the
    latter its :class:`~controllers.payload.fit.CorrectionFit`'s, to which the empty moves' samples go).

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
            self._equation, self._fit, holding, current, previous, observation["joint_torques"]
        )
        return (information, moment) if used else None


class SmoothedRegressor:
    """The fixed-lag smoother's estimate of sample k - L (``regressor="smoothed"``): it smooths the tracking error
    theta - theta_ref, and the reference's exact derivatives at sample k - L are added back; tau0 and phi there,
    with the torque measured with that sample. Its state is a :data:`SMOOTHED` record, one compiled call per sample
    (:func:`smoothed_moments`).

    Attributes:
        joint_filter: The :class:`JointStateSmoother` whose weights the record holds (the record keeps the window).
        state: The record's bytes.
    """

    def __init__(self, dynamics: DeltaDynamics, equation: NDArray[np.uint8], fit: NDArray[np.uint8]) -> None:
        self.dynamics = dynamics
        self.model, self._equation, self._fit = dynamics.model_constants, equation, fit
        self.joint_filter = JointStateSmoother()
        self.delay = self.joint_filter.lag
        self.state = np.zeros(1, SMOOTHED).view(np.uint8)
        self._record = self.state.view(SMOOTHED)
        self._record["weights"] = self.joint_filter.weights
        self.reset()

    def reset(self) -> None:
        record = self._record
        record["started"] = record["has_previous"] = False
        record["next_slot"] = record["pending_head"] = record["pending_count"] = 0

    def moments(
        self,
        observation: Observation,
        holding: bool,
        reference_torque: NDArray[np.float64] | None,
        reference_regressor: NDArray[np.float64] | None,
    ) -> tuple[float, float] | None:
        """The equation at the smoothed state of sample k - L (the reference's tau0 and phi are not used)."""
        status, used, information, moment = smoothed_moments(
            self.state,
            self.model,
            self._equation,
            self._fit,
            observation["joint_angles"],
            observation["reference_angles"],
            observation["reference_velocities"],
            observation["reference_accelerations"],
            observation["joint_torques"],
            holding,
        )
        if status == kernels.NOT_FINITE:
            error = observation["joint_angles"] - observation["reference_angles"]
            raise ValueError(f"the tracking error must be 3 finite values (one per joint), got {error!r}")
        # a smoothed state the model cannot take (a plant gone astray, which the env ends as diverged): no equation
        return (information, moment) if used and status == kernels.VALID else None


class FilteredRegressor:
    """The causal Kalman filter's estimate (``regressor="filtered"``): angle and rate of sample k - D with the
    acceleration estimated at sample k, D its acceleration lag (:func:`acceleration_lag`) in samples; tau0 and phi
    there, with the torque measured with sample k - D."""

    def __init__(self, dynamics: DeltaDynamics, equation: NDArray[np.uint8], fit: NDArray[np.uint8]) -> None:
        self.dynamics = dynamics
        self._model, self._equation, self._fit = dynamics.model_constants, equation, fit
        self.joint_filter = JointStateFilter()
        self.delay = round(acceleration_lag(self.joint_filter) / CONTROL_PERIOD)
        # (the filter's estimate, measured torque, gripper holding) of the last D + 1 samples.
        self._history: collections.deque[tuple[NDArray, NDArray, bool]] = collections.deque(maxlen=self.delay + 1)
        self._started = False
        self._previous_state: NDArray[np.float64] | None = None  # (3, 3): theta, theta_dot, theta_ddot

    def reset(self) -> None:
        self._started = False
        self._previous_state = None
        self._history.clear()

    def moments(
        self,
        observation: Observation,
        holding: bool,
        reference_torque: NDArray[np.float64] | None,
        reference_regressor: NDArray[np.float64] | None,
    ) -> tuple[float, float] | None:
        """The equation at the filtered state of sample k - D (the reference's tau0 and phi are not used)."""
        angles = observation["joint_angles"]
        if not self._started:
            self.joint_filter.reset(angles)
            self._started = True
        newest = self.joint_filter.update(angles)
        self._history.append((newest, observation["joint_torques"].copy(), holding))
        if len(self._history) <= self.delay:
            return None
        delayed, torque, held = self._history[0]
        state = np.array((delayed[0], delayed[1], newest[2]))
        previous_state = self._previous_state if self._previous_state is not None else state
        self._previous_state = state
        if holding != held:
            return None
        # The torque of sample k - D was measured MEASURED_TORQUE_DELAY before its encoder sample.
        status, used, information, moment = estimated_state_equation(
            self._model, self._equation, self._fit, state, previous_state, holding, torque
        )
        # a state the model cannot take (a plant gone astray, which the env ends as diverged): no equation
        return (information, moment) if used and status == kernels.VALID else None


SMOOTHED = np.dtype((np.record, DELAYED_STATE_FIELDS))
"""The state of :func:`smoothed_moments`: the smoother's window of tracking errors and the readings the smoothed
state lags behind (rows of the joint states theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2), torques (N m))."""


@numba.njit(cache=True)
def smoothed_moments(
    regressor: NDArray[np.uint8],
    model: NDArray[np.uint8],
    equation: NDArray[np.uint8],
    fit: NDArray[np.uint8],
    angles: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
    holding: bool,
) -> tuple[int, bool, float, float]:
    """One reading into the :data:`SMOOTHED` record ``regressor`` (in place): the observation's angles (rad), the
    reference's angles, rates and accelerations (rad, rad/s, rad/s^2) and torque (N m), each (3,), as the env gives
    them; returns the equation of the sample a lag ago: (status, used, sum w phi^2, sum w phi y).

    The status is :data:`~delta_env.kernels.NOT_FINITE` for a reading whose tracking error is not finite (nothing
    changes), else the model's at the smoothed state (that state is then in ``previous``).
    """
    r = regressor.view(SMOOTHED)[0]
    error = angles - reference_angles
    if not math.isfinite(error[0] + error[1] + error[2]):
        return kernels.NOT_FINITE, False, 0.0, 0.0
    head, state, previous = delayed_state_step(
        r, error, reference_angles, reference_rates, reference_accelerations, torque, holding
    )
    if head < 0:
        return kernels.VALID, False, 0.0, 0.0
    if holding != (r.pending_holding[head] != 0):
        return kernels.VALID, False, 0.0, 0.0
    # the torque of sample k - L was measured MEASURED_TORQUE_DELAY before its encoder sample
    return estimated_state_equation(model, equation, fit, state, previous, holding, r.pending_torque[head])


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
