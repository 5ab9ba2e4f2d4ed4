"""The MuJoCo plant against the kinematics, its model conventions, payload handling and randomization."""

from collections.abc import Callable
from dataclasses import replace

import mujoco
import numpy as np
import pytest
from numpy.testing import assert_allclose

from delta_env import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses, kinematics
from delta_env.config import (
    FOREARM_SPACING,
    MIN_PAYLOAD_MASS,
    PhysicalParameters,
    PlantConfig,
    PlantRealism,
    RandomizationRanges,
)
from delta_env.geometry import CHAIN_AZIMUTHS
from delta_env.plant import DeltaPlant
from delta_env.robot import robot_spec
from delta_env.scene import build_mjcf, build_model

CONFIGS = {"ideal": PlantConfig.ideal(), "realistic": PlantConfig()}
VARIANTS = list(CONFIGS)


@pytest.fixture(scope="module", params=VARIANTS)
def plant(request: pytest.FixtureRequest) -> DeltaPlant:
    return DeltaPlant(CONFIGS[request.param])


def equality_rows(data: mujoco.MjData) -> np.ndarray:
    """Mask of the equality-constraint rows (loops, and the suction weld when active) of efc_*."""
    return data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY


def test_assembled_plant_matches_kinematics(plant: DeltaPlant, workzone_angles: Callable) -> None:
    """MuJoCo's own kinematics of the assembled model: platform at FK, loops closed, theta > 0 down."""
    model, data, g = plant.model, plant.data, NOMINAL_GEOMETRY
    rng = np.random.default_rng(0)
    platform = model.body("platform").id
    for theta in workzone_angles(20, seed=1):
        theta_dot = rng.normal(0.0, 2.0, 3)
        plant.assemble(theta, theta_dot)
        assert_allclose(data.xpos[platform], kinematics.forward(g, theta), atol=1e-12)
        assert_allclose(data.xquat[platform], [1.0, 0.0, 0.0, 0.0], atol=1e-12)
        assert plant.loop_gap() < 1e-12
        assert_allclose(plant.joint_angles(), theta, atol=0.0)
        # Each forearm hangs from the elbow F_i + l1 (u_i cos th - e_z sin th), offset along t_i.
        for label, offset, alpha, th in forearms(plant, theta):
            u, t = np.array([np.cos(alpha), np.sin(alpha), 0.0]), np.array([-np.sin(alpha), np.cos(alpha), 0.0])
            elbow = g.ra * u + g.l1 * (np.cos(th) * u - np.sin(th) * np.array([0.0, 0.0, 1.0])) + offset * t
            assert_allclose(data.xpos[model.body(f"forearm_{label}").id], elbow, atol=1e-12)
        # Velocities: loops closed to first order and the platform moves with J theta_dot.
        assert_allclose(plant.loops.jacobian() @ data.qvel, 0.0, atol=1e-12)
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, platform, velocity, 0)
        assert_allclose(velocity[3:], kinematics.jacobian(g, theta) @ theta_dot, atol=1e-12)
        assert_allclose(velocity[:3], 0.0, atol=1e-12)


@pytest.mark.parametrize("variant", VARIANTS)
def test_other_geometry_and_masses_assemble_closed(variant: str) -> None:
    """The MJCF is generated from parameters (design optimization): a smaller, lighter robot."""
    geometry, masses = DeltaGeometry(ra=0.12, rb=0.04, l1=0.25, l2=0.6), DeltaMasses(m1=1.5, m2=0.1, m0=0.5)
    plant = DeltaPlant(replace(CONFIGS[variant], geometry=geometry, masses=masses))
    assert_allclose(plant.platform_position(), kinematics.forward(geometry, np.zeros(3)), atol=1e-15)
    robot = [b for b in range(1, plant.model.nbody) if plant.model.body(b).name != "payload"]
    assert_allclose(plant.model.body_mass[robot].sum(), 3 * masses.m1 + 6 * masses.m2 + masses.m0, rtol=1e-14)
    for theta in np.random.default_rng(12).uniform(-0.3, 1.0, (10, 3)):
        plant.assemble(theta)
        assert_allclose(
            plant.data.xpos[plant.model.body("platform").id], kinematics.forward(geometry, theta), atol=1e-12
        )
        assert plant.loop_gap() < 1e-12


