"""Fault injection: FaultSpec checks, scenario files, and what each kind does to an episode at its drawn step."""

import math
from dataclasses import replace

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from numpy.testing import assert_array_equal

from controllers.base import PDController
from delta_env import DeltaPickPlaceEnv
from delta_env.faults import FaultSpec, is_latent
from delta_env.scenario import PickPlaceTask, Scenario, preset

PRESET_HASHES = {
    "heavy": "2ea4b0c343aff2c3",
    "nominal": "b0b1aad3e0df7d60",
    "paper": "859da178ce0f4994",
    "pick-rate": "2f8698718e7eb1fd",
    "randomized": "b54731e67861e996",
    "stress-6g": "173dc1f8b50511d4",
    "worn": "42037da62f2cc13d",
}
"""The content hashes of the presets before faults (and the in-position release) existed: faults must not change
them."""

SEED = 4
AT = 0.4  # s: when the timed faults of the tests start, mid-move of the empty arch to the first pick
TIMED = "timed"  # the release of the episodes AT is set in (the timed release's half dwell before the arch)


# -- FaultSpec ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "wobble"}, "kind must be one of"),
        ({"kind": "slip", "probability": 1.5}, r"probability must be a finite number in \[0, 1\]"),
        ({"kind": "encoder_glitch", "carry_fraction": (0.2, 0.8), "start": (1.0, 2.0)}, "not both"),
        ({"kind": "slip", "carry_fraction": None, "start": (1.0, 2.0)}, "a slip happens during a carry"),
        ({"kind": "slip", "carry_fraction": (0.5, 1.2)}, "carry_fraction must be a pair 0 <= min <= max <= 1"),
        ({"kind": "encoder_glitch", "start": (2.0, 1.0)}, "start must be a pair 0 <= min <= max"),
        ({"kind": "encoder_glitch", "joint": 3}, r"joint must be an integer in \[0, 2\]"),
        ({"kind": "slip", "joint": 1}, "joint is for"),
        ({"kind": "collision", "joint": 1}, "joint is for"),
        ({"kind": "slip", "size": (1.0, 2.0)}, "size is not used by kind 'slip'"),
        ({"kind": "encoder_stuck", "size": (1.0, 2.0)}, "size is not used by kind 'encoder_stuck'"),
        ({"kind": "collision", "target": "obstacle", "size": (1.0, 2.0)}, "with target 'obstacle'"),
        ({"kind": "slip", "duration": (0.1, 0.2)}, "duration is not used by kind 'slip'"),
        ({"kind": "torque_glitch", "size": (-5.0, 5.0)}, "size must be a pair 0 <= min"),
        ({"kind": "drive_fault", "size": (0.5, 1.0)}, r"must lie in \[0, 1\)"),
        ({"kind": "collision", "duration": (0.1, math.inf)}, "duration must be a pair"),
        ({"kind": "sensor_nan", "sensor": "camera"}, "sensor must be one of"),
        ({"kind": "encoder_glitch", "sensor": "torque"}, "sensor is not used by kind 'encoder_glitch'"),
        ({"kind": "collision", "target": "wall"}, "target must be one of"),
        ({"kind": "drive_fault", "target": "arm"}, "target is not used"),
        ({"kind": "drive_fault", "relative_to": "mean"}, "relative_to must be one of"),
        ({"kind": "collision", "relative_to": "peak"}, "relative_to is not used by kind 'collision'"),
    ],
)
def test_bad_fault_specs_are_refused_naming_the_field(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FaultSpec(**kwargs)


def test_a_spec_takes_its_kinds_defaults() -> None:
    glitch = FaultSpec("encoder_glitch")
    assert (glitch.carry_fraction, glitch.start, glitch.size, glitch.duration) == (
        (0.2, 0.8),
        None,
        (0.005, 0.05),
        (0.001, 0.001),
    )
    assert FaultSpec("collision").target == "platform"
    assert FaultSpec("sensor_nan").sensor == "encoder"
    assert FaultSpec("collision", target="obstacle").size is None
    assert FaultSpec("torque_glitch", start=(1.0, 2.0)).carry_fraction is None
    assert FaultSpec("drive_fault").relative_to == "command" and FaultSpec("slip").relative_to is None


# -- scenario files -------------------------------------------------------------------------------

FAULTY = (
    FaultSpec("slip", probability=0.5),
    FaultSpec("collision", target="arm", joint=2, start=(1.0, 2.0)),
    FaultSpec("sensor_nan", sensor="torque"),
)


def test_faults_round_trip_through_toml_and_change_the_hash_only_when_present() -> None:
    scenario = replace(Scenario(), task=PickPlaceTask(faults=FAULTY))
    text = scenario.to_toml()
    assert text.count("[[task.faults]]") == 3
    loaded = Scenario.from_toml(text)
    assert loaded == scenario and loaded.content_hash == scenario.content_hash
    assert scenario.content_hash != Scenario().content_hash
    # (and timed like the presets then: the in-position release came later, and the timed one keeps the hashes)
    timed = {name: replace(preset(name), task=replace(preset(name).task, release="timed")) for name in PRESET_HASHES}
    assert {name: scenario.content_hash for name, scenario in timed.items()} == PRESET_HASHES


def test_a_fault_table_is_read_with_defaults_and_bad_fields_named() -> None:
    text = '[[task.faults]]\nkind = "encoder_glitch"\njoint = 1\nstart = [0.5, 1.0]\n'
    (fault,) = Scenario.from_toml(text).task.faults
    assert fault == FaultSpec("encoder_glitch", joint=1, start=(0.5, 1.0))
    with pytest.raises(ValueError, match=r"task.faults\[0\]: size must be a pair"):
        Scenario.from_toml('[[task.faults]]\nkind = "collision"\nsize = [10.0, 1.0]\n')
    with pytest.raises(ValueError, match=r"unknown key\(s\) task.faults\[0\].force"):
        Scenario.from_toml('[[task.faults]]\nkind = "collision"\nforce = 3\n')


def test_the_env_takes_the_scenarios_faults_unless_given_its_own() -> None:
    scenario = replace(Scenario(), task=PickPlaceTask(n_cycles=1, faults=FAULTY))
    assert DeltaPickPlaceEnv(scenario=scenario).faults == FAULTY
    assert DeltaPickPlaceEnv(scenario=scenario, faults=()).faults == ()
    with pytest.raises(ValueError, match=r"faults\[0\] must be a FaultSpec"):
        DeltaPickPlaceEnv(faults=["slip"])


# -- episodes -------------------------------------------------------------------------------------


def pd_rollout(env: DeltaPickPlaceEnv, seed: int = SEED, options: dict | None = None) -> list:
    """(action, observation, info) of every step of a PD episode."""
    observation, _ = env.reset(seed=seed, options=options)
    controller, records = PDController(), []
    while True:
        action = controller(observation)
        observation, _, terminated, truncated, info = env.step(action)
        records.append((action, observation, info))
        if terminated or truncated:
            return records


@pytest.fixture(scope="module")
def clean() -> list:
    """The fault-free PD episode of SEED (one cycle)."""
    return pd_rollout(DeltaPickPlaceEnv(n_cycles=1, release=TIMED))


def replay(faults: list[FaultSpec], clean: list) -> tuple[DeltaPickPlaceEnv, list]:
    """The actions of ``clean`` replayed in an env with ``faults`` (same seed): (env, [(observation, info)])."""
    env = DeltaPickPlaceEnv(n_cycles=1, faults=faults, release=TIMED)
    env.reset(seed=SEED)
    records = []
    for action, _, _ in clean:
        observation, _, terminated, _, info = env.step(action)
        records.append((observation, info))
        assert not terminated
    return env, records


def fault_steps(env: DeltaPickPlaceEnv) -> range:
    (fault,) = env.injected_faults
    return range(fault.start_step, fault.start_step + fault.steps)


def test_episodes_without_faults_are_bit_identical(clean: list) -> None:
    """Faults are drawn after everything else: one that never happens changes no observation."""
    for faults in ((), [FaultSpec("encoder_glitch", probability=0.0)]):
        other = pd_rollout(DeltaPickPlaceEnv(n_cycles=1, faults=faults, release=TIMED))
        assert len(other) == len(clean)
        for (_, a, info_a), (_, b, info_b) in zip(clean, other, strict=True):
            for key in a:
                assert_array_equal(a[key], b[key])
            assert info_a["payload_mass"] == info_b["payload_mass"] and info_b["faults"] == ()


def sensor_difference(spec: FaultSpec, clean: list, key: str) -> tuple[DeltaPickPlaceEnv, np.ndarray, list]:
    """Replay with one sensor fault: the env, observation[key] minus the clean one per step, and info["faults"]."""
    env, faulty = replay([spec], clean)
    difference = np.array([obs[key] - c[1][key] for (obs, _), c in zip(faulty, clean, strict=True)])
    return env, difference, [info["faults"] for _, info in faulty]


def test_an_encoder_glitch_offsets_the_reading_by_its_size_at_its_samples_only(clean: list) -> None:
    spec = FaultSpec("encoder_glitch", start=(AT, AT), joint=1, duration=(0.003, 0.003))
    env, difference, kinds = sensor_difference(spec, clean, "joint_angles")
    (fault,) = env.injected_faults
    steps = fault_steps(env)
    assert (fault.start_step, fault.steps, fault.joint) == (round(AT / env.dt) - 1, 3, 1)
    assert 0.005 <= abs(fault.size) <= 0.05
    expected = np.zeros_like(difference)
    expected[steps, 1] = fault.size
    np.testing.assert_allclose(difference, expected, rtol=0.0, atol=1e-12)
    assert [k for k, kind in enumerate(kinds) if kind] == list(steps)
    # The backward difference sees the jump in and out.
    _, rates, _ = sensor_difference(spec, clean, "joint_velocities")
    nonzero = np.flatnonzero(np.abs(rates[:, 1]) > 1e-6)
    assert nonzero.tolist() == [steps[0], steps[-1] + 1]
    assert rates[steps[0], 1] == pytest.approx(fault.size / env.dt)


def test_a_stuck_encoder_repeats_its_last_reading(clean: list) -> None:
    spec = FaultSpec("encoder_stuck", start=(AT, AT), joint=0, duration=(0.01, 0.01))
    env, faulty = replay([spec], clean)
    steps = fault_steps(env)
    readings = np.array([obs["joint_angles"][0] for obs, _ in faulty])
    true = np.array([c[1]["joint_angles"][0] for c in clean])
    assert len(steps) == 10
    assert np.all(readings[steps] == true[steps[0] - 1])
    assert np.all(true[steps] != true[steps[0] - 1])  # the joint moves meanwhile
    outside = np.ones(len(readings), bool)
    outside[steps] = False
    assert_array_equal(readings[outside], true[outside])


@pytest.mark.parametrize(("sensor", "key"), [("encoder", "joint_angles"), ("torque", "joint_torques")])
def test_a_sensor_nan_is_nan_exactly_at_its_samples(clean: list, sensor: str, key: str) -> None:
    spec = FaultSpec("sensor_nan", sensor=sensor, start=(AT, AT), joint=2, duration=(0.002, 0.002))
    env, difference, _ = sensor_difference(spec, clean, key)
    steps = list(fault_steps(env))
    assert np.flatnonzero(np.isnan(difference).any(axis=1)).tolist() == steps
    assert not np.isnan(difference[:, :2]).any()
    if sensor == "encoder":  # the rate is a backward difference: one more NaN after
        _, rates, _ = sensor_difference(spec, clean, "joint_velocities")
        assert np.flatnonzero(np.isnan(rates[:, 2])).tolist() == [*steps, steps[-1] + 1]


def test_a_torque_glitch_offsets_the_measured_torque(clean: list) -> None:
    spec = FaultSpec("torque_glitch", start=(AT, AT), joint=0)
    env, difference, _ = sensor_difference(spec, clean, "joint_torques")
    (fault,) = env.injected_faults
    expected = np.zeros_like(difference)
    expected[fault.start_step, 0] = fault.size
    assert 20.0 <= abs(fault.size) <= 200.0
    np.testing.assert_allclose(difference, expected, rtol=0.0, atol=1e-9)


def test_a_slip_drops_the_object_while_the_gripper_still_reads_held() -> None:
    masses = {"payload_masses": [3.5, 3.5]}
    env = DeltaPickPlaceEnv(n_cycles=2, faults=[FaultSpec("slip", carry_fraction=(0.5, 0.5))])
    slipped = pd_rollout(env, options=masses)
    held = pd_rollout(DeltaPickPlaceEnv(n_cycles=2), options=masses)
    (fault,) = env.injected_faults
    assert fault.size == 3.5 and len(slipped) == len(held)  # the episode runs on through the place and next pick
    trajectory = env.trajectory
    carry = max(c for c, pick in enumerate(trajectory.pick_indices) if pick <= fault.start_step)
    place = int(trajectory.place_indices[carry])
    window = range(fault.start_step, place - 1)
    assert all(slipped[k][2]["payload_mass"] == 0.0 and slipped[k][1]["gripper"][0] == 1.0 for k in window)
    assert all(held[k][2]["payload_mass"] == 3.5 for k in window)
    assert slipped[place][1]["gripper"][0] == 0.0
    # Holding a 3.5 kg object up costs the arms torque the slip saves (the same PD, averaged after the slip).
    late = range(fault.start_step + 50, place - 1)
    need = [np.mean([abs(run[k][2]["applied_torque"]).sum() for k in late]) for run in (slipped, held)]
    assert need[0] < 0.6 * need[1]


@pytest.mark.parametrize("target", ["platform", "arm"])
def test_a_collision_pushes_for_its_duration_then_lets_go(clean: list, target: str) -> None:
    joint = 1 if target == "arm" else None
    spec = FaultSpec("collision", target=target, joint=joint, start=(AT, AT), size=(800.0, 800.0))
    env, faulty = replay([spec], clean)
    (fault,) = env.injected_faults
    steps = fault_steps(env)
    assert (fault.size, fault.detail, fault.joint) == (800.0, target, joint)
    deviation = [
        np.linalg.norm(info["platform_position"] - c[2]["platform_position"])
        for (_, info), c in zip(faulty, clean, strict=True)
    ]
    assert max(deviation[: steps[0]]) == 0.0
    assert max(deviation) > 1e-3
    assert not env.plant.data.xfrc_applied.any()
    assert [k for k, (_, info) in enumerate(faulty) if info["faults"]] == list(steps)


def test_the_collision_force_is_cleared_at_reset() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, faults=[FaultSpec("collision", start=(0.002, 0.002), duration=(1.0, 1.0))])
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(3))
    assert env.plant.data.xfrc_applied.any()
    env.reset(seed=0)
    assert not env.plant.data.xfrc_applied.any() and env.injected_faults == []


