"""The servo on a gearhead with backlash (issue 36, docs/design.md section 6, "Backlash"): inside the band the rotor
is alone, and gains placed on the rotor and the arm together are several times too high for it; with the band known
and a load encoder the servo places them on the rotor alone there and the joint comes to rest. Through a torque
reversal the rotor strikes the other flank, and its rattle there is damped on the arm's rate, not the rotor's."""

import numpy as np
import pytest

from controllers.compliance import SMALLEST_BACKLASH, DriveCompliance, band_deflection, static_deflection
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.servo import JointServo, ResonanceNotch, servo_gains
from delta_env.scenario import preset
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, encoder_resolution

GEARHEAD = preset("compliant").plant.realism.compliance
ROTOR = GEARHEAD.rotor_inertia
STIFFNESS = GEARHEAD.stiffness_per_joint
DAMPING = GEARHEAD.damping_per_joint
BACKLASH = np.full(3, 3.0 * 2.908882e-4)
"""3 arcmin per gearhead (rad): the SP+ 140's standard class."""

ARM_INERTIA = np.array([0.2, 0.3, 0.45])
"""Arm side of each joint (kg m^2): the nominal arm's diagonal, empty at home to loaded."""

LAG = 1e-3
"""The drive's current-loop lag (s)."""

SUBSTEPS = 20
"""Integration steps per control period: the dead band's kinks need a step well below the mode's period."""


def _gearhead(twist: np.ndarray, twist_rate: np.ndarray) -> np.ndarray:
    """The torque (N m) each gearhead passes at a ``twist`` (rad, rotor minus arm) and its rate (rad/s): its spring
    and damper beyond the half band of :data:`BACKLASH` on either side, nothing inside it."""
    beyond = twist - np.clip(twist, -0.5 * BACKLASH, 0.5 * BACKLASH)
    return np.where(beyond != 0.0, STIFFNESS * beyond + DAMPING * twist_rate, 0.0)


def _at_rest(rotor: np.ndarray, last_rotor: np.ndarray, arm: np.ndarray) -> dict[str, np.ndarray]:
    """The servo's observation of joints whose reference rests at 0: the rotors' angles ``rotor`` (rad), their rates
    from the sample before's ``last_rotor``, and the arms' angles ``arm`` (rad) on the load encoders."""
    zero = np.zeros(3)
    return {
        "reference_angles": zero,
        "reference_velocities": zero,
        "reference_accelerations": zero,
        "joint_angles": rotor.copy(),
        "joint_velocities": (rotor - last_rotor) / CONTROL_PERIOD,
        "load_angles": arm.copy(),
    }


