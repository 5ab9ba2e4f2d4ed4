"""The Delta model of one joint state, compiled for the 1 kHz loop (docs/design.md sections 2 and 3).

:func:`single_sample_model` is :class:`~controllers.dynamics.DeltaDynamics` (``inverse_dynamics`` at mp = 0 and
``payload_regressor``) written out in scalars: the 1 kHz controllers evaluate it twice per step (at the reference and
at the estimated joint state), and in CPython one evaluation alone costs about half a physics step.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from delta_env import kernels
from delta_env.geometry import CHAIN_COS, CHAIN_SIN

MODEL_CONSTANTS = np.dtype(
    (
        np.record,
        [
            ("l1", np.float64),
            ("r", np.float64),
            ("l2", np.float64),
            ("g", np.float64),
            ("inertia", np.float64),
            ("gravity", np.float64),
            ("platform_mass", np.float64),
            ("viscous", np.float64, 3),
            ("coulomb", np.float64, 3),
            ("forearm_rods", np.bool_),
            ("rod_coefficient", np.float64),
        ],
    )
)
"""The constants of :func:`single_sample_model` (:attr:`~controllers.dynamics.DeltaDynamics.model_constants`):
lengths l1, r, l2 (m), g (m/s^2), the scaled rho1 I (kg m^2) and rho2 G amplitude (N m), Mt without payload (kg),
fv_i (N m s/rad), fc_i (N m), whether the forearms are rods and -m2 / 3 (kg) if so. The model takes the record's
bytes (as the kernels of :mod:`delta_env.kernels`, for a cheaper call from Python)."""


@numba.njit(cache=True)
def single_sample_model(
    constants: NDArray[np.uint8],
    t1: float,
    t2: float,
    t3: float,
    w1: float,
    w2: float,
    w3: float,
    u1: float,
    u2: float,
    u3: float,
) -> tuple[int, NDArray[np.float64]]:
    """tau0 and phi of one joint state, rows 0 and 1 of the returned ``(6, 3)``, then the rows a_1..a_3 of A (m) and
    k (m); a status code first (:data:`delta_env.kernels.INVALID_STATE`).

    Written out in scalars (docs/design.md sections 2 and 3): forward kinematics, A, k, xdd and A^{-T} once.
    ``constants`` are the bytes of a :data:`MODEL_CONSTANTS` record
    (:attr:`~controllers.dynamics.DeltaDynamics.model_constants`).
    """
    terms = np.zeros((6, 3))
    if not math.isfinite(t1 + t2 + t3 + w1 + w2 + w3 + u1 + u2 + u3):
        return kernels.NOT_FINITE, terms
    model = constants.view(MODEL_CONSTANTS)[0]
    l1, r, l2 = model.l1, model.r, model.l2
    ca1, ca2, ca3 = CHAIN_COS
    sa1, sa2, sa3 = CHAIN_SIN
    c1, c2, c3 = math.cos(t1), math.cos(t2), math.cos(t3)
    s1, s2, s3 = math.sin(t1), math.sin(t2), math.sin(t3)
    # Elbows J'_i (docs/design.md section 2) and forward kinematics.
    p1x, p1y, p1z = kernels.elbow(t1, 0, r, l1)
    p2x, p2y, p2z = kernels.elbow(t2, 1, r, l1)
    p3x, p3y, p3z = kernels.elbow(t3, 2, r, l1)
    status, x, y, z = kernels.lower_intersection(p1x, p1y, p1z, p2x, p2y, p2z, p3x, p3y, p3z, l2)
    if status != kernels.VALID:
        return status, terms

    # Rows a_i = x - J'_i of A; k_i = -a_i . dJ'_i/dth_i with dJ'_i/dth_i = -l1 (s ca, s sa, c).
    a1x, a1y, a1z = x - p1x, y - p1y, z - p1z
    a2x, a2y, a2z = x - p2x, y - p2y, z - p2z
    a3x, a3y, a3z = x - p3x, y - p3y, z - p3z
    k1 = l1 * (s1 * (a1x * ca1 + a1y * sa1) + c1 * a1z)
    k2 = l1 * (s2 * (a2x * ca2 + a2y * sa2) + c2 * a2z)
    k3 = l1 * (s3 * (a3x * ca3 + a3y * sa3) + c3 * a3z)
    # A^{-1} = [g1 g2 g3] / det A by columns, g1 = a2 x a3, g2 = a3 x a1, g3 = a1 x a2.
    g1x, g1y, g1z = a2y * a3z - a2z * a3y, a2z * a3x - a2x * a3z, a2x * a3y - a2y * a3x
    g2x, g2y, g2z = a3y * a1z - a3z * a1y, a3z * a1x - a3x * a1z, a3x * a1y - a3y * a1x
    g3x, g3y, g3z = a1y * a2z - a1z * a2y, a1z * a2x - a1x * a2z, a1x * a2y - a1y * a2x
    det = a1x * g1x + a1y * g1y + a1z * g1z
    if det == 0.0 or not math.isfinite(det):
        return kernels.SINGULAR, terms
    inv_det = 1.0 / det

    # A xd = -K thd.
    b1, b2, b3 = -k1 * w1 * inv_det, -k2 * w2 * inv_det, -k3 * w3 * inv_det
    vx, vy, vz = b1 * g1x + b2 * g2x + b3 * g3x, b1 * g1y + b2 * g2y + b3 * g3y, b1 * g1z + b2 * g2z + b3 * g3z
    # A xdd = -|v_i|^2 + a_i . J'_thth,i thd_i^2 - k_i thdd_i, v_i = xd - J'_th,i thd_i,
    # J'_th,i = -l1 (s ca, s sa, c) and J'_thth,i = l1 (-c ca, -c sa, s).
    q1x, q1y, q1z = vx + l1 * s1 * ca1 * w1, vy + l1 * s1 * sa1 * w1, vz + l1 * c1 * w1
    q2x, q2y, q2z = vx + l1 * s2 * ca2 * w2, vy + l1 * s2 * sa2 * w2, vz + l1 * c2 * w2
    q3x, q3y, q3z = vx + l1 * s3 * ca3 * w3, vy + l1 * s3 * sa3 * w3, vz + l1 * c3 * w3
    r1 = (l1 * (s1 * a1z - c1 * (a1x * ca1 + a1y * sa1)) * w1 * w1 - k1 * u1) - (q1x * q1x + q1y * q1y + q1z * q1z)
    r2 = (l1 * (s2 * a2z - c2 * (a2x * ca2 + a2y * sa2)) * w2 * w2 - k2 * u2) - (q2x * q2x + q2y * q2y + q2z * q2z)
    r3 = (l1 * (s3 * a3z - c3 * (a3x * ca3 + a3y * sa3)) * w3 * w3 - k3 * u3) - (q3x * q3x + q3y * q3y + q3z * q3z)
    r1, r2, r3 = r1 * inv_det, r2 * inv_det, r3 * inv_det
    fx = r1 * g1x + r2 * g2x + r3 * g3x
    fy = r1 * g1y + r2 * g2y + r3 * g3y
    xdd_z = r1 * g1z + r2 * g2z + r3 * g3z
    fz = xdd_z + model.g  # xdd + g e_z
    # phi = J^T (xdd + g e_z) = -K A^{-T} (xdd + g e_z); row i of A^{-T} is g_i / det A.
    phi1 = -k1 * inv_det * (g1x * fx + g1y * fy + g1z * fz)
    phi2 = -k2 * inv_det * (g2x * fx + g2y * fy + g2z * fz)
    phi3 = -k3 * inv_det * (g3x * fx + g3y * fy + g3z * fz)

    inertia, gravity, mass = model.inertia, model.gravity, model.platform_mass
    fv1, fv2, fv3 = model.viscous[0], model.viscous[1], model.viscous[2]
    fc1, fc2, fc3 = model.coulomb[0], model.coulomb[1], model.coulomb[2]
    # sign(0) = 0, as np.sign in inverse_dynamics.
    tau1 = inertia * u1 + gravity * c1 + fv1 * w1 + fc1 * ((w1 > 0.0) - (w1 < 0.0)) + mass * phi1
    tau2 = inertia * u2 + gravity * c2 + fv2 * w2 + fc2 * ((w2 > 0.0) - (w2 < 0.0)) + mass * phi2
    tau3 = inertia * u3 + gravity * c3 + fv3 * w3 + fc3 * ((w3 > 0.0) - (w3 < 0.0)) + mass * phi3

    if model.forearm_rods:
        # u_ddot_i = xdd - J'_thth,i thd_i^2 - J'_th,i thdd_i, its part across the rod, then the virtual work
        # through d u_dot_i / d thd = J - J'_th,i e_i^T (module docstring). J'_thth = -l1 (c ca, c sa, -s)
        # and J'_th = -l1 (s ca, s sa, c).
        inv_l2_sq = 1.0 / (l2 * l2)
        ux1, uy1, uz1, own1 = _across_forearm(fx, fy, xdd_z, a1x, a1y, a1z, c1, s1, ca1, sa1, w1, u1, l1, inv_l2_sq)
        ux2, uy2, uz2, own2 = _across_forearm(fx, fy, xdd_z, a2x, a2y, a2z, c2, s2, ca2, sa2, w2, u2, l1, inv_l2_sq)
        ux3, uy3, uz3, own3 = _across_forearm(fx, fy, xdd_z, a3x, a3y, a3z, c3, s3, ca3, sa3, w3, u3, l1, inv_l2_sq)
        sx, sy, sz = 0.0 + ux1 + ux2 + ux3, 0.0 + uy1 + uy2 + uy3, 0.0 + uz1 + uz2 + uz3
        rod = model.rod_coefficient
        # J^T s = -K A^{-T} s, as phi.
        tau1 += rod * (-k1 * inv_det * (g1x * sx + g1y * sy + g1z * sz) - own1)
        tau2 += rod * (-k2 * inv_det * (g2x * sx + g2y * sy + g2z * sz) - own2)
        tau3 += rod * (-k3 * inv_det * (g3x * sx + g3y * sy + g3z * sz) - own3)
    terms[0, 0], terms[0, 1], terms[0, 2] = tau1, tau2, tau3
    terms[1, 0], terms[1, 1], terms[1, 2] = phi1, phi2, phi3
    terms[2, 0], terms[2, 1], terms[2, 2] = a1x, a1y, a1z
    terms[3, 0], terms[3, 1], terms[3, 2] = a2x, a2y, a2z
    terms[4, 0], terms[4, 1], terms[4, 2] = a3x, a3y, a3z
    terms[5, 0], terms[5, 1], terms[5, 2] = k1, k2, k3
    return kernels.VALID, terms


@numba.njit(cache=True, inline="always")
def _across_forearm(
    ax_: float,
    ay_: float,
    az_: float,
    px: float,
    py: float,
    pz: float,
    c: float,
    s: float,
    ca: float,
    sa: float,
    w: float,
    u: float,
    l1: float,
    inv_l2_sq: float,
) -> tuple[float, float, float, float]:
    """u_ddot_i across forearm i (m/s^2) and J'_th,i . u_ddot_perp_i, for one chain of the rod correction."""
    cx, cy, cz = c * ca, c * sa, -s
    dx, dy, dz = s * ca, s * sa, c
    ww, uu = l1 * w * w, l1 * u
    ux, uy, uz = ax_ + ww * cx + uu * dx, ay_ + ww * cy + uu * dy, az_ + ww * cz + uu * dz
    along = (px * ux + py * uy + pz * uz) * inv_l2_sq
    ux, uy, uz = ux - along * px, uy - along * py, uz - along * pz
    return ux, uy, uz, -l1 * (dx * ux + dy * uy + dz * uz)