def forearms(plant: DeltaPlant, theta: np.ndarray) -> list[tuple[str, float, float, float]]:
    """(name suffix, offset along t_i in m, alpha_i, theta_i) of every forearm rod."""
    half = FOREARM_SPACING / 2.0
    rods = [("", 0.0)] if plant.config.variant == "ideal" else [("a", half), ("b", -half)]
    return [(f"{i + 1}{rod}", offset, CHAIN_AZIMUTHS[i], theta[i]) for i in range(3) for rod, offset in rods]


def test_platform_follows_forward_kinematics_in_simulation(plant: DeltaPlant, workzone_angles: Callable) -> None:
    """Driven by PD (no assemble), MuJoCo's closed chain keeps the platform at FK(measured angles)."""
    g = NOMINAL_GEOMETRY
    start, goal = workzone_angles(2, seed=3)
    plant.reset(start)
    worst = 0.0
    for k in range(300):
        target = start + (goal - start) * min(1.0, k / 200.0)
        plant.step(3000.0 * (target - plant.joint_angles()) - 60.0 * plant.joint_velocities(), 2)
        error = plant.platform_position() - kinematics.forward(g, plant.joint_angles())
        worst = max(worst, float(np.max(np.abs(error))))
    assert np.max(np.abs(goal - start)) > 0.2
    assert_allclose(plant.joint_angles(), goal, atol=0.01)  # PD without gravity compensation
    assert worst < 2e-5, f"platform left FK(theta) by {worst} m"


def test_home_keyframe_is_assembled_at_rest(plant: DeltaPlant) -> None:
    model, data = plant.model, plant.data
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    assert_allclose(data.qpos, model.qpos0, atol=1e-15)
    assert_allclose(plant.joint_angles(), 0.0, atol=0.0)
    assert_allclose(plant.platform_position(), kinematics.forward(NOMINAL_GEOMETRY, np.zeros(3)), atol=1e-15)
    assert_allclose(plant.platform_position()[2], plant.config.home_height, atol=1e-15)
    assert plant.loop_gap() < 1e-15
    plant.reset()
    assert_allclose(data.qpos, model.qpos0, atol=1e-15)


ALL_VARIANTS = {
    f"{variant}{'' if payload else '_without_payload'}": replace(config, payload_body=payload)
    for variant, config in CONFIGS.items()
    for payload in (True, False)
}
ALL_VARIANTS["realistic_realism_off"] = PlantConfig(realism=PlantRealism.off())


@pytest.mark.parametrize("name", list(ALL_VARIANTS))
def test_every_element_has_a_unique_name(name: str) -> None:
    """Menagerie convention: every body, joint, geom, site, equality, actuator, camera, light and key named."""
    model = build_model(ALL_VARIANTS[name])
    kinds = {
        mujoco.mjtObj.mjOBJ_BODY: model.nbody,
        mujoco.mjtObj.mjOBJ_JOINT: model.njnt,
        mujoco.mjtObj.mjOBJ_GEOM: model.ngeom,
        mujoco.mjtObj.mjOBJ_SITE: model.nsite,
        mujoco.mjtObj.mjOBJ_EQUALITY: model.neq,
        mujoco.mjtObj.mjOBJ_ACTUATOR: model.nu,
        mujoco.mjtObj.mjOBJ_CAMERA: model.ncam,
        mujoco.mjtObj.mjOBJ_LIGHT: model.nlight,
        mujoco.mjtObj.mjOBJ_KEY: model.nkey,
        mujoco.mjtObj.mjOBJ_MATERIAL: model.nmat,
    }
    for kind, count in kinds.items():
        assert count > 0 or kind == mujoco.mjtObj.mjOBJ_EQUALITY
        first = 1 if kind == mujoco.mjtObj.mjOBJ_BODY else 0  # body 0 is MuJoCo's world
        names = [mujoco.mj_id2name(model, kind, i) for i in range(first, count)]
        assert all(names), f"unnamed {kind.name}: {names}"
        assert len(set(names)) == len(names), f"duplicate {kind.name} names: {names}"


