"""Offline identification of MId and MId+F from excitation runs on the plant (DESIGN.md section 7).

Data: excitation trajectories (:func:`delta_env.trajectories.excitation_trajectory`, 6 g, workspace
edges, slow moves) run in closed loop on the plant (PD plus MKH feedforward along the reference); only
the observations are recorded: encoder angles and measured motor torques. Rates and accelerations come
from the Kalman RTS smoother (:func:`controllers.estimation.smooth_joint_motion`). Then two methods on
the same samples:

- the paper's (section 4), replicated: per trajectory an exhaustive grid search of (rho1, rho2)
  minimising the RMS torque error of eq. (7), averaged over trajectories (MId); then per trajectory and
  per joint the least squares of (fv, fc) on the remaining error, averaged (MId+F);
- ours: one linear least squares of all parameters [rho1, rho2, fv_1..3, fc_1..3] at once with the
  regressor of ``DeltaDynamics.identification_regressor``, with residual statistics and standard
  errors; plus a least squares of (rho1, rho2) alone for the MId row;
- beyond the paper, the same joint least squares on the model with the forearms as rods
  (``DeltaDynamics(forearm_rods=True)``, MId+F+R), which the payload estimator uses.

The result is a JSON file with provenance, :data:`DEFAULT_PARAMETER_PATH`, that the controllers load
through :func:`load_or_identify`.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from controllers.base import PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import ENCODER_NOISE_STD, SMOOTHER_JERK_STD, smooth_joint_motion
from controllers.processes import pool_context
from controllers.provenance import package_versions
from delta_env import PlantConfig, Trajectory, build_mjcf, excitation_trajectory
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import GRAVITY, NOMINAL_GEOMETRY
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY

logger = logging.getLogger(__name__)

DEFAULT_PARAMETER_PATH = Path("runs/identification/parameters.json")
"""Where :func:`load_or_identify` (and so ``python -m eval``) looks for identified parameters."""

FILE_FORMAT_VERSION = 2
"""Version of the JSON parameter file; bumped on incompatible changes."""

DEFAULT_TRAJECTORIES = 12
"""Excitation trajectories of the identification, as in the paper."""

DEFAULT_DURATION = 8.0
"""Length of each excitation trajectory (s)."""

VALIDATION_DURATION = 10.0
"""Length of the held-out free-motion stress trajectory (s), the paper's upsilon_F."""

TRIM_SAMPLES = 50
"""Samples dropped at each end of a record (50 ms): the RTS smoother has data on one side only there
(its estimates are poor for ~20 samples) and the first torque reading precedes the first command."""

REST_VELOCITY = 0.02
"""Smoothed rates below this (rad/s) are set to exactly 0: the joint is at rest.

At rest the RTS smoother's rates are encoder quantization noise (up to 0.011 rad/s in the dwells of the
default excitation), whose sign would switch the models' Coulomb term fc sign(thd) at random; at rest the
feedforward sees the reference's exact zero rate, so sign 0 is also how the models are used there.
"""

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

MODEL_FIELDS = ("mid", "mid_f", "mid_f_rods", "paper_mid", "paper_mid_f")
"""The parameter sets of an :class:`IdentificationResult`, in the order of the JSON file."""

_MAX_CONDITION = 1e10  # of the scaled normal equations; beyond it the data do not determine the parameters

_Item = TypeVar("_Item")
_Output = TypeVar("_Output")


# ---------------------------------------------------------------------------------------------
# Data


