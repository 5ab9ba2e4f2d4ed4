# Over 500 lines: one estimator, its physics notes and the compiled kernels of its 1 kHz update.
"""Online payload mass estimation for the feedforward controllers (the paper's section 5, docs/design.md section 6).

The payload enters the identified model linearly, tau(mp) = tau0 + mp phi with tau0 = tau_model(mp = 0) and
phi = J^T (xdd + g e_z) (``DeltaDynamics.torque_and_payload_regressor``), so each control step gives three
equations in the one unknown mp,

    y = tau_measured - tau0 = phi mp + e,

solved by recursive least squares with forgetting (:class:`~controllers.estimation.PayloadRLS`, filterpy's
fading-memory Kalman filter). What biases the estimate on this plant, and what is done about it:

- **Friction near zero speed.** At rest the Coulomb friction is a constraint force anywhere in [-fc_i, fc_i]
  and the plant adds a Stribeck excess near zero speed, while the model predicts fc_i sign(thd_i) (0 at rest);
  while a joint starts or stops, its friction is not the model's either. With phi_i of a few N m/kg at rest
  (gravity alone), 4 N m of unknown friction is a kilogram of error. Each joint's equation is therefore
  weighted by a standard deviation that grows as |thd_i| falls (:func:`residual_std`): the nominal residual
  plus the static friction band fc_i, fading as exp(-(thd_i / v_w)^2) with v_w = 1 rad/s
  (:data:`FRICTION_VELOCITY`). That error is one constant per stop, not white noise, so its variance is
  inflated by the samples of a dwell: a whole stop counts as one equation, instead of outweighing the
  moving samples of the carry that follows it. Weighting is done by whitening
  (dividing phi_i and y_i by sigma_i), which is exactly RLS with R = diag(sigma_i^2) per update.
- **Torque timing.** A measured torque is ``delta_env.sensors.MEASURED_TORQUE_DELAY`` older than the
  encoder sample it comes with; every regressor below evaluates the model at the joint state interpolated
  linearly back to that instant, between the sample and the one before.
- **Joint states.** With ``regressor="smoothed"`` (the default) tau0 and phi are evaluated on the
  fixed-lag Kalman smoother's estimate of sample k - L (:class:`~controllers.estimation.JointStateSmoother`,
  L = 5 ms) and compared with the torque measured with that sample. The smoother runs on the tracking error
  theta - theta_ref, and the reference's exact derivatives at sample k - L are added back: what the reference
  describes needs no smoothing, and where its jerk steps (the start of a lift, 1e4 rad/s^3 at 6 g) the smoother
  follows only the robot's departure from it. ``regressor="filtered"`` uses the
  causal Kalman filter (:class:`~controllers.estimation.JointStateFilter`) instead, which estimates angle
  and rate without lag but the acceleration about 3 ms late (:func:`acceleration_lag`): the model is
  evaluated at (theta_{k-D}, theta_dot_{k-D}, theta_ddot_k), D = that lag in samples, with the torque of
  sample k - D. That alignment is exact for a constant jerk only; where the jerk changes, the filter's
  acceleration error has another shape, which biases light payload estimates by several percent for
  100 ms and more in the middle of a carry; the smoother has no such bias within its model.
  ``regressor="reference"`` evaluates tau0 and phi on the reference instead: no lag and no noise, but it
  silently assumes the robot is where the reference is, so the tracking transient right after a pick (the
  payload not yet fed forward) biases the estimate when it matters most; ``python -m eval`` runs both.
- **Model error along phi (the tare).** The model should have the forearm pairs as rods (MId+F+R,
  ``DeltaDynamics(forearm_rods=True)``): MId+F lumps each pair into two point masses, more inertia than two
  rods, so even at the plant's exact states it needs -0.1 kg of payload to match the plant with an empty
  gripper, and how much depends on the path (+0.3 kg in the first 30 ms of a lift). With MId+F+R the tare
  is 0.00 to -0.03 kg. Like a scale, the estimator is tared all the same: the apparent
  payload with nothing picked that the corrections fitted on the empty moves leave (a few grams) is measured
  on payload-free pick cycles (:func:`tare_from_observations`) and subtracted from the estimate; the
  feedforward keeps the apparent mass, which is what the model needs.
- **Gripper events.** The controller knows when the gripper closes and opens (``observation["gripper"]``).
  A pick is an abrupt change of mp that forgetting tracks slowly, so the covariance is reset there. While
  the gripper is open no object is carried: mp = 0 is known, so on release the estimate goes back to 0
  (the apparent mass to the tare; the object is gone) and the RLS does not run until the next pick (the
  suction cup belongs to m0).
- **At rest.** While every joint is slower than :data:`REST_RATE` (the dwell in which the gripper closes),
  static friction holds an unknown share of the load and the equation is not used: the estimate starts
  from the prior when the lift begins, instead of jumping on friction before it.
- **Masses and friction of the robot at hand.** A robot's masses and friction are not exactly the identified
  ones (domain randomization: +-10 % and +-30 %). A platform-mass error (m0, and the platform's share 3 m2 of
  the forearms) is exactly a payload error; an arm-mass error adds d_arm (I thdd + G), whose gravity part
  resembles phi at rest; a friction error is odd in the rate, so it biases the carry and the empty move back
  with opposite signs. The empty moves (mp = 0 known) fit all three by weighted least squares with priors
  (:class:`ModelCorrections`, :data:`MASS_CORRECTION_STD`, :data:`FRICTION_SCALE_STD`) and the carries'
  equations have them removed. On a carry dm and mp are the same column, so nothing in it tells them apart:
  a carry is corrected only if an empty move came before it in the episode (the env's default start, at a
  place point, gives every carry one; with ``start="pick"`` the first carry has none) or the robot's earlier
  empty moves seed the fit (:class:`EmptyMoveSums`, its calibration episodes). From one empty move the fitted
  platform mass is uncertain (it is collinear with the arm-mass scale there) and carries about 8 g of torque
  noise into the carry; the seeded sums of the same robot remove that.
- Torque ripple (1 N m, fast in position) and the measured-torque noise are zero-mean over a carry and go
  into the nominal residual standard deviation.
"""

