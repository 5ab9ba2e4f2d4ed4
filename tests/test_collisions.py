"""Arm-arm and arm-base collision checks (delta_env.collisions) and the plant's collision geometry."""

import math

import numpy as np
import pytest

from controllers.registry import build_controller
from delta_env import collisions, kinematics, workspace
from delta_env.config import PlantConfig
from delta_env.cylinder import data_sheet_cylinder
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry
from delta_env.plant import DeltaPlant
from delta_env.scaling import forearm_rod_radius
from eval.episodes import run_episode

NARROW = DeltaGeometry(0.2, 0.03, 0.37, 0.95)  # neighbouring ball joints 2 mm apart: their rods overlap


def test_segment_distance_known_cases():
    p1, q1 = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    skew = collisions.segment_distance(p1, q1, np.array([0.5, -1.0, 0.3]), np.array([0.5, 1.0, 0.3]))
    parallel = collisions.segment_distance(p1, q1, np.array([0.2, 0.4, 0.0]), np.array([0.8, 0.4, 0.0]))
    beyond = collisions.segment_distance(p1, q1, np.array([2.0, 0.0, 1.0]), np.array([3.0, 0.0, 1.0]))
    np.testing.assert_allclose([skew, parallel, beyond], [0.3, 0.4, math.sqrt(2.0)], atol=1e-12)
    # a segment passing over the top face of a solid cylinder, and one through it
    centre = np.array([0.0, 0.0, 0.0])
    over = collisions.segment_cylinder_distance(np.array([-1.0, 0.0, 0.3]), np.array([1.0, 0.0, 0.3]), centre, 0.5, 0.1)
    through = collisions.segment_cylinder_distance(
        np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), centre, 0.5, 0.1
    )
    edge = collisions.segment_cylinder_distance(np.array([1.0, 0.0, 0.5]), np.array([1.0, 0.0, 0.9]), centre, 0.5, 0.1)
    np.testing.assert_allclose([over, through, edge], [0.2, 0.0, math.hypot(0.5, 0.4)], atol=1e-7)


def test_neighbouring_forearms_collide_on_a_narrow_platform_and_clear_on_the_nominal():
    theta = np.array([0.3, 0.5, 0.2])
    for geometry, expected in ((NARROW, 0.00196), (NOMINAL_GEOMETRY, 0.0366)):
        point = kinematics.forward(geometry, theta)
        # the closest rods of chains 1 and 2 meet at the platform: ball-joint distance minus two rod radii
        clearance = collisions.arm_arm_clearance(geometry, point, theta)
        assert float(clearance) == pytest.approx(expected - 2 * forearm_rod_radius(geometry.l2), abs=1e-4)
    assert collisions.arm_arm_clearance(NARROW, kinematics.forward(NARROW, theta), theta) < 0.0


def test_arms_clear_the_base_plate_over_the_motor_range_and_hit_it_beyond():
    low = workspace.THETA_RANGE[0]
    for l1 in (0.25, 0.37, 0.55):
        g = DeltaGeometry(0.2, 0.05, l1, 1.4)
        for theta, clear in ((low, True), (low - 0.15, False)):
            angles = np.full(3, theta)
            clearance = collisions.arm_base_clearance(g, kinematics.forward(g, angles), angles)
            assert (float(clearance) > 0.0) == clear, (l1, theta, clearance)


def test_collision_plant_detects_what_the_checks_find():
    theta_touch = np.full(3, workspace.THETA_RANGE[0] - 0.2)
    plant = DeltaPlant(PlantConfig(collisions=True, payload_body=False))
    plant.step(np.zeros(3), 1)
    assert plant.robot_contacts == {}  # home: nothing touches
    plant.assemble(theta_touch)
    plant.step(np.zeros(3), 1)
    touching = plant.robot_contacts
    assert {pair for pair in touching} == {("base_plate", f"upper_arm_{i}_tube") for i in "123"}
    g = NOMINAL_GEOMETRY
    depth = -float(collisions.arm_base_clearance(g, kinematics.forward(g, theta_touch), theta_touch))
    assert max(touching.values()) == pytest.approx(depth, abs=0.005)
    # neighbouring forearms on the narrow platform
    narrow = DeltaPlant(PlantConfig(geometry=NARROW, collisions=True, payload_body=False))
    narrow.step(np.zeros(3), 1)
    assert ("forearm_1a_rod", "forearm_2b_rod") in narrow.robot_contacts
    plant.reset()
    assert plant.robot_contacts == {}


def test_default_plant_has_no_collisions_and_ideal_refuses_them():
    plant = DeltaPlant(PlantConfig(geometry=NARROW, payload_body=False))
    plant.step(np.zeros(3), 1)
    assert plant.data.ncon == 0 and plant.robot_contacts == {}
    with pytest.raises(ValueError, match="collisions"):
        PlantConfig.ideal(collisions=True)


def test_an_episode_records_the_contacts_its_plant_saw(controller_setup):
    seen = {}
    for name, geometry in (("narrow", NARROW), ("nominal", NOMINAL_GEOMETRY)):
        env = DeltaPickPlaceEnv(plant=PlantConfig(geometry=geometry, collisions=True), n_cycles=1)
        seen[name] = run_episode(env, build_controller("pd", controller_setup, env), 0).robot_contacts
        env.close()
    assert ("forearm_1a_rod", "forearm_2b_rod") in seen["narrow"]
    assert seen["nominal"] == {}


def test_smallest_clearances_over_points_find_the_touching_pose():
    cylinder = data_sheet_cylinder(NOMINAL_GEOMETRY)
    points = cylinder.surface_points()
    arm, base = collisions.smallest_clearances(NOMINAL_GEOMETRY, points)
    theta = kinematics.inverse(NOMINAL_GEOMETRY, points)
    assert arm == pytest.approx(float(np.min(collisions.arm_arm_clearance(NOMINAL_GEOMETRY, points, theta))))
    assert base == pytest.approx(float(np.min(collisions.arm_base_clearance(NOMINAL_GEOMETRY, points, theta))))
    assert arm > 0.0 and base > 0.0
    assert collisions.smallest_clearances(NARROW, points)[0] < 0.0  # its rods overlap everywhere
    with pytest.raises(ValueError, match="outside the reachable workspace"):
        collisions.smallest_clearances(NOMINAL_GEOMETRY, [[0.0, 0.0, -3.0]])
    with pytest.raises(ValueError, match="at least one point"):
        collisions.smallest_clearances(NOMINAL_GEOMETRY, np.zeros((0, 3)))
