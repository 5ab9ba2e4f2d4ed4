"""The Delta robot as a ``mujoco.MjSpec``: bodies, joints, loop closures and motors (docs/design.md section 4).

Two variants share one builder, :func:`robot_spec`:

- ``ideal`` satisfies the Kuo-Huang (MKH) assumptions of the analytical model exactly (platform on three
  slides, one forearm rod per chain whose mass m2 sits at its lower end, upper arm with the lumped inertia
  (m1/3 + m2) l1^2), so that the analytical dynamics can be validated against MuJoCo to round-off.
- ``realistic`` is a true parallelogram Delta (two rods per chain, free-joint platform held level only by
  the parallelograms) with the drive effects of :class:`~delta_env.config.PlantRealism` that the
  analytical model ignores.

Conventions follow docs/design.md section 1: chain i = 1, 2, 3 at azimuth alpha_i, motor hinge axis
t_i = e_z x u_i so that the motor joint's qpos is theta_i and theta_i > 0 turns the arm down. Like a
MuJoCo Menagerie robot, the robot is separate from its scene (:mod:`delta_env.scene` adds the floor,
light, camera and payload) and every element is named.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from delta_env.config import FOREARM_SPACING, SUCTION_CUP_OFFSET, PlantConfig
from delta_env.geometry import CHAIN_AZIMUTHS, CHAIN_COS, CHAIN_SIN, GRAVITY, DeltaGeometry, DeltaMasses
from delta_env.scaling import forearm_rod_radius, upper_arm_tube_radius

CHAIN_LABELS = ("1", "2", "3")
"""Chain suffixes used in element names (``motor_1`` ... ``motor_3``), docs/design.md numbering."""

ROD_LABELS = ("a", "b")
"""Rod suffixes of a realistic parallelogram: rod a sits at +FOREARM_SPACING/2 along t_i, rod b at -."""

HOME_KEY = "home"
"""Name of the keyframe with the assembled home pose (arms horizontal, loops closed, at rest)."""

POINT_INERTIA = 1e-12
"""Inertia (kg m^2) of the "point" bodies of the ideal variant; adds ~1e-10 N m at 100 rad/s^2."""

ROTOR_BODY_MASS = 1e-12
"""Mass (kg) of a compliant drive's rotor body: a point on its fixed axis, which neither gravity nor motion loads
(MuJoCo needs a moving body's mass > 0); the rotor's inertia is its joint's armature."""

UPPER_ARM_SPLIT = {"hub": 0.30, "tube": 0.50, "bar": 0.20}
"""Fractions of m1 in the hub, tube and elbow bar of the realistic upper arm."""

PLATFORM_THICKNESS = 0.02
"""Thickness (m) of the platform disc."""

PLATFORM_RIM = 0.015
"""How far (m) the platform disc reaches beyond its outermost ball-joint centres."""

ELBOW_BAR_RADIUS = 0.018
"""Radius (m) of the elbow bar that carries a chain's two upper ball joints."""

ELBOW_BAR_OVERHANG = 0.015
"""How far (m) the elbow bar reaches beyond each upper ball-joint centre along the motor axis."""

UPPER_ARM_TUBE_SPAN = (0.12, 0.96)
"""Where the upper arm's tube starts and ends, as fractions of l1 from the motor axis (hub and elbow bar beyond)."""

UPPER_ARM_HUB = (0.045, 0.05)
"""Half-length along the motor axis and radius (m) of the upper arm's hub on the gearbox output."""

BASE_PLATE_OVERHANG = 0.12
"""How far (m) the base plate reaches beyond the motor axes' circle (radius ra + this)."""

BASE_PLATE_Z = (0.13, 0.17)
"""Bottom and top (m) of the base plate: its bottom clears the upper arms' tubes up to 0.6 rad above
horizontal (the motor range of :data:`delta_env.workspace.THETA_RANGE`) on every arm up to 0.55 m long
(tests/test_collisions.py checks it)."""

ROBOT_CONTACT_BIT = 4
"""Contact bit (contype and conaffinity) of the robot's collision geometry when ``PlantConfig.collisions`` is on:
its links and the base plate collide with each other and with nothing else."""

ROBOT_MATERIALS = {
    "base": (0.35, 0.37, 0.4, 1.0),
    "arm": (0.9, 0.55, 0.1, 1.0),
    "rod": (0.15, 0.15, 0.15, 1.0),
    "platform": (0.7, 0.72, 0.75, 1.0),
    "cup": (0.2, 0.4, 0.8, 1.0),
}
"""RGBA of the robot's materials."""

EQUALITY_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
"""Impedance of the loop closures and the suction weld: nearly hard (MuJoCo's default opens the loops by ~8 mm)."""

_VISUAL_GROUP = 2
_SITE_GROUP = 4
_SITE_RGBA = (1.0, 0.3, 0.1, 1.0)
_SITE_SIZE = (0.008, 0.005, 0.005)  # radius of the sphere; the rest are MuJoCo's defaults


def equality_solref(config: PlantConfig) -> tuple[float, float]:
    """Reference (time constant s, damping ratio) of the loop closures and the suction weld.

    The time constant 2 x timestep is MuJoCo's refsafe minimum, the stiffest closure that stays stable.
    """
    return (2.0 * config.timestep, 1.0)


def forearm_home_tilt(geometry: DeltaGeometry) -> float:
    """Angle (rad) of the forearms from the vertical, inward about t_i, at home (theta = 0).

    The ball-joint cups are mounted along this direction (:mod:`delta_env.buildability`). For a geometry whose
    forearms cannot reach below the base with the arms horizontal (no plant exists) it is the limit pi/2.
    """
    reach = geometry.r + geometry.l1
    return math.atan2(reach, math.sqrt(max(geometry.l2**2 - reach**2, 0.0)))


def ideal_upper_arm_inertial(geometry: DeltaGeometry, masses: DeltaMasses) -> tuple[float, float, float]:
    """Mass (kg), CoM distance from the motor axis (m) and inertia about the CoM (kg m^2) of the ideal arm.

    The arm carries m1 (homogeneous rod) plus the elbow half m2 of its forearm pair, so that the gravity
    torque is -(m1/2 + m2) g l1 cos(theta) and the inertia about the motor axis is (m1/3 + m2) l1^2.
    """
    mass = masses.m1 + masses.m2
    com = (masses.m1 / 2.0 + masses.m2) * geometry.l1 / mass
    inertia_about_com = (masses.m1 / 3.0 + masses.m2) * geometry.l1**2 - mass * com**2
    return mass, com, inertia_about_com


def rod_offsets(config: PlantConfig) -> tuple[tuple[str, float], ...]:
    """(label, offset along t_i in m) of the forearm rods of one chain: one rod (ideal) or two."""
    if config.variant == "ideal":
        return (("", 0.0),)
    return ((ROD_LABELS[0], FOREARM_SPACING / 2.0), (ROD_LABELS[1], -FOREARM_SPACING / 2.0))


def robot_spec(config: PlantConfig) -> mujoco.MjSpec:
    """The robot of ``config`` as an MjSpec, with a ``home`` keyframe; it compiles on its own.

    The model's reference configuration qpos0 is the assembled home pose (arms horizontal, loops
    closed), which the ``home`` keyframe repeats explicitly.

    Raises:
        ValueError: if ``config`` is not a :class:`~delta_env.config.PlantConfig`.
    """
    if not isinstance(config, PlantConfig):
        raise ValueError(f"config must be a PlantConfig, got {type(config).__name__}")
    spec = mujoco.MjSpec()
    spec.modelname = f"delta_{config.variant}"
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    _set_options(spec, config)
    classes = _add_defaults(spec, config)
    for name, rgba in ROBOT_MATERIALS.items():
        spec.add_material(name=name, rgba=rgba)
    home_qpos: list[float] = []
    bottom, top = BASE_PLATE_Z
    spec.worldbody.add_geom(
        name="base_plate",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        pos=(0.0, 0.0, (bottom + top) / 2.0),
        size=(config.geometry.ra + BASE_PLATE_OVERHANG, (top - bottom) / 2.0, 0.0),
        material="base",
    )
    _add_platform(spec, config, classes, home_qpos)
    for index in range(3):
        _add_chain(spec, config, index, classes, home_qpos)
    _add_loop_closures(spec, config)
    if config.realism.compliance is not None:
        _add_gearheads(spec, config)
    _add_motors(spec, config)
    if config.collisions:
        _enable_collisions(spec)
    spec.add_key(name=HOME_KEY, qpos=home_qpos)
    return spec


def collision_geom_names() -> tuple[str, ...]:
    """Names of the geoms that collide when ``PlantConfig.collisions`` is on (realistic variant).

    The base plate, each upper arm's tube and elbow bar, every forearm rod and the platform disc; the hubs sit on
    the motor axes (they turn in place) and the suction cup is the gripper's.
    """
    names = ["base_plate", "platform_disc"]
    for label in CHAIN_LABELS:
        names += [f"upper_arm_{label}_tube", f"upper_arm_{label}_bar"]
        names += [f"forearm_{label}{rod}_rod" for rod in ROD_LABELS]
    return tuple(names)


def _enable_collisions(spec: mujoco.MjSpec) -> None:
    """Turn on the contacts of :func:`collision_geom_names` among themselves (:data:`ROBOT_CONTACT_BIT`).

    Excluded: each forearm with the platform it is ball-jointed to (the loop pairs); MuJoCo already filters each
    forearm with its parent upper arm. Contacts are hard (MuJoCo's default softness), so a touch is visible as a
    contact and a push.
    """
    for name in collision_geom_names():
        geom = spec.geom(name)
        geom.contype = ROBOT_CONTACT_BIT
        geom.conaffinity = ROBOT_CONTACT_BIT
    for label in CHAIN_LABELS:
        for rod in ROD_LABELS:
            spec.add_exclude(bodyname1="platform", bodyname2=f"forearm_{label}{rod}")


def _set_options(spec: mujoco.MjSpec, config: PlantConfig) -> None:
    # timestep 0.5 ms with implicitfast: with the stiffest safe loop closures the loop gap stays below
    # 1e-5 m in a 6 g cycle with 3.8 kg (docs/design.md section 4). Dense Jacobians: MuJoCo 4.0.0's
    # sparse Cholesky gives the Newton solver wrong factors (fixed in MuJoCo 4.0.1).
    option = spec.option
    option.timestep = config.timestep
    option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    option.gravity = (0.0, 0.0, -GRAVITY)
    option.solver = mujoco.mjtSolver.mjSOL_NEWTON
    option.jacobian = mujoco.mjtJacobian.mjJAC_DENSE


def _add_defaults(spec: mujoco.MjSpec, config: PlantConfig) -> dict[str, mujoco.MjsDefault]:
    """The default classes; returns them by name (``motor``, ``elbow``, ``platform_slide``, ``visual``)."""
    main = spec.default
    # No contacts anywhere: robot parts and the payload pass through each other.
    main.geom.contype = 0
    main.geom.conaffinity = 0
    main.geom.group = 1
    main.site.size = _SITE_SIZE
    main.site.group = _SITE_GROUP
    main.site.rgba = _SITE_RGBA
    motor = spec.add_default("motor", main)
    motor.joint.type = mujoco.mjtJoint.mjJNT_HINGE
    motor.joint.axis = (0.0, 1.0, 0.0)
    motor.joint.armature = config.realism.armature
    # Coulomb friction (frictionloss) is a constraint too: at MuJoCo's default solref (20 ms) it acts as a
    # stiff viscous term below ~1 rad/s and even reverses while a joint brakes; the refsafe minimum
    # 2 x timestep makes it behave like Coulomb friction down to ~0.1 rad/s.
    motor.joint.solref_friction = equality_solref(config)
    elbow = spec.add_default("elbow", main)
    elbow.joint.type = mujoco.mjtJoint.mjJNT_HINGE
    platform_slide = spec.add_default("platform_slide", main)
    platform_slide.joint.type = mujoco.mjtJoint.mjJNT_SLIDE
    visual = spec.add_default("visual", main)
    visual.geom.group = _VISUAL_GROUP
    visual.geom.mass = 0.0
    return {"motor": motor, "elbow": elbow, "platform_slide": platform_slide, "visual": visual}


def _chain_frame(index: int) -> tuple[np.ndarray, np.ndarray]:
    """u_i (outward) and t_i = e_z x u_i (motor axis) of chain ``index``."""
    cos_alpha, sin_alpha = CHAIN_COS[index], CHAIN_SIN[index]
    return np.array([cos_alpha, sin_alpha, 0.0]), np.array([-sin_alpha, cos_alpha, 0.0])


def _cylinder(fromto: tuple[float, ...], radius: float) -> dict[str, object]:
    fromto_array = np.array([float(v) for v in fromto])
    return {"type": mujoco.mjtGeom.mjGEOM_CYLINDER, "fromto": fromto_array, "size": (radius, 0.0, 0.0)}


def _add_platform(
    spec: mujoco.MjSpec, config: PlantConfig, classes: dict[str, mujoco.MjsDefault], home_qpos: list[float]
) -> None:
    g, m = config.geometry, config.masses
    disc = (platform_disc_radius(g), PLATFORM_THICKNESS / 2.0, 0.0)
    # The platform's origin is E0. Not "simple": its mass changes at run time (oracle, randomization).
    platform = spec.worldbody.add_body(name="platform", pos=(0.0, 0.0, config.home_height))
    platform.simple = 0
    cylinder = mujoco.mjtGeom.mjGEOM_CYLINDER
    if config.variant == "ideal":
        # MKH: the platform only translates and is a point mass m0.
        for axis_name, axis in (("x", (1.0, 0.0, 0.0)), ("y", (0.0, 1.0, 0.0)), ("z", (0.0, 0.0, 1.0))):
            platform.add_joint(classes["platform_slide"], name=f"platform_{axis_name}", axis=axis)
            home_qpos.append(0.0)
        _set_inertial(platform, (0.0, 0.0, 0.0), m.m0, (POINT_INERTIA,) * 3)
        platform.add_geom(classes["visual"], name="platform_disc", type=cylinder, size=disc, material="platform")
    else:
        # Free joint: the parallelograms alone keep the platform level.
        platform.add_freejoint(name="platform")
        home_qpos.extend([0.0, 0.0, config.home_height, 1.0, 0.0, 0.0, 0.0])
        platform.add_geom(name="platform_disc", type=cylinder, size=disc, mass=m.m0, material="platform")
    cup = (0.0, 0.0, -PLATFORM_THICKNESS / 2.0, 0.0, 0.0, -SUCTION_CUP_OFFSET)
    platform.add_geom(classes["visual"], name="suction_cup", material="cup", **_cylinder(cup, 0.02))
    platform.add_site(name="suction_cup", pos=(0.0, 0.0, -SUCTION_CUP_OFFSET))
    for index, label in enumerate(CHAIN_LABELS):
        u, t = _chain_frame(index)
        for rod, offset in rod_offsets(config):
            platform.add_site(name=f"platform_{label}{rod}", pos=g.rb * u + offset * t)


def platform_disc_radius(geometry: DeltaGeometry) -> float:
    """Radius (m) of the platform disc: its outermost ball-joint centres plus :data:`PLATFORM_RIM`."""
    return math.hypot(geometry.rb, FOREARM_SPACING / 2.0) + PLATFORM_RIM


def upper_arm_parts(geometry: DeltaGeometry) -> dict[str, tuple[tuple[float, ...], float]]:
    """The upper arm's hub, tube and elbow bar: (fromto in the arm frame (x = u_i, y = t_i, z up) in m, radius m).

    The tube's radius follows the stiffness rule of :mod:`delta_env.scaling`.
    """
    l1 = geometry.l1
    start, end = UPPER_ARM_TUBE_SPAN
    hub_half, hub_radius = UPPER_ARM_HUB
    bar_half = FOREARM_SPACING / 2.0 + ELBOW_BAR_OVERHANG
    return {
        "hub": ((0.0, -hub_half, 0.0, 0.0, hub_half, 0.0), hub_radius),
        "tube": ((start * l1, 0.0, 0.0, end * l1, 0.0, 0.0), upper_arm_tube_radius(l1)),
        "bar": ((l1, -bar_half, 0.0, l1, bar_half, 0.0), ELBOW_BAR_RADIUS),
    }


def _set_inertial(body: mujoco.MjsBody, pos: tuple[float, ...], mass: float, diaginertia: tuple[float, ...]) -> None:
    """An explicit inertial (MJCF ``<inertial>``): the body's geoms then carry no mass."""
    body.explicitinertial = True
    body.ipos = pos
    body.iquat = (1.0, 0.0, 0.0, 0.0)
    body.mass = mass
    body.inertia = diaginertia


def _add_upper_arm_geoms(
    arm: mujoco.MjsBody, config: PlantConfig, label: str, classes: dict[str, mujoco.MjsDefault]
) -> None:
    g, m = config.geometry, config.masses
    parts = upper_arm_parts(g)
    ideal = config.variant == "ideal"
    if ideal:
        # MKH: rod m1 plus the elbow half m2 of the forearm pair, lumped exactly; the geoms are visual.
        mass, com, inertia = ideal_upper_arm_inertial(g, m)
        _set_inertial(arm, (com, 0.0, 0.0), mass, (POINT_INERTIA, inertia, inertia))
    # Realistic: hub + tube + elbow bar, total m1, with a CoM and inertia unlike the MKH homogeneous rod.
    for part, (fromto, radius) in parts.items():
        name = f"upper_arm_{label}_{part}"
        if ideal:
            arm.add_geom(classes["visual"], name=name, material="arm", **_cylinder(fromto, radius))
        else:
            mass = UPPER_ARM_SPLIT[part] * m.m1
            arm.add_geom(name=name, material="arm", mass=mass, **_cylinder(fromto, radius))


def _quat_z(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2.0), 0.0, 0.0, math.sin(angle / 2.0))


