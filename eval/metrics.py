"""Evaluation metrics: pure functions of recorded episodes (docs/design.md section 8).

Definitions (units in the names):

- tracking: Cartesian distance between the platform and the reference, RMS and max over the episode (mm);
- torque: the motor torque that acts (after saturation and the current loop), RMS over time and joints
  and peak |tau_i| (N m);
- energy: the absolute mechanical work of the three motors, sum_i integral |tau_i theta_dot_i| dt (J):
  every joule a motor delivers or absorbs counts, since the drives of a Delta do not regenerate into each
  other;
- payload: per carry, the estimate's relative error at the end of the carry (%), the settling time to
  +-5 %, the time after the pick from which the estimate stays inside the band until the release (ms), and
  the peak estimate during the carry (kg); over many carries, the counts against the payload targets
  (:func:`payload_targets`);
- torque error statistics of a model: mean and standard deviation of tau_measured - tau_model per joint
  (N m), the paper's Tables 1 and 2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

PAYLOAD_BAND = 0.05
"""Relative band (5 %) of the payload settling time."""

MIN_RELATIVE_MASS = 0.5
"""Smallest payload (kg) whose relative estimate error is scored: relative errors of near-empty grippers
say nothing about the estimator."""

LIGHT_OBJECT_BAND_KG = 0.025
"""Target band (kg) of the end-of-carry error of objects lighter than :data:`MIN_RELATIVE_MASS`."""

OVERSHOOT_BOUND = (0.2, 0.2)
"""(kg, relative): during a carry the estimate must not exceed the true mass by more than
max(0.2 kg, 20 % of it)."""

SETTLING_DEADLINE_MS = 150.0
"""Deadline (ms after each pick) by which estimates of objects >= :data:`MIN_RELATIVE_MASS` should be within +-5 %."""


def tracking_metrics(tracking_error: ArrayLike) -> tuple[float, float]:
    """RMS and max (mm) of Cartesian tracking errors given in m, ``(N,)``; NaN samples are excluded."""
    error = np.asarray(tracking_error, dtype=float)
    error = error[np.isfinite(error)]
    if error.size == 0:
        return math.nan, math.nan
    return 1e3 * float(np.sqrt(np.mean(error**2))), 1e3 * float(np.max(error))


def torque_metrics(torque: ArrayLike) -> tuple[float, float]:
    """RMS over time and joints and peak |tau_i| (N m) of motor torques ``(N, 3)``."""
    torque = np.asarray(torque, dtype=float)
    return float(np.sqrt(np.mean(torque**2))), float(np.max(np.abs(torque)))


def mechanical_energy(torque: ArrayLike, joint_velocity: ArrayLike, dt: float) -> float:
    """Absolute mechanical work (J) of the motors: sum_i integral |tau_i theta_dot_i| dt, rectangle rule.

    Args:
        torque: Motor torques (N m), ``(N, 3)``, each held over one period.
        joint_velocity: Joint rates (rad/s), ``(N, 3)``, over the same periods.
        dt: Period (s).
    """
    power = np.abs(np.asarray(torque, dtype=float) * np.asarray(joint_velocity, dtype=float))
    return float(np.sum(power) * dt)


@dataclass(frozen=True)
class CarryMetrics:
    """How well a payload estimate followed one carried object.

    Attributes:
        mass: True mass (kg).
        end_estimate: Estimate at the last sample of the carry (kg).
        end_error_percent: 100 (end_estimate - mass) / mass (%); NaN for a 0 kg object.
        settling_time_ms: Time after the pick from which the estimate stays within +-5 % until the release
            (ms); NaN if it is outside at the end of the carry.
        peak_estimate: Largest estimate during the carry (kg).
    """

    mass: float
    end_estimate: float
    end_error_percent: float
    settling_time_ms: float
    peak_estimate: float

    @property
    def end_error_kg(self) -> float:
        """end_estimate - mass (kg)."""
        return self.end_estimate - self.mass


def carry_metrics(
    estimates: ArrayLike,
    pick_indices: Sequence[int],
    place_indices: Sequence[int],
    masses: Sequence[float],
    dt: float,
    band: float = PAYLOAD_BAND,
) -> list[CarryMetrics]:
    """Per-carry payload metrics of an estimate sampled every ``dt`` (s).

    Args:
        estimates: Payload estimate (kg) that the controller used at each step, ``(N,)``.
        pick_indices: First step of each carry (the gripper holds from there).
        place_indices: First step after each carry.
        masses: True mass of each carried object (kg).
        dt: Sample period (s).
        band: Relative half-width of the settling band.
    """
    estimates = np.asarray(estimates, dtype=float)
    results = []
    for pick, place, mass in zip(pick_indices, place_indices, masses, strict=True):
        carry = estimates[pick:place]
        if carry.size == 0:
            raise ValueError(f"empty carry from step {pick} to {place}")
        outside = np.flatnonzero(~(np.abs(carry - mass) <= band * mass))
        if outside.size == 0:
            settling = 0.0
        elif outside[-1] == carry.size - 1:
            settling = math.nan
        else:
            settling = 1e3 * dt * (outside[-1] + 1)
        end = float(carry[-1])
        error = 100.0 * (end - mass) / mass if mass > 0.0 else math.nan
        results.append(CarryMetrics(float(mass), end, error, settling, float(np.max(carry))))
    return results


@dataclass(frozen=True)
class PayloadTargets:
    """How many carries meet each payload target (counts a of b).

    Attributes:
        end_within_band: Objects >= :data:`MIN_RELATIVE_MASS` whose end-of-carry estimate is within +-5 %, of all
            such objects.
        light_within_band: Lighter objects whose end-of-carry error is within +-:data:`LIGHT_OBJECT_BAND_KG`, of all.
        light_error_range_kg: Smallest and largest end-of-carry error of the lighter objects (kg); NaN if none.
        overshoots: Carries whose peak estimate exceeds the mass by more than :data:`OVERSHOOT_BOUND`, of all.
        settled: Objects >= :data:`MIN_RELATIVE_MASS` within +-5 % by :data:`SETTLING_DEADLINE_MS`, of all such.
    """

    end_within_band: tuple[int, int]
    light_within_band: tuple[int, int]
    light_error_range_kg: tuple[float, float]
    overshoots: tuple[int, int]
    settled: tuple[int, int]


def payload_targets(carries: Sequence[CarryMetrics], band: float = PAYLOAD_BAND) -> PayloadTargets:
    """Count the carries against the payload targets (:class:`PayloadTargets`); NaN settling is "not settled"."""
    heavy = [carry for carry in carries if carry.mass >= MIN_RELATIVE_MASS]
    light_errors = [carry.end_error_kg for carry in carries if carry.mass < MIN_RELATIVE_MASS]
    bound_kg, bound_fraction = OVERSHOOT_BOUND
    over = sum(carry.peak_estimate - carry.mass > max(bound_kg, bound_fraction * carry.mass) for carry in carries)
    return PayloadTargets(
        end_within_band=(sum(abs(carry.end_error_percent) <= 100.0 * band for carry in heavy), len(heavy)),
        light_within_band=(sum(abs(error) <= LIGHT_OBJECT_BAND_KG for error in light_errors), len(light_errors)),
        light_error_range_kg=(min(light_errors), max(light_errors)) if light_errors else (math.nan, math.nan),
        overshoots=(int(over), len(carries)),
        settled=(sum(carry.settling_time_ms <= SETTLING_DEADLINE_MS for carry in heavy), len(heavy)),
    )


def torque_error_statistics(
    torque_measured: ArrayLike, torque_model: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean and standard deviation per joint (N m) of tau_measured - tau_model, each ``(3,)``."""
    error = np.asarray(torque_measured, dtype=float) - np.asarray(torque_model, dtype=float)
    return error.mean(axis=0), error.std(axis=0)


def mean_std(values: ArrayLike) -> tuple[float, float, int]:
    """Mean, sample standard deviation and count of the finite values (NaN, NaN, 0 when none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.nan, math.nan, 0
    std = float(np.std(values, ddof=1)) if values.size > 1 else 0.0
    return float(np.mean(values)), std, int(values.size)


def format_mean_std(values: ArrayLike, digits: int = 2) -> str:
    """``"mean ± std"`` of the finite values, ``"n/a"`` when there are none."""
    mean, std, count = mean_std(values)
    if count == 0:
        return "n/a"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines.extend("| " + " | ".join(row) + " |" for row in rows)
    return "\n".join(lines)


def group_by(rows: Sequence[Mapping[str, object]], key: str) -> dict[object, list[Mapping[str, object]]]:
    """Rows grouped by the value of ``key``, in first-seen order."""
    groups: dict[object, list[Mapping[str, object]]] = {}
    for row in rows:
        groups.setdefault(row[key], []).append(row)
    return groups
