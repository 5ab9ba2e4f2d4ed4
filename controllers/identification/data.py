"""Identification samples: smoothed joint motion aligned with the measured torques (docs/design.md section 7).

Rates and accelerations of recorded encoder angles come from the Kalman RTS smoother
(:func:`controllers.estimation.smooth_joint_motion`), interpolated back to the instant each torque was
measured (``delta_env.sensors.MEASURED_TORQUE_DELAY`` before its encoder sample); the record's ends, where
the smoother sees one side only, are trimmed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import smooth_joint_motion
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY

TRIM_SAMPLES = 50
"""Samples dropped at each end of a record (50 ms): the RTS smoother has data on one side only there
(its estimates are poor for ~20 samples) and the first torque reading precedes the first command."""

REST_VELOCITY = 0.02
"""Smoothed rates below this (rad/s) are set to exactly 0: the joint is at rest.

At rest the RTS smoother's rates are encoder quantization noise (up to 0.011 rad/s in the dwells of the
default excitation), whose sign would switch the models' Coulomb term fc sign(thd) at random; at rest the
feedforward sees the reference's exact zero rate, so sign 0 is also how the models are used there.
"""


@dataclass(frozen=True, eq=False)
class MotionData:
    """Identification samples: joint motion and the motor torque that produced it, ``(M, 3)`` each.

    Attributes:
        theta: Joint angles (rad).
        theta_dot: Joint rates (rad/s).
        theta_ddot: Joint accelerations (rad/s^2).
        torque: Motor torques (N m).
    """

    theta: NDArray[np.float64]
    theta_dot: NDArray[np.float64]
    theta_ddot: NDArray[np.float64]
    torque: NDArray[np.float64]

    def __post_init__(self) -> None:
        shape = np.shape(self.theta)
        if len(shape) != 2 or shape[1] != 3 or shape[0] < 1:
            raise ValueError(f"theta must have shape (M >= 1, 3), got {shape}")
        for name in ("theta", "theta_dot", "theta_ddot", "torque"):
            array = np.array(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f"{name} must have the shape of theta {shape}, got {array.shape}")
            if not np.all(np.isfinite(array)):
                raise ValueError(f"{name} must be finite")
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    def __len__(self) -> int:
        return len(self.theta)


def _interpolate(values: NDArray[np.float64], delay_samples: float) -> NDArray[np.float64]:
    """``values`` (N, 3) linearly interpolated at sample times n - delay_samples (held at the ends)."""
    grid = np.arange(len(values), dtype=float)
    return np.column_stack([np.interp(grid - delay_samples, grid, column) for column in values.T])


def motion_at_torque_samples(
    angles: ArrayLike, dt: float = CONTROL_PERIOD, torque_delay: float = MEASURED_TORQUE_DELAY
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Smoothed joint motion of recorded encoder angles at the instants their torques were measured.

    Args:
        angles: Encoder angles (rad), ``(N, 3)``, sampled every ``dt`` (s).
        dt: Sample period (s).
        torque_delay: Age of a torque reading relative to its encoder sample (s).

    Returns:
        theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2), each ``(N, 3)``; sample n is taken
        ``torque_delay`` before encoder sample n (held at the first sample).
    """
    delay = torque_delay / dt
    return tuple(_interpolate(x, delay) for x in smooth_joint_motion(angles, dt))


def prepare_motion(
    angles: ArrayLike,
    torques: ArrayLike,
    dt: float = CONTROL_PERIOD,
    *,
    trim: int = TRIM_SAMPLES,
    torque_delay: float = MEASURED_TORQUE_DELAY,
    rest_velocity: float = REST_VELOCITY,
) -> MotionData:
    """Identification samples of a record: smoothed motion aligned with the torques, edges trimmed.

    Args:
        angles: Encoder angles (rad), ``(N, 3)``.
        torques: Measured motor torques (N m), ``(N, 3)``; reading n comes with encoder sample n.
        dt: Sample period (s).
        trim: Samples dropped at each end (:data:`TRIM_SAMPLES`).
        torque_delay: Age of the torque readings (s), ``MEASURED_TORQUE_DELAY``.
        rest_velocity: Rates below this (rad/s) are set to 0 (:data:`REST_VELOCITY`).
    """
    angles = np.asarray(angles, dtype=float)
    if len(angles) <= 2 * trim + 1:
        raise ValueError(f"a record of {len(angles)} samples is too short to trim {trim} at each end")
    theta, theta_dot, theta_ddot = motion_at_torque_samples(angles, dt, torque_delay)
    theta_dot[np.abs(theta_dot) < rest_velocity] = 0.0
    kept = slice(trim, len(angles) - trim)
    return MotionData(theta[kept], theta_dot[kept], theta_ddot[kept], torque=np.asarray(torques)[kept])


def model_with(dynamics: DeltaDynamics | None, parameters: ModelParameters | None = None) -> DeltaDynamics:
    """``dynamics`` (the nominal lumped model if None) with ``parameters`` (plain MKH if None)."""
    return (DeltaDynamics.nominal() if dynamics is None else dynamics).with_parameters(parameters)


def regressor(data: MotionData, dynamics: DeltaDynamics | None) -> tuple[NDArray, NDArray]:
    """The identification regressor of ``data``: rows (M, 3, 4) [I thdd, G, thd, sign thd] and the target
    tau + 2 K lambda (M, 3), N m, of the model ``dynamics`` (nominal lumped if None)."""
    rows, known = model_with(dynamics).identification_regressor(data.theta, data.theta_dot, data.theta_ddot)
    return rows, data.torque - known


def torque_errors(
    parameters: ModelParameters, data: MotionData, dynamics: DeltaDynamics | None = None
) -> NDArray[np.float64]:
    """tau - tau_hat (N m), ``(M, 3)``: measured minus model torque along the data's motion."""
    model = model_with(dynamics, parameters)
    return data.torque - model.inverse_dynamics(data.theta, data.theta_dot, data.theta_ddot)


def error_table(models: Mapping[str, DeltaDynamics], data: MotionData) -> dict[str, dict[str, list[float]]]:
    """The paper's Table 1: per model (with its parameters) the mean and std of tau - tau_hat per joint (N m).

    Returns:
        ``{name: {"mean": [3], "std": [3], "rms": [3]}}``, in the order of ``models``.
    """
    table = {}
    for name, model in models.items():
        errors = data.torque - model.inverse_dynamics(data.theta, data.theta_dot, data.theta_ddot)
        table[name] = {
            "mean": errors.mean(axis=0).tolist(),
            "std": errors.std(axis=0).tolist(),
            "rms": np.sqrt(np.mean(errors**2, axis=0)).tolist(),
        }
    return table


def concatenate(data: Sequence[MotionData]) -> MotionData:
    """The samples of several records as one :class:`MotionData`."""
    if not data:
        raise ValueError("need at least one MotionData")
    fields = ("theta", "theta_dot", "theta_ddot", "torque")
    return MotionData(*(np.concatenate([getattr(d, name) for d in data]) for name in fields))
