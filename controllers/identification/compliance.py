"""Identification of compliant drives: the rotor's inertia and friction, the gearhead's stiffness and damping per
joint, from logs of a periodic excitation with the load-side angle (docs/design.md section 7, "Compliant drives").

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
import scipy.optimize
from numpy.typing import NDArray

from controllers.compliance import DriveCompliance
from controllers.identification.data import REST_VELOCITY
from controllers.identification.logs import DriveLog
from delta_env.excitation import MULTISINE_PERIOD
from delta_env.sensors import MEASURED_TORQUE_DELAY

COMPLIANCE_PARAMETER_NAMES = ("rotor_inertia", "viscous", "coulomb", "stiffness", "damping", "backlash")
"""The motor side's parameters per joint (J_m, f_v, f_c, k, c, b; SI units)."""

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
    """

    compliance: DriveCompliance
    estimate: NDArray[np.float64]
    standard_errors: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    periods: int
    logs: int

    def summary(self) -> dict[str, Any]:
        """JSON-ready estimates, standard errors and residuals per joint."""
        return {
            "estimate": {name: self.estimate[:, i].tolist() for i, name in enumerate(COMPLIANCE_PARAMETER_NAMES)},
            "standard_errors": {
                name: self.standard_errors[:, i].tolist() for i, name in enumerate(COMPLIANCE_PARAMETER_NAMES)
            },
            "residual_rms_per_joint": self.residual_rms.tolist(),
            "periods_per_log": self.periods,
            "logs": self.logs,
        }


def _periods(log: DriveLog, samples: int, settle: int) -> tuple[NDArray[np.float64], ...]:
    """Motor-side angles, load-side angles and torques of the log's whole periods after ``settle`` (the last
    ``n * samples`` rows), each ``(n, samples, 3)``."""
    if log.load_angles is None:
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
    return tuple(
        np.reshape(values[kept], (count, samples, 3))
        for values in (log.motor_side_angles, log.load_angles, log.torques)
    )


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
    if not logs:
        raise ValueError("need at least one log")
    dt = logs[0].dt
    samples = round(period / dt)
    if samples < 3 or abs(samples * dt - period) > 1e-9 * period:
        raise ValueError(f"period must be a whole number (>= 3) of the logs' {dt:g} s samples, got {period!r} s")
    if any(abs(log.dt - dt) > 1e-12 for log in logs):
        raise ValueError(f"the logs must share one sample period, got {sorted({log.dt for log in logs})} s")
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
