"""Timed cycles: moves timed by a MoveTiming keep the fixed timing's path, dwells and events; online retiming."""

from __future__ import annotations

import math

import numpy as np
import pytest

from delta_env.cycles import conveyor_cycles, standard_cycle
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.scenario import PickPlaceTask, Scenario
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timed_cycles import TimedCycles
from delta_env.timing import TimeLaw, move_samples
from delta_env.trajectories import Segment, evaluate_segments, quintic

DT = CONTROL_PERIOD


def quintic_law(duration: float) -> TimeLaw:
    """tau(t) = s(t / T), the fixed timing's blend, on a whole number of samples (T rounded to dt)."""
    samples = round(duration / DT)
    duration = samples * DT
    s, ds, dds = quintic(np.arange(samples + 1) * DT / duration)
    s[-1] = 1.0
    return TimeLaw(DT, s, ds / duration, dds / duration**2)


class QuinticTiming:
    """Carries take (1 + m / 4) times as long as empty moves; optionally retimes each carry once, at ``retime_at``."""

    def __init__(self, duration: float = 0.3, retime_at: int | None = None) -> None:
        self.duration = duration
        self.retime_at = retime_at
        self.retimes_online = retime_at is not None
        self.declared: list[float] = []
        self.retimed: list[int] = []

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        self.declared.append(declared_mass)
        return quintic_law(self.duration * (1.0 + declared_mass / 4.0))

    def empty(self, shape: Segment) -> TimeLaw:
        return quintic_law(self.duration)

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        if index != self.retime_at:
            return None
        self.retimed.append(index)
        # hold the reached tau for the rest of a shorter move: same past, then a quintic from there to 1
        rest = quintic_law(0.2)
        tau = np.concatenate((law.tau[: index + 1], law.tau[index] + (1.0 - law.tau[index]) * rest.tau[1:]))
        tau_dot = np.concatenate((law.tau_dot[: index + 1], (1.0 - law.tau[index]) * rest.tau_dot[1:]))
        tau_ddot = np.concatenate((law.tau_ddot[: index + 1], (1.0 - law.tau[index]) * rest.tau_ddot[1:]))
        return TimeLaw(DT, tau, tau_dot, tau_ddot)


def test_a_linear_time_law_reproduces_the_fixed_timing_of_a_move() -> None:
    shape = Segment(np.array([0.0, -0.15, -0.9]), np.array([0.0, 0.15, -0.9]), 1.0, 0.025, 0.3)
    duration = 0.25
    samples = round(duration / DT) + 1
    law = TimeLaw(DT, np.linspace(0.0, 1.0, samples), np.full(samples, 1.0 / duration), np.zeros(samples))
    xyz, xyz_dot, xyz_ddot = move_samples(shape, law)
    timed = Segment(shape.start, shape.end, duration, shape.lift_height, shape.lift_fraction)
    expected = evaluate_segments([timed], np.zeros(len(law), dtype=int), np.arange(len(law)) * DT)
    for got, want in zip((xyz, xyz_dot, xyz_ddot), expected, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)


@pytest.mark.parametrize("start", ["place", "pick"])
def test_timed_cycles_keep_the_stations_dwells_and_events(start: str) -> None:
    timing = QuinticTiming()
    masses = [0.0, 4.0]
    planned = standard_cycle(NOMINAL_GEOMETRY, n_cycles=2, start=start, timing=timing, declared_masses=masses)
    fixed = standard_cycle(NOMINAL_GEOMETRY, n_cycles=2, start=start)
    assert isinstance(planned, TimedCycles)
    assert timing.declared == masses
    trajectory = planned.trajectory()
    np.testing.assert_allclose(trajectory.xyz[trajectory.pick_indices], fixed.xyz[fixed.pick_indices], atol=1e-12)
    np.testing.assert_allclose(trajectory.xyz[trajectory.place_indices], fixed.xyz[fixed.place_indices], atol=1e-12)
    # the 4 kg carry takes twice the 0 kg one: 0.3 s more between its pick and its place
    pick_to_place = (trajectory.place_indices - trajectory.pick_indices) * DT
    np.testing.assert_allclose(pick_to_place, [0.1 + 0.3, 0.1 + 0.6], atol=1e-9)
    # at rest around every event, and the gripper holds exactly between pick and place
    for index in (*trajectory.pick_indices, *trajectory.place_indices):
        assert np.all(trajectory.xyz_dot[index - 40 : index + 40] == 0.0)
    assert trajectory.gripper.sum() == np.sum(trajectory.place_indices - trajectory.pick_indices)


