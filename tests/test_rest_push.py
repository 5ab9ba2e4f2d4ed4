"""The push at rest behind the notch (issue 36, docs/design.md section 6, "The push at rest behind the notch"): on
compliant drives the breakaway pushed in the error's direction is a relay whose gain on the loop's own 33-47 Hz pair
is 2 to 19 times kp, past the notched loop's gain margin; ramped up after each change of the error's sign it leaves
the pair its damping, and a rotor its encoder reads stuck still gets the whole breakaway."""

import math

import numpy as np

from controllers.servo import (
    CROSSOVER_RATIO,
    PUSH_RAMP_PERIODS,
    STUCK_PERIOD_SHARE,
    JointServo,
    ResonanceNotch,
    servo_gains,
)
from delta_env.scenario import preset
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, encoder_resolution

GEARHEAD = preset("compliant").plant.realism.compliance
ROTOR, STIFFNESS, DAMPING = GEARHEAD.rotor_inertia, GEARHEAD.stiffness, GEARHEAD.damping
STEP = encoder_resolution(ENCODER_BITS)
ARM_INERTIA = np.array([0.3, 0.6, 1.0])
"""Arm side of each joint (kg m^2): empty at home to loaded."""

BREAKAWAY, COULOMB = 5.0, 3.0
"""The rotor's static and sliding friction (N m); the servo pushes the static one (the identified breakaway)."""

LAG, SUBSTEPS = 1e-3, 20
WINDOW = 5e-5
"""The arm's error (rad) taken as settled: about 20 um at the platform, inside the cell's 50 um window."""


def _at_rest(start: float, duration: float, breakaway: float = BREAKAWAY) -> np.ndarray:
    """The arms' angles (rad), one row per control period, of three compliant joints (the preset's gearhead, arm
    sides :data:`ARM_INERTIA`) under the notched servo pushing ``breakaway`` (N m) at rest, reference at 0, rotor and
    arm starting at rest ``start`` (rad) off it: the rotor sticks below :data:`BREAKAWAY` and slides against
    :data:`COULOMB`, the 1 ms drive lag, the 17-bit motor encoder and its backward-difference rate."""
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, (STIFFNESS,) * 3)
    servo = JointServo(servo_gains(inertia, breakaway, LAG, notch=notch), notch=notch)
    servo.schedule(inertia)
    rotor, arm = np.full(3, start), np.full(3, start)
    rotor_rate, arm_rate, drive = np.zeros(3), np.zeros(3), np.zeros(3)
    last = np.round(rotor / STEP) * STEP
    zero, h, arms = np.zeros(3), CONTROL_PERIOD / SUBSTEPS, []
    for _ in range(round(duration / CONTROL_PERIOD)):
        reading = np.round(rotor / STEP) * STEP
        observation = {
            "reference_angles": zero,
            "reference_velocities": zero,
            "reference_accelerations": zero,
            "joint_angles": reading,
            "joint_velocities": (reading - last) / CONTROL_PERIOD,
        }
        command, last = servo.feedback(observation), reading
        for _ in range(SUBSTEPS):
            spring = STIFFNESS * (rotor - arm) + DAMPING * (rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            net = drive - spring
            stuck = (rotor_rate == 0.0) & (np.abs(net) <= BREAKAWAY)
            friction = COULOMB * np.where(rotor_rate != 0.0, np.sign(rotor_rate), np.sign(net))
            rate = rotor_rate + h * (net - friction) / ROTOR
            stops = (rotor_rate != 0.0) & (np.sign(rate) != np.sign(rotor_rate))  # sliding rotors stop at rate 0
            rotor_rate = np.where(stuck | stops, 0.0, rate)
            arm_rate += h * spring / ARM_INERTIA
            rotor += h * rotor_rate
            arm += h * arm_rate
        arms.append(arm.copy())
    return np.array(arms)


def _settle_times(arms: np.ndarray) -> np.ndarray:
    """Per joint, the time (s) from which its arm stays within :data:`WINDOW` of the reference to the end."""
    outside = np.abs(arms) > WINDOW
    last = np.array([np.flatnonzero(column)[-1] + 1 if column.any() else 0 for column in outside.T])
    return last * CONTROL_PERIOD


def _pair_period() -> np.ndarray:
    """The loop's pair period (s) per joint, 2 pi / (CROSSOVER_RATIO w0), w0 = kp / kd."""
    gains = servo_gains(ROTOR + ARM_INERTIA, BREAKAWAY, LAG, notch=ResonanceNotch((ROTOR,) * 3, (STIFFNESS,) * 3))
    return 2.0 * math.pi * np.array(gains.kd) / (CROSSOVER_RATIO * np.array(gains.kp))


def test_the_ring_after_a_stop_settles_as_the_damped_pair_does() -> None:
    """300 urad off at a stop, the joints ring at the loop's pair (about 40 Hz). With the push kept under half of kp
    on its swings the linear one-joint model damps the pair at least 0.12 (0.23 without a push, below 0.05 with the
    relay's 2 to 19 kp), so it decays to the window within ln(300 / 50) / (0.12 w), w the pair's angular frequency:
    58 to 60 ms here. Measured 33 to 72 ms with the ramped push (the lightest arm's rotor sticking once on the way);
    with the plain relay b sat(e / w) 88 ms on the heaviest arm, and the 0.3 and 0.6 kg m^2 arms still swing 120 to
    160 urad after 150 ms."""
    arms = _at_rest(3e-4, 0.15)
    bound = math.log(3e-4 / WINDOW) / (0.12 * 2.0 * math.pi / _pair_period())
    np.testing.assert_array_less(_settle_times(arms), 1.25 * bound)
    assert np.abs(arms[-50:]).max() < WINDOW


def test_a_stuck_rotor_is_freed_within_the_stuck_time() -> None:
    """200 urad off at rest, the rotor stuck (kp e about 1.6 to 4.6 N m below its 5 N m breakaway): its encoder
    reading no motion for STUCK_PERIOD_SHARE of the pair's period (6 ms), the push is the whole breakaway and the arm
    is in the window within 14 ms, where the ramp alone (PUSH_RAMP_PERIODS of the pair, 50 ms) would take 20 to 35;
    without any push only the integral frees the lightest arm's, after 92 ms."""
    stuck_time = STUCK_PERIOD_SHARE * _pair_period()
    pushed, unpushed = _at_rest(2e-4, 0.1), _at_rest(2e-4, 0.1, breakaway=0.0)
    first = np.array([np.flatnonzero(np.abs(column) < WINDOW)[0] * CONTROL_PERIOD for column in pushed.T])
    np.testing.assert_array_less(first, stuck_time + 0.01)
    assert np.all(first < 0.5 * PUSH_RAMP_PERIODS * _pair_period())
    assert np.flatnonzero(np.abs(unpushed[:, 0]) < WINDOW)[0] * CONTROL_PERIOD > 2.0 * first.max()
