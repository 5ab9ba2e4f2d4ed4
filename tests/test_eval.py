"""Evaluation: metric definitions on known signals, and ``python -m eval`` end to end on a tiny run."""

import csv
import dataclasses
import json
import math
from pathlib import Path

import imageio.v2 as imageio
import matplotlib.pyplot as plt
import numpy as np
import pytest

from controllers.base import PDController
from controllers.registry import CONTROLLER_LABELS, build_controller, estimation_model
from delta_env import NOMINAL_GEOMETRY
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL, standard_cycle
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import GRAVITY
from delta_env.release import Settle
from delta_env.scenario import Scenario, preset
from delta_env.trajectories import WORKING_HEIGHT, Segment, Trajectory
from eval import metrics
from eval.comparison.__main__ import main
from eval.comparison.run import TABLE2_KEY, table2_statistics
from eval.comparison.tables import (
    BOUND_HOLDS,
    bound_violations,
    controller_table,
    place_check_words,
    residual_gain,
)
from eval.episodes import EpisodeRecord, run_episode
from eval.fault_tables import FAULT_COLUMNS
from eval.identification.parameter_files import load_or_identify
from tests.conftest import pd_episode

DT = 1e-3

UNPLACED = "; the place error needs two episodes to be checked (paired, one-sided t-test)"
"""What the bound check says of rows without a place error."""


def estimate_with_excursions(mass: float, inside_from: int, excursion: tuple[int, int], length: int = 100) -> list:
    """An estimate (kg) outside +-5 % before ``inside_from`` and within ``excursion``, inside elsewhere."""
    estimate = np.full(length, mass)
    estimate[:inside_from] = 0.5 * mass
    estimate[excursion[0] : excursion[1]] = 1.1 * mass
    return estimate.tolist()


@pytest.mark.parametrize(
    ("inside_from", "excursion", "expected_ms"),
    [
        (30, (0, 0), 30.0),  # enters at 30 ms and stays
        (30, (50, 60), 60.0),  # leaves again from 50 to 59 ms: settled at 60 ms
        (0, (0, 0), 0.0),  # inside from the start
        (30, (90, 100), math.nan),  # outside at the end of the carry: never settled
    ],
)
def test_settling_time_is_the_last_entry_into_the_band(inside_from, excursion, expected_ms) -> None:
    estimate = [0.0] * 10 + estimate_with_excursions(2.0, inside_from, excursion) + [0.0] * 10
    (carry,) = metrics.carry_metrics(estimate, [10], [110], [2.0], DT)
    assert carry.settling_time_ms == pytest.approx(expected_ms, nan_ok=True)
    assert carry.end_estimate == estimate[109]
    assert carry.end_error_percent == pytest.approx(100.0 * (estimate[109] - 2.0) / 2.0)


def test_peak_estimate_is_the_largest_estimate_of_the_carry() -> None:
    estimate = [9.0] * 10 + estimate_with_excursions(2.0, 30, (50, 60)) + [9.0] * 10  # 9 kg outside the carry
    (carry,) = metrics.carry_metrics(estimate, [10], [110], [2.0], DT)
    assert carry.peak_estimate == pytest.approx(2.2)


def carry(mass: float, end: float, settling_ms: float = 50.0, peak: float | None = None) -> metrics.CarryMetrics:
    """A carry of ``mass`` (kg) whose estimate ends at ``end`` (kg)."""
    error = 100.0 * (end - mass) / mass if mass > 0.0 else math.nan
    return metrics.CarryMetrics(mass, end, error, settling_ms, end if peak is None else peak)


def test_payload_targets_count_every_carry_against_each_target() -> None:
    carries = [
        carry(2.0, 2.09),  # +4.5 %: within
        carry(2.0, 2.12, settling_ms=math.nan),  # +6 %: outside, never settled
        carry(0.5, 0.476, settling_ms=150.0),  # -4.8 %: within, settled just in time
        carry(1.0, 1.0, settling_ms=151.0, peak=1.21),  # settled too late; 21 % over 1 kg: over max(0.2 kg, 20 %)
        carry(3.0, 3.0, peak=3.59),  # 0.59 kg < 20 % of 3 kg: not over
        carry(0.3, 0.324, peak=0.5),  # +24 g: within; 0.2 kg over a light object: not over
        carry(0.2, 0.17, peak=0.41),  # -30 g: outside; 0.21 kg over: over
    ]
    targets = metrics.payload_targets(carries)
    assert targets.end_within_band == (4, 5)
    assert targets.light_within_band == (1, 2)
    assert targets.light_error_range_kg == pytest.approx((-0.03, 0.024))
    assert targets.overshoots == (2, 7)
    assert targets.settled == (3, 5)
    empty = metrics.payload_targets([carry(2.0, 2.0)])
    assert empty.light_within_band == (0, 0) and all(math.isnan(v) for v in empty.light_error_range_kg)