@dataclass(frozen=True)
class ExcitationSpec:
    """One excitation trajectory: the arguments of ``excitation_trajectory`` and the episode seed.

    Attributes:
        seed: Seeds the trajectory's generator and the env's reset (its torque noise).
        duration: Length (s).
        peak_acceleration: Largest peak Cartesian |xdd| of a move (m/s^2).
        min_acceleration_fraction: Smallest peak |xdd| of a fast move, relative to the largest.
        edge_fraction: Probability that a fast move ends on the workspace edge.
        slow_fraction: Probability that a move is slow (friction near zero speed).
    """

    seed: int
    duration: float = DEFAULT_DURATION
    peak_acceleration: float = 6.0 * GRAVITY
    min_acceleration_fraction: float = 0.2
    edge_fraction: float = 0.3
    slow_fraction: float = 0.2

    @classmethod
    def stress(cls, seed: int, duration: float = VALIDATION_DURATION) -> ExcitationSpec:
        """The held-out free-motion stress trajectory (the paper's upsilon_F): fast moves only (3 to 6 g),
        half of them to the workspace edge, with the excitation's short dwells (0 to 0.1 s)."""
        return cls(seed=seed, duration=duration, min_acceleration_fraction=0.5, edge_fraction=0.5, slow_fraction=0.0)

    def reference(self) -> Trajectory:
        """The reference :class:`~delta_env.trajectories.Trajectory` (nominal geometry, 1 kHz)."""
        return excitation_trajectory(
            NOMINAL_GEOMETRY,
            np.random.default_rng(self.seed),
            self.duration,
            self.peak_acceleration,
            min_acceleration_fraction=self.min_acceleration_fraction,
            edge_fraction=self.edge_fraction,
            slow_fraction=self.slow_fraction,
            dt=CONTROL_PERIOD,
        )


@dataclass(frozen=True, eq=False)
class ExcitationRecord:
    """What the drive recorded along one excitation run: observations only, never the plant's truth.

    Attributes:
        spec: The trajectory that was run.
        dt: Sample period (s).
        angles: Encoder angles (rad), ``(N, 3)``.
        torques: Measured motor torques (N m), ``(N, 3)``; sample k is :data:`MEASURED_TORQUE_DELAY` older
            than angle sample k.
    """

    spec: ExcitationSpec
    dt: float
    angles: NDArray[np.float64]
    torques: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class MotionData:
    """Identification samples: joint motion and the motor torque that produced it, ``(M, 3)`` each.

    Attributes:
        theta: Joint angles (rad).
        theta_dot: Joint rates (rad/s).
        theta_ddot: Joint accelerations (rad/s^2).
        torque: Motor torques (N m).
    """

    theta: NDArray[np.float64]
    theta_dot: NDArray[np.float64]
    theta_ddot: NDArray[np.float64]
    torque: NDArray[np.float64]

    def __post_init__(self) -> None:
        shape = np.shape(self.theta)
        if len(shape) != 2 or shape[1] != 3 or shape[0] < 1:
            raise ValueError(f"theta must have shape (M >= 1, 3), got {shape}")
        for name in ("theta", "theta_dot", "theta_ddot", "torque"):
            array = np.array(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f"{name} must have the shape of theta {shape}, got {array.shape}")
            if not np.all(np.isfinite(array)):
                raise ValueError(f"{name} must be finite")
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    def __len__(self) -> int:
        return len(self.theta)


def _run_excitation(spec: ExcitationSpec, plant: PlantConfig | None) -> ExcitationRecord:
    """Run ``spec`` with PD + MKH feedforward on the plant; record encoder angles and measured torques."""
    reference = spec.reference()
    # MKH feedforward along the reference, in one batch (single-sample calls are ~100x slower).
    feedforward = DeltaDynamics.nominal().inverse_dynamics(reference.theta, reference.theta_dot, reference.theta_ddot)
    env = DeltaPickPlaceEnv(plant=plant)
    controller = PDController()
    observation, _ = env.reset(seed=spec.seed, options={"reference": reference})
    angles = np.empty((len(reference), 3))
    torques = np.empty((len(reference), 3))
    angles[0], torques[0] = observation["joint_angles"], observation["joint_torques"]
    for k in range(len(reference) - 1):
        observation, _, terminated, _, info = env.step(feedforward[k] + controller(observation))
        if terminated:
            raise RuntimeError(
                f"the plant diverged at step {k + 1} of excitation seed {spec.seed} (loop gap {info['loop_gap']:.3g} m)"
            )
        angles[k + 1], torques[k + 1] = observation["joint_angles"], observation["joint_torques"]
    env.close()
    return ExcitationRecord(spec=spec, dt=CONTROL_PERIOD, angles=angles, torques=torques)