def _quat_y(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2.0), 0.0, math.sin(angle / 2.0), 0.0)


def _add_chain(
    spec: mujoco.MjSpec,
    config: PlantConfig,
    index: int,
    classes: dict[str, mujoco.MjsDefault],
    home_qpos: list[float],
) -> None:
    g, m, realism = config.geometry, config.masses, config.realism
    label, alpha = CHAIN_LABELS[index], float(CHAIN_AZIMUTHS[index])
    u, _ = _chain_frame(index)
    # Local frame of the upper arm: x = u_i (outward), y = t_i (motor axis), z up.
    arm = spec.worldbody.add_body(name=f"upper_arm_{label}", pos=g.ra * u, quat=_quat_z(alpha))
    # The drive's friction acts where its torque does: on the arm's joint, or on the rotor of a compliant drive.
    friction = {
        "damping": [float(realism.viscous_per_joint[index])],
        "frictionloss": float(realism.coulomb_per_joint[index]),
    }
    compliant = realism.compliance is not None
    arm.add_joint(classes["motor"], name=f"motor_{label}", **({} if compliant else friction))
    home_qpos.append(0.0)
    housing = (0.0, -0.08, 0.0, 0.0, 0.08, 0.0)
    arm.add_geom(classes["visual"], name=f"motor_{label}_housing", material="base", **_cylinder(housing, 0.07))
    _add_upper_arm_geoms(arm, config, label, classes)
    tilt = _quat_y(forearm_home_tilt(g))
    for rod, offset in rod_offsets(config):
        name = f"{label}{rod}"
        forearm = arm.add_body(name=f"forearm_{name}", pos=(g.l1, offset, 0.0), quat=tilt)
        forearm.add_joint(classes["elbow"], name=f"elbow_{name}_pitch", axis=(0.0, 1.0, 0.0))
        forearm.add_joint(classes["elbow"], name=f"elbow_{name}_roll", axis=(1.0, 0.0, 0.0))
        home_qpos.extend([0.0, 0.0])
        rod_line = (0.0, 0.0, 0.0, 0.0, 0.0, -g.l2)
        rod_radius = forearm_rod_radius(g.l2)
        if config.variant == "ideal":
            # MKH: the platform half m2 of the pair, a point at the lower end; the geom is visual.
            _set_inertial(forearm, (0.0, 0.0, -g.l2), m.m2, (POINT_INERTIA,) * 3)
            forearm.add_geom(
                classes["visual"], name=f"forearm_{name}_rod", material="rod", **_cylinder(rod_line, rod_radius)
            )
        else:
            forearm.add_geom(name=f"forearm_{name}_rod", material="rod", mass=m.m2, **_cylinder(rod_line, rod_radius))
        forearm.add_site(name=f"forearm_{name}_end", pos=(0.0, 0.0, -g.l2))
    if compliant:
        # The motor's rotor, coaxial with the arm, its angle at the joint's scale (the shaft's over the ratio): its
        # reflected inertia is the joint's armature, the body itself a point on the axis (no gravity moment).
        rotor = spec.worldbody.add_body(name=f"rotor_{label}", pos=g.ra * u, quat=_quat_z(alpha))
        rotor.add_joint(classes["motor"], name=f"rotor_{label}", armature=realism.compliance.rotor_inertia, **friction)
        _set_inertial(rotor, (0.0, 0.0, 0.0), ROTOR_BODY_MASS, (POINT_INERTIA,) * 3)
        home_qpos.append(0.0)


