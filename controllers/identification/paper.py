"""The paper's identification method, replicated (its section 4; docs/design.md section 7).

Per trajectory an exhaustive grid search of (rho1, rho2) minimising the RMS torque error of the paper's
eq. (7), averaged over trajectories (MId); then per trajectory and per joint the least squares of
(fv, fc) on the remaining error, averaged (MId+F).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.identification.data import MotionData, regressor, torque_errors
from controllers.identification.least_squares import clipped_parameters

RHO1_GRID = (0.5, 3.0, 0.01)
"""(min, max, step) of the paper's grid of rho1 (dimensionless)."""

RHO2_GRID = (0.5, 1.5, 0.01)
"""(min, max, step) of the paper's grid of rho2 (dimensionless)."""


def rho_grid(grid: tuple[float, float, float]) -> NDArray[np.float64]:
    """The values min, min + step, ..., max of a (min, max, step) grid."""
    low, high, step = grid
    if not (0.0 < low < high and step > 0.0):
        raise ValueError(f"a rho grid must be (min > 0, max > min, step > 0), got {grid}")
    return low + step * np.arange(round((high - low) / step) + 1)


def grid_search_rho(
    data: MotionData,
    *,
    dynamics: DeltaDynamics | None = None,
    rho1_grid: tuple[float, float, float] = RHO1_GRID,
    rho2_grid: tuple[float, float, float] = RHO2_GRID,
) -> tuple[float, float]:
    """The paper's eq. (7) on one trajectory: the grid point (rho1, rho2) of least RMS(tau - tau_hat).

    tau_hat = rho1 a + rho2 b + c is affine in (rho1, rho2), so the squared error of every grid point is
    evaluated exactly from the sums of a^2, ab, b^2, a e, b e with e = tau - c (all samples, joints
    pooled), instead of recomputing the torques for each point.

    Returns:
        (rho1, rho2) at the minimum; ties go to the first point in grid order.
    """
    rows, target = regressor(data, dynamics)
    a, b, e = rows[..., 0].ravel(), rows[..., 1].ravel(), target.ravel()
    r1, r2 = np.meshgrid(rho_grid(rho1_grid), rho_grid(rho2_grid), indexing="ij")
    # sum (e - r1 a - r2 b)^2 for every grid point
    squared_error = (
        e @ e - 2.0 * (r1 * (a @ e) + r2 * (b @ e)) + r1**2 * (a @ a) + 2.0 * r1 * r2 * (a @ b) + r2**2 * (b @ b)
    )
    best = np.unravel_index(np.argmin(squared_error), squared_error.shape)
    return float(r1[best]), float(r2[best])


def fit_friction_per_joint(
    data: MotionData, rho1: float, rho2: float, *, dynamics: DeltaDynamics | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The paper's section 4.2 on one trajectory: per joint, Delta tau = [thd, sign thd] (fv, fc) by LS.

    Delta tau = tau - tau_hat_MId(rho1, rho2), over all samples of the trajectory.

    Returns:
        fv (N m s/rad) and fc (N m), ``(3,)`` each, unclipped.
    """
    residual = torque_errors(ModelParameters(rho1=rho1, rho2=rho2), data, dynamics)
    viscous, coulomb = np.empty(3), np.empty(3)
    for joint in range(3):
        phi = np.column_stack((data.theta_dot[:, joint], np.sign(data.theta_dot[:, joint])))
        (viscous[joint], coulomb[joint]), *_ = np.linalg.lstsq(phi, residual[:, joint], rcond=None)
    return viscous, coulomb


@dataclass(frozen=True)
class PaperFit:
    """The paper's method over a set of trajectories.

    Attributes:
        mid: Averaged grid-search (rho1, rho2), no friction.
        mid_f: The same rho with the averaged per-joint friction.
        rho: Per-trajectory grid minima, ``(n, 2)``.
        viscous: Per-trajectory fv, ``(n, 3)`` (N m s/rad), unclipped.
        coulomb: Per-trajectory fc, ``(n, 3)`` (N m), unclipped.
    """

    mid: ModelParameters
    mid_f: ModelParameters
    rho: NDArray[np.float64]
    viscous: NDArray[np.float64]
    coulomb: NDArray[np.float64]


def fit_paper_method(
    data: Sequence[MotionData],
    *,
    dynamics: DeltaDynamics | None = None,
    rho1_grid: tuple[float, float, float] = RHO1_GRID,
    rho2_grid: tuple[float, float, float] = RHO2_GRID,
) -> PaperFit:
    """MId and MId+F as in the paper: grid search per trajectory, average; friction LS per trajectory, average."""
    if not data:
        raise ValueError("need at least one trajectory")
    rho = np.array([grid_search_rho(d, dynamics=dynamics, rho1_grid=rho1_grid, rho2_grid=rho2_grid) for d in data])
    rho1, rho2 = (float(v) for v in rho.mean(axis=0))
    friction = [fit_friction_per_joint(d, rho1, rho2, dynamics=dynamics) for d in data]
    viscous = np.array([fv for fv, _ in friction])
    coulomb = np.array([fc for _, fc in friction])
    return PaperFit(
        mid=ModelParameters(rho1=rho1, rho2=rho2),
        mid_f=clipped_parameters(rho1, rho2, viscous.mean(axis=0), coulomb.mean(axis=0), "paper method"),
        rho=rho,
        viscous=viscous,
        coulomb=coulomb,
    )
