"""Sensor timing against the simulator: how old the measured torque is relative to the encoder sample."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from delta_env import MEASURED_TORQUE_DELAY, NOMINAL_GEOMETRY, DeltaPickPlaceEnv, PlantConfig, PlantRealism
from delta_env.excitation import excitation_trajectory
from delta_env.oracle import InverseDynamicsOracle
from delta_env.sensors import PHYSICS_TIMESTEP


def torque_fit_errors(actuator_lag: float, delays: list[float]) -> dict[float, float]:
    """RMS (N m) of measured torque minus exact inverse dynamics at the motion shifted back by each delay (s).

    The default plant with exact sensors (no torque noise, no encoder quantization) tracks a 2 s
    excitation (PD plus exact feedforward). The measured angles are interpolated by a cubic spline;
    the closed-chain oracle gives the torque of the spline's state at t - D, compared with the torque
    read at t. Samples where a joint is slower than 0.05 rad/s are left out: there Coulomb friction
    is indeterminate.
    """
    realism = replace(PlantRealism(), torque_noise_std=0.0, encoder_bits=None, actuator_lag=actuator_lag)
    env = DeltaPickPlaceEnv(plant=PlantConfig(realism=realism), n_cycles=1)
    reference = excitation_trajectory(NOMINAL_GEOMETRY, np.random.default_rng(0), 2.0, slow_fraction=0.0)
    oracle = InverseDynamicsOracle(env.plant_config)
    feedforward = oracle.torques(reference.theta, reference.theta_dot, reference.theta_ddot)
    observation, _ = env.reset(seed=0, options={"reference": reference})
    angles, torques = [observation["joint_angles"]], [observation["joint_torques"]]
    for k in range(len(reference) - 1):
        error = observation["reference_angles"] - observation["joint_angles"]
        rate_error = observation["reference_velocities"] - observation["joint_velocities"]
        observation, _, terminated, _, _ = env.step(feedforward[k] + 3000.0 * error + 60.0 * rate_error)
        assert not terminated
        angles.append(observation["joint_angles"])
        torques.append(observation["joint_torques"])
    time = np.arange(len(angles)) * env.dt
    motion = CubicSpline(time, np.array(angles))
    kept = np.arange(20, len(time) - 20)
    kept = kept[np.all(np.abs(motion(time[kept], 1)) > 0.05, axis=1)]
    assert len(kept) > 800
    measured = np.array(torques)[kept]
    assert np.max(np.abs(measured)) > 60.0, "not a demanding motion"
    errors = {}
    for delay in delays:
        at = time[kept] - delay
        exact = oracle.torques(motion(at), motion(at, 1), motion(at, 2))
        errors[delay] = float(np.sqrt(np.mean((measured - exact) ** 2)))
    return errors


def test_measured_torque_delay_is_one_physics_step() -> None:
    """The constant is the plant's own timing: one physics step h of the default plant."""
    assert PlantConfig().timestep == PHYSICS_TIMESTEP
    assert MEASURED_TORQUE_DELAY == PHYSICS_TIMESTEP


@pytest.mark.parametrize("actuator_lag", [0.0005, 0.001, 0.002], ids=["lag 0.5 ms", "lag 1 ms (default)", "lag 2 ms"])
def test_measured_torque_matches_inverse_dynamics_one_physics_step_back(actuator_lag: float) -> None:
    """Of D = 0, h/2, h, 3h/2 the torque reading fits the exact inverse dynamics best at D = h.

    The reading is the actuator force held over the last physics step [t - h, t]; MuJoCo's
    semi-implicit Euler turns it into the acceleration at the start of that step, the central second
    difference of the positions at t - h. Over the randomization range of the current-loop lag the
    fit stays best at h and clearly better than at h/2 or 0.
    """
    h = PHYSICS_TIMESTEP
    errors = torque_fit_errors(actuator_lag, [0.0, 0.5 * h, h, 1.5 * h])
    best = min(errors, key=errors.__getitem__)
    assert best == pytest.approx(MEASURED_TORQUE_DELAY, abs=1e-12), errors
    assert errors[h] < 0.85 * errors[0.5 * h], errors
    assert errors[h] < 0.5 * errors[0.0], errors
    assert errors[h] < 0.15, errors
