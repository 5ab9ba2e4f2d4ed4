"""Can a Delta geometry be built: ball-joint spacing on the platform, ball-joint cones and parallelogram skew.

One home for the facts that the plant (:mod:`delta_env.robot`), the workspace (:mod:`delta_env.workspace`)
and the design study's optimizer share:

- **Ball-joint spacing.** Each chain ends in two ball joints FOREARM_SPACING apart along its motor axis t_i, at
  rb u_i +- (s/2) t_i on the platform. The closest joints of neighbouring chains (120 deg apart) are
  ``sqrt(3) rb - s/2`` apart (the two points mirror each other about the bisector at 60 deg, each
  ``rb sin 60 - (s/2) cos 60`` from it). Their housings must not touch: that distance must be at least
  :data:`BALL_JOINT_HOUSING_DIAMETER` + :data:`BALL_JOINT_CLEARANCE`, so
  ``rb >= (s/2 + D + c) / sqrt(3)`` (:func:`min_platform_radius`).
- **Ball-joint cone about the cup axis.** A ball joint accepts the forearm within a cone about the axis its
  cup is mounted along. The cups are mounted so that every joint sits in the middle of its cone at home (arms
  horizontal, platform on the axis): the cup axis is the forearm's direction there, in the chain's plane and
  inclined :func:`delta_env.robot.forearm_home_tilt` from the vertical towards the axis (the orientation the plant
  builds its forearms in). The platform's cups do not rotate (the platform stays level), so their axis is fixed;
  the elbow's cups turn with the upper arm, so their axis is inclined ``forearm_home_tilt + theta_i``. The angle
  of a joint is the angle between the forearm and its cup axis (:func:`joint_angles`).
- **Parallelogram skew.** The angle of the forearms out of the plane normal to the elbow axis t_i,
  ``asin(|d . t_i|)`` with d the forearm's unit direction: the parallelogram leaves its rectangle by this
  angle, and the rods' distance across the pair (what holds the platform level about that chain) shrinks by
  ``cos(skew)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.config import FOREARM_SPACING
from delta_env.geometry import CHAIN_COS, CHAIN_SIN, DeltaGeometry
from delta_env.robot import forearm_home_tilt
from delta_env.validation import require_in, require_positive, require_vectors

BALL_JOINT_HOUSING_DIAMETER = 0.024
"""Outer diameter (m) of a ball-joint socket housing: DIN 71805 size 16 (16 mm ball, M10/M12 thread, body
24 mm), the standard socket for the nominal 12 mm forearm rods (:data:`delta_env.scaling.NOMINAL_FOREARM_ROD`)."""

BALL_JOINT_CLEARANCE = 0.005
"""Gap (m) kept between the housings of neighbouring ball joints: tolerances and the housings swivelling about
their balls (assumed)."""

_SQRT3 = math.sqrt(3.0)
_COS_ALPHA = np.array(CHAIN_COS)
_SIN_ALPHA = np.array(CHAIN_SIN)


def ball_joint_distance(rb: float, spacing: float = FOREARM_SPACING) -> float:
    """Distance (m) between the closest ball-joint centres of neighbouring chains on a platform of radius ``rb`` (m)."""
    require_positive("rb", rb, "m")
    require_positive("spacing", spacing, "m")
    return _SQRT3 * rb - spacing / 2.0


def min_platform_radius(
    spacing: float = FOREARM_SPACING,
    housing: float = BALL_JOINT_HOUSING_DIAMETER,
    clearance: float = BALL_JOINT_CLEARANCE,
) -> float:
    """Smallest platform radius rb (m) whose neighbouring ball joints keep ``housing + clearance`` (m) apart.

    Raises:
        ValueError: if a value is not positive, or the two joints of one chain (``spacing`` apart) already touch.
    """
    require_positive("spacing", spacing, "m")
    require_positive("housing", housing, "m")
    require_in("clearance", clearance, 0.0, math.inf, unit="m")
    if spacing < housing + clearance:
        raise ValueError(
            f"spacing must be >= housing + clearance = {housing + clearance} m so the two ball joints of one chain "
            f"do not touch, got {spacing} m"
        )
    return (spacing / 2.0 + housing + clearance) / _SQRT3


def platform_radius_shortfall(geometry: DeltaGeometry) -> float:
    """How far (m) ``geometry.rb`` falls short of :func:`min_platform_radius` of the plant; <= 0 when buildable.

    The optimizer's constraint (pymoo, <= 0) and the design study's buildability check.
    """
    return min_platform_radius() - geometry.rb


def joint_angles(
    geometry: DeltaGeometry, xyz: ArrayLike, theta: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ball-joint angle from the cup axis and parallelogram skew (rad) of each chain, each ``(..., 3)``.

    Args:
        geometry: Robot geometry.
        xyz: Platform positions (m), ``(..., 3)``.
        theta: Motor angles (rad) that reach them, ``(..., 3)`` (e.g. :func:`kinematics.elbow_out_angles`).

    Returns:
        (cone, skew): per chain the larger of the elbow's and the platform's joint angle from its cup axis,
        and the skew ``asin(|d . t_i|)`` (module docstring).
    """
    xyz = require_vectors("xyz", xyz)
    theta = require_vectors("theta", theta)
    a, _ = kinematics.constraint_terms(geometry, xyz, theta)
    return forearm_angles(geometry, a, theta)


def forearm_angles(
    geometry: DeltaGeometry, rows: NDArray[np.float64], theta: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`joint_angles` from the rows a_i = x - J'_i (m) of :func:`delta_env.kinematics.constraint_terms`,
    ``(..., 3, 3)``, and the motor angles (rad) ``(..., 3)``: for callers that already have the rows."""
    direction = rows / geometry.l2  # elbow to platform, unit length
    along_u = direction[..., 0] * _COS_ALPHA + direction[..., 1] * _SIN_ALPHA
    along_t = -direction[..., 0] * _SIN_ALPHA + direction[..., 1] * _COS_ALPHA
    along_z = direction[..., 2]
    tilt = forearm_home_tilt(geometry)

    def angle_from_axis(axis_tilt: ArrayLike) -> NDArray[np.float64]:
        # the cup axis points along -sin(tilt) u_i - cos(tilt) e_z (from the elbow down to the platform)
        cosine = -along_u * np.sin(axis_tilt) - along_z * np.cos(axis_tilt)
        return np.arccos(np.clip(cosine, -1.0, 1.0))

    cone = np.maximum(angle_from_axis(tilt), angle_from_axis(tilt + theta))
    skew = np.arcsin(np.clip(np.abs(along_t), 0.0, 1.0))
    return cone, skew
