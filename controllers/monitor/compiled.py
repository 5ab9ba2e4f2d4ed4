"""The fault monitor's arithmetic on three-vectors, compiled for the 1 kHz loop (docs/design.md section 6, "Fault
monitor"): the model's residual, the platform force, the slip check's sums and the torque steps' variance, the
collision check's band along the reference and the smoother's error at the tracking error's steps, the current
loop's output.

The dot products are summed as OpenBLAS's kernels sum three terms, one fused multiply-add per term after the first
(``_dot3``, which alone may contract): the monitor's thresholds and campaigns were set with NumPy's ``@`` on
OpenBLAS, and these kernels keep its numbers. ``tests/test_monitor_compiled.py`` checks each kernel against its
definition: the model's equations, a brute-force sum, a finely integrated current loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numba
import numpy as np
from numpy.typing import NDArray

from controllers.compiled_model import single_sample_model
from controllers.monitor.tuning import REST_RATE
from delta_env.config import MAX_PAYLOAD_MASS

if TYPE_CHECKING:
    from controllers.payload import ModelCorrections

CORRECTION_TERMS = np.dtype(
    (
        np.record,
        [
            ("enabled", np.bool_),
            ("platform_mass", np.float64),
            ("arm_mass_scale", np.float64),
            ("friction_scale", np.float64, 3),
            ("inertia", np.float64),
            ("gravity_amplitude", np.float64),
            ("viscous", np.float64, 3),
            ("coulomb", np.float64, 3),
        ],
    )
)
"""What :func:`model_residual` takes off the residual: the fields of
:class:`~controllers.payload.ModelCorrections` (kg, dimensionless, (3,)) and the model's unscaled I (kg m^2), G
amplitude (N m), fv_i (N m s/rad) and fc_i (N m); nothing unless ``enabled``."""


def correction_terms(
    corrections: ModelCorrections | None,
    inertia: float,
    gravity_amplitude: float,
    viscous: Sequence[float],
    coulomb: Sequence[float],
) -> np.record:
    """A :data:`CORRECTION_TERMS` record: ``corrections`` (a ModelCorrections, or None for none) with the model's
    I (kg m^2), G amplitude (N m), fv (N m s/rad) and fc (N m)."""
    if corrections is None:
        fields = (False, 0.0, 0.0, (0.0, 0.0, 0.0))
    else:
        fields = (True, corrections.platform_mass, corrections.arm_mass_scale, corrections.friction_scale)
    return np.array([(*fields, inertia, gravity_amplitude, viscous, coulomb)], dtype=CORRECTION_TERMS)[0]


@numba.njit(cache=True, fastmath=False)  # explicit: a callee inherits its caller's fastmath otherwise
def _product(a: float, b: float) -> float:
    """a b rounded: compiled without contraction, so that no caller can fuse it into an addition."""
    return a * b


@numba.njit(cache=True, fastmath={"contract"})
def _dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """a . b as OpenBLAS's ddot and dgemv sum three terms: from 0, one fused multiply-add per term.

    The first product is rounded on its own (``_product``): with two products in one sum, contraction could fuse
    either, and inlined into a caller that squares a vector the compiler fused the second.
    """
    total = 0.0 + _product(a0, b0)
    total = total + a1 * b1
    total = total + a2 * b2
    return total


@numba.njit(cache=True, error_model="numpy")  # k_i = 0 (a serial singularity) gives inf, as NumPy did, not a raise
def model_residual(
    constants: NDArray[np.uint8],
    state: NDArray[np.float64],
    previous: NDArray[np.float64],
    torque_age: float,
    torque: NDArray[np.float64],
    corrections: np.record,
) -> tuple[int, NDArray[np.float64]]:
    """The model's residual at the smoothed state interpolated back to the torque's instant.

    ``state`` and ``previous`` are the smoother's (3, 3) states (rows theta, theta_dot, theta_ddot) of this sample
    and the one before; the state used is ``state - torque_age (state - previous)`` (``torque_age`` periods). Returns
    the status of :func:`~controllers.compiled_model.single_sample_model` and a (6, 3): the residual r = torque - tau0
    - ``corrections`` (a :data:`CORRECTION_TERMS` record; N m), phi (N m/kg), theta_dot at the torque's instant
    (rad/s), then the force map J^-T (N per N m, rows 3-5, as
    :meth:`~controllers.dynamics.DeltaDynamics.torque_regressor_and_force_map`).
    """
    out = np.zeros((6, 3))
    at = state - torque_age * (state - previous)
    status, terms = single_sample_model(
        constants, at[0, 0], at[0, 1], at[0, 2], at[1, 0], at[1, 1], at[1, 2], at[2, 0], at[2, 1], at[2, 2]
    )
    if status != 0:
        return status, out
    for joint in range(3):
        theta, theta_dot, theta_ddot = at[0, joint], at[1, joint], at[2, joint]
        phi = terms[1, joint]
        residual = torque[joint] - terms[0, joint]
        if corrections.enabled:
            arm = corrections.inertia * theta_ddot + corrections.gravity_amplitude * math.cos(theta)
            sign = (theta_dot > 0.0) - (theta_dot < 0.0)
            friction = corrections.viscous[joint] * theta_dot + corrections.coulomb[joint] * sign
            residual = residual - (
                corrections.platform_mass * phi
                + corrections.arm_mass_scale * arm
                + corrections.friction_scale[joint] * friction
            )
        out[0, joint], out[1, joint], out[2, joint] = residual, phi, theta_dot
        for axis in range(3):  # F = -sum_i a_i tau_i / k_i: column i of the map is -a_i / k_i
            out[3 + axis, joint] = -terms[2 + joint, axis] / terms[5, joint]
    return status, out


@numba.njit(cache=True)
def platform_force(
    terms: NDArray[np.float64],
    held_mass: float,
    subtract_held: bool,
    mass_unknown: bool,
    coulomb: NDArray[np.float64],
    breakaway: NDArray[np.float64],
    model_band: NDArray[np.float64],
    sliding: NDArray[np.float64],
) -> tuple[NDArray[np.float64], float]:
    """The platform force F = J^-T e (N), (3,), and its norm, of :func:`model_residual`'s ``terms``.

    e is the residual r less ``held_mass`` (kg) phi if ``subtract_held``, or, if ``mass_unknown``, less the m phi
    that explains most of it, m = r.phi / phi.phi clipped to the masses the cup can hold,
    [0, :data:`~delta_env.config.MAX_PAYLOAD_MASS`] (a residual along phi beyond any of them is a force); then less
    what the model's own error can explain: on every joint its part within +-``model_band`` (N m, (3,)), and on each
    joint slower than :data:`~controllers.monitor.tuning.REST_RATE` its unknown friction too: the model charged
    fc_i sign(theta_dot_i) (``coulomb``, N m) where the friction may be anything within +-``breakaway`` (N m), so e_i
    loses its part within [-w_i - b_i - fc_i s_i, w_i + b_i - fc_i s_i] (the NumPy ``e - clip(e, low, high)``, w the
    band). A slow joint whose encoder shows it sliding (``sliding`` +1 or -1, the direction its readings moved across
    the checked sample; 0 where they did not) has kinetic friction, which resists the motion: anything within
    ``sliding`` [0, b_i], not +-b_i.
    """
    r0, r1, r2 = terms[0, 0], terms[0, 1], terms[0, 2]
    p0, p1, p2 = terms[1, 0], terms[1, 1], terms[1, 2]
    if subtract_held:
        r0, r1, r2 = r0 - held_mass * p0, r1 - held_mass * p1, r2 - held_mass * p2
    elif mass_unknown:
        information = _dot3(p0, p1, p2, p0, p1, p2)
        if information > 0.0:
            share = min(max(_dot3(r0, r1, r2, p0, p1, p2) / information, 0.0), MAX_PAYLOAD_MASS)
            r0, r1, r2 = r0 - share * p0, r1 - share * p1, r2 - share * p2
    external = np.array((r0, r1, r2))
    for joint in range(3):
        rate = terms[2, joint]
        low, high = -model_band[joint], model_band[joint]
        if abs(rate) < REST_RATE:
            charged = coulomb[joint] * ((rate > 0.0) - (rate < 0.0))
            least = 0.0 if sliding[joint] > 0.0 else -breakaway[joint]
            most = 0.0 if sliding[joint] < 0.0 else breakaway[joint]
            low, high = low + least - charged, high + most - charged
        value = external[joint]
        explained = low if value < low else (high if value > high else value)  # np.clip
        external[joint] = value - explained
    force = np.empty(3)
    for axis in range(3):
        force[axis] = _dot3(
            terms[3 + axis, 0], terms[3 + axis, 1], terms[3 + axis, 2], external[0], external[1], external[2]
        )
    return force, math.sqrt(_dot3(force[0], force[1], force[2], force[0], force[1], force[2]))


@numba.njit(cache=True)
def learn_scatter(
    scatter: NDArray[np.float64],
    terms: NDArray[np.float64],
    held_mass: float,
    moving_speed: float,
    rate: float,
    floor: float,
) -> None:
    """Update ``scatter`` (N^2 m^2), in place: the running mean square (weight ``rate``) of the deviation r - m phi
    (``held_mass`` m, kg) of :func:`model_residual`'s ``terms``, per joint faster than ``moving_speed`` (rad/s), at
    least ``floor``."""
    for joint in range(3):
        if abs(terms[2, joint]) > moving_speed:
            deviation = terms[0, joint] - held_mass * terms[1, joint]
            learned = (1.0 - rate) * scatter[joint] + rate * deviation * deviation
            scatter[joint] = learned if not learned < floor else floor  # np.maximum: a NaN stays


@numba.njit(cache=True)
def slip_moments(
    terms: NDArray[np.float64], band: NDArray[np.float64], scatter: NDArray[np.float64]
) -> tuple[float, float]:
    """phi^T W phi (kg^-2) and phi^T W r (kg^-1) of :func:`model_residual`'s ``terms``, W = diag 1 / (band^2 +
    scatter) (band N m, scatter N^2 m^2)."""
    weighted = np.empty(3)
    for joint in range(3):
        weighted[joint] = 1.0 / (band[joint] * band[joint] + scatter[joint]) * terms[1, joint]
    # np.sum of three: left to right from the first term
    information = weighted[0] * terms[1, 0] + weighted[1] * terms[1, 1] + weighted[2] * terms[1, 2]
    moment = weighted[0] * terms[0, 0] + weighted[1] * terms[0, 1] + weighted[2] * terms[0, 2]
    return information, moment


@numba.njit(cache=True)
def loop_output(previous: float, before: float, held: float, hold: float, keep: float) -> float:
    """The current loop's output (N m) at the next reading: from the ``previous`` reading towards the command held
    ``before`` until the command changed, then towards the one ``held`` since, with the ``hold`` and ``keep`` of
    :func:`controllers.monitor.detector.loop_response`; exact for a first-order loop."""
    return held + (before - held) * hold + (previous - before) * keep


@numba.njit(cache=True)
def shift_in(torques: NDArray[np.float64], torque: NDArray[np.float64]) -> None:
    """Shift ``torque`` ((3,)) into the window ``torques`` ((n + 1, 3), oldest first), in place."""
    rows = torques.shape[0]
    for row in range(rows - 1):
        for joint in range(3):
            torques[row, joint] = torques[row + 1, joint]
    for joint in range(3):
        torques[rows - 1, joint] = torque[joint]


@numba.njit(cache=True)
def torque_step_variance(
    torques: NDArray[np.float64], torque: NDArray[np.float64], squared_response: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Shift ``torque`` (N m, (3,)) into ``torques`` (the window's measured torques and the one before, (n + 1, 3),
    oldest first; in place) and return, per joint, sum_m ``squared_response``_m (tau_{m+1} - tau_m)^2 (N^2 m^2,
    (3,)): the NumPy ``squared_response @ np.diff(torques, axis=0) ** 2`` summed from the oldest step."""
    shift_in(torques, torque)
    rows = torques.shape[0]
    variance = np.zeros(3)
    for row in range(rows - 1):
        weight = squared_response[row]
        for joint in range(3):
            step = torques[row + 1, joint] - torques[row, joint]
            variance[joint] += weight * (step * step)
    return variance


