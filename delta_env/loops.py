"""The loop closures of the plant's closed chains (part of :class:`~delta_env.plant.DeltaPlant`, docs/design.md
section 4): the ``connect`` equalities that join each forearm rod's end to its point on the platform.

:class:`LoopClosures` caches the sites once and reads their residuals' Jacobian, its rate term and the largest gap
from a MuJoCo state, in the rows of one constraint Jacobian J_c (3 per connect).
"""

from __future__ import annotations

import math

import mujoco
import numba
import numpy as np
from numpy.typing import NDArray

from delta_env.robot import CHAIN_LABELS


class LoopClosures:
    """The loop-closure constraints of a Delta model: one per forearm rod (three on the ideal variant).

    Args:
        model: The plant's ``mujoco.MjModel``.
        data: The plant's ``mujoco.MjData``.
        rods: Rod labels per chain, ``ROD_LABELS`` for the realistic variant and ``("",)`` for the ideal one.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, rods: tuple[str, ...]) -> None:
        self.model, self.data = model, data
        site = mujoco.mjtObj.mjOBJ_SITE
        sites = [
            (
                mujoco.mj_name2id(model, site, f"forearm_{label}{rod}_end"),
                mujoco.mj_name2id(model, site, f"platform_{label}{rod}"),
            )
            for label in CHAIN_LABELS
            for rod in rods
        ]
        bodies = model.site_bodyid[np.array(sites)].tolist()
        self.n_rows = 3 * len(sites)
        """Number of constraint rows (3 per connect)."""
        # The Jacobians (and their derivatives) of the forearm-end sites in the rows of one array and those of
        # the platform sites in another, so that one subtraction forms the loop's; per loop, the ids as Python
        # ints, views of the two sites' positions (MjData keeps its buffers for its lifetime) and of the
        # loop's three rows in each array.
        self._site_jac = np.zeros((2, self.n_rows, model.nv))
        self._site_jac_dot = np.zeros((2, self.n_rows, model.nv))
        self._jac = np.zeros((self.n_rows, model.nv))
        self._jac_dot = np.zeros((self.n_rows, model.nv))
        self._terms = [
            (
                rod_site,
                platform_site,
                rod_body,
                platform_body,
                data.site_xpos[rod_site],
                data.site_xpos[platform_site],
                self._site_jac[0, 3 * k : 3 * k + 3],
                self._site_jac[1, 3 * k : 3 * k + 3],
                self._site_jac_dot[0, 3 * k : 3 * k + 3],
                self._site_jac_dot[1, 3 * k : 3 * k + 3],
            )
            for k, ((rod_site, platform_site), (rod_body, platform_body)) in enumerate(zip(sites, bodies, strict=True))
        ]
        self._site_pairs = np.array(sites, dtype=np.int64).reshape(-1, 2)
        self._site_xpos = data.site_xpos

    def jacobian(self) -> NDArray[np.float64]:
        """Jacobian (n_rows, nv) of the loop residuals (forearm end minus platform point, m).

        Uses the current ``site_xpos`` and ``cdof``: call after ``mj_kinematics`` and ``mj_comPos``
        (``mj_forward`` does both). The returned array is reused by the next call.
        """
        model, data = self.model, self.data
        for rod_site, platform_site, _, _, _, _, rod_rows, platform_rows, _, _ in self._terms:
            mujoco.mj_jacSite(model, data, rod_rows, None, rod_site)
            mujoco.mj_jacSite(model, data, platform_rows, None, platform_site)
        return np.subtract(self._site_jac[0], self._site_jac[1], out=self._jac)

    def bias_acceleration(self) -> NDArray[np.float64]:
        """Jdot_c qvel (m/s^2) of the loop residuals, shape (n_rows,), from ``mj_jacDot``.

        Needs the velocity stage (``cvel``, ``cdof_dot``) of the current state: call after ``mj_forward``, or
        after ``mj_kinematics``, ``mj_comPos`` and ``mj_comVel``.
        """
        model, data = self.model, self.data
        for _, _, rod_body, platform_body, rod_point, platform_point, _, _, rod_rows, platform_rows in self._terms:
            mujoco.mj_jacDot(model, data, rod_rows, None, rod_point, rod_body)
            mujoco.mj_jacDot(model, data, platform_rows, None, platform_point, platform_body)
        np.subtract(self._site_jac_dot[0], self._site_jac_dot[1], out=self._jac_dot)
        return self._jac_dot @ data.qvel

    def gap(self) -> float:
        """Largest distance (m) between the two points of any connect, from the current ``site_xpos``."""
        return largest_gap(self._site_xpos, self._site_pairs)


@numba.njit(cache=True)
def largest_gap(points: NDArray[np.float64], pairs: NDArray[np.int64]) -> float:
    """Largest distance (m) between the two points of any pair: rows ``pairs[k, 0]`` and ``pairs[k, 1]`` of
    ``points`` (n, 3) (m), ``pairs`` (m, 2); 0 without pairs. A NaN distance is skipped (it fails the comparison)."""
    largest = 0.0  # squared
    for k in range(pairs.shape[0]):
        a, b = pairs[k, 0], pairs[k, 1]
        dx, dy, dz = points[a, 0] - points[b, 0], points[a, 1] - points[b, 1], points[a, 2] - points[b, 2]
        squared = dx * dx + dy * dy + dz * dz
        if squared > largest:
            largest = squared
    return math.sqrt(largest)