def test_a_drive_fault_limits_the_command_the_drive_holds(clean: list) -> None:
    spec = FaultSpec("drive_fault", start=(AT, AT), joint=2, size=(0.0, 0.0))
    env, faulty = replay([spec], clean)
    steps = fault_steps(env)
    commands = np.array([info["torque_command"] for _, info in faulty])
    assert np.all(commands[steps, 2] == 0.0)
    assert np.any(np.abs([clean[k][0][2] for k in steps]) > 1.0)  # the PD asked for torque there
    assert commands[steps[-1] + 1, 2] != 0.0


def test_a_drive_fault_keeps_its_share_of_the_onset_command_and_records_what_it_withheld(clean: list) -> None:
    spec = FaultSpec("drive_fault", start=(AT, AT), joint=0, size=(0.4, 0.4), duration=(0.02, 0.02))
    env, faulty = replay([spec], clean)
    (fault,) = env.injected_faults
    steps = fault_steps(env)
    asked = np.array([clean[k][2]["torque_command"][0] for k in steps])  # what the drive held without the fault
    limit = 0.4 * abs(asked[0])
    assert limit > 1.0 and fault.detail == "command"
    assert fault.size * env.plant_config.drive.peak_torque == pytest.approx(limit, rel=1e-12)
    held = np.array([info["torque_command"][0] for _, info in faulty])[steps]
    np.testing.assert_allclose(held, np.clip(asked, -limit, limit), rtol=0.0, atol=1e-12)
    assert fault.withheld == pytest.approx(np.max(np.abs(asked)) - limit, rel=1e-12)
    assert fault.withheld >= 0.6 * abs(asked[0]) and not is_latent(fault)  # withheld from the first step on


