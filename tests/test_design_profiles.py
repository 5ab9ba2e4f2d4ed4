"""Time profiles of a design over one standard cycle (eval.design.profiles): the paper's Figs. 3-6."""

import math

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from delta_env import kinematics
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.geometry import NOMINAL_GEOMETRY, DeltaGeometry
from eval.design import model as design_model
from eval.design import performance, profiles


@pytest.fixture(scope="module")
def nominal() -> performance.Performance:
    return performance.evaluate(NOMINAL_GEOMETRY)


@pytest.fixture(scope="module")
def profile(nominal) -> profiles.CycleProfile:
    return profiles.design_profile(nominal, profiles.worst_cycle(nominal))


def _direction(profile: profiles.CycleProfile) -> np.ndarray:
    return np.array([math.cos(profile.heading), math.sin(profile.heading), 0.0])


def test_platform_starts_and_ends_at_the_pick_point_and_reaches_the_place_point(profile):
    centre, direction = np.asarray(profile.centre), _direction(profile)
    pick, place = centre - STANDARD_TRAVEL / 2 * direction, centre + STANDARD_TRAVEL / 2 * direction
    np.testing.assert_allclose(profile.trajectory.xyz[0], pick, atol=1e-9)
    np.testing.assert_allclose(profile.trajectory.xyz[-1], pick, atol=1e-9)
    farthest = np.argmax((profile.trajectory.xyz - centre) @ direction)
    np.testing.assert_allclose(profile.trajectory.xyz[farthest], place, atol=1e-9)
    assert np.max(profile.trajectory.xyz[:, 2]) == pytest.approx(centre[2] + STANDARD_LIFT, abs=1e-9)  # the 25 mm lift
    # carried from pick to place only: the payload is on the outbound move and off on the way back
    held = profile.payload > 0.0
    assert held[np.argmax((profile.trajectory.xyz - centre) @ direction) - 1] and not held[0] and not held[-1]


def test_rates_are_the_derivatives_of_the_positions(profile):
    """Integrating the acceleration gives the velocity and integrating that the position (trapezoids at the
    profile's own period; integration, unlike differencing, is not thrown off by the jerk's jumps)."""
    dt = profile.trajectory.time[1] - profile.trajectory.time[0]
    for position, rate, acceleration in (
        (profile.trajectory.xyz, profile.trajectory.xyz_dot, profile.trajectory.xyz_ddot),
        (profile.trajectory.theta, profile.trajectory.theta_dot, profile.trajectory.theta_ddot),
    ):
        from_rate = position[0] + cumulative_trapezoid(rate, dx=dt, axis=0, initial=0.0)
        np.testing.assert_allclose(from_rate, position, atol=1e-3 * np.max(np.abs(position - position[0])))
        from_acceleration = rate[0] + cumulative_trapezoid(acceleration, dx=dt, axis=0, initial=0.0)
        np.testing.assert_allclose(from_acceleration, rate, atol=1e-2 * np.max(np.abs(rate)))


def test_joint_angles_give_back_the_platform_path(profile):
    """The paper's direct-kinematics view (its Figs. 3-4): forward kinematics of the joint profile is the path."""
    np.testing.assert_allclose(
        kinematics.forward(NOMINAL_GEOMETRY, profile.trajectory.theta), profile.trajectory.xyz, atol=1e-9
    )


def test_torques_are_the_design_models_with_the_payload_while_carried(nominal, profile):
    model = design_model.design_model(nominal.geometry, nominal.masses)
    samples = [
        0,
        int(np.argmax(profile.payload)) + 30,
        len(profile.trajectory.time) - 40,
    ]  # rest, carrying, returning empty
    for k in samples:
        # the virtual-work form reaches the torques through the Jacobian, not the multipliers
        expected = model.inverse_dynamics_virtual_work(
            profile.trajectory.theta[k],
            profile.trajectory.theta_dot[k],
            profile.trajectory.theta_ddot[k],
            profile.payload[k],
        )
        np.testing.assert_allclose(profile.torque[k], expected, atol=1e-6)
    empty = profiles.cycle_profile(nominal.geometry, profile.centre, profile.heading, payload=0.0)
    held = profile.payload > 0.0
    np.testing.assert_array_equal(profile.torque[~held], empty.torque[~held])
    assert np.max(np.abs(profile.torque[held] - empty.torque[held])) > 5.0  # 3.8 kg matters: N m, not rounding


def test_worst_cycle_profile_peaks_at_the_designs_peak_torque(nominal, profile):
    assert np.max(np.abs(profile.torque)) == pytest.approx(nominal.peak_torque_nm, rel=1e-12)
    for cycle in range(len(performance.TASK_CYCLES)):
        other = profiles.design_profile(nominal, cycle)
        assert np.max(np.abs(other.torque)) <= nominal.peak_torque_nm * (1 + 1e-12)


def test_bad_cycles_and_mixed_profiles_are_refused(nominal, profile, tmp_path):
    with pytest.raises(ValueError, match="cycle must be an integer in"):
        profiles.design_profile(nominal, len(performance.TASK_CYCLES))
    with pytest.raises(ValueError, match="payload"):
        profiles.cycle_profile(NOMINAL_GEOMETRY, profile.centre, profile.heading, payload=-1.0)
    other = profiles.design_profile(nominal, (profiles.worst_cycle(nominal) + 1) % len(performance.TASK_CYCLES))
    with pytest.raises(ValueError, match="another cycle"):
        profiles.plot_profiles({"a": profile, "b": other}, tmp_path)


def test_plot_profiles_writes_the_three_figures(nominal, profile, tmp_path):
    longer = performance.evaluate(DeltaGeometry(ra=0.2, rb=0.05, l1=0.4, l2=1.0))
    paths = profiles.plot_profiles(
        {"nominal": profile, "longer": profiles.design_profile(longer, profiles.worst_cycle(nominal))}, tmp_path
    )
    assert [p.name for p in paths] == ["profiles_joints.png", "profiles_end_effector.png", "profiles_torque.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)
