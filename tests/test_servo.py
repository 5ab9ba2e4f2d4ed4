"""The servo layer: pole placement and phase margin against their definitions, the clamped integral, and a step
against static friction on the plant."""

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers.base import PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import OracleController
from controllers.servo import (
    DEFAULT_PHASE_MARGIN,
    JointServo,
    ServoGains,
    joint_inertia,
    loop_delay,
    model_inertia,
    phase_margin,
    servo_bandwidth,
    servo_gains,
)
from controllers.setup import ControllerSetup, model_row
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.kinematics import inverse
from delta_env.trajectories import Trajectory
from eval.episodes import run_episode

# The nominal robot's MId+F+R parameters as its identification finds them; the plant's Coulomb friction is
# 4.0 x (1.0, 0.85, 1.15) N m, its drive lag 1 ms (docs/design.md section 4).
NOMINAL_RODS = ModelParameters(rho1=1.95, rho2=0.95, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6))
LAG = (0.001, 0.001, 0.001)
STRIBECK_EXCESS = (2.0, 1.7, 2.3)
"""The plant's Stribeck excess (N m): half its Coulomb friction."""


def brute_force_phase_margin(bandwidth: float, delay: float) -> float:
    """180 degrees plus the phase of L(jw) at the frequency of a fine grid where |L| is nearest 1 (rad)."""
    w = np.geomspace(bandwidth * 1e-2, bandwidth * 1e2, 400_001)
    s = 1j * w
    loop = bandwidth * (3 * s**2 + 3 * bandwidth * s + bandwidth**2) / s**3 * np.exp(-s * delay)
    crossover = np.argmin(np.abs(np.abs(loop) - 1.0))
    # At low frequency L ~ (w0 / s)^3, -270 degrees, which np.angle reads as +90: one turn down.
    phase = np.unwrap(np.angle(loop)) - 2.0 * math.pi
    return math.pi + float(phase[crossover])


@pytest.mark.parametrize("delay", [0.001, 0.002, 0.003])
def test_phase_margin_matches_a_frequency_sweep(delay: float) -> None:
    bandwidth = servo_bandwidth(delay)
    assert phase_margin(bandwidth, delay) == pytest.approx(DEFAULT_PHASE_MARGIN, abs=1e-6)
    assert brute_force_phase_margin(bandwidth, delay) == pytest.approx(DEFAULT_PHASE_MARGIN, abs=math.radians(0.05))
    # The bandwidth is the largest that keeps the margin: 5 % more loses it.
    assert phase_margin(1.05 * bandwidth, delay) < DEFAULT_PHASE_MARGIN - math.radians(1.0)


def test_gains_place_a_triple_pole_on_the_identified_inertia() -> None:
    dynamics = DeltaDynamics.nominal(NOMINAL_RODS, forearm_rods=True)
    inertia = joint_inertia(dynamics.inverse_dynamics)
    gains = servo_gains(inertia, NOMINAL_RODS.coulomb, LAG)
    bandwidth = servo_bandwidth(loop_delay(0.001))
    for joint in range(3):
        poles = np.roots([inertia[joint], gains.kd[joint], gains.kp[joint], gains.ki[joint]])
        assert_allclose(poles, -bandwidth, rtol=1e-3)
    assert gains.breakaway == NOMINAL_RODS.coulomb
    # A slower drive gets a slower loop: twice the lag, two thirds of the bandwidth or less.
    assert max(servo_gains(inertia, NOMINAL_RODS.coulomb, 0.002).kd) < 0.7 * min(gains.kd)


def test_joint_inertia_against_the_model_torque() -> None:
    dynamics = DeltaDynamics.nominal(NOMINAL_RODS, forearm_rods=True)
    theta = np.array([0.3, -0.1, 0.5])
    inertia = joint_inertia(dynamics.inverse_dynamics, theta, payload=2.0)
    zero = np.zeros(3)
    for joint in range(3):
        acceleration = np.zeros(3)
        acceleration[joint] = 10.0
        torque = dynamics.inverse_dynamics(theta, zero, acceleration, 2.0) - dynamics.inverse_dynamics(
            theta, zero, zero, 2.0
        )
        assert torque[joint] == pytest.approx(10.0 * inertia[joint], rel=1e-9)
    assert np.all(inertia > joint_inertia(dynamics.inverse_dynamics, theta))  # a payload adds inertia