def test_a_drive_fault_that_keeps_more_than_the_motion_asks_is_latent(clean: list) -> None:
    spec = FaultSpec("drive_fault", start=(AT, AT), joint=2, size=(0.9, 0.9), duration=(0.02, 0.02), relative_to="peak")
    env, faulty = replay([spec], clean)
    (fault,) = env.injected_faults
    assert (fault.size, fault.detail, fault.withheld) == (0.9, "peak", 0.0) and is_latent(fault)
    for (_, info), (_, _, clean_info) in zip(faulty, clean, strict=True):
        assert_array_equal(info["torque_command"], clean_info["torque_command"])


def test_the_obstacle_is_hit_about_the_drawn_time() -> None:
    spec = FaultSpec("collision", target="obstacle", carry_fraction=(0.5, 0.5), duration=(0.03, 0.03))
    env = DeltaPickPlaceEnv(n_cycles=1, faults=[spec])
    records = pd_rollout(env)
    (fault,) = env.injected_faults
    pick, place = int(env.trajectory.pick_indices[0]), int(env.trajectory.place_indices[0])
    place -= round(env.settles[1].settle_time / env.dt)  # the carry as planned at the pick: before the place's wait
    drawn = pick + round(0.5 * (place - pick)) - 1
    assert abs(fault.start_step - drawn) <= 5
    assert fault.size > 50.0 and fault.detail == "obstacle"
    assert not any(info["diverged"] for _, _, info in records)
    assert env.plant.data.mocap_pos[0, 2] > 5.0  # parked again