def _rattle(backlash_known: np.ndarray | None, duration: float = 0.5) -> np.ndarray:
    """Per joint, the rotor's peak-to-peak motion (rad) over the last 0.1 s of ``duration`` (s) at a reference at rest
    at 0 with no load (the rotor inside the band, which it starts at its edge), three independent joints with the
    band ``BACKLASH``, under the notched servo placed on the rotor and the arm, told ``backlash_known`` (rad) or
    None; the observation carries the load encoder's angle."""
    inertia = ROTOR + ARM_INERTIA
    servo = JointServo(
        servo_gains(inertia, 0.0, LAG),
        notch=ResonanceNotch((ROTOR,) * 3, tuple(STIFFNESS)),
        rate_window=CONTROL_PERIOD,
        backlash=backlash_known,
    )
    servo.schedule(inertia)
    rotor, rotor_rate = 0.5 * BACKLASH.copy(), np.zeros(3)
    arm, arm_rate, drive = np.zeros(3), np.zeros(3), np.zeros(3)
    last_rotor = rotor.copy()
    history = []
    h = CONTROL_PERIOD / SUBSTEPS
    for _ in range(round(duration / CONTROL_PERIOD)):
        observation = _at_rest(rotor, last_rotor, arm)
        command = servo.feedback(observation)
        last_rotor = rotor.copy()
        for _ in range(SUBSTEPS):
            spring = _gearhead(rotor - arm, rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            rotor_rate += h * (drive - spring) / ROTOR
            arm_rate += h * spring / ARM_INERTIA
            rotor += h * rotor_rate
            arm += h * arm_rate
        history.append(rotor.copy())
    tail = np.array(history[-round(0.1 / CONTROL_PERIOD) :])
    return tail.max(axis=0) - tail.min(axis=0)


def test_gains_on_the_rotor_inside_the_band_stop_the_rattle() -> None:
    """Told nothing of the band, the servo drives the lone rotor with gains three to five times its inertia's, whose
    loop is unstable (|z| 1.09 to 1.18): it rattles from flank to flank, across the whole band. Told the band, it
    places them on the rotor there and the rotor comes to rest, to a hundredth of the band."""
    np.testing.assert_array_less(0.5 * BACKLASH, _rattle(None))
    np.testing.assert_array_less(_rattle(BACKLASH), 0.01 * BACKLASH)


def test_the_band_inertia_frees_each_rotor_in_the_band_of_its_arm() -> None:
    """Inside the band a joint's row and column of the inertia matrix become its rotor's inertia alone; the joints
    outside keep theirs, and the twist is the motor encoder's angle minus the load encoder's."""
    inertia = np.array([[0.5, 0.1, -0.05], [0.1, 0.6, 0.08], [-0.05, 0.08, 0.7]])
    servo = JointServo(
        servo_gains(np.diag(inertia), 0.0, LAG),
        notch=ResonanceNotch((ROTOR,) * 3, tuple(STIFFNESS)),
        backlash=BACKLASH,
    )
    servo.schedule(inertia)
    twist = np.array([0.4, 0.6, -0.4]) * BACKLASH
    observation = {"joint_angles": np.array([0.1, 0.2, 0.3]) + twist, "load_angles": np.array([0.1, 0.2, 0.3])}
    in_band = servo.in_band(observation)
    np.testing.assert_array_equal(in_band, [True, False, True])
    expected = np.array([[ROTOR, 0.0, 0.0], [0.0, 0.6, 0.0], [0.0, 0.0, ROTOR]])
    np.testing.assert_allclose(servo.band_inertia(in_band), expected, rtol=1e-12)


def test_a_servo_backlash_needs_the_notch() -> None:
    with pytest.raises(ValueError, match="notch"):
        JointServo(servo_gains(np.full(3, 0.4), 0.0, LAG), backlash=BACKLASH)


def test_the_deflection_takes_half_the_band_in_the_loads_direction() -> None:
    """The rotor rests on the flank the static load presses: delta = g / k + sign(g) b / 2; a backlash below
    SMALLEST_BACKLASH (an identification's estimate on a drive without any) is none."""
    model = DeltaDynamics.nominal()
    theta = np.array([0.3, -0.1, 0.5])
    load = model.inverse_dynamics(theta, np.zeros(3), np.zeros(3), 1.0)
    drives = DriveCompliance((ROTOR,) * 3, tuple(STIFFNESS), tuple(DAMPING), tuple(BACKLASH))
    expected = load / STIFFNESS + 0.5 * np.sign(load) * BACKLASH
    np.testing.assert_allclose(static_deflection(model, drives, theta, 1.0), expected, rtol=1e-12)
    tiny = DriveCompliance((ROTOR,) * 3, tuple(STIFFNESS), tuple(DAMPING), (0.5 * SMALLEST_BACKLASH,) * 3)
    np.testing.assert_allclose(static_deflection(model, tiny, theta, 1.0), load / STIFFNESS, rtol=1e-12)


REVERSAL_LOAD = np.array([10.0, -10.0, 10.0])
"""The arm sides' static load per joint (N m): gravity's, small beside the move's inertia torque, which reverses."""

ROTOR_FRICTION = 1.0
"""The rotor's Coulomb friction (N m), smoothed over 5 mrad/s: a drive's, a fraction of the plant's."""


def _through_reversal(band_rates: bool, move: float = 0.12, rest: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Three dead-band joints (3 arcmin, arm sides ``ARM_INERTIA``, static loads ``REVERSAL_LOAD``) driven 0.3 rad
    along a half cosine in ``move`` (s), whose arm torque reverses mid-move, then held for ``rest`` (s), under the
    model's feedforward and the notched servo told the band, fed the deflection the reference's torque asks (the
    law of :func:`controllers.compliance.band_deflection`, written out for these one-joint arms: the static load's
    g / k and half the band on the side of the arm's torque); with the servo's ``band_rates`` or, if False,
    the rotor's rate in the derivative term throughout. Returns per joint the twist's flank changes over the whole
    run and the arm's error (rad) over the last 50 ms."""
    inertia = ROTOR + ARM_INERTIA
    servo = JointServo(
        servo_gains(inertia, 0.0, LAG), notch=ResonanceNotch((ROTOR,) * 3, tuple(STIFFNESS)), backlash=BACKLASH
    )
    if not band_rates:
        servo.band_rates = lambda observation, in_band, rates, arm, rotor: (rates, rotor)
    servo.schedule(inertia)
    half = 0.5 * BACKLASH
    rotor = REVERSAL_LOAD / STIFFNESS + half * np.sign(REVERSAL_LOAD)
    rotor_rate, arm, arm_rate, drive = np.zeros(3), np.zeros(3), np.zeros(3), REVERSAL_LOAD.copy()
    last_rotor, twists, errors = rotor.copy(), [], []
    h, rate = CONTROL_PERIOD / SUBSTEPS, np.pi / move
    for step in range(round((move + rest) / CONTROL_PERIOD)):
        t = step * CONTROL_PERIOD
        moving = t < move
        angle = 0.15 * (1.0 - np.cos(rate * t)) if moving else 0.3
        velocity = 0.15 * rate * np.sin(rate * t) if moving else 0.0
        acceleration = 0.15 * rate**2 * np.cos(rate * t) if moving else 0.0
        flank = np.sign(ARM_INERTIA * acceleration + REVERSAL_LOAD) if moving else np.sign(REVERSAL_LOAD)
        observation = {
            "reference_angles": np.full(3, angle),
            "reference_velocities": np.full(3, velocity),
            "reference_accelerations": np.full(3, acceleration),
            "joint_angles": rotor.copy(),
            "joint_velocities": (rotor - last_rotor) / CONTROL_PERIOD,
            "load_angles": arm.copy(),
        }
        deflection = REVERSAL_LOAD / STIFFNESS + half * flank
        command = inertia * acceleration + REVERSAL_LOAD + servo.feedback(observation, deflection)
        last_rotor = rotor.copy()
        for _ in range(SUBSTEPS):
            spring = _gearhead(rotor - arm, rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            friction = ROTOR_FRICTION * np.tanh(rotor_rate / 5e-3)
            rotor_rate += h * (drive - spring - friction) / ROTOR
            arm_rate += h * (spring - REVERSAL_LOAD) / ARM_INERTIA
            rotor += h * rotor_rate
            arm += h * arm_rate
        twists.append((rotor - arm) / half)
        errors.append(arm - angle)
    flank_changes = (np.diff(np.sign(np.array(twists)), axis=0) != 0).sum(axis=0)
    return flank_changes, np.array(errors[-round(0.05 / CONTROL_PERIOD) :])


def test_the_arms_rate_above_the_rattle_brings_the_joints_to_rest_after_a_torque_reversal() -> None:
    """Through a torque reversal the rotor crosses the band and strikes the other flank; with the derivative term on
    the rotor's rate it keeps bouncing between the flanks (77 to 113 flank changes, the arms 1.4 to 4.1 mrad peak to
    peak over the last 50 ms); on the arm's rate above ``BAND_RATE_CUTOFF`` (:meth:`JointServo.band_rates`) it
    crosses a few times and the arms come to rest on the reference (10 to 24 flank changes, within 9 urad)."""
    flank_changes, errors = _through_reversal(band_rates=True)
    np.testing.assert_array_less(flank_changes, 35)
    np.testing.assert_array_less(np.abs(errors).max(axis=0), 15e-6)
    rotor_flank_changes, rotor_errors = _through_reversal(band_rates=False)
    np.testing.assert_array_less(100, rotor_flank_changes.sum() - flank_changes.sum())
    np.testing.assert_array_less(500e-6, rotor_errors.max(axis=0) - rotor_errors.min(axis=0))


def test_the_band_deflection_takes_the_flank_of_the_references_torque() -> None:
    """Moving, the rotor's half band lies on the side of the arm's torque, the model's joint torque less the rotor's
    J_m theta_ddot; at rest it is the static deflection; without a resolved backlash the elastic part alone."""
    model = DeltaDynamics.nominal()
    theta, rates = np.array([0.3, -0.1, 0.5]), np.array([0.5, -0.2, 0.1])
    accelerations = np.array([80.0, -60.0, 5.0])
    drives = DriveCompliance((ROTOR,) * 3, tuple(STIFFNESS), tuple(DAMPING), tuple(BACKLASH))
    arm = model.inverse_dynamics(theta, rates, accelerations, 1.0) - ROTOR * accelerations
    load = model.inverse_dynamics(theta, np.zeros(3), np.zeros(3), 1.0)
    expected = load / STIFFNESS + 0.5 * np.sign(arm) * BACKLASH
    np.testing.assert_allclose(band_deflection(model, drives, theta, rates, accelerations, 1.0), expected, rtol=1e-12)
    at_rest = band_deflection(model, drives, theta, np.zeros(3), accelerations, 1.0)
    np.testing.assert_allclose(at_rest, static_deflection(model, drives, theta, 1.0), rtol=1e-12)
    tiny = DriveCompliance((ROTOR,) * 3, tuple(STIFFNESS), tuple(DAMPING), (0.5 * SMALLEST_BACKLASH,) * 3)
    elastic = band_deflection(model, tiny, theta, rates, accelerations, 1.0)
    np.testing.assert_allclose(elastic, load / STIFFNESS, rtol=1e-12)
    assert np.sign(arm).tolist() != np.sign(load).tolist()  # the case tests a reversal


def test_the_flank_leaves_the_drives_friction_to_the_rotor() -> None:
    """The drive's friction acts on the rotor, not through the gearhead: on a model with friction, a joint whose
    motion torque is a few N m against its Coulomb friction presses the flank of that motion torque, not of the sum
    (the arm's torque computed by hand, on the frictionless model with the same inertia and gravity)."""
    parameters = ModelParameters(rho1=1.35, rho2=1.12, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6))
    frictionless = ModelParameters(rho1=1.35, rho2=1.12)
    model, bare = DeltaDynamics.nominal(parameters), DeltaDynamics.nominal(frictionless)
    drives = DriveCompliance((ROTOR,) * 3, tuple(STIFFNESS), tuple(DAMPING), tuple(BACKLASH))
    theta, rates = np.array([0.3, -0.1, 0.5]), np.array([-0.5, 0.4, -0.3])
    static = bare.inverse_dynamics(theta, np.zeros(3), np.zeros(3), 1.0)
    # accelerations that leave each arm torque +2 N m (opposite the friction of its rate on joints 0 and 2)
    column = np.array([bare.inverse_dynamics(theta, rates, np.eye(3)[j], 1.0) for j in range(3)]).T
    velocity_only = bare.inverse_dynamics(theta, rates, np.zeros(3), 1.0)
    accelerations = np.linalg.solve(column - velocity_only[:, None] - ROTOR * np.eye(3), 2.0 - velocity_only)
    arm = bare.inverse_dynamics(theta, rates, accelerations, 1.0) - ROTOR * accelerations
    np.testing.assert_allclose(arm, 2.0, atol=1e-9)
    expected = static / STIFFNESS + 0.5 * BACKLASH  # every flank positive
    got = band_deflection(model, drives, theta, rates, accelerations, 1.0)
    np.testing.assert_allclose(got, expected, rtol=1e-12)


LIGHT_LOAD = np.array([1.5, -1.5, 2.0])
"""Static loads per joint (N m) a few times less than the servo's transient torques: the joints that hunted at rest
on the 3-arcmin plant (about 1.5 N m through the gearhead)."""

ROTOR_COULOMB = 4.0
"""The rotor's Coulomb friction (N m): the plant's drive (4 N m, 0.85 to 1.15 times per joint)."""

ROTOR_BREAKAWAY = 5.6
"""Torque (N m) that starts the rotor from rest: Coulomb plus the Stribeck excess met on the way out."""


def _light_rest(floor: bool, duration: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Three dead-band joints (3 arcmin, arm sides ``ARM_INERTIA``, static loads ``LIGHT_LOAD``) at rest at 0 under
    the static load's feedforward and the notched servo told the band, the push at rest and the rotor's friction; the
    rotor starts on the far flank, where the braking torque of a move leaves it, and the arm 0.3 mrad off the
    reference on the side its load lets it fall, both moving that way at 0.02 rad/s. The rotor sticks below
    ``ROTOR_BREAKAWAY`` and slides against ``ROTOR_COULOMB``. With :meth:`JointServo.flank_floor` or, if ``floor``
    is False, without. Returns per joint the number of flank changes (the rotor meeting the other flank than the
    one it last pressed) and the sample (ms) after the last one."""
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, tuple(STIFFNESS))
    gains = servo_gains(inertia, ROTOR_BREAKAWAY, LAG, notch=notch, friction_width=encoder_resolution(ENCODER_BITS))
    servo = JointServo(gains, notch=notch, backlash=BACKLASH, rotor_friction=ROTOR_COULOMB)
    if not floor:
        servo.flank_floor = lambda observation, deflection, torque, integral: torque
    servo.schedule(inertia)
    half, flank = 0.5 * BACKLASH, np.sign(LIGHT_LOAD)
    deflection = LIGHT_LOAD / STIFFNESS + half * flank
    arm = 3e-4 * flank
    rotor = arm - half * flank
    rotor_rate, arm_rate, drive = 0.02 * flank, 0.02 * flank, LIGHT_LOAD.copy()
    last_rotor, sides = rotor.copy(), []
    h = CONTROL_PERIOD / SUBSTEPS
    for _ in range(round(duration / CONTROL_PERIOD)):
        observation = _at_rest(rotor, last_rotor, arm)
        command = LIGHT_LOAD + servo.feedback(observation, deflection)
        last_rotor = rotor.copy()
        for _ in range(SUBSTEPS):
            spring = _gearhead(rotor - arm, rotor_rate - arm_rate)
            drive += h * (command - drive) / LAG
            net = drive - spring
            sliding = rotor_rate != 0.0
            slid = rotor_rate + h * (net - ROTOR_COULOMB * np.sign(rotor_rate)) / ROTOR
            started = h * (net - ROTOR_COULOMB * np.sign(net)) / ROTOR
            rotor_rate = np.where(
                sliding,
                np.where(np.sign(slid) == np.sign(rotor_rate), slid, 0.0),
                np.where(np.abs(net) > ROTOR_BREAKAWAY, started, 0.0),
            )
            arm_rate += h * (spring - LIGHT_LOAD) / ARM_INERTIA
            rotor += h * rotor_rate
            arm += h * arm_rate
        twist = (rotor - arm) / half
        sides.append(np.where(np.abs(twist) >= 1.0, np.sign(twist), 0.0))
    sides = np.array(sides)
    changes, last_change = np.zeros(3, dtype=int), np.zeros(3, dtype=int)
    for joint in range(3):
        touching = np.flatnonzero(sides[:, joint])
        flips = touching[1:][np.diff(sides[touching, joint]) != 0]
        changes[joint] = flips.size
        last_change[joint] = flips.max() + 1 if flips.size else 0
    return changes, last_change


def test_the_flank_floor_stops_a_light_joint_hunting_across_the_band_at_rest() -> None:
    """A joint whose static load is a few N m holds its rotor on the load's flank only while the servo does not pull
    the rotor back faster than the load lets the arm follow. Without the floor the servo's pulls (its push at rest,
    the P and D terms on the arm's offset) throw the rotor to the far flank again and again (7, 45 and 73 flank
    changes in 0.3 s, the last at 56, 219 and 299 ms); with it the rotor lands on the loaded flank and stays (3, 3
    and 5 changes, the last at 35, 38 and 56 ms)."""
    changes, last_change = _light_rest(floor=True)
    np.testing.assert_array_less(changes, 10)
    np.testing.assert_array_less(last_change, 110)
    hunting_changes, hunting_last = _light_rest(floor=False)
    assert hunting_changes.sum() > 60
    assert hunting_last.max() > 200


def test_the_flank_floor_holds_the_pull_to_what_the_load_lets_the_arm_follow() -> None:
    """At rest the torque pulling a rotor off its loaded flank is raised to s f - |g| J / J_a (f the rotor's friction
    against its rate, |g| the static load the deflection implies) and the integral of that joint kept; a push, a
    joint whose reference moves and one whose pull is within the floor are left as they are."""
    inertia = ROTOR + ARM_INERTIA
    notch = ResonanceNotch((ROTOR,) * 3, tuple(STIFFNESS))
    servo = JointServo(servo_gains(inertia, 5.0, LAG, notch=notch), notch=notch, backlash=BACKLASH, rotor_friction=4.0)
    servo.schedule(inertia)
    load = np.array([2.0, -2.0, 2.0])
    deflection = load / STIFFNESS + 0.5 * BACKLASH * np.sign(load)
    observation = {"reference_velocities": np.array([0.0, 0.0, 0.3]), "joint_velocities": np.zeros(3)}
    servo._integral = [1.0, 2.0, 3.0]
    torque = np.array([-10.0, 3.0, -10.0])
    held = servo.flank_floor(observation, deflection, torque, [0.5, 0.5, 0.5])
    floor = -4.0 - 2.0 * inertia / ARM_INERTIA
    np.testing.assert_allclose(held, [floor[0], torque[1], torque[2]], rtol=1e-9)
    np.testing.assert_allclose(servo.integral, [0.5, 2.0, 3.0])
    rising = {"reference_velocities": np.zeros(3), "joint_velocities": np.array([1.0, -1.0, 1.0])}
    held = servo.flank_floor(rising, deflection, np.array([0.0, 0.0, 0.0]), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(held, np.sign(load) * (4.0 - 2.0 * inertia / ARM_INERTIA), rtol=1e-9)
