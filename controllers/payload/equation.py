"""The payload equation of one control step and the empty-move fit, compiled for the 1 kHz loop.

Two named records carry the state of the kernels, which numba reads and writes by field: :data:`EQUATION`, the
constants of the weighted payload equation (:func:`equation_constants`), and :data:`FIT`, the weighted least squares
of the model's corrections (:class:`~controllers.payload.fit.CorrectionFit`) over the empty moves. The kernels take
each record's bytes, as those of :mod:`delta_env.kernels` do, for a cheaper call from Python.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.compiled_model import single_sample_model
from controllers.dynamics import DeltaDynamics
from delta_env import kernels

PLATFORM_MASS, ARM_MASS_SCALE, FRICTION_SCALE, PARAMETERS = 0, 1, 2, 5
"""Columns of the empty-move fit: dm (kg), d_arm, then kappa_1..3 from FRICTION_SCALE on; PARAMETERS of them."""

EQUATION = np.dtype(
    (
        np.record,
        [
            ("band_std", np.float64, 3),
            ("inverse_friction_velocity", np.float64),
            ("nominal_variance", np.float64),
            ("viscous", np.float64, 3),
            ("coulomb", np.float64, 3),
            ("torque_age", np.float64),
            ("rest_rate", np.float64),
            ("inertia", np.float64),
            ("gravity", np.float64),
        ],
    )
)
"""Constants of the payload equation: the static friction band's standard deviation sqrt(n_c) f_i (N m), 1 / v_w
(s/rad) and sigma_0^2 (N^2 m^2) of :func:`~controllers.payload.tuning.residual_std`; the model's fv_i (N m s/rad) and
fc_i (N m); the torque's age (control periods); the rest rate (rad/s); the unscaled I (kg m^2) and G amplitude (N m)."""

FIT = np.dtype(
    (
        np.record,
        [
            ("prior_information", np.float64, PARAMETERS),
            ("fits", np.bool_),
            ("information", np.float64, (PARAMETERS, PARAMETERS)),
            ("moment", np.float64, PARAMETERS),
            ("solution", np.float64, PARAMETERS),
            ("stale", np.bool_),
            ("samples", np.int64),
        ],
    )
)
"""The empty-move least squares: the prior information 1 / std^2 of each parameter (inf for one held at 0: not
fitted) and whether any is fitted; sum of w c c^T and of w c y, the parameters solved from them, whether equations
came in since, and how many samples entered."""


def equation_constants(
    dynamics: DeltaDynamics,
    static_friction: tuple[float, float, float],
    nominal_std: float,
    friction_velocity: float,
    correlation_samples: float,
    rest_rate: float,
    torque_age: float,
) -> NDArray[np.uint8]:
    """The bytes of the :data:`EQUATION` record of ``dynamics`` and the weighting of
    :func:`~controllers.payload.tuning.residual_std` (arguments in its units; the rest rate in rad/s), its torques
    ``torque_age`` control periods older than their encoder samples."""
    record = np.zeros(1, EQUATION)
    equation = record[0]
    # the band's standard deviation is sqrt(n_c) f_i
    equation["band_std"] = [math.sqrt(correlation_samples) * f for f in static_friction]
    equation["inverse_friction_velocity"] = 1.0 / friction_velocity
    equation["nominal_variance"] = nominal_std**2
    equation["viscous"], equation["coulomb"] = dynamics.parameters.viscous, dynamics.parameters.coulomb
    equation["torque_age"], equation["rest_rate"] = torque_age, rest_rate
    equation["inertia"], equation["gravity"] = dynamics.inertia, dynamics.gravity_amplitude
    return record.view(np.uint8)


@numba.njit(cache=True)
def solve_fit(fit: NDArray[np.uint8]) -> None:
    """Solve the empty-move least squares with its prior (information added to the diagonal) into ``fit``'s
    solution; a parameter of infinite prior information is not fitted: it stays 0."""
    f = fit.view(FIT)[0]
    matrix = np.empty((PARAMETERS, PARAMETERS))
    vector = np.empty(PARAMETERS)
    for a in range(PARAMETERS):
        vector[a] = f.moment[a]
        for b in range(PARAMETERS):
            matrix[a, b] = f.information[a, b]
    for a in range(PARAMETERS):
        if math.isinf(f.prior_information[a]):
            matrix[a, :] = 0.0
            matrix[:, a] = 0.0
            matrix[a, a] = 1.0
            vector[a] = 0.0
        else:
            matrix[a, a] += f.prior_information[a]
    solution = np.linalg.solve(matrix, vector)
    for a in range(PARAMETERS):
        f.solution[a] = solution[a]
    f.stale = False


