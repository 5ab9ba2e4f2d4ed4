"""The physics every layer shares, written once and compiled with numba (docs/design.md sections 2 and 4).

Forward kinematics (the lower intersection of the forearm spheres), the forearms' elbow angles that close the
plant's loops, and the Stribeck and ripple torque of the drive. :mod:`delta_env.kinematics` (batched NumPy),
:class:`~delta_env.plant.DeltaPlant`, :class:`~delta_env.oracle.InverseDynamicsOracle` and the single-sample model
of ``controllers.dynamics`` all call these kernels, so the numbers agree to the last bit between them.

Conventions as in :mod:`delta_env.kinematics`: base frame at the centre of the motor axes, z up, theta_i > 0
turns arm i down; chains are numbered 0, 1, 2 here. Kernels that can fail return a status code first
(:data:`VALID` or the reason, :data:`INVALID_STATE`) instead of raising, so compiled callers can check it.

Constants with names travel as a NumPy record (a dtype of ``np.record``, so NumPy reads its fields as attributes
too), and a kernel called from Python takes the record's bytes (``records.view(np.uint8)``) and views them as the
record: numba dispatches a byte array as cheaply as a float array, a record array at a multiple of that cost, which
the 1 kHz loop would pay several times a step.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from delta_env.geometry import CHAIN_COS, CHAIN_SIN

VALID, NOT_FINITE, COLLINEAR, UNREACHABLE, SINGULAR, GIMBAL_LOCK = range(6)
"""Status codes of the kernels (and of the compiled models built on them)."""

INVALID_STATE = {
    NOT_FINITE: "joint states must be finite",
    COLLINEAR: "forward kinematics is undefined: the elbows are collinear",
    UNREACHABLE: "forward kinematics has no real solution",
    SINGULAR: "A is singular (parallel-type singularity)",
    GIMBAL_LOCK: "a forearm lies along its motor axis (gimbal lock)",
}
"""The error each status code other than :data:`VALID` means."""

STRIBECK_SIGN_SLOPE = 4.0
"""Slope factor of the smooth sign tanh(4 v / v_s) of the Stribeck term: stays explicit-stable at 1 kHz."""


def _stribeck_peak() -> float:
    """max over x >= 0 of exp(-x^2) tanh(STRIBECK_SIGN_SLOPE x), by golden-section search on [0, 2]."""

    def share(x: float) -> float:
        return math.exp(-x * x) * math.tanh(STRIBECK_SIGN_SLOPE * x)

    low, high = 0.0, 2.0
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(100):
        a, b = high - ratio * (high - low), low + ratio * (high - low)
        low, high = (low, b) if share(a) > share(b) else (a, high)
    return share(0.5 * (low + high))


STRIBECK_PEAK = _stribeck_peak()
"""Largest share of its excess the plant's Stribeck term resists (0.787, at 0.38 v_s): 0 at rest, where the
Coulomb friction alone holds the joint, and at most this much more on the way out of rest, so a joint leaves rest
once the torque passes fc + STRIBECK_PEAK * excess * fc."""

DISTURBANCE = np.dtype(
    (
        np.record,
        [
            ("stribeck_gain", np.float64, 3),
            ("inverse_stribeck_velocity", np.float64),
            ("ripple_amplitude", np.float64),
            ("ripple_periods", np.float64),
        ],
    )
)
"""The constants of :func:`motor_disturbance`: Stribeck gain excess * fc_i per joint (N m), 1 / v_s (s/rad),
ripple amplitude (N m) and ripple periods per revolution."""


@numba.njit(cache=True, inline="always")
def elbow(theta: float, chain: int, r: float, l1: float) -> tuple[float, float, float]:
    """Elbow J'_i (m) of chain ``chain`` at motor angle ``theta`` (rad): r = ra - rb and l1 (m)."""
    radial = r + l1 * math.cos(theta)
    return radial * CHAIN_COS[chain], radial * CHAIN_SIN[chain], -l1 * math.sin(theta)


@numba.njit(cache=True, inline="always")
def determinant3(m: NDArray[np.float64]) -> float:
    """Determinant of a 3 x 3 matrix by its first row's cofactors."""
    return (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )


@numba.njit(cache=True, inline="always")
def elbow_out_angle(x: float, y: float, z: float, chain: int, r: float, l1: float, l2: float) -> float:
    """Motor angle (rad) of chain ``chain`` on the elbow-out branch for the platform at (x, y, z) (m), NaN if the
    chain cannot reach it: :func:`delta_env.kinematics.elbow_out_angles` in scalar arithmetic."""
    cos_a, sin_a = CHAIN_COS[chain], CHAIN_SIN[chain]
    x_local = x * cos_a + y * sin_a - r
    y_local = -x * sin_a + y * cos_a
    p, q = -2.0 * l1 * x_local, 2.0 * l1 * z
    ratio = (l2**2 - l1**2 - x_local**2 - y_local**2 - z**2) / math.hypot(p, q)
    return math.atan2(q, p) + math.acos(min(max(ratio, -1.0), 1.0)) if abs(ratio) <= 1.0 else math.nan