def test_payload_target_table_has_a_row_per_estimating_controller() -> None:
    from eval.comparison.tables import payload_target_table

    def row(label: str, item: metrics.CarryMetrics) -> dict:
        return {
            "controller": label,
            "mass_kg": item.mass,
            "end_estimate_kg": item.end_estimate,
            "end_error_percent": item.end_error_percent,
            "settling_time_ms": item.settling_time_ms,
            "peak_estimate_kg": item.peak_estimate,
        }

    rows = [row("A", carry(2.0, 2.09)), row("A", carry(0.2, 0.17, peak=0.41)), row("B", carry(2.0, 2.5))]
    table = payload_target_table(rows).splitlines()
    assert table[0].startswith("| Controller | End within ±5 % (≥ 0.5 kg) |")
    assert table[2] == "| A | 1/1 (100 %) | 0/1 (0 %) | -30, -30 | 1/2 (50 %) | 1/1 (100 %) |"
    assert table[3] == "| B | 0/1 (0 %) | n/a | n/a | 1/1 (100 %) | 1/1 (100 %) |"


def test_energy_counts_motor_work_in_both_directions() -> None:
    # 1 s at 10 N m and 2 rad/s driving on joint 1, braking (negative power) on joint 2: 20 J each.
    steps = 1000
    torque = np.tile([10.0, -10.0, 5.0], (steps, 1))
    velocity = np.tile([2.0, 2.0, 0.0], (steps, 1))
    assert metrics.mechanical_energy(torque, velocity, DT) == pytest.approx(40.0)


def test_tracking_and_torque_metrics() -> None:
    rms, peak = metrics.tracking_metrics([3e-3, -4e-3, math.nan])  # NaN: the step a simulation diverged
    assert (rms, peak) == pytest.approx((1e3 * math.sqrt(12.5e-6), 3.0))
    assert metrics.torque_metrics([[3.0, -4.0, 0.0]]) == pytest.approx((math.sqrt(25.0 / 3.0), 4.0))


def test_torque_error_statistics_are_per_joint() -> None:
    measured = np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]])
    mean, std = metrics.torque_error_statistics(measured, np.ones((2, 3)))
    np.testing.assert_allclose(mean, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(std, [1.0, 0.0, 1.0])


L_PATH = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
"""An L-shaped polyline (m): 1 m along x, then 1 m along y."""


def test_path_deviation_is_the_distance_to_the_nearest_segment() -> None:
    on_path = [[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.7, 0.0], [1.0, 1.0, 0.0]]
    assert metrics.path_deviation(on_path, L_PATH) == pytest.approx((0.0, 0.0), abs=1e-9)
    off_path = [
        [0.5, 0.003, 0.0],  # 3 mm beside the first leg
        [1.004, 0.5, 0.0],  # 4 mm beside the second leg
        [0.2, 0.0, -0.002],  # 2 mm below the first leg
        [1.003, -0.004, 0.0],  # 5 mm off the corner, beyond both legs' ends
        [math.nan, 0.0, 0.0],  # the step a simulation diverged: left out
    ]
    rms, peak = metrics.path_deviation(off_path, L_PATH)
    assert rms == pytest.approx(math.sqrt((9.0 + 16.0 + 4.0 + 25.0) / 4.0), rel=1e-9)
    assert peak == pytest.approx(5.0, rel=1e-9)


def _nearest_in_window(positions: np.ndarray, path: np.ndarray, index: np.ndarray, window: int) -> np.ndarray:
    """path_deviation's definition, one sample and one segment at a time (mm)."""
    distances = []
    for position, center in zip(positions, index, strict=True):
        nearest = math.inf
        for j in range(center - window, center + window + 1):
            start, end = path[min(max(j, 0), len(path) - 2)], path[min(max(j, 0), len(path) - 2) + 1]
            along = np.clip(np.dot(position - start, end - start) / np.dot(end - start, end - start), 0.0, 1.0)
            nearest = min(nearest, float(np.linalg.norm(position - start - along * (end - start))))
        distances.append(1e3 * nearest)
    return np.array(distances)


def test_path_deviation_searches_the_window_around_each_sample_clipped_to_the_path() -> None:
    # A random walk whose nearest segment lies a few segments from each sample's own index; indices also past both
    # ends of the path.
    rng = np.random.default_rng(7)
    path = np.cumsum(rng.normal(size=(40, 3)), axis=0)
    positions = path + 0.1 * rng.normal(size=path.shape)
    index = np.clip(np.arange(40) + rng.integers(-2, 3, size=40), 0, 39)
    index[:3], index[-3:] = (-60, -10, -1), (40, 45, 60)
    for window in (0, 1, 3, 12):
        expected = _nearest_in_window(positions, path, index, window)
        rms, peak = metrics.path_deviation(positions, path, index, window=window)
        assert (rms, peak) == pytest.approx((np.sqrt(np.mean(expected**2)), expected.max()), rel=1e-12)
    assert metrics.path_deviation(positions, path, index, window=60) == pytest.approx(
        metrics.path_deviation(positions, path), rel=1e-12
    )
    for path_, window in ((np.zeros((0, 3)), 5), (np.full((4, 3), math.nan), 5), (path, -1)):
        with pytest.raises(ValueError, match=r"path must|window must"):
            metrics.path_deviation(positions, path_, index, window=window)


def _nearest_segment_distances_numpy(
    positions: np.ndarray, starts: np.ndarray, ends: np.ndarray, centers: np.ndarray, window: int
) -> np.ndarray:
    """metrics._nearest_segment_distances's definition in NumPy, every segment of each window measured (m)."""
    distances = []
    for position, center in zip(positions, centers, strict=True):
        low = min(max(center - window, 0), len(starts) - 1)
        high = max(min(center + window, len(starts) - 1), low)
        d = ends[low : high + 1] - starts[low : high + 1]
        r = position - starts[low : high + 1]
        length2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        along = (r[:, 0] * d[:, 0] + r[:, 1] * d[:, 1] + r[:, 2] * d[:, 2]) / np.where(length2 > 0.0, length2, 1.0)
        g = r - np.clip(along, 0.0, 1.0)[:, None] * d
        distances.append(math.sqrt(np.min(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2])))
    return np.array(distances)


