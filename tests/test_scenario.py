"""Scenarios: TOML round trip, field validation, presets, robot identity and the env's scenario argument."""

import dataclasses
import math
import tomllib
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import delta_env  # noqa: F401 - registers DeltaPickPlace-v0
from controllers.base import PDController, payload_estimator_of
from controllers.payload_timing import EstimatingController
from controllers.registry import build_controller, cell_estimator, monitored
from delta_env import cycles
from delta_env import scenario as scenario_module
from delta_env.config import PlantConfig, PlantRealism, RandomizationRanges
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import GRAVITY, DeltaGeometry
from delta_env.scenario import Condition, PickPlaceTask, Scenario, preset, preset_names, resolve_scenario
from delta_env.sensors import control_substeps
from eval.work import timed

PRESETS = (
    "compliant",
    "faults",
    "heavy",
    "nominal",
    "paper",
    "pick-rate",
    "pick-rate-randomized",
    "randomized",
    "stress-6g",
    "worn",
)


def unusual_scenario() -> Scenario:
    """Every kind of field away from its default, None included."""
    return Scenario(
        name="unusual",
        description="a shorter forearm, exact encoders, lag not randomized",
        plant=PlantConfig(
            geometry=DeltaGeometry(ra=0.22, rb=0.06, l1=0.35, l2=0.9),
            realism=dataclasses.replace(PlantRealism(), encoder_bits=None, coulomb_scale=(1.0, 1.1, 0.9)),
            timestep=0.00025,
        ),
        condition=Condition(friction_scale=1.25, actuator_lag=0.0015),
        task=PickPlaceTask(
            cycle="standard",
            n_cycles=2,
            start="pick",
            peak_acceleration=2.5 * GRAVITY,
            payload_mass_range=(0.5, 1.5),
            domain_randomization=RandomizationRanges(mass_fraction=0.05, actuator_lag=None),
        ),
    )


@pytest.mark.parametrize("scenario", [unusual_scenario(), *(preset(name) for name in PRESETS)], ids=lambda s: s.name)
def test_scenario_round_trips_through_a_toml_file(scenario: Scenario, tmp_path) -> None:
    path = scenario.save(tmp_path / "sub" / "scenario.toml")
    loaded = Scenario.load(path)
    assert loaded == scenario
    assert loaded.content_hash == scenario.content_hash
    assert Scenario.from_toml(scenario.to_toml()) == scenario


def test_integers_in_a_file_mean_the_same_floats() -> None:
    written = Scenario.from_toml('name = "n"\n[plant.realism]\ncoulomb = 4\n[task]\npayload_mass_range = [0, 4]\n')
    assert written.content_hash == Scenario().content_hash
    assert isinstance(written.plant.realism.coulomb, float)


SCENARIO_FILES = sorted((Path(__file__).parents[1] / "docs" / "scenarios").glob("*.toml"))
"""The files docs/scenarios ships: scenarios (the compliant plants of docs/measurements.md) and geometry files
(``--geometry``, a ``[geometry]`` table)."""


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=[path.stem for path in SCENARIO_FILES])
def test_every_file_the_docs_ship_loads(path: Path) -> None:
    if "geometry" in tomllib.loads(path.read_text()):
        assert scenario_module.load_geometry(path).l2 > 0.0
        return
    scenario = resolve_scenario(str(path))
    assert scenario.name == path.stem
    assert Scenario.from_toml(scenario.to_toml()) == scenario