@pytest.mark.parametrize("name", list(ALL_VARIANTS))
def test_every_variant_steps_without_mujoco_warnings(name: str) -> None:
    """Menagerie-style smoke test: from the home keyframe, one second of torques raises no MuJoCo warning."""
    model = build_model(ALL_VARIANTS[name])
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    if ALL_VARIANTS[name].payload_body:  # carry a 4 kg payload on the suction weld, at its home offset
        payload, suction = model.body("payload").id, model.equality("suction").id
        model.body_mass[payload] = 4.0
        model.body_gravcomp[payload] = 0.0
        model.eq_data[suction, 3:6] = data.xpos[payload] - data.xpos[model.body("platform").id]
        data.eq_active[suction] = 1
        mujoco.mj_setConst(model, mujoco.MjData(model))
    motors = [model.joint(f"motor_{label}") for label in ("1", "2", "3")]
    angles, rates = [joint.qposadr[0] for joint in motors], [joint.dofadr[0] for joint in motors]
    time = np.arange(2000) * model.opt.timestep
    swing = np.zeros(3)
    for k in range(2000):
        target = 0.2 * np.sin(2.0 * np.pi * np.array([1.0, 1.5, 2.0]) * time[k])
        data.ctrl[:] = 3000.0 * (target - data.qpos[angles]) - 60.0 * data.qvel[rates] + 60.0
        mujoco.mj_step(model, data)
        swing = np.maximum(swing, np.abs(data.qpos[angles]))
    warnings = {mujoco.mjtWarning(i).name: w.number for i, w in enumerate(data.warning) if w.number}
    assert not warnings, warnings
    assert np.all(np.isfinite(data.qpos))
    assert np.all(swing > 0.1), "the arms must have moved"


@pytest.mark.parametrize("variant", VARIANTS)
def test_robot_compiles_on_its_own_and_the_mjcf_text_loads(variant: str) -> None:
    """The robot spec needs no scene; the scene's MJCF text (6 significant digits) loads into the same model."""
    robot = robot_spec(CONFIGS[variant]).compile()
    scene = build_model(CONFIGS[variant])
    assert robot.nv == scene.nv - 6 and robot.nu == scene.nu == 3
    assert robot.neq == scene.neq - 1, "the scene adds the suction weld"
    reloaded = mujoco.MjModel.from_xml_string(build_mjcf(CONFIGS[variant]))
    for field in ("body_mass", "body_inertia", "body_pos", "jnt_axis", "dof_damping", "eq_solref", "qpos0"):
        assert_allclose(getattr(reloaded, field), getattr(scene, field), rtol=1e-5, atol=1e-6, err_msg=field)


@pytest.mark.parametrize("variant", VARIANTS)
def test_two_seconds_of_pick_and_place_raise_no_warnings(variant: str) -> None:
    """A PD-driven motion with a 4 kg pick and release: no MuJoCo warning, loops closed throughout."""
    plant = DeltaPlant(CONFIGS[variant])
    g = NOMINAL_GEOMETRY
    pick, place = kinematics.inverse(g, [[0.3, 0.0, -0.95], [-0.2, 0.3, -0.85]])
    plant.reset(pick)
    plant.place_payload(plant.suction_cup_position() - [0.0, 0.0, 0.05], 4.0, (0.1, 0.1, 0.1))
    plant.attach_payload()
    worst_gap = 0.0
    for k in range(2000):
        s = min(1.0, k / 800.0)
        target = pick + (place - pick) * (10 * s**3 - 15 * s**4 + 6 * s**5)
        hold = -50.0  # N m, about the gravity-holding torque
        plant.step(3000.0 * (target - plant.joint_angles()) - 60.0 * plant.joint_velocities() + hold, 2)
        if k == 1000:
            plant.release_payload()
        worst_gap = max(worst_gap, plant.loop_gap())
        assert plant.data.ncon == 0, "robot parts and the payload must not collide"
    assert [w.number for w in plant.data.warning] == [0] * mujoco.mjtWarning.mjNWARNING
    assert np.all(np.isfinite(plant.data.qpos))
    assert worst_gap < 1e-4
    assert_allclose(plant.joint_angles(), place, atol=0.02)


