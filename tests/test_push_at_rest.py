"""The push at rest behind the notch (issue 36, docs/design.md section 6, "Friction in motion at rest"): while a
joint's reference rests, a rotor its encoder reads moving gets its Coulomb friction compensated in the direction of
its motion (no term in the error, so no gain on the notched loop's pair), a still rotor the breakaway b sat(e / e_f)
that frees it; the rigid servo pushes the breakaway on every sample at rest, as before."""

import numpy as np
import pytest
import scipy.signal

from controllers.servo import JointServo, ResonanceNotch, servo_gains
from delta_env.kernels import STRIBECK_PEAK, STRIBECK_SIGN_SLOPE
from delta_env.scenario import preset
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, encoder_resolution

GEARHEAD = preset("compliant").plant.realism.compliance
ROTOR = GEARHEAD.rotor_inertia
ARM_INERTIA = np.array([0.3, 0.45, 1.0])
"""Arm side of each joint (kg m^2): empty at home to loaded."""

LAG = 1e-3
"""The drive's current-loop lag (s)."""

COULOMB, STRIBECK_EXCESS, STRIBECK_VELOCITY, VISCOUS = 4.0, 1.6, 0.05, 2.0
"""The rotor's friction: Coulomb (N m), the Stribeck excess (N m) and its decay speed (rad/s), viscous (N m s/rad);
about the plant's nominal joint friction."""

BREAKAWAY = COULOMB + STRIBECK_EXCESS
"""What the servo pushes on a still rotor (N m): the identified Coulomb friction plus Stribeck excess."""

HOLDING = COULOMB + STRIBECK_PEAK * STRIBECK_EXCESS
"""What holds a stuck rotor (N m): the plant's Coulomb friction plus the most of the excess its smooth sign resists."""

MOTOR_STEP = encoder_resolution(ENCODER_BITS) / GEARHEAD.gear_ratio
"""The motor encoder's step at the joint (rad): 17 bits on the motor shaft behind the gearhead."""

SUBSTEPS = 20
"""Integration steps per control period."""


def _relay(servo: JointServo) -> None:
    """Give ``servo`` the push at rest before this law: the breakaway b sat(e / e_f) on every sample at rest."""
    servo.rest_push = lambda joint, error, rotor_rate: BREAKAWAY * np.clip(error / servo.gains.friction_width, -1, 1)


def _servo(breakaway: float, notched: bool = True) -> JointServo:
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, (GEARHEAD.stiffness,) * 3) if notched else None
    servo = JointServo(servo_gains(inertia, breakaway, LAG, notch=notch), notch=notch, rotor_friction=COULOMB)
    servo.schedule(np.diag(inertia) if notched else inertia)
    return servo


def _observation(error: float, rotor_rate: float, reference_rate: float = 0.0) -> dict[str, np.ndarray]:
    return {
        "reference_angles": np.full(3, error),
        "reference_velocities": np.full(3, reference_rate),
        "reference_accelerations": np.zeros(3),
        "joint_angles": np.zeros(3),
        "joint_velocities": np.full(3, rotor_rate),
    }


@pytest.mark.parametrize("notched", [True, False])
def test_a_moving_rotor_at_rest_gets_its_coulomb_friction_and_a_still_one_the_breakaway(notched: bool) -> None:
    """The servo with the push against the same servo without it (no breakaway, no rotor friction), fed the same
    samples: their torques differ by the push through the notch. Behind the notch a moving rotor gets fc in its
    direction of motion whatever its error, a still one b sat(e / e_f); the rigid servo b sat(e / e_f) at every
    sample at rest; none while the reference moves."""
    step = encoder_resolution(ENCODER_BITS)
    samples = [  # (error in encoder steps, the rotor's rate in rad/s, the reference's rate in rad/s)
        (3.0, 0.2, 0.0),  # moving to its target
        (-2.0, 0.2, 0.0),  # moving away from it
        (-1.0, -0.01, 0.0),  # moving back to it
        (-0.5, 0.0, 0.0),  # still: proportionally within the step
        (2.0, -0.1, 0.0),  # moving away on the other side
        (3.0, 0.0, 0.0),  # still: the whole breakaway
        (1.0, 0.0, 0.3),  # the reference moves: none
    ]
    pushed, unpushed = _servo(BREAKAWAY, notched), _servo(0.0, notched)
    unpushed.rotor_friction = np.zeros(3)
    difference = [
        pushed(observation)[0] - unpushed(observation)[0]
        for observation in (_observation(e * step, rate, moving) for e, rate, moving in samples)
    ]
    expected = [
        0.0
        if moving != 0.0
        else COULOMB * np.sign(rate)
        if notched and rate != 0.0
        else BREAKAWAY * np.clip(e, -1.0, 1.0)
        for e, rate, moving in samples
    ]
    if notched:
        b0, b1, b2, a1, a2 = pushed._notch_coefficients[0]
        expected = scipy.signal.lfilter([b0, b1, b2], [1.0, a1, a2], expected)
    np.testing.assert_allclose(difference, expected, rtol=1e-9, atol=1e-9)


