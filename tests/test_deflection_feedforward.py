"""The deflection feedforward of compliant drives (issue 36, docs/design.md section 6, "The deflection feedforward"):
the servo on the motor encoder holds the rotor at the arm's reference plus the gearhead's deflection under the
static load, so that the arm, not the rotor, comes to rest on the reference."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from controllers.compliance import DriveCompliance, static_deflection
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import FeedforwardController
from controllers.servo import JointServo, ResonanceNotch, ServoGains, servo_gains
from controllers.setup import model_row
from delta_env.scenario import preset
from delta_env.sensors import CONTROL_PERIOD

GEARHEAD = preset("compliant").plant.realism.compliance
SOFT = DriveCompliance(
    rotor_inertia=(GEARHEAD.rotor_inertia,) * 3,
    stiffness=tuple(0.7 * GEARHEAD.stiffness_per_joint),
    damping=tuple(GEARHEAD.damping_per_joint),
)
"""The preset's drives with gearheads 0.7 times as stiff: the soft plant the feedforward was built for."""

ARM_INERTIA = np.array([0.25, 0.35, 0.5])
"""Arm side of each joint (kg m^2): the nominal arm's diagonal empty at home to loaded at the conveyors."""

LOAD = np.array([40.0, -60.0, 90.0])
"""Constant torque each arm needs to stay at rest (N m): gravity and a payload, both signs."""

LAG = 1e-3
"""The drive's current-loop lag (s)."""


