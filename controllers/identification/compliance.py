"""Identification of compliant drives: the rotor's inertia and friction, the gearhead's stiffness and damping per
joint, from logs of a periodic excitation with the load-side angle, or from the motor side alone with the arm side's
inertia from a model (docs/design.md section 7, "Compliant drives").

Per joint the motor side's equation (section 4, "The two-mass model") is linear in its parameters,

    tau = J_m phi_ddot + f_v phi_dot + f_c sign(phi_dot) + k dead(phi - theta) + c (phi_dot - theta_dot) + b,

dead(d) = d - clip(d, -w/2, w/2) the deflection beyond the backlash w (searched: the fit is linear given w), with
every signal measured: the torque tau, the motor-side angle phi (the motor encoder) and the load-side angle theta
(an encoder on the arm); b absorbs the constant torques (gravity, the gearhead's wind-up under it). It needs
nothing of the arm, so a rigid model that is wrong about the arm (on a compliant plant the rigid fit's rho1 is
4.3) does not bias it. The excitation is periodic (:func:`delta_env.excitation.multisine_torques` on the drives,
held at rest poses): a record of whole periods at steady state is its own periodic extension, so the rates and
accelerations follow exactly from its DFT (i omega, -omega^2 per line) up to the modes at 200 to 300 Hz, where
finite differences at 1 kHz would be 16 % off, and so does the torque's age (a phase e^{i omega d}). The fit is on the
mean over the periods; a nonlinear column (the dead band, the friction's sign) is the mean of each period's, since a
rattling backlash does not repeat from period to period.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import NDArray

from controllers.compliance import DriveCompliance
from controllers.identification.data import REST_VELOCITY
from controllers.identification.logs import DriveLog
from delta_env.config import MAX_STIFFNESS, MAX_VISCOUS
from delta_env.excitation import MULTISINE_PERIOD
from delta_env.sensors import MEASURED_TORQUE_DELAY

COMPLIANCE_PARAMETER_NAMES = ("rotor_inertia", "viscous", "coulomb", "stiffness", "damping", "backlash")
"""The motor side's parameters per joint (J_m, f_v, f_c, k, c, b; SI units)."""

MOTOR_SIDE_PARAMETER_NAMES = COMPLIANCE_PARAMETER_NAMES[:5]
"""What the motor side alone identifies per joint (:func:`fit_motor_side_compliance`): all but the backlash."""

_REGRESSOR_NAMES = ("rotor_inertia", "viscous", "coulomb", "stiffness", "damping", "offset")
"""What the regressor's columns multiply."""

MAX_BACKLASH = 0.01
"""Widest dead band searched (rad), the plant's largest."""

BACKLASH_GRID = 41
"""Grid points of the backlash search per joint."""

FIT_BAND_TOP = 300.0
"""Highest DFT line fitted (Hz)."""

SETTLE_PERIODS = 1
"""Periods at the start of each log left out: the response to the excitation's start (the gearhead mode decays
in about 1 / (zeta omega) = 20 ms; the hold's loop in a few tens of ms)."""