@numba.njit(cache=True)
def tracking_step_error(
    torques: NDArray[np.float64],
    torque_response: NDArray[np.float64],
    reference_torques: NDArray[np.float64],
    reference_regressors: NDArray[np.float64],
    acceleration_response: NDArray[np.float64],
    mass: float,
) -> NDArray[np.float64]:
    """Per joint (N m, (3,)), what the residual at the smoothed state lacks where the tracking error's acceleration
    stepped within the window: sum_m g_m d tau_m - sum_m h_m (d tau*_m + ``mass`` d phi*_m).

    The plant's acceleration steps with its measured torque (M da = d tau; ``torques``, the window's measured
    torques and the one before, (n + 1, 3), oldest first; g ``torque_response`` of
    :func:`~controllers.monitor.model_check.torque_step_response`), the reference's with the model's torque along
    it (``reference_torques``, with the feedforward's mass, plus ``mass`` (kg) more along its payload regressor
    ``reference_regressors``; h ``acceleration_response`` of
    :func:`~controllers.monitor.model_check.acceleration_step_response`); the smoother, which adds the reference's
    own acceleration back, errs only by the difference (docs/design.md section 6, "Fault monitor")."""
    error = np.zeros(3)
    for row in range(torques.shape[0] - 1):
        plant, reference = torque_response[row], acceleration_response[row]
        for joint in range(3):
            planned = reference_torques[row + 1, joint] - reference_torques[row, joint]
            planned += mass * (reference_regressors[row + 1, joint] - reference_regressors[row, joint])
            error[joint] += plant * (torques[row + 1, joint] - torques[row, joint]) - reference * planned
    return error


