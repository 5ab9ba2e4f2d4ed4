"""The Stribeck excess of each joint's friction near zero speed, and so its breakaway torque (docs/design.md section 7).

The joint least squares leaves out the rows slower than :data:`FRICTION_VELOCITY_THRESHOLD`, where friction is more
than fv thd + fc sign(thd). On those rows (moving: faster than :data:`REST_VELOCITY`), the torque the identified
model leaves is fitted to the Stribeck law

    tau_i - tau_hat_i = fs_i exp(-(thd_i / vs)^2) sign(thd_i),

linear in the excess fs_i (N m) per joint for a decay speed vs (rad/s) shared by the joints, which a bounded scalar
search over log vs picks (the least total squared error). A joint at rest holds any torque up to its breakaway
fc_i + fs_i: what a servo must push to start it (:mod:`controllers.servo`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.identification.data import REST_VELOCITY, MotionData, concatenate, torque_errors
from controllers.identification.least_squares import FRICTION_VELOCITY_THRESHOLD
from delta_env.geometry import TORQUE_LIMIT

SLOWEST_DECAY = REST_VELOCITY
"""Smallest decay speed vs (rad/s) searched: rates below :data:`REST_VELOCITY` are set to 0 (at rest), so a faster
decay leaves no moving row to fit its excess (exp(-(v / vs)^2) vanishes on every one)."""

MIN_ROWS = 50
"""Fewest slow moving rows per joint the fit needs (the excitation's reversals give hundreds per trajectory)."""


@dataclass(frozen=True)
class StribeckFit:
    """The fitted Stribeck law of the three joints.

    Attributes:
        excess: Stribeck excess fs_i per joint (N m, >= 0: a negative estimate is clipped to 0).
        velocity: Decay speed vs (rad/s).
        standard_errors: Standard errors of the excess per joint (N m), at the fitted vs (optimistic: rows 1 ms apart
            have correlated residuals).
        rows: Slow moving rows per joint.
    """

    excess: tuple[float, float, float]
    velocity: float
    standard_errors: tuple[float, float, float]
    rows: tuple[int, int, int]


def _excess(rates: NDArray[np.float64], errors: NDArray[np.float64], velocity: float) -> tuple[float, float, float]:
    """Least squares of one joint's ``errors`` (N m) on exp(-(rate / velocity)^2) sign(rate): the excess, its
    standard error and the squared error left."""
    shape = np.exp(-((rates / velocity) ** 2)) * np.sign(rates)
    weight = float(shape @ shape)
    excess = float(shape @ errors) / weight
    squared = float(np.sum((errors - excess * shape) ** 2))
    return excess, math.sqrt(squared / max(len(rates) - 1, 1) / weight), squared


def fit_stribeck(
    data: Sequence[MotionData],
    parameters: ModelParameters,
    dynamics: DeltaDynamics,
    *,
    velocity_threshold: float = FRICTION_VELOCITY_THRESHOLD,
) -> StribeckFit:
    """Fit the Stribeck excess on the rows the joint least squares leaves out (module docstring).

    Args:
        data: Samples of one or more trajectories (rates at rest are exactly 0: :data:`REST_VELOCITY`).
        parameters: The identified parameters of ``dynamics`` (its Coulomb and viscous friction).
        dynamics: The model the parameters belong to (e.g. with rod forearms).
        velocity_threshold: Fastest |theta_dot_i| (rad/s) of a slow row, > :data:`REST_VELOCITY`.

    Raises:
        ValueError: if a joint has fewer than :data:`MIN_ROWS` slow moving rows, if the best decay speed lies at the
            search's bound (the data do not determine it; also a robot without excess), or if an excess is not
            finite or beyond the drive's torque limit.
    """
    if not velocity_threshold > REST_VELOCITY:
        raise ValueError(
            f"velocity_threshold must be > REST_VELOCITY = {REST_VELOCITY} rad/s, got {velocity_threshold}"
        )
    samples = concatenate(data)
    errors = torque_errors(parameters, samples, dynamics)
    speed = np.abs(samples.theta_dot)
    slow = (speed > 0.0) & (speed <= velocity_threshold)
    rows = tuple(int(n) for n in slow.sum(axis=0))
    if min(rows) < MIN_ROWS:
        raise ValueError(
            f"the data have {list(rows)} moving rows per joint slower than {velocity_threshold} rad/s; the "
            f"Stribeck fit needs at least {MIN_ROWS} on each joint (motion that starts, stops and reverses)"
        )
    columns = [(samples.theta_dot[slow[:, j], j], errors[slow[:, j], j]) for j in range(3)]

    def squared_error(log_velocity: float) -> float:
        return sum(_excess(rates, error, math.exp(log_velocity))[2] for rates, error in columns)

    search = minimize_scalar(
        squared_error, bounds=(math.log(SLOWEST_DECAY), math.log(velocity_threshold)), method="bounded"
    )
    velocity = math.exp(search.x)
    if not SLOWEST_DECAY * 1.01 < velocity < velocity_threshold / 1.01:
        raise ValueError(
            f"the data do not determine the Stribeck decay speed: the best lies at the search's bound, {velocity:.4f} "
            f"rad/s (too few slow moving rows near zero speed: {list(rows)} per joint)"
        )
    fits = [_excess(rates, error, velocity) for rates, error in columns]
    for joint, (excess, error, _) in enumerate(fits, start=1):
        if not (math.isfinite(excess) and math.isfinite(error) and abs(excess) <= TORQUE_LIMIT):
            raise ValueError(
                f"the Stribeck excess of joint {joint} is not determined by the data (fitted {excess!r} N m at vs = "
                f"{velocity:.4f} rad/s): too few slow moving rows near zero speed"
            )
    return StribeckFit(
        excess=tuple(max(excess, 0.0) for excess, _, _ in fits),
        velocity=velocity,
        standard_errors=tuple(error for _, error, _ in fits),
        rows=rows,
    )
