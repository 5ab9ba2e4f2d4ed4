"""Buildable geometry: ball-joint spacing on the platform, cones about the cup axes, parallelogram skew, the
stiffness-keeping mass rule and the platform's first natural frequency."""

import math

import numpy as np
import pytest

from delta_env import buildability, kinematics, scaling, workspace
from delta_env.config import FOREARM_SPACING, PlantConfig
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry
from delta_env.plant import DeltaPlant
from delta_env.robot import forearm_home_tilt
from eval.design import optimize, stiffness

NEED = buildability.BALL_JOINT_HOUSING_DIAMETER + buildability.BALL_JOINT_CLEARANCE


def test_ball_joint_distance_is_the_hand_computed_one():
    # chain 1's rod a at (rb, s/2), chain 2's rod b at rb u_2 - s/2 t_2: the 2 mm at 30 mm, 37 mm nominal
    for rb in (0.03, 0.036, 0.05):
        a = np.array([rb, FOREARM_SPACING / 2])
        u2, t2 = np.array([-0.5, math.sqrt(3) / 2]), np.array([-math.sqrt(3) / 2, -0.5])
        b = rb * u2 - FOREARM_SPACING / 2 * t2
        assert buildability.ball_joint_distance(rb) == pytest.approx(np.linalg.norm(a - b), abs=1e-12)
    assert buildability.ball_joint_distance(0.03) == pytest.approx(0.00196, abs=1e-5)


def test_touching_ball_joints_set_the_minimum_platform_radius():
    rb_min = buildability.min_platform_radius()
    assert rb_min == pytest.approx((FOREARM_SPACING / 2 + NEED) / math.sqrt(3), rel=1e-12)
    for rb, buildable in ((rb_min - 1e-4, False), (rb_min + 1e-4, True)):
        geometry = DeltaGeometry(0.2, rb, 0.37, 0.95)
        assert (buildability.ball_joint_distance(rb) >= NEED) == buildable
        assert (buildability.platform_radius_shortfall(geometry) <= 0.0) == buildable
    assert buildability.platform_radius_shortfall(NOMINAL_GEOMETRY) < 0.0
    with pytest.raises(ValueError, match="spacing"):
        buildability.min_platform_radius(spacing=0.02)


def test_the_plant_and_the_optimizer_use_the_same_ball_joints():
    rb = buildability.min_platform_radius()
    plant = DeltaPlant(PlantConfig(geometry=DeltaGeometry(0.2, rb, 0.37, 0.95), payload_body=False))
    first, second = (plant.data.site(name).xpos for name in ("platform_1a", "platform_2b"))
    assert np.linalg.norm(first - second) == pytest.approx(NEED, abs=1e-9)
    assert optimize.DEFAULT_BOUNDS.rb[0] == rb
    narrow = optimize.constraint_vector(optimize.evaluate(DeltaGeometry(0.2, 0.03, 0.37, 0.95)))
    assert narrow[3] == pytest.approx(buildability.platform_radius_shortfall(DeltaGeometry(0.2, 0.03, 0.37, 0.95)))
    assert narrow[3] > 0.0


def test_cone_is_zero_at_home_and_follows_the_arms():
    g = NOMINAL_GEOMETRY
    home = np.array([0.0, 0.0, g.home_height])
    cone, skew = buildability.joint_angles(g, home, np.zeros(3))
    np.testing.assert_allclose(cone, 0.0, atol=1e-7)
    np.testing.assert_allclose(skew, 0.0, atol=1e-12)
    theta = np.full(3, 0.4)
    platform = kinematics.forward(g, theta)
    elbow_radius, elbow_z = g.r + g.l1 * math.cos(0.4), -g.l1 * math.sin(0.4)
    rod_tilt = math.atan2(elbow_radius, elbow_z - platform[2])  # from the vertical, towards the axis
    platform_side, arm_side = abs(rod_tilt - forearm_home_tilt(g)), abs(rod_tilt - forearm_home_tilt(g) - 0.4)
    cone, skew = buildability.joint_angles(g, platform, theta)
    np.testing.assert_allclose(cone, max(platform_side, arm_side), atol=1e-9)
    np.testing.assert_allclose(skew, 0.0, atol=1e-9)