def test_nearest_segment_search_equals_measuring_every_segment() -> None:
    # Back-and-forth moves with dwells between them (repeated vertices), so that segments far apart in the window
    # are near in space; positions near the path, some far off, some indices past the ends; 16 does not divide the
    # segment count.
    rng = np.random.default_rng(11)
    legs = [np.linspace(a, b, 37) for a, b in ((0.0, 0.3), (0.3, 0.3), (0.3, -0.1), (-0.1, -0.1), (-0.1, 0.25))]
    x = np.concatenate([*legs, np.full(20, 0.25)])
    path = np.stack([x, 0.1 * np.sin(8.0 * x), np.full_like(x, -0.8)], axis=1)
    starts, ends = np.ascontiguousarray(path[:-1]), np.ascontiguousarray(path[1:])
    centers = np.clip(np.arange(len(path)) + rng.integers(-3, 4, size=len(path)), -20, len(path) + 20)
    positions = path + 1e-3 * rng.normal(size=path.shape)
    positions[::17] += 0.2 * rng.normal(size=positions[::17].shape)
    for window in (0, 5, 40, 100, 400):
        found = metrics._nearest_segment_distances(positions, starts, ends, centers, -window, window)
        assert np.array_equal(found, _nearest_segment_distances_numpy(positions, starts, ends, centers, window))


def test_path_deviation_does_not_score_a_lag_along_the_path() -> None:
    # A half circle of radius 0.1 m in 2001 samples; the platform runs 2 mm outside it, 30 samples late.
    angle = np.linspace(0.0, math.pi, 2001)
    circle = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
    index = np.arange(30, len(angle))
    positions = 0.102 * circle[index - 30]
    rms, peak = metrics.path_deviation(positions, 0.1 * circle, index, window=40)
    # the chords lie within 0.1 m (1 - cos(pi / 4000)) = 0.03 um inside the circle
    assert (rms, peak) == pytest.approx((2.0, 2.0), abs=1e-3)
    # the same lag as a tracking error: about 30 samples of arc, 4.7 mm
    assert 1e3 * np.linalg.norm(positions[0] - 0.1 * circle[30]) > 4.0


@pytest.mark.parametrize("start", ["place", "pick"])
def test_pick_rate_and_cycle_times_of_the_standard_cycle(start: str) -> None:
    acceleration, dwell, lift_fraction, cycles = 4.0 * GRAVITY, 0.08, 0.3, 3
    reference = standard_cycle(
        NOMINAL_GEOMETRY, acceleration, n_cycles=cycles, dwell=dwell, lift_fraction=lift_fraction, start=start
    )
    pick = np.array([0.0, -0.5 * STANDARD_TRAVEL, WORKING_HEIGHT])
    place = np.array([0.0, 0.5 * STANDARD_TRAVEL, WORKING_HEIGHT])
    there = Segment(pick, place, 1.0, STANDARD_LIFT, lift_fraction).timed(acceleration).duration
    back = Segment(place, pick, 1.0, STANDARD_LIFT, lift_fraction).timed(acceleration).duration
    cycle = 2.0 * dwell + there + back  # dwell at the pick, carry, dwell at the place, return
    dt = reference.dt
    # Sample times round the arrivals up to the next sample, the end of the reference too: within one sample.
    times = metrics.cycle_times(reference.xyz_dot, reference.pick_indices, dt)
    np.testing.assert_allclose(times, cycle, atol=dt + 1e-9)
    expected_rate = 60.0 * cycles / (cycles * cycle)
    rate = metrics.picks_per_min(reference.xyz_dot, reference.pick_indices, dt)
    assert rate == pytest.approx(expected_rate, abs=expected_rate * dt / cycle)
    # From a place point the episode rests half a dwell, then returns to the first pick point.
    arrival = 0.0 if start == "pick" else 0.5 * dwell + back
    assert metrics.arrivals(reference.xyz_dot, reference.pick_indices)[0] * dt == pytest.approx(arrival, abs=dt)


def test_a_pick_must_lie_at_rest() -> None:
    velocity = np.zeros((10, 3))
    velocity[4:7, 0] = 0.1
    np.testing.assert_array_equal(metrics.arrivals(velocity, [2, 8]), [0, 7])
    assert math.isnan(metrics.picks_per_min(velocity, [], 1e-3)) and metrics.cycle_times(velocity, [], 1e-3).size == 0
    with pytest.raises(ValueError, match="moves at an event"):
        metrics.arrivals(velocity, [5])


def test_torque_ratios_and_envelope_violations() -> None:
    # joint 1: 100 N m RMS; joint 2: one 300 N m step in four, 150 N m RMS; joint 3 idle
    torque = [[100.0, 300.0, 0.0], [-100.0, 0.0, 0.0], [100.0, 0.0, 0.0], [-100.0, 0.0, 0.0]]
    assert metrics.torque_ratios(torque, peak_torque=400.0, rated_torque=128.0) == pytest.approx(
        (0.75, 150.0 / 128.0), rel=1e-12
    )
    assert metrics.envelope_violations(3, 2) == 5