@numba.njit(cache=True)
def reference_step_bound(
    torques: NDArray[np.float64], torque: NDArray[np.float64], step_weights: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Shift the feedforward's model torque along the reference ``torque`` ((3,), N m) into its window ``torques``
    ((n + 1, 3), oldest first; in place) and return, per joint, sum_m ``step_weights``_m |d tau_m| (N m, (3,)): the
    most the smoother's acceleration error can put into the model torque where the command's feedforward steps
    (docs/design.md section 6, "Fault monitor")."""
    shift_in(torques, torque)
    bound = np.zeros(3)
    for row in range(torques.shape[0] - 1):
        weight = step_weights[row]
        for joint in range(3):
            bound[joint] += weight * abs(torques[row + 1, joint] - torques[row, joint])
    return bound


@numba.njit(cache=True)
def reference_torque(
    constants: NDArray[np.uint8],
    reference: NDArray[np.float64],
    torque: NDArray[np.float64],
    regressor: NDArray[np.float64],
) -> bool:
    """The model's torque without payload and its payload regressor (N m, N m/kg) at the reference's angles and
    accelerations (``reference``, (3, 3): rows theta, theta_dot, theta_ddot) with the rates taken as zero, into
    ``torque`` and ``regressor`` ((3,) each): the inertial and gravity torque, whose steps are the acceleration's,
    without friction's sign or the rates' terms. Returns False, leaving both as they are, where the model cannot take
    the reference's pose."""
    status, terms = single_sample_model(
        constants,
        reference[0, 0],
        reference[0, 1],
        reference[0, 2],
        0.0,
        0.0,
        0.0,
        reference[2, 0],
        reference[2, 1],
        reference[2, 2],
    )
    if status != 0:
        return False
    for joint in range(3):
        torque[joint] = terms[0, joint]
        regressor[joint] = terms[1, joint]
    return True
