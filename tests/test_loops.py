"""The realistic plant keeps its kinematic loops closed in the hardest motion the task asks for."""

import numpy as np

from controllers.base import PDController
from delta_env.env import DeltaPickPlaceEnv
from delta_env.oracle import InverseDynamicsOracle
from delta_env.trajectories import STRESS_PEAK_ACCELERATION


def test_loops_stay_closed_in_6g_cycle_carrying_4kg() -> None:
    """PD + oracle feedforward along a 6 g pick-and-place cycle carrying 4 kg: gap < 0.1 mm."""
    payload = 4.0
    env = DeltaPickPlaceEnv(n_cycles=1, cycle="standard", peak_acceleration=STRESS_PEAK_ACCELERATION)
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
    assert max(gaps) < 1e-4
    assert max(errors) < 5e-3, "the exact feedforward should track within millimetres"
