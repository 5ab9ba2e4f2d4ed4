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

Pick rate, scored like a picker's data sheet (:func:`arrivals`):

- work time: from the reference's arrival at rest at the first pick point to the end of the reference, which
  ends at rest at the next pick point (one full cycle per object); it is a property of the reference alone,
  the timing's rate, not of how well a controller followed it;
- picks per minute: 60 * (objects of the reference) / work time (1/min);
- cycle time of object k: arrival at pick k to arrival at pick k + 1, the end of the reference for the last (s);
- place error: per object, the distance from the platform to the place point when the gripper opens (mm);
- settle time: per pick and place with the in-position release, from the reference's arrival at rest to the cell's
  in-position signal (ms), a wait that timed out counting as the time-out (the time it waited); mean and max over
  the episode's waits, and the count of time-outs (``settle_timeouts``);
- residual vibration at the place: per place with the in-position release, the peak to peak of the platform's true
  position (the largest distance between two of its positions) over :data:`RESIDUAL_WINDOW` from the cell's
  in-position signal, while the gripper's air activation runs, cut at the release (um); mean and max over the
  episode's places;
- path deviation: the platform's distance to the reference polyline, nearest segment, RMS and max (mm): a
  time-independent tracking score (lagging along the path but on it scores well);
- envelope violations: steps on which the drive clipped the command plus steps on which a joint exceeded its
  maximum speed (a step with both counts twice);
- torque ratios: peak |tau| over joints and time / the drive's peak torque, and the largest per-joint RMS
  torque over the episode / its rated torque; thermal margin = 1 - the RMS ratio (negative: over the thermal
  rating).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env.trajectories import arrivals

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

PATH_WINDOW = 100
"""Reference segments searched on either side of a sample's own reference sample by :func:`path_deviation`:
0.1 s at 1 kHz, far more than any controller's lag along the path, and the search stays linear in N."""


RESIDUAL_WINDOW = 0.030
"""Window (s) of the residual vibration at the place, from the cell's in-position signal (the platform measured
within the in-position window): the motion the object sees while the gripper releases it. Four to seven periods of
the compliant drives' first mode (146-234 Hz over the designs and payloads) and 1.4 to 2.2 of its decay times (damping
ratio near 0.05), and within the default air activation (35 ms), so that the release's step in the static deflection
is not in it. docs/design.md section 9."""


def peak_to_peak(positions: ArrayLike) -> float:
    """The largest distance (m) between two of ``positions`` (m), ``(M, 3)``; NaN for none or a non-finite one."""
    points = np.asarray(positions, dtype=float).reshape(-1, 3)
    if len(points) == 0 or not np.all(np.isfinite(points)):
        return math.nan
    return float(np.max(np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)))


def settle_metrics(settle_times: Sequence[float], timed_out: Sequence[bool]) -> tuple[float, float, int]:
    """Mean and max settle time (ms) of an episode's waits for the in-position signal, given in s (NaN, NaN without
    a wait: the timed release), and how many of them timed out."""
    times = 1e3 * np.asarray(settle_times, dtype=float)
    if times.size == 0:
        return math.nan, math.nan, 0
    return float(np.mean(times)), float(np.max(times)), int(np.sum(timed_out))


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


def cycle_times(reference_velocity: ArrayLike, pick_indices: Sequence[int], dt: float) -> NDArray[np.float64]:
    """Cycle time (s) of each object: the reference's arrival at rest at its pick point to the arrival at the
    next one, the end of the reference (at rest at the next pick point) for the last object, ``(n,)``.

    Args:
        reference_velocity: Reference platform velocity (m/s), ``(M, 3)``.
        pick_indices: Samples where the gripper closes, one per object, in order.
        dt: Sample period (s).
    """
    start = arrivals(reference_velocity, pick_indices)
    if start.size == 0:  # a reference without objects (an excitation) has no cycles
        return np.zeros(0)
    end = np.append(start[1:], len(np.asarray(reference_velocity)) - 1)
    return (end - start) * dt