def test_draws_follow_the_seed() -> None:
    env = DeltaPickPlaceEnv(
        n_cycles=2, faults=[FaultSpec("encoder_glitch"), FaultSpec("torque_glitch", start=(0.1, 1.0))]
    )
    runs = {}
    for seed in (1, 1, 2):
        pd_rollout(env, seed=seed)
        runs.setdefault(seed, []).append(list(env.injected_faults))
    assert runs[1][0] == runs[1][1] and len(runs[1][0]) == 2
    assert runs[2][0] != runs[1][0]


def test_faults_past_the_end_do_not_happen() -> None:
    env = DeltaPickPlaceEnv(n_cycles=1, faults=[FaultSpec("encoder_glitch", start=(100.0, 100.0))])
    records = pd_rollout(env)
    assert env.injected_faults == [] and all(info["faults"] == () for _, _, info in records)


def test_gymnasium_env_checker_with_faults() -> None:
    faults = [FaultSpec(kind, start=(0.001, 0.002)) for kind in ("encoder_glitch", "torque_glitch", "drive_fault")]
    gym_check_env(
        DeltaPickPlaceEnv(n_cycles=1, faults=[*faults, FaultSpec("collision", target="obstacle")]),
        skip_render_check=True,
    )


def test_a_bare_fault_spec_is_refused_with_a_clear_error() -> None:
    with pytest.raises(ValueError, match="faults must be a sequence of FaultSpec"):
        DeltaPickPlaceEnv(faults=FaultSpec("slip"))


def test_two_obstacle_faults_are_refused_with_a_clear_error() -> None:
    obstacle = FaultSpec("collision", target="obstacle")
    with pytest.raises(ValueError, match="at most one obstacle collision fault, got 2"):
        DeltaPickPlaceEnv(faults=[obstacle, obstacle])
