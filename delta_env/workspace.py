"""Workspace, dexterity and singularity analysis of a Delta geometry (docs/design.md sections 1 and 2).

Everything here follows from :class:`~delta_env.geometry.DeltaGeometry` alone and is vectorized over
points ``(..., 3)`` (m, base frame). A point is *admissible* when

- the elbow-out inverse kinematics exists with every theta_i in ``theta_range`` (rad, theta > 0 down),
- every ball joint, at the elbow and on the platform, holds its forearm within ``max_forearm_tilt`` of its cup
  axis (the ball-joint cone; :func:`delta_env.buildability.joint_angles`),
- every parallelogram leaves its rectangle by at most ``max_skew`` (the forearms' tilt along the elbow axis), and
- the local conditioning index 1 / cond_2(J) (J: xd = J thd) is at least ``min_conditioning``.

With rows a_i of A (|a_i| = l2) and k_i of the velocity constraint A xd + K thd = 0, J^{-1} = -K^{-1} A has
rows -a_i / k_i, which stay finite everywhere except at serial singularities. So

- conditioning = sigma_min / sigma_max of K^{-1} A: 0 at both singularity types (det A = 0, some k_i = 0);
- the inverse measurement index IMI = 1 / sqrt(det(J J^T)) = |det A| / prod |k_i| (rad^3/m^3);
- the speed the platform reaches in *every* direction with |thd_i| <= omega is
  omega * min_i |k_i| / l2 (the largest row norm of J^{-1} is l2 / min |k_i|).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import buildability, kernels, kinematics
from delta_env.geometry import CHAIN_COS, CHAIN_SIN, DeltaGeometry
from delta_env.robot import forearm_home_tilt
from delta_env.validation import require_count, require_in, require_interval, require_positive

THETA_RANGE = (-0.6, 1.5)
"""Default motor range (rad): up to 34 deg above horizontal before the arm meets the base housing, down to
86 deg, just short of hanging vertically under its motor."""

MAX_FOREARM_TILT = math.radians(60.0)
"""Default ball-joint cone (rad): the half-angle about its cup axis within which a ball joint holds its forearm
(assumed, for ball-cup joints with inclined cups; the cup axes are those of :mod:`delta_env.buildability`)."""

MAX_PARALLELOGRAM_SKEW = math.radians(30.0)
"""Default parallelogram skew limit (rad): the forearms may tilt at most this far along the elbow axis, where
the rods' distance across the pair, which holds the platform level about the chain, is still cos 30 deg = 87 %
of their spacing (assumed)."""

DEXTEROUS_CONDITIONING = 0.25
"""Default dexterity threshold on 1 / cond_2(J): beyond a condition number of 4 a joint error moves the
platform four times more in one direction than in another."""

VOLUME_SAMPLES = 400_000
"""Default Monte Carlo samples of :func:`reachable_volume`: a relative standard error near 1 %."""

_CHUNK = 100_000  # points per vectorized batch: bounds memory at a few tens of MB
_TINY = float(np.finfo(float).tiny)


@dataclass(frozen=True)
class Criteria:
    """What makes a point admissible (module docstring).

    Attributes:
        theta_range: (min, max) motor angle (rad).
        max_forearm_tilt: Ball-joint cone: largest forearm angle from a cup axis (rad), in (0, pi].
        min_conditioning: Smallest 1 / cond_2(J), in [0, 1].
        max_skew: Largest parallelogram skew (rad), in (0, pi/2].
    """

    theta_range: tuple[float, float] = THETA_RANGE
    max_forearm_tilt: float = MAX_FOREARM_TILT
    min_conditioning: float = DEXTEROUS_CONDITIONING
    max_skew: float = MAX_PARALLELOGRAM_SKEW

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "theta_range", require_interval("theta_range", self.theta_range, -math.pi, math.pi, unit="rad")
        )
        require_in("max_forearm_tilt", self.max_forearm_tilt, 0.0, math.pi, unit="rad", low_open=True)
        require_in("min_conditioning", self.min_conditioning, 0.0, 1.0)
        require_in("max_skew", self.max_skew, 0.0, math.pi / 2, unit="rad", low_open=True)


DEXTEROUS = Criteria()
"""The default criteria: the dexterous workspace."""

REACHABLE = Criteria(min_conditioning=0.0)
"""The default joint limits without a dexterity threshold: the reachable workspace."""


@dataclass(frozen=True)
class PoseMeasures:
    """Kinematic measures at points, each ``(...)``; NaN where the inverse kinematics does not exist.

    Attributes:
        reachable: True where the elbow-out inverse kinematics exists.
        theta: Motor angles (rad), ``(..., 3)``.
        conditioning: 1 / cond_2(J) (dimensionless, 0 at singularities).
        imi: Inverse measurement index 1 / sqrt(det(J J^T)) (rad^3/m^3).
        det_a: det A (m^3), zero at parallel-type singularities.
        min_abs_k: min_i |k_i| (m^2/rad), zero at serial-type singularities.
        forearm_tilt: Largest forearm angle from a ball-joint cup axis (rad), over the chains' elbow and platform
            joints.
        skew: Largest parallelogram skew (rad).
    """

    reachable: NDArray[np.bool_]
    theta: NDArray[np.float64]
    conditioning: NDArray[np.float64]
    imi: NDArray[np.float64]
    det_a: NDArray[np.float64]
    min_abs_k: NDArray[np.float64]
    forearm_tilt: NDArray[np.float64]
    skew: NDArray[np.float64]

    def admissible(self, criteria: Criteria = DEXTEROUS) -> NDArray[np.bool_]:
        """Whether each point satisfies ``criteria``, ``(...)``."""
        low, high = criteria.theta_range
        with np.errstate(invalid="ignore"):
            inside = np.all((self.theta >= low) & (self.theta <= high), axis=-1)
            inside &= self.forearm_tilt <= criteria.max_forearm_tilt
            inside &= self.skew <= criteria.max_skew
            inside &= self.conditioning >= criteria.min_conditioning
        return self.reachable & inside


def _points(xyz: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(xyz, dtype=float)
    if array.ndim == 0 or array.shape[-1] != 3 or not np.all(np.isfinite(array)):
        raise ValueError(f"xyz must be finite points with a last axis of length 3, got shape {array.shape}")
    return array


def _det3(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Determinants of 3 x 3 matrices ``(..., 3, 3)``, written out (a batched LU costs more than this)."""
    return (
        m[..., 0, 0] * (m[..., 1, 1] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 1])
        - m[..., 0, 1] * (m[..., 1, 0] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 0])
        + m[..., 0, 2] * (m[..., 1, 0] * m[..., 2, 1] - m[..., 1, 1] * m[..., 2, 0])
    )


