"""The time-optimal planner of pick-and-place moves: known optima, the envelope by the model's own account
(recomputed here independently), payload monotonicity, online replanning and the ideal plant."""

import itertools
import math

import numpy as np
import pytest

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.timing import PlannedLaw, TimeOptimalPlanner
from controllers.topp import StageConstraints, solve
from delta_env import kinematics
from delta_env.config import PlantConfig
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.drive import DriveLimits
from delta_env.oracle import InverseDynamicsOracle
from delta_env.timing import move_samples
from delta_env.trajectories import WORKING_HEIGHT, Segment

MARGIN = 0.10
LAG = 1e-3
FRICTION = ModelParameters(viscous=(2.0, 2.0, 2.0), coulomb=(4.0, 4.0, 4.0))


def standard_carry() -> Segment:
    """The 25/305/25 mm carry of ``standard_cycle``: along +y through (0, 0, -0.9) m."""
    centre = np.array([0.0, 0.0, WORKING_HEIGHT])
    half = 0.5 * STANDARD_TRAVEL * np.array([0.0, 1.0, 0.0])
    return Segment(centre - half, centre + half, 1.0, STANDARD_LIFT, 0.3)


def shares(dynamics: DeltaDynamics, shape: Segment, law: PlannedLaw, payload: float, lag: float) -> np.ndarray:
    """Share of the shrunk envelope used by the model's torque, the lag-inverse command and the speed, (n, 3).

    Written out here rather than taken from the planner: u_k = (tau_{k+1} - p tau_k) / (1 - p) with the drive
    holding tau_0 at rest before the move.
    """
    x, xd, xdd = move_samples(shape, law)
    q, qd, qdd = kinematics.cartesian_to_joint(dynamics.geometry, x, xd, xdd)
    torque = dynamics.inverse_dynamics(q, qd, qdd, payload)
    pole = math.exp(-law.dt / lag) if lag > 0.0 else 0.0
    command = (torque[1:] - pole * torque[:-1]) / (1.0 - pole)
    drive = DriveLimits()
    held = MARGIN * drive.peak_torque
    lower, upper = drive.torque_bounds(qd)
    lower, upper = lower + held, upper - held

    def share(value: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        return np.where(value >= 0.0, value / high, value / low)

    result = np.maximum(share(torque, lower, upper), np.abs(qd) / ((1.0 - MARGIN) * drive.max_speed))
    both_low, both_high = np.maximum(lower[1:], lower[:-1]), np.minimum(upper[1:], upper[:-1])
    result[:-1] = np.maximum(result[:-1], share(command, both_low, both_high))
    return result


@pytest.fixture(scope="module")
def dynamics() -> DeltaDynamics:
    return DeltaDynamics.nominal(FRICTION, forearm_rods=True)


@pytest.fixture(scope="module")
def planner(dynamics: DeltaDynamics) -> TimeOptimalPlanner:
    return TimeOptimalPlanner(dynamics, DriveLimits(), drive_lag=LAG, margin=MARGIN)


@pytest.fixture(scope="module")
def plans(planner: TimeOptimalPlanner) -> dict[float, PlannedLaw]:
    return {payload: planner.plan(standard_carry(), payload) for payload in (0.0, 1.0, 4.0, 8.0)}


@pytest.mark.parametrize(("speed", "expected"), [(1e3, 2.0 * math.sqrt(1.0 / 2.0)), (1.0, 1.0 / 1.0 + 1.0 / 2.0)])
def test_core_matches_bang_bang_and_trapezoid(speed: float, expected: float) -> None:
    # |sdd| <= 2 on a path of length 1: bang-bang in sqrt(L / A) each way, or a trapezoid capped at sd = 1.
    grid = np.linspace(0.0, 1.0, 201)
    rows = np.tile([1.0, -1.0], (201, 1))
    stages = StageConstraints(grid, rows, np.zeros_like(rows), np.full_like(rows, 2.0), np.full(201, speed**2))
    profile = solve(stages)
    assert profile.duration == pytest.approx(expected, rel=0.01)
    s, sd = profile.state(np.array([0.0, profile.duration]))
    assert s.tolist() == pytest.approx([0.0, 1.0]) and sd.tolist() == pytest.approx([0.0, 0.0], abs=1e-9)
    # The integral of the bang-bang s(t) = t^2 (first half): 1/3 (T/2)^3 + ... is exact to round-off.
    assert profile.integral(np.array([profile.duration])) == pytest.approx(expected / 2.0, rel=0.01)


def test_core_rejects_an_uncontrollable_start() -> None:
    grid = np.linspace(0.0, 1.0, 51)
    rows = np.tile([1.0, -1.0], (51, 1))
    stages = StageConstraints(grid, rows, np.zeros_like(rows), np.full_like(rows, 2.0), np.full(51, 1e6))
    with pytest.raises(ValueError, match="no feasible time law"):
        solve(stages, sd_start=5.0)  # braking from 5 at |sdd| <= 2 needs a path of 6.25


def test_smoothing_adds_its_window(plans: dict[float, PlannedLaw], planner: TimeOptimalPlanner) -> None:
    for law in plans.values():
        extra = law.duration - law.raw.duration - planner.smoothing
        assert 0.0 <= extra < law.dt + 1e-12


def test_plans_stay_in_the_envelope_and_reach_it(plans: dict[float, PlannedLaw], dynamics: DeltaDynamics) -> None:
    for payload, law in plans.items():
        used = shares(dynamics, standard_carry(), law, payload, LAG)
        assert used.max() <= 1.0 + 1e-9, f"{payload} kg"
        assert used.max() > 0.9, f"{payload} kg: time-optimal means at the limit somewhere"


def test_heavier_payloads_take_longer(plans: dict[float, PlannedLaw]) -> None:
    raw = [plans[m].raw.duration for m in sorted(plans)]
    assert all(a < b for a, b in itertools.pairwise(raw)), raw
    smoothed = [plans[m].duration for m in sorted(plans)]
    assert all(a < b for a, b in itertools.pairwise(smoothed)), smoothed


def test_the_laws_are_c2_and_rest_to_rest(plans: dict[float, PlannedLaw]) -> None:
    law = plans[4.0]
    _, velocity, acceleration = move_samples(standard_carry(), law)
    assert np.abs(velocity[[0, -1]]).max() < 1e-9 and np.abs(acceleration[[0, -1]]).max() < 1e-6
    # Bounded jerk: from accelerating to braking the raw profile steps by about twice the peak acceleration in
    # one sample; the smoothed law spreads that over its window (8 samples).
    peak = np.linalg.norm(acceleration, axis=1).max()
    assert np.linalg.norm(np.diff(acceleration, axis=0), axis=1).max() < 0.25 * peak


def test_replan_keeps_the_past_and_speeds_up_a_lighter_carry(
    plans: dict[float, PlannedLaw], planner: TimeOptimalPlanner, dynamics: DeltaDynamics
) -> None:
    heavy = plans[8.0]
    index = len(heavy) // 3
    light = planner.replan(standard_carry(), heavy, index, 1.0)
    for name in ("tau", "tau_dot", "tau_ddot"):
        assert np.array_equal(getattr(light, name)[: index + 1], getattr(heavy, name)[: index + 1]), name
    assert light.duration < heavy.duration
    assert shares(dynamics, standard_carry(), light, 1.0, LAG)[index:].max() <= 1.0 + 1e-9
    # The continuation is smooth: no acceleration step at the junction beyond the law's own.
    _, _, acceleration = move_samples(standard_carry(), light)
    steps = np.linalg.norm(np.diff(acceleration, axis=0), axis=1)
    assert steps[index - 1 : index + 2].max() < 0.25 * np.linalg.norm(acceleration, axis=1).max()


def test_replan_brakes_within_its_braking_share(plans: dict[float, PlannedLaw], planner: TimeOptimalPlanner) -> None:
    heavy, shape = plans[8.0], standard_carry()
    index = len(heavy) // 4
    free = planner.replan(shape, heavy, index, 1.0)
    braked = planner.replan(shape, heavy, index, 1.0, braking=(0.6, 0.5))
    # from tau 0.6 on (and the smoothing window) about half the envelope (the lag-inverse command overshoots a
    # little); before it, all of it
    later = braked.tau >= 0.6 + 0.05
    assert planner.utilisation(shape, braked, 1.0).max(axis=1)[later].max() <= 0.55
    assert planner.utilisation(shape, free, 1.0).max(axis=1)[free.tau >= 0.65].max() > 0.9
    assert free.duration < braked.duration
    with pytest.raises(ValueError, match="torque_scale"):
        planner.replan(shape, heavy, index, 1.0, braking=(0.6, 0.0))


def test_replan_rejects_a_law_it_did_not_plan(planner: TimeOptimalPlanner, plans: dict[float, PlannedLaw]) -> None:
    law = plans[0.0]
    with pytest.raises(ValueError, match="index must lie"):
        planner.replan(standard_carry(), law, len(law), 0.0)
    plain = TimeOptimalPlanner(planner.dynamics, planner.drive, smoothing=0.0)
    with pytest.raises(ValueError, match="PlannedLaw of this planner"):
        plain.replan(standard_carry(), law, 3, 0.0)


def test_the_ideal_plant_needs_no_more_than_the_envelope() -> None:
    # On the ideal plant MKH (lumped forearms, no friction, no lag) is exact: the torques MuJoCo needs along the
    # planned motion are the model's, so they stay within the envelope less the margin.
    config = PlantConfig.ideal()
    masses = config.masses
    model = DeltaDynamics(config.geometry, m1=masses.m1, m2=masses.m2, m0=masses.m0)
    payload = 2.0
    law = TimeOptimalPlanner(model, DriveLimits(), margin=MARGIN).plan(standard_carry(), payload)
    x, xd, xdd = move_samples(standard_carry(), law)
    q, qd, qdd = kinematics.cartesian_to_joint(config.geometry, x, xd, xdd)
    torque = InverseDynamicsOracle(config).torques(q, qd, qdd, payload)
    lower, upper = DriveLimits().torque_bounds(qd)
    held = MARGIN * DriveLimits().peak_torque
    assert np.all(torque <= upper - held + 1e-6) and np.all(torque >= lower + held - 1e-6)
    assert np.abs(torque).max() > 0.8 * (1.0 - MARGIN) * DriveLimits().peak_torque