@numba.njit(cache=True, inline="always")
def constraint_row(
    x: float, y: float, z: float, theta: float, chain: int, r: float, l1: float
) -> tuple[float, float, float, float]:
    """Row a_i = x - J'_i (m) and k_i = -a_i . dJ'_i/dtheta_i (m^2/rad) of the velocity constraint of chain
    ``chain`` (:func:`delta_env.kinematics.constraint_terms`) at the platform (x, y, z) (m) and angle ``theta``."""
    ex, ey, ez = elbow(theta, chain, r, l1)
    ax, ay, az = x - ex, y - ey, z - ez
    s, c = math.sin(theta), math.cos(theta)
    return ax, ay, az, -(ax * (-l1 * s * CHAIN_COS[chain]) + ay * (-l1 * s * CHAIN_SIN[chain]) + az * (-l1 * c))


@numba.njit(cache=True, inline="always")
def lower_intersection(
    p1x: float,
    p1y: float,
    p1z: float,
    p2x: float,
    p2y: float,
    p2z: float,
    p3x: float,
    p3y: float,
    p3z: float,
    l2: float,
) -> tuple[int, float, float, float]:
    """Forward kinematics from the elbows p1..p3 (m): status and the platform (m), the lower intersection of the
    three spheres of radius l2 (m) around them.

    The circumcentre of the elbows plus the height along the normal n of their plane, turned to point down;
    :data:`COLLINEAR` without a plane, :data:`UNREACHABLE` if the spheres do not meet.
    """
    ax, ay, az = p1x - p3x, p1y - p3y, p1z - p3z
    bx, by, bz = p2x - p3x, p2y - p3y, p2z - p3z
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    nn = nx * nx + ny * ny + nz * nz
    if nn < 1e-18:
        return COLLINEAR, 0.0, 0.0, 0.0
    aa, bb = ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz
    mx, my, mz = aa * bx - bb * ax, aa * by - bb * ay, aa * bz - bb * az
    h = 0.5 / nn
    ox, oy, oz = (my * nz - mz * ny) * h, (mz * nx - mx * nz) * h, (mx * ny - my * nx) * h  # centre - p3
    height_sq = l2**2 - (ox * ox + oy * oy + oz * oz)
    if height_sq < 0.0:
        return UNREACHABLE, 0.0, 0.0, 0.0
    scale = math.sqrt(height_sq / nn)
    if nz > 0.0:
        scale = -scale
    return VALID, p3x + ox + scale * nx, p3y + oy + scale * ny, p3z + oz + scale * nz


@numba.njit(cache=True, inline="always")
def platform_position(
    t1: float, t2: float, t3: float, r: float, l1: float, l2: float
) -> tuple[int, float, float, float]:
    """Status and platform position (m) at motor angles t1..t3 (rad): :func:`elbow` and :func:`lower_intersection`."""
    p1x, p1y, p1z = elbow(t1, 0, r, l1)
    p2x, p2y, p2z = elbow(t2, 1, r, l1)
    p3x, p3y, p3z = elbow(t3, 2, r, l1)
    return lower_intersection(p1x, p1y, p1z, p2x, p2y, p2z, p3x, p3y, p3z, l2)


@numba.njit(cache=True)
def platform_positions(
    theta: NDArray[np.float64], r: float, l1: float, l2: float, out: NDArray[np.float64]
) -> tuple[int, int]:
    """:func:`platform_position` of every row of ``theta`` (n, 3) into ``out`` (n, 3); the status and row of the
    first failure, or (:data:`VALID`, -1)."""
    for row in range(theta.shape[0]):
        status, out[row, 0], out[row, 1], out[row, 2] = platform_position(
            theta[row, 0], theta[row, 1], theta[row, 2], r, l1, l2
        )
        if status != VALID:
            return status, row
    return VALID, -1