def test_a_file_without_a_name_is_named_after_its_stem(tmp_path) -> None:
    path = tmp_path / "slow-cell.toml"
    path.write_text("[task]\npeak_acceleration = 9.81\n")
    scenario = resolve_scenario(str(path))
    assert scenario.name == "slow-cell"
    assert scenario.task.peak_acceleration == 9.81


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[task]\nn_cycle = 3\n", "unknown key(s) task.n_cycle"),
        ("colour = 1\n", "unknown key(s) colour"),
        ("[plant.realism]\ncoulomb = -1.0\n", "plant.realism: coulomb must be"),
        ("[plant.realism]\nencoder_bits = 17.5\n", 'plant.realism.encoder_bits must be an integer or "none"'),
        ("[plant.realism]\nviscous_scale = [1.0, 1.0]\n", "plant.realism.viscous_scale must be an array of 3"),
        ("[plant.geometry]\nrb = 0.3\n", "plant.geometry: rb must be < ra"),
        ("[plant]\nvariant = 'perfect'\n", "plant.variant must be one of 'ideal', 'realistic'"),
        ("[plant]\ngeometry = 1\n", "plant.geometry must be a table"),
        ("[task]\nn_cycles = 1.5\n", "task.n_cycles must be an integer"),
        ("[task]\nn_cycles = 0\n", "task: n_cycles must be an integer >= 1"),
        ("[task]\ncycle = 'circle'\n", "task.cycle must be one of 'conveyor', 'standard'"),
        ("[task]\nstart = 'home'\n", "task.start must be one of 'place', 'pick', got 'home'"),
        ("[task]\npeak_acceleration = true\n", "task.peak_acceleration must be a number"),
        (
            "[plant]\ntimestep = 0.0003\n",
            "plant: the physics timestep 0.0003 s must divide the control period 0.001 s (timestep = 0.001 s / n",
        ),
        ("[plant]\ntimestep = 0.002\n", "plant: timestep must be a finite number in [1e-05, 0.001] s, got 0.002"),
        (
            "[task]\npeak_acceleration = 981.0\n",
            "task: peak_acceleration must be a finite number in (0, 294.3] m/s^2, got 981.0",
        ),
        ("[task]\npayload_mass_range = [0.0, 30.0]\n", "task: payload_mass_range must be a pair 0 <= min <= max <= 20"),
        ("[task.domain_randomization]\nmass_fraction = 0.95\n", "task.domain_randomization: mass_fraction must be"),
        ("[condition]\nfriction_scale = 0.0\n", "condition: friction_scale must be a finite number in (0, 10]"),
        (
            "[plant.realism]\ncoulomb = 50.0\n[condition]\nfriction_scale = 9.0\n",
            "condition: the worn plant is invalid: coulomb",
        ),
        ("name = ''\n", "name must be a non-empty string"),
        ("[task\n", "not valid TOML"),
    ],
)
def test_bad_fields_are_errors_naming_the_field(text: str, message: str) -> None:
    with pytest.raises(ValueError) as error:
        Scenario.from_toml(text, "test.toml")
    assert message in str(error.value)
    assert str(error.value).startswith("scenario test.toml: ")


def test_unknown_preset_lists_the_presets() -> None:
    assert preset_names() == sorted(PRESETS)
    with pytest.raises(
        ValueError,
        match="compliant, faults, heavy, nominal, paper, pick-rate, pick-rate-randomized, randomized, stress-6g, worn",
    ):
        resolve_scenario("nominl")
    with pytest.raises(ValueError, match="no such file"):
        resolve_scenario("missing/dir/cell.toml")


def test_presets_resolve_next_to_the_module_not_the_working_directory(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "nominal.toml").write_text("[task]\nn_cycles = 9\n")
    assert resolve_scenario("nominal").task.n_cycles == 3


def test_nominal_preset_is_the_default_env() -> None:
    assert preset("nominal").content_hash == Scenario().content_hash
    default, nominal = DeltaPickPlaceEnv(), DeltaPickPlaceEnv(scenario="nominal")
    for env in (default, nominal):
        assert env.plant_config == PlantConfig()
        assert (env.n_cycles, env.cycle, env.start, env.payload_mass_range) == (3, "conveyor", "place", (0.0, 4.0))
        assert env.peak_acceleration == pytest.approx(3.0 * GRAVITY)
        assert env.domain_randomization is None


