"""The scene around the robot: floor, light, camera, the two conveyors and the pick-and-place payload with its
suction weld.

:func:`scene_spec` starts from the robot of :func:`delta_env.robot.robot_spec` and adds the scene to it,
as a MuJoCo Menagerie ``scene.xml`` includes its robot; :func:`build_model` compiles it and
:func:`build_mjcf` writes it as MJCF text (``MjSpec.to_xml``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from delta_env.config import DEFAULT_PAYLOAD_SIZE, SUCTION_CUP_OFFSET, PlantConfig
from delta_env.cycles import PICK_ZONE, PLACE_ZONE, ConveyorZone
from delta_env.robot import EQUALITY_SOLIMP, HOME_KEY, equality_solref, robot_spec

FLOOR_HEIGHT = -1.25
"""Height (m) of the floor plane, visual only (no contacts)."""

PAYLOAD_RGBA = (0.75, 0.6, 0.4, 1.0)
"""Colour of the payload box."""

OBSTACLE_RADIUS = 0.04
"""Radius (m) of the obstacle sphere a collision fault puts in the platform's path."""

OBSTACLE_PARKED = (0.0, 0.0, 10.0)
"""Where the obstacle waits (m) while no fault uses it: far from everything."""

OBSTACLE_SOLREF = (0.01, 1.0)
"""Contact softness of the obstacle (time constant s, damping ratio): a compliant bumper, not a rigid wall."""

OBSTACLE_CONTACT_BIT = 2
"""The contact bit the obstacle (contype) and the platform disc (conaffinity) share: only they collide."""

BELT_HEIGHT = PICK_ZONE.z - SUCTION_CUP_OFFSET - DEFAULT_PAYLOAD_SIZE[2]
"""Height (m) of the conveyors' belts: an object waiting at a pick point of height ``PICK_ZONE.z`` rests on it."""

BELT_MARGIN = (0.2, 0.05)
"""How far (m) a drawn belt reaches beyond its zone of pick or place points, along x (the belt's run) and along y."""

_BELT_THICKNESS = 0.04
_RAIL_SIZE = (0.015, 0.05)  # width and height (m) of the side rails that hold a belt, 1 cm above it
_LEG_SIZE = 0.02  # half-width (m) of a square leg

_CAMERA_POSITION = np.array([2.2, -2.2, 0.4])
_CAMERA_TARGET = np.array([0.0, 0.0, -0.7])


OFFSCREEN_SIZE = (1280, 720)
"""Width and height (px) of the model's offscreen framebuffer: the largest frame it renders."""

RENDER_SIZE = (960, 720)
"""Default width and height (px) of a rendered frame (the env's ``rgb_array``, a video's): 4:3 within
:data:`OFFSCREEN_SIZE`, multiples of a video codec's 16 px blocks."""


def scene_spec(config: PlantConfig, obstacle: bool = False) -> mujoco.MjSpec:
    """The robot of ``config`` in its scene, with the payload body if ``config.payload_body``.

    With ``obstacle``, the scene also has the obstacle of collision faults (:func:`_add_obstacle`); without it,
    nothing in the scene collides.

    Raises:
        ValueError: if ``config`` is not a :class:`~delta_env.config.PlantConfig`.
    """
    spec = robot_spec(config)
    spec.visual.global_.offwidth, spec.visual.global_.offheight = OFFSCREEN_SIZE
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        width=512,
        height=512,
        rgb1=(0.25, 0.27, 0.3),
        rgb2=(0.3, 0.32, 0.35),
    )
    floor_material = spec.add_material(name="floor", texrepeat=(8.0, 8.0), reflectance=0.1)
    floor_material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.add_material(name="payload", rgba=PAYLOAD_RGBA)
    spec.add_material(name="belt", rgba=(0.2, 0.21, 0.23, 1.0), reflectance=0.05)
    spec.add_material(name="conveyor_frame", rgba=(0.62, 0.64, 0.68, 1.0), reflectance=0.2)
    world = spec.worldbody
    world.add_light(
        name="key", pos=(0.0, -1.0, 2.0), dir=(0.0, 0.4, -1.0), type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    )
    forward = _CAMERA_TARGET - _CAMERA_POSITION
    right = np.cross(forward, [0.0, 0.0, 1.0])
    up = np.cross(right, forward)
    camera = world.add_camera(name="overview", pos=_CAMERA_POSITION)
    camera.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    camera.alt.xyaxes = np.concatenate((right / np.linalg.norm(right), up / np.linalg.norm(up)))
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        pos=(0.0, 0.0, FLOOR_HEIGHT),
        size=(2.0, 2.0, 0.05),
        material="floor",
    )
    for name, zone in (("pick", PICK_ZONE), ("place", PLACE_ZONE)):
        _add_conveyor(spec, name, zone)
    if config.payload_body:
        _add_payload(spec, config)
    if obstacle:
        _add_obstacle(spec)
    return spec