@pytest.mark.parametrize(
    ("variant", "payload_body", "nv", "loop_rows"),
    [("ideal", False, 12, 9), ("ideal", True, 18, 9), ("realistic", False, 21, 18), ("realistic", True, 27, 18)],
)
def test_degrees_of_freedom_and_independent_loop_rows(
    variant: str, payload_body: bool, nv: int, loop_rows: int, workzone_angles: Callable
) -> None:
    plant = DeltaPlant(replace(CONFIGS[variant], payload_body=payload_body))
    model, data = plant.model, plant.data
    assert model.nv == nv
    plant.assemble(workzone_angles(1, seed=4)[0])
    rows = _equality_jacobian(plant)
    assert rows.shape[0] == loop_rows == plant.loops.n_rows
    robot_dofs = model.nv - (6 if payload_body else 0)
    assert robot_dofs - loop_rows == 3, "the closed chain must have exactly the three motor DOF"
    assert np.linalg.matrix_rank(rows) == loop_rows
    if payload_body:
        plant.attach_payload()
        mujoco.mj_forward(model, data)
        assert np.linalg.matrix_rank(_equality_jacobian(plant)) == loop_rows + 6


def _equality_jacobian(plant: DeltaPlant) -> np.ndarray:
    model, data = plant.model, plant.data
    jacobian = data.efc_J.reshape(data.nefc, model.nv)
    return jacobian[equality_rows(data)]


def test_sign_of_motor_torque_lifts_the_arm() -> None:
    """A hinge with axis t_i has qpos = theta: a negative torque (gravity's sign) turns the arm up."""
    plant = DeltaPlant(CONFIGS["ideal"])
    plant.step(np.full(3, -300.0), 20)
    assert np.all(plant.joint_velocities() < 0.0)
    assert plant.platform_position()[2] > plant.config.home_height


def test_payload_floats_free_and_follows_when_attached(workzone_angles: Callable) -> None:
    plant = DeltaPlant(CONFIGS["realistic"])
    theta = workzone_angles(2, seed=5)
    plant.reset(theta[0])
    spot = np.array([0.4, -0.3, -1.0])
    plant.place_payload(spot, 0.0, (0.2, 0.1, 0.05))
    assert plant.payload_mass == MIN_PAYLOAD_MASS
    box_inertia = MIN_PAYLOAD_MASS / 12 * np.array([0.1**2 + 0.05**2, 0.2**2 + 0.05**2, 0.2**2 + 0.1**2])
    assert_allclose(plant.model.body_inertia[plant.model.body("payload").id], box_inertia, rtol=1e-14)
    for _ in range(100):
        plant.step(np.zeros(3), 2)
    assert_allclose(plant.payload_position(), spot, atol=0.0)

    plant.reset(theta[0])
    cup = plant.suction_cup_position()
    plant.place_payload(cup - [0.0, 0.0, 0.05], 3.0, (0.1, 0.1, 0.1))
    assert plant.payload_mass == 3.0 and not plant.payload_attached
    plant.attach_payload()
    offset = plant.payload_position() - plant.platform_position()
    for k in range(300):
        target = theta[0] + (theta[1] - theta[0]) * min(1.0, k / 200.0)
        plant.step(3000.0 * (target - plant.joint_angles()) - 60.0 * plant.joint_velocities(), 2)
        assert_allclose(plant.payload_position() - plant.platform_position(), offset, atol=1e-5)
    plant.release_payload()
    released = plant.payload_position()
    for _ in range(100):
        plant.step(np.zeros(3), 2)
    assert_allclose(plant.payload_position(), released, atol=1e-12)
    assert not plant.payload_attached


def test_assemble_carries_an_attached_payload(workzone_angles: Callable) -> None:
    plant = DeltaPlant(CONFIGS["realistic"])
    plant.place_payload(plant.suction_cup_position() - [0.02, 0.0, 0.05], 2.0, (0.1, 0.1, 0.1))
    plant.attach_payload()
    offset = plant.payload_position() - plant.platform_position()
    theta_dot = np.array([1.0, -2.0, 0.5])
    plant.assemble(workzone_angles(1, seed=6)[0], theta_dot)
    weld = plant.data.efc_pos[equality_rows(plant.data)][-6:]
    assert_allclose(weld, 0.0, atol=1e-12)
    assert_allclose(plant.payload_position() - plant.platform_position(), offset, atol=1e-12)
    payload_velocity = plant.data.qvel[plant.model.jnt_dofadr[plant.model.joint("payload").id] :][:3]
    platform_velocity = kinematics.jacobian(NOMINAL_GEOMETRY, plant.joint_angles()) @ theta_dot
    assert_allclose(payload_velocity, platform_velocity, atol=1e-12)


