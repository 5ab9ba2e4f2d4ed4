"""The drive's current-loop lag: its identification from excitation data, and the reference one period ahead.

The plant's drive is a first-order lag T dtau/dt = u - tau per joint (:mod:`delta_env.drive`). A command u_k
held over the control period Delta gives tau(t_k + s) = e^{-s/T} tau(t_k) + (1 - e^{-s/T}) u_k for s in
[0, Delta]; the torque the drive reports at instant k + 1 is the output one physics step h before it
(the force MuJoCo held over the last physics step, ``delta_env.sensors.PHYSICS_TIMESTEP``), i.e. at
s = Delta - h.

Identification (:func:`identify_lag`) is an output-error fit per joint: the commands alone are run through
that exact sampled model for a trial T, and T minimizes the squared difference to the measured torques
(``scipy.optimize.minimize_scalar``, bounded). Only the measurements carry noise, so the fit is consistent;
an equation-error least squares on tau[k+1] = a tau[k] + (1 - a) u[k] would have the noisy torque as its
regressor and be biased towards a faster drive.

Control: :class:`ReferencePredictor` gives the reference ahead, where the controllers that lead the lag
(:class:`controllers.feedforward.LagCompensatedController`, one period ahead, and the oracle, at the lead that
gives the held command's physics steps the mean of the wanted torque) evaluate their feedforward before passing
it through the exact inverse of the sampled lag.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar
from scipy.signal import lfilter

from controllers.base import Observation
from delta_env.drive import MAX_TIME_CONSTANT
from delta_env.sensors import CONTROL_PERIOD, PHYSICS_TIMESTEP
from delta_env.trajectories import Trajectory

MIN_TIME_CONSTANT = 1e-5
"""Smallest lag (s) the fit considers; below it the drive is a direct torque source at 1 kHz."""


class ReferencePredictor:
    """The joint reference a short horizon ahead (one control period by default), from the reference of this step
    and the last one, or from the reference's samples ahead when it is given them (:meth:`follow`).

    A cubic Taylor step: the jerk is the backward difference of the reference accelerations over the period (0 at
    the first step). The error is of order horizon^2 times the reference's snap, or horizon times a jump of its
    jerk: a jerk step of the reference is seen one period late. Following the reference's samples, the prediction
    is the quintic Hermite interpolant of the two samples around the instant (exact for a quintic, within
    period times a jerk step across one).

    Args:
        period: Control period (s), in (0, 0.1].
        horizon: How far ahead (s), per joint (shape (3,)) or one for all, each in [0, 2 period]; one period when
            None. The oracle aims at :meth:`delta_env.drive.SampledLag.hold_lead`.
    """

    def __init__(self, period: float = CONTROL_PERIOD, horizon: ArrayLike | None = None) -> None:
        if not (math.isfinite(period) and 0.0 < period <= 0.1):
            raise ValueError(f"period must lie in (0, 0.1] s, got {period}")
        self.period = float(period)
        horizon = np.broadcast_to(np.asarray(self.period if horizon is None else horizon, dtype=float), (3,))
        if not np.all(np.isfinite(horizon) & (horizon >= 0.0) & (horizon <= 2.0 * self.period)):
            raise ValueError(f"horizon must lie in [0, {2.0 * self.period}] s, got {horizon.tolist()}")
        self.horizon = horizon.copy()
        self.trajectory: Trajectory | None = None
        self._last_acceleration = np.zeros(3)
        self._has_last = False
        self._step = 0

    def follow(self, trajectory: Trajectory | None) -> None:
        """Predict from ``trajectory``'s samples (the reference ahead, a privilege of the oracle) while each step's
        reference is its sample k, k the steps since :meth:`reset`; None: from this step's reference alone.

        Raises:
            ValueError: if the trajectory's sample period is not the control period.
        """
        if trajectory is not None and not math.isclose(trajectory.dt, self.period):
            raise ValueError(f"the trajectory's sample period {trajectory.dt} s must be the period {self.period} s")
        self.trajectory = trajectory

    def reset(self) -> None:
        """Forget the last reference (a new episode); a trajectory followed is kept (give the new one)."""
        self._has_last = False
        self._step = 0

    def next(self, observation: Observation) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Reference angles (rad), rates (rad/s) and accelerations (rad/s^2) one horizon ahead, each (3,)."""
        return self.jet(observation)[:3]

    def jet(self, observation: Observation) -> tuple[NDArray[np.float64], ...]:
        """The reference one horizon ahead with its jerk (rad/s^3) and snap (rad/s^4): five (3,) arrays, the first
        three those of :meth:`next` (call one of the two per step). Following the reference's samples they are the
        Hermite interpolant's (its jerk and snap within period^3 and period^2 times the reference's sixth
        derivative, a jerk step of the reference spread over the period around it); predicted, the jerk is the last
        period's and the snap 0."""
        angles = observation["reference_angles"]
        prediction = _taylor_step(
            angles,
            observation["reference_velocities"],
            observation["reference_accelerations"],
            self._last_acceleration,
            self._has_last,
            self.horizon,
            self.period,
        )
        self._has_last = True
        k, self._step = self._step, self._step + 1
        trajectory = self.trajectory
        if trajectory is not None and k + 2 < len(trajectory) and np.array_equal(angles, trajectory.theta[k]):
            return _hermite_step(
                trajectory.theta, trajectory.theta_dot, trajectory.theta_ddot, k, self.horizon, self.period
            )
        return prediction