@numba.njit(cache=True, inline="always")
def weighted_equation(
    equation: NDArray[np.uint8],
    fit: NDArray[np.uint8],
    carrying: bool,
    tau0: NDArray[np.float64],
    phi: NDArray[np.float64],
    angles: NDArray[np.float64],
    rates: NDArray[np.float64],
    accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
) -> tuple[bool, float, float]:
    """One sample's weighted payload equation: (used, sum w phi^2, sum w phi y), or the empty-move fit.

    tau0 (N m) and phi (N m/kg) of the model at the joint angles (rad), rates (rad/s) and accelerations (rad/s^2),
    each (3,), and the measured ``torque`` (N m).

    w_i = 1 / sigma_i^2 of :func:`~controllers.payload.tuning.residual_std`, f_i = fv_i thd_i + fc_i sign(thd_i) the
    model's friction, and per joint the columns c_i = (phi_i, I thdd_i + G cos th_i, f_i on the joint's own kappa)
    of the model's corrections. With the gripper open (mp = 0 known) the sample adds w_i c_i c_i^T and
    w_i c_i (tau_i - tau0_i) to the fit (``fit``, in place); while carrying, y_i = tau_i - tau0_i - c_i . p with
    p the fit solved at the first carrying sample after empty ones.
    """
    e, f = equation.view(EQUATION)[0], fit.view(FIT)[0]
    rest = e.rest_rate
    if abs(rates[0]) < rest and abs(rates[1]) < rest and abs(rates[2]) < rest:
        return False, 0.0, 0.0  # static friction holds an unknown share of the load: no measurement of the mass
    if not carrying and not f.fits:
        return False, 0.0, 0.0
    if carrying and f.stale:
        solve_fit(fit)
    information = moment = 0.0
    for i in range(3):
        rate = rates[i]
        scaled = rate * e.inverse_friction_velocity
        band = e.band_std[i] * math.exp(-(scaled * scaled))
        weight = 1.0 / (e.nominal_variance + band * band)
        coulomb = math.copysign(e.coulomb[i], rate) if rate != 0.0 else 0.0  # fc sign(thd), 0 at rest
        friction = e.viscous[i] * rate + coulomb
        arm = e.inertia * accelerations[i] + e.gravity * math.cos(angles[i])
        columns = (phi[i], arm, friction)
        indices = (PLATFORM_MASS, ARM_MASS_SCALE, FRICTION_SCALE + i)
        residual = torque[i] - tau0[i]
        if carrying:
            for a in range(3):
                residual -= f.solution[indices[a]] * columns[a]
            information += weight * phi[i] * phi[i]
            moment += weight * phi[i] * residual
        else:
            for a in range(3):
                weighted = weight * columns[a]
                f.moment[indices[a]] += weighted * residual
                for b in range(3):
                    f.information[indices[a], indices[b]] += weighted * columns[b]
    if not carrying:
        f.stale = True
        f.samples += 1
    return carrying, information, moment


@numba.njit(cache=True)
def back_to_torque_instant(current: NDArray[np.float64], previous: NDArray[np.float64], age: float) -> NDArray:
    """Rows (rows, 3) of this sample interpolated back ``age`` control periods towards the previous sample's:
    x - age (x - x_previous), the instant of the measured torque."""
    x = np.empty(current.shape)
    for row in range(current.shape[0]):
        for joint in range(3):
            now = current[row, joint]
            x[row, joint] = now - age * (now - previous[row, joint])
    return x


@numba.njit(cache=True)
def reference_equation(
    equation: NDArray[np.uint8],
    fit: NDArray[np.uint8],
    carrying: bool,
    current: NDArray[np.float64],
    previous: NDArray[np.float64],
    torque: NDArray[np.float64],
) -> tuple[bool, float, float]:
    """:func:`weighted_equation` at the reference, interpolated back to the torque's instant between the previous
    step's and this step's ``(5, 3)``: rows tau0 (N m), phi (N m/kg), theta (rad), theta_dot (rad/s), theta_ddot
    (rad/s^2); the measured ``torque`` (N m), (3,)."""
    x = back_to_torque_instant(current, previous, equation.view(EQUATION)[0].torque_age)
    return weighted_equation(equation, fit, carrying, x[0], x[1], x[2], x[3], x[4], torque)


@numba.njit(cache=True)
def estimated_state_equation(
    model: NDArray[np.uint8],
    equation: NDArray[np.uint8],
    fit: NDArray[np.uint8],
    state: NDArray[np.float64],
    previous: NDArray[np.float64],
    carrying: bool,
    torque: NDArray[np.float64],
) -> tuple[int, bool, float, float]:
    """The weighted payload equation at an estimated joint state: (model status, used, moments).

    ``model`` is the dynamics' :attr:`~controllers.dynamics.DeltaDynamics.model_constants`; ``state`` and
    ``previous`` are (3, 3), rows theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2) of this sample and the one
    before; the model is evaluated at the state interpolated back to the torque's instant, x - a (x - x_previous)
    with a the torque's age in control periods; ``torque`` (N m), (3,), was measured then.
    """
    x = back_to_torque_instant(state, previous, equation.view(EQUATION)[0].torque_age)
    status, terms = single_sample_model(
        model, x[0, 0], x[0, 1], x[0, 2], x[1, 0], x[1, 1], x[1, 2], x[2, 0], x[2, 1], x[2, 2]
    )
    if status != kernels.VALID:
        return status, False, 0.0, 0.0
    used, information, moment = weighted_equation(equation, fit, carrying, terms[0], terms[1], x[0], x[1], x[2], torque)
    return status, used, information, moment
