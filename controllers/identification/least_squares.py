"""Our identification: one linear least squares of all parameters at once (docs/design.md section 7).

Every (sample, joint) pair is a row of tau_i + 2 k_i lambda_i = rho1 I thdd_i + rho2 G_i + fv_i thd_i
+ fc_i sign(thd_i), with the regressor of ``DeltaDynamics.identification_regressor``; the fit reports
residual statistics and standard errors. A least squares of (rho1, rho2) alone gives MId.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.identification.data import MotionData, concatenate, regressor
from delta_env.validation import require_in

logger = logging.getLogger(__name__)

FRICTION_VELOCITY_THRESHOLD = 0.2
"""Smallest |theta_dot_i| (rad/s) of a moving joint-i row in the joint least squares.

Between rest (exactly 0 after :data:`REST_VELOCITY`) and this speed the model fv thd + fc sign(thd)
does not describe the plant's friction: the Stribeck excess (+50 % of Coulomb) decays over ~0.15 rad/s.
(With MuJoCo's default friction solref the plant's Coulomb friction was a soft constraint that reversed
sign while a joint braked below ~1 rad/s; the plant now uses the stiffest safe solreffriction, which
made 0.2 rad/s a valid threshold.) Rows at rest are left out too: there the plant's static friction
holds any torque up to its breakaway value (~1.5 fc), which no model of the rate can predict; keeping
them biased rho2 and made it vary 9x more between trajectories.
"""

RHO1_GRID = (0.5, 3.0, 0.01)
"""(min, max, step) of the paper's grid of rho1 (dimensionless)."""

RHO2_GRID = (0.5, 1.5, 0.01)
"""(min, max, step) of the paper's grid of rho2 (dimensionless)."""

JOINT_PARAMETER_NAMES = (
    "rho1",
    "rho2",
    "viscous_1",
    "viscous_2",
    "viscous_3",
    "coulomb_1",
    "coulomb_2",
    "coulomb_3",
)
"""Order of the parameters of the joint least squares (units: -, -, N m s/rad x3, N m x3)."""

_MAX_CONDITION = 1e10  # of the scaled normal equations; beyond it the data do not determine the parameters


