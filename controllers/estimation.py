"""Estimators on filterpy: joint rates and accelerations from encoders, payload mass by RLS.

- :func:`smooth_joint_motion`: offline Kalman RTS smoother over recorded encoder angles, for the
  identification (docs/design.md section 7; the paper smooths with Kalman smoothers too).
- :class:`JointStateSmoother`: the fixed-lag RTS smoother of the same model for the 1 kHz payload
  estimator: a few milliseconds late, but without the causal filter's lag and shape errors.
- :class:`JointStateFilter`: the causal Kalman filter of the same model.
- :class:`PayloadRLS`: recursive least squares of the payload mass with forgetting (docs/design.md
  section 6): the fading-memory Kalman filter of the constant mass, closed-form for one unknown.

Joint model: per joint a constant-acceleration model driven by white jerk; the three joints form
one 9-state block filter with the state ordered by derivative,
x = (theta_1..3 (rad), theta_dot_1..3 (rad/s), theta_ddot_1..3 (rad/s^2)).
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
import scipy.linalg
from filterpy.common import Q_continuous_white_noise, kinematic_state_transition
from filterpy.kalman import KalmanFilter
from numpy.typing import ArrayLike, NDArray

from delta_env.sensors import CONTROL_PERIOD, ENCODER_NOISE_STD
from delta_env.validation import require_in, require_joint_vector, require_positive

SMOOTHER_JERK_STD = 1000.0
"""Default jerk standard deviation (rad/s^3) of the offline smoother's model (:func:`smooth_joint_motion`), white
at the sample rate.

Below the peak joint jerk of 3 g and 6 g minimum-jerk pick moves (2e3 to 6e3 rad/s^3): on such moves
sampled by 17-bit encoders the smoother's acceleration error is flat over a wide range of this value and
two orders of magnitude below central differences.
"""

FIXED_LAG_JERK_STD = 3000.0
"""Default jerk standard deviation (rad/s^3) of :class:`JointStateSmoother`'s model.

Three times the offline smoother's: with only :data:`SMOOTHER_LAG` readings after the estimated sample, a model of
lower jerk standard deviation lags where the jerk steps up. At the start of a 6 g lift (a jerk step of about 1e4
rad/s^3) the acceleration came out 15 to 20 % low for the first ten samples at 1000 rad/s^3, which the payload RLS
read as a mass up to 0.4 kg too heavy at lift-off. The payload estimator smooths the tracking error instead of the
angles (:class:`~controllers.payload.PayloadEstimator`), which steps far less; at 1000 rad/s^3 it still lagged
(docs/measurements.md, "The fixed-lag smoother: jerk standard deviation, tracking error").
"""

FILTER_JERK_STD = 3000.0
"""Default jerk standard deviation (rad/s^3) of the causal filter's model.

