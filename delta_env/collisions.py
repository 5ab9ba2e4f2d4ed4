"""Arm-arm and arm-base collision checks of a Delta pose, on the plant's own link geometry.

At a platform position and its motor angles every link of the realistic plant (:mod:`delta_env.robot`) is a
capsule around a segment (the upper arm's tube and elbow bar, the forearm rods) or a vertical solid cylinder
(the platform disc, the base plate), with the plant's dimensions. The checks are their clearances (m, negative
when they overlap):

- **arm-arm**: forearm rods against the rods, tubes and elbow bars of the other chains, upper arms against
  each other, and the platform disc against the upper arms;
- **arm-base**: the upper arms, the rods and the platform disc against the base plate.

Left out, as in the plant with collisions on: each rod with the platform and the elbow bar it is ball-jointed
to, and the hubs, which turn in place on the motor axes. Capsules round the ends of the plant's cylinders, so a
clearance can differ from MuJoCo's contact distance by a fraction of a rod radius at an end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.config import FOREARM_SPACING
from delta_env.geometry import CHAIN_COS, CHAIN_SIN, DeltaGeometry
from delta_env.robot import (
    BASE_PLATE_OVERHANG,
    BASE_PLATE_Z,
    PLATFORM_THICKNESS,
    platform_disc_radius,
    upper_arm_parts,
)
from delta_env.scaling import forearm_rod_radius
from delta_env.validation import require_vectors

_U = np.stack((CHAIN_COS, CHAIN_SIN, np.zeros(3)), axis=-1)  # u_i, (3 chains, 3)
_T = np.stack((-np.array(CHAIN_SIN), CHAIN_COS, np.zeros(3)), axis=-1)  # t_i = e_z x u_i
_EZ = np.array([0.0, 0.0, 1.0])
_GOLDEN_STEPS = 30  # golden-section steps of a segment-cylinder distance: the bracket shrinks to 0.618^30 ~ 5e-7


@dataclass(frozen=True)
class Capsules:
    """Segments (m) and radii (m) of a set of capsules at poses: ``start``, ``end`` ``(..., n, 3)``, ``radius (n,)``."""

    start: NDArray[np.float64]
    end: NDArray[np.float64]
    radius: NDArray[np.float64]


@dataclass(frozen=True)
class PoseLinks:
    """The plant's links at poses ``(...)`` (module docstring).

    Attributes:
        tubes: Upper arms' tubes, one per chain.
        bars: Elbow bars, one per chain.
        rods: Forearm rods, chain-major (1a, 1b, 2a, ...).
        platform: Platform disc centres (m), ``(..., 3)``.
    """

    tubes: Capsules
    bars: Capsules
    rods: Capsules
    platform: NDArray[np.float64]


def pose_links(geometry: DeltaGeometry, xyz: ArrayLike, theta: ArrayLike) -> PoseLinks:
    """The plant's links with the platform at ``xyz`` (m) and motor angles ``theta`` (rad), each ``(..., 3)``."""
    xyz = require_vectors("xyz", xyz)
    theta = require_vectors("theta", theta)[..., None]
    arm = np.cos(theta) * _U - np.sin(theta) * _EZ  # (..., 3 chains, 3)
    motor = geometry.ra * _U
    elbow = motor + geometry.l1 * arm
    parts = upper_arm_parts(geometry)
    (start, _, _, end, _, _), tube_radius = parts["tube"]
    bar_half, bar_radius = parts["bar"][0][4], parts["bar"][1]
    ones = np.ones(3)
    tubes = Capsules(motor + start * arm, motor + end * arm, tube_radius * ones)
    bars = Capsules(elbow - bar_half * _T, elbow + bar_half * _T, bar_radius * ones)
    offsets = np.array([1.0, -1.0]) * FOREARM_SPACING / 2.0  # rod a, rod b along t_i
    side = _T[:, None, :] * offsets[None, :, None]  # (3 chains, 2 rods, 3)
    top = elbow[..., :, None, :] + side
    bottom = xyz[..., None, None, :] + geometry.rb * _U[:, None, :] + side
    shape = (*xyz.shape[:-1], 6, 3)
    rods = Capsules(top.reshape(shape), bottom.reshape(shape), forearm_rod_radius(geometry.l2) * np.ones(6))
    return PoseLinks(tubes=tubes, bars=bars, rods=rods, platform=xyz)