def test_timed_cycles_need_one_declared_mass_per_cycle_and_whole_sample_dwells() -> None:
    with pytest.raises(ValueError, match="one declared mass per cycle"):
        standard_cycle(NOMINAL_GEOMETRY, n_cycles=2, timing=QuinticTiming(), declared_masses=[1.0])
    with pytest.raises(ValueError, match="even number of sample periods"):
        standard_cycle(NOMINAL_GEOMETRY, n_cycles=1, dwell=0.1005, timing=QuinticTiming(), declared_masses=[1.0])


def test_a_timing_draws_nothing_from_the_episode_generator() -> None:
    fixed = conveyor_cycles(NOMINAL_GEOMETRY, np.random.default_rng(3), 2)
    planned = conveyor_cycles(
        NOMINAL_GEOMETRY, np.random.default_rng(3), 2, timing=QuinticTiming(), declared_masses=[1.0, 2.0]
    ).trajectory()
    np.testing.assert_array_equal(planned.xyz[planned.pick_indices], fixed.xyz[fixed.pick_indices])


@pytest.mark.parametrize("release", ["timed", "in_position"])
def test_the_env_follows_a_timing_and_an_online_retime_keeps_the_past(release: str) -> None:
    masses = [4.0, 4.0]
    env = DeltaPickPlaceEnv(n_cycles=2, timing=QuinticTiming(retime_at=50), release=release)
    env.reset(seed=1, options={"payload_masses": masses})
    before = env.trajectory
    seen = []
    while True:
        observation, _, terminated, truncated, _ = env.step(np.zeros(3))
        seen.append(observation["reference_angles"])
        if terminated or truncated:
            break
    after = env.trajectory
    assert env.timing.retimed == [50, 50]
    # each 0.6 s carry was cut to 50 ms + 0.2 s: 2 x 0.35 s shorter; an unpowered robot never gets in position, so
    # with the in-position release each of the 4 events waited its time-out
    waits = sum(settle.settle_time for settle in env.settles)
    assert math.isclose(waits, 0.0 if release == "timed" else 4 * env.release.settle_timeout, abs_tol=1e-9)
    assert math.isclose((len(before) - len(after)) * DT + waits, 0.7, abs_tol=1e-9)
    np.testing.assert_array_equal(np.array(seen), after.theta[1 : len(seen) + 1])
    # the timed pieces, holds and retimes included, give the reference followed, whose past never changed
    np.testing.assert_array_equal(env._reference._timed.trajectory().theta, after.theta)
    if release == "timed":  # and without holds, the past before the retime is the plan's
        first_carry = before.pick_indices[0] + 50 + 50  # pick mid-dwell, dwell's second half, 50 samples into the move
        np.testing.assert_array_equal(after.theta[: first_carry + 1], before.theta[: first_carry + 1])


def test_a_scenario_with_a_planned_timing_needs_a_timing_object() -> None:
    env = DeltaPickPlaceEnv(scenario=Scenario(task=PickPlaceTask(timing="online")))
    with pytest.raises(ValueError, match="needs a planner on the identified model"):
        env.reset(seed=0)
    with pytest.raises(ValueError, match="timing must be one of"):
        PickPlaceTask(timing="fast")


class RewritingTiming(QuinticTiming):
    """Retimes every carry at sample 10 with a law that changes the samples already followed."""

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        return quintic_law(0.2) if index == 10 else None


def test_a_retime_that_changes_the_past_is_refused() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, timing=RewritingTiming(retime_at=10))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="must repeat the 11 samples already followed"):
        for _ in range(len(env.trajectory)):
            env.step(np.zeros(3))