def _add_loop_closures(spec: mujoco.MjSpec, config: PlantConfig) -> None:
    """A ball joint (``connect``) between each forearm end and its platform point, with explicit softness."""
    for label in CHAIN_LABELS:
        for rod, _ in rod_offsets(config):
            spec.add_equality(
                name=f"loop_{label}{rod}",
                type=mujoco.mjtEq.mjEQ_CONNECT,
                objtype=mujoco.mjtObj.mjOBJ_SITE,
                name1=f"forearm_{label}{rod}_end",
                name2=f"platform_{label}{rod}",
                solref=equality_solref(config),
                solimp=EQUALITY_SOLIMP,
            )


def gearhead_springlength(backlash: float) -> tuple[float, float]:
    """MuJoCo ``springlength`` (rad) of a gearhead tendon with ``backlash`` (rad) of lost motion: the dead band
    [-backlash / 2, backlash / 2] of the deflection rotor - arm, in which the spring passes no torque."""
    return (-0.5 * backlash, 0.5 * backlash)


def _add_gearheads(spec: mujoco.MjSpec, config: PlantConfig) -> None:
    """The gearhead of each compliant drive: a fixed tendon of length rotor - arm angle (rad) whose stiffness and
    damping are the gearhead's torsional ones (docs/design.md section 4, "Compliant drives").

    A tendon's spring is MuJoCo's passive force -k (L - springlength) - c L_dot, exact and linear in N m/rad, with a
    dead band between two spring lengths (the backlash). A joint equality with a soft ``solref`` would instead give
    a stiffness scaled by the constraint's impedance and effective mass, not the data sheet's N m/rad.
    """
    compliance = config.realism.compliance
    stiffness, damping = compliance.stiffness_per_joint, compliance.damping_per_joint
    for index, label in enumerate(CHAIN_LABELS):
        tendon = spec.add_tendon(
            name=f"gearhead_{label}",
            stiffness=[float(stiffness[index]), 0.0, 0.0],
            damping=[float(damping[index]), 0.0, 0.0],
            springlength=gearhead_springlength(compliance.backlash),
        )
        tendon.wrap_joint(f"rotor_{label}", 1.0)
        tendon.wrap_joint(f"motor_{label}", -1.0)


def _add_motors(spec: mujoco.MjSpec, config: PlantConfig) -> None:
    """Torque motors on the three motor joints (the rotors' of compliant drives), clipped at the drive's peak torque
    (the env enforces the rest of its envelope).

    With a lag, the current loop is a first-order filter integrated exactly (``filterexact``), accurate
    for lags down to one timestep; the joint torque is the filtered command.
    """
    lag = config.realism.actuator_lag
    dynamics = mujoco.mjtDyn.mjDYN_FILTEREXACT if lag > 0.0 else mujoco.mjtDyn.mjDYN_NONE
    driven = "motor" if config.realism.compliance is None else "rotor"
    for label in CHAIN_LABELS:
        motor = spec.add_actuator(
            name=f"motor_{label}",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            target=f"{driven}_{label}",
            dyntype=dynamics,
            gaintype=mujoco.mjtGain.mjGAIN_FIXED,
            biastype=mujoco.mjtBias.mjBIAS_NONE,
            ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            ctrlrange=(-config.drive.peak_torque, config.drive.peak_torque),
        )
        motor.gainprm[0] = 1.0
        if lag > 0.0:
            motor.dynprm[0] = lag