Higher than the smoother's because the causal filter's error is dominated by lag (about 3 ms on
the acceleration), which a stiffer model shortens at the price of noise.
"""

_INITIAL_RATE_STD = 10.0  # rad/s: the first rate is unknown until a few samples are in
_INITIAL_ACCELERATION_STD = 1000.0  # rad/s^2


def _finite_joint_values(name: str, value: ArrayLike) -> list[float]:
    """3 finite values as Python floats, for the 1 kHz paths (cheaper than ``require_joint_vector``)."""
    if not (isinstance(value, np.ndarray) and value.shape == (3,) and value.dtype == np.float64):
        return require_joint_vector(name, value).tolist()
    values = value.tolist()
    if not math.isfinite(values[0] + values[1] + values[2]):
        raise ValueError(f"{name} must be 3 finite values (one per joint), got {value!r}")
    return values


def _joint_kalman_filter(
    dt: float, measurement_std: float, jerk_std: float, theta0: NDArray[np.float64]
) -> KalmanFilter:
    """The constant-acceleration filter of ``len(theta0)`` joints (3 states each), at rest at ``theta0`` (rad)."""
    require_positive("dt", dt)
    require_positive("measurement_std", measurement_std)
    require_positive("jerk_std", jerk_std)
    joints = len(theta0)
    kf = KalmanFilter(dim_x=3 * joints, dim_z=joints)
    kf.F = np.kron(kinematic_state_transition(order=2, dt=dt), np.eye(joints))
    # White jerk of standard deviation jerk_std at the sample rate has the spectral density jerk_std^2 dt.
    kf.Q = Q_continuous_white_noise(
        dim=3, dt=dt, spectral_density=jerk_std**2 * dt, block_size=joints, order_by_dim=False
    )
    kf.H = np.hstack((np.eye(joints), np.zeros((joints, 2 * joints))))
    kf.R = measurement_std**2 * np.eye(joints)
    kf.x = np.concatenate((theta0, np.zeros(2 * joints)))
    kf.P = np.diag(np.repeat([measurement_std**2, _INITIAL_RATE_STD**2, _INITIAL_ACCELERATION_STD**2], joints))
    return kf


def smooth_joint_motion(
    angles: ArrayLike,
    dt: float = CONTROL_PERIOD,
    *,
    measurement_std: float = ENCODER_NOISE_STD,
    jerk_std: float = SMOOTHER_JERK_STD,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Joint angles, rates and accelerations from recorded encoder angles (offline, non-causal).

    A Kalman filter forward, then the Rauch-Tung-Striebel smoother backward (filterpy's
    ``batch_filter`` and ``rts_smoother``, their gains from :func:`_smoother_gains`): no lag, unlike
    :class:`JointStateFilter`. The first and
    last 20 or so samples only have data on one side: start and end recordings at rest, or drop
    them (a record that starts at 4.7 rad/s and 1200 rad/s^3 is off by 0.9 rad/s and 220 rad/s^2 at
    its first sample, by 0.06 rad/s and 17 rad/s^2 ten samples later).

    Args:
        angles: Encoder angles (rad), ``(N, 3)``, sampled every ``dt``; N >= 2.
        dt: Sample period (s).
        measurement_std: Standard deviation of the angle error (rad); the default is the
            quantization of a 17-bit encoder.
        jerk_std: Standard deviation of the white jerk of the motion model (rad/s^3).

    Returns:
        theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2), each ``(N, 3)``.
    """
    angles = np.asarray(angles, dtype=float)
    if angles.ndim != 2 or angles.shape[1] != 3 or angles.shape[0] < 2:
        raise ValueError(f"angles must have shape (N >= 2, 3), got {angles.shape}")
    if not np.all(np.isfinite(angles)):
        raise ValueError("angles must be finite")
    kf = _joint_kalman_filter(dt, measurement_std, jerk_std, angles[0])
    gains = _smoother_gains if len(angles) <= CACHED_GAINS_LENGTH else _smoother_gains.__wrapped__
    filter_gains, smoother_gains = gains(dt, measurement_std, jerk_std, len(angles))
    # batch_filter's and rts_smoother's state updates, with their gains (which do not depend on the angles)
    means, x = np.zeros((len(angles), kf.dim_x)), kf.x
    for i, z in enumerate(angles):
        x = np.dot(kf.F, x)
        x = x + np.dot(filter_gains[i], z - np.dot(kf.H, x))
        means[i, :] = x
    smoothed = means.copy()
    for k in range(len(angles) - 2, -1, -1):
        smoothed[k] += np.dot(smoother_gains[k], smoothed[k + 1] - np.dot(kf.F, smoothed[k]))
    return smoothed[:, :3], smoothed[:, 3:6], smoothed[:, 6:]


CACHED_GAINS_LENGTH = 20_000
"""Longest record (samples) whose smoother gains are kept (about 0.9 kB a sample; the four kept lengths at most
70 MB): a longer one, such as a robot's long drive log, has its gains computed for it alone."""


