"""The push at rest behind the notch (issue 36, docs/design.md section 6, "A push at rest that feeds no ring"): once a
joint has passed its target, the breakaway torque is pushed only on a rotor its encoder reads still or one moving away
from its target, never on one already moving towards it, so it damps the notched loop's own ring after a stop instead
of driving it; a stuck rotor, and the approach before the pass, still get the whole push."""

import numpy as np
import pytest
import scipy.signal

from controllers.servo import JointServo, ResonanceNotch, servo_gains
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
the plant's nominal joint friction."""

BREAKAWAY = COULOMB + STRIBECK_EXCESS
"""What holds a stuck rotor (N m), and what the servo pushes at rest."""

MOTOR_STEP = encoder_resolution(ENCODER_BITS) / GEARHEAD.gear_ratio
"""The motor encoder's step at the joint (rad): 17 bits on the motor shaft behind the gearhead."""

SUBSTEPS = 20
"""Integration steps per control period."""


def _servo(breakaway: float, notched: bool = True) -> JointServo:
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, (GEARHEAD.stiffness,) * 3) if notched else None
    servo = JointServo(servo_gains(inertia, breakaway, LAG, notch=notch), notch=notch)
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
def test_the_push_stops_aiding_a_rotor_that_moves_to_its_target_once_it_has_passed_it(notched: bool) -> None:
    """The servo with the push against the same servo without it, fed the same samples: their torques differ by the
    push through the notch. Behind the notch the push is whole while the joint approaches (before its error has
    changed sign), then only on a still rotor or one moving away, and none in motion; the rigid servo pushes at every
    sample at rest."""
    step = encoder_resolution(ENCODER_BITS)
    samples = [  # (error in encoder steps, the rotor's rate in rad/s, the reference's rate in rad/s)
        (3.0, 0.2, 0.0),  # approaching: pushed
        (-2.0, 0.2, 0.0),  # past the target, moving away: pushed
        (-1.0, -0.1, 0.0),  # moving back to it: not
        (-0.5, 0.0, 0.0),  # still: pushed, proportionally within the step
        (2.0, -0.1, 0.0),  # moving away on the other side: pushed
        (1.0, 0.2, 0.0),  # moving to it: not
        (1.0, 0.0, 0.3),  # the reference moves: not, and a new rest begins
        (3.0, 0.2, 0.0),  # approaching again: pushed
    ]
    rigid_pushes = [reference_rate == 0.0 for _, _, reference_rate in samples]
    gated_pushes = [True, True, False, True, True, False, False, True]
    pushed, unpushed = _servo(BREAKAWAY, notched), _servo(0.0, notched)
    difference = [
        pushed(observation)[0] - unpushed(observation)[0]
        for observation in (_observation(e * step, rate, moving) for e, rate, moving in samples)
    ]
    expected = [
        BREAKAWAY * np.clip(e, -1.0, 1.0) * on
        for (e, _, _), on in zip(samples, gated_pushes if notched else rigid_pushes, strict=True)
    ]
    if notched:
        b0, b1, b2, a1, a2 = pushed._notch_coefficients[0]
        expected = scipy.signal.lfilter([b0, b1, b2], [1.0, a1, a2], expected)
    np.testing.assert_allclose(difference, expected, rtol=1e-9, atol=1e-9)


def _ring(gated: bool, stiffness_scale: float, twist: float, duration: float = 0.06) -> np.ndarray:
    """The arms' angle (rad), (samples, 3), after a stop: three one-joint compliant drives (rotor, the preset's
    gearhead times ``stiffness_scale``, arm sides ``ARM_INERTIA``) under the notched servo at a reference at rest at
    0, the rotor there and the arm ``twist`` (rad) past it, at rest (the stop's twist released); the rotor has
    stick-slip friction (sticking below the breakaway, Coulomb with the Stribeck excess and viscous friction when it
    slides), the encoder reads it to the motor encoder's step, the drive lags 1 ms. ``gated`` False: the push at rest
    on every sample, as before the gate."""
    stiffness, damping = GEARHEAD.stiffness * stiffness_scale, GEARHEAD.damping
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, (stiffness,) * 3)
    servo = JointServo(servo_gains(inertia, BREAKAWAY, LAG, notch=notch), notch=notch)
    if not gated:
        servo._pushes = lambda joint, error, reference_rate, rotor_rate: reference_rate == 0.0
    servo.schedule(np.diag(inertia))
    rotor, rotor_rate, arm, arm_rate, drive = np.zeros(3), np.zeros(3), np.full(3, twist), np.zeros(3), np.zeros(3)
    last, arms, h = np.zeros(3), [], CONTROL_PERIOD / SUBSTEPS
    for _ in range(round(duration / CONTROL_PERIOD)):
        reading = np.round(rotor / MOTOR_STEP) * MOTOR_STEP
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
            spring = stiffness * (rotor - arm) + damping * (rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            net = drive - spring
            sliding = rotor_rate != 0.0
            kinetic = COULOMB + STRIBECK_EXCESS * np.exp(-((rotor_rate / STRIBECK_VELOCITY) ** 2))
            friction = np.where(
                sliding, kinetic * np.sign(rotor_rate) + VISCOUS * rotor_rate, np.clip(net, -BREAKAWAY, BREAKAWAY)
            )
            new_rate = rotor_rate + h * (net - friction) / ROTOR
            rotor_rate = np.where(sliding & (np.sign(new_rate) != np.sign(rotor_rate)), 0.0, new_rate)  # it sticks
            arm_rate += h * spring / ARM_INERTIA
            rotor += h * rotor_rate
            arm += h * arm_rate
        arms.append(arm.copy())
    return np.array(arms)


@pytest.mark.parametrize(("stiffness_scale", "twist"), [(0.7, 300e-6), (0.7, 600e-6), (1.0, 300e-6), (1.0, 600e-6)])
def test_the_gated_push_damps_the_ring_after_a_stop(stiffness_scale: float, twist: float) -> None:
    """After a stop's twist is released, the arms swing 460 to 1090 urad peak to peak in the first 30 ms, at the
    notched loop's pair; 30 to 60 ms after it the push on every sample leaves 80 to 580 urad per arm, the gated push 6
    to 370, 0.19 to 0.48 of it in sum over the three arms."""

    def late_swing(arms: np.ndarray) -> float:
        window = arms[30:60]
        return float((window.max(axis=0) - window.min(axis=0)).sum())

    gated, ungated = late_swing(_ring(True, stiffness_scale, twist)), late_swing(_ring(False, stiffness_scale, twist))
    assert gated < 0.6 * ungated