def test_robot_identity_is_the_plant_only() -> None:
    identities = {preset(name).robot_identity for name in PRESETS if name != "compliant"}
    assert identities == {Scenario().robot_identity}  # worn, heavy, randomized: the nominal robot
    assert preset("compliant").robot_identity != Scenario().robot_identity  # other drive hardware: another robot
    assert len({preset(name).content_hash for name in PRESETS}) == len(PRESETS)
    other_geometry = Scenario(plant=PlantConfig(geometry=DeltaGeometry(l1=0.4)))
    other_sensor = Scenario(plant=PlantConfig(realism=dataclasses.replace(PlantRealism(), encoder_bits=20)))
    assert other_geometry.robot_identity != Scenario().robot_identity
    assert other_sensor.robot_identity != Scenario().robot_identity
    renamed = dataclasses.replace(preset("worn"), name="tired", description="")
    assert (renamed.robot_identity, renamed.content_hash) == (
        preset("worn").robot_identity,
        preset("worn").content_hash,
    )


def test_worn_condition_changes_the_physics_not_the_plant() -> None:
    worn = preset("worn")
    assert worn.plant == PlantConfig()
    realism = worn.effective_plant.realism
    assert realism.viscous == pytest.approx(1.5 * PlantRealism().viscous)
    assert realism.coulomb == pytest.approx(1.5 * PlantRealism().coulomb)
    assert realism.actuator_lag == 0.002
    nominal_env, worn_env = DeltaPickPlaceEnv(), DeltaPickPlaceEnv(scenario=worn)
    motor_dofs = worn_env.plant._motor_dofs
    np.testing.assert_allclose(
        worn_env.plant.model.dof_frictionloss[motor_dofs], 1.5 * nominal_env.plant.model.dof_frictionloss[motor_dofs]
    )
    assert worn_env.plant.model.actuator_dynprm[0, 0] == pytest.approx(0.002)


@pytest.mark.parametrize(
    "name",
    # the standard cycle timed online on the whole envelope: its carry's table of continuations, about 40 s of a core
    [pytest.param(name, marks=pytest.mark.slow) if name == "pick-rate-randomized" else name for name in PRESETS],
)
def test_every_preset_builds_and_runs_a_short_episode(name: str, controller_setup) -> None:
    env = gym.make("DeltaPickPlace-v0", scenario=name, n_cycles=1).unwrapped
    scenario = preset(name)
    assert env.n_cycles == 1  # the keyword overrides the scenario's field
    assert (env.cycle, env.start, env.peak_acceleration) == (
        scenario.task.cycle,
        scenario.task.start,
        scenario.task.peak_acceleration,
    )
    assert env.domain_randomization == scenario.task.domain_randomization
    # PD, but on the whole envelope (the data sheet's share) the model row that the planner's margin is left for
    key = "pd" if scenario.task.torque_share < 1.0 else "mid_f_rls_lag"
    # compliant drives: a rate gain of 60 N m s/rad on the motor encoder, through the 1 ms current loop, rings the
    # gearhead's mode up (docs/design.md section 4); 30 does not
    rate_gain = 60.0 if scenario.plant.realism.compliance is None else 30.0
    controller = PDController(3000.0, rate_gain) if key == "pd" else build_controller(key, controller_setup)
    estimator = payload_estimator_of(controller)
    if scenario.task.timing == "online" and estimator is None:  # the cell's estimator beside PD, as the eval runs it
        estimator = cell_estimator(controller_setup)
        controller = EstimatingController(controller, estimator)
    if scenario.task.faults:  # a NaN reading must reach no controller: a monitor cleans the observations
        controller = monitored(controller, controller_setup)
    # a planned timing plans on the identified model: the evaluation gives it
    timed(env, controller_setup, estimator)
    observation, info = env.reset(seed=3)
    low, high = scenario.task.payload_mass_range
    assert np.all((info["payload_masses"] >= low) & (info["payload_masses"] <= high))
    errors = []
    while True:
        observation, _, terminated, truncated, step_info = env.step(controller(observation))
        errors.append(step_info["tracking_error"])
        assert not step_info["torque_saturated"]
        if terminated or truncated:
            break
    assert truncated and not terminated
    assert len(errors) == len(env.trajectory) - 1
    # PD alone: millimetres, not metres (measured 3.6 to 6.7 mm on the presets); the model row: tenths of a millimetre
    fewest, most = (2.5e-3, 10e-3) if key == "pd" else (0.02e-3, 2e-3)
    assert fewest < math.sqrt(np.mean(np.square(errors))) < most
    if name in ("randomized", "pick-rate-randomized"):
        assert env.plant.parameters != env.plant.nominal_parameters
    else:
        assert env.plant.parameters == env.plant.nominal_parameters