@functools.lru_cache(maxsize=4)
def _smoother_gains(
    dt: float, measurement_std: float, jerk_std: float, samples: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Kalman gains of filterpy's ``batch_filter`` ``(samples, 9, 3)`` and the RTS gains of its ``rts_smoother``
    ``(samples - 1, 9, 9)`` for :func:`smooth_joint_motion`, computed as they do (read-only). They depend on the
    model and the record's length alone, not on the angles: kept per process, as the identification smooths many
    records of a few lengths."""
    kf = _joint_kalman_filter(dt, measurement_std, jerk_std, np.zeros(3))
    F, Q, H, R, P = kf.F, kf.Q, kf.H, kf.R, kf.P
    filtered = np.zeros((samples, kf.dim_x, kf.dim_x))
    filter_gains = np.zeros((samples, kf.dim_x, kf.dim_z))
    for i in range(samples):
        P = kf.alpha**2 * np.dot(np.dot(F, P), F.T) + Q  # predict
        PHT = np.dot(P, H.T)  # update, Joseph form
        K = np.dot(PHT, kf.inv(np.dot(H, PHT) + R))
        I_KH = np.eye(kf.dim_x) - np.dot(K, H)
        P = np.dot(np.dot(I_KH, P), I_KH.T) + np.dot(np.dot(K, R), K.T)
        filter_gains[i], filtered[i] = K, P
    smoother_gains = np.zeros((max(samples - 1, 0), kf.dim_x, kf.dim_x))
    for k in range(samples - 2, -1, -1):
        predicted = np.dot(np.dot(F, filtered[k]), F.T) + Q
        smoother_gains[k] = np.dot(np.dot(filtered[k], F.T), kf.inv(predicted))
    filter_gains.flags.writeable = smoother_gains.flags.writeable = False
    return filter_gains, smoother_gains


class JointStateFilter:
    """Causal Kalman filter of the joint angles, rates and accelerations for the 1 kHz controller.

    The model of :func:`smooth_joint_motion`, run forward only: the estimates lag the truth (the
    acceleration by about 3 ms), in exchange for using no future samples. :meth:`reset` starts at
    rest with the filter's steady-state covariance, as if it had been watching the robot stand
    still: no start-up transient when the robot does stand still, convergence within a few tens
    of milliseconds when it does not.

    Args:
        dt: Sample period (s).
        measurement_std: Standard deviation of the angle error (rad).
        jerk_std: Standard deviation of the white jerk of the motion model (rad/s^3).

    Attributes:
        kf: The filterpy ``KalmanFilter`` (dim_x = 9, dim_z = 3); its priors and posteriors can be
            inspected.
    """

    def __init__(
        self,
        dt: float = CONTROL_PERIOD,
        *,
        measurement_std: float = ENCODER_NOISE_STD,
        jerk_std: float = FILTER_JERK_STD,
    ) -> None:
        self.kf = _joint_kalman_filter(dt, measurement_std, jerk_std, np.zeros(3))
        kf = self.kf
        # Steady-state prior from the Riccati equation, then its measurement update.
        prior = scipy.linalg.solve_discrete_are(kf.F.T, kf.H.T, kf.Q, kf.R)
        gain = prior @ kf.H.T @ np.linalg.inv(kf.H @ prior @ kf.H.T + kf.R)
        self._steady_state_P = prior - gain @ kf.H @ prior
        self._is_reset = False

    @property
    def x(self) -> NDArray[np.float64]:
        """State estimate (theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2)), ``(9,)``."""
        return self.kf.x

    @property
    def P(self) -> NDArray[np.float64]:
        """State covariance, ``(9, 9)``, in the units of x squared."""
        return self.kf.P

    def reset(self, theta0: ArrayLike) -> None:
        """Start at rest at the measured angles ``theta0`` (rad), ``(3,)``."""
        self.kf.x = np.concatenate((require_joint_vector("theta0", theta0), np.zeros(6)))
        self.kf.P = self._steady_state_P.copy()
        self._is_reset = True

    def update(self, theta_measured: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Advance one period and fuse the measured angles (rad), ``(3,)``.

        Returns:
            Posterior theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2), each ``(3,)`` (a copy).

        Raises:
            RuntimeError: before the first :meth:`reset`.
        """
        if not self._is_reset:
            raise RuntimeError("JointStateFilter.reset(theta0) must be called before update()")
        z = require_joint_vector("theta_measured", theta_measured)
        self.kf.predict()
        self.kf.update(z)
        state = self.kf.x.copy()
        return state[:3], state[3:6], state[6:]