def singular_value_ratio(m: ArrayLike) -> NDArray[np.float64]:
    """sigma_min / sigma_max of 3 x 3 matrices ``(..., 3, 3)`` (0 for a zero matrix), in closed form.

    The eigenvalues of the symmetric B = M^T M by the trigonometric solution of its characteristic cubic
    (O. K. Smith, "Eigenvalues of a symmetric 3 x 3 matrix", Commun. ACM 4(4), 1961, doi:10.1145/355578.366316):
    with q = tr(B) / 3, p = sqrt(tr((B - qI)^2) / 6) and r = det((B - qI) / p) / 2, the largest is
    q + 2p cos(phi) and the smallest q + 2p cos(phi + 2 pi / 3), phi = acos(r) / 3. A batched SVD costs several
    times more. Against LAPACK's SVD on 200,000 random matrices the ratio differs by 2e-9 at most (on near-singular
    ones, where the smallest eigenvalue of B carries an error of about 1e-16 of the largest): far below the 0.25
    dexterity threshold.
    """
    m = np.asarray(m, dtype=float)
    b = np.einsum("...ki,...kj->...ij", m, m)
    q = np.trace(b, axis1=-2, axis2=-1) / 3.0
    off = b[..., 0, 1] ** 2 + b[..., 0, 2] ** 2 + b[..., 1, 2] ** 2
    spread = (b[..., 0, 0] - q) ** 2 + (b[..., 1, 1] - q) ** 2 + (b[..., 2, 2] - q) ** 2 + 2.0 * off
    p = np.sqrt(spread / 6.0)
    equal = p <= 1e-15 * np.maximum(q, np.finfo(float).tiny)
    safe_p = np.where(equal, 1.0, p)
    shifted = (b - q[..., None, None] * np.eye(3)) / safe_p[..., None, None]
    phi = np.arccos(np.clip(_det3(shifted) / 2.0, -1.0, 1.0)) / 3.0
    largest = np.where(equal, q, q + 2.0 * p * np.cos(phi))
    smallest = np.where(equal, q, q + 2.0 * p * np.cos(phi + 2.0 * math.pi / 3.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(largest > 0.0, np.sqrt(np.clip(smallest, 0.0, None) / largest), 0.0)


def _conditioning(a: NDArray[np.float64], k: NDArray[np.float64]) -> NDArray[np.float64]:
    """1 / cond_2(J) from the velocity constraint's rows a_i (m) and k_i (m^2/rad): 0 where some k_i is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse_jacobian = a / k[..., None]  # J^{-1} = -K^{-1} A up to sign
        matrix = np.nan_to_num(inverse_jacobian, nan=0.0, posinf=0.0, neginf=0.0)
        return np.where(np.all(np.abs(k) > 0.0, axis=-1), singular_value_ratio(matrix), 0.0)


def pose_measures(geometry: DeltaGeometry, xyz: ArrayLike) -> PoseMeasures:
    """Kinematic measures at platform positions ``xyz`` (m), ``(..., 3)``; unreachable points get NaN."""
    xyz = _points(xyz)
    theta = kinematics.elbow_out_angles(geometry, xyz)
    reachable = np.all(np.isfinite(theta), axis=-1)
    theta = np.where(reachable[..., None], theta, np.nan)
    # rows a_i = x - J'_i (|a_i| = l2 where reachable) and k_i; unreachable points are masked below
    a, k = kinematics.constraint_terms(geometry, xyz, np.nan_to_num(theta))
    abs_k = np.abs(k)
    conditioning = _conditioning(a, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        det_a = np.linalg.det(np.nan_to_num(a))
        imi = np.abs(det_a) / np.prod(abs_k, axis=-1)
    cone, skew = buildability.forearm_angles(geometry, a, np.nan_to_num(theta))
    nan = np.where(reachable, 0.0, np.nan)
    return PoseMeasures(
        reachable=reachable,
        theta=theta,
        conditioning=np.nan_to_num(conditioning) + nan,
        imi=imi + nan,
        det_a=det_a + nan,
        min_abs_k=np.min(abs_k, axis=-1) + nan,
        forearm_tilt=np.max(cone, axis=-1) + nan,
        skew=np.max(skew, axis=-1) + nan,
    )


def admissible(geometry: DeltaGeometry, xyz: ArrayLike, criteria: Criteria = DEXTEROUS) -> NDArray[np.bool_]:
    """Whether platform positions ``xyz`` (m), ``(..., 3)``, satisfy ``criteria``, ``(...)``.

    The same test as :meth:`PoseMeasures.admissible` of :func:`pose_measures`, computing only what it needs, point by
    point in compiled code (:func:`admissible_point`): the workspace searches call it thousands of times on a few
    hundred points, where NumPy's per-call cost dominated.
    """
    xyz = _points(xyz)
    flat = np.ascontiguousarray(xyz.reshape(-1, 3))
    result = np.empty(len(flat), dtype=bool)
    _admissible_points(flat, admissible_constants(geometry, criteria), result)
    return result.reshape(xyz.shape[:-1])


def admissible_constants(geometry: DeltaGeometry, criteria: Criteria = DEXTEROUS) -> NDArray[np.float64]:
    """What :func:`admissible_point` needs of a geometry and criteria: r, l1, l2 (m), the forearms' home tilt, the
    theta range, ball-joint cone and skew (rad) and the conditioning threshold, ``(9,)``."""
    low, high = criteria.theta_range
    return np.array(
        (
            geometry.r,
            geometry.l1,
            geometry.l2,
            forearm_home_tilt(geometry),
            low,
            high,
            criteria.max_forearm_tilt,
            criteria.max_skew,
            criteria.min_conditioning,
        )
    )


@numba.njit(cache=True, error_model="numpy")
def _admissible_points(xyz: NDArray[np.float64], constants: NDArray[np.float64], out: NDArray[np.bool_]) -> None:
    """:func:`admissible_point` of every row of ``xyz`` (n, 3) (m) into ``out`` (n,)."""
    theta, rows = np.empty(3), np.empty((3, 3))
    for point in range(xyz.shape[0]):
        out[point] = admissible_point(xyz[point, 0], xyz[point, 1], xyz[point, 2], constants, theta, rows)


@numba.njit(cache=True, error_model="numpy")
def admissible_point(
    x: float, y: float, z: float, constants: NDArray[np.float64], theta: NDArray[np.float64], rows: NDArray[np.float64]
) -> bool:
    """:func:`admissible` of one point (m) for compiled callers, with :func:`admissible_constants` and scratch arrays
    ``theta`` (3,) and ``rows`` (3, 3): the steps of :func:`kinematics.elbow_out_angles`,
    :func:`kinematics.constraint_terms`, :func:`buildability.forearm_angles` and :func:`_conditioning` in scalar
    arithmetic, left at the first failed test."""
    r, l1, l2, tilt, low, high, max_tilt, max_skew, min_conditioning = constants
    for chain in range(3):
        theta[chain] = kernels.elbow_out_angle(x, y, z, chain, r, l1, l2)
        if not (low <= theta[chain] <= high):  # NaN (unreachable) fails
            return False
    serial = False
    for chain in range(3):
        cos_a, sin_a = CHAIN_COS[chain], CHAIN_SIN[chain]
        ax, ay, az, k = kernels.constraint_row(x, y, z, theta[chain], chain, r, l1)
        along_u = ax / l2 * cos_a + ay / l2 * sin_a
        along_t = -ax / l2 * sin_a + ay / l2 * cos_a
        cone = 0.0
        for axis_tilt in (tilt, tilt + theta[chain]):
            cosine = -along_u * math.sin(axis_tilt) - az / l2 * math.cos(axis_tilt)
            cone = max(cone, math.acos(min(max(cosine, -1.0), 1.0)))
        if not (cone <= max_tilt and math.asin(min(abs(along_t), 1.0)) <= max_skew):
            return False
        serial |= not abs(k) > 0.0
        rows[chain, 0], rows[chain, 1], rows[chain, 2] = ax / k, ay / k, az / k  # J^{-1} up to sign
    return (0.0 if serial else _singular_value_ratio(rows)) >= min_conditioning


@numba.njit(cache=True, inline="always")
def _singular_value_ratio(m: NDArray[np.float64]) -> float:
    """:func:`singular_value_ratio` of one 3 x 3 matrix, its steps in scalar arithmetic."""
    b = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            b[i, j] = m[0, i] * m[0, j] + m[1, i] * m[1, j] + m[2, i] * m[2, j]
    q = (b[0, 0] + b[1, 1] + b[2, 2]) / 3.0
    off = b[0, 1] ** 2 + b[0, 2] ** 2 + b[1, 2] ** 2
    p = math.sqrt(((b[0, 0] - q) ** 2 + (b[1, 1] - q) ** 2 + (b[2, 2] - q) ** 2 + 2.0 * off) / 6.0)
    if p <= 1e-15 * max(q, _TINY):
        largest = smallest = q
    else:
        for i in range(3):
            for j in range(3):
                b[i, j] = (b[i, j] - (q if i == j else 0.0)) / p
        phi = math.acos(min(max(kernels.determinant3(b) / 2.0, -1.0), 1.0)) / 3.0
        largest = q + 2.0 * p * math.cos(phi)
        smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return math.sqrt(max(smallest, 0.0) / largest) if largest > 0.0 else 0.0


def reach_bounds(geometry: DeltaGeometry, theta_range: tuple[float, float] = THETA_RANGE) -> tuple[float, float, float]:
    """A vertical cylinder that holds every reachable point: (radius, z_min, z_max) in m.

    The elbows of arms in ``theta_range`` lie within radius r + l1 and heights
    [-l1 max(sin th), -l1 min(sin th)]; the platform is l2 from each elbow.
    """
    low, high = require_interval("theta_range", theta_range, -math.pi, math.pi, unit="rad")
    angles = np.linspace(low, high, 721)
    elbow_z = -geometry.l1 * np.sin(angles)
    radius = geometry.r + geometry.l1 * float(np.max(np.cos(angles))) + geometry.l2
    return radius, float(np.min(elbow_z)) - geometry.l2, float(np.max(elbow_z)) + geometry.l2


def monte_carlo_volume(
    inside: Callable[[NDArray[np.float64]], NDArray[np.bool_]],
    bounds: tuple[float, float, float],
    samples: int,
    seed: int,
) -> tuple[float, float]:
    """Volume (m^3) and its standard error of a region inside a vertical cylinder, by Monte Carlo.

    Args:
        inside: Callable mapping points ``(n, 3)`` to booleans ``(n,)``.
        bounds: (radius, z_min, z_max) of a vertical cylinder on the z axis that holds the region (m).
        samples: Uniform samples in the cylinder, >= 100.
        seed: Seed of the sample points.

    Returns:
        (volume, standard error) in m^3; the error is that of a binomial proportion.
    """
    require_count("samples", samples, minimum=100)
    radius, z_min, z_max = bounds
    require_positive("bounds radius", radius, "m")
    require_in("bounds z_max", z_max, z_min, math.inf, unit="m", low_open=True)
    rng = np.random.default_rng(seed)
    hits = 0
    for start in range(0, samples, _CHUNK):
        n = min(_CHUNK, samples - start)
        rho = radius * np.sqrt(rng.random(n))
        phi = 2.0 * math.pi * rng.random(n)
        points = np.column_stack((rho * np.cos(phi), rho * np.sin(phi), rng.uniform(z_min, z_max, n)))
        hits += int(np.count_nonzero(inside(points)))
    fraction = hits / samples
    total = math.pi * radius**2 * (z_max - z_min)
    return total * fraction, total * math.sqrt(fraction * (1.0 - fraction) / samples)


def reachable_volume_estimate(
    geometry: DeltaGeometry, criteria: Criteria = REACHABLE, samples: int = VOLUME_SAMPLES, seed: int = 0
) -> tuple[float, float]:
    """Volume (m^3) of the points that satisfy ``criteria`` and its Monte Carlo standard error (m^3).

    Monte Carlo over a cylinder that holds the reach (:func:`reach_bounds`), reproducible by ``seed``; the
    standard error is about 1 % of the volume with the default samples.

    Args:
        geometry: Robot geometry.
        criteria: What makes a point admissible; by default the joint limits without a dexterity threshold.
        samples: Monte Carlo samples, >= 100.
        seed: Seed of the sample points.
    """
    bounds = reach_bounds(geometry, criteria.theta_range)
    return monte_carlo_volume(lambda points: admissible(geometry, points, criteria), bounds, samples, seed)


def reachable_volume(
    geometry: DeltaGeometry,
    theta_range: tuple[float, float] = THETA_RANGE,
    min_conditioning: float = 0.0,
    samples: int = VOLUME_SAMPLES,
    seed: int = 0,
    *,
    max_forearm_tilt: float = MAX_FOREARM_TILT,
    max_skew: float = MAX_PARALLELOGRAM_SKEW,
) -> float:
    """Volume (m^3) of the points reachable with theta in ``theta_range`` and 1/cond(J) >= ``min_conditioning``.

    The estimate of :func:`reachable_volume_estimate` (which also gives its standard error) for the
    :class:`Criteria` these arguments make.

    Args:
        geometry: Robot geometry.
        theta_range: (min, max) motor angle (rad).
        min_conditioning: Smallest 1 / cond_2(J), in [0, 1].
        samples: Monte Carlo samples, >= 100.
        seed: Seed of the sample points.
        max_forearm_tilt: Ball-joint cone (rad).
        max_skew: Parallelogram skew limit (rad).
    """
    criteria = Criteria(theta_range, max_forearm_tilt, min_conditioning, max_skew)
    return reachable_volume_estimate(geometry, criteria, samples, seed)[0]


@dataclass(frozen=True)
class SliceMap:
    """Kinematic measures on a plane grid.

    Attributes:
        plane: ``"horizontal"`` (axes x, y at height ``level``) or ``"vertical"`` (axes x, z at y = ``level``).
        level: z (horizontal) or y (vertical) of the plane (m).
        axis_u: First grid axis (m), ``(U,)``.
        axis_v: Second grid axis (m), ``(V,)``.
        points: Grid points (m), ``(V, U, 3)``.
        measures: :class:`PoseMeasures` on the grid, each ``(V, U)``.
    """

    plane: str
    level: float
    axis_u: NDArray[np.float64]
    axis_v: NDArray[np.float64]
    points: NDArray[np.float64]
    measures: PoseMeasures


def slice_map(
    geometry: DeltaGeometry,
    plane: str,
    level: float,
    extent_u: tuple[float, float],
    extent_v: tuple[float, float],
    resolution: int = 81,
) -> SliceMap:
    """Conditioning, IMI, det A and min |k_i| on a horizontal or vertical plane.

    Args:
        geometry: Robot geometry.
        plane: ``"horizontal"`` (x, y at z = level) or ``"vertical"`` (x, z at y = level).
        level: Height z or offset y of the plane (m).
        extent_u: (min, max) of x (m).
        extent_v: (min, max) of y (horizontal) or z (vertical) (m).
        resolution: Grid points per axis, >= 2.
    """
    if plane not in ("horizontal", "vertical"):
        raise ValueError(f"plane must be 'horizontal' or 'vertical', got {plane!r}")
    require_in("level", level, unit="m")
    low_u, high_u = require_interval("extent_u", extent_u, unit="m")
    low_v, high_v = require_interval("extent_v", extent_v, unit="m")
    require_count("resolution", resolution, minimum=2)
    axis_u, axis_v = np.linspace(low_u, high_u, resolution), np.linspace(low_v, high_v, resolution)
    grid_u, grid_v = np.meshgrid(axis_u, axis_v)
    fixed = np.full_like(grid_u, float(level))
    columns = (grid_u, grid_v, fixed) if plane == "horizontal" else (grid_u, fixed, grid_v)
    points = np.stack(columns, axis=-1)
    return SliceMap(plane, float(level), axis_u, axis_v, points, pose_measures(geometry, points))


def isotropic_speed(
    geometry: DeltaGeometry, xyz: ArrayLike, joint_speed_limit: float, measures: PoseMeasures | None = None
) -> NDArray[np.float64]:
    """Platform speed (m/s) reachable in every direction with |thd_i| <= ``joint_speed_limit`` (rad/s).

    omega * min_i |k_i| / l2 (module docstring); NaN where unreachable. ``measures``: :func:`pose_measures` at
    ``xyz`` if the caller has them already.
    """
    require_positive("joint_speed_limit", joint_speed_limit, "rad/s")
    measures = pose_measures(geometry, xyz) if measures is None else measures
    return joint_speed_limit * measures.min_abs_k / geometry.l2