def constructed_record(reference: Trajectory, platform: np.ndarray, torque: np.ndarray, **fields) -> EpisodeRecord:
    """A record of ``len(platform)`` steps following ``reference``, zero elsewhere, with ``fields`` set."""
    steps = len(platform)
    zeros = np.zeros((steps, 3))
    record = EpisodeRecord(
        tracking_error=np.linalg.norm(platform - reference.xyz[1 : steps + 1], axis=1),
        torque=torque,
        command=torque,
        joint_velocity=zeros,
        joint_error=zeros,
        payload_mass=np.zeros(steps + 1),
        payload_estimate=np.zeros(steps),
        measured_torque=np.zeros((steps + 1, 3)),
        encoder_angles=np.zeros((steps + 1, 3)),
        pick_indices=reference.pick_indices,
        place_indices=reference.place_indices,
        masses=np.ones(len(reference.pick_indices)),
        diverged=False,
        saturated_steps=0,
        max_loop_gap=0.0,
        platform_position=platform,
        reference=reference,
        peak_torque=400.0,
        rated_torque=128.0,
    )
    return dataclasses.replace(record, **fields)


def test_episode_metrics_score_the_pick_rate_the_placements_and_the_drive() -> None:
    reference = standard_cycle(NOMINAL_GEOMETRY, n_cycles=2, start="pick")
    platform = reference.xyz[1:].copy()  # step n ends at reference sample n + 1
    first, second = reference.place_indices
    # Sideways (x) off the place points as the gripper opens: the path runs in the plane x = 0.
    platform[first - 1] += [0.005, 0.0, 0.0]  # 5 mm off the first place point
    platform[second - 1] += [-0.001, 0.0, 0.0]  # 1 mm off the second
    torque = np.zeros((len(platform), 3))
    torque[0] = [-200.0, 0.0, 0.0]
    record = constructed_record(reference, platform, torque, saturated_steps=2, speed_exceeded_steps=1)
    scores = record.metrics()
    np.testing.assert_allclose(record.place_errors(), [5.0, 1.0], rtol=1e-9)
    assert (scores["place_error_max_mm"], scores["place_error_mean_mm"]) == pytest.approx((5.0, 3.0), rel=1e-9)
    # two single samples off the path, 5 and 1 mm
    assert scores["path_deviation_max_mm"] == pytest.approx(5.0, rel=1e-9)
    assert scores["path_deviation_rms_mm"] == pytest.approx(math.sqrt(26.0 / len(platform)), rel=1e-9)
    times = metrics.cycle_times(reference.xyz_dot, reference.pick_indices, reference.dt)
    assert scores["cycle_time_mean_s"] == pytest.approx(np.mean(times))
    assert scores["picks_per_min"] == pytest.approx(60.0 / np.mean(times))
    assert scores["envelope_violations"] == 3
    assert scores["peak_torque_ratio"] == pytest.approx(0.5)
    rms_ratio = 200.0 / math.sqrt(len(platform)) / 128.0
    assert (scores["rms_torque_ratio"], scores["thermal_margin"]) == pytest.approx((rms_ratio, 1.0 - rms_ratio))


def test_peak_to_peak_is_the_largest_distance_between_two_positions() -> None:
    t = np.arange(30) * 1e-3
    ring = np.column_stack([3e-6 * np.sin(2 * np.pi * 220.0 * t), np.zeros_like(t), np.full_like(t, -0.9)])
    assert metrics.peak_to_peak(ring) == pytest.approx(np.ptp(ring[:, 0]), rel=1e-12)  # one axis: its peak to peak
    circle = np.column_stack(
        [2e-6 * np.cos(np.linspace(0, 2 * np.pi, 41)), 2e-6 * np.sin(np.linspace(0, 2 * np.pi, 41))]
    )
    assert metrics.peak_to_peak(np.column_stack([circle, np.zeros(41)])) == pytest.approx(4e-6, rel=1e-9)  # diameter
    assert math.isnan(metrics.peak_to_peak(np.zeros((0, 3)))) and math.isnan(metrics.peak_to_peak([[0.0, 0, math.nan]]))