def _parallel_map(
    function: Callable[[_Item], _Output], items: Sequence[_Item], workers: int, progress: bool, description: str
) -> list[_Output]:
    """``[function(item) for item in items]`` in order, on ``workers`` processes, with a tqdm bar."""
    from tqdm.auto import tqdm

    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    bar = functools.partial(tqdm, total=len(items), desc=description, disable=not progress, unit="run")
    if workers == 1 or len(items) == 1:
        return list(bar(map(function, items)))
    with pool_context().Pool(min(workers, len(items))) as pool:
        return list(bar(pool.imap(function, items)))


def collect_excitation_data(
    specs: Sequence[ExcitationSpec],
    *,
    plant: PlantConfig | None = None,
    workers: int = 1,
    progress: bool = False,
) -> list[ExcitationRecord]:
    """Run excitation trajectories in closed loop on the plant and record the observations.

    Each run: ``DeltaPickPlaceEnv(plant)`` reset with the trajectory as reference (no picks),
    ``PDController()`` plus MKH feedforward precomputed along the reference. Recorded: the encoder
    angles and the measured motor torques of the observations (with the plant's sensor noise and
    quantization), never the simulator's state.

    Args:
        specs: The trajectories.
        plant: Plant configuration; None is the default realistic plant.
        workers: Processes running trajectories in parallel.
        progress: Show a tqdm progress bar.

    Raises:
        RuntimeError: if the plant diverges.
    """
    run = functools.partial(_run_excitation, plant=plant)
    return _parallel_map(run, list(specs), workers, progress, "excitation runs")


def _interpolate(values: NDArray[np.float64], delay_samples: float) -> NDArray[np.float64]:
    """``values`` (N, 3) linearly interpolated at sample times n - delay_samples (held at the ends)."""
    grid = np.arange(len(values), dtype=float)
    return np.column_stack([np.interp(grid - delay_samples, grid, column) for column in values.T])


def prepare_motion(
    record: ExcitationRecord,
    *,
    trim: int = TRIM_SAMPLES,
    torque_delay: float = MEASURED_TORQUE_DELAY,
    rest_velocity: float = REST_VELOCITY,
) -> MotionData:
    """Identification samples of a record: smoothed motion aligned with the torques, edges trimmed.

    Args:
        record: Encoder angles and measured torques.
        trim: Samples dropped at each end (:data:`TRIM_SAMPLES`).
        torque_delay: Age of the torque readings (s), :data:`MEASURED_TORQUE_DELAY`.
        rest_velocity: Rates below this (rad/s) are set to 0 (:data:`REST_VELOCITY`).
    """
    if len(record.angles) <= 2 * trim + 1:
        raise ValueError(f"a record of {len(record.angles)} samples is too short to trim {trim} at each end")
    delay = torque_delay / record.dt
    theta, theta_dot, theta_ddot = (_interpolate(x, delay) for x in smooth_joint_motion(record.angles, record.dt))
    theta_dot[np.abs(theta_dot) < rest_velocity] = 0.0
    kept = slice(trim, len(record.angles) - trim)
    return MotionData(theta[kept], theta_dot[kept], theta_ddot[kept], torque=record.torques[kept])


def _collect_and_prepare(spec: ExcitationSpec, plant: PlantConfig | None) -> MotionData:
    return prepare_motion(_run_excitation(spec, plant))


# ---------------------------------------------------------------------------------------------
# Regressors and errors


def _model(dynamics: DeltaDynamics | None, parameters: ModelParameters | None = None) -> DeltaDynamics:
    return (DeltaDynamics.nominal() if dynamics is None else dynamics).with_parameters(parameters)