@functools.lru_cache(maxsize=16)
def _fixed_lag_weights(
    lag: int, history: int, dt: float, measurement_std: float, jerk_std: float
) -> NDArray[np.float64]:
    """:class:`JointStateSmoother`'s weights, ``(3, history + lag + 1)`` (read-only): filterpy's RTS smoother of one
    joint run on each unit reading of the window. Computed once per process and model, not per controller: every
    episode builds several smoothers."""
    window = history + lag + 1
    # One joint of the block model; the diffuse prior leaves the window's readings alone to decide.
    kf = _joint_kalman_filter(dt, measurement_std, jerk_std, np.zeros(1))
    diffuse = np.diag([1.0, 1.0 / dt**2, 1.0 / dt**4])
    weights = np.empty((3, window))
    for reading in range(window):
        unit = np.zeros(window)
        unit[reading] = 1.0
        kf.x, kf.P = np.zeros(3), diffuse.copy()
        means, covariances, _, _ = kf.batch_filter(unit)
        smoothed, _, _, _ = kf.rts_smoother(means, covariances)
        weights[:, reading] = smoothed[history]
    weights.flags.writeable = False
    return weights


SMOOTHER_LAG = 5
"""Default delay (samples) of :class:`JointStateSmoother`'s estimates: the readings after the estimated
sample that it uses: the shortest delay at which the payload RLS loses the causal filter's bias (with 3
samples the bias is back)."""

SMOOTHER_HISTORY = 20
"""Default readings (samples) before the estimated one that :class:`JointStateSmoother` uses: longer
windows give the same payload estimates."""

SMOOTHER_WINDOW = SMOOTHER_HISTORY + SMOOTHER_LAG + 1
"""Readings in the window of a :class:`JointStateSmoother` with the default history and lag."""