def segment_distance(p1: NDArray, q1: NDArray, p2: NDArray, q2: NDArray) -> NDArray[np.float64]:
    """Distance (m) between segments p1-q1 and p2-q2, elementwise over ``(..., 3)`` (closest points, clamped).

    Each segment must have a positive length.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = np.sum(d1 * d1, axis=-1), np.sum(d2 * d2, axis=-1)
    b, c, f = np.sum(d1 * d2, axis=-1), np.sum(d1 * r, axis=-1), np.sum(d2 * r, axis=-1)
    denominator = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-12 * a * e, np.clip((b * f - c * e) / denominator, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    gap = (p1 + s[..., None] * d1) - (p2 + t[..., None] * d2)
    return np.linalg.norm(gap, axis=-1)


def _cylinder_distance(
    point: NDArray, centre: NDArray, radius: float | NDArray, half_height: float
) -> NDArray[np.float64]:
    """Distance (m) of points to a solid vertical cylinder, elementwise (0 inside)."""
    offset = point - centre
    radial = np.maximum(np.hypot(offset[..., 0], offset[..., 1]) - radius, 0.0)
    vertical = np.maximum(np.abs(offset[..., 2]) - half_height, 0.0)
    return np.hypot(radial, vertical)


def segment_cylinder_distance(
    start: NDArray, end: NDArray, centre: NDArray, radius: float | NDArray, half_height: float
) -> NDArray[np.float64]:
    """Distance (m) between segments and solid vertical cylinders, elementwise over ``(..., 3)``.

    The distance of a point to a convex body is convex along the segment, so a golden-section search finds
    its minimum.
    """
    ratio = (math.sqrt(5.0) - 1.0) / 2.0

    def at(s: NDArray) -> NDArray:
        return _cylinder_distance(start + s[..., None] * (end - start), centre, radius, half_height)

    low, high = np.zeros(start.shape[:-1]), np.ones(start.shape[:-1])
    left, right = high - ratio, low + ratio
    at_left, at_right = at(left), at(right)
    for _ in range(_GOLDEN_STEPS):  # one new evaluation per step: the kept inner point is the next one's
        keep_left = at_left <= at_right
        low, high = np.where(keep_left, low, left), np.where(keep_left, right, high)
        inner = np.where(keep_left, high - ratio * (high - low), low + ratio * (high - low))
        at_inner = at(inner)
        left, right = np.where(keep_left, inner, right), np.where(keep_left, left, inner)
        at_left, at_right = np.where(keep_left, at_inner, at_right), np.where(keep_left, at_left, at_inner)
    ends = np.minimum(at(np.zeros_like(low)), at(np.ones_like(low)))
    return np.minimum(np.minimum(at_left, at_right), ends)


def _capsule_pairs(first: Capsules, i: list[int], second: Capsules, j: list[int]) -> NDArray[np.float64]:
    """Clearances (m) of capsules ``first[i]`` and ``second[j]``, ``(..., len(i))``."""
    start, end = first.start[..., i, :], first.end[..., i, :]
    distance = segment_distance(start, end, second.start[..., j, :], second.end[..., j, :])
    return distance - first.radius[i] - second.radius[j]


def arm_arm_clearance(geometry: DeltaGeometry, xyz: ArrayLike, theta: ArrayLike) -> NDArray[np.float64]:
    """Smallest clearance (m) between links of different chains and between the platform and the upper arms,
    ``(...)``; negative where they overlap (module docstring)."""
    links = pose_links(geometry, xyz, theta)
    rod_chain = np.repeat(np.arange(3), 2)
    rod_pairs = [(m, n) for m in range(6) for n in range(m + 1, 6) if rod_chain[m] != rod_chain[n]]
    rod_arm = [(m, c) for m in range(6) for c in range(3) if rod_chain[m] != c]
    arm_pairs = [(c, d) for c in range(3) for d in range(c + 1, 3)]
    arms = (links.tubes, links.bars)
    clearances = [_capsule_pairs(links.rods, [m for m, _ in rod_pairs], links.rods, [n for _, n in rod_pairs])]
    for part in arms:
        clearances.append(_capsule_pairs(links.rods, [m for m, _ in rod_arm], part, [c for _, c in rod_arm]))
        for other in arms:
            clearances.append(_capsule_pairs(part, [c for c, _ in arm_pairs], other, [d for _, d in arm_pairs]))
        disc = segment_cylinder_distance(
            part.start, part.end, links.platform[..., None, :], platform_disc_radius(geometry), PLATFORM_THICKNESS / 2
        )
        clearances.append(disc - part.radius)
    return np.min(np.concatenate(clearances, axis=-1), axis=-1)


def arm_base_clearance(geometry: DeltaGeometry, xyz: ArrayLike, theta: ArrayLike) -> NDArray[np.float64]:
    """Smallest clearance (m) between the upper arms, the rods or the platform disc and the base plate, ``(...)``;
    negative where they overlap (module docstring)."""
    links = pose_links(geometry, xyz, theta)
    bottom, top = BASE_PLATE_Z
    centre = np.array([0.0, 0.0, (bottom + top) / 2.0])
    plate_radius, plate_half = geometry.ra + BASE_PLATE_OVERHANG, (top - bottom) / 2.0
    clearances = [
        segment_cylinder_distance(part.start, part.end, centre, plate_radius, plate_half) - part.radius
        for part in (links.tubes, links.bars, links.rods)
    ]
    offset = links.platform - centre
    radial = np.hypot(offset[..., 0], offset[..., 1]) - plate_radius - platform_disc_radius(geometry)
    vertical = np.abs(offset[..., 2]) - plate_half - PLATFORM_THICKNESS / 2
    apart = np.hypot(np.maximum(radial, 0.0), np.maximum(vertical, 0.0))
    disc = np.where((radial > 0.0) | (vertical > 0.0), apart, np.maximum(radial, vertical))
    return np.minimum(np.min(np.concatenate(clearances, axis=-1), axis=-1), disc)


def smallest_clearances(geometry: DeltaGeometry, xyz: ArrayLike) -> tuple[float, float]:
    """Smallest arm-arm and arm-base clearance (m) over platform positions ``xyz`` (m), ``(n, 3)``, each with its
    elbow-out motor angles (:func:`delta_env.kinematics.inverse`, which raises for an unreachable point)."""
    xyz = require_vectors("xyz", xyz)
    if xyz.size == 0:
        raise ValueError("smallest_clearances needs at least one point")
    theta = kinematics.inverse(geometry, xyz)
    arm = float(np.min(arm_arm_clearance(geometry, xyz, theta)))
    return arm, float(np.min(arm_base_clearance(geometry, xyz, theta)))
