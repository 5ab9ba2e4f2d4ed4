"""The payload estimator's settings, each with its reason, and the weighting of its equations (docs/design.md
section 6)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.estimation import SMOOTHER_WINDOW

RESIDUAL_STD = 1.5
"""Standard deviation (N m) of y - phi mp while the joints move: measured-torque noise (0.5 N m), torque
ripple (1 N m amplitude, 0.7 N m RMS) and the model's error on the plant (about 1 N m RMS of
tau_plant - tau_MId+F over excitation data at exact states), added in quadrature. MId+F+R's smaller error
(0.06 N m at exact states, 0.8 N m RMS on smoothed measured data) would make it 1.2 N m; the estimates
hardly depend on this value between 0.7 and 1.5 N m."""

FRICTION_VELOCITY = 1.0
"""Speed (rad/s) below which the friction of a joint is not the model's fv thd + fc sign(thd).

On a geared drive that covers the Stribeck region (0.01 to 0.1 rad/s is typical) and, more widely, the
start and the end of every move, where the friction builds up or falls away while the joint accelerates
or brakes: on the plant, the identification's held-out torque error is 1.45 N m RMS between 0 and
0.2 rad/s against 0.80 N m above. A narrower band lets that friction error into light payload estimates
after each stop; a wider one discards the samples of the lift that determine the mass."""

FRICTION_CORRELATION_SAMPLES = 100
"""Samples over which the friction error of a joint at rest stays the same: a station dwell (100 ms at
1 kHz with the timed release; with the in-position release a stop is 35 ms of air activation after the settle,
and the value was kept from the timed cell's tuning). Static friction is not white noise but one unknown constant
per stop; inflating its variance by the number of correlated samples makes a whole dwell count as about one
independent equation (the usual effective-sample-size correction of least squares with correlated errors)."""

REST_RATE = 0.05
"""Joint rate (rad/s) below which every joint counts as at rest: the payload equation of a sample with all
three joints slower is not used. At rest, static friction (and its Stribeck excess) holds any part of the
load within +-fc_i: the equation bounds the mass instead of measuring it, and its error is not zero-mean
over the dwell in which the gripper closes. Used, those samples carried a 0.17 kg object's estimate to
1.3 kg before the lift began; the estimate then starts from the prior when the joints start to move."""

FRICTION_SCALE_STD = 0.3
"""Prior standard deviation of the relative error of each joint's identified friction on the robot at hand
(a drive's friction changes by tens of percent with temperature, lubrication and wear): kappa_i of the
empty-move fit (:class:`PayloadEstimator`, ``friction_scale_std``). The friction torque is odd in the joint
rate and the payload regressor is not (gravity dominates it), so a friction error biases the apparent payload
with opposite signs on the carry and on the empty move back: a tare re-measured on the empty moves alone
would double that bias instead of removing it."""

MASS_CORRECTION_STD = (0.06, 0.05)
"""Prior standard deviations of the mass errors of the robot at hand fitted on the empty moves: its platform
mass (kg, the payload-like offset along phi) and the relative error of the arms' mass (dimensionless), which
scales both their inertia I = (m1/3 + m2) l1^2 and their gravity amplitude G = -(m1/2 + m2) g l1. They are
those of masses off by up to +-10 % each (uniform: a standard deviation of 5.8 % of each): m0 + 3 m2 = 1.4 kg
gives 0.06 kg, and I and G, dominated by m1, 5 %. With thousands of equations per empty move the data outweigh
them after the first move.

One scale for I and G, not one each: a mass error of the arms changes both by nearly the same fraction (m1
+10 %: I +7.7 %, G +8.3 %; m2 +10 %: +2.3 % and +1.7 %). On its own, a gravity error cannot be told from the
payload regressor at rest (J^T g e_z, which varies with cos th_i much as G_i does) nor from the Coulomb
friction of a joint that moves one way on every empty move (the empty moves all go from a place to a pick):
fitted freely, it was read as friction, whose sign then flips on the carry back. Tied to the inertia, it is
measured by the accelerations, which no other column resembles."""

DROP_VARIANCE = 0.01
"""Variance (kg^2) of the estimate restarted at the tare when a slip is detected: nothing is held, give or take
0.1 kg (the check that found the slip is that sure)."""

INNOVATION_GATE = 3.0
"""Normalized innovation (:meth:`~controllers.estimation.PayloadRLS.normalized_innovation`, standard deviations)
within which a carry's equation agrees with the estimate, after a disturbance (:meth:`PayloadEstimator.hold_out`):
99.7 % of the samples of a normal law, where a servo's recovery from a push lies two orders of magnitude out
(measured in docs/measurements.md, "A push's recovery, the estimate at the place and the pick's blind spot")."""

CONSISTENT_SAMPLES = SMOOTHER_WINDOW
"""Equations in a row within :data:`INNOVATION_GATE` that end a hold-out: as long as the fault monitor's collision
check asks its own residual to stay calm before it calls a collision over (the smoother's window, 26 samples). A
servo's recovery from a push swings through zero, a few samples at a time within the gate."""

PICK_PRIOR_VARIANCE = 16.0 / 3.0
"""Variance (kg^2) restored at a pick: the mean square of a mass uniform on [0, 4] kg (the rating)
around the prior of 0 kg."""


def residual_std(
    theta_dot: ArrayLike,
    static_friction: ArrayLike,
    nominal_std: float = RESIDUAL_STD,
    friction_velocity: float = FRICTION_VELOCITY,
    correlation_samples: float = FRICTION_CORRELATION_SAMPLES,
) -> NDArray[np.float64]:
    """Per-joint standard deviation (N m) of the payload equation's error at joint rates ``theta_dot``.

    sigma_i^2 = nominal_std^2 + n_c (f_i exp(-(thd_i / v_w)^2))^2: the nominal residual while moving, plus
    the static friction band f_i (N m) of a joint at rest, fading out as the joint speeds up past v_w,
    its variance inflated by the n_c samples over which it stays the same.

    Args:
        theta_dot: Joint rates (rad/s), ``(..., 3)``.
        static_friction: f_i (N m), ``(3,)``.
        nominal_std: Residual standard deviation while moving (N m).
        friction_velocity: v_w (rad/s).
        correlation_samples: n_c (samples).

    Returns:
        sigma (N m), ``(..., 3)``.
    """
    band = np.asarray(static_friction) * np.exp(-((np.asarray(theta_dot) / friction_velocity) ** 2))
    return np.sqrt(nominal_std**2 + correlation_samples * band**2)