@pytest.mark.parametrize("variant", VARIANTS)
def test_step_holds_stribeck_and_ripple_of_the_state_at_the_call(variant: str, workzone_angles: Callable) -> None:
    plant = DeltaPlant(CONFIGS[variant])
    plant.assemble(workzone_angles(1, seed=7)[0], [0.02, -0.5, 0.0])
    theta = plant.joint_angles()
    expected = plant.motor_disturbance(theta, plant.joint_velocities())
    plant.step(np.zeros(3), 2)
    assert_allclose(plant.data.qfrc_applied[plant.motor_dofs], expected, rtol=1e-14, atol=1e-14)
    if variant == "ideal":
        assert_allclose(expected, 0.0, atol=0.0)
    else:
        realism = plant.config.realism
        ripple = realism.ripple_amplitude * np.sin(realism.ripple_periods * theta)
        assert expected[0] < ripple[0] - 0.5 * realism.stribeck_excess * realism.coulomb_per_joint[0]
        assert abs(expected[2] - ripple[2]) < 1e-15  # at rest: a smooth sign gives no Stribeck torque


def test_stribeck_is_odd_smooth_and_bounded() -> None:
    plant = DeltaPlant(CONFIGS["realistic"])
    realism = plant.config.realism
    theta = np.zeros(3)  # sin(180 * 0) = 0: no ripple
    speeds = np.linspace(-0.5, 0.5, 2001)[:, None] * np.ones(3)
    friction = plant.motor_disturbance(theta, speeds)
    assert_allclose(friction, -friction[::-1], atol=1e-15)
    assert np.all(np.abs(friction) <= realism.stribeck_excess * realism.coulomb_per_joint + 1e-12)
    assert np.all(friction[speeds > 0.0] < 0.0), "the excess opposes the motion"
    slope = np.max(np.abs(np.diff(friction, axis=0)) / np.diff(speeds, axis=0))
    assert slope < 4.0 * realism.stribeck_excess * realism.coulomb_per_joint.max() / realism.stribeck_velocity


def test_randomize_edits_the_model_in_place_and_restores_nominal() -> None:
    plant = DeltaPlant(CONFIGS["realistic"])
    model = plant.model
    fields = ("body_mass", "body_inertia", "body_ipos", "dof_damping", "dof_frictionloss", "actuator_dynprm")
    nominal = {name: getattr(model, name).copy() for name in fields}
    robot = [model.body(name).id for name in ("platform", "upper_arm_1", "forearm_1a")]
    motors = plant.motor_dofs

    parameters = plant.randomize(np.random.default_rng(8))
    assert parameters == plant.parameters
    assert parameters == DeltaPlant(CONFIGS["realistic"]).randomize(np.random.default_rng(8)), "deterministic"
    masses = parameters.masses
    for value, reference in zip(
        (masses.m1, masses.m2, masses.m0), (NOMINAL_MASSES.m1, NOMINAL_MASSES.m2, NOMINAL_MASSES.m0), strict=True
    ):
        assert 0.9 * reference <= value <= 1.1 * reference
    assert_allclose(model.body_mass[robot], [masses.m0, masses.m1, masses.m2], rtol=1e-14)
    assert_allclose(
        model.dof_frictionloss[motors], plant.config.realism.coulomb_per_joint * parameters.friction_scale, rtol=1e-14
    )
    assert_allclose(model.actuator_dynprm[:, 0], parameters.actuator_lag)
    assert 0.0005 <= parameters.actuator_lag <= 0.002
    stribeck = plant.motor_disturbance(np.zeros(3), np.full(3, 0.01))  # theta = 0: no ripple
    plant.restore_nominal()
    assert_allclose(stribeck / plant.motor_disturbance(np.zeros(3), np.full(3, 0.01)), parameters.friction_scale)

    for name in fields:
        assert_allclose(getattr(model, name), nominal[name], rtol=1e-15, err_msg=name)
    assert plant.parameters == plant.nominal_parameters


