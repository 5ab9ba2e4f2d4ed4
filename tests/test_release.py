"""The in-position release (delta_env.release): the cell judges the platform from its encoders only, holds the
reference until it is in position, runs the air activation, and times out when the platform never settles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.base import PDController
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.kinematics import inverse
from delta_env.release import DEFAULT_AIR_ACTIVATION, DEFAULT_SETTLE_TIMEOUT, InPositionRelease, ReleaseSettings
from delta_env.scenario import PickPlaceTask, Scenario
from delta_env.trajectories import arrivals
from eval.metrics import settle_metrics

DT = 1e-3


def encoders_read(env: DeltaPickPlaceEnv, offset: float = 0.0):
    """Make the encoders read the reference's angles of the current step, joint 1 ``offset`` (rad) off: the platform
    held on (or off) target as the cell measures it, whatever the simulated robot does."""

    def angles() -> tuple[float, float, float]:
        a0, a1, a2 = env.trajectory.theta[env._step_index].tolist()
        return a0 + offset, a1, a2

    return angles


def episode(env: DeltaPickPlaceEnv, seed: int = 0) -> tuple[list[dict], int]:
    """The infos of a PD episode, and the reference's length at its start."""
    observation, _ = env.reset(seed=seed)
    planned = len(env.trajectory)
    controller = PDController()
    infos = []
    while True:
        observation, _, terminated, truncated, info = env.step(controller(observation))
        infos.append(info)
        if terminated or truncated:
            return infos, planned


def test_a_platform_held_on_target_is_in_position_at_once_and_the_air_activation_lasts_35_ms(monkeypatch) -> None:
    env = DeltaPickPlaceEnv(n_cycles=2)
    monkeypatch.setattr(env.plant, "rotor_angle_values", encoders_read(env))
    infos, planned = episode(env)
    reference = env.trajectory
    assert [settle.settle_time for settle in env.settles] == [0.0] * 4
    assert not any(settle.timed_out for settle in env.settles)
    assert len(reference) == planned  # nothing held
    events = sorted([*reference.pick_indices.tolist(), *reference.place_indices.tolist()])
    air = round(DEFAULT_AIR_ACTIVATION / DT)
    assert [event - settle.arrival_step for event, settle in zip(events, env.settles, strict=True)] == [air] * 4
    assert all(infos[settle.arrival_step - 1]["in_position"] for settle in env.settles)
    # the reference is at rest from the arrival to the event, and moves right after it
    for settle, event in zip(env.settles, events, strict=True):
        assert not np.any(reference.xyz_dot[settle.arrival_step : event + 1])
        assert np.any(reference.xyz_dot[event + 1])

    # the air activation is the cycle's dwell: 25 ms less of it at each of the 4 events, 0.1 s shorter
    shorter = DeltaPickPlaceEnv(n_cycles=2, air_activation=0.01)
    monkeypatch.setattr(shorter.plant, "rotor_angle_values", encoders_read(shorter))
    episode(shorter)
    assert len(env.trajectory) - len(shorter.trajectory) == pytest.approx(4 * 25, abs=4)


def test_a_platform_held_off_target_times_out_and_is_flagged(monkeypatch) -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    monkeypatch.setattr(env.plant, "rotor_angle_values", encoders_read(env, offset=1e-3))  # about 0.3 mm off
    infos, planned = episode(env)
    timeout = round(DEFAULT_SETTLE_TIMEOUT / DT)
    assert [(settle.kind, settle.timed_out) for settle in env.settles] == [("pick", True), ("place", True)]
    assert [settle.settle_time for settle in env.settles] == [DEFAULT_SETTLE_TIMEOUT] * 2
    flagged = [step for step, info in enumerate(infos, start=1) if info["settle_timeout"]]
    assert flagged == [settle.arrival_step + timeout for settle in env.settles]
    assert not any(info["in_position"] for info in infos)
    assert len(env.trajectory) == planned + 2 * timeout  # the cycle time counts the waits
    # and the gripper acted anyway: the air activation after each time-out
    air = round(DEFAULT_AIR_ACTIVATION / DT)
    assert env.trajectory.pick_indices.tolist() == [flagged[0] + air]
    assert env.trajectory.place_indices.tolist() == [flagged[1] + air]
    assert settle_metrics([s.settle_time for s in env.settles], [s.timed_out for s in env.settles]) == (
        pytest.approx(1e3 * DEFAULT_SETTLE_TIMEOUT),
        pytest.approx(1e3 * DEFAULT_SETTLE_TIMEOUT),
        2,
    )