def clipped_parameters(
    rho1: float, rho2: float, viscous: NDArray[np.float64], coulomb: NDArray[np.float64], method: str
) -> ModelParameters:
    """ModelParameters with negative friction estimates clipped at 0 (with a warning)."""
    for name, value in (("rho1", rho1), ("rho2", rho2)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{method}: identified {name} = {value!r} is not > 0; the data cannot support MId")
    clipped = {}
    for name, values in (("viscous", viscous), ("coulomb", coulomb)):
        negative = np.flatnonzero(values < 0.0)
        if negative.size:
            logger.warning(
                "%s: negative %s friction %s on joint(s) %s clipped to 0",
                method,
                name,
                np.round(values[negative], 4).tolist(),
                (negative + 1).tolist(),
            )
        clipped[name] = tuple(float(v) for v in np.maximum(values, 0.0))
    return ModelParameters(rho1=float(rho1), rho2=float(rho2), **clipped)


@dataclass(frozen=True)
class LeastSquaresFit:
    """A linear least-squares fit of (some of) the parameters, with residual statistics.

    Attributes:
        parameters: The fitted model; friction estimates below 0 are clipped to 0.
        names: Names of the estimated parameters (:data:`JOINT_PARAMETER_NAMES` or its first two).
        estimate: The raw (unclipped) estimates, ``(len(names),)``.
        standard_errors: sqrt(diag(sigma^2 (X^T X)^-1)) in the units of ``estimate``, with
            sigma^2 = RSS / (rows - parameters). The rows are 1 ms apart along smooth motions and their
            residuals (unmodelled dynamics, ripple, smoothing error) are strongly correlated, so the
            effective sample count is far smaller than ``rows``: these standard errors are optimistic,
            lower bounds; the spread between trajectories is the honest uncertainty.
        rows: Rows used per joint, ``(3,)``.
        residual_mean: Mean residual per joint (N m), ``(3,)``.
        residual_rms: RMS residual per joint (N m), ``(3,)``.
        residual_rms_total: RMS residual over all rows (N m).
    """

    parameters: ModelParameters
    names: tuple[str, ...]
    estimate: tuple[float, ...]
    standard_errors: tuple[float, ...]
    rows: tuple[int, int, int]
    residual_mean: tuple[float, float, float]
    residual_rms: tuple[float, float, float]
    residual_rms_total: float

    def summary(self) -> dict[str, Any]:
        """JSON-ready residual and sample statistics."""
        return {
            "rows_per_joint": list(self.rows),
            "residual_mean_per_joint": list(self.residual_mean),
            "residual_rms_per_joint": list(self.residual_rms),
            "residual_rms": self.residual_rms_total,
        }


def _parameter_columns(k: int) -> NDArray[np.int_]:
    """Per joint, the parameters its first ``k`` regressor columns [I thdd, G, thd, sign thd] multiply, ``(3, k)``.

    rho1 and rho2 are shared by the joints, fv_i and fc_i belong to joint i (JOINT_PARAMETER_NAMES order).
    """
    joints = np.arange(3)
    return np.column_stack((np.zeros(3, int), np.ones(3, int), 2 + joints, 5 + joints))[:, :k]


def _least_squares(
    rows: NDArray[np.float64],
    target: NDArray[np.float64],
    used: NDArray[np.bool_],
    names: tuple[str, ...],
    method: str,
) -> LeastSquaresFit:
    """Least squares of target[used] = X p over the used (sample, joint) rows, p named ``names``.

    X has one row per used (sample, joint): the first ``k`` regressor columns of that joint placed at the
    parameters of :func:`_parameter_columns` (k = 2 for rho alone, 4 with friction). It is never built:
    its normal equations are sums over the samples of per-joint 5 x 5 moment matrices of
    [regressor, target], one batched matrix product; the residuals are then computed explicitly.
    """
    k = 4 if len(names) > 2 else 2
    columns = _parameter_columns(k)
    z = np.concatenate((rows[..., :k], target[..., None]), axis=-1)  # (M, 3, k + 1)
    weighted = z * used[..., None]
    moments = np.matmul(weighted.transpose(1, 2, 0), z.transpose(1, 0, 2))  # (3, k + 1, k + 1)
    gram, projection = np.zeros((len(names), len(names))), np.zeros(len(names))
    for joint in range(3):
        index = columns[joint]
        gram[np.ix_(index, index)] += moments[joint, :k, :k]
        projection[index] += moments[joint, :k, k]
    n_rows = int(used.sum())
    if n_rows <= len(names):
        raise ValueError(f"{method}: {n_rows} rows cannot determine {len(names)} parameters {names}")
    scale = np.sqrt(np.diag(gram))
    if np.any(scale == 0.0):
        missing = [name for name, norm in zip(names, scale, strict=True) if norm == 0.0]
        raise ValueError(f"{method}: the data do not excite {missing}")
    # Jacobi scaling: the scaled Gram matrix of excitation data has a condition number near 1e2.
    scaled = gram / np.outer(scale, scale)
    condition = np.linalg.cond(scaled)
    if condition > _MAX_CONDITION:
        raise ValueError(f"{method}: the data do not determine {names} (condition number {condition:.3g})")
    inverse = np.linalg.inv(scaled) / np.outer(scale, scale)  # (X^T X)^-1
    estimate = inverse @ projection

    residual = target - np.sum(rows[..., :k] * estimate[columns], axis=-1)  # (M, 3)
    counts = used.sum(axis=0)  # > 0: a joint without rows leaves its friction unexcited (raised above)
    residual_sums = np.sum(residual * used, axis=0)
    squares = np.sum(residual**2 * used, axis=0)
    sigma2 = squares.sum() / (n_rows - len(names))
    friction = (estimate[2:5], estimate[5:8]) if k == 4 else (np.zeros(3), np.zeros(3))
    return LeastSquaresFit(
        parameters=clipped_parameters(estimate[0], estimate[1], *friction, method),
        names=names,
        estimate=tuple(float(v) for v in estimate),
        standard_errors=tuple(float(v) for v in np.sqrt(sigma2 * np.diag(inverse))),
        rows=tuple(int(c) for c in counts),
        residual_mean=tuple(float(v) for v in residual_sums / counts),
        residual_rms=tuple(float(v) for v in np.sqrt(squares / counts)),
        residual_rms_total=float(np.sqrt(squares.sum() / n_rows)),
    )


def _fit_joint(
    rows: NDArray[np.float64], target: NDArray[np.float64], theta_dot: NDArray[np.float64], velocity_threshold: float
) -> LeastSquaresFit:
    used = np.abs(theta_dot) > velocity_threshold
    return _least_squares(rows, target, used, JOINT_PARAMETER_NAMES, "joint least squares")


def _fit_rho(rows: NDArray[np.float64], target: NDArray[np.float64]) -> LeastSquaresFit:
    used = np.ones(target.shape, dtype=bool)
    return _least_squares(rows, target, used, JOINT_PARAMETER_NAMES[:2], "rho least squares")


def fit_joint_least_squares(
    data: Sequence[MotionData],
    *,
    dynamics: DeltaDynamics | None = None,
    velocity_threshold: float = FRICTION_VELOCITY_THRESHOLD,
) -> LeastSquaresFit:
    """MId+F by one linear least squares of [rho1, rho2, fv_1..3, fc_1..3] over all trajectories.

    Every (sample, joint) pair is a row of tau_i + 2 k_i lambda_i = rho1 I thdd_i + rho2 G_i + fv_i thd_i
    + fc_i sign(thd_i). Rows with |thd_i| <= ``velocity_threshold`` are left out: there the friction
    model is not valid (:data:`FRICTION_VELOCITY_THRESHOLD`), and so are rows at rest, where static friction
    takes an unknown share of the load.

    Args:
        data: Samples of one or more trajectories.
        dynamics: The analytical model (masses, geometry) whose corrections are identified; nominal if None.
        velocity_threshold: Smallest |theta_dot_i| (rad/s) of a moving row, >= 0.
    """
    require_in("velocity_threshold", velocity_threshold, 0.0, unit="rad/s")
    samples = concatenate(data)
    return _fit_joint(*regressor(samples, dynamics), samples.theta_dot, velocity_threshold)


def fit_rho_least_squares(data: Sequence[MotionData], *, dynamics: DeltaDynamics | None = None) -> LeastSquaresFit:
    """MId by linear least squares of (rho1, rho2) alone, friction not modelled, over all samples."""
    return _fit_rho(*regressor(concatenate(data), dynamics))


def fit_least_squares(
    data: Sequence[MotionData],
    *,
    dynamics: DeltaDynamics | None = None,
    velocity_threshold: float = FRICTION_VELOCITY_THRESHOLD,
) -> tuple[LeastSquaresFit, LeastSquaresFit]:
    """Both of our fits from one evaluation of the regressor: (MId by rho LS, MId+F by joint LS).

    The same as :func:`fit_rho_least_squares` and :func:`fit_joint_least_squares`, at half the cost.
    """
    require_in("velocity_threshold", velocity_threshold, 0.0, unit="rad/s")
    samples = concatenate(data)
    rows, target = regressor(samples, dynamics)
    return _fit_rho(rows, target), _fit_joint(rows, target, samples.theta_dot, velocity_threshold)


def between_trajectory_spread(data: Sequence[MotionData], dynamics: DeltaDynamics | None = None) -> dict[str, Any]:
    """Joint LS on each trajectory alone: the estimates and the standard error of their mean.

    ``dynamics`` is the model fitted, as in :func:`fit_joint_least_squares` (None: the nominal MKH).

    The honest uncertainty of the pooled estimate, unlike sigma^2 (X^T X)^-1 over correlated rows.
    """
    estimates = np.full((len(data), len(JOINT_PARAMETER_NAMES)), math.nan)
    for index, samples in enumerate(data):
        try:
            estimates[index] = fit_joint_least_squares([samples], dynamics=dynamics).estimate
        except ValueError as error:  # a short trajectory alone may not determine every parameter
            logger.info("trajectory %d left out of the between-trajectory spread: %s", index, error)
    fitted = estimates[~np.isnan(estimates).any(axis=1)]
    spread = (
        fitted.std(axis=0, ddof=1) / math.sqrt(len(fitted)) if len(fitted) > 1 else [None] * len(JOINT_PARAMETER_NAMES)
    )
    return {
        "per_trajectory": [[None if math.isnan(v) else v for v in row] for row in estimates.tolist()],
        "standard_error_of_mean": {
            name: None if value is None else float(value)
            for name, value in zip(JOINT_PARAMETER_NAMES, spread, strict=True)
        },
    }
