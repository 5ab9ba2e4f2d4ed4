"""Speed override (issue 20, part 3): the time scaling of the rest of a reference and the env's override_speed."""

import math

import numpy as np
import pytest

from controllers.registry import build_controller
from delta_env import NOMINAL_GEOMETRY
from delta_env.cycles import conveyor_cycles
from delta_env.env import DeltaPickPlaceEnv
from delta_env.override import STOP_HOLD, RateLimits, SpeedOverride, override_speed, scale_speed
from delta_env.trajectories import Trajectory

NAMES = ("xyz", "xyz_dot", "xyz_ddot", "theta", "theta_dot", "theta_ddot")


@pytest.fixture(scope="module")
def cycles() -> Trajectory:
    """Two conveyor cycles at 3 g."""
    return conveyor_cycles(NOMINAL_GEOMETRY, np.random.default_rng(0), 2)


def constant_velocity(n: int = 2001, dt: float = 1e-3) -> Trajectory:
    """A straight line at a constant 0.5 m/s (and 2 rad/s on every joint), never at rest."""
    t = np.arange(n)[:, None] * dt
    zero = np.zeros((n, 3))
    return Trajectory(dt, 0.5 * t + zero, 0.5 + zero, zero, 2.0 * t + zero, 2.0 + zero, zero, np.zeros(n, bool), [], [])


def consistent(trajectory: Trajectory, start: int) -> None:
    """Position, velocity and acceleration from ``start`` on agree with each other (trapezoid rule)."""
    dt = trajectory.dt
    for name in ("xyz", "theta"):
        x, v, a = (getattr(trajectory, name + suffix)[start:] for suffix in ("", "_dot", "_ddot"))
        # The trapezoid rule errs by dt^2/12 times the next derivative (the planned cycles reach 4.5e-4 rad/s and
        # 0.7 rad/s^2); a lost s_dot factor or s_ddot term would err by rad/s and 100 rad/s^2.
        assert np.max(np.abs(np.diff(x, axis=0) / dt - 0.5 * (v[1:] + v[:-1]))) < 1e-3
        assert np.max(np.abs(np.diff(v, axis=0) / dt - 0.5 * (a[1:] + a[:-1]))) < 1.5


def test_full_rate_gives_back_the_same_trajectory(cycles: Trajectory) -> None:
    same = scale_speed(cycles, 600, 1.0)
    assert len(same) == len(cycles)
    for name in NAMES:
        np.testing.assert_allclose(getattr(same, name), getattr(cycles, name), rtol=0, atol=1e-10)
    np.testing.assert_array_equal(same.gripper, cycles.gripper)
    np.testing.assert_array_equal(same.pick_indices, cycles.pick_indices)
    np.testing.assert_array_equal(same.place_indices, cycles.place_indices)


def test_half_rate_halves_the_velocity_and_doubles_the_duration() -> None:
    line, k = constant_velocity(), 200
    slow = override_speed(line, k, 0.5)
    ramp_end = int(np.flatnonzero(slow.path_rate == 0.5)[0])
    ramp = (ramp_end - k) * line.dt
    assert 0.0 < ramp < 0.5
    np.testing.assert_allclose(slow.trajectory.xyz_dot[ramp_end:], 0.25, atol=1e-9)
    np.testing.assert_allclose(slow.trajectory.theta_dot[ramp_end:], 1.0, atol=1e-9)
    np.testing.assert_allclose(slow.trajectory.xyz_ddot[ramp_end:], 0.0, atol=1e-9)
    # the symmetric ramp from 1 to 0.5 runs at 0.75 on average: the rest takes twice as long, less half the ramp
    remaining = line.duration - k * line.dt
    assert slow.trajectory.duration - k * line.dt == pytest.approx(2 * remaining - 0.5 * ramp, abs=2 * line.dt)
    np.testing.assert_allclose(slow.trajectory.xyz[-1], line.xyz[-1], atol=1e-12)  # to the old end
    np.testing.assert_array_equal(slow.trajectory.xyz[: k + 1], line.xyz[: k + 1])
    consistent(slow.trajectory, 0)


