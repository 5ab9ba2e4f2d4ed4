"""Excitation trajectories for identification: random rest-to-rest moves over the whole workspace.

Fast moves at high acceleration to random and edge points excite the inertia terms, slow moves at a
few mm/s excite friction near zero speed (docs/design.md section 7). A compliant drive's gearhead mode is seen
by a multisine torque at rest poses (:func:`multisine_torques`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from delta_env.geometry import DeltaGeometry
from delta_env.limits import WORKSPACE_LIMITS, WorkspaceLimits, edge_point, require_admissible, segment_admissible
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import (
    QUINTIC_PEAK_SPEED,
    STRESS_PEAK_ACCELERATION,
    WORKING_HEIGHT,
    Segment,
    Trajectory,
    require_peak_acceleration,
    require_sample_period,
    sample_segments,
)
from delta_env.validation import require_generator, require_in, require_interval, require_positive

MAX_DRAWS = 1000
"""Random draws allowed to find one admissible move before giving up."""

MIN_FAST_DISTANCE = 0.05
"""Shortest fast move (m): shorter ones would last only a few samples."""


def excitation_trajectory(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    duration: float,
    peak_acceleration: float = STRESS_PEAK_ACCELERATION,
    *,
    start: tuple[float, float, float] = (0.0, 0.0, WORKING_HEIGHT),
    min_acceleration_fraction: float = 0.2,
    edge_fraction: float = 0.3,
    slow_fraction: float = 0.2,
    slow_speed_range: tuple[float, float] = (0.005, 0.1),
    slow_duration_range: tuple[float, float] = (0.3, 1.0),
    dwell_range: tuple[float, float] = (0.0, 0.1),
    limits: WorkspaceLimits = WORKSPACE_LIMITS,
    dt: float = CONTROL_PERIOD,
) -> Trajectory:
    """Random rest-to-rest straight moves over the whole admissible workspace, for identification.

    Three kinds of moves, each a straight-line quintic followed by a random dwell:
    - fast, to a point drawn uniformly in ``limits`` with a peak |xdd| drawn uniformly in
      [min_acceleration_fraction, 1] * peak_acceleration;
    - fast to the workspace edge (probability ``edge_fraction`` among fast moves): a point on the
      boundary of ``limits`` (cylinder wall or singularity margin) at a random height and azimuth;
    - slow (probability ``slow_fraction``): a short move in a random direction whose peak speed is
      drawn log-uniformly in ``slow_speed_range``, to excite friction near zero speed.
    The trajectory has no gripper events. It lasts exactly ``duration``: a move that would not fit
    is dropped and the remaining time is spent at rest.

    Args:
        geometry: Robot geometry.
        rng: Source of all randomness.
        duration: Length of the trajectory (s), > 0.
        peak_acceleration: Largest peak |xdd| of a move (m/s^2), in (0, MAX_PEAK_ACCELERATION = 30 g].
        start: Initial rest position (m), inside ``limits``.
        min_acceleration_fraction: Smallest peak |xdd| of a fast move, relative, in (0, 1].
        edge_fraction: Probability that a fast move ends on the workspace edge, in [0, 1].
        slow_fraction: Probability that a move is slow, in [0, 1].
        slow_speed_range: (min, max) peak speed of slow moves (m/s), 0 < min <= max.
        slow_duration_range: (min, max) duration of slow moves (s), 0 < min <= max.
        dwell_range: (min, max) rest after each move (s), 0 <= min <= max.
        limits: Region and singularity margins every sample must respect.
        dt: Sample period (s).

    Raises:
        ValueError: on a bad argument or a start outside ``limits``.
    """
    require_generator(rng)
    require_sample_period(dt)
    require_positive("duration", duration, "s")
    require_peak_acceleration(peak_acceleration)
    require_in("min_acceleration_fraction", min_acceleration_fraction, 0.0, 1.0, low_open=True)
    require_in("edge_fraction", edge_fraction, 0.0, 1.0)
    require_in("slow_fraction", slow_fraction, 0.0, 1.0)
    for name, interval, unit in (
        ("slow_speed_range", slow_speed_range, "m/s"),
        ("slow_duration_range", slow_duration_range, "s"),
    ):
        low, _ = require_interval(name, interval, 0.0, unit=unit)
        require_in(f"{name}[0]", low, 0.0, unit=unit, low_open=True)
    require_interval("dwell_range", dwell_range, 0.0, unit="s")
    point = np.asarray(start, dtype=float)
    require_admissible(geometry, point[None], limits, "start point")

    segments: list[Segment] = []
    elapsed = 0.0
    while True:
        if rng.random() < slow_fraction:
            move_time = rng.uniform(*slow_duration_range)
            speed = math.exp(rng.uniform(math.log(slow_speed_range[0]), math.log(slow_speed_range[1])))
            target = _slow_target(geometry, rng, point, speed * move_time / QUINTIC_PEAK_SPEED, limits)
            move = Segment.line(point, target, move_time)
        else:
            on_edge = rng.random() < edge_fraction
            target = _fast_target(geometry, rng, point, limits, on_edge)
            acceleration = peak_acceleration * rng.uniform(min_acceleration_fraction, 1.0)
            move = Segment.line(point, target, 1.0).timed(acceleration)
        rest = rng.uniform(*dwell_range)
        if elapsed + move.duration > duration:
            break
        segments.append(move)
        point = move.end
        elapsed += move.duration
        if rest > 0.0 and elapsed < duration:
            segments.append(Segment.line(point, point, min(rest, duration - elapsed)))
            elapsed += segments[-1].duration
    if duration - elapsed > 0.0:
        segments.append(Segment.line(point, point, duration - elapsed))
    return sample_segments(geometry, segments, dt, events=[])


def _fast_target(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    point: np.ndarray,
    limits: WorkspaceLimits,
    on_edge: bool,
) -> np.ndarray:
    for _ in range(MAX_DRAWS):
        if on_edge:
            target = edge_point(geometry, rng, limits)
        else:
            radius = limits.radius * math.sqrt(rng.random())
            angle = rng.uniform(0.0, 2.0 * math.pi)
            xy = radius * np.array([math.cos(angle), math.sin(angle)])
            target = np.array([*xy, rng.uniform(limits.z_min, limits.z_max)])
        if (
            target is not None
            and np.linalg.norm(target - point) >= MIN_FAST_DISTANCE
            and segment_admissible(geometry, point, target, limits)
        ):
            return target
    raise ValueError(f"found no admissible move from {point.tolist()} m in {MAX_DRAWS} draws; limits {limits}")


def _slow_target(
    geometry: DeltaGeometry,
    rng: np.random.Generator,
    point: np.ndarray,
    distance: float,
    limits: WorkspaceLimits,
) -> np.ndarray:
    for _ in range(MAX_DRAWS):
        direction = rng.normal(size=3)
        target = point + distance * direction / np.linalg.norm(direction)
        if segment_admissible(geometry, point, target, limits):
            return target
    raise ValueError(f"found no admissible slow move from {point.tolist()} m in {MAX_DRAWS} draws")


MULTISINE_PERIOD = 0.2
"""Period (s) of the compliance excitation's multisine (:func:`multisine_torques`): 5 Hz between its lines."""

