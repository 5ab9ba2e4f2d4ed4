"""Cartesian stiffness and first natural frequency of a design's platform (a reported figure, not a constraint).

Each chain is three springs in series between the base and the platform: the gearbox's torsional stiffness
and the upper arm bent as a cantilever (rotation per torque l1 / (3 E I): a tip force F deflects it
F l1^3 / (3 E I), and the torque is F l1), both about the motor axis, and the forearm pair stretched along its
rods (two rods, E A / l2 each; :mod:`delta_env.scaling` gives the sections). With the velocity constraint
a_i . xd + k_i thd_i = 0 (docs/design.md section 2), a platform displacement along the forearm direction
n_i = a_i / l2 turns the arm by |k_i| / l2 per metre, so chain i acts along n_i with stiffness

    s_i = 1 / ((k_i / l2)^2 c_i + 1 / (2 E A / l2)),   c_i = 1 / k_gear + l1 / (3 E I),

and the platform's translational stiffness is K_x = sum_i s_i n_i n_i^T. Its mass matrix is the design model's
joint-space inertia M(theta) mapped to the platform, M_x = J^-T M J^-1, with the payload on the platform and the
motor shafts held by their servo loops (the rotor inertia sits behind the gearbox, outside this mode). The
first natural frequency is the smallest root of det(K_x - w^2 M_x) = 0, over 2 pi.

Left out: the arm's out-of-plane bending and torsion (the forearms' pull is in the chain's plane up to the skew),
the ball joints' and the base frame's compliance, and the platform's tilt (the 3-DOF model has none): the figure
is an upper bound on the real robot's.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.scaling import arm_tip_stiffness, rod_axial_stiffness, scaled_masses
from delta_env.validation import require_in
from eval.design.model import design_model

GEARBOX_TORSIONAL_STIFFNESS = 50.0 * 60.0 * 180.0 / math.pi
"""Torsional stiffness (N m/rad) of each joint's gearbox at its output: 50 N m/arcmin (1.7e5 N m/rad), the order
that precision planetary gearboxes for about 400 N m peak output torque list in their data sheets (assumed, not one
catalogue entry)."""


def chain_compliance(geometry: DeltaGeometry) -> float:
    """Rotational compliance (rad/(N m)) of one chain about its motor axis: gearbox and bent upper arm in series."""
    return 1.0 / GEARBOX_TORSIONAL_STIFFNESS + 1.0 / (arm_tip_stiffness(geometry.l1) * geometry.l1**2)


def cartesian_stiffness(geometry: DeltaGeometry, xyz: ArrayLike) -> NDArray[np.float64]:
    """Translational stiffness K_x (N/m) of the platform at ``xyz`` (m), ``(..., 3, 3)`` (module docstring).

    Raises:
        ValueError: if a point is outside the reachable workspace.
    """
    theta = kinematics.inverse(geometry, xyz)
    a, k = kinematics.constraint_terms(geometry, xyz, theta)
    direction = a / geometry.l2
    legs = 1.0 / ((k / geometry.l2) ** 2 * chain_compliance(geometry) + 1.0 / (2.0 * rod_axial_stiffness(geometry.l2)))
    return np.einsum("...i,...ij,...ik->...jk", legs, direction, direction)


def cartesian_mass(
    geometry: DeltaGeometry, xyz: ArrayLike, payload: float, masses: DeltaMasses | None = None
) -> NDArray[np.float64]:
    """Mass matrix M_x (kg) of the platform at ``xyz`` (m) carrying ``payload`` (kg), ``(..., 3, 3)``: the links'
    inertia of the design model (its scaled masses unless ``masses``), without the rotors (module docstring)."""
    require_in("payload", payload, 0.0, math.inf, unit="kg")
    model = design_model(geometry, scaled_masses(geometry) if masses is None else masses, drive=None)
    xyz = np.asarray(xyz, dtype=float)
    theta = kinematics.inverse(geometry, xyz)
    zero = np.zeros_like(theta)
    gravity = model.inverse_dynamics(theta, zero, zero, payload)
    columns = [
        model.inverse_dynamics(theta, zero, np.broadcast_to(unit, theta.shape), payload) - gravity for unit in np.eye(3)
    ]
    joint_mass = np.stack(columns, axis=-1)  # M(theta), column j = response to thdd = e_j
    a, k = kinematics.constraint_terms(geometry, xyz, theta)
    inverse_jacobian = -a / k[..., None]  # thd = J^-1 xd
    return np.swapaxes(inverse_jacobian, -1, -2) @ joint_mass @ inverse_jacobian


def first_natural_frequency(
    geometry: DeltaGeometry, xyz: ArrayLike, payload: float, masses: DeltaMasses | None = None
) -> NDArray[np.float64]:
    """Lowest natural frequency (Hz) of the platform at each point ``xyz`` (m), ``(...)``, carrying ``payload`` (kg)."""
    xyz = np.asarray(xyz, dtype=float)
    stiffness = cartesian_stiffness(geometry, xyz).reshape(-1, 3, 3)
    mass = cartesian_mass(geometry, xyz, payload, masses).reshape(-1, 3, 3)
    lowest = [
        scipy.linalg.eigh(k, m, eigvals_only=True, subset_by_index=(0, 0))[0]
        for k, m in zip(stiffness, mass, strict=True)
    ]
    return (np.sqrt(np.array(lowest)) / (2.0 * math.pi)).reshape(xyz.shape[:-1])