def _add_conveyor(spec: mujoco.MjSpec, name: str, zone: ConveyorZone) -> None:
    """The conveyor ``name`` under ``zone``, drawn only: a belt with its top at :data:`BELT_HEIGHT`, reaching
    :data:`BELT_MARGIN` beyond the zone, side rails and four legs to the floor.

    Its geoms neither collide nor weigh (contype and conaffinity 0, on the static world body): the physics is that
    of the scene without it, step for step.
    """
    (x0, x1), (y0, y1) = zone.x_range, zone.y_range
    margin_x, margin_y = BELT_MARGIN
    center_x, center_y = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half_length, half_width = 0.5 * (x1 - x0) + margin_x, 0.5 * (y1 - y0) + margin_y
    rail_width, rail_height = _RAIL_SIZE
    belt_center = BELT_HEIGHT - 0.5 * _BELT_THICKNESS
    drawn = {"contype": 0, "conaffinity": 0, "type": mujoco.mjtGeom.mjGEOM_BOX}
    world = spec.worldbody
    world.add_geom(
        name=f"{name}_conveyor_belt",
        pos=(center_x, center_y, belt_center),
        size=(half_length, half_width, 0.5 * _BELT_THICKNESS),
        material="belt",
        **drawn,
    )
    rail_center = BELT_HEIGHT + 0.5 * rail_height - _BELT_THICKNESS
    for side, sign in (("left", 1.0), ("right", -1.0)):
        world.add_geom(
            name=f"{name}_conveyor_rail_{side}",
            pos=(center_x, center_y + sign * (half_width + rail_width), rail_center),
            size=(half_length, rail_width, 0.5 * rail_height),
            material="conveyor_frame",
            **drawn,
        )
    leg_top = BELT_HEIGHT - _BELT_THICKNESS
    leg_half_height = 0.5 * (leg_top - FLOOR_HEIGHT)
    for n, (sign_x, sign_y) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        world.add_geom(
            name=f"{name}_conveyor_leg_{n + 1}",
            pos=(
                center_x + sign_x * (half_length - _LEG_SIZE),
                center_y + sign_y * (half_width + rail_width),
                leg_top - leg_half_height,
            ),
            size=(_LEG_SIZE, _LEG_SIZE, leg_half_height),
            material="conveyor_frame",
            **drawn,
        )


def _add_obstacle(spec: mujoco.MjSpec) -> None:
    """A sphere on a mocap body, parked far away, that collides with the platform disc and nothing else.

    It is moved by :meth:`delta_env.contacts.Obstacle.place`; its contact is compliant (:data:`OBSTACLE_SOLREF`).
    """
    spec.geom("platform_disc").conaffinity = OBSTACLE_CONTACT_BIT
    body = spec.worldbody.add_body(name="obstacle", pos=OBSTACLE_PARKED, mocap=True)
    body.add_geom(
        name="obstacle",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=(OBSTACLE_RADIUS, 0.0, 0.0),
        contype=OBSTACLE_CONTACT_BIT,
        conaffinity=0,
        solref=OBSTACLE_SOLREF,
        rgba=(0.8, 0.15, 0.15, 1.0),
    )


def _add_payload(spec: mujoco.MjSpec, config: PlantConfig) -> None:
    """The pick-and-place object and the suction gripper's weld (inactive until a pick).

    Mass and size are set at run time (:meth:`DeltaPlant.place_payload`). Gravity compensation 1 floats
    the object where it is put while not carried (0 while carried); not "simple", so its mass can change.
    The weld's relative pose is set to the pose at the pick by :meth:`DeltaPlant.attach_payload`.
    """
    half = np.asarray(DEFAULT_PAYLOAD_SIZE) / 2.0
    position = (0.0, 0.0, config.home_height - SUCTION_CUP_OFFSET - half[2])
    payload = spec.worldbody.add_body(name="payload", pos=position, gravcomp=1.0)
    payload.simple = 0
    payload.add_freejoint(name="payload")
    payload.add_geom(name="payload_box", type=mujoco.mjtGeom.mjGEOM_BOX, size=half, mass=1.0, material="payload")
    suction = spec.add_equality(
        name="suction",
        type=mujoco.mjtEq.mjEQ_WELD,
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        name1="platform",
        name2="payload",
        active=False,
        solref=equality_solref(config),
        solimp=EQUALITY_SOLIMP,
    )
    # Anchor at the payload's origin; relative pose (position, quaternion) set at the pick.
    suction.data[0:10] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    home = spec.key(HOME_KEY)
    home.qpos = np.concatenate((home.qpos, [*position, 1.0, 0.0, 0.0, 0.0]))


def build_model(config: PlantConfig, obstacle: bool = False) -> mujoco.MjModel:
    """Compile the scene of ``config`` (with the obstacle of collision faults if ``obstacle``) into an ``MjModel``."""
    return scene_spec(config, obstacle).compile()


def build_mjcf(config: PlantConfig) -> str:
    """MJCF text of the scene of ``config`` (``MjSpec.to_xml``), to read or to record.

    MuJoCo writes numbers with 6 significant digits, so the text reloads into the same model up to
    that rounding; :func:`build_model` is the exact model.
    """
    spec = scene_spec(config)
    spec.compile()
    return spec.to_xml()