MULTISINE_BAND = (5.0, 300.0)
"""Band (Hz) of the compliance excitation's multisine: from the lowest line up to the gearhead modes of a compliant
drive (205 Hz locked, 257 Hz free at home for the SP+ 140). Not higher: the drive holds each command over the 1 ms
control period, whose images at 1 kHz - f alias back onto a line f of samples at 1 kHz; at 300 Hz they move the
rotor by 4 % of what the line does, at 450 Hz by 30 % (docs/measurements.md, "Compliant drives")."""


def multisine_torques(
    rng: np.random.Generator,
    rms: float,
    period: float = MULTISINE_PERIOD,
    band: tuple[float, float] = MULTISINE_BAND,
    dt: float = CONTROL_PERIOD,
) -> NDArray[np.float64]:
    """One period of a random-phase multisine per joint, to excite a compliant drive's modes (docs/design.md
    section 7, "Compliant drives").

    Every DFT line of the period inside ``band`` gets the same amplitude and a phase drawn uniformly, independently
    per joint (the joints' signals are uncorrelated); repeated, the signal is periodic, so a record of whole periods
    at steady state has no leakage and its derivatives follow exactly from its DFT.

    Args:
        rng: Source of the phases.
        rms: RMS torque per joint (N m), > 0.
        period: Period (s), a whole number of samples, > 2 ``dt``.
        band: (lowest, highest) line (Hz), 0 < lowest <= highest < 1 / (2 dt).
        dt: Sample period (s).

    Returns:
        Torques (N m), ``(round(period / dt), 3)``, zero mean.
    """
    require_generator(rng)
    require_sample_period(dt)
    require_positive("rms", rms, "N m")
    samples = round(require_positive("period", period, "s") / dt)
    if samples < 3 or abs(samples * dt - period) > 1e-9 * period:
        raise ValueError(f"period must be a whole number (>= 3) of {dt:g} s samples, got {period!r} s")
    low, high = require_interval("band", band, 0.0, 0.5 / dt, unit="Hz")
    frequencies = np.fft.rfftfreq(samples, dt)
    lines = np.flatnonzero((frequencies >= low) & (frequencies <= high) & (frequencies < 0.5 / dt))
    if lines.size == 0:
        raise ValueError(f"band {band} Hz holds no line of a {period:g} s period (lines every {1 / period:g} Hz)")
    spectrum = np.zeros((len(frequencies), 3), dtype=complex)
    spectrum[lines] = np.exp(2j * np.pi * rng.random((lines.size, 3)))
    signal = np.fft.irfft(spectrum, n=samples, axis=0)
    return signal * (rms / np.sqrt(np.mean(signal**2, axis=0)))
