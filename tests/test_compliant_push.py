"""The servo's push at rest on a compliant joint (issue 36, docs/design.md section 6, "The push at rest on a compliant
joint"): inside its width the push is a spring on the motor encoder's error, which adds to the loop's proportional
gain. At one encoder step it is about twelve times k_p, and the notched loop, whose margin the notch's lag has
spent, is unstable there; saturating where it is as stiff as k_p keeps the loop stable on gearheads the controllers
were not developed on."""

import numpy as np
import pytest
import scipy.signal

from controllers.servo import ResonanceNotch, compliant_friction_width, servo_gains
from delta_env.scenario import preset
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, encoder_resolution

GEARHEAD = preset("compliant").plant.realism.compliance
LAG = 1e-3
"""The drive's current-loop lag (s)."""

VISCOUS = 2.0
"""The drive's viscous friction on the rotor (N m s/rad)."""

BREAKAWAY = 5.5
"""The push (N m): the identified breakaway of the `compliant` preset's joints, 5.0 to 6.2 N m."""

STEP = encoder_resolution(ENCODER_BITS)
"""One motor encoder step (rad), the rigid servo's width."""


def _closed_loop_poles(stiffness: float, damping: float, arm_inertia: float, friction_width: float) -> np.ndarray:
    """Closed-loop poles (z) of one compliant joint at rest under the notched servo, its push inside the width a
    spring ``BREAKAWAY`` / ``friction_width`` (N m/rad) on the motor encoder's error added to k_p: the rotor, the
    gearhead ``stiffness`` (N m/rad) and ``damping`` (N m s/rad), the arm side ``arm_inertia`` (kg m^2), the 1 ms
    first-order lag over the 1 kHz zero-order hold, the backward-difference rate, the gains placed on the joint's
    inertia through the notch's lag and the notch at its mode."""
    rotor, period = GEARHEAD.rotor_inertia, CONTROL_PERIOD
    a = np.zeros((5, 5))  # x = (phi, phi_dot, theta, theta_dot, drive torque)
    a[0, 1] = a[2, 3] = 1.0
    a[1] = [-stiffness / rotor, -(damping + VISCOUS) / rotor, stiffness / rotor, damping / rotor, 1.0 / rotor]
    a[3] = [stiffness / arm_inertia, damping / arm_inertia, -stiffness / arm_inertia, -damping / arm_inertia, 0.0]
    a[4, 4] = -1.0 / LAG
    b = np.zeros((5, 1))
    b[4, 0] = 1.0 / LAG
    c = np.zeros((1, 5))
    c[0, 0] = 1.0
    discrete = scipy.signal.cont2discrete((a, b, c, np.zeros((1, 1))), period, "zoh")
    plant_num, plant_den = scipy.signal.ss2tf(*discrete[:4])
    inertia = np.full(3, rotor + arm_inertia)
    notch = ResonanceNotch((rotor,) * 3, (stiffness,) * 3)
    gains = servo_gains(inertia, BREAKAWAY, LAG, friction_width=STEP, notch=notch)
    kp = gains.kp[0] + BREAKAWAY / friction_width
    kd, ki = gains.kd[0], gains.ki[0]
    # C(z) = kp + kd (z - 1) / (T z) + ki T z / (z - 1) over the common denominator T z (z - 1), then the notch
    control_num = kp * np.polymul([period, 0.0], [1.0, -1.0]) + kd * np.polymul([1.0, -1.0], [1.0, -1.0])
    control_num = control_num + ki * period**2 * np.array([1.0, 0.0, 0.0])
    control_den = np.polymul([period, 0.0], [1.0, -1.0])
    b0, b1, b2, a1, a2 = notch.coefficients(float(notch.frequency(inertia)[0]))
    control_num, control_den = np.polymul(control_num, [b0, b1, b2]), np.polymul(control_den, [1.0, a1, a2])
    characteristic = np.polyadd(np.polymul(plant_den, control_den), np.polymul(plant_num[0], control_num))
    return np.roots(characteristic)


def _compliant_width(stiffness: float, arm_inertia: float) -> float:
    notch = ResonanceNotch((GEARHEAD.rotor_inertia,) * 3, (stiffness,) * 3)
    inertia = np.full(3, GEARHEAD.rotor_inertia + arm_inertia)
    return servo_gains(inertia, BREAKAWAY, LAG, friction_width=STEP, notch=notch).friction_width


@pytest.mark.parametrize(("stiffness_scale", "damping_scale"), [(1.0, 1.0), (0.7, 1.0), (0.5, 0.6), (1.4, 1.0)])
@pytest.mark.parametrize("arm_inertia", [0.195, 0.45, 1.0])
def test_the_push_no_stiffer_than_kp_keeps_the_notched_loop_stable(
    stiffness_scale: float, damping_scale: float, arm_inertia: float
) -> None:
    """At one encoder step the push makes the notched loop unstable (|z| 1.018 to 1.19 over these gearheads and arm
    sides); at the compliant width its poles stay inside the unit circle (|z| 0.988 to 0.990), and at half that width
    (the push 2 k_p) outside again (1.003 to 1.02)."""
    stiffness, damping = stiffness_scale * GEARHEAD.stiffness, damping_scale * GEARHEAD.damping
    width = _compliant_width(stiffness, arm_inertia)
    assert width > 2.0 * STEP
    largest = [
        float(np.max(np.abs(_closed_loop_poles(stiffness, damping, arm_inertia, w)))) for w in (STEP, width, width / 2)
    ]
    assert largest[0] > 1.015
    assert largest[1] < 0.995
    assert largest[2] > 1.0


def test_the_compliant_width_is_where_the_push_is_as_stiff_as_kp() -> None:
    """The width is max_j fb_j / kp_j, at least the step; the rigid servo keeps the step (its results unchanged)."""
    kp = np.array([9000.0, 10000.0, 12000.0])
    breakaway = np.array([5.0, 6.0, 6.0])
    assert compliant_friction_width(breakaway, kp, STEP) == pytest.approx(6.0 / 10000.0, rel=1e-12)
    assert compliant_friction_width(np.zeros(3), kp, STEP) == STEP
    rigid = servo_gains(np.full(3, 0.43), breakaway, LAG, friction_width=STEP)
    assert rigid.friction_width == STEP
    notched = servo_gains(
        np.full(3, 0.43), breakaway, LAG, friction_width=STEP, notch=ResonanceNotch((0.11,) * 3, (1.3e5,) * 3)
    )
    assert notched.friction_width == pytest.approx(max(breakaway / np.array(notched.kp)), rel=1e-12)
    with pytest.raises(ValueError, match="kp"):
        compliant_friction_width(breakaway, np.zeros(3), STEP)
    with pytest.raises(ValueError, match="step"):
        compliant_friction_width(breakaway, kp, 0.0)