def _regressor(data: MotionData, dynamics: DeltaDynamics | None) -> tuple[NDArray, NDArray]:
    """Rows (M, 3, 4) [I thdd, G, thd, sign thd] and the target tau + 2 K lambda (M, 3), N m."""
    rows, known = _model(dynamics).identification_regressor(data.theta, data.theta_dot, data.theta_ddot)
    return rows, data.torque - known


def torque_errors(
    parameters: ModelParameters, data: MotionData, dynamics: DeltaDynamics | None = None
) -> NDArray[np.float64]:
    """tau - tau_hat (N m), ``(M, 3)``: measured minus model torque along the data's motion."""
    model = _model(dynamics, parameters)
    return data.torque - model.inverse_dynamics(data.theta, data.theta_dot, data.theta_ddot)


def error_table(models: Mapping[str, DeltaDynamics], data: MotionData) -> dict[str, dict[str, list[float]]]:
    """The paper's Table 1: per model (with its parameters) the mean and std of tau - tau_hat per joint (N m).

    Returns:
        ``{name: {"mean": [3], "std": [3], "rms": [3]}}``, in the order of ``models``.
    """
    table = {}
    for name, model in models.items():
        errors = data.torque - model.inverse_dynamics(data.theta, data.theta_dot, data.theta_ddot)
        table[name] = {
            "mean": errors.mean(axis=0).tolist(),
            "std": errors.std(axis=0).tolist(),
            "rms": np.sqrt(np.mean(errors**2, axis=0)).tolist(),
        }
    return table


def _concatenate(data: Sequence[MotionData]) -> MotionData:
    if not data:
        raise ValueError("need at least one MotionData")
    fields = ("theta", "theta_dot", "theta_ddot", "torque")
    return MotionData(*(np.concatenate([getattr(d, name) for d in data]) for name in fields))


def _clipped_parameters(
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


# ---------------------------------------------------------------------------------------------
# Ours: joint least squares


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
        parameters=_clipped_parameters(estimate[0], estimate[1], *friction, method),
        names=names,
        estimate=tuple(float(v) for v in estimate),
        standard_errors=tuple(float(v) for v in np.sqrt(sigma2 * np.diag(inverse))),
        rows=tuple(int(c) for c in counts),
        residual_mean=tuple(float(v) for v in residual_sums / counts),
        residual_rms=tuple(float(v) for v in np.sqrt(squares / counts)),
        residual_rms_total=float(np.sqrt(squares.sum() / n_rows)),
    )


def _require_threshold(velocity_threshold: float) -> None:
    if not (math.isfinite(velocity_threshold) and velocity_threshold >= 0.0):
        raise ValueError(f"velocity_threshold must be a finite number >= 0 rad/s, got {velocity_threshold!r}")


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
    _require_threshold(velocity_threshold)
    samples = _concatenate(data)
    return _fit_joint(*_regressor(samples, dynamics), samples.theta_dot, velocity_threshold)


def fit_rho_least_squares(data: Sequence[MotionData], *, dynamics: DeltaDynamics | None = None) -> LeastSquaresFit:
    """MId by linear least squares of (rho1, rho2) alone, friction not modelled, over all samples."""
    return _fit_rho(*_regressor(_concatenate(data), dynamics))


def fit_least_squares(
    data: Sequence[MotionData],
    *,
    dynamics: DeltaDynamics | None = None,
    velocity_threshold: float = FRICTION_VELOCITY_THRESHOLD,
) -> tuple[LeastSquaresFit, LeastSquaresFit]:
    """Both of our fits from one evaluation of the regressor: (MId by rho LS, MId+F by joint LS).

    The same as :func:`fit_rho_least_squares` and :func:`fit_joint_least_squares`, at half the cost.
    """
    _require_threshold(velocity_threshold)
    samples = _concatenate(data)
    rows, target = _regressor(samples, dynamics)
    return _fit_rho(rows, target), _fit_joint(rows, target, samples.theta_dot, velocity_threshold)