def observation(error: float, rate_error: float = 0.0, reference_rate: float = 0.0) -> dict[str, np.ndarray]:
    return {
        "reference_angles": np.full(3, error),
        "joint_angles": np.zeros(3),
        "reference_velocities": np.full(3, reference_rate),
        "reference_accelerations": np.zeros(3),
        "joint_velocities": np.full(3, reference_rate - rate_error),
    }


def test_integral_is_clamped_under_a_held_error_and_unwinds_at_once() -> None:
    gains = ServoGains(kp=(1000.0,) * 3, ki=(1e5,) * 3, kd=(10.0,) * 3, integral_limit=25.0)
    servo = JointServo(gains)
    for _ in range(10_000):  # 10 s against a blocked joint, 1 mrad off: unclamped, 1000 N m of integral
        torque = servo.feedback(observation(1e-3, reference_rate=0.5))
    assert_allclose(servo.integral, 25.0)
    assert_allclose(torque, 1.0 + 25.0)
    # The error reverses: the integral leaves the clamp on the first step, no stored windup to unwind.
    servo.feedback(observation(-1e-4, reference_rate=0.5))
    assert_allclose(servo.integral, 25.0 - 1e5 * 1e-4 * servo.period)

    servo.reset()
    assert_allclose(servo.integral, 0.0)


def test_friction_push_only_at_rest_saturating_at_its_width() -> None:
    gains = ServoGains(kp=(0.0,) * 3, ki=(0.0,) * 3, kd=(0.0,) * 3, breakaway=(4.0, 3.0, 5.0), friction_width=1e-4)
    servo = JointServo(gains)
    assert_allclose(servo.feedback(observation(5e-5)), [2.0, 1.5, 2.5])
    assert_allclose(servo.feedback(observation(-1e-3)), [-4.0, -3.0, -5.0])
    assert_allclose(servo.feedback(observation(1e-3, reference_rate=0.2)), 0.0)  # moving: the model's fc sign(thd)


def test_gains_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match="kp"):
        ServoGains(kp=(-1.0, 0.0, 0.0), ki=(0.0,) * 3, kd=(0.0,) * 3)
    with pytest.raises(ValueError, match="friction_width"):
        ServoGains(kp=(1.0,) * 3, ki=(0.0,) * 3, kd=(0.0,) * 3, friction_width=0.0)
    with pytest.raises(ValueError, match="delay"):
        servo_bandwidth(0.0)
    # no bandwidth keeps more margin than the loop has without delay (about 71 degrees)
    with pytest.raises(ValueError, match=r"margin must be a finite number in \(0, 1\.24"):
        servo_bandwidth(0.001, math.radians(75.0))


def step_reference(step: float, samples: int = 400) -> Trajectory:
    """At rest at a pose below home for one sample, then at rest ``step`` (m) along x from it."""
    start = np.array([0.0, 0.0, NOMINAL_GEOMETRY.home_height - 0.1])
    xyz = np.repeat(start[None], samples, axis=0)
    xyz[1:, 0] += step
    zero = np.zeros_like(xyz)
    return Trajectory(
        dt=0.001,
        xyz=xyz,
        xyz_dot=zero,
        xyz_ddot=zero,
        theta=inverse(NOMINAL_GEOMETRY, xyz),
        theta_dot=zero,
        theta_ddot=zero,
        gripper=np.zeros(samples, dtype=bool),
        pick_indices=np.zeros(0, dtype=np.int64),
        place_indices=np.zeros(0, dtype=np.int64),
    )


def settle_time(errors: np.ndarray, window: float = 0.05e-3) -> int:
    """Samples (ms) until the error stays within ``window`` (m)."""
    return int(np.nonzero(errors > window)[0][-1] + 1)