def _release(relay: bool, stiffness_scale: float, arm: float, rotor: float, duration: float = 0.08) -> np.ndarray:
    """The arms' angle (rad), (samples, 3), at rest: three one-joint compliant drives (rotor, the preset's gearhead
    times ``stiffness_scale``, arm sides ``ARM_INERTIA``) under the notched servo at a reference at rest at 0, the
    rotor at ``rotor`` and the arm at ``arm`` (rad), both still. The rotor has the plant's friction (sticking up to
    ``HOLDING``; sliding, Coulomb, the Stribeck excess through the smooth sign and viscous), the encoder reads it to
    the motor encoder's step, the drive lags 1 ms. ``relay``: the push at rest before this law."""
    stiffness, damping = GEARHEAD.stiffness * stiffness_scale, GEARHEAD.damping
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, (stiffness,) * 3)
    servo = JointServo(servo_gains(inertia, BREAKAWAY, LAG, notch=notch), notch=notch, rotor_friction=COULOMB)
    if relay:
        _relay(servo)
    servo.schedule(np.diag(inertia))
    rotor_angle, rotor_rate, arm_angle, arm_rate = np.full(3, rotor), np.zeros(3), np.full(3, arm), np.zeros(3)
    drive, arms, h = np.zeros(3), [], CONTROL_PERIOD / SUBSTEPS
    last = np.round(rotor_angle / MOTOR_STEP) * MOTOR_STEP
    for _ in range(round(duration / CONTROL_PERIOD)):
        reading = np.round(rotor_angle / MOTOR_STEP) * MOTOR_STEP
        command = servo(
            {
                "reference_angles": np.zeros(3),
                "reference_velocities": np.zeros(3),
                "reference_accelerations": np.zeros(3),
                "joint_angles": reading,
                "joint_velocities": (reading - last) / CONTROL_PERIOD,
            }
        )
        last = reading
        for _ in range(SUBSTEPS):
            spring = stiffness * (rotor_angle - arm_angle) + damping * (rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            net = drive - spring
            sliding = rotor_rate != 0.0
            speed = rotor_rate / STRIBECK_VELOCITY
            excess = STRIBECK_EXCESS * np.exp(-(speed**2)) * np.tanh(STRIBECK_SIGN_SLOPE * speed)
            friction = np.where(
                sliding,
                COULOMB * np.sign(rotor_rate) + excess + VISCOUS * rotor_rate,
                np.clip(net, -HOLDING, HOLDING),
            )
            new_rate = rotor_rate + h * (net - friction) / ROTOR
            rotor_rate = np.where(sliding & (np.sign(new_rate) != np.sign(rotor_rate)), 0.0, new_rate)  # it sticks
            arm_rate += h * spring / ARM_INERTIA
            rotor_angle += h * rotor_rate
            arm_angle += h * arm_rate
        arms.append(arm_angle.copy())
    return np.array(arms)


def _swing(arms: np.ndarray, start: int, end: int) -> float:
    """The arms' peak-to-peak swing (rad) from sample ``start`` to ``end``, summed over the three."""
    window = arms[start:end]
    return float((window.max(axis=0) - window.min(axis=0)).sum())


@pytest.mark.parametrize(("stiffness_scale", "twist"), [(0.7, 300e-6), (1.0, 300e-6), (1.0, 600e-6), (1.4, 600e-6)])
def test_the_ring_after_a_stop_decays_faster_than_under_the_relay(stiffness_scale: float, twist: float) -> None:
    """After a stop's twist is released (the rotor at the target, the arm ``twist`` past it), the arms swing 1 to 2.5
    mrad peak to peak in sum over the three in the first 10 ms, at the notched loop's pair; 30 to 60 ms after it the
    relay (the breakaway pushed in the error's direction, a gain 4b / (pi A) on the pair) leaves 0.46 to 0.84 mrad, the
    friction compensated in motion 0.07 to 0.49 of that."""
    law, relay = _release(False, stiffness_scale, twist, 0.0), _release(True, stiffness_scale, twist, 0.0)
    assert _swing(law, 30, 60) < 0.6 * _swing(relay, 30, 60)


@pytest.mark.parametrize("stiffness_scale", [0.7, 1.4])
def test_a_rotor_stalled_short_of_its_target_is_freed(stiffness_scale: float) -> None:
    """Joints at rest 0.3 mrad short of their target, rotor and arm (kp e 2.4 to 7 N m, the lighter two below the
    5.3 N m that hold the rotor): the breakaway on the still rotor frees them and the compensated friction carries
    them in, every arm within 70 urad of the target from 30 ms on and 45 at the end (about one encoder step at the
    joint, the push's width); with the Coulomb friction compensated but no push on a still rotor, the lighter two
    stay 0.29 to 0.36 mrad off."""
    arms = _release(False, stiffness_scale, 300e-6, 300e-6)
    assert np.abs(arms[30:]).max() < 100e-6
    assert np.abs(arms[-1]).max() < 60e-6
    pushed = JointServo.rest_push

    def compensated_only(servo: JointServo, joint: int, error: float, rotor_rate: float) -> float:
        return 0.0 if rotor_rate == 0.0 else pushed(servo, joint, error, rotor_rate)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(JointServo, "rest_push", compensated_only)
        stalled = _release(False, stiffness_scale, 300e-6, 300e-6)
    assert np.abs(stalled[-1]).max() > 250e-6
