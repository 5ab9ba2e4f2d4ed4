"""The realistic plant keeps its kinematic loops closed in the hardest motion the task asks for."""

import numpy as np

from controllers.base import PDController
from delta_env.env import DeltaPickPlaceEnv
from delta_env.loops import largest_gap
from delta_env.oracle import InverseDynamicsOracle
from delta_env.trajectories import STRESS_PEAK_ACCELERATION


def test_loops_stay_closed_in_6g_cycle_carrying_4kg() -> None:
    """PD + oracle feedforward along a 6 g pick-and-place cycle carrying 4 kg: the loops closed to 7 um (measured
    4.5 um), the platform within 2.5 mm (measured 1.4 mm)."""
    payload = 4.0
    # the timed release: its reference never waits for the in-position signal, so the feedforward is planned once
    env = DeltaPickPlaceEnv(n_cycles=1, cycle="standard", peak_acceleration=STRESS_PEAK_ACCELERATION, release="timed")
    observation, _ = env.reset(seed=0, options={"payload_masses": [payload]})
    reference = env.trajectory
    oracle = InverseDynamicsOracle(env.plant_config)
    feedforward = oracle.torques(
        reference.theta, reference.theta_dot, reference.theta_ddot, payload * reference.gripper
    )
    pd = PDController()
    gaps, errors, carried = [], [], []
    for k in range(len(reference) - 1):
        observation, _, terminated, _, info = env.step(feedforward[k] + pd(observation))
        assert not terminated
        gaps.append(info["loop_gap"])
        errors.append(info["tracking_error"])
        carried.append(info["payload_mass"])
    assert max(carried) == payload, "the 4 kg object was never carried"
    assert np.max(np.abs(feedforward)) > 100.0, "not a demanding cycle: peak torque should exceed 100 N m"
    assert max(gaps) < 7e-6
    assert max(errors) < 2.5e-3, "the exact feedforward should track within millimetres"


def numpy_largest_gap(points: np.ndarray, pairs: np.ndarray) -> float:
    """The plain NumPy definition of :func:`delta_env.loops.largest_gap`: NaN distances skipped, 0 without pairs."""
    squared = np.sum((points[pairs[:, 0]] - points[pairs[:, 1]]) ** 2, axis=1)
    return float(np.sqrt(np.max(squared[~np.isnan(squared)], initial=0.0)))


def test_compiled_largest_gap_equals_its_numpy_definition_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        points = rng.normal(0.0, rng.choice([1e-9, 1e-4, 1.0]), (13, 3))
        pairs = rng.integers(0, 13, (int(rng.integers(0, 7)), 2))
        if rng.random() < 0.2:
            points[rng.integers(13), rng.integers(3)] = rng.choice([np.nan, np.inf])
        assert largest_gap(points, pairs) == numpy_largest_gap(points, pairs)
    # the plant's loops: the connects of the realistic variant, at a state off the closed configuration
    env = DeltaPickPlaceEnv()
    env.reset(seed=1)
    loops = env.plant.loops
    env.plant.data.site_xpos[:] += rng.normal(0.0, 1e-4, env.plant.data.site_xpos.shape)
    assert loops.gap() == numpy_largest_gap(env.plant.data.site_xpos, loops._site_pairs) > 0.0