from __future__ import annotations

import collections
import copy
import math
from collections.abc import Iterable
from typing import Literal, NamedTuple

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics, single_sample_model
from controllers.estimation import JointStateFilter, JointStateSmoother, PayloadRLS
from delta_env import kernels
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from delta_env.validation import require_in, require_positive

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
1 kHz). Static friction is not white noise but one unknown constant per stop; inflating its variance
by the number of correlated samples makes a whole dwell count as about one independent equation
(the usual effective-sample-size correction of least squares with correlated errors)."""

_TORQUE_AGE = MEASURED_TORQUE_DELAY / CONTROL_PERIOD
"""How long (in control periods) a measured torque precedes the encoder sample it comes with: the
payload equation of a sample is formed at the state interpolated this far back towards the previous one."""

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

PICK_PRIOR_VARIANCE = 16.0 / 3.0
"""Variance (kg^2) restored at a pick: the mean square of a mass uniform on [0, 4] kg (the rating)
around the prior of 0 kg."""


class ModelCorrections(NamedTuple):
    """Corrections of the identified model to the robot at hand, fitted on the empty moves of an episode.

    The plant's torque with an empty gripper is modelled as tau0 + dm phi + d_arm (I thdd + G) + kappa_i f_i: the
    model's, plus what mass and friction errors add (the model is linear in each; docs/design.md section 3).

    Attributes:
        platform_mass: dm (kg), the mass the model lacks at the platform: a payload-like offset along phi.
        arm_mass_scale: d_arm, the relative error of the arms' inertia I = (m1/3 + m2) l1^2 and gravity amplitude
            G = -(m1/2 + m2) g l1 together (dimensionless; :data:`MASS_CORRECTION_STD`).
        friction_scale: kappa_i, the relative error of each joint's friction fv_i thd_i + fc_i sign(thd_i), (3,).
    """

    platform_mass: float
    arm_mass_scale: float
    friction_scale: NDArray[np.float64]


class EmptyMoveSums(NamedTuple):
    """The weighted least-squares sums of a robot's empty moves, over the columns of :class:`ModelCorrections`
    (platform mass, arm-mass scale, three friction scales).

    What the robot's earlier work taught about its own mass and friction errors: seeded into the fit at every
    episode (``PayloadEstimator(empty_moves=...)``), they make its corrections as certain from the start as many
    empty moves would. Only for the robot they were measured on.

    Attributes:
        information: sum of w c c^T, (5, 5).
        moment: sum of w c y, (5,).
    """

    information: NDArray[np.float64]
    moment: NDArray[np.float64]


class Tare(NamedTuple):
    """What payload-free pick cycles tell a payload estimator (:func:`tare_from_observations`).

    Attributes:
        mass: Apparent payload of the empty gripper on carries (kg), the tare.
        spread: Standard deviation of the same estimate carry by carry (kg); NaN from one carry.
        empty_moves: The sums of the cycles' empty moves (:class:`EmptyMoveSums`).
    """

    mass: float
    spread: float
    empty_moves: EmptyMoveSums


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


def acceleration_lag(joint_filter: JointStateFilter, dt: float = CONTROL_PERIOD) -> float:
    """Steady-state lag (s) of a joint filter's acceleration estimate behind a constant-jerk motion.

    A copy of the filter is run on theta = j t^3 / 6 until its error settles; the acceleration error over
    the jerk is the lag. The constant-acceleration model tracks angle and rate of such a motion without
    lag (below 0.02 ms at the default settings), so the acceleration is the one to align.
    """
    probe = copy.deepcopy(joint_filter)
    probe.reset(np.zeros(3))
    jerk, samples = 1000.0, 500
    for n in range(1, samples + 1):
        _, _, theta_ddot = probe.update(np.full(3, jerk * (n * dt) ** 3 / 6.0))
    return float(jerk * samples * dt - theta_ddot[0]) / jerk


# Layout of PayloadEstimator._equation, the constants of the compiled payload equation.
_EQ_BAND, _EQ_INVERSE_VELOCITY, _EQ_NOMINAL_VARIANCE, _EQ_VISCOUS, _EQ_COULOMB = 0, 3, 4, 5, 8
_EQ_TORQUE_AGE, _EQ_REST_RATE, _EQ_INERTIA, _EQ_GRAVITY, _EQ_PRIOR, _EQ_FITS = 11, 12, 13, 14, 15, 20
# Parameters of the empty-move fit: dm (kg), d_arm, kappa_1..3 (ModelCorrections).
_P_PLATFORM, _P_ARM, _P_FRICTION, _PARAMETERS = 0, 1, 2, 5
# Layout of PayloadEstimator._fit: sum of w c c^T (5 x 5, by rows) and of w c y over the empty moves, the
# parameters solved from them, whether new empty-move equations came in since, and how many came in.
_FIT_INFORMATION, _FIT_MOMENT, _FIT_SOLUTION, _FIT_STALE, _FIT_SAMPLES, _FIT_SIZE = 0, 25, 30, 35, 36, 37


@numba.njit(cache=True)
def _solve_fit(equation: NDArray[np.float64], fit: NDArray[np.float64]) -> None:
    """Solve the empty-move least squares with its prior (information added to the diagonal) into ``fit``.

    A parameter whose prior information is NaN is not fitted: it stays 0.
    """
    matrix = np.empty((_PARAMETERS, _PARAMETERS))
    vector = np.empty(_PARAMETERS)
    for a in range(_PARAMETERS):
        vector[a] = fit[_FIT_MOMENT + a]
        for b in range(_PARAMETERS):
            matrix[a, b] = fit[_FIT_INFORMATION + _PARAMETERS * a + b]
    for a in range(_PARAMETERS):
        prior = equation[_EQ_PRIOR + a]
        if math.isnan(prior):
            matrix[a, :] = 0.0
            matrix[:, a] = 0.0
            matrix[a, a] = 1.0
            vector[a] = 0.0
        else:
            matrix[a, a] += prior
    solution = np.linalg.solve(matrix, vector)
    for a in range(_PARAMETERS):
        fit[_FIT_SOLUTION + a] = solution[a]
    fit[_FIT_STALE] = 0.0


@numba.njit(cache=True, inline="always")
def _weighted_equation(
    equation: NDArray[np.float64],
    fit: NDArray[np.float64],
    carrying: bool,
    tau0: tuple[float, float, float],
    phi: tuple[float, float, float],
    rates: tuple[float, float, float],
    torque: tuple[float, float, float],
    cosines: tuple[float, float, float],
    accelerations: tuple[float, float, float],
) -> tuple[bool, float, float]:
    """One sample's weighted payload equation: (used, sum w phi^2, sum w phi y), or the empty-move fit.

    w_i = 1 / sigma_i^2 of :func:`residual_std`, f_i = fv_i thd_i + fc_i sign(thd_i) the model's friction, and per
    joint the columns c_i = (phi_i, I thdd_i + G cos th_i, f_i on the joint's own kappa) of
    :class:`ModelCorrections`. With the gripper open (mp = 0 known) the sample adds w_i c_i c_i^T and
    w_i c_i (tau_i - tau0_i) to the fit (``fit``, in place); while carrying, y_i = tau_i - tau0_i - c_i . p with
    p the fit solved at the first carrying sample after empty ones.
    """
    rest = equation[_EQ_REST_RATE]
    if abs(rates[0]) < rest and abs(rates[1]) < rest and abs(rates[2]) < rest:
        return False, 0.0, 0.0  # static friction holds an unknown share of the load: no measurement of the mass
    fits = equation[_EQ_FITS] != 0.0
    if not carrying and not fits:
        return False, 0.0, 0.0
    if carrying and fit[_FIT_STALE] != 0.0:
        _solve_fit(equation, fit)
    information = moment = 0.0
    for i in range(3):
        rate = rates[i]
        scaled = rate * equation[_EQ_INVERSE_VELOCITY]
        band = equation[_EQ_BAND + i] * math.exp(-(scaled * scaled))
        weight = 1.0 / (equation[_EQ_NOMINAL_VARIANCE] + band * band)
        coulomb = math.copysign(equation[_EQ_COULOMB + i], rate) if rate != 0.0 else 0.0  # fc sign(thd), 0 at rest
        friction = equation[_EQ_VISCOUS + i] * rate + coulomb
        arm = equation[_EQ_INERTIA] * accelerations[i] + equation[_EQ_GRAVITY] * cosines[i]
        columns = (phi[i], arm, friction)
        indices = (_P_PLATFORM, _P_ARM, _P_FRICTION + i)
        residual = torque[i] - tau0[i]
        if carrying:
            for a in range(3):
                residual -= fit[_FIT_SOLUTION + indices[a]] * columns[a]
            information += weight * phi[i] * phi[i]
            moment += weight * phi[i] * residual
        else:
            for a in range(3):
                weighted = weight * columns[a]
                fit[_FIT_MOMENT + indices[a]] += weighted * residual
                for b in range(3):
                    fit[_FIT_INFORMATION + _PARAMETERS * indices[a] + indices[b]] += weighted * columns[b]
    if not carrying:
        fit[_FIT_STALE] = 1.0
        fit[_FIT_SAMPLES] += 1.0
    return carrying, information, moment


@numba.njit(cache=True)
def _back_to_torque_instant(
    current: NDArray[np.float64], previous: NDArray[np.float64], age: float
) -> NDArray[np.float64]:
    """Rows (rows, 3) of this sample interpolated back ``age`` control periods towards the previous sample's:
    x - age (x - x_previous), the instant of the measured torque."""
    x = np.empty(current.shape)
    for row in range(current.shape[0]):
        for joint in range(3):
            now = current[row, joint]
            x[row, joint] = now - age * (now - previous[row, joint])
    return x


@numba.njit(cache=True)
def _reference_equation(
    equation: NDArray[np.float64],
    fit: NDArray[np.float64],
    carrying: bool,
    current: NDArray[np.float64],
    previous: NDArray[np.float64],
    torque1: float,
    torque2: float,
    torque3: float,
) -> tuple[bool, float, float]:
    """:func:`_weighted_equation` at the reference (``regressor="reference"``), interpolated back to the torque's
    instant between the previous step's and this step's ``(5, 3)``: rows tau0 (N m), phi (N m/kg), theta (rad),
    theta_dot (rad/s), theta_ddot (rad/s^2)."""
    x = _back_to_torque_instant(current, previous, equation[_EQ_TORQUE_AGE])
    return _weighted_equation(
        equation,
        fit,
        carrying,
        (x[0, 0], x[0, 1], x[0, 2]),
        (x[1, 0], x[1, 1], x[1, 2]),
        (x[3, 0], x[3, 1], x[3, 2]),
        (torque1, torque2, torque3),
        (math.cos(x[2, 0]), math.cos(x[2, 1]), math.cos(x[2, 2])),
        (x[4, 0], x[4, 1], x[4, 2]),
    )


@numba.njit(cache=True)
def _estimated_state_equation(
    model: NDArray,
    equation: NDArray[np.float64],
    fit: NDArray[np.float64],
    state: NDArray[np.float64],
    previous: NDArray[np.float64],
    carrying: bool,
    torque1: float,
    torque2: float,
    torque3: float,
) -> tuple[int, bool, float, float]:
    """The weighted payload equation at an estimated joint state: (model status, used, moments).

    ``state`` and ``previous`` are (3, 3), rows theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2) of this
    sample and the one before; the model is evaluated at the state interpolated back to the torque's instant,
    x - a (x - x_previous) with a the torque's age in control periods.
    """
    x = _back_to_torque_instant(state, previous, equation[_EQ_TORQUE_AGE])
    status, terms = single_sample_model(
        model, x[0, 0], x[0, 1], x[0, 2], x[1, 0], x[1, 1], x[1, 2], x[2, 0], x[2, 1], x[2, 2]
    )
    if status != kernels.VALID:
        return status, False, 0.0, 0.0
    used, information, moment = _weighted_equation(
        equation,
        fit,
        carrying,
        (terms[0, 0], terms[0, 1], terms[0, 2]),
        (terms[1, 0], terms[1, 1], terms[1, 2]),
        (x[1, 0], x[1, 1], x[1, 2]),
        (torque1, torque2, torque3),
        (math.cos(x[0, 0]), math.cos(x[0, 1]), math.cos(x[0, 2])),
        (x[2, 0], x[2, 1], x[2, 2]),
    )
    return status, used, information, moment


def _checked_sums(sums: EmptyMoveSums) -> EmptyMoveSums:
    """``sums`` as float arrays of shapes (5, 5) and (5,), finite, the information symmetric; else ValueError."""
    information = np.array(sums.information, dtype=np.float64)
    moment = np.array(sums.moment, dtype=np.float64)
    if information.shape != (_PARAMETERS, _PARAMETERS) or moment.shape != (_PARAMETERS,):
        raise ValueError(f"empty_moves must be (5, 5) and (5,) sums, got shapes {information.shape} and {moment.shape}")
    if not (np.all(np.isfinite(information)) and np.all(np.isfinite(moment))):
        raise ValueError("empty_moves must be finite")
    if not np.allclose(information, information.T, rtol=1e-9, atol=0.0):
        raise ValueError("empty_moves.information must be symmetric (a sum of w c c^T)")
    return EmptyMoveSums(information, moment)


class PayloadEstimator:
    """Payload mass (kg) from measured joint torques, updated once per control step while the gripper holds.

    The empty moves of the episode (gripper open, mp = 0 known), added to the robot's earlier ones if seeded
    (``empty_moves``), fit the robot's own mass and friction errors (:class:`ModelCorrections`); the carries'
    equations have them removed, and their RLS state is the object's mass plus the tare, the model's remaining
    error along phi on carries (about 0.00 to -0.03 kg for MId+F+R on the nominal plant). The estimate of the
    object is the RLS state minus the tare; the feedforward uses the apparent mass, what the model needs at its
    platform: the RLS state plus the fitted platform-mass correction.

    Args:
        dynamics: The identified model (MId+F) whose torque at mp = 0 is subtracted.
        regressor: ``"smoothed"`` evaluates tau0 and phi on the :class:`JointStateSmoother` estimate of
            the measured joints; ``"filtered"`` on the :class:`JointStateFilter` estimate, aligned with its
            acceleration lag; ``"reference"`` on the reference interpolated to the torque sample (see the
            module docstring).
        tare: Apparent payload of the empty gripper on carries (kg) beyond the empty-move fit, from
            :func:`tare_from_observations` on payload-free pick cycles; 0 trusts the model.
        nominal_std: Residual standard deviation while moving (N m).
        static_friction: Static friction band f_i per joint (N m); None uses the model's Coulomb friction
            fc_i (MId+F's identified values), which is what the model cannot predict at rest.
        friction_velocity: v_w (rad/s) of :func:`residual_std`.
        correlation_samples: n_c of :func:`residual_std`.
        forgetting_factor: lambda of the RLS within a carry (memory about 1 / (1 - lambda) samples).
        prior_variance: Variance of the mass (kg^2) restored at every pick.
        rest_rate: Samples with every joint slower than this (rad/s) are not used (:data:`REST_RATE`); 0 uses all.
        friction_scale_std: Prior standard deviation of each joint's friction scale error kappa_i
            (dimensionless), fitted on the empty moves and removed from the carries' equations
            (:data:`FRICTION_SCALE_STD`); None trusts the identified friction.
        mass_correction_std: Prior standard deviations of the platform-mass error (kg) and of the arms' relative
            mass error (dimensionless), fitted likewise (:data:`MASS_CORRECTION_STD`); None trusts the
            identified masses.
        empty_moves: Sums of this robot's earlier empty moves (:class:`EmptyMoveSums`, e.g. its calibration
            episodes) that seed the fit of the corrections at every episode; None starts each episode from the
            priors alone (a robot with no history). Needs a fit (a correction std not None).

    Attributes:
        rls: The :class:`PayloadRLS` of the apparent payload (whitened: its noise standard deviation is 1).
        joint_filter: The :class:`JointStateSmoother` of the tracking error (``"smoothed"``) or the
            :class:`JointStateFilter` of the measured joints (``"filtered"``); None with ``regressor="reference"``.
        delay: Control periods between the newest observation and the sample whose equation is formed: the
            smoother's lag, the filter's acceleration lag, or 0 with ``regressor="reference"``.
        empty_moves: The checked seed sums (:class:`EmptyMoveSums`), or None.
    """

    def __init__(
        self,
        dynamics: DeltaDynamics,
        *,
        regressor: Literal["smoothed", "filtered", "reference"] = "smoothed",
        tare: float = 0.0,
        nominal_std: float = RESIDUAL_STD,
        static_friction: tuple[float, float, float] | None = None,
        friction_velocity: float = FRICTION_VELOCITY,
        correlation_samples: float = FRICTION_CORRELATION_SAMPLES,
        forgetting_factor: float = 0.999,
        prior_variance: float = PICK_PRIOR_VARIANCE,
        rest_rate: float = REST_RATE,
        friction_scale_std: float | None = FRICTION_SCALE_STD,
        mass_correction_std: tuple[float, float] | None = MASS_CORRECTION_STD,
        empty_moves: EmptyMoveSums | None = None,
    ) -> None:
        if regressor not in ("smoothed", "filtered", "reference"):
            raise ValueError(f"regressor must be 'smoothed', 'filtered' or 'reference', got {regressor!r}")
        require_positive("nominal_std", nominal_std)
        require_positive("friction_velocity", friction_velocity)
        require_positive("correlation_samples", correlation_samples)
        require_in("tare", tare, unit="kg")
        require_in("rest_rate", rest_rate, 0.0, unit="rad/s")
        if friction_scale_std is not None:
            require_positive("friction_scale_std", friction_scale_std)
        if mass_correction_std is not None:
            if len(mass_correction_std) != 2:
                raise ValueError(f"mass_correction_std must be 2 values (kg, -), got {mass_correction_std!r}")
            for name, std in zip(("platform mass", "arm mass scale"), mass_correction_std, strict=True):
                require_positive(f"mass_correction_std ({name})", std)
        friction = dynamics.parameters.coulomb if static_friction is None else tuple(static_friction)
        if len(friction) != 3 or not all(math.isfinite(f) and f >= 0.0 for f in friction):
            raise ValueError(f"static_friction must be 3 finite values >= 0 N m, got {static_friction!r}")
        self.dynamics = dynamics
        self.regressor = regressor
        self.tare = float(tare)
        self.nominal_std = float(nominal_std)
        self.static_friction = tuple(float(f) for f in friction)
        self.friction_velocity = float(friction_velocity)
        self.correlation_samples = float(correlation_samples)
        self.rest_rate = float(rest_rate)
        # The empty-move least squares and its solution (layout _FIT_*).
        self._fit = np.zeros(_FIT_SIZE)
        self.rls = PayloadRLS(
            forgetting_factor=forgetting_factor, noise_std=1.0, initial_variance=prior_variance, initial_mass=tare
        )
        self.joint_filter: JointStateSmoother | JointStateFilter | None = None
        self.delay = 0
        if regressor == "smoothed":
            self.joint_filter = JointStateSmoother()
            self.delay = self.joint_filter.lag
        elif regressor == "filtered":
            self.joint_filter = JointStateFilter()
            self.delay = round(acceleration_lag(self.joint_filter) / CONTROL_PERIOD)
        # (the causal filter's joint-state estimate, or the reference's (3, 3) state with the smoother; measured
        # torque; gripper holding) of the last D + 1 samples.
        self._history: collections.deque[tuple[tuple[NDArray, NDArray, NDArray] | None, list[float], bool]] = (
            collections.deque(maxlen=self.delay + 1)
        )
        # Prior information of the fitted parameters (layout _P_*), NaN for those not fitted.
        mass_prior = (math.nan,) * 2 if mass_correction_std is None else tuple(std**-2 for std in mass_correction_std)
        friction_prior = math.nan if friction_scale_std is None else friction_scale_std**-2
        prior_information = (*mass_prior, *(friction_prior,) * 3)
        # Constants of the compiled payload equation (layout _EQ_*); the band's standard deviation is sqrt(n_c) f_i.
        self._equation = np.array(
            [
                *(math.sqrt(self.correlation_samples) * f for f in self.static_friction),
                1.0 / self.friction_velocity,
                self.nominal_std**2,
                *dynamics.parameters.viscous,
                *dynamics.parameters.coulomb,
                _TORQUE_AGE,
                self.rest_rate,
                dynamics.inertia,
                dynamics.gravity_amplitude,
                *prior_information,
                float(not all(math.isnan(p) for p in prior_information)),
            ],
            dtype=np.float64,
        )
        self.empty_moves = None if empty_moves is None else _checked_sums(empty_moves)
        if self.empty_moves is not None and not self.fits_corrections:
            raise ValueError("empty_moves seed the fit of the model's corrections, but this estimator fits none")
        self._restart_fit()
        self._filter_started = False
        self._holding = False
        # (2, 5, 3): the reference's tau0, phi, theta, rates and accelerations of this step and the previous one.
        self._references = np.zeros((2, 5, 3))
        self._reference_slot = 0
        self._has_previous_reference = False
        self._previous_state: NDArray[np.float64] | None = None  # (3, 3): theta, theta_dot, theta_ddot
        self._checkpoints: NDArray[np.float64] | None = None  # (n, fit + RLS state) of the last n updates
        self._checkpoint = self._checkpointed = 0  # the ring's next slot; how many of its updates a rollback may undo
        self._skip = 0

    @property
    def mass(self) -> float:
        """Estimated mass of the object held (kg): apparent mass minus tare; 0 while the gripper is open."""
        return self.rls.mass - self.tare if self._holding else 0.0

    @property
    def apparent_mass(self) -> float:
        """The payload (kg) the model needs at its platform, fed forward: the RLS state (the object plus the tare)
        plus the platform-mass correction as solved at the last carry's start."""
        return self.rls.mass + self._fit[_FIT_SOLUTION + _P_PLATFORM]

    @property
    def corrections(self) -> ModelCorrections:
        """The model's corrections fitted on the seeded sums and this episode's empty moves so far (0 before any).

        Solved on a copy: the solution the carries and the feedforward use stays the one of the last carry's start.
        """
        fit = self._fit
        if fit[_FIT_STALE] != 0.0:
            fit = fit.copy()
            _solve_fit(self._equation, fit)
        p = fit[_FIT_SOLUTION : _FIT_SOLUTION + _PARAMETERS]
        return ModelCorrections(float(p[_P_PLATFORM]), float(p[_P_ARM]), p[_P_FRICTION:].copy())

    @property
    def fits_corrections(self) -> bool:
        """Whether the empty moves fit any correction of the model (:class:`ModelCorrections`)."""
        return bool(self._equation[_EQ_FITS] != 0.0)

    @property
    def empty_move_sums(self) -> EmptyMoveSums:
        """The fit's sums so far (:class:`EmptyMoveSums`): the seeded ones plus this episode's empty moves."""
        information = self._fit[_FIT_INFORMATION:_FIT_MOMENT].reshape(_PARAMETERS, _PARAMETERS).copy()
        return EmptyMoveSums(information, self._fit[_FIT_MOMENT:_FIT_SOLUTION].copy())

    @property
    def empty_move_samples(self) -> int:
        """Samples of this episode's empty moves that entered the fit so far."""
        return int(self._fit[_FIT_SAMPLES])

    @property
    def friction_scale_error(self) -> NDArray[np.float64]:
        """Relative error kappa_i of each joint's identified friction, fitted as :attr:`corrections`, (3,)."""
        return self.corrections.friction_scale

    def reset(self) -> None:
        """Start an episode: nothing held, the fit back to the seeded sums (empty without), RLS at the tare, joint
        filter restarted at the next reading."""
        self.rls.reset(self.tare)
        self._restart_fit()
        self._filter_started = False
        self._holding = False
        self._has_previous_reference = False
        self._previous_state = None
        self._history.clear()
        self._skip = 0
        self._checkpointed = 0

    def _restart_fit(self) -> None:
        """The empty-move fit as an episode starts: the seeded sums, to be solved at the first carry, or nothing."""
        self._fit[:] = 0.0
        if self.empty_moves is not None:
            self._fit[_FIT_INFORMATION:_FIT_MOMENT] = self.empty_moves.information.ravel()
            self._fit[_FIT_MOMENT:_FIT_SOLUTION] = self.empty_moves.moment
            self._fit[_FIT_STALE] = 1.0

    def update(
        self,
        observation: Observation,
        reference_torque: NDArray[np.float64] | None = None,
        reference_regressor: NDArray[np.float64] | None = None,
    ) -> float:
        """Fuse one observation and return the apparent payload (kg) to feed forward (:attr:`apparent_mass`).

        Arguments as in :meth:`measurement`.
        """
        holding = observation["gripper"].item(0) > 0.5
        if holding != self._holding:
            self._holding = holding
            self._checkpointed = 0  # a rollback never crosses a pick or a release
            if holding:
                self.rls.reset_covariance()
            else:
                self.rls.reset(self.tare)  # released: the object is known to be gone
        if self._checkpoints is None:
            moments = self.measurement(observation, reference_torque, reference_regressor)
            if moments is not None:
                self.rls.update_moments(*moments)
            return self.apparent_mass
        checkpoint = self._checkpoints[self._checkpoint]
        self._checkpoint = (self._checkpoint + 1) % len(self._checkpoints)
        self._checkpointed = min(self._checkpointed + 1, len(self._checkpoints))
        checkpoint[:_FIT_SIZE] = self._fit
        checkpoint[_FIT_SIZE:] = self.rls.state
        moments = self.measurement(observation, reference_torque, reference_regressor)
        if self._skip > 0:
            self._skip -= 1
            self._fit[:] = checkpoint[:_FIT_SIZE]  # the sample entered neither the fit nor the RLS
        elif moments is not None:
            self.rls.update_moments(*moments)
        return self.apparent_mass

    def keep_checkpoints(self, samples: int) -> None:
        """Keep the fit and RLS state of the last ``samples`` updates so that :meth:`rollback` can undo them."""
        self._checkpoints = np.zeros((samples, _FIT_SIZE + 2))
        self._checkpoint = self._checkpointed = 0

    def skip(self, samples: int) -> None:
        """Leave the equations of the next ``samples`` updates out of the fit and the RLS (faulty samples);
        needs :meth:`keep_checkpoints`."""
        if self._checkpoints is None:
            raise RuntimeError("skip() needs keep_checkpoints()")
        self._skip = max(self._skip, samples)

    def rollback(self, samples: int) -> None:
        """Undo the last ``samples`` updates' equations (samples found faulty late), as far back as the checkpoints
        kept reach within this episode and since the last pick or release."""
        if self._checkpoints is None:
            raise RuntimeError("rollback() needs keep_checkpoints()")
        kept = len(self._checkpoints)
        if not 1 <= samples <= kept:
            raise ValueError(f"samples must be in [1, {kept}] (the checkpoints kept), got {samples!r}")
        samples = min(samples, self._checkpointed)
        if samples == 0:
            return
        self._checkpointed -= samples
        checkpoint = self._checkpoints[(self._checkpoint - samples) % kept]
        self._fit[:] = checkpoint[:_FIT_SIZE]
        self.rls.state = checkpoint[_FIT_SIZE:]

    def drop_object(self) -> None:
        """The object is gone although the gripper still holds (a detected slip): the estimate restarts at the tare
        with the variance :data:`DROP_VARIANCE`; the equations still in the pipeline (of samples before the slip was
        found, up to :attr:`delay` ago), and those whose smoothing window straddles the slip, are left out; needs
        :meth:`keep_checkpoints`."""
        self.rls.state = (self.tare, DROP_VARIANCE)
        self.skip(4 * self.delay + 1)

    def measurement(
        self,
        observation: Observation,
        reference_torque: NDArray[np.float64] | None = None,
        reference_regressor: NDArray[np.float64] | None = None,
    ) -> tuple[float, float] | None:
        """This step's weighted payload equation as its moments, or None with the gripper open or every joint at
        rest (:data:`REST_RATE`). With the gripper open, the sample enters the fit of the model's corrections
        instead (:class:`ModelCorrections`), which are removed from the carries' equations.

        With the weights w_i = 1 / sigma_i^2 (:func:`residual_std`), the moments are sum_i w_i phi_i^2
        ((N m/kg)^2) and sum_i w_i phi_i y_i (N^2 m^2/kg): all that RLS with R = diag(sigma_i^2) needs of a
        sample (:meth:`PayloadRLS.update_moments` with a noise standard deviation of 1).

        Call once per control step, in order (it keeps the previous reference and the joint filter).

        Args:
            observation: The env's observation; reads ``joint_torques``, ``gripper`` and, by regressor, the
                reference (``reference_angles``, ``reference_velocities``, ``reference_accelerations``) and
                ``joint_angles``: ``"smoothed"`` both, ``"reference"`` the reference, ``"filtered"`` the angles.
            reference_torque: tau0 (N m) at this step's reference, if the caller has it already
                (``regressor="reference"``); computed otherwise.
            reference_regressor: phi (N m/kg) at this step's reference, with ``reference_torque``.
        """
        holding = observation["gripper"].item(0) > 0.5
        if self.regressor == "reference":
            if reference_torque is None or reference_regressor is None:
                reference_torque, reference_regressor = self.dynamics.torque_and_payload_regressor(
                    observation["reference_angles"],
                    observation["reference_velocities"],
                    observation["reference_accelerations"],
                )
            # Two buffers used in turn: this step's reference and the previous step's.
            self._reference_slot = 1 - self._reference_slot
            current = self._references[self._reference_slot]
            current[0], current[1] = reference_torque, reference_regressor
            current[2] = observation["reference_angles"]
            current[3] = observation["reference_velocities"]
            current[4] = observation["reference_accelerations"]
            previous = self._references[1 - self._reference_slot] if self._has_previous_reference else current
            self._has_previous_reference = True
            # The torque was measured MEASURED_TORQUE_DELAY before the encoders and the reference of this step.
            used, information, moment = _reference_equation(
                self._equation, self._fit, holding, current, previous, *observation["joint_torques"].tolist()
            )
            return (information, moment) if used else None
        angles = observation["joint_angles"]
        if self.regressor == "smoothed":
            # The smoother estimates the tracking error; the reference's own derivatives are known exactly.
            reference = np.array(
                (
                    observation["reference_angles"],
                    observation["reference_velocities"],
                    observation["reference_accelerations"],
                )
            )
            if not self._filter_started:
                self.joint_filter.reset(angles - reference[0])
                self._filter_started = True
            error = self.joint_filter.update_state(angles - reference[0])
            self._history.append((reference, observation["joint_torques"].tolist(), holding))
        else:
            if not self._filter_started:
                self.joint_filter.reset(angles)
                self._filter_started = True
            estimate = self.joint_filter.update(angles)
            self._history.append((estimate, observation["joint_torques"].tolist(), holding))
        if len(self._history) <= self.delay:
            return None
        # Everything belongs to sample k - D: the smoother's estimate with the reference of that sample, the
        # filter's acceleration estimate with its angles and rates of D samples ago, and the torque measured then.
        delayed, torque, held = self._history[0]
        state = error + delayed if self.regressor == "smoothed" else np.array((delayed[0], delayed[1], estimate[2]))
        previous_state = self._previous_state if self._previous_state is not None else state
        self._previous_state = state
        if holding != held:
            return None
        # The torque of sample k - D was measured MEASURED_TORQUE_DELAY before its encoder sample.
        status, used, information, moment = _estimated_state_equation(
            self.dynamics.model_constants,
            self._equation,
            self._fit,
            state,
            previous_state,
            holding,
            *torque,
        )
        if status != kernels.VALID:
            raise ValueError(f"{kernels.INVALID_STATE[status]}: joint state estimate {state!r}")
        return (information, moment) if used else None