class JointStateSmoother:
    """Fixed-lag Kalman smoother of the joint angles, rates and accelerations for the 1 kHz controller.

    After reading k it returns the estimate of sample k - ``lag``: the Rauch-Tung-Striebel smoother of
    :func:`smooth_joint_motion`'s model (with :data:`FIXED_LAG_JERK_STD`; filterpy's ``batch_filter`` and
    ``rts_smoother``) over the window
    of the last ``history + lag + 1`` readings, with a diffuse prior at the window start. That estimate is
    linear in the window's readings, so the smoother is computed once per model (and process) as the weights
    of each reading (filterpy's smoother run on unit readings), and each update is one small matrix product,
    several times cheaper than :class:`JointStateFilter`'s filterpy predict and update.

    Unlike :class:`JointStateFilter`, whose acceleration lags about 3 ms behind a constant jerk and has a
    different shape error wherever the jerk changes, the smoother is unbiased within the model; the price
    is the fixed delay, which the payload estimator matches by pairing it with the torque of sample
    k - ``lag``.

    Args:
        lag: Readings after the estimated sample, >= 0.
        history: Readings before it, >= 2.
        dt: Sample period (s).
        measurement_std: Standard deviation of the angle error (rad).
        jerk_std: Standard deviation of the white jerk of the motion model (rad/s^3).

    Attributes:
        weights: ``(3, history + lag + 1)``: row d gives derivative d (rad, rad/s, rad/s^2) of the
            estimated sample from the window's readings, oldest first (read-only: smoothers of one model share it).
    """

    def __init__(
        self,
        lag: int = SMOOTHER_LAG,
        history: int = SMOOTHER_HISTORY,
        dt: float = CONTROL_PERIOD,
        *,
        measurement_std: float = ENCODER_NOISE_STD,
        jerk_std: float = FIXED_LAG_JERK_STD,
    ) -> None:
        if isinstance(lag, bool) or not isinstance(lag, int) or lag < 0:
            raise ValueError(f"lag must be an integer >= 0 samples, got {lag!r}")
        if isinstance(history, bool) or not isinstance(history, int) or history < 2:
            raise ValueError(f"history must be an integer >= 2 samples, got {history!r}")
        self.lag, self.history = lag, history
        window = history + lag + 1
        self.weights = _fixed_lag_weights(lag, history, dt, measurement_std, jerk_std)
        self._readings = np.zeros((2 * window, 3))  # the window of fixed_lag_step: each reading written twice
        self._next = 0
        self._estimates = np.zeros((2, 3, 3))
        self._buffer = 0
        self._is_reset = False

    def reset(self, theta0: ArrayLike) -> None:
        """Start at rest at the measured angles ``theta0`` (rad), ``(3,)``: the window is filled with them."""
        self._readings[:] = require_joint_vector("theta0", theta0)
        self._next = 0
        self._is_reset = True

    def update(self, theta_measured: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Take one reading (rad), ``(3,)``, and return the estimate of the reading ``lag`` samples ago.

        Returns:
            theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2) of sample k - ``lag``, each ``(3,)``.

        Raises:
            RuntimeError: before the first :meth:`reset`.
        """
        theta, theta_dot, theta_ddot = self.update_state(theta_measured).copy()
        return theta, theta_dot, theta_ddot

    def update_state(self, theta_measured: ArrayLike) -> NDArray[np.float64]:
        """:meth:`update` as one array (:func:`fixed_lag_step` on this smoother's window).

        Returns:
            ``(3, 3)``, rows theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2) of sample k - ``lag``: one of
            two buffers used in turn, so it holds until the next call but one.

        Raises:
            RuntimeError: before the first :meth:`reset`.
        """
        if not self._is_reset:
            raise RuntimeError("JointStateSmoother.reset(theta0) must be called before update()")
        z = np.array(_finite_joint_values("theta_measured", theta_measured))
        estimate, self._next = fixed_lag_step(self.weights, self._readings, self._next, z, False)
        self._buffer = 1 - self._buffer
        self._estimates[self._buffer] = estimate
        return self._estimates[self._buffer]


@numba.njit(cache=True)
def fixed_lag_step(
    weights: NDArray[np.float64], readings: NDArray[np.float64], slot: int, reading: NDArray[np.float64], restart: bool
) -> tuple[NDArray[np.float64], int]:
    """:meth:`JointStateSmoother.update_state` on a window a compiled caller keeps: ``reading`` (3,) into ``readings``
    ((2 W, 3), each reading written twice so that the last W are one slice) at ``slot``, after filling the window with
    it if ``restart`` (:meth:`JointStateSmoother.reset`); returns the estimate (3, 3: theta, theta_dot, theta_ddot of
    the reading a lag ago, in the reading's units) and the next slot. ``weights`` are the smoother's."""
    window = weights.shape[1]
    if restart:
        for row in range(2 * window):
            readings[row, :] = reading
        slot = 0
    readings[slot, :] = reading
    readings[slot + window, :] = reading
    estimate = np.dot(weights, np.ascontiguousarray(readings[slot + 1 : slot + 1 + window]))
    return estimate, (slot + 1 if slot + 1 < window else 0)


DELAYED_STATE_FIELDS = [
    # JointStateSmoother's weights and window of tracking errors (each reading written twice)
    ("weights", np.float64, (3, SMOOTHER_WINDOW)),
    ("readings", np.float64, (2 * SMOOTHER_WINDOW, 3)),
    ("next_slot", np.int64),
    ("started", np.bool_),
    # the readings the smoothed state lags behind, oldest at pending_head
    ("pending_reference", np.float64, (SMOOTHER_LAG + 1, 3, 3)),
    ("pending_torque", np.float64, (SMOOTHER_LAG + 1, 3)),
    ("pending_holding", np.uint8, (SMOOTHER_LAG + 1,)),  # flags (numba has no boolean subarrays)
    ("pending_head", np.int64),
    ("pending_count", np.int64),
    # the smoothed state of the last sample due
    ("previous", np.float64, (3, 3)),
    ("has_previous", np.bool_),
]
"""The fields of a compiled caller's record that :func:`delayed_state_step` keeps: rows of joint states theta (rad),
theta_dot (rad/s), theta_ddot (rad/s^2), torques (N m)."""


@numba.njit(cache=True)
def delayed_state_step(
    record: np.record,
    error: NDArray[np.float64],
    reference_angles: NDArray[np.float64],
    reference_rates: NDArray[np.float64],
    reference_accelerations: NDArray[np.float64],
    torque: NDArray[np.float64],
    holding: bool,
) -> tuple[int, NDArray[np.float64], NDArray[np.float64]]:
    """One sample into a record with :data:`DELAYED_STATE_FIELDS`: its tracking error (rad, (3,)) into the smoother
    (started at rest at the first one) and its reference's state, measured torque and gripper into the pending
    readings. Returns the slot in the pending arrays of the sample :data:`SMOOTHER_LAG` readings ago, its smoothed
    joint state (the reference's state plus the smoothed error, (3, 3)) and the one of the sample before it (itself
    at the first); a slot of -1 while the smoother fills (the states are then meaningless)."""
    smoothed_error, record.next_slot = fixed_lag_step(
        record.weights, record.readings, record.next_slot, error, not record.started
    )
    record.started = True
    tail = (record.pending_head + record.pending_count) % (SMOOTHER_LAG + 1)
    record.pending_reference[tail, 0, :] = reference_angles
    record.pending_reference[tail, 1, :] = reference_rates
    record.pending_reference[tail, 2, :] = reference_accelerations
    record.pending_torque[tail, :] = torque
    record.pending_holding[tail] = holding
    record.pending_count += 1
    if record.pending_count <= SMOOTHER_LAG:
        return -1, smoothed_error, smoothed_error
    head = record.pending_head
    record.pending_head = (head + 1) % (SMOOTHER_LAG + 1)
    record.pending_count -= 1
    state = record.pending_reference[head] + smoothed_error
    previous = record.previous.copy() if record.has_previous else state
    record.previous[:, :] = state
    record.has_previous = True
    return head, state, previous


class PayloadRLS:
    """Recursive least squares of the payload mass mp in y = phi mp + e, with forgetting.

    y = tau_measured - tau_model(mp = 0) (N m) and phi = J^T (xdd + g e_z) (N m/kg, from
    ``DeltaDynamics.payload_regressor``), three rows per sample, e white with covariance R I.
    This is the Kalman filter of the constant mp (F = 1, Q = 0, H = phi) with fading memory, i.e. RLS with
    forgetting factor lambda (docs/design.md section 6), named as filterpy names its filters: the state x = mp,
    its variance P, the measurement noise R. With one unknown the update is closed-form (the matrix inversion
    lemma; :meth:`update_moments`), which equals filterpy's ``KalmanFilter`` with those matrices and
    ``alpha = 1/sqrt(lambda)`` to round-off, at a fiftieth of its cost per sample. A sample enters only through
    phi.phi and phi.y.

    Args:
        forgetting_factor: lambda in (0, 1]; the memory is about 1 / (1 - lambda) samples
            (1000 samples = 1 s at 1 kHz for the default).
        noise_std: Standard deviation of e (N m): torque noise plus model error. It scales
            :attr:`P`, not the estimate.
        initial_variance: Prior variance of the mass (kg^2); also restored by :meth:`reset_covariance`.
        initial_mass: Prior mass (kg).

    Attributes:
        x: The mass estimate (kg).
        P: Its variance (kg^2), as far as R describes e.
        R: The noise variance s^2 (N^2 m^2) of each row of y.
        forgetting_factor: lambda.
        initial_variance: P0 (kg^2).
    """

    def __init__(
        self,
        forgetting_factor: float = 0.999,
        noise_std: float = 2.0,
        initial_variance: float = 4.0,
        initial_mass: float = 0.0,
    ) -> None:
        require_in("forgetting_factor", forgetting_factor, 0.0, 1.0, low_open=True)
        require_positive("noise_std", noise_std)
        require_positive("initial_variance", initial_variance)
        require_in("initial_mass", initial_mass, unit="kg")
        self.forgetting_factor = float(forgetting_factor)
        self.initial_variance = float(initial_variance)
        self.R = float(noise_std) ** 2
        self.x = float(initial_mass)
        self.P = self.initial_variance
        self._alpha_sq = 1.0 / self.forgetting_factor  # filterpy's fading memory alpha^2 = 1 / lambda

    @property
    def mass(self) -> float:
        """Estimated payload mass (kg): :attr:`x`."""
        return self.x

    @property
    def variance(self) -> float:
        """Variance of the estimate (kg^2): :attr:`P`."""
        return self.P

    def update(self, phi: ArrayLike, y: ArrayLike) -> float:
        """Fuse one sample and return the new mass estimate (kg).

        Args:
            phi: Payload regressor (N m/kg), ``(3,)``.
            y: Torque residual tau_measured - tau_model(mp = 0) (N m), ``(3,)``.
        """
        h1, h2, h3 = _finite_joint_values("phi", phi)
        y1, y2, y3 = _finite_joint_values("y", y)
        return self.update_moments(h1 * h1 + h2 * h2 + h3 * h3, h1 * y1 + h2 * y2 + h3 * y3)

    def update_moments(self, information: float, moment: float) -> float:
        """Fuse one sample given as phi.phi ((N m/kg)^2) and phi.y (N^2 m^2/kg); return the mass (kg).

        No checks: the caller (the 1 kHz estimator) forms finite moments.
        """
        # predict with fading memory: P- = alpha^2 P
        prior = self.P * self._alpha_sq
        # update (matrix inversion lemma): P+ = (1 / P- + phi.phi / R)^-1 = P- R / (R + P- phi.phi) and
        # x+ = x + P+ (phi.y - phi.phi x) / R
        denominator = self.R + prior * information
        self.x += prior * (moment - information * self.x) / denominator
        self.P = prior * self.R / denominator
        return self.x

    def normalized_innovation(self, information: float, moment: float) -> float:
        """How far one sample, given as in :meth:`update_moments`, lies from the estimate, in standard deviations:
        its score phi.y - phi.phi x over the score's standard deviation sqrt(phi.phi (R + phi.phi P-)) when y = phi
        mp + e holds (the sample's noise and the estimate's own variance); 0 for a sample without information."""
        if information <= 0.0:
            return 0.0
        prior = self.P * self._alpha_sq
        # S = phi.phi R + (phi.phi)^2 P-: the variance of the score phi.(y - phi x)
        return (moment - information * self.x) / math.sqrt(information * (self.R + prior * information))

    def reset_covariance(self) -> None:
        """Restore the prior variance, keeping the estimate: call it at a pick or a release."""
        self.P = self.initial_variance

    def reset(self, mass: float, variance: float | None = None) -> None:
        """Restart from a known mass (kg) with ``variance`` (kg^2), the prior variance if None."""
        self.x = float(mass)
        self.P = self.initial_variance if variance is None else float(variance)