def test_paper_preset_is_the_standard_cycle_with_3_8_kg_on_every_pick() -> None:
    env = DeltaPickPlaceEnv(scenario="paper")
    _, info = env.reset(seed=11)
    np.testing.assert_array_equal(info["payload_masses"], [3.8, 3.8, 3.8])
    xyz = env.trajectory.xyz
    pick, place = env.trajectory.pick_indices[0], env.trajectory.place_indices[0]
    assert np.linalg.norm(xyz[place, :2] - xyz[pick, :2]) == pytest.approx(0.305, abs=1e-9)
    assert xyz[:, 2].max() - xyz[pick, 2] == pytest.approx(0.025, abs=1e-9)
    # as in the paper's repeated cycles, the robot starts at rest at the pick point
    assert env.start == "pick"
    np.testing.assert_allclose(xyz[0], xyz[pick], rtol=0, atol=1e-12)


def test_start_is_part_of_the_task_hash_not_of_the_robot() -> None:
    from_pick = Scenario(task=PickPlaceTask(start="pick"))
    assert Scenario().task.start == "place"
    assert from_pick.content_hash != Scenario().content_hash
    assert from_pick.robot_identity == Scenario().robot_identity
    assert Scenario.from_toml(from_pick.to_toml()).task.start == "pick"
    assert DeltaPickPlaceEnv(scenario=from_pick).start == "pick"
    assert DeltaPickPlaceEnv(scenario="paper", start="place").start == "place"  # the keyword overrides
    with pytest.raises(ValueError, match="start must be 'place' or 'pick', got 'home'"):
        PickPlaceTask(start="home")


def test_jerk_limited_is_part_of_the_task_hash_only_when_set() -> None:
    online = Scenario(task=PickPlaceTask(timing="online"))
    jerky = Scenario(task=PickPlaceTask(timing="online", jerk_limited=True))
    assert "jerk_limited" not in scenario_module._task_table(online.task)  # earlier scenarios keep their hashes
    assert jerky.content_hash != online.content_hash and jerky.robot_identity == online.robot_identity
    assert Scenario.from_toml(jerky.to_toml()).task.jerk_limited
    assert DeltaPickPlaceEnv(scenario=jerky).jerk_limited and not DeltaPickPlaceEnv(scenario=online).jerk_limited
    with pytest.raises(ValueError, match="jerk_limited smooths a planned timing's laws; the 'fixed' timing plans none"):
        PickPlaceTask(jerk_limited=True)


def test_keywords_override_the_scenario_and_plant_replaces_its_plant() -> None:
    ideal = PlantConfig.ideal()
    env = DeltaPickPlaceEnv(plant=ideal, scenario="worn", payload_mass_range=(1.0, 2.0), cycle="standard")
    assert env.plant_config == ideal
    assert (env.cycle, env.payload_mass_range, env.n_cycles) == ("standard", (1.0, 2.0), 3)
    with pytest.raises(ValueError, match="scenario must be a preset name"):
        DeltaPickPlaceEnv(scenario=42)