def test_skew_limit_on_a_sideways_platform():
    # platform at (0, y, z): chain 1's forearms tilt along t_1 = e_y by asin(y / l2), more than chains 2 and 3
    g = NOMINAL_GEOMETRY
    criteria = workspace.Criteria(
        theta_range=(-math.pi, math.pi), max_forearm_tilt=math.pi, min_conditioning=0.0, max_skew=math.radians(30)
    )
    for degrees, admissible in ((29.0, True), (31.0, False)):
        y = g.l2 * math.sin(math.radians(degrees))
        point = np.array([0.0, y, -0.75])
        measures = workspace.pose_measures(g, point)
        assert measures.reachable
        assert float(measures.skew) == pytest.approx(math.radians(degrees), abs=1e-12)
        assert bool(workspace.admissible(g, point, criteria)) == admissible


def test_mass_rule_keeps_the_links_stiffness():
    for factor in (0.6, 1.5):
        l1, l2 = factor * NOMINAL_GEOMETRY.l1, factor * NOMINAL_GEOMETRY.l2
        assert scaling.arm_tip_stiffness(l1) == pytest.approx(scaling.arm_tip_stiffness(NOMINAL_GEOMETRY.l1), rel=1e-12)
        assert scaling.rod_axial_stiffness(l2) == pytest.approx(
            scaling.rod_axial_stiffness(NOMINAL_GEOMETRY.l2), rel=1e-12
        )
        # the masses grow like the sections' area times length
        masses = scaling.scaled_masses(DeltaGeometry(0.2, 0.05, l1, l2))
        arm_volume = (
            scaling.upper_arm_section(l1).area * l1 / (scaling.NOMINAL_UPPER_ARM_TUBE.area * NOMINAL_GEOMETRY.l1)
        )
        rod_volume = scaling.forearm_section(l2).area * l2 / (scaling.NOMINAL_FOREARM_ROD.area * NOMINAL_GEOMETRY.l2)
        assert masses.m1 == pytest.approx(NOMINAL_MASSES.m1 * arm_volume, rel=1e-12)
        assert masses.m2 == pytest.approx(NOMINAL_MASSES.m2 * rod_volume, rel=1e-12)
    assert scaling.scaled_masses(NOMINAL_GEOMETRY) == NOMINAL_MASSES
    model = DeltaPlant(PlantConfig(payload_body=False)).model
    assert model.geom("upper_arm_1_tube").size[0] == scaling.NOMINAL_UPPER_ARM_TUBE.outer_radius == 0.025
    assert model.geom("forearm_1a_rod").size[0] == scaling.NOMINAL_FOREARM_ROD.outer_radius == 0.006


def test_platform_mass_matrix_is_the_models_inertia_in_cartesian_space():
    g, payload = NOMINAL_GEOMETRY, 4.0
    point, acceleration = np.array([0.1, -0.2, -0.9]), np.array([3.0, -2.0, 5.0])
    model = stiffness.design_model(g, scaling.scaled_masses(g), drive=None)
    theta, theta_dot, theta_ddot = kinematics.cartesian_to_joint(g, point, np.zeros(3), acceleration)
    torque = model.inverse_dynamics(theta, theta_dot, theta_ddot, payload)
    torque -= model.inverse_dynamics(theta, theta_dot, np.zeros(3), payload)
    force = np.linalg.solve(kinematics.jacobian(g, theta).T, torque)  # tau = J^T F
    np.testing.assert_allclose(stiffness.cartesian_mass(g, point, payload) @ acceleration, force, rtol=1e-9)


def test_first_natural_frequency_of_a_heavy_payload_is_that_of_a_point_mass():
    g, payload = NOMINAL_GEOMETRY, 1000.0
    point = np.array([0.1, 0.05, -0.9])
    lowest_stiffness = np.linalg.eigvalsh(stiffness.cartesian_stiffness(g, point))[0]
    expected = math.sqrt(lowest_stiffness / payload) / (2 * math.pi)
    assert float(stiffness.first_natural_frequency(g, point, payload)) == pytest.approx(expected, rel=0.01)
    # gearbox and bent arm in series, about the motor axis
    arm = 1.0 / (scaling.arm_tip_stiffness(g.l1) * g.l1**2)
    assert stiffness.chain_compliance(g) == pytest.approx(1.0 / stiffness.GEARBOX_TORSIONAL_STIFFNESS + arm, rel=1e-12)