def picks_per_min(reference_velocity: ArrayLike, pick_indices: Sequence[int], dt: float) -> float:
    """Pick rate of a reference (1/min): 60 * objects / work time, the work time from the arrival at rest at the
    first pick point to the end of the reference (:func:`cycle_times` summed); NaN without objects."""
    if len(pick_indices) == 0:
        return math.nan
    return 60.0 * len(pick_indices) / float(np.sum(cycle_times(reference_velocity, pick_indices, dt)))


def place_errors(release_positions: ArrayLike, place_points: ArrayLike) -> NDArray[np.float64]:
    """Distance (mm) of the platform at each release, (n, 3) m, from its place point, (n, 3) m, ``(n,)``."""
    offset = np.asarray(release_positions, dtype=float) - np.asarray(place_points, dtype=float)
    return 1e3 * np.linalg.norm(offset.reshape(-1, 3), axis=1)


def path_deviation(
    positions: ArrayLike, path: ArrayLike, index: ArrayLike | None = None, window: int = PATH_WINDOW
) -> tuple[float, float]:
    """RMS and max (mm) of the distance of each position to the polyline ``path``: to the nearest of its segments.

    Args:
        positions: Platform positions (m), ``(N, 3)``; non-finite samples are excluded.
        path: Polyline vertices (m), ``(M, 3)``: the reference's samples.
        index: The path sample each position belongs to, ``(N,)``: only the segments within ``window`` samples
            of it are searched. None searches every segment (short paths).
        window: Segments searched on either side of ``index``.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    path = np.asarray(path, dtype=float).reshape(-1, 3)
    if len(path) == 0 or not np.all(np.isfinite(path)):
        raise ValueError(f"path must hold at least one vertex, all finite; got {len(path)} vertices")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 0:
        raise ValueError(f"window must be an integer >= 0 segments, got {window!r}")
    finite = np.all(np.isfinite(positions), axis=1)
    positions = positions[finite]
    if positions.shape[0] == 0:
        return math.nan, math.nan
    # A single vertex is a zero-length segment onto itself.
    starts, ends = (path[:-1], path[1:]) if len(path) > 1 else (path, path)
    if index is None:
        centers, first, last = np.zeros(len(positions), dtype=np.int64), 0, len(starts) - 1
    else:
        centers, first, last = np.asarray(index, dtype=np.int64)[finite], -window, window
    distance = _nearest_segment_distances(
        positions, np.ascontiguousarray(starts), np.ascontiguousarray(ends), centers, first, last
    )
    return 1e3 * float(np.sqrt(np.mean(distance**2))), 1e3 * float(np.max(distance))


SEGMENT_BLOCK = 16
"""Consecutive segments whose bounding box :func:`_nearest_segment_distances` tests before it measures them."""

PRUNING_TOLERANCE = 1e-9
"""Relative margin (of the coordinates involved) by which :func:`_nearest_segment_distances` must find a block of
segments farther than the nearest segment so far before it skips the block: far above the rounding of the distances."""


@numba.njit(cache=True, inline="always")
def _segment_distance2(
    positions: NDArray[np.float64], n: int, starts: NDArray[np.float64], ends: NDArray[np.float64], j: int
) -> float:
    """Squared distance (m^2) of position ``n`` to the segment ``starts[j] -> ends[j]``."""
    dx, dy, dz = ends[j, 0] - starts[j, 0], ends[j, 1] - starts[j, 1], ends[j, 2] - starts[j, 2]
    rx, ry, rz = positions[n, 0] - starts[j, 0], positions[n, 1] - starts[j, 1], positions[n, 2] - starts[j, 2]
    length2 = dx * dx + dy * dy + dz * dz
    # Zero-length segments (dwells) project onto their start point.
    along = (rx * dx + ry * dy + rz * dz) / (length2 if length2 > 0.0 else 1.0)
    along = min(max(along, 0.0), 1.0)
    gx, gy, gz = rx - along * dx, ry - along * dy, rz - along * dz
    return gx * gx + gy * gy + gz * gz


@numba.njit(cache=True)
def _nearest_segment_distances(
    positions: NDArray[np.float64],
    starts: NDArray[np.float64],
    ends: NDArray[np.float64],
    centers: NDArray[np.int64],
    first: int,
    last: int,
) -> NDArray[np.float64]:
    """Distance (m) of each position, ``(N, 3)``, to the nearest of the segments ``starts[j] -> ends[j]``, ``(M, 3)``,
    searched over j = ``centers[n] + first .. centers[n] + last`` (clipped to the segments).

    The minimum over that range, found without measuring every segment: the position's own segment (its center,
    clipped into the range) first; then each block of :data:`SEGMENT_BLOCK` segments whose bounding box is not
    farther than the nearest so far; in a block, a segment equal to the one before it (a dwell's zero-length
    segments) is not measured again.
    """
    count = len(starts)
    blocks = (count + SEGMENT_BLOCK - 1) // SEGMENT_BLOCK
    low_corner, high_corner = np.full((blocks, 3), np.inf), np.full((blocks, 3), -np.inf)
    repeats = np.zeros(count, dtype=np.bool_)  # segment j equals segment j - 1
    magnitude = 0.0
    for j in range(count):
        block = j // SEGMENT_BLOCK
        same = j > 0
        for axis in range(3):
            a, b = starts[j, axis], ends[j, axis]
            low_corner[block, axis] = min(low_corner[block, axis], a, b)
            high_corner[block, axis] = max(high_corner[block, axis], a, b)
            magnitude = max(magnitude, abs(a), abs(b))
            same = same and a == starts[j - 1, axis] and b == ends[j - 1, axis]
        repeats[j] = same
    distance = np.empty(len(positions))
    for n in range(len(positions)):
        low = min(max(centers[n] + first, 0), count - 1)
        high = max(min(centers[n] + last, count - 1), low)
        own = min(max(centers[n], low), high)
        nearest = _segment_distance2(positions, n, starts, ends, own)
        scale = magnitude + max(abs(positions[n, 0]), abs(positions[n, 1]), abs(positions[n, 2]))
        for block in range(low // SEGMENT_BLOCK, high // SEGMENT_BLOCK + 1):
            gap2 = 0.0
            for axis in range(3):
                gap = max(low_corner[block, axis] - positions[n, axis], positions[n, axis] - high_corner[block, axis])
                gap2 += max(gap, 0.0) ** 2
            if math.sqrt(gap2) > math.sqrt(nearest) + PRUNING_TOLERANCE * scale:
                continue
            for j in range(max(block * SEGMENT_BLOCK, low), min((block + 1) * SEGMENT_BLOCK, high + 1)):
                if j != own and not (repeats[j] and j > low):
                    nearest = min(nearest, _segment_distance2(positions, n, starts, ends, j))
        distance[n] = math.sqrt(nearest)
    return distance


def torque_ratios(torque: ArrayLike, peak_torque: float, rated_torque: float) -> tuple[float, float]:
    """How much of the drive an episode used: peak |tau| over joints and time / ``peak_torque``, and the largest
    per-joint RMS torque over the episode / ``rated_torque`` (both dimensionless).

    Args:
        torque: Motor torques that acted (N m), ``(N, 3)``.
        peak_torque: The drive's peak torque (N m).
        rated_torque: The drive's rated continuous torque (N m).
    """
    torque = np.asarray(torque, dtype=float)
    rms = np.sqrt(np.mean(torque**2, axis=0))
    return float(np.max(np.abs(torque))) / peak_torque, float(np.max(rms)) / rated_torque


def envelope_violations(saturated_steps: int, speed_exceeded_steps: int) -> int:
    """Steps outside the drive's envelope: those whose command the drive clipped plus those on which a joint
    exceeded its maximum speed (a step with both counts twice)."""
    return int(saturated_steps) + int(speed_exceeded_steps)


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


PAYLOAD_SCORES = ("payload_end_error_percent", "payload_end_abs_error_percent", "payload_settling_ms")
"""The payload scores of one episode (:func:`payload_scores`)."""


def payload_scores(carries: Sequence[CarryMetrics]) -> dict[str, float]:
    """An episode's payload scores over its carries of objects >= :data:`MIN_RELATIVE_MASS` (NaN without any):
    the mean end-of-carry error (%, signed: the tables' "m_hat error, end of carry"), the mean of its magnitude (%)
    and the worst settling time to +-5 % (ms; NaN if a carry never settles)."""
    scored = [carry for carry in carries if carry.mass >= MIN_RELATIVE_MASS]
    if not scored:
        return dict.fromkeys(PAYLOAD_SCORES, math.nan)
    errors = np.array([carry.end_error_percent for carry in scored])
    return {
        "payload_end_error_percent": float(np.mean(errors)),
        "payload_end_abs_error_percent": float(np.mean(np.abs(errors))),
        "payload_settling_ms": max(carry.settling_time_ms for carry in scored),
    }


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


METRIC_LABELS = {
    "tracking_rms_mm": "Tracking RMS (mm)",
    "tracking_max_mm": "Tracking max (mm)",
    "joint_error_rms_mrad": "Joint error RMS (mrad)",
    "torque_rms_nm": "Torque RMS (N m)",
    "torque_peak_nm": "Torque peak (N m)",
    "energy_j": "Energy (J)",
    "payload_end_error_percent": "m_hat error, end of carry (%)",
    "payload_end_abs_error_percent": "|m_hat error|, end of carry (%)",
    "payload_settling_ms": "m_hat settling to ±5 % (ms)",
    "picks_per_min": "Picks/min",
    "cycle_time_mean_s": "Cycle time, mean (s)",
    "cycle_time_max_s": "Cycle time, max (s)",
    "place_error_mean_mm": "Place error, mean (mm)",
    "place_error_max_mm": "Place error, max (mm)",
    "settle_time_mean_ms": "Settle time, mean (ms)",
    "settle_time_max_ms": "Settle time, max (ms)",
    "settle_timeouts": "Settle time-outs",
    "path_deviation_rms_mm": "Path deviation RMS (mm)",
    "path_deviation_max_mm": "Path deviation max (mm)",
    "envelope_violations": "Envelope violations (steps)",
    "peak_torque_ratio": "Peak torque / drive peak",
    "rms_torque_ratio": "RMS torque / drive rated",
    "thermal_margin": "Thermal margin (1 - RMS / rated)",
}
"""Words and units of the per-episode metrics (:meth:`eval.episodes.EpisodeRecord.metrics`,
:data:`PAYLOAD_SCORES`), for the headers of tables."""


def metric_label(name: str) -> str:
    """The words and unit of metric ``name`` (:data:`METRIC_LABELS`); else its name in words."""
    return METRIC_LABELS.get(name, name.replace("_", " "))


def format_number(value: float, digits: int = 3) -> str:
    """``value`` rounded to ``digits`` significant digits (at least), in positional notation from 1e-4 to 1e9
    ("197", "5.30", "0.0512"), else in exponent notation; "n/a" when it is not finite."""
    if not math.isfinite(value):
        return "n/a"
    if value == 0.0 or not 1e-4 <= abs(value) < 1e9:
        return f"{value:.{digits - 1}e}" if value else "0"
    return f"{value:.{max(digits - 1 - math.floor(math.log10(abs(value))), 0)}f}"


def format_with_spread(value: float, spread: float, digits: int = 3) -> str:
    """``"value ± spread"``, both to the decimals that give the larger of the two ``digits`` significant digits
    ("197 ± 110", "5.30 ± 0.12"); ``value`` alone when ``spread`` is not finite."""
    if not math.isfinite(spread) or not math.isfinite(value):
        return format_number(value, digits)
    scale = max(abs(value), abs(spread))
    if scale == 0.0:
        return "0 ± 0"
    if not 1e-4 <= scale < 1e9:
        return f"{value:.{digits - 1}e} ± {spread:.{digits - 1}e}"
    decimals = max(digits - 1 - math.floor(math.log10(scale)), 0)
    return f"{value:.{decimals}f} ± {spread:.{decimals}f}"


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