@numba.njit(cache=True)
def _hermite_step(
    theta: NDArray[np.float64],
    theta_dot: NDArray[np.float64],
    theta_ddot: NDArray[np.float64],
    k: int,
    horizon: NDArray[np.float64],
    period: float,
) -> tuple[NDArray[np.float64], ...]:
    """Angles, rates, accelerations, jerks and snaps, each (3,), at k period + horizon by the quintic Hermite
    interpolant of the samples around it; samples k + 2 must exist."""
    angle, rate, acceleration, jerk, snap = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for joint in range(3):
        s = horizon[joint] / period
        i = k
        if s > 1.0:
            i, s = k + 1, s - 1.0
        # samples i and i + 1 in units of the period: p(s) = sum c_n s^n on s in [0, 1]
        p0, p1 = theta[i, joint], theta[i + 1, joint]
        v0, v1 = theta_dot[i, joint] * period, theta_dot[i + 1, joint] * period
        a0, a1 = theta_ddot[i, joint] * period**2, theta_ddot[i + 1, joint] * period**2
        step = p1 - p0
        c3 = 10.0 * step - 6.0 * v0 - 4.0 * v1 - 1.5 * a0 + 0.5 * a1
        c4 = -15.0 * step + 8.0 * v0 + 7.0 * v1 + 1.5 * a0 - a1
        c5 = 6.0 * step - 3.0 * v0 - 3.0 * v1 - 0.5 * a0 + 0.5 * a1
        angle[joint] = p0 + s * (v0 + s * (0.5 * a0 + s * (c3 + s * (c4 + s * c5))))
        rate[joint] = (v0 + s * (a0 + s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5)))) / period
        acceleration[joint] = (a0 + s * (6.0 * c3 + s * (12.0 * c4 + s * 20.0 * c5))) / period**2
        jerk[joint] = (6.0 * c3 + s * (24.0 * c4 + s * 60.0 * c5)) / period**3
        snap[joint] = (24.0 * c4 + s * 120.0 * c5) / period**4
    return angle, rate, acceleration, jerk, snap


@numba.njit(cache=True)
def _taylor_step(
    theta: NDArray[np.float64],
    theta_dot: NDArray[np.float64],
    theta_ddot: NDArray[np.float64],
    last_acceleration: NDArray[np.float64],
    has_last: bool,
    horizon: NDArray[np.float64],
    period: float,
) -> tuple[NDArray[np.float64], ...]:
    """:meth:`ReferencePredictor.jet` per joint in scalar math (a dozen NumPy calls on three values cost more);
    ``last_acceleration`` (3,) is the last step's reference acceleration, replaced by this step's."""
    angle, rate, acceleration, jerk = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for joint in range(3):
        p, v, a = theta[joint], theta_dot[joint], theta_ddot[joint]
        dt = horizon[joint]
        # the acceleration's change over the horizon: the last period's change, scaled (bit for bit itself at 1)
        j = (a - last_acceleration[joint]) * (dt / period) if has_last else 0.0
        jerk[joint] = (a - last_acceleration[joint]) / period if has_last else 0.0
        last_acceleration[joint] = a
        angle[joint] = p + dt * (v + dt * (0.5 * a + j / 6.0))
        rate[joint] = v + dt * (a + 0.5 * j)
        acceleration[joint] = a + j
    return angle, rate, acceleration, jerk, np.zeros(3)


class MeasuredReferenceRate:
    """The reference rate as the joint rate is measured: its mean over the window ending now that the observed
    ``joint_velocities`` average over (:func:`delta_env.sensors.rate_window`).

    (theta(t) - theta(t - w)) / w = theta_dot - w theta_ddot / 2 + w^2 theta_dddot / 6 + O(w^3), the jerk being the
    backward difference of the reference accelerations over the period (0 at the first step): the past the window
    covers, so a jerk step of the reference is no error here. A feedback that compares this with the measured rate
    is zero on the reference; the instantaneous reference rate would leave w theta_ddot / 2 between them.

    Args:
        window: The measuring window w (s), in (0, period].
        period: Control period (s), in (0, 0.1].
    """

    def __init__(self, window: float, period: float = CONTROL_PERIOD) -> None:
        if not (math.isfinite(period) and 0.0 < period <= 0.1):
            raise ValueError(f"period must lie in (0, 0.1] s, got {period}")
        if not (math.isfinite(window) and 0.0 < window <= period):
            raise ValueError(f"window must lie in (0, {period}] s, got {window}")
        self.window = float(window)
        self.period = float(period)
        self._last_acceleration: list[float] | None = None

    def reset(self) -> None:
        """Forget the last reference (a new episode)."""
        self._last_acceleration = None

    def rates(self, observation: Observation) -> list[float]:
        """The reference's mean rate (rad/s) per joint over the window ending at this step: three floats (the 1 kHz
        path of the servo layer; at three values, Python floats cost less than NumPy's operations)."""
        acceleration = observation["reference_accelerations"].tolist()
        last, self._last_acceleration = self._last_acceleration, acceleration
        w, period = self.window, self.period
        rates = observation["reference_velocities"].tolist()
        for joint in range(3):
            jerk = 0.0 if last is None else (acceleration[joint] - last[joint]) / period
            rates[joint] -= w * (0.5 * acceleration[joint] - w * jerk / 6.0)
        return rates

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        """The reference's mean rate (rad/s, shape (3,)) over the window ending at this step (:meth:`rates`)."""
        return np.array(self.rates(observation))