@numba.njit(cache=True, inline="always")
def elbow_angles(
    theta: float, chain: int, px: float, py: float, pz: float, ex: float, ey: float, ez: float, l2: float, tilt: float
) -> tuple[int, float, float]:
    """Status and the (pitch, roll) elbow angles (rad) of the forearm of ``chain`` from its elbow (ex, ey, ez) to
    the platform (px, py, pz) (m); both rods of a parallelogram are parallel to x - J'_i.

    The direction (x - J'_i) / l2 in the arm frame (x = u_i, y = t_i), then in the forearm body's frame at zero
    elbow angles, which is the arm frame turned by R_y(theta + tilt) (``tilt``: the forearms' home tilt, rad);
    there the rod points along -z and the two hinges give the direction (-sin p cos r, sin r, -cos p cos r).
    :data:`GIMBAL_LOCK` if the forearm lies along its motor axis.
    """
    cos_a, sin_a = CHAIN_COS[chain], CHAIN_SIN[chain]
    dx, dy, dz = (px - ex) / l2, (py - ey) / l2, (pz - ez) / l2
    radial, tangential = dx * cos_a + dy * sin_a, -dx * sin_a + dy * cos_a
    if abs(tangential) >= 1.0 - 1e-9:
        return GIMBAL_LOCK, 0.0, 0.0
    turn = theta + tilt
    local_x = math.cos(turn) * radial - math.sin(turn) * dz
    local_z = math.sin(turn) * radial + math.cos(turn) * dz
    return VALID, math.atan2(-local_x, -local_z), math.asin(tangential)


@numba.njit(cache=True)
def assembly(
    theta: NDArray[np.float64],
    r: float,
    l1: float,
    l2: float,
    tilt: float,
    platform: NDArray[np.float64],
    elbows: NDArray[np.float64],
) -> tuple[int, int]:
    """The coordinates that close every loop at each row of motor angles ``theta`` (n, 3) (rad): the platform (m)
    into ``platform`` (n, 3) and the elbow (pitch, roll) angles (rad) into ``elbows`` (n, 3, 2); the status and row
    of the first failure, or (:data:`VALID`, -1). Lengths (m) and tilt (rad) as :func:`elbow_angles`."""
    for row in range(theta.shape[0]):
        status, px, py, pz = platform_position(theta[row, 0], theta[row, 1], theta[row, 2], r, l1, l2)
        if status != VALID:
            return status, row
        platform[row, 0], platform[row, 1], platform[row, 2] = px, py, pz
        for chain in range(3):
            ex, ey, ez = elbow(theta[row, chain], chain, r, l1)
            status, elbows[row, chain, 0], elbows[row, chain, 1] = elbow_angles(
                theta[row, chain], chain, px, py, pz, ex, ey, ez, l2, tilt
            )
            if status != VALID:
                return status, row
    return VALID, -1


@numba.njit(cache=True, inline="always")
def motor_disturbance(c: np.record, joint: int, theta: float, theta_dot: float) -> float:
    """Stribeck excess and torque ripple (N m) on motor ``joint`` at angle ``theta`` (rad) and rate ``theta_dot``
    (rad/s), with the constants ``c`` of a :data:`DISTURBANCE` record.

    Stribeck: -excess * fc_i * exp(-(v / v_s)^2) * tanh(4 v / v_s); the tanh is a smooth sign whose slope at zero
    speed (4 excess fc_i / v_s, 160 N m s/rad by default) stays well inside the explicit stability limit of a 1 kHz
    zero-order hold, so it does not chatter. Ripple: amplitude * sin(periods * theta).
    """
    v = theta_dot * c.inverse_stribeck_velocity
    ripple = c.ripple_amplitude * math.sin(c.ripple_periods * theta)
    return ripple - c.stribeck_gain[joint] * math.exp(-v * v) * math.tanh(v * STRIBECK_SIGN_SLOPE)


@numba.njit(cache=True)
def motor_disturbances(
    coefficients: NDArray[np.uint8],
    theta: NDArray[np.float64],
    theta_dot: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """:func:`motor_disturbance` of every row of ``theta`` and ``theta_dot`` (n, 3) into ``out`` (n, 3), with the
    bytes of a :data:`DISTURBANCE` record."""
    c = coefficients.view(DISTURBANCE)[0]
    for row in range(theta.shape[0]):
        for joint in range(3):
            out[row, joint] = motor_disturbance(c, joint, theta[row, joint], theta_dot[row, joint])


@numba.njit(cache=True)
def apply_motor_disturbance(
    coefficients: NDArray[np.uint8],
    qpos: NDArray[np.float64],
    qvel: NDArray[np.float64],
    qpos_addresses: NDArray[np.int64],
    dofs: NDArray[np.int64],
    qfrc_applied: NDArray[np.float64],
) -> None:
    """Write :func:`motor_disturbance` of the motor joints at ``qpos_addresses`` and ``dofs`` (3,) of a MuJoCo state
    into ``qfrc_applied`` (nv,), with the bytes of a :data:`DISTURBANCE` record."""
    c = coefficients.view(DISTURBANCE)[0]
    for joint in range(3):
        dof = dofs[joint]
        qfrc_applied[dof] = motor_disturbance(c, joint, qpos[qpos_addresses[joint]], qvel[dof])