def test_mass_changes_reach_the_dynamics() -> None:
    """Simple-body optimizations must not freeze the platform's or payload's mass at compile time."""
    plant = DeltaPlant(CONFIGS["ideal"])
    heavier = PhysicalParameters(masses=replace(NOMINAL_MASSES, m0=2.0 * NOMINAL_MASSES.m0))
    plant.set_physical_parameters(heavier)
    plant.assemble(np.zeros(3))
    inertia = np.zeros((plant.model.nv, plant.model.nv))
    mujoco.mj_fullM(plant.model, plant.data, inertia)
    platform_x = plant.model.joint("platform_x").dofadr[0]
    assert_allclose(inertia[platform_x, platform_x], 2.0 * NOMINAL_MASSES.m0, rtol=1e-14)
    plant.place_payload(plant.platform_position() + np.array([0.5, 0.0, 0.0]), 2.5)
    payload = plant.model.body("payload").id
    mujoco.mj_fullM(plant.model, plant.data, inertia)
    assert_allclose(inertia[plant.model.body_dofadr[payload], plant.model.body_dofadr[payload]], 2.5, rtol=1e-14)
    # The suction weld's softness scales with the payload's inverse mass, refreshed by mj_setConst.
    assert_allclose(plant.model.body_invweight0[payload, 0], 1.0 / 2.5, rtol=1e-12)


def test_randomizing_while_carrying_keeps_the_released_payload_floating() -> None:
    """mj_setConst derives the gravity-compensation flag; a carried payload has gravcomp 0 at that moment."""
    plant = DeltaPlant(CONFIGS["realistic"])
    plant.place_payload(plant.suction_cup_position() - np.array([0.0, 0.0, 0.05]), 2.0)
    plant.attach_payload()
    plant.randomize(np.random.default_rng(9))
    plant.release_payload()
    released = plant.payload_position()
    for _ in range(200):
        plant.step(np.zeros(3), 2)
    assert_allclose(plant.payload_position(), released, atol=1e-12)


def _bad_calls() -> dict[str, tuple[Callable[[], object], str]]:
    realistic = DeltaPlant(CONFIGS["realistic"])
    ideal = DeltaPlant(replace(CONFIGS["ideal"], payload_body=False))
    return {
        "negative armature": (lambda: PlantRealism(armature=-0.1), "armature"),
        "two scales": (lambda: PlantRealism(viscous_scale=(1.0, 1.0)), "viscous_scale"),
        "zero stribeck velocity": (lambda: PlantRealism(stribeck_velocity=0.0), "stribeck_velocity"),
        "fractional periods": (lambda: PlantRealism(ripple_periods=1.5), "ripple_periods"),
        "encoder bits": (lambda: PlantRealism(encoder_bits=4), "encoder_bits"),
        "unknown variant": (lambda: PlantConfig(variant="fancy"), "variant"),
        "ideal with friction": (lambda: PlantConfig(variant="ideal"), "MKH"),
        "large timestep": (lambda: PlantConfig(timestep=0.01), "timestep"),
        "short forearm": (lambda: PlantConfig(geometry=DeltaGeometry(l1=0.37, l2=0.5)), "l2"),
        "negative mass": (lambda: PhysicalParameters(masses=replace(NOMINAL_MASSES, m1=-1.0)), "m1"),
        "negative payload": (lambda: realistic.place_payload([0.0, 0.0, -1.0], -1.0), "mass"),
        "flat payload": (lambda: realistic.place_payload([0.0, 0.0, -1.0], 1.0, (0.1, 0.1, 0.0)), "size"),
        "unreachable angles": (lambda: realistic.assemble([0.0, 0.0, np.pi]), "no real solution"),
        "nan angles": (lambda: realistic.assemble([0.0, np.nan, 0.0]), "theta"),
        "lag on a lagless plant": (lambda: ideal.randomize(np.random.default_rng(0)), "actuator lag"),
        "lag removed": (lambda: realistic.set_physical_parameters(PhysicalParameters(NOMINAL_MASSES)), "actuator_lag"),
        "bad lag range": (lambda: RandomizationRanges(actuator_lag=(0.002, 0.001)), "actuator_lag"),
        "no payload body": (lambda: ideal.attach_payload(), "payload_body=False"),
    }


BAD_CALLS = _bad_calls()


@pytest.mark.parametrize("case", list(BAD_CALLS))
def test_bad_input_raises_a_clear_error(case: str) -> None:
    call, message = BAD_CALLS[case]
    with pytest.raises((ValueError, RuntimeError), match=message):
        call()