def test_a_step_against_static_friction_settles_inside_the_window() -> None:
    """0.2 mm at rest: static friction holds the paper's PD short of it (Kp e < fc); the servo settles within
    0.05 mm and stays there. Pushing the Coulomb friction alone it settles in 19 ms (without a push 290 ms), pushing
    the breakaway (with the plant's Stribeck excess) in 11 ms; then within 0.011 mm."""
    setup = ControllerSetup(mid=NOMINAL_RODS, mid_f=NOMINAL_RODS, mid_f_rods=NOMINAL_RODS, drive_lag=LAG)
    env = DeltaPickPlaceEnv()
    reference = step_reference(2e-4)
    errors = {}
    for servo, excess in (("servo", None), ("servo", STRIBECK_EXCESS), ("pd", None)):
        controller = model_row("mid_f_r", dataclasses.replace(setup, servo=servo, stribeck_excess=excess))
        errors[servo, excess] = run_episode(env, controller, seed=0, reference=reference).tracking_error
    assert isinstance(model_row("mid_f_r", dataclasses.replace(setup, servo="pd")).servo, PDController)
    assert errors["pd", None][-1] > 0.1e-3  # the stick band of the fixed PD
    coulomb, breakaway = settle_time(errors["servo", None]), settle_time(errors["servo", STRIBECK_EXCESS])
    assert coulomb < 30, f"settled after {coulomb} ms"
    assert breakaway < 15 and breakaway < 0.75 * coulomb, f"settled after {breakaway} ms ({coulomb} ms)"
    assert max(errors["servo", None][-100:].max(), errors["servo", STRIBECK_EXCESS][-100:].max()) < 0.02e-3


def test_rows_push_their_friction_models_breakaway_at_rest() -> None:
    """The identified Stribeck excess adds to the Coulomb friction of a row that models friction; a row without a
    friction model (MKH, MId) pushes nothing, and without an identified excess the Coulomb friction alone."""
    setup = ControllerSetup(
        mid=ModelParameters(rho1=1.7, rho2=0.9),
        mid_f=NOMINAL_RODS,
        mid_f_rods=NOMINAL_RODS,
        drive_lag=LAG,
        stribeck_excess=STRIBECK_EXCESS,
    )
    assert_allclose(model_row("mid_f_rls_lag", setup).base.servo.gains.breakaway, (6.0, 5.1, 6.9))
    assert_allclose(model_row("mid_f", setup).servo.gains.breakaway, (6.0, 5.1, 6.9))
    assert model_row("mid", setup).servo.gains.breakaway == (0.0, 0.0, 0.0)
    assert model_row("mkh", setup).servo.gains.breakaway == (0.0, 0.0, 0.0)
    unknown = dataclasses.replace(setup, stribeck_excess=None)
    assert model_row("mid_f_r", unknown).servo.gains.breakaway == NOMINAL_RODS.coulomb
    with pytest.raises(ValueError, match="stribeck_excess"):
        dataclasses.replace(setup, stribeck_excess=(1.0, -1.0, 1.0))


def test_no_feedback_on_the_reference_itself_when_rates_are_measured_alike() -> None:
    """A joint exactly on a quintic reference, its rate the encoder's backward difference: the servo pushes nothing.
    With the instantaneous reference rate it would push kd period thdd / 2 (5.5 N m at kd 76 and 144 rad/s^2)."""
    gains = ServoGains(kp=(4600.0,) * 3, ki=(9e4,) * 3, kd=(76.0,) * 3, breakaway=(4.0,) * 3)
    servo = JointServo(gains)
    t = np.arange(0.0, 0.2, 0.001)
    s = t / 0.2
    angle = 10 * s**3 - 15 * s**4 + 6 * s**5  # 1 rad in 0.2 s
    rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / 0.2
    acceleration = (60 * s - 180 * s**2 + 120 * s**3) / 0.2**2
    torques = []
    for k in range(1, len(t) - 1):
        torques.append(
            servo.feedback(
                {
                    "reference_angles": np.full(3, angle[k]),
                    "joint_angles": np.full(3, angle[k]),
                    "reference_velocities": np.full(3, rate[k]),
                    "reference_accelerations": np.full(3, acceleration[k]),
                    "joint_velocities": np.full(3, (angle[k] - angle[k - 1]) / 0.001),
                }
            )
        )
    assert np.abs(acceleration).max() > 140.0
    # What is left is the third-order term of the backward difference, against 5.5 N m unlike.
    assert np.abs(torques[1:]).max() < 0.05


