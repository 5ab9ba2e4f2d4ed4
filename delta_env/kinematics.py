"""Delta robot kinematics on the equivalent robot with a point platform (docs/design.md section 2).

Conventions: base frame at the centre of the motor axes, z up; theta_i > 0 turns arm i down.
Every function accepts a leading batch shape ``(...)`` so that whole trajectories are evaluated at
once; joint and Cartesian vectors have a last axis of length 3, matrices end in ``(3, 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels
from delta_env.geometry import CHAIN_COS, CHAIN_SIN, DeltaGeometry
from delta_env.validation import require_vectors

_COS_ALPHA = np.array(CHAIN_COS)
_SIN_ALPHA = np.array(CHAIN_SIN)


def elbow_points(geometry: DeltaGeometry, theta: ArrayLike) -> NDArray[np.float64]:
    """Elbows J'_i of the equivalent robot (m), shape ``(..., 3 chains, 3 xyz)``."""
    theta = require_vectors("theta", theta)
    radial = geometry.r + geometry.l1 * np.cos(theta)
    return np.stack((radial * _COS_ALPHA, radial * _SIN_ALPHA, -geometry.l1 * np.sin(theta)), axis=-1)


def elbow_derivatives(geometry: DeltaGeometry, theta: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """dJ'_i/dtheta_i and d^2J'_i/dtheta_i^2 (m/rad, m/rad^2), each ``(..., 3, 3)``."""
    c, s = np.cos(theta), np.sin(theta)
    l1 = geometry.l1
    first = np.stack((-l1 * s * _COS_ALPHA, -l1 * s * _SIN_ALPHA, -l1 * c), axis=-1)
    second = np.stack((-l1 * c * _COS_ALPHA, -l1 * c * _SIN_ALPHA, l1 * s), axis=-1)
    return first, second


def forward(geometry: DeltaGeometry, theta: ArrayLike) -> NDArray[np.float64]:
    """Platform position (m) from motor angles (rad): the lower intersection of three spheres
    (:func:`delta_env.kernels.platform_position`).

    Raises:
        ValueError: if the forearms cannot reach a common point (no real solution).
    """
    theta = require_vectors("theta", theta)
    rows = np.ascontiguousarray(theta.reshape(-1, 3))
    xyz = np.empty(rows.shape)
    status, _ = kernels.platform_positions(rows, geometry.r, geometry.l1, geometry.l2, xyz)
    if status == kernels.COLLINEAR:
        raise ValueError(f"forward kinematics is undefined: elbows are collinear for theta={theta}")
    if status == kernels.UNREACHABLE:
        raise ValueError(
            f"forward kinematics has no real solution for theta={theta}: the forearms "
            f"(l2={geometry.l2} m) cannot reach a common point"
        )
    return xyz.reshape(theta.shape)


def inverse(geometry: DeltaGeometry, xyz: ArrayLike) -> NDArray[np.float64]:
    """Motor angles (rad) of the elbow-out branch for a platform position (m), ``(..., 3)``.

    The result is the one :func:`forward` inverts: ``forward(geometry, inverse(geometry, p))`` is ``p``.
    Vectorized over a batch of points, it raises on the first inadmissible point rather than returning
    NaN rows; :func:`elbow_out_angles` is the NaN-returning form (NaN where a chain cannot reach).

    Raises:
        ValueError: naming the point and why, if it is on or above the base plane (z >= 0), out of every
            chain's reach, or above the plane of the elbows the angles give (forward kinematics, which
            takes the lower intersection of the forearm spheres, would return another point).
    """
    xyz = require_vectors("xyz", xyz)
    above = xyz[..., 2] >= 0.0
    if np.any(above):
        point = xyz[tuple(np.argwhere(above)[0])] if xyz.ndim > 1 else xyz
        raise ValueError(f"point {np.round(point, 6).tolist()} m is on or above the base plane: z must be < 0 m (z up)")
    theta = elbow_out_angles(geometry, xyz)
    unreachable = np.any(np.isnan(theta), axis=-1)
    if np.any(unreachable):
        point = xyz[tuple(np.argwhere(unreachable)[0])] if xyz.ndim > 1 else xyz
        raise ValueError(f"point {np.round(point, 6).tolist()} m is outside the reachable workspace of {geometry}")
    # forward() returns the intersection below the elbows' plane (normal turned to point down)
    elbows = elbow_points(geometry, theta)
    normal = np.cross(elbows[..., 0, :] - elbows[..., 2, :], elbows[..., 1, :] - elbows[..., 2, :])
    side = np.sum((xyz - elbows[..., 2, :]) * normal, axis=-1) * np.where(normal[..., 2] > 0.0, -1.0, 1.0)
    upper = side < 0.0
    if np.any(upper):
        point = xyz[tuple(np.argwhere(upper)[0])] if xyz.ndim > 1 else xyz
        raise ValueError(
            f"point {np.round(point, 6).tolist()} m is outside the reachable workspace of {geometry}: "
            "it lies above the plane of the elbows (the upper assembly mode, which forward kinematics excludes)"
        )
    return theta


def elbow_out_angles(geometry: DeltaGeometry, xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    """Motor angles (rad) of the elbow-out branch, ``(..., 3)``; NaN for a chain that cannot reach ``xyz`` (m).

    Chain i in its own frame: |J'_i - x| = l2 gives p cos th + q sin th = c, solved by
    th = atan2(q, p) + acos(c / hypot(p, q)) (the elbow-out root); |c| > hypot(p, q) has no solution.
    """
    x, y, z = xyz[..., 0:1], xyz[..., 1:2], xyz[..., 2:3]
    x_local = x * _COS_ALPHA + y * _SIN_ALPHA - geometry.r
    y_local = -x * _SIN_ALPHA + y * _COS_ALPHA
    p = -2.0 * geometry.l1 * x_local
    q = 2.0 * geometry.l1 * np.broadcast_to(z, x_local.shape)
    c = geometry.l2**2 - geometry.l1**2 - x_local**2 - y_local**2 - z**2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = c / np.hypot(p, q)
        return np.where(np.abs(ratio) <= 1.0, np.arctan2(q, p) + np.arccos(np.clip(ratio, -1.0, 1.0)), np.nan)


def constraint_terms(
    geometry: DeltaGeometry, xyz: ArrayLike, theta: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Terms of the velocity constraint ``A xd + K thd = 0``, K = diag(k).

    Returns:
        A with rows a_i = x - J'_i (m), ``(..., 3, 3)``, and k_i = -a_i . dJ'_i/dtheta_i (m^2/rad),
        ``(..., 3)``; k_i < 0 on the elbow-out branch.
    """
    xyz = require_vectors("xyz", xyz)
    theta = require_vectors("theta", theta)
    a = xyz[..., None, :] - elbow_points(geometry, theta)
    first, _ = elbow_derivatives(geometry, theta)
    k = -np.sum(a * first, axis=-1)
    return a, k


def jacobian(geometry: DeltaGeometry, theta: ArrayLike) -> NDArray[np.float64]:
    """Jacobian J (m/rad) with xd = J thd, ``(..., 3, 3)``; J = -A^{-1} K."""
    xyz = forward(geometry, theta)
    a, k = constraint_terms(geometry, xyz, theta)
    return np.linalg.solve(a, -k[..., None, :] * np.eye(3))


def joint_to_cartesian(
    geometry: DeltaGeometry, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Platform position (m), velocity (m/s), acceleration (m/s^2) from joint motion."""
    theta = require_vectors("theta", theta)
    theta_dot = require_vectors("theta_dot", theta_dot)
    theta_ddot = require_vectors("theta_ddot", theta_ddot)
    xyz = forward(geometry, theta)
    a, k = constraint_terms(geometry, xyz, theta)
    xyz_dot = np.linalg.solve(a, (-k * theta_dot)[..., None])[..., 0]
    first, second = elbow_derivatives(geometry, theta)
    v = xyz_dot[..., None, :] - first * theta_dot[..., None]
    # A xdd = -|v_i|^2 + a_i . J'_thth,i thd_i^2 - k_i thdd_i  (second derivative of the constraint)
    rhs = -np.sum(v * v, axis=-1) + np.sum(a * second, axis=-1) * theta_dot**2 - k * theta_ddot
    xyz_ddot = np.linalg.solve(a, rhs[..., None])[..., 0]
    return xyz, xyz_dot, xyz_ddot


def cartesian_to_joint(
    geometry: DeltaGeometry, xyz: ArrayLike, xyz_dot: ArrayLike, xyz_ddot: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Joint angles (rad), rates (rad/s), accelerations (rad/s^2) from platform motion."""
    xyz = require_vectors("xyz", xyz)
    xyz_dot = require_vectors("xyz_dot", xyz_dot)
    xyz_ddot = require_vectors("xyz_ddot", xyz_ddot)
    theta = inverse(geometry, xyz)
    a, k = constraint_terms(geometry, xyz, theta)
    theta_dot = -np.sum(a * xyz_dot[..., None, :], axis=-1) / k
    first, second = elbow_derivatives(geometry, theta)
    v = xyz_dot[..., None, :] - first * theta_dot[..., None]
    # k_i thdd_i = -|v_i|^2 - a_i . (xdd - J'_thth,i thd_i^2)
    relative_acc = xyz_ddot[..., None, :] - second * (theta_dot**2)[..., None]
    theta_ddot = (-np.sum(v * v, axis=-1) - np.sum(a * relative_acc, axis=-1)) / k
    return theta, theta_dot, theta_ddot


@dataclass(frozen=True)
class SingularityMeasures:
    """Distance to singularity at one or many poses.

    Attributes:
        det_a: det A (m^3); zero at parallel-type singularities (forearms coplanar).
        min_abs_k: min_i |k_i| (m^2/rad); zero at serial-type singularities (arm and forearm aligned).
        jacobian_condition: 2-norm condition number of J (dimensionless; inf when singular).
    """

    det_a: NDArray[np.float64]
    min_abs_k: NDArray[np.float64]
    jacobian_condition: NDArray[np.float64]


def singularity_measures(geometry: DeltaGeometry, theta: ArrayLike) -> SingularityMeasures:
    """Singularity measures at motor angles ``theta`` (rad)."""
    xyz = forward(geometry, theta)
    a, k = constraint_terms(geometry, xyz, theta)
    # J = -A^{-1} K; the pseudo-inverse keeps this finite at det A = 0, where the ratio becomes inf.
    with np.errstate(divide="ignore", invalid="ignore"):
        singular_values = np.linalg.svd(np.linalg.pinv(a) @ (k[..., None, :] * np.eye(3)), compute_uv=False)
        condition = singular_values[..., 0] / singular_values[..., -1]
    return SingularityMeasures(
        det_a=np.linalg.det(a), min_abs_k=np.min(np.abs(k), axis=-1), jacobian_condition=condition
    )