# ---------------------------------------------------------------------------------------------
# The paper's method


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
    rows, target = _regressor(data, dynamics)
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
        mid_f=_clipped_parameters(rho1, rho2, viscous.mean(axis=0), coulomb.mean(axis=0), "paper method"),
        rho=rho,
        viscous=viscous,
        coulomb=coulomb,
    )


# ---------------------------------------------------------------------------------------------
# Identification, result and file


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameter sets with their provenance.

    Attributes:
        mid: MId by least squares of (rho1, rho2) alone (no friction).
        mid_f: MId+F by the joint least squares of all parameters (ours).
        mid_f_rods: MId+F+R: the same least squares on the model with rod forearms
            (``DeltaDynamics.nominal(mid_f_rods, forearm_rods=True)``).
        paper_mid: MId by the paper's grid search, averaged over trajectories.
        paper_mid_f: MId+F by the paper's method (grid rho + per-joint friction LS, averaged).
        standard_errors: Standard errors of the least-squares estimates, keyed ``"mid.rho1"``,
            ``"mid_f.viscous_2"``, ... (units of the parameter); optimistic, see
            :attr:`LeastSquaresFit.standard_errors`.
        provenance: JSON-ready record of how the parameters were obtained: method, trajectories, plant
            summary, sample counts, residual statistics, held-out validation, run times, versions, date.
    """

    mid: ModelParameters
    mid_f: ModelParameters
    mid_f_rods: ModelParameters
    paper_mid: ModelParameters
    paper_mid_f: ModelParameters
    standard_errors: dict[str, float]
    provenance: dict[str, Any]


@dataclass(frozen=True)
class IdentificationRun:
    """An identification with its held-out validation data, for reports.

    Attributes:
        result: The identified parameters.
        data: Samples of the identification trajectories.
        validation: Samples of the held-out free-motion stress trajectory.
        models: The models compared on it, with their parameters (Table 1 rows), by name.
    """

    result: IdentificationResult
    data: tuple[MotionData, ...]
    validation: MotionData
    models: dict[str, DeltaDynamics]


def _trajectory_seeds(seed: int, n_trajectories: int) -> tuple[list[int], int]:
    """Distinct episode seeds of the identification trajectories and of the held-out one."""
    training, held_out = np.random.SeedSequence(seed).spawn(2)
    seeds = [int(s) for s in training.generate_state(n_trajectories)]
    validation_seed = int(held_out.generate_state(1)[0])
    if len({*seeds, validation_seed}) != n_trajectories + 1:
        raise RuntimeError(f"seed {seed} gave repeated trajectory seeds {seeds} + {validation_seed}")
    return seeds, validation_seed


def _plant_summary(plant: PlantConfig) -> dict[str, Any]:
    """What a test-bench log would state about the robot: no friction or mass values (those are truth)."""
    return {
        "variant": plant.variant,
        "mjcf_sha256": hashlib.sha256(build_mjcf(plant).encode()).hexdigest(),
        "control_period_s": CONTROL_PERIOD,
        "encoder_bits": plant.realism.encoder_bits,
        "torque_noise_std_Nm": plant.realism.torque_noise_std,
    }


def _standard_errors(fits: Mapping[str, LeastSquaresFit]) -> dict[str, float]:
    return {
        f"{label}.{name}": error
        for label, fit in fits.items()
        for name, error in zip(fit.names, fit.standard_errors, strict=True)
    }


def _best_time(function: Callable[[], _Output], repeats: int = 3) -> tuple[_Output, float]:
    """The result of ``function()`` and its shortest wall time (s) over ``repeats`` calls.

    The shortest of a few runs is the least disturbed by other processes on the machine.
    """
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        output = function()
        times.append(time.perf_counter() - started)
    return output, min(times)


def _between_trajectory_errors(data: Sequence[MotionData]) -> dict[str, Any]:
    """Joint LS on each trajectory alone: the estimates and the standard error of their mean.

    The honest uncertainty of the pooled estimate, unlike sigma^2 (X^T X)^-1 over correlated rows.
    """
    estimates = np.full((len(data), len(JOINT_PARAMETER_NAMES)), math.nan)
    for index, samples in enumerate(data):
        try:
            estimates[index] = fit_joint_least_squares([samples]).estimate
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


def run_identification(
    n_trajectories: int = DEFAULT_TRAJECTORIES,
    seed: int = 0,
    duration: float = DEFAULT_DURATION,
    *,
    validation_duration: float = VALIDATION_DURATION,
    progress: bool = True,
    workers: int | None = None,
    plant: PlantConfig | None = None,
) -> IdentificationRun:
    """Collect data, identify with both methods and validate on a held-out stress trajectory.

    Arguments as in :func:`identify`; ``validation_duration`` is the length (s) of the held-out
    trajectory.
    """
    start = time.perf_counter()
    if isinstance(n_trajectories, bool) or not isinstance(n_trajectories, int) or n_trajectories < 1:
        raise ValueError(f"n_trajectories must be an integer >= 1, got {n_trajectories!r}")
    workers = min(2, os.cpu_count() or 1) if workers is None else workers
    plant = PlantConfig() if plant is None else plant
    seeds, validation_seed = _trajectory_seeds(seed, n_trajectories)
    specs = [ExcitationSpec(seed=s, duration=duration) for s in seeds]
    specs.append(ExcitationSpec.stress(validation_seed, validation_duration))

    run = functools.partial(_collect_and_prepare, plant=plant)
    *data, validation = _parallel_map(run, specs, workers, progress, "excitation runs")
    data_time = time.perf_counter() - start

    (rho_fit, joint_fit), ours_time = _best_time(lambda: fit_least_squares(data))
    paper, paper_time = _best_time(lambda: fit_paper_method(data))
    lumped, rods = DeltaDynamics.nominal(), DeltaDynamics.nominal(forearm_rods=True)
    rod_fit = fit_joint_least_squares(data, dynamics=rods)

    models = {
        "MKH": lumped,
        "MId (paper)": lumped.with_parameters(paper.mid),
        "MId+F (paper)": lumped.with_parameters(paper.mid_f),
        "MId (LS)": lumped.with_parameters(rho_fit.parameters),
        "MId+F (joint LS)": lumped.with_parameters(joint_fit.parameters),
        "MId+F+R (joint LS)": rods.with_parameters(rod_fit.parameters),
    }
    validation_table = error_table(models, validation)
    training_table = error_table(models, _concatenate(data))
    provenance = {
        "method": {
            "data": "excitation trajectories in closed loop (PD + MKH feedforward) on the plant; encoder angles "
            "and measured motor torques from the observations; Kalman RTS smoother for rates and accelerations",
            "mid": "linear least squares of (rho1, rho2), all samples",
            "mid_f": "joint linear least squares of [rho1, rho2, fv_1..3, fc_1..3]; rows with "
            f"|theta_dot_i| <= {FRICTION_VELOCITY_THRESHOLD} rad/s left out (static and Stribeck friction)",
            "paper_mid": "per-trajectory grid search of (rho1, rho2) minimising RMS torque error (eq. 7), averaged",
            "paper_mid_f": "paper_mid rho + per-trajectory, per-joint LS of (fv, fc) on the remaining error, averaged",
            "mid_f_rods": "the mid_f least squares on the model with homogeneous rod forearms (forearm_rods=True)",
            "sample_period_s": CONTROL_PERIOD,
            "velocity_threshold_rad_s": FRICTION_VELOCITY_THRESHOLD,
            "rest_velocity_rad_s": REST_VELOCITY,
            "trim_samples": TRIM_SAMPLES,
            "torque_sample_delay_s": MEASURED_TORQUE_DELAY,
            "smoother": {"jerk_std": SMOOTHER_JERK_STD, "measurement_std": ENCODER_NOISE_STD},
            "rho1_grid": list(RHO1_GRID),
            "rho2_grid": list(RHO2_GRID),
            "controller": {"kp": PDController().kp, "kd": PDController().kd, "feedforward": "MKH, nominal"},
        },
        "seed": seed,
        "trajectories": [dataclasses.asdict(spec) for spec in specs[:-1]],
        "validation_trajectory": dataclasses.asdict(specs[-1]),
        "plant": _plant_summary(plant),
        "samples": {
            "per_trajectory": [len(d) for d in data],
            "total": sum(len(d) for d in data),
            "validation": len(validation),
        },
        "residuals": {"mid": rho_fit.summary(), "mid_f": joint_fit.summary(), "mid_f_rods": rod_fit.summary()},
        "mid_f_between_trajectories": _between_trajectory_errors(data),
        "raw_estimates": {
            "mid_f": dict(zip(joint_fit.names, joint_fit.estimate, strict=True)),
            "mid_f_rods": dict(zip(rod_fit.names, rod_fit.estimate, strict=True)),
            "paper_per_trajectory": {
                "rho": paper.rho.tolist(),
                "viscous": paper.viscous.tolist(),
                "coulomb": paper.coulomb.tolist(),
            },
        },
        "torque_error_training": training_table,
        "torque_error_validation": validation_table,
        "run_time_s": {
            "data_collection_and_smoothing": data_time,
            "joint_least_squares": ours_time,
            "paper_method": paper_time,
            "fits_timed_as": "best of 3 runs, from smoothed samples to parameters",
            "total": time.perf_counter() - start,
        },
        "workers": workers,
        "versions": package_versions(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    result = IdentificationResult(
        mid=rho_fit.parameters,
        mid_f=joint_fit.parameters,
        mid_f_rods=rod_fit.parameters,
        paper_mid=paper.mid,
        paper_mid_f=paper.mid_f,
        standard_errors=_standard_errors({"mid": rho_fit, "mid_f": joint_fit, "mid_f_rods": rod_fit}),
        provenance=provenance,
    )
    return IdentificationRun(result=result, data=tuple(data), validation=validation, models=models)


def identify(
    n_trajectories: int = DEFAULT_TRAJECTORIES,
    seed: int = 0,
    duration: float = DEFAULT_DURATION,
    progress: bool = True,
    workers: int | None = None,
    **kwargs: Any,
) -> IdentificationResult:
    """Identify MId and MId+F on the default realistic plant, by the paper's method and ours.

    Args:
        n_trajectories: Excitation trajectories (distinct seeds derived from ``seed``), >= 1.
        seed: Seed of the whole identification (trajectories and sensor noise).
        duration: Length of each excitation trajectory (s).
        progress: Show a tqdm progress bar.
        workers: Processes simulating trajectories; None uses up to 2 cores.
        **kwargs: ``validation_duration`` (s) and ``plant`` (a PlantConfig), see :func:`run_identification`.
    """
    return run_identification(n_trajectories, seed, duration, progress=progress, workers=workers, **kwargs).result


class ParameterFileError(ValueError):
    """An identified-parameter file that cannot be used; the message names the path and the problem."""


def _model_to_json(parameters: ModelParameters) -> dict[str, Any]:
    return {
        "rho1": parameters.rho1,
        "rho2": parameters.rho2,
        "viscous": list(parameters.viscous),
        "coulomb": list(parameters.coulomb),
    }


def _json_ready(value: Any) -> Any:
    """Numpy scalars and arrays inside ``value`` as plain Python numbers and lists."""
    if isinstance(value, Mapping):
        return {str(key): _json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(item) for item in value]
    if isinstance(value, np.ndarray):
        return _json_ready(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def save_result(result: IdentificationResult, path: str | os.PathLike[str]) -> Path:
    """Write ``result`` as JSON to ``path`` (parent folders are created; the write is atomic).

    Returns:
        The path written.
    """
    path = Path(path)
    document = {"format_version": FILE_FORMAT_VERSION}
    document.update({name: _model_to_json(getattr(result, name)) for name in MODEL_FIELDS})
    document["standard_errors"] = dict(result.standard_errors)
    document["provenance"] = result.provenance
    text = json.dumps(_json_ready(document), indent=2, allow_nan=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(text + "\n")
    os.replace(temporary, path)
    return path


def _require_number(path: Path, where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterFileError(f"{path}: {where} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterFileError(f"{path}: {where} must be finite, got {value!r}")
    return float(value)


def _require_key(path: Path, mapping: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in mapping:
        raise ParameterFileError(f"{path}: missing key {key!r} in {where}")
    return mapping[key]


def _require_mapping(path: Path, value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ParameterFileError(f"{path}: {where} must be a JSON object, got {type(value).__name__}")
    return value


def _model_from_json(path: Path, document: Mapping[str, Any], name: str) -> ModelParameters:
    entry = _require_mapping(path, _require_key(path, document, name, "the file"), name)
    values: dict[str, Any] = {}
    for key in ("rho1", "rho2"):
        values[key] = _require_number(path, f"{name}.{key}", _require_key(path, entry, key, name))
    for key in ("viscous", "coulomb"):
        joints = _require_key(path, entry, key, name)
        if not isinstance(joints, list) or len(joints) != 3:
            raise ParameterFileError(f"{path}: {name}.{key} must be a list of 3 numbers, got {joints!r}")
        values[key] = tuple(_require_number(path, f"{name}.{key}[{i}]", v) for i, v in enumerate(joints))
    try:
        return ModelParameters(**values)
    except ValueError as error:
        raise ParameterFileError(f"{path}: {name}: {error}") from error


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a file written by :func:`save_result`.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ParameterFileError: if it is not valid JSON, has missing keys, wrong types or out-of-range values;
            the message names the path and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"identified parameter file {path} does not exist; run `python -m controllers.identify` to create it"
        )
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ParameterFileError(f"{path}: not valid JSON ({error})") from error
    document = _require_mapping(path, document, "the file")
    version = _require_key(path, document, "format_version", "the file")
    if version != FILE_FORMAT_VERSION:
        raise ParameterFileError(
            f"{path}: format_version {version!r} is not {FILE_FORMAT_VERSION}; delete the file or run "
            "`python -m controllers.identify` to identify again"
        )
    models = {name: _model_from_json(path, document, name) for name in MODEL_FIELDS}
    errors = _require_mapping(path, _require_key(path, document, "standard_errors", "the file"), "standard_errors")
    standard_errors = {}
    for key, value in errors.items():
        standard_errors[key] = _require_number(path, f"standard_errors[{key!r}]", value)
        if standard_errors[key] < 0.0:
            raise ParameterFileError(f"{path}: standard_errors[{key!r}] must be >= 0, got {value!r}")
    provenance = _require_mapping(path, _require_key(path, document, "provenance", "the file"), "provenance")
    return IdentificationResult(**models, standard_errors=standard_errors, provenance=dict(provenance))


def load_or_identify(
    path: str | os.PathLike[str] = DEFAULT_PARAMETER_PATH, **identify_kwargs: Any
) -> IdentificationResult:
    """The identified parameters at ``path``; if the file does not exist, identify and save them there.

    Args:
        path: Parameter file.
        **identify_kwargs: Arguments of :func:`identify`, used only when the file is missing.

    Raises:
        ParameterFileError: if the file exists but is corrupt (it is never silently replaced).
    """
    path = Path(path)
    if path.exists():
        return load_result(path)
    logger.info("no identified parameters at %s: identifying (about a minute)", path)
    result = identify(**identify_kwargs)
    save_result(result, path)
    return result