def test_the_residual_vibration_is_the_peak_to_peak_from_the_in_position_signal_to_the_window_end() -> None:
    """A platform that rings at a known amplitude inside each place's window (from the in-position signal on, for
    :data:`eval.metrics.RESIDUAL_WINDOW`) and moves far more before it (the approach) and from the release on: the
    residual vibration is the ring's peak to peak; a window that reaches the release is cut there; the pick's wait
    is not a place."""
    reference = standard_cycle(NOMINAL_GEOMETRY, n_cycles=2, start="pick")
    platform = reference.xyz[1:].copy()
    window = round(metrics.RESIDUAL_WINDOW / reference.dt)
    settles, expected = [], []
    for cycle, (place, amplitude) in enumerate(zip(reference.place_indices, (2e-6, 5e-6), strict=True)):
        arrival = place - 40  # at rest from 40 samples before the release
        signal = arrival + 3  # a settle time of 3 ms
        settles += [Settle("pick", cycle, arrival - 200, 0.05, True), Settle("place", cycle, arrival, 0.003, False)]
        platform[arrival - 200 : arrival - 150, 1] += 1e-2  # large motion at the pick: no place
        platform[arrival - 1 : signal - 1, 0] += 1e-3  # the approach: 1 mm off until the signal
        ring = amplitude * np.sin(2 * np.pi * 220.0 * np.arange(window) * reference.dt + 0.3)
        platform[signal - 1 : signal - 1 + window, 0] += ring
        platform[place - 1 : place + 20, 2] += 1e-3  # the release's step, from reference sample ``place`` on
        expected.append(1e6 * np.ptp(ring))
    assert expected == pytest.approx([4.0, 10.0], rel=0.02)  # about twice the amplitudes (um)
    zero = np.zeros((len(platform), 3))
    record = constructed_record(reference, platform, zero, settles=settles)
    np.testing.assert_allclose(record.residual_vibrations(), expected, rtol=1e-9)
    scores = record.metrics()
    assert scores["residual_vibration_mean_um"] == pytest.approx(np.mean(expected), rel=1e-9)
    assert scores["residual_vibration_max_um"] == pytest.approx(max(expected), rel=1e-9)
    # in position 35 ms after the arrival: the window, 5 samples at rest, ends at the release, not 25 samples later
    late = [dataclasses.replace(settle, settle_time=0.035) for settle in settles]
    cut = constructed_record(reference, platform, zero, settles=late).residual_vibrations()
    np.testing.assert_allclose(cut, 0.0, atol=1e-6)
    # the timed release waits nowhere: no residual vibration
    assert math.isnan(constructed_record(reference, platform, zero).metrics()["residual_vibration_mean_um"])


def test_diverged_episodes_are_counted_and_left_out_of_the_means() -> None:
    rows = [
        {"controller": "PD", "diverged": False, "tracking_rms_mm": 1.0},
        {"controller": "PD", "diverged": True, "tracking_rms_mm": 100.0},
        {"controller": "PD", "diverged": False, "tracking_rms_mm": 3.0},
    ]
    for row in rows:
        row.update(tracking_max_mm=1.0, torque_rms_nm=1.0, torque_peak_nm=1.0, energy_j=1.0)
    table = controller_table(rows, [])
    line = table.splitlines()[2]
    assert line.startswith("| PD | 3 (1) | 2.00 ± 1.41 |")


def test_table2_analogue_payload_estimate_shrinks_the_torque_error_spread(controller_setup) -> None:
    # MId+F+R+RLS (untared) carrying 3.8 kg: the paper's Table 2, tau_model at mp = 0 against mp = m_hat.
    setup = dataclasses.replace(controller_setup, mid=controller_setup.mid_f)
    env = DeltaPickPlaceEnv(n_cycles=1)
    record = run_episode(env, build_controller(TABLE2_KEY, setup), seed=2, payload_masses=[3.8])
    rows = table2_statistics(record.model_torques(estimation_model(setup)))
    # Measured: std 6.25, 15.04, 10.82 N m with mp = 0 and 2.29, 2.62, 3.02 N m with m_hat (ratios 0.37, 0.17, 0.28;
    # seed 4: 0.35, 0.17, 0.26); means 0.28, -0.36, -0.33 N m with m_hat. The bounds are 1.5 times those ratios.
    for row, ratio in zip(rows, (0.55, 0.26, 0.42), strict=True):
        assert row["mp_hat_std"] <= ratio * row["mp_0_std"]
        assert abs(row["mp_hat_mean"]) < 0.7


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