def tare_from_observations(estimator: PayloadEstimator, episodes: Iterable[Iterable[Observation]]) -> Tare:
    """The apparent payload of an empty gripper (kg): weighted least squares over payload-free carries.

    Taring, as on a scale: pick cycles are run with nothing to pick (the gripper still closes and opens,
    mp = 0 is known), and the mass that the model needs along phi over the carry phases, beyond what the
    estimator fits on the empty moves of the same episode (:class:`ModelCorrections`), is its error there.
    The estimate is the weighted least squares of the RLS without forgetting or prior, over all carries at once.

    Only the carries that follow an empty move count, if there are any: before the first, nothing is fitted, and
    the apparent payload of a first carry also holds the calibration plant's own mass and friction errors (on a
    randomized plant, tens of grams that the next plant does not share). Episodes that start at their pick point
    with one cycle have no such carry; their first carries are used then.

    Args:
        estimator: Gives the payload equations, with the corrections it fits on each episode's empty moves
            removed (its tare does not enter them); reset here before each episode.
        episodes: Observation sequences of payload-free pick-and-place episodes.

    Returns:
        The tare (kg), the standard deviation (kg) of the same estimate carry by carry (the model error along phi
        changes with the path, so this, not the torque noise, is its uncertainty) and the sums of the episodes'
        empty moves, which the estimator fitted (:class:`Tare`).
    """
    # (sum of phi.y, sum of phi.phi) over one carry, weighted, and whether an empty move was fitted before it; a
    # carry runs from a closing of the gripper to the next (moments are also None while every joint rests, which
    # does not end a carry).
    carries: list[tuple[float, float, bool]] = []
    if estimator.empty_moves is not None:
        raise ValueError("taring needs an estimator without seeded empty moves: it sums the episodes' own")
    empty_information, empty_moment = np.zeros((_PARAMETERS, _PARAMETERS)), np.zeros(_PARAMETERS)
    for episode in episodes:
        estimator.reset()
        holding = False
        for observation in episode:
            closed = observation["gripper"].item(0) > 0.5
            if closed and not holding:
                carries.append((0.0, 0.0, estimator.empty_move_samples > 0))
            holding = closed
            moments = estimator.measurement(observation)
            if moments is None:
                continue
            information, moment = moments
            carry_moment, carry_information, corrected = carries[-1]
            carries[-1] = (carry_moment + moment, carry_information + information, corrected)
        sums = estimator.empty_move_sums
        empty_information += sums.information
        empty_moment += sums.moment
    carries = [carry for carry in carries if carry[1] > 0.0]
    if not carries:
        raise ValueError("no carry phase in the calibration episodes: the gripper never closed while moving")
    if estimator.fits_corrections and any(corrected for *_, corrected in carries):
        carries = [carry for carry in carries if carry[2]]
    moments, informations, _ = np.array(carries).T
    per_carry = moments / informations
    spread = float(np.std(per_carry, ddof=1)) if len(carries) > 1 else math.nan
    return Tare(float(moments.sum() / informations.sum()), spread, EmptyMoveSums(empty_information, empty_moment))