def test_a_scheduled_servo_keeps_the_triple_pole_on_the_inertia_it_is_given() -> None:
    """With 4 kg at the conveyors' pose the joint inertia is about four times the design's: scheduled, the loop keeps
    its triple pole at the bandwidth there; unscheduled its poles would be those of J s^3 + kd s^2 + kp s + ki with
    the design's gains, about half as fast."""
    dynamics = DeltaDynamics.nominal(NOMINAL_RODS, forearm_rods=True)
    design = joint_inertia(dynamics.inverse_dynamics)
    servo = JointServo(servo_gains(design, NOMINAL_RODS.coulomb, LAG))
    pose = np.array([0.6, 0.5, 0.7])
    heavy = model_inertia(dynamics, pose, 4.0)
    assert_allclose(heavy, joint_inertia(dynamics.inverse_dynamics, pose, 4.0), rtol=1e-12)
    assert np.all(heavy > 3.5 * design)
    bandwidth = servo_bandwidth(loop_delay(0.001))
    fixed = [np.roots([heavy[j], servo.gains.kd[j], servo.gains.kp[j], servo.gains.ki[j]]) for j in range(3)]
    assert max(np.abs(poles).min() for poles in fixed) < 0.6 * bandwidth
    servo.schedule(heavy)
    kp, ki, kd = servo.current_gains
    for joint in range(3):
        assert_allclose(np.roots([heavy[joint], kd[joint], kp[joint], ki[joint]]), -bandwidth, rtol=1e-3)
    servo.reset()  # back on the design's inertia
    assert servo.current_gains == (list(servo.gains.kp), list(servo.gains.ki), list(servo.gains.kd))
    with pytest.raises(ValueError, match="not placed on an inertia"):
        JointServo(ServoGains(kp=(1.0,) * 3, ki=(0.0,) * 3, kd=(0.0,) * 3)).schedule(heavy)


def test_rows_and_the_bound_schedule_their_servo_on_the_arm_at_the_reference() -> None:
    """A model row's servo is placed on its model's inertia at the reference's pose, the bound's on the plant's exact
    inertia there, without the payload either way (with 4 kg held, over 3.5 times as much)."""
    pose = np.array([0.6, 0.5, 0.7])
    sample = {
        "reference_angles": pose,
        "reference_velocities": np.zeros(3),
        "reference_accelerations": np.zeros(3),
        "joint_angles": pose,
        "joint_velocities": np.zeros(3),
        "joint_torques": np.zeros(3),
        "gripper": np.array([1.0]),
    }
    setup = ControllerSetup(mid=NOMINAL_RODS, mid_f=NOMINAL_RODS, mid_f_rods=NOMINAL_RODS, drive_lag=LAG)
    row = model_row("mid_f_r", setup)
    row(sample)
    scheduled = model_inertia(row.dynamics, pose, 0.0)
    assert_allclose(row.servo.current_gains[0], np.array(row.servo.gains.kp) * scheduled / row.servo.gains.inertia)
    bound = OracleController(PlantConfig(), servo="servo")
    bound.set_payload_masses([4.0])
    bound(sample)
    truth = joint_inertia(bound.oracle.torques, pose)
    assert_allclose(bound.servo.current_gains[0], np.array(bound.servo.gains.kp) * truth / bound.servo.gains.inertia)
    assert np.all(truth > 1.3 * np.array(bound.servo.gains.inertia))
    assert np.all(joint_inertia(bound.oracle.torques, pose, 4.0) > 3.5 * np.array(bound.servo.gains.inertia))


def test_a_schedule_does_not_step_the_command_and_a_reset_returns_to_the_design() -> None:
    """Bumpless: at the last sample's errors the scheduled gains and the integral give the command of before."""
    dynamics = DeltaDynamics.nominal(NOMINAL_RODS, forearm_rods=True)
    servo = JointServo(servo_gains(joint_inertia(dynamics.inverse_dynamics), NOMINAL_RODS.coulomb, LAG))
    sample = {
        "reference_angles": np.array([0.30, 0.20, 0.25]),
        "joint_angles": np.array([0.3002, 0.1997, 0.2501]),
        "reference_velocities": np.array([0.5, -0.4, 0.2]),
        "reference_accelerations": np.array([3.0, -2.0, 1.0]),
        "joint_velocities": np.array([0.47, -0.43, 0.21]),
    }
    before = servo.feedback(sample)
    error, rate_error = servo._error, servo._rate_error
    servo.schedule(1.5 * np.array(servo.gains.inertia))
    kp, _, kd = servo.current_gains
    after = [kp[j] * error[j] + kd[j] * rate_error[j] + servo.integral[j] for j in range(3)]
    assert_allclose(after, before, atol=1e-12)
    assert kp[0] == pytest.approx(1.5 * servo.gains.kp[0])
    servo.reset()
    assert_allclose(servo.integral, 0.0)
    assert servo.current_gains[0] == list(servo.gains.kp)