def test_the_judgement_follows_the_encoders_never_the_truth(monkeypatch) -> None:
    """The encoders read the reference while the robot, under PD alone, sags millimetres below it: in position at
    once. Then the truth alone is moved (the platform position the simulator reports, 5 mm off): nothing changes."""
    env = DeltaPickPlaceEnv(n_cycles=1)
    monkeypatch.setattr(env.plant, "rotor_angle_values", encoders_read(env))
    infos, _ = episode(env)
    assert [settle.settle_time for settle in env.settles] == [0.0, 0.0]
    arrival = env.settles[0].arrival_step
    assert infos[arrival - 1]["tracking_error"] > 1e-3  # the true platform is far outside the window

    judged = [(info["in_position"], info["settle_timeout"]) for info in infos]
    true_point, true_position = env.plant.platform_point, env.plant.platform_position
    monkeypatch.setattr(env.plant, "platform_point", lambda: tuple(np.add(true_point(), (0.005, 0.0, 0.0))))
    monkeypatch.setattr(env.plant, "platform_position", lambda: np.add(true_position(), (0.005, 0.0, 0.0)))
    moved, _ = episode(env)
    assert [(info["in_position"], info["settle_timeout"]) for info in moved] == judged
    assert [settle.settle_time for settle in env.settles] == [0.0, 0.0]
    assert moved[arrival - 1]["platform_position"][0] == pytest.approx(
        infos[arrival - 1]["platform_position"][0] + 5e-3
    )


def test_pd_episodes_are_deterministic_and_the_timed_release_is_the_old_cell() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    first, _ = episode(env, seed=2)
    settles = list(env.settles)
    reference = env.trajectory
    second, _ = episode(env, seed=2)
    assert env.settles == settles
    np.testing.assert_array_equal(env.trajectory.theta, reference.theta)
    assert [info["platform_position"].tolist() for info in first] == [
        info["platform_position"].tolist() for info in second
    ]
    # PD alone leaves millimetres of gravity sag: it never gets in position
    assert all(settle.timed_out for settle in settles)

    timed = DeltaPickPlaceEnv(n_cycles=1, release="timed")
    infos, planned = episode(timed, seed=2)
    assert timed.settles == [] and len(timed.trajectory) == planned == len(infos) + 1
    assert not any(info["in_position"] or info["settle_timeout"] for info in infos)
    # the gripper switches mid-way through a 0.1 s dwell
    reference = timed.trajectory
    for event in (reference.pick_indices[0], reference.place_indices[0]):
        assert event - arrivals(reference.xyz_dot, [event])[0] == pytest.approx(50, abs=1)
        assert not np.any(reference.xyz_dot[event : event + 49])


