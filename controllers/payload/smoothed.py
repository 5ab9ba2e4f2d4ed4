"""The ``"smoothed"`` regressor's step, compiled for the 1 kHz loop: the fixed-lag smoother of the tracking error,
the readings it lags behind, the payload equation at the smoothed state and, in :func:`smoothed_update`, the
estimator's checkpoint and RLS update, in one call.

:data:`SMOOTHED` holds the regressor's state; the kernels take its bytes, as those of
:mod:`controllers.payload.equation` take the :data:`~controllers.payload.equation.EQUATION` and
:data:`~controllers.payload.equation.FIT` records'.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.estimation import DELAYED_STATE_FIELDS, delayed_state_step, rls_update
from controllers.payload.equation import FIT, PLATFORM_MASS, estimated_state_equation
from delta_env import kernels

SMOOTHED = np.dtype((np.record, DELAYED_STATE_FIELDS))
"""The state of :func:`smoothed_moments` and :func:`smoothed_update`: rows of the joint states theta (rad),
theta_dot (rad/s), theta_ddot (rad/s^2), torques (N m)."""


@numba.njit(cache=True, inline="always")
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
    """One reading of the :data:`SMOOTHED` record ``regressor`` (in place): angles (rad), the reference's angles,
    rates and accelerations (rad, rad/s, rad/s^2) and torque (N m), each (3,); returns the equation of the sample a lag
    ago: (status, used, sum w phi^2, sum w phi y).

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
    t = r.pending_torque[head]
    return estimated_state_equation(model, equation, fit, state, previous, holding, t[0], t[1], t[2])


@numba.njit(cache=True)
def _copy_fit(source: np.record, target: np.record) -> None:
    """Every field of the :data:`~controllers.payload.equation.FIT` record ``source`` into ``target``."""
    target.information[:, :] = source.information
    target.moment[:] = source.moment
    target.solution[:] = source.solution
    target.stale = source.stale
    target.samples = source.samples


@numba.njit(cache=True)
def smoothed_update(
    regressor: NDArray[np.uint8],
    model: NDArray[np.uint8],
    equation: NDArray[np.uint8],
    fit: NDArray[np.uint8],
    rls: NDArray[np.float64],
    inverse_forgetting: float,
    noise_variance: float,
    fit_checkpoints: NDArray[np.uint8],
    rls_checkpoints: NDArray[np.float64],
    slot: int,
    skip: bool,
    angles: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
    holding: bool,
) -> tuple[int, float]:
    """:meth:`~controllers.payload.estimator.PayloadEstimator.update`'s step after the gripper's edges: (status of
    :func:`smoothed_moments`, apparent mass (kg)).

    ``rls`` is the :class:`~controllers.estimation.PayloadRLS` state (mass (kg), variance (kg^2)), updated in place
    with its 1 / lambda and s^2. With ``slot`` >= 0 the fit and ``rls`` are first saved into that slot of the
    checkpoint rings (``fit_checkpoints``, the bytes of :data:`~controllers.payload.equation.FIT` records, and
    ``rls_checkpoints``, (n, 2)); with ``skip`` the sample then enters neither the fit nor the RLS.
    """
    f = fit.view(FIT)[0]
    if slot >= 0:
        _copy_fit(f, fit_checkpoints.view(FIT)[slot])
        rls_checkpoints[slot, 0] = rls[0]
        rls_checkpoints[slot, 1] = rls[1]
    status, used, information, moment = smoothed_moments(
        regressor,
        model,
        equation,
        fit,
        angles,
        reference_angles,
        reference_rates,
        reference_accelerations,
        torque,
        holding,
    )
    if status != kernels.VALID:
        return status, 0.0
    if skip:
        _copy_fit(fit_checkpoints.view(FIT)[slot], f)
    elif used:
        rls_update(rls, information, moment, inverse_forgetting, noise_variance)
    return status, rls[0] + f.solution[PLATFORM_MASS]