@dataclass(frozen=True)
class ComplianceFit:
    """The motor side's least squares per joint, with standard errors.

    Attributes:
        compliance: The identified drives (rotor inertia, stiffness, damping; damping below 0 clipped to 0).
        estimate: Per joint the estimates of :data:`COMPLIANCE_PARAMETER_NAMES` (SI), ``(3, 6)``.
        standard_errors: Their standard errors, ``(3, 6)``: the spread of the same fit on each period alone, over
            the square root of the periods (the periods' noise is independent; a bias common to every period, as
            from the motor's unmodelled Stribeck friction and ripple, is not in it).
        residual_rms: RMS torque residual per joint (N m) on the periods' mean, ``(3,)``.
        periods: Periods averaged per log.
        logs: Logs fitted.
        parameter_names: What the columns of ``estimate`` are: :data:`COMPLIANCE_PARAMETER_NAMES`, or
            :data:`MOTOR_SIDE_PARAMETER_NAMES` from the motor side alone (the backlash not identified, taken as 0).
        arm_inertia_scale: From the motor side alone, the factor on the model's arm-side inertia the fit found, and
            its standard error; None with the load side.
    """

    compliance: DriveCompliance
    estimate: NDArray[np.float64]
    standard_errors: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    periods: int
    logs: int
    parameter_names: tuple[str, ...] = COMPLIANCE_PARAMETER_NAMES
    arm_inertia_scale: tuple[float, float] | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready estimates, standard errors and residuals per joint."""
        summary = {
            "estimate": {name: self.estimate[:, i].tolist() for i, name in enumerate(self.parameter_names)},
            "standard_errors": {
                name: self.standard_errors[:, i].tolist() for i, name in enumerate(self.parameter_names)
            },
            "residual_rms_per_joint": self.residual_rms.tolist(),
            "periods_per_log": self.periods,
            "logs": self.logs,
        }
        if self.arm_inertia_scale is not None:
            summary["arm_inertia_scale"] = {
                "estimate": self.arm_inertia_scale[0],
                "standard_error": self.arm_inertia_scale[1],
            }
        return summary


def _periods(log: DriveLog, samples: int, settle: int, *, load_side: bool = True) -> tuple[NDArray[np.float64], ...]:
    """Motor-side angles, load-side angles (with ``load_side``) and torques of the log's whole periods after
    ``settle`` (the last ``n * samples`` rows), each ``(n, samples, 3)``."""
    if load_side and log.load_angles is None:
        raise ValueError(
            "a compliant drive's stiffness needs the load-side angle: the log has no load_angle_1..3 columns"
        )
    count = len(log) // samples - settle
    if count < 2:
        raise ValueError(
            f"a log of {len(log)} samples holds {len(log) // samples} periods of {samples} samples; the fit needs "
            f"{settle + 2} (settling {settle}, then 2 to compare)"
        )
    kept = slice(len(log) - count * samples, len(log))
    signals = (
        (log.motor_side_angles, log.load_angles, log.torques) if load_side else (log.motor_side_angles, log.torques)
    )
    return tuple(np.reshape(values[kept], (count, samples, 3)) for values in signals)


def _samples_per_period(logs: Sequence[DriveLog], period: float) -> int:
    """Samples in one ``period`` (s) of the logs, which must share one sample period that divides it."""
    if not logs:
        raise ValueError("need at least one log")
    dt = logs[0].dt
    samples = round(period / dt)
    if samples < 3 or abs(samples * dt - period) > 1e-9 * period:
        raise ValueError(f"period must be a whole number (>= 3) of the logs' {dt:g} s samples, got {period!r} s")
    if any(abs(log.dt - dt) > 1e-12 for log in logs):
        raise ValueError(f"the logs must share one sample period, got {sorted({log.dt for log in logs})} s")
    return samples


@dataclass(frozen=True, eq=False)
class _PeriodSignals:
    """The signals of a log's periods per joint at the instants the torques were measured, averaged over the periods,
    on the fitted DFT lines.

    The equation is linear in its columns, so it holds for their mean over the periods; a nonlinear column (the
    friction's sign, the dead band) is the mean of the function of each period's signal, not the function of the
    mean signal (a rattling backlash does not repeat from period to period).

    Attributes:
        columns: [phi_ddot, phi_dot, sign phi_dot, delta, delta_dot, 1], ``(P, 3, 6)``; ``delta`` is the
            deflection without backlash.
        deflections: Each period's deflection phi - theta (rad) on every line, ``(n, P, 3)``: the dead band acts on
            them.
        fitted: Which DFT lines are fitted, ``(P // 2 + 1,)``.
        torque: The measured torques on the fitted lines (N m), ``(P, 3)``.
    """

    columns: NDArray[np.float64]
    deflections: NDArray[np.float64]
    fitted: NDArray[np.bool_]
    torque: NDArray[np.float64]

    def band(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """``values`` (P, ...) with only the fitted lines kept."""
        lines = np.fft.rfft(values, axis=0)
        lines[~self.fitted] = 0.0
        return np.fft.irfft(lines, n=len(values), axis=0)

    def rows(self, backlash: float, joint: int) -> NDArray[np.float64]:
        """One joint's rows ``(P, 6)`` with the spring's deflection beyond the dead band of width ``backlash``
        (rad)."""
        deflections = self.deflections[..., joint]
        half = 0.5 * backlash
        beyond = deflections - np.clip(deflections, -half, half)
        rows = self.columns[:, joint].copy()
        rows[:, 3] = self.band(beyond.mean(axis=0))
        return rows


def _period_signals(
    motor: NDArray[np.float64],
    load: NDArray[np.float64],
    torque: NDArray[np.float64],
    dt: float,
    delay: float,
    highest: float,
) -> _PeriodSignals:
    """The signals of ``n`` periods of motor-side and load-side angles (rad) and torques (N m), ``(n, P, 3)`` each:
    the angles taken ``delay`` (s) earlier (a phase e^{-i omega d}), their rates and accelerations by i omega, the
    lines above ``highest`` (Hz) and the Nyquist line (no phase to shift) left out."""
    samples = motor.shape[1]
    omega = 2.0 * np.pi * np.fft.rfftfreq(samples, dt)[:, None]
    shift = np.exp(-1j * omega * delay)
    if samples % 2 == 0:
        shift[-1] = 0.0
    fitted = omega[:, 0] <= 2.0 * np.pi * highest
    motor_lines = np.fft.rfft(motor, axis=1) * shift
    deflection_lines = np.fft.rfft(motor - load, axis=1) * shift

    def signal(lines: NDArray[np.complex128], keep: NDArray[np.bool_] = fitted) -> NDArray[np.float64]:
        return np.fft.irfft(lines * keep[:, None], n=samples, axis=-2)

    everything = np.ones_like(fitted)
    motor_rates = signal(1j * omega * motor_lines, everything)
    sliding = np.where(np.abs(motor_rates) > REST_VELOCITY, np.sign(motor_rates), 0.0).mean(axis=0)
    motor_mean, deflection_mean = motor_lines.mean(axis=0), deflection_lines.mean(axis=0)
    columns = (
        signal(-(omega**2) * motor_mean),
        signal(1j * omega * motor_mean),
        signal(np.fft.rfft(sliding, axis=0)),
        signal(deflection_mean),
        signal(1j * omega * deflection_mean),
        np.ones((samples, 3)),
    )
    deflections = signal(deflection_lines, everything)
    return _PeriodSignals(
        np.stack(columns, axis=-1), deflections, fitted, signal(np.fft.rfft(torque.mean(axis=0), axis=0))
    )


def _solve_joint(rows: NDArray[np.float64], torque: NDArray[np.float64], joint: int) -> NDArray[np.float64]:
    """Least squares of one joint's torques ``(M,)`` on its rows ``(M, 6)``. A friction column that is zero (the
    rotor never slid: its Coulomb friction unseen) is left out, its estimate 0; the others must be excited."""
    scale = np.linalg.norm(rows, axis=0)
    seen = scale > 0.0
    required = np.array([name not in ("viscous", "coulomb") for name in _REGRESSOR_NAMES])
    if np.any(required & ~seen):
        missing = [name for name, ok in zip(_REGRESSOR_NAMES, seen | ~required, strict=True) if not ok]
        raise ValueError(f"joint {joint + 1}: the logs do not excite {missing}")
    scaled = rows[:, seen] / scale[seen]
    solution = np.zeros(len(scale))
    # the normal equations of the Jacobi-scaled columns (6 x 6): thousands of solves in the backlash search
    solution[seen] = np.linalg.solve(scaled.T @ scaled, scaled.T @ torque) / scale[seen]
    return solution


def _fit_periods(signals: Sequence[_PeriodSignals]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per joint the estimates [J_m, f_v, f_c, k, c, offset, backlash] ``(3, 7)`` and the residuals ``(M, 3)``.

    The stiffness acts beyond a dead band (backlash b, centred on zero deflection: motor and load encoders zeroed
    together); given b the fit is linear, so b is searched per joint: a grid up to the largest deflection seen (or
    :data:`MAX_BACKLASH`), then a bounded scalar search about the best grid point.
    """
    torque = np.concatenate([s.torque for s in signals])
    largest = np.max(np.abs(np.concatenate([s.deflections.reshape(-1, 3) for s in signals])), axis=0)
    estimate, residual = np.empty((3, 7)), np.empty_like(torque)

    def rows_at(backlash: float, joint: int) -> NDArray[np.float64]:
        return np.concatenate([s.rows(backlash, joint) for s in signals])

    def squares(backlash: float, joint: int) -> float:
        rows = rows_at(backlash, joint)
        if not np.any(rows[:, 3]):
            return math.inf  # a dead band wider than every deflection: no spring left to fit
        return float(np.sum((torque[:, joint] - rows @ _solve_joint(rows, torque[:, joint], joint)) ** 2))

    for joint in range(3):
        top = min(MAX_BACKLASH, 2.0 * largest[joint])
        grid = np.linspace(0.0, top, BACKLASH_GRID)
        best = int(np.argmin([squares(b, joint) for b in grid]))
        low, high = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
        found = scipy.optimize.minimize_scalar(
            squares, bounds=(low, high), args=(joint,), method="bounded", options={"xatol": 1e-3 * (high - low)}
        )
        backlash = float(found.x) if found.fun < squares(grid[best], joint) else float(grid[best])
        rows = rows_at(backlash, joint)
        estimate[joint, :6] = _solve_joint(rows, torque[:, joint], joint)
        estimate[joint, 6] = backlash
        residual[:, joint] = torque[:, joint] - rows @ estimate[joint, :6]
    return estimate, residual


def fit_compliance(
    logs: Sequence[DriveLog],
    period: float = MULTISINE_PERIOD,
    torque_delay: float = MEASURED_TORQUE_DELAY,
    settle_periods: int = SETTLE_PERIODS,
    highest_line: float = FIT_BAND_TOP,
) -> ComplianceFit:
    """Fit the motor side's equation (module docstring) per joint to periodic excitation logs.

    Args:
        logs: Logs of a periodic excitation at rest poses with the load-side angles, each at least
            ``settle_periods + 2`` periods long, all with the same sample period.
        period: The excitation's period (s), a whole number of samples.
        torque_delay: Age of a torque reading relative to its angle sample (s): the simulated drive's physics step.
        settle_periods: Periods at each log's start left out.
        highest_line: Highest DFT line fitted (Hz).

    Raises:
        ValueError: without logs, without load-side angles, on logs too short, or if the data do not excite a
            parameter.
    """
    samples = _samples_per_period(logs, period)
    dt = logs[0].dt
    blocks = [_periods(log, samples, settle_periods) for log in logs]
    periods = min(len(motor) for motor, _, _ in blocks)

    def signals(select: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> list[_PeriodSignals]:
        return [_period_signals(*map(select, block), dt, torque_delay, highest_line) for block in blocks]

    estimate, residual = _fit_periods(signals(lambda values: values))
    per_period = np.array([_fit_periods(signals(lambda values, n=n: values[n : n + 1]))[0] for n in range(periods)])
    standard_errors = per_period.std(axis=0, ddof=1) / np.sqrt(periods)
    rotor_inertia, stiffness, damping = estimate[:, 0], estimate[:, 3], estimate[:, 4]
    if np.any(rotor_inertia <= 0.0) or np.any(stiffness <= 0.0):
        raise ValueError(
            f"the fit gave a rotor inertia {rotor_inertia.tolist()} kg m^2 or a stiffness {stiffness.tolist()} N m/rad "
            "that is not positive: the logs do not excite the drives' mode"
        )
    compliance = DriveCompliance(
        tuple(rotor_inertia), tuple(stiffness), tuple(np.maximum(damping, 0.0)), tuple(estimate[:, 6])
    )
    kept = [0, 1, 2, 3, 4, 6]
    return ComplianceFit(
        compliance=compliance,
        estimate=estimate[:, kept],
        standard_errors=standard_errors[:, kept],
        residual_rms=np.sqrt(np.mean(residual**2, axis=0)),
        periods=periods,
        logs=len(logs),
    )


MOTOR_SIDE_STIFFNESS_GRID = np.geomspace(1e4, 1e7, 7)
"""Stiffnesses (N m/rad), shared by the joints, the motor-side fit starts from: modes of about 25 Hz to 1.6 kHz on
the preset's rotor and arms, around the multisine's band."""

MOTOR_SIDE_START_DAMPING_RATIO = 0.05
"""Damping ratio c / (2 sqrt(k J_m)) of the motor-side fit's starts, J_m solved at each start's stiffness (a few per
cent is usual for a geared drive)."""

MOTOR_SIDE_MAX_UNEXPLAINED = 0.15
"""Largest share of the torque's RMS on the lines up to :data:`MOTOR_SIDE_CHECK_TOP` the motor-side fit may leave in
its residual per joint: the two-mass model leaves out the motor's Stribeck friction and ripple, whose share is well
under it over the stiffnesses the plant takes, while a dead band as narrow as the smallest backlash the controllers
act on (:data:`controllers.compliance.SMALLEST_BACKLASH`) leaves more (docs/measurements.md, "Motor-side
identification")."""

MOTOR_SIDE_CHECK_TOP = 200.0
"""Highest DFT line (Hz) on which the residual is judged against :data:`MOTOR_SIDE_MAX_UNEXPLAINED`: a dead band's
error lies about the mode, while on the lines near the band's top, on stiff drives whose antiresonances reach them,
the model leaves a residual that grows with the stiffness without any backlash (docs/measurements.md, "Motor-side
identification: the refusal")."""

MOTOR_SIDE_BOUND_TOLERANCE = 1e-3
"""How near a bound of :data:`_BOUNDS` (in log k) a fitted stiffness counts as on it: the fit then did not find it."""


class UnexplainedTorqueError(ValueError):
    """The motor-side fit leaves more of the torque unexplained than :data:`MOTOR_SIDE_MAX_UNEXPLAINED`: the two-mass
    model does not explain the drives (a backlash is one cause)."""


class UnseenModeError(ValueError):
    """The motor-side fit's stiffness is not seen by the data: on a bound of its search, or the drives' mode (the
    lowest antiresonance of the fitted drives) above the fitted lines."""


MOTOR_SIDE_SCALE_RANGE = (0.5, 2.0)
"""Range of the arm inertia's scale the motor-side fit searches (the datasheet model's arm against the robot's)."""

_BOUNDS = (
    np.array([math.log(0.1 * MOTOR_SIDE_STIFFNESS_GRID[0])] * 3 + [0.0] * 3 + [math.log(MOTOR_SIDE_SCALE_RANGE[0])]),
    np.array([math.log(MAX_STIFFNESS)] * 3 + [MAX_VISCOUS] * 3 + [math.log(MOTOR_SIDE_SCALE_RANGE[1])]),
)
"""Bounds of the motor-side fit's log k, c and log s: a tenth of the stiffness grid's lowest to the plant's highest,
the damping in the plant's range."""


@dataclass(frozen=True, eq=False)
class _MotorLines:
    """One log's periods on the fitted DFT lines, the angles taken at the torques' instants.

    Attributes:
        omega: The lines' angular frequencies (rad/s), ``(L,)``.
        angle: Each period's motor-side angle per line (rad: unscaled DFT sums), ``(n, L, 3)``.
        torque: Each period's torque per line (N m: unscaled DFT sums), ``(n, L, 3)``.
        sliding: Each period's sign of the rotor's rate (0 at rest) per line, ``(n, L, 3)``.
        arm_inertia: The model's arm-side joint inertia at the log's pose (kg m^2), ``(3, 3)``.
    """

    omega: NDArray[np.float64]
    angle: NDArray[np.complex128]
    torque: NDArray[np.complex128]
    sliding: NDArray[np.complex128]
    arm_inertia: NDArray[np.float64]

    def periods(self, chosen: slice) -> _MotorLines:
        """These lines with only the ``chosen`` periods."""
        return _MotorLines(self.omega, self.angle[chosen], self.torque[chosen], self.sliding[chosen], self.arm_inertia)


def _motor_lines(
    motor: NDArray[np.float64],
    torque: NDArray[np.float64],
    arm_inertia: NDArray[np.float64],
    dt: float,
    delay: float,
    highest: float,
) -> _MotorLines:
    """The lines above 0 and up to ``highest`` (Hz) of ``n`` periods of motor-side angles (rad) and torques (N m),
    ``(n, P, 3)`` each, the angles taken ``delay`` (s) earlier (a phase e^{-i omega d}); the Nyquist line left out."""
    samples = motor.shape[1]
    omega = 2.0 * np.pi * np.fft.rfftfreq(samples, dt)
    angle = np.fft.rfft(motor, axis=1) * np.exp(-1j * omega * delay)[:, None]
    rates = np.fft.irfft(1j * omega[:, None] * angle, n=samples, axis=1)
    sliding = np.where(np.abs(rates) > REST_VELOCITY, np.sign(rates), 0.0)
    fitted = (omega > 0.0) & (omega <= 2.0 * np.pi * highest)
    if samples % 2 == 0:
        fitted[-1] = False
    return _MotorLines(
        omega[fitted],
        angle[:, fitted],
        np.fft.rfft(torque, axis=1)[:, fitted],
        np.fft.rfft(sliding, axis=1)[:, fitted],
        np.asarray(arm_inertia, dtype=float),
    )


def _gearhead_torque(
    lines: _MotorLines,
    angle: NDArray[np.complex128],
    stiffness: NDArray[np.float64],
    damping: NDArray[np.float64],
    scale: float,
) -> NDArray[np.complex128]:
    """The torque the gearheads take from the rotors on each line (N m, unscaled DFT sums), ``(L, 3)``, for the rotor
    angles ``angle`` ``(L, 3)``: with G = K + i omega C and the arm side -omega^2 s M at rest, the arm's angle is
    theta = (G - omega^2 s M)^-1 G phi, so G (phi - theta) = -omega^2 G (G - omega^2 s M)^-1 s M phi."""
    omega = lines.omega[:, None, None]
    gearhead = np.diag(stiffness)[None] + 1j * omega * np.diag(damping)[None]
    arm = -(omega**2) * scale * lines.arm_inertia[None]
    twist = np.linalg.solve(gearhead + arm, (arm @ angle[:, :, None]))
    return (gearhead @ twist)[..., 0]


def _motor_side_solution(
    blocks: Sequence[_MotorLines], nonlinear: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Given log k (3), c (3) and log s, the least squares of the rotor's linear parameters (J_m, f_v, f_c per
    joint, ``(3, 3)``) and the residuals, real and imaginary parts stacked per joint, ``(2 L_total, 3)``."""
    stiffness, damping, scale = np.exp(nonlinear[:3]), nonlinear[3:6], float(np.exp(nonlinear[6]))
    columns, remainders = [], []
    for lines in blocks:
        angle = lines.angle.mean(axis=0)
        remainders.append(lines.torque.mean(axis=0) - _gearhead_torque(lines, angle, stiffness, damping, scale))
        omega = lines.omega[:, None]
        columns.append(np.stack([-(omega**2) * angle, 1j * omega * angle, lines.sliding.mean(axis=0)], axis=-1))
    rows, remainder = np.concatenate(columns), np.concatenate(remainders)
    linear, residual = np.empty((3, 3)), np.empty((2 * len(remainder), 3))
    for joint in range(3):
        real_rows = np.vstack([rows[:, joint].real, rows[:, joint].imag])
        real_torque = np.concatenate([remainder[:, joint].real, remainder[:, joint].imag])
        linear[joint] = np.linalg.lstsq(real_rows, real_torque, rcond=None)[0]
        residual[:, joint] = real_torque - real_rows @ linear[joint]
    return linear, residual


def _fit_motor_side(blocks: Sequence[_MotorLines], start: NDArray[np.float64]) -> NDArray[np.float64]:
    """The nonlinear least squares over log k, c and log s from ``start`` (variable projection: the rotor's linear
    parameters solved inside)."""
    found = scipy.optimize.least_squares(
        lambda x: _motor_side_solution(blocks, x)[1].ravel(), start, x_scale="jac", method="trf", bounds=_BOUNDS
    )
    return found.x


def _motor_side_starts(blocks: Sequence[_MotorLines]) -> list[NDArray[np.float64]]:
    """Where the motor-side fit starts: each stiffness of :data:`MOTOR_SIDE_STIFFNESS_GRID` shared by the joints,
    the model's arm inertia unscaled, the damping at :data:`MOTOR_SIDE_START_DAMPING_RATIO` against the rotor
    inertia solved at that stiffness."""

    def start_at(stiffness: float) -> NDArray[np.float64]:
        x = np.concatenate([np.full(3, math.log(stiffness)), np.zeros(3), [0.0]])
        rotor = np.clip(_motor_side_solution(blocks, x)[0][:, 0], 1e-6, None)
        x[3:6] = np.clip(2.0 * MOTOR_SIDE_START_DAMPING_RATIO * np.sqrt(stiffness * rotor), 0.0, MAX_VISCOUS)
        return x

    return [start_at(float(k)) for k in MOTOR_SIDE_STIFFNESS_GRID]


def _best_motor_side_fit(blocks: Sequence[_MotorLines]) -> NDArray[np.float64]:
    """The least squares from every start (:func:`_motor_side_starts`) with the least squared residual: a mode put
    at the wrong frequency fits worse than none, so the cost between the starts is no guide to the basin."""
    fits = [_fit_motor_side(blocks, start) for start in _motor_side_starts(blocks)]
    return fits[int(np.argmin([np.sum(_motor_side_solution(blocks, x)[1] ** 2) for x in fits]))]


def _require_seen_mode(blocks: Sequence[_MotorLines], nonlinear: NDArray[np.float64], highest_line: float) -> None:
    """Refuse a motor-side fit whose stiffness the data do not show: a log k on a bound of :data:`_BOUNDS` (within
    :data:`MOTOR_SIDE_BOUND_TOLERANCE`), or, at some pose, the fitted drives' lowest antiresonance (the lowest
    sqrt of the generalized eigenvalues of K against s M, the arm ringing against held rotors) above ``highest_line``
    (Hz): below its antiresonances the drive moves as one body and k shows only in a small curvature.

    Raises:
        UnseenModeError: naming the stiffnesses and the bound, or the antiresonance and the band.
    """
    stiffness = np.exp(nonlinear[:3])
    low, high = _BOUNDS[0][:3], _BOUNDS[1][:3]
    on_bound = (nonlinear[:3] - low < MOTOR_SIDE_BOUND_TOLERANCE) | (high - nonlinear[:3] < MOTOR_SIDE_BOUND_TOLERANCE)
    if np.any(on_bound):
        raise UnseenModeError(
            f"the motor-side fit's stiffness {stiffness.tolist()} N m/rad sits on a bound of its search "
            f"({math.exp(low[0]):g} to {math.exp(high[0]):g} N m/rad): the logs do not show the drives' mode"
        )
    scale = math.exp(nonlinear[6])
    lowest = [
        math.sqrt(scipy.linalg.eigh(np.diag(stiffness), scale * lines.arm_inertia, eigvals_only=True)[0])
        / (2 * math.pi)
        for lines in blocks
    ]
    if max(lowest) > highest_line:
        raise UnseenModeError(
            f"the fitted drives' lowest antiresonance per log, {np.round(lowest, 1).tolist()} Hz, is above the fitted "
            f"lines (up to {highest_line:g} Hz) at some pose: the logs do not show the drives' mode"
        )


def _unexplained(
    blocks: Sequence[_MotorLines], residual: NDArray[np.float64], samples: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per joint the residual's RMS over a period (N m) on every fitted line, and its share of the torque's RMS on the
    lines up to :data:`MOTOR_SIDE_CHECK_TOP`, from the stacked real and imaginary residuals of
    :func:`_motor_side_solution` (Parseval: each line below the Nyquist rate holds twice its share; the mean square
    over the logs)."""
    lines = sum(len(b.omega) for b in blocks)
    residual_lines = residual[:lines] + 1j * residual[lines:]
    torque_lines = np.concatenate([b.torque.mean(axis=0) for b in blocks])
    checked = np.concatenate([b.omega for b in blocks]) <= 2.0 * np.pi * MOTOR_SIDE_CHECK_TOP

    def rms(amplitude: NDArray[np.complex128]) -> NDArray[np.float64]:
        return np.sqrt(2.0 * np.sum(np.abs(amplitude) ** 2, axis=0) / len(blocks)) / samples

    return rms(residual_lines), rms(residual_lines[checked]) / rms(torque_lines[checked])


def fit_motor_side_compliance(
    logs: Sequence[DriveLog],
    arm_inertias: Sequence[NDArray[np.float64]],
    period: float = MULTISINE_PERIOD,
    torque_delay: float = MEASURED_TORQUE_DELAY,
    settle_periods: int = SETTLE_PERIODS,
    highest_line: float = FIT_BAND_TOP,
) -> ComplianceFit:
    """Fit the two-mass drives to periodic excitation logs of the motor side alone (docs/design.md section 7,
    "From the motor side alone").

    Per DFT line omega of the periods' mean the measured torque is the rotor's and the gearheads',

        tau = (-omega^2 J_m + i omega F_v) phi + F_c S - omega^2 G (G - omega^2 s M)^-1 s M phi,

    G = K + i omega C, M each log's arm-side joint inertia from the model and s one scale on it for every pose (the
    model's arm is a few per cent off the robot's), S the line of sign(phi_dot). The motor-side response to torque
    has its antiresonances where det(G - omega^2 s M) = 0 and its resonances above them; low lines see
    J_m + s M, high ones J_m. K, C and s are found by nonlinear least squares (J_m, F_v, F_c, linear, solved inside),
    from several shared stiffnesses, the best kept. The backlash is not identified (taken as 0).

    Args:
        logs: Logs of a periodic excitation at rest poses (motor-side angles and torques), each at least
            ``settle_periods + 2`` periods long, all with the same sample period.
        arm_inertias: The model's arm-side joint inertia M (kg m^2, ``(3, 3)``, no rotor in it) at each log's pose.
        period: The excitation's period (s), a whole number of samples.
        torque_delay: Age of a torque reading relative to its angle sample (s).
        settle_periods: Periods at each log's start left out.
        highest_line: Highest DFT line fitted (Hz).

    Returns:
        The fit, its columns :data:`MOTOR_SIDE_PARAMETER_NAMES`, with the arm inertia's scale; standard errors from
        the fits to single periods, as :func:`fit_compliance`'s: the periods' noise only, 10 to 30 times under the
        stiffness's error on known plants (docs/measurements.md).

    Raises:
        ValueError: without logs, for an inertia per log missing or not (3, 3), on logs too short, or if the fit's
            rotor inertia is not positive.
        UnseenModeError: if the stiffness is not seen (:func:`_require_seen_mode`).
        UnexplainedTorqueError: if the fit leaves more than :data:`MOTOR_SIDE_MAX_UNEXPLAINED` of a joint's torque on
            the lines up to :data:`MOTOR_SIDE_CHECK_TOP` unexplained: the two-mass model does not explain the drive.
    """
    samples = _samples_per_period(logs, period)
    if len(arm_inertias) != len(logs) or any(np.shape(m) != (3, 3) for m in arm_inertias):
        raise ValueError(
            f"need one (3, 3) arm-side inertia per log ({len(logs)}), got shapes {[np.shape(m) for m in arm_inertias]}"
        )
    dt = logs[0].dt
    blocks = [
        _motor_lines(*_periods(log, samples, settle_periods, load_side=False), inertia, dt, torque_delay, highest_line)
        for log, inertia in zip(logs, arm_inertias, strict=True)
    ]
    periods = min(len(lines.angle) for lines in blocks)
    nonlinear = _best_motor_side_fit(blocks)
    linear, residual = _motor_side_solution(blocks, nonlinear)

    def estimate_of(x: NDArray[np.float64], solved: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.column_stack([solved, np.exp(x[:3]), x[3:6], np.full(3, np.exp(x[6]))])

    if np.any(linear[:, 0] <= 0.0):
        raise ValueError(
            f"the fit gave a rotor inertia {linear[:, 0].tolist()} kg m^2 that is not positive: the logs do not "
            "excite the drives' mode"
        )
    _require_seen_mode(blocks, nonlinear, highest_line)
    residual_rms, unexplained = _unexplained(blocks, residual, samples)
    if np.any(unexplained > MOTOR_SIDE_MAX_UNEXPLAINED):
        raise UnexplainedTorqueError(
            f"the two-mass model does not explain the drive: it leaves {np.round(unexplained, 3).tolist()} of the "
            f"torque per joint on the lines up to {MOTOR_SIDE_CHECK_TOP:g} Hz unexplained (at most "
            f"{MOTOR_SIDE_MAX_UNEXPLAINED:g}), and the motor side alone does not identify the drives"
        )
    estimate = estimate_of(nonlinear, linear)
    per_period = []
    for n in range(periods):
        single = [lines.periods(slice(n, n + 1)) for lines in blocks]
        x = _fit_motor_side(single, nonlinear)
        per_period.append(estimate_of(x, _motor_side_solution(single, x)[0]))
    standard_errors = np.std(per_period, axis=0, ddof=1) / np.sqrt(periods)
    rotor_inertia, stiffness, damping = estimate[:, 0], estimate[:, 3], estimate[:, 4]
    return ComplianceFit(
        compliance=DriveCompliance(tuple(rotor_inertia), tuple(stiffness), tuple(damping)),
        estimate=estimate[:, :5],
        standard_errors=standard_errors[:, :5],
        residual_rms=residual_rms,
        periods=periods,
        logs=len(logs),
        parameter_names=MOTOR_SIDE_PARAMETER_NAMES,
        arm_inertia_scale=(float(estimate[0, 5]), float(standard_errors[0, 5])),
    )