def test_a_stop_ends_at_rest_within_the_limits(cycles: Trajectory) -> None:
    k = int(cycles.pick_indices[0]) + 150  # mid-carry, at speed
    limits = RateLimits.of(cycles)
    stop = override_speed(cycles, k, 0.0)
    trajectory, hold = stop.trajectory, round(STOP_HOLD / cycles.dt)
    assert k + hold < len(trajectory) < len(cycles)
    rest = slice(len(trajectory) - hold - 1, None)  # the hold and the sample that reaches rest
    for name in ("xyz_dot", "xyz_ddot", "theta_dot", "theta_ddot"):
        assert np.max(np.abs(getattr(trajectory, name)[rest])) < 1e-9, name
    assert np.ptp(trajectory.xyz[rest], axis=0).max() < 1e-12  # holding still
    assert np.max(np.abs(stop.path_acceleration)) <= limits.acceleration * (1 + 1e-9)
    jerk = np.diff(stop.path_acceleration) / cycles.dt
    assert np.max(np.abs(jerk)) <= limits.jerk * (1 + 1e-6)
    assert np.all(np.diff(stop.path_time) >= 0.0)  # forward along the path only
    # the braking term theta' s_ddot is within the reference's own peak: at most twice it in all
    assert np.all(np.max(np.abs(trajectory.theta_ddot), axis=0) <= 2.0 * np.max(np.abs(cycles.theta_ddot), axis=0))
    consistent(trajectory, 0)


def test_continuous_at_the_switch(cycles: Trajectory) -> None:
    k = int(cycles.pick_indices[0]) + 150
    nominal_step = {name: np.max(np.abs(np.diff(getattr(cycles, name), axis=0))) for name in NAMES}
    for rate in (0.0, 0.5):
        trajectory = scale_speed(cycles, k, rate)
        for name in NAMES:
            np.testing.assert_array_equal(getattr(trajectory, name)[: k + 1], getattr(cycles, name)[: k + 1])
            # no step at k beyond what the jerk-limited braking adds to the reference's own steps
            assert np.max(np.abs(getattr(trajectory, name)[k + 1] - getattr(trajectory, name)[k])) <= (
                3.0 * nominal_step[name]
            ), (rate, name)
        consistent(trajectory, k - 5)


def test_events_are_remapped_or_dropped(cycles: Trajectory) -> None:
    picks, places = cycles.pick_indices, cycles.place_indices
    # slowed: events before k stay, the later ones move to the first sample whose path time reaches them
    k = int(picks[0]) + 150
    slow = override_speed(cycles, k, 0.5)
    assert slow.trajectory.pick_indices[0] == picks[0]
    for new, old in ((slow.trajectory.place_indices, places), (slow.trajectory.pick_indices[1:], picks[1:])):
        assert len(new) == len(old)
        for n, event in zip(new, old, strict=True):
            assert slow.path_time[n] >= event * cycles.dt - 1e-12 > slow.path_time[n - 1]
    gripper = slow.trajectory.gripper
    assert np.flatnonzero(np.diff(gripper.astype(int)) == 1).tolist() == [p - 1 for p in slow.trajectory.pick_indices]
    # a stop mid-carry keeps the pick and drops everything after: the object stays held to the end
    stopped = scale_speed(cycles, k, 0.0)
    assert stopped.pick_indices.tolist() == [picks[0]]
    assert stopped.place_indices.tolist() == []
    assert stopped.gripper[picks[0] :].all()
    # a stop just before a release reaches it, and never the next pick
    stopped = scale_speed(cycles, int(places[0]) - 20, 0.0)
    assert stopped.pick_indices.tolist() == [picks[0]]
    assert len(stopped.place_indices) == 1 and stopped.place_indices[0] >= places[0]
    assert not stopped.gripper[stopped.place_indices[0] :].any()


def test_rates_are_fractions_of_the_planned_speed(cycles: Trajectory) -> None:
    k = int(cycles.pick_indices[0]) + 150
    slow = override_speed(cycles, k, 0.5)
    again = override_speed(slow, k + 400, 0.5)  # long after the ramp: nothing changes
    assert isinstance(again, SpeedOverride) and again.nominal is cycles
    for name in NAMES:
        np.testing.assert_allclose(getattr(again.trajectory, name), getattr(slow.trajectory, name), atol=1e-9)
    np.testing.assert_array_equal(again.trajectory.pick_indices, slow.trajectory.pick_indices)
    # a stop then full speed again: back to the planned rate, every event kept
    resumed = override_speed(override_speed(cycles, k, 0.0), k + 40, 1.0)
    assert resumed.path_rate[-1] == 1.0
    assert len(resumed.trajectory.place_indices) == len(cycles.place_indices)


@pytest.mark.parametrize("rate", [-0.1, 1.5, math.nan, math.inf, "slow", True, None])
def test_bad_rates_are_refused(cycles: Trajectory, rate: object) -> None:
    with pytest.raises(ValueError, match=r"rate must be a finite number in \[0, 1\]"):
        scale_speed(cycles, 10, rate)