def test_geometry_file_round_trips_and_names_bad_fields(tmp_path) -> None:
    from delta_env.scenario import load_geometry, save_geometry, with_geometry

    design = DeltaGeometry(ra=0.22, rb=0.06, l1=0.35, l2=0.90)
    path = save_geometry(design, tmp_path / "design.toml", extra={"objectives": {"torque_change": -0.1}})
    assert load_geometry(path) == design
    moved = with_geometry(preset("worn"), design)
    assert moved.plant.geometry == design and moved.condition == preset("worn").condition
    assert moved.robot_identity != preset("worn").robot_identity  # another robot
    (tmp_path / "short.toml").write_text("[geometry]\nra = 0.2\nrb = 0.05\nl1 = 0.37\n")
    with pytest.raises(ValueError, match="misses l2"):
        load_geometry(tmp_path / "short.toml")
    (tmp_path / "typo.toml").write_text("[geometry]\nra = 0.2\nrb = 0.05\nl1 = 0.37\nl2 = 0.95\nl3 = 1.0\n")
    with pytest.raises(ValueError, match=r"geometry\.l3"):
        load_geometry(tmp_path / "typo.toml")
    (tmp_path / "inverted.toml").write_text("[geometry]\nra = 0.05\nrb = 0.2\nl1 = 0.37\nl2 = 0.95\n")
    with pytest.raises(ValueError, match="rb"):
        load_geometry(tmp_path / "inverted.toml")


@pytest.mark.parametrize("timestep", [0.0003, 0.0007, 0.0004])
def test_a_timestep_the_env_refuses_is_refused_by_the_plant_config_with_the_same_message(timestep: float) -> None:
    with pytest.raises(ValueError) as from_config:
        PlantConfig(timestep=timestep)
    with pytest.raises(ValueError) as from_check:
        control_substeps(timestep)
    assert str(from_config.value) == str(from_check.value)
    assert f"the physics timestep {timestep} s must divide the control period 0.001 s" in str(from_check.value)


@pytest.mark.parametrize(("timestep", "n_substeps"), [(0.001, 1), (0.0005, 2), (0.00025, 4), (1e-4, 10)])
def test_a_timestep_that_divides_the_control_period_is_accepted(timestep: float, n_substeps: int) -> None:
    assert PlantConfig(timestep=timestep).timestep == timestep
    assert control_substeps(timestep) == n_substeps


@pytest.mark.parametrize("cycle", ["conveyor", "standard"])
def test_a_tasks_peak_acceleration_is_checked_once_on_its_way_to_the_cycles(
    cycle: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    checked = []

    def counted(module: object) -> None:
        check = module.require_peak_acceleration
        monkeypatch.setattr(module, "require_peak_acceleration", lambda value: checked.append(value) or check(value))

    counted(scenario_module)
    counted(cycles)
    scenario = Scenario(task=PickPlaceTask(cycle=cycle, n_cycles=1, peak_acceleration=2.0 * GRAVITY))
    assert checked == [2.0 * GRAVITY], "the task checks it as it is made"
    env = DeltaPickPlaceEnv(scenario=scenario, n_cycles=1)  # as the evaluation makes it: its own cycle count
    for seed in (0, 1):
        env.reset(seed=seed)
    assert checked == [2.0 * GRAVITY], "neither the env nor the cycles it plans check it again"
    assert env.peak_acceleration == 2.0 * GRAVITY
    cycles.standard_cycle(scenario.plant.geometry, 3.0 * GRAVITY)
    assert checked == [2.0 * GRAVITY, 3.0 * GRAVITY], "a cycle built from given values checks them"
    with pytest.raises(ValueError, match="peak_acceleration must be a finite number"):
        DeltaPickPlaceEnv(scenario=scenario, peak_acceleration=0.0)  # an override is checked by the task
