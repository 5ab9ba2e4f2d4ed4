"""The region reference paths may visit: a cylinder around the work zone, away from singularities.

:func:`admissible` tests points against :class:`WorkspaceLimits`; :func:`require_admissible` raises an
error that names the first bad point and why it is refused (docs/design.md section 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels, kinematics
from delta_env.geometry import DeltaGeometry
from delta_env.validation import require_interval, require_positive

CHECK_SPACING = 0.01
"""Distance (m) between admissibility checks along a straight move."""


@dataclass(frozen=True)
class WorkspaceLimits:
    """The region reference paths may visit and its margins from singularities.

    The defaults bound a cylinder around the work zone (1.2 m across at z = -0.9 m,
    docs/design.md section 4) plus a 0.1 m rim for identification. Nominal geometry values at (0, 0, -0.9) for
    scale: min |k_i| = 0.336 m^2/rad and |det A| = 0.537 m^3; both vanish at singularities and the
    margins keep them above ~45 % and ~28 % of that (Jacobian condition number below ~8).

    Attributes:
        radius: Largest distance from the base z axis (m).
        z_min: Lowest platform height (m).
        z_max: Highest platform height (m).
        min_abs_k: Serial-singularity margin: smallest allowed min_i |k_i| (m^2/rad).
        min_abs_det_a: Parallel-singularity margin: smallest allowed |det A| (m^3).
    """

    radius: float = 0.7
    z_min: float = -1.1
    z_max: float = -0.7
    min_abs_k: float = 0.15
    min_abs_det_a: float = 0.15

    def __post_init__(self) -> None:
        for name, unit in (("radius", "m"), ("min_abs_k", "m^2/rad"), ("min_abs_det_a", "m^3")):
            require_positive(name, getattr(self, name), unit)
        require_interval("(z_min, z_max)", (self.z_min, self.z_max), unit="m")
        if self.z_min == self.z_max:
            raise ValueError(f"need z_min < z_max, got z_min={self.z_min!r}, z_max={self.z_max!r}")


WORKSPACE_LIMITS = WorkspaceLimits()
"""Default workspace limits for the nominal geometry."""


def admissible(geometry: DeltaGeometry, xyz: ArrayLike, limits: WorkspaceLimits = WORKSPACE_LIMITS) -> NDArray:
    """Whether platform positions lie inside ``limits`` (reachable, within margins).

    The measures of :func:`kinematics.singularity_measures` without its SVD, point by point in compiled code
    (:func:`_inside_limits`): reference cycles check their stations and paths with it thousands of times.

    Args:
        geometry: Robot geometry.
        xyz: Platform positions (m), ``(..., 3)``.
        limits: Region and singularity margins.

    Returns:
        Boolean array ``(...)``.
    """
    xyz = np.asarray(xyz, dtype=float)
    flat = np.ascontiguousarray(xyz.reshape(-1, 3))
    inside = np.empty(len(flat), dtype=bool)
    bounds = np.array((limits.radius, limits.z_min, limits.z_max, limits.min_abs_k, limits.min_abs_det_a))
    _inside_limits(flat, geometry.r, geometry.l1, geometry.l2, bounds, inside)
    return inside.reshape(xyz.shape[:-1])


@numba.njit(cache=True, error_model="numpy")
def _inside_limits(
    xyz: NDArray[np.float64], r: float, l1: float, l2: float, bounds: NDArray[np.float64], out: NDArray[np.bool_]
) -> None:
    """:func:`admissible` of every row of ``xyz`` (n, 3) (m) into ``out`` (n,); ``bounds``: the limits' radius,
    z_min, z_max (m), min |k_i| (m^2/rad) and min |det A| (m^3)."""
    radius, z_min, z_max, min_abs_k, min_abs_det_a = bounds[0], bounds[1], bounds[2], bounds[3], bounds[4]
    a = np.empty((3, 3))
    for point in range(xyz.shape[0]):
        x, y, z = xyz[point, 0], xyz[point, 1], xyz[point, 2]
        inside = math.hypot(x, y) <= radius and z_min <= z <= z_max
        for chain in range(3):
            if not inside:
                break
            theta = kernels.elbow_out_angle(x, y, z, chain, r, l1, l2)
            a[chain, 0], a[chain, 1], a[chain, 2], k = kernels.constraint_row(x, y, z, theta, chain, r, l1)
            inside = abs(k) >= min_abs_k  # False for NaN (unreachable)
        if inside:
            inside = abs(kernels.determinant3(a)) >= min_abs_det_a
        out[point] = inside


def _why_not_admissible(geometry: DeltaGeometry, point: np.ndarray, limits: WorkspaceLimits) -> str:
    """Why one point (m) is outside ``limits``, for error messages; '' if it is inside."""
    if math.hypot(point[0], point[1]) > limits.radius:
        return f"farther than {limits.radius} m from the z axis"
    if not limits.z_min <= point[2] <= limits.z_max:
        return f"outside z in [{limits.z_min}, {limits.z_max}] m"
    try:
        theta = kinematics.inverse(geometry, point)
    except ValueError:
        return "unreachable"
    measures = kinematics.singularity_measures(geometry, theta)
    if measures.min_abs_k < limits.min_abs_k:
        return f"near a serial singularity: min |k_i| = {measures.min_abs_k:.3g} m^2/rad < {limits.min_abs_k}"
    if abs(measures.det_a) < limits.min_abs_det_a:
        return f"near a parallel singularity: |det A| = {abs(measures.det_a):.3g} m^3 < {limits.min_abs_det_a}"
    return ""


def require_admissible(geometry: DeltaGeometry, points: np.ndarray, limits: WorkspaceLimits, what: str) -> None:
    """Raise ``ValueError`` naming the first of ``points`` (m), ``(..., 3)``, outside ``limits`` and why."""
    inside = admissible(geometry, points, limits).reshape(-1)
    if not np.all(inside):
        point = points.reshape(-1, 3)[np.argmin(inside)]
        reason = _why_not_admissible(geometry, point, limits)
        raise ValueError(f"{what} {(np.round(point, 4) + 0.0).tolist()} m is not admissible: {reason} ({limits})")


def segment_admissible(geometry: DeltaGeometry, start: np.ndarray, end: np.ndarray, limits: WorkspaceLimits) -> bool:
    """Whether the straight line from ``start`` to ``end`` (m) stays inside ``limits``, checked every CHECK_SPACING."""
    count = max(2, math.ceil(float(np.linalg.norm(end - start)) / CHECK_SPACING) + 1)
    points = start + np.linspace(0.0, 1.0, count)[:, None] * (end - start)
    return bool(np.all(admissible(geometry, points, limits)))


def edge_point(geometry: DeltaGeometry, rng: np.random.Generator, limits: WorkspaceLimits) -> np.ndarray | None:
    """A point on the boundary of ``limits`` along a random horizontal ray from the z axis, or None."""
    z = rng.uniform(limits.z_min, limits.z_max)
    angle = rng.uniform(0.0, 2.0 * math.pi)
    direction = np.array([math.cos(angle), math.sin(angle), 0.0])
    axis_point = np.array([0.0, 0.0, z])
    if not admissible(geometry, axis_point, limits):
        return None
    if admissible(geometry, axis_point + limits.radius * direction, limits):
        return axis_point + limits.radius * direction
    inside, outside = 0.0, limits.radius
    while outside - inside > 1e-4:
        middle = 0.5 * (inside + outside)
        if admissible(geometry, axis_point + middle * direction, limits):
            inside = middle
        else:
            outside = middle
    return axis_point + inside * direction