def test_bad_start_samples_are_refused(cycles: Trajectory) -> None:
    with pytest.raises(ValueError, match="k must be a sample index"):
        scale_speed(cycles, len(cycles), 0.5)


# -- the env ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def env() -> DeltaPickPlaceEnv:
    return DeltaPickPlaceEnv(n_cycles=2)


def run(env, controller, rate, call_at, seed=3):
    """Observations and infos of an episode whose speed is overridden to ``rate`` at step ``call_at``."""
    observation, _ = env.reset(seed=seed)
    controller.reset()
    observations, infos = [observation], []
    while True:
        if rate is not None and env._step_index == call_at:
            env.override_speed(rate)
        observation, _, terminated, truncated, info = env.step(controller(observation))
        observations.append(observation)
        infos.append(info)
        if terminated or truncated:
            assert not terminated
            return observations, infos


@pytest.fixture(scope="module")
def controller(controller_setup):
    return build_controller("mid_f_rls", controller_setup)


@pytest.fixture(scope="module")
def nominal_run(env, controller):
    """Observations, infos and the reference followed (its holds for the in-position signal included)."""
    return (*run(env, controller, None, None), env.trajectory)


def picks_and_places(observations) -> tuple[int, int]:
    gripper = np.array([o["gripper"][0] for o in observations])
    return int(np.sum(np.diff(gripper) > 0)), int(np.sum(np.diff(gripper) < 0))


def test_env_reports_no_override_normally(nominal_run) -> None:
    _, infos, _ = nominal_run
    assert all(info["speed_override"] == 1.0 and not info["stopped"] for info in infos)


def test_env_stop_mid_carry_ends_at_rest(env, controller, nominal_run) -> None:
    k = int(env.trajectory.pick_indices[0]) + 150  # the reference is the nominal one: no override yet
    observations, infos = run(env, controller, 0.0, k)
    assert len(infos) < len(nominal_run[1])
    assert infos[-1]["stopped"] and not any(info["stopped"] for info in infos[:-1])
    assert all(info["speed_override"] == 0.0 for info in infos[k:])
    errors = [info["tracking_error"] for info in infos]
    assert max(errors) < 0.25e-3  # m: the stop is tracked as well as the cycle (0.13 mm here)
    last = infos[-1]
    np.testing.assert_allclose(last["platform_position"], env.trajectory.xyz[-1], atol=15e-6)  # measured 8.8 um
    np.testing.assert_allclose(last["reference_position"], env.trajectory.xyz[-1])
    assert np.max(np.abs(observations[-1]["joint_velocities"])) < 0.05  # rad/s: at rest
    assert picks_and_places(observations) == (1, 0)  # the object is still held
    assert last["payload_mass"] == env.payload_masses[0] > 0.0


def test_env_stop_after_a_release_never_picks_again(env, controller, nominal_run) -> None:
    k = int(nominal_run[2].place_indices[0]) - 20  # in the air activation, after the wait for the in-position signal
    observations, infos = run(env, controller, 0.0, k)
    assert infos[-1]["stopped"]
    assert picks_and_places(observations) == (1, 1)
    assert infos[-1]["payload_mass"] == 0.0
    assert len(env.trajectory.pick_indices) == 1


def test_env_slow_down_is_longer_and_picks_everything(env, controller, nominal_run) -> None:
    env.reset(seed=3)
    k = int(env.trajectory.pick_indices[0]) + 150
    observations, infos = run(env, controller, 0.5, k)
    assert len(infos) > 1.4 * len(nominal_run[1])
    assert picks_and_places(observations) == picks_and_places(nominal_run[0]) == (2, 2)
    assert infos[-1]["speed_override"] == 0.5 and not infos[-1]["stopped"]
    assert max(info["tracking_error"] for info in infos) < 1e-3


def test_env_override_is_deterministic(env, controller) -> None:
    env.reset(seed=5)
    k = int(env.trajectory.pick_indices[0]) + 100
    first, _ = run(env, controller, 0.5, k, seed=5)
    second, _ = run(env, controller, 0.5, k, seed=5)
    assert len(first) == len(second)
    for a, b in zip(first, second, strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])


def test_env_refuses_bad_rates(env) -> None:
    with pytest.raises(RuntimeError, match="override_speed"):
        DeltaPickPlaceEnv(n_cycles=1).override_speed(0.5)
    env.reset(seed=0)
    for rate in (-0.5, 2.0, math.nan):
        with pytest.raises(ValueError, match=r"rate must be a finite number in \[0, 1\]"):
            env.override_speed(rate)