def test_a_wide_window_settles_pd_without_a_time_out() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, in_position_window=0.01)  # 10 mm: wider than PD's sag
    episode(env)
    assert not any(settle.timed_out for settle in env.settles)
    assert all(settle.settle_time < DEFAULT_SETTLE_TIMEOUT for settle in env.settles)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("release", "early", "release must be one of"),
        ("in_position_window", 0.0, r"in_position_window must be a finite number in \(0, 0.01\] m"),
        ("in_position_time", 0.0, r"in_position_time must be a finite number in \[0.001, 10\] s"),
        ("air_activation", 0.0355, "air_activation must be a whole number of control periods"),
        ("air_activation", 0.001, r"air_activation must be a finite number in \[0.002, 10\] s"),
        ("settle_timeout", -0.1, r"settle_timeout must be a finite number in \[0, 10\] s"),
        ("settle_timeout", math.nan, "settle_timeout must be a finite number"),
    ],
)
def test_bad_release_settings_are_refused(field: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ReleaseSettings(**{field: value})
    with pytest.raises(ValueError, match=message):
        PickPlaceTask(**{field: value})
    with pytest.raises(ValueError, match=message):
        DeltaPickPlaceEnv(n_cycles=1, **{field: value})


def test_the_scenario_carries_the_release_and_a_timed_task_hashes_as_before() -> None:
    scenario = Scenario(task=PickPlaceTask(release="timed", air_activation=0.05))
    assert Scenario.from_toml(scenario.to_toml()) == scenario
    # a timed task's hash leaves the release's fields out: the scenarios before the in-position release keep theirs
    assert scenario.content_hash == Scenario(task=PickPlaceTask(release="timed")).content_hash
    assert Scenario().content_hash != Scenario(task=PickPlaceTask(settle_timeout=0.1)).content_hash
    env = DeltaPickPlaceEnv(scenario=Scenario(task=PickPlaceTask(settle_timeout=0.2)), air_activation=0.02)
    assert env.release == ReleaseSettings(settle_timeout=0.2, air_activation=0.02)


@pytest.mark.parametrize("rate", [0.5, 0.0])
def test_a_speed_override_during_a_wait(monkeypatch, rate: float) -> None:
    """A slow-down during the wait keeps it (the hold goes on in the scaled reference, the event still comes); a stop
    that never reaches the event (a 0.2 s air activation, longer than the stop's ramp) drops it, and the wait."""
    env = DeltaPickPlaceEnv(n_cycles=1, air_activation=0.035 if rate else 0.2)
    monkeypatch.setattr(env.plant, "rotor_angle_values", encoders_read(env, offset=1e-3))
    observation, _ = env.reset(seed=0)
    controller = PDController()
    arrival = next(iter(env._reference.gates))
    gripper = []
    while True:
        if env._step_index == arrival + 10:
            env.override_speed(rate)
        observation, _, terminated, truncated, info = env.step(controller(observation))
        gripper.append(observation["gripper"][0])
        if terminated or truncated:
            break
    if rate > 0.0:
        assert [(settle.kind, settle.timed_out) for settle in env.settles] == [("pick", True), ("place", True)]
        assert env.settles[0].arrival_step == arrival
        timeout = round(DEFAULT_SETTLE_TIMEOUT / DT)
        # the air activation after the time-out is path time: longer as the rate ramps down to a half, at most twice
        air = env.trajectory.pick_indices[0] - (arrival + timeout)
        assert DEFAULT_AIR_ACTIVATION / DT + 5 < air < 2 * DEFAULT_AIR_ACTIVATION / DT
        assert np.sum(np.diff(gripper) > 0) == 1 and np.sum(np.diff(gripper) < 0) == 1
    else:
        assert env.settles == [] and info["stopped"]
        assert not any(gripper) and len(env.trajectory.pick_indices) == 0


@pytest.mark.parametrize(("offset", "inside"), [(0.045e-3, True), (0.055e-3, False)])
def test_the_window_is_judged_on_the_declared_forward_kinematics_for_consecutive_samples(
    offset: float, inside: bool
) -> None:
    """Encoder angles of a point ``offset`` (m) from the target, by the declared geometry's exact inverse: inside the
    0.05 mm window from the third consecutive sample on, or never; one sample outside starts the count again."""
    target = np.array([0.05, -0.2, -0.9])
    release = InPositionRelease(ReleaseSettings(), NOMINAL_GEOMETRY)
    angles = inverse(NOMINAL_GEOMETRY, target + offset * np.array([0.6, 0.0, 0.8])).tolist()
    judged = [release.judge(angles, target.tolist()) for _ in range(4)]
    assert judged == ([False, False, True, True] if inside else [False] * 4)
    far = inverse(NOMINAL_GEOMETRY, target + np.array([1e-3, 0.0, 0.0])).tolist()
    assert [release.judge(a, target.tolist()) for a in (far, angles, angles, angles)] == [False, False, False, inside]
    assert not release.judge([math.nan, 0.0, 0.0], target.tolist())
    # the window and the time are settings: 0.06 mm held for 1 ms takes the first sample
    wide = InPositionRelease(ReleaseSettings(in_position_window=0.06e-3, in_position_time=0.001), NOMINAL_GEOMETRY)
    assert wide.judge(angles, target.tolist())