def _sampled_joints(stiffness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the three independent two-mass joints sampled over the control period, exact under a held command:
    per joint the state (phi, phi_dot, theta, theta_dot, drive torque), the inputs (command, arm load)."""
    rotor, damping = GEARHEAD.rotor_inertia, np.asarray(SOFT.damping)
    size = 15
    a = np.zeros((size + 6, size + 6))  # [A B; 0 0]: its exponential holds the sampled A and B
    for joint in range(3):
        i, k, c, arm = 5 * joint, stiffness[joint], damping[joint], ARM_INERTIA[joint]
        a[i, i + 1] = a[i + 2, i + 3] = 1.0
        a[i + 1, i : i + 5] = np.array([-k, -c, k, c, 1.0]) / rotor
        a[i + 3, i : i + 4] = np.array([k, c, -k, -c]) / arm
        a[i + 4, i + 4] = -1.0 / LAG
        a[i + 4, size + joint] = 1.0 / LAG  # the command
        a[i + 3, size + 3 + joint] = -1.0 / arm  # the load the arm's torque must meet
    sampled = expm(a * CONTROL_PERIOD)
    return sampled[:size, :size], sampled[:size, size:]


def _arm_at_rest(deflection: np.ndarray | None, duration: float = 0.6) -> np.ndarray:
    """The arms' angles (rad) after ``duration`` (s) at a reference at rest at 0, each joint's feedforward its load,
    the servo (gains on J_m + the arm, notched at the mode) on the motor encoder given ``deflection`` (rad), (3,),
    or None."""
    a, b = _sampled_joints(np.asarray(SOFT.stiffness))
    inertia = GEARHEAD.rotor_inertia + ARM_INERTIA
    servo = JointServo(
        servo_gains(inertia, 0.0, LAG), notch=ResonanceNotch(SOFT.rotor_inertia, SOFT.stiffness), rate_window=1e-3
    )
    state, last_rotor = np.zeros(15), np.zeros(3)
    zero = np.zeros(3)
    for _ in range(round(duration / CONTROL_PERIOD)):
        rotor = state[0::5]
        observation = {
            "reference_angles": zero,
            "reference_velocities": zero,
            "reference_accelerations": zero,
            "joint_angles": rotor,
            "joint_velocities": (rotor - last_rotor) / CONTROL_PERIOD,
        }
        command = LOAD + servo.feedback(observation, deflection)
        last_rotor = rotor.copy()
        state = a @ state + b @ np.concatenate([command, LOAD])
    return state[2::5]


def test_the_arm_rests_on_the_reference_with_the_deflection_fed_forward() -> None:
    """At rest the gearhead passes the arm's load L at k (phi - theta) = L: with the rotor held at the reference the
    arm sits L / k off it; with the deflection L / k fed forward it sits on it, and with a deflection from a stiffness
    twice the plant's it keeps half of L / k."""
    sag = LOAD / np.asarray(SOFT.stiffness)
    np.testing.assert_allclose(_arm_at_rest(None), -sag, rtol=0.02)
    np.testing.assert_allclose(_arm_at_rest(sag), 0.0, atol=0.01 * np.abs(sag).min())
    np.testing.assert_allclose(_arm_at_rest(0.5 * sag), -0.5 * sag, rtol=0.02)


@pytest.mark.parametrize("payload", [0.0, 2.5])
def test_the_static_deflection_is_the_models_torque_at_rest_over_the_stiffness(payload: float) -> None:
    """delta = tau(theta, 0, 0; m) / k: gravity's torque on the arms and the payload at the pose, whatever friction
    the model has (it takes none at rest)."""
    model = DeltaDynamics.nominal(ModelParameters(viscous=(2.0, 3.0, 4.0), coulomb=(5.0, 6.0, 7.0)))
    theta = np.array([0.3, -0.1, 0.5])
    torque = model.inverse_dynamics(theta, np.zeros(3), np.zeros(3), payload)
    expected = torque / np.asarray(SOFT.stiffness)
    np.testing.assert_allclose(static_deflection(model, SOFT, theta, payload), expected, rtol=1e-9)
    assert np.all(np.abs(expected) > 1e-5)  # tens of N m over 1.3e5 N m/rad


@pytest.mark.parametrize("window", [CONTROL_PERIOD, 0.25e-3])
def test_the_servo_takes_the_deflections_rate_over_the_encoders_window(window: float) -> None:
    """A deflection delta = a t^2 / 2 reads to the derivative term as its mean rate over the window w ending now,
    a (t - w / 2), the mean the measured rate is (the encoder's backward difference, or the last physics step): the
    servo's torque on a rotor at rest is kp delta + kd a (t - w / 2)."""
    kp, kd = np.array([1.0e4, 2.0e4, 3.0e4]), np.array([100.0, 150.0, 200.0])
    servo = JointServo(ServoGains(kp=tuple(kp), ki=(0.0,) * 3, kd=tuple(kd)), rate_window=window)
    zero = np.zeros(3)
    keys = ("reference_angles", "reference_velocities", "reference_accelerations", "joint_angles", "joint_velocities")
    observation = dict.fromkeys(keys, zero)
    acceleration = np.array([2.0, -3.0, 5.0])
    for step in range(4):
        time = step * CONTROL_PERIOD
        torque = servo.feedback(observation, 0.5 * acceleration * time**2)
    expected = kp * 0.5 * acceleration * time**2 + kd * acceleration * (time - 0.5 * window)
    np.testing.assert_allclose(torque, expected, rtol=1e-9)


@pytest.mark.parametrize("compliance", [None, SOFT])
def test_the_model_rows_feed_the_deflection_forward_only_on_compliant_drives(controller_setup, compliance) -> None:
    """A model row of a rigid setup gives its servo no deflection (the rigid results unchanged); one of a compliant
    setup gives it the deflection under its model's static load at the reference pose."""
    controller = model_row("mid_f_r", replace(controller_setup, compliance=compliance))
    assert isinstance(controller, FeedforwardController)
    observation = {
        "reference_angles": np.array([0.1, 0.2, 0.3]),
        "reference_velocities": np.array([0.5, -0.4, 0.0]),
        "reference_accelerations": np.array([20.0, 0.0, -10.0]),
    }
    deflection = controller.deflection(observation)
    if compliance is None:
        assert deflection is None
        return
    expected = static_deflection(controller.dynamics, SOFT, observation["reference_angles"], 0.0)
    np.testing.assert_allclose(deflection, expected, rtol=1e-12)
    assert np.all(np.abs(deflection) > 1e-5)


def test_a_deflection_feedforward_needs_the_servo_layer() -> None:
    with pytest.raises(ValueError, match="servo layer"):
        FeedforwardController("x", DeltaDynamics.nominal(), compliance=SOFT)