def measured_lag_response(
    commands: ArrayLike,
    time_constant: float,
    initial: float = 0.0,
    period: float = CONTROL_PERIOD,
    sample_delay: float = PHYSICS_TIMESTEP,
) -> NDArray[np.float64]:
    """The torques a drive with lag ``time_constant`` reports for a sequence of held commands.

    Args:
        commands: Command u_k (N m) held over period k, shape (N,).
        time_constant: Lag T (s), >= 0.
        initial: Drive output (N m) at the first control instant.
        period: Control period (s).
        sample_delay: How long before the control instant the reported torque is taken (s), in [0, period).

    Returns:
        The torque reported at instants 1 ... N (N m), shape (N,): the output at t_{k+1} - sample_delay.
    """
    commands = np.asarray(commands, dtype=float)
    if time_constant <= 0.0:
        return commands.copy()
    pole = math.exp(-period / time_constant)
    to_sample = math.exp(-(period - sample_delay) / time_constant)
    # Output at the instants: out_{k+1} = pole out_k + (1 - pole) u_k, a one-pole filter.
    outputs, _ = lfilter([1.0 - pole], [1.0, -pole], commands, zi=[pole * initial])
    at_instants = np.concatenate(([initial], outputs[:-1]))
    return to_sample * at_instants + (1.0 - to_sample) * commands


def identify_lag(
    commands: ArrayLike,
    measured: ArrayLike,
    period: float = CONTROL_PERIOD,
    sample_delay: float = PHYSICS_TIMESTEP,
    skip: int = 20,
) -> NDArray[np.float64]:
    """Per-joint drive lag (s) from held commands and the torques the drive reported.

    Output-error fit (module docstring): the drive's output at the first instant is taken as the first
    measurement, and the first ``skip`` samples, where that guess still matters (its weight decays as
    e^{-k period / T}), are left out of the cost.

    Args:
        commands: Commands u_k (N m) as the plant applied them (after the torque limit), shape (N, 3).
        measured: Torque reported at the instant after each command (N m), shape (N, 3): the
            ``joint_torques`` of the observation that ``env.step(u_k)`` returns.
        period: Control period (s).
        sample_delay: How long before the control instant the reported torque is taken (s).
        skip: Leading samples left out of the cost, >= 0 and < N - 10.

    Returns:
        Lag time constants T (s), shape (3,), each in [1e-5, 0.1].

    Raises:
        ValueError: for mismatched shapes, non-finite values, too few samples or a command that never moves.
    """
    commands, measured = np.asarray(commands, dtype=float), np.asarray(measured, dtype=float)
    if commands.ndim != 2 or commands.shape[1] != 3:
        raise ValueError(f"commands must have shape (N, 3), got {commands.shape}")
    if measured.shape != commands.shape:
        raise ValueError(f"measured must have the shape of commands {commands.shape}, got {measured.shape}")
    if not (np.all(np.isfinite(commands)) and np.all(np.isfinite(measured))):
        raise ValueError("commands and measured torques must be finite")
    if not (isinstance(skip, int) and 0 <= skip < len(commands) - 10):
        raise ValueError(f"skip must be an int in [0, {len(commands) - 10}), got {skip!r}")
    if np.any(np.ptp(commands[skip:], axis=0) <= 0.0):
        raise ValueError("every joint's command must vary: a constant command does not show the lag")
    lags = np.empty(3)
    for joint in range(3):
        u, y = commands[:, joint], measured[:, joint]

        def cost(log_lag: float, u: NDArray = u, y: NDArray = y) -> float:
            predicted = measured_lag_response(u, math.exp(log_lag), y[0], period, sample_delay)
            return float(np.sum((predicted[skip:] - y[skip:]) ** 2))

        result = minimize_scalar(
            cost,
            bounds=(math.log(MIN_TIME_CONSTANT), math.log(MAX_TIME_CONSTANT)),
            method="bounded",
            options={"xatol": 1e-6},
        )
        lags[joint] = math.exp(result.x)
    return lags