@pytest.mark.slow
def test_eval_cli_end_to_end(parameter_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    argv = ["--episodes", "1", "--cycles", "1", "--controllers", "pd,mid_f_rls", "--out", str(out)]
    argv += ["--parameters", str(parameter_file), "--calibration-episodes", "1", "--seed", "4", "--scenario", "paper"]
    argv += ["--runs-dir", str(tmp_path / "runs")]
    assert main(argv) == 0

    printed = capsys.readouterr().out
    assert printed.startswith("# Controller comparison, scenario paper:")
    assert Scenario.load(out / "scenario.toml") == preset("paper")
    assert "| Controller |" in printed and "| PD | 1 (0) |" in printed and "| MId+F+R+RLS+PD | 1 (0) |" in printed
    assert "Table 2 analogue" in printed
    assert "## Payload targets" in printed and "| MId+F+R+RLS+PD | 1/1 (100 %) |" in printed
    assert "## Pick rate" in printed and "| PD | " in printed.split("## Pick rate")[1]
    assert (out / "summary.md").read_text() == printed

    episodes = read_csv(out / "episodes.csv")
    assert [row["key"] for row in episodes] == ["pd", "mid_f_rls"]
    assert all(row["seed"] == "4" and row["diverged"] == "False" for row in episodes)
    rms = {row["key"]: float(row["tracking_rms_mm"]) for row in episodes}
    assert rms["mid_f_rls"] <= 0.025 * rms["pd"]  # measured 0.091 against 6.39 mm: 0.014
    # the paper's standard cycle, under a second per object, from rest at the pick point: the PD's friction band times
    # out the in-position wait at the place, the servo layer settles there, and so picks faster
    pd_row, servo_row = episodes
    assert int(pd_row["settle_timeouts"]) == 1 and int(servo_row["settle_timeouts"]) == 0
    # measured 85.3 and 89.4 picks/min: the servo layer 4.8 % faster
    assert float(pd_row["picks_per_min"]) == pytest.approx(85.3, rel=0.1)
    assert float(servo_row["picks_per_min"]) >= 1.03 * float(pd_row["picks_per_min"])
    (carry,) = read_csv(out / "carries.csv")
    assert carry["key"] == "mid_f_rls" and float(carry["mass_kg"]) == 3.8  # the paper's payload on every pick
    table2 = read_csv(out / "table2.csv")
    assert [row["joint"] for row in table2] == ["1", "2", "3"]
    # the payload estimate cuts the model's torque spread: measured ratios 0.45, 0.16, 0.15
    for row, ratio in zip(table2, (0.67, 0.25, 0.22), strict=True):
        assert float(row["mp_hat_std"]) <= ratio * float(row["mp_0_std"])
    # no fault injected and none detected: faults.csv has its header only, the summary no Faults section
    assert (out / "faults.csv").read_text().strip() == ",".join(FAULT_COLUMNS)
    assert "## Faults" not in printed
    assert all(row["faults_injected"] == "0" and row["false_alarms"] == "0" for row in episodes)

    written = json.loads((out / "config.json").read_text())
    assert written["command"].endswith("-m eval " + " ".join(argv))
    assert {"versions", "git_commit", "started"} <= set(written)
    config = written["config"]
    assert config["arguments"]["controllers"] == ["pd", "mid_f_rls"]
    assert config["scenario"]["name"] == "paper" and config["env"]["cycle"] == "standard"
    assert config["episode_seeds"] == [4] and config["identification"]["path"] == str(parameter_file)
    assert set(written["results"]["tare_kg"]) == {"mid_f_rls"}

    with np.load(out / "traces.npz") as traces:
        assert list(traces["keys"]) == ["pd", "mid_f_rls"]
        assert traces["mid_f_rls.torque"].shape[1] == 3
        # the platform's path against the reference of the same instants: the tracking error, step for step
        platform, reference = traces["pd.platform_position"], traces["pd.reference_xyz"]
        assert platform.shape == reference.shape == (int(episodes[0]["steps"]), 3)
        deviation = np.linalg.norm(platform - reference, axis=1)
        np.testing.assert_allclose(deviation, traces["pd.tracking_error"], atol=1e-12)
        assert list(traces["pd.pick_indices"]) and len(traces["pd.place_indices"]) == 1
    for name in ("torque_profiles", "table2_torques", "payload_estimate", "error_bars", "tracking_error", "paths_3d"):
        image = plt.imread(out / f"{name}.png")
        assert image.ndim == 3 and min(image.shape[:2]) > 200
    assert not (out / "fault_timeline.png").exists() and not list(out.glob("video_*"))  # no faults, no --video


@pytest.mark.slow
def test_eval_cli_films_the_first_episode_of_each_row(
    parameter_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture, opengl_context: None
) -> None:
    out = tmp_path / "run"
    argv = ["--episodes", "1", "--cycles", "1", "--controllers", "pd", "--out", str(out), "--video", "--seed", "2"]
    argv += ["--parameters", str(parameter_file), "--calibration-episodes", "1", "--runs-dir", str(tmp_path / "runs")]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    (row,) = read_csv(out / "episodes.csv")
    duration = int(row["steps"]) * 1e-3
    with imageio.get_reader(out / "video_pd.mp4") as reader:
        frames, meta = reader.count_frames(), reader.get_meta_data()
    assert frames == math.floor(duration * 30.0 + 1e-9) + 1 and meta["fps"] == 30.0 and meta["size"] == (960, 720)
    assert f"- video_pd.mp4: {frames} frames at 30 fps, 960 x 720 px, {duration:.2f} s of episode" in printed
    assert json.loads((out / "config.json").read_text())["results"]["videos"] == ["video_pd.mp4"]


def test_help_lists_every_controller_key_beside_its_label(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    listing = capsys.readouterr().out.split("controllers (--controllers key: row label):")[1].splitlines()[1:]
    assert [line.split(maxsplit=1) for line in listing] == [[key, label] for key, label in CONTROLLER_LABELS.items()]


@pytest.mark.slow
def test_default_comparison_meets_the_projects_targets(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The acceptance targets of the controller comparison, on 3 default episodes after a 4-trajectory identification.

    Targets: the RLS controller tracks within 0.2 x PD; no controller tracks better than the oracle bound (it
    inverts mechanism and drive exactly, so this is an invariant, not a target); the residual policy cuts its
    base's (the lag-compensated RLS controller's) tracking RMS by at least 15 % for at most +5 % torque RMS;
    every estimate of an object of 0.5 kg or more is within +-5 % by 150 ms after its pick; the payload estimate
    cuts the spread of tau_measured - tau_model to at most 0.6 of its value with mp = 0 on every joint (the
    paper's Table 2).
    """
    folder = tmp_path_factory.mktemp("comparison")
    parameters = folder / "parameters.json"
    load_or_identify(parameters, n_trajectories=4, progress=False)
    out = folder / "run"
    main(["--episodes", "3", "--parameters", str(parameters), "--out", str(out), "--runs-dir", str(folder / "runs")])

    episodes = read_csv(out / "episodes.csv")
    assert all(row["diverged"] == "False" for row in episodes)

    def mean(key: str, column: str) -> float:
        return float(np.mean([float(row[column]) for row in episodes if row["key"] == key]))

    tracking = {key: mean(key, "tracking_rms_mm") for key in {row["key"] for row in episodes}}
    assert tracking["mid_f_rls"] <= 0.2 * tracking["pd"]
    assert min(tracking, key=tracking.__getitem__) == "oracle", tracking
    assert tracking["residual"] <= 0.85 * tracking["mid_f_rls_lag"], "the residual adds >= 15 % over its base"
    assert mean("residual", "torque_rms_nm") <= 1.05 * mean("mid_f_rls_lag", "torque_rms_nm")
    carries = [row for row in read_csv(out / "carries.csv") if row["key"] in ("mid_f_rls", "residual")]
    scored = [row for row in carries if float(row["mass_kg"]) >= metrics.MIN_RELATIVE_MASS]
    assert scored and all(float(row["settling_time_ms"]) <= 150.0 for row in scored)
    for row in read_csv(out / "table2.csv"):
        assert float(row["mp_hat_std"]) <= 0.6 * float(row["mp_0_std"])


def bound_row(
    label: str, seed: int, rms: float, diverged: bool = False, clipped: int = 0, fast: int = 0, faults: int = 0
) -> dict:
    """An episode row of the bound check: tracking RMS (mm), steps the drive clipped and steps beyond its speed,
    faults injected. A label that is no built-in row's ("A", "B") stands for a plain controller's row."""
    keys = {row_label: key for key, row_label in CONTROLLER_LABELS.items()}
    return {
        "key": keys.get(label, "mid"),
        "controller": label,
        "seed": seed,
        "tracking_rms_mm": rms,
        "diverged": diverged,
        "saturated_steps": clipped,
        "speed_exceeded_steps": fast,
        "faults_injected": faults,
    }


def test_bound_check_names_every_controller_below_the_oracle_and_ignores_diverged_episodes() -> None:
    from eval.comparison.report import bound_section

    row = bound_row

    bound = "Oracle+PD (bound)"
    holds = [row(bound, 0, 0.03), row(bound, 1, 0.05), row("PD", 0, 6.0), row("MId+F+R+RLS+lag+PD", 1, 0.051)]
    holds_line = BOUND_HOLDS.format(bound=bound, places=UNPLACED)
    assert bound_section(holds) == [holds_line, ""]
    # Mean 0.035 < 0.04: a violation, and so is its episode 1 (0.04 < 0.05); a diverged episode's short record
    # counts neither in the mean nor as an episode.
    broken = [*holds, row("A", 0, 0.03), row("A", 1, 0.04), row("A", 2, 0.001, diverged=True)]
    section = bound_section(broken)
    assert section[0] == "## Bound violated" and len(section) == 5
    assert "A tracks at 0.035 mm RMS, below Oracle+PD (bound) at 0.040 mm" in section[2]
    assert "A tracks episode 1 at 0.040 mm RMS, below Oracle+PD (bound) at 0.050 mm on the same episode" in section[3]
    # A mean above the bound's still violates it on an episode the controller tracked better.
    one_episode = [*holds, row("B", 0, 0.02), row("B", 1, 0.09)]
    assert bound_section(one_episode)[2:] == [
        "- B tracks episode 0 at 0.020 mm RMS, below Oracle+PD (bound) at 0.030 mm on the same episode",
        "",
    ]
    assert bound_section([row("PD", 0, 6.0)]) == []  # no oracle row, nothing to check


def test_bound_check_skips_the_oracle_episodes_the_drive_limited() -> None:
    """An oracle episode whose commands the drive clipped, or in which a joint exceeded the drive's speed, is no
    bound: its seed leaves the check (mean and episodes) for every controller, and the summary says so."""
    from eval.comparison.report import bound_section

    bound = "Oracle+PD (bound)"
    rows = [
        bound_row(bound, 0, 0.03),
        bound_row(bound, 1, 0.50, clipped=12),
        bound_row(bound, 2, 0.04, fast=3),
        bound_row("A", 0, 0.031),
        bound_row("A", 1, 0.10),  # better than the clipped oracle on its episode, and in the mean over all three
        bound_row("A", 2, 0.035),
    ]
    note = (
        f"Not a bound on episode(s) 1, 2: the drive clipped {bound}'s command on 12, 0 steps and a joint was beyond "
        "the drive's maximum speed on 0, 3 steps; the bound check skips these episodes."
    )
    holds = BOUND_HOLDS.format(bound=bound, places=UNPLACED)
    assert bound_section(rows) == [note, "", holds, ""]
    rows[3] = bound_row("A", 0, 0.02)  # episode 0 is still checked
    assert bound_section(rows)[2] == "## Bound violated"
    assert bound_section(rows[1:3]) == [note, ""]  # no episode left to check


def test_bound_check_skips_the_oracle_episodes_with_an_injected_fault() -> None:
    """The oracle knows the fault-free plant and the payloads: on an episode with an injected fault it is no bound,
    and the check skips that seed for every controller."""
    from eval.comparison.report import bound_section
    from eval.comparison.tables import unbounded_episodes

    bound = "Oracle+PD (bound)"
    rows = [
        bound_row(bound, 0, 0.03),
        bound_row(bound, 1, 0.90, faults=2),
        bound_row(bound, 2, 0.50, clipped=4),
        bound_row("A", 0, 0.031, faults=0),
        bound_row("A", 1, 0.20, faults=2),  # better than the oracle on its fault episode
        bound_row("A", 2, 0.60),
    ]
    assert [row["seed"] for row in unbounded_episodes(rows, bound)] == [1, 2]
    clipped = (
        f"Not a bound on episode(s) 2: the drive clipped {bound}'s command on 4 steps and a joint was beyond "
        "the drive's maximum speed on 0 steps; the bound check skips these episodes."
    )
    faulted = (
        f"Not a bound on episode(s) 1: 2 fault(s) were injected, and {bound} knows the fault-free plant and the "
        "payloads; the bound check skips these episodes."
    )
    holds = BOUND_HOLDS.format(bound=bound, places=UNPLACED)
    assert bound_section(rows) == [clipped, "", faulted, "", holds, ""]
    assert bound_section(rows[1:2]) == [faulted, ""]  # no episode left to check


def test_run_episode_records_the_largest_loop_gap() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    record = run_episode(env, PDController(), seed=4, payload_masses=[1.0])
    # the same seeded episode stepped by hand: the record holds the largest gap the env reported
    steps = pd_episode(env, 4, {"payload_masses": [1.0]}, max_steps=len(record.tracking_error))
    gaps = [step.info["loop_gap"] for step in steps]
    env.close()
    assert record.max_loop_gap == max(gaps)
    assert 0.0 < record.max_loop_gap < 1e-5  # measured 6.4 um: the realistic plant's loops stay closed


def test_residual_gain_compares_the_residual_with_its_base_on_the_episodes_both_completed() -> None:
    def row(label: str, seed: int, tracking: float, torque: float, diverged: bool = False) -> dict:
        return {
            "controller": label,
            "seed": seed,
            "tracking_rms_mm": tracking,
            "torque_rms_nm": torque,
            "diverged": diverged,
        }

    rows = [
        row("base", 0, 0.40, 20.0),
        row("base", 1, 0.20, 20.0),
        row("res", 0, 0.30, 20.6),
        row("res", 1, 0.15, 21.2),
        row("res", 2, 9.0, 90.0, diverged=True),
        row("base", 2, 0.30, 20.0),
    ]
    (met,) = (line for line in residual_gain(rows, "res", "base") if line)
    assert "tracking RMS -25.0 %" in met and "torque RMS +4.5 %" in met and "; met)" in met
    rows[3]["torque_rms_nm"] = 21.6
    (missed,) = (line for line in residual_gain(rows, "res", "base") if line)
    assert "torque RMS +5.5 %" in missed and "not met" in missed
    assert residual_gain(rows, "res", "absent") == []


@pytest.mark.parametrize(
    "module", ["eval.comparison.__main__", "eval.sweep.__main__", "eval.rate.__main__", "eval.design.__main__"]
)
def test_episode_seeds_may_not_reach_the_tare_seeds(module: str, capsys: pytest.CaptureFixture) -> None:
    import importlib

    from eval.calibration import CALIBRATION_SEED_OFFSET

    parse_args = importlib.import_module(module).parse_args
    last = CALIBRATION_SEED_OFFSET - 1
    assert parse_args(["--seed", str(last - 1), "--episodes", "2"]).seed == last - 1  # seeds up to 99999: fine
    with pytest.raises(SystemExit):
        parse_args(["--seed", str(last), "--episodes", "2"])
    assert f"reaches seed {CALIBRATION_SEED_OFFSET}" in capsys.readouterr().err


def test_bound_check_names_a_controller_that_places_closer_than_the_oracle() -> None:
    """The bound is a bound on the place error too (the oracle runs the rows' servo layer): a mean place error
    significantly below the bound's on the same episodes is named; a difference within the scatter that the encoders'
    quantization gives both, or on a single episode, is not; rows without a place error (no release) are not
    checked."""
    bound = "Oracle+PD (bound)"

    def placed(label: str, seed: int, tracking: float, place: float) -> dict[str, object]:
        return {**bound_row(label, seed, tracking), "place_error_mean_mm": place}

    rows = [placed(bound, 0, 0.01, 0.006), placed(bound, 1, 0.01, 0.008), placed("A", 0, 0.05, 0.02)]
    assert bound_violations(rows, bound) == []
    rows += [placed("B", 0, 0.05, 0.004), placed("B", 1, 0.06, 0.006)]  # closer by 2 µm on both: no scatter
    assert bound_violations(rows, bound) == [
        f"- B places at 0.005 mm on average, closer than {bound} at 0.007 mm on the same 2 episodes (one-sided "
        "paired t-test, p = 0): the bound does not hold"
    ]
    single = [placed(bound, 0, 0.01, 0.006), placed("C", 0, 0.05, 0.005)]  # a quarter count on one episode
    assert bound_violations(single, bound) == []
    assert place_check_words(single, bound) == UNPLACED  # and the summary says it was not checked
    assert place_check_words(rows, bound).startswith(", nor places closer on average")
    rng = np.random.default_rng(0)
    bound_places = rng.uniform(0.004, 0.012, 10)
    scattered = [placed(bound, seed, 0.01, place) for seed, place in enumerate(bound_places)]
    noise = [placed("D", seed, 0.05, place + rng.normal(0.0, 0.003)) for seed, place in enumerate(bound_places)]
    noise[0]["place_error_mean_mm"] = bound_places[0] - 0.004  # its mean below the bound's, within the scatter
    assert bound_violations(scattered + noise, bound) == []
    closer = [placed("E", seed, 0.05, place - 0.003 + rng.normal(0, 0.001)) for seed, place in enumerate(bound_places)]
    (line,) = bound_violations(scattered + closer, bound)
    assert line.startswith("- E places at") and "same 10 episodes" in line
    assert bound_violations([bound_row(bound, 0, 0.01), bound_row("C", 0, 0.02)], bound) == []
