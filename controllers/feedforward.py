"""Model-based feedforward plus a joint servo, and the oracle bound (docs/design.md section 6; the paper's Fig. 9).

tau = model(th_ref, thd_ref, thdd_ref; m_hat) + servo feedback

The servo is the paper's PD, Kp (th_ref - th) + Kd (thd_ref - thd) (:class:`~controllers.base.PDController`), or
the servo layer (:class:`~controllers.servo.JointServo`: integral action and friction compensation at rest).

- :class:`FeedforwardController` with an MKH, MId or MId+F :class:`~controllers.dynamics.DeltaDynamics`
  built from the nominal geometry and masses: m_hat = 0 without an estimator, or the online estimate of a
  :class:`~controllers.payload.PayloadEstimator` (MId+F + RLS).
- :class:`OracleController`: exact inverse of the plant, the closed-chain dynamics with the true payload and
  the drive's lag. It is the one controller that knows the truth (the plant configuration and the payload
  masses): a bound for comparison, never a controller a real robot could run. Its name says so.

Controllers see only the observation and nominal or identified parameters; none takes an env or a plant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm

from controllers.base import JointFeedback, Observation, PDController
from controllers.compliance import DriveCompliance, band_deflection
from controllers.drive import ReferencePredictor
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.payload import FRICTION_VELOCITY, EmptyMoveSums, PayloadEstimator
from controllers.servo import (
    DEFAULT_FRICTION_WIDTH,
    JointServo,
    ServoGains,
    compliant_servo,
    joint_inertia,
    joint_inertia_matrix,
    model_inertia,
    model_inertia_matrix,
    servo_gains,
)
from delta_env.config import RATED_PAYLOAD, PhysicalParameters, PlantConfig
from delta_env.drive import SampledLag
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.oracle import CompliantDriveOracle, InverseDynamicsOracle, RotorMotion
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY, encoder_resolution, rate_window
from delta_env.trajectories import Trajectory
from delta_env.validation import require_in


class FeedforwardController:
    """A joint servo plus the feedforward of an analytical model at the reference, with an optional payload estimate.

    Args:
        name: Label in tables and plots (e.g. ``"MId+F+PD"``).
        dynamics: The model; use ``DeltaDynamics.nominal(parameters)`` for nominal geometry and masses.
        servo: The feedback part; ``PDController()`` (Kp 3000 N m/rad, Kd 60 N m s/rad) when None.
        estimator: Online payload estimator; None feeds forward mp = 0.
        compliance: The drives' compliance (:class:`~controllers.compliance.DriveCompliance`), whose encoders read the
            rotors: the servo layer then holds them at the reference plus the gearheads' deflection under the static
            load (:meth:`deflection`); None: rigid drives. It needs the servo layer
            (:class:`~controllers.servo.JointServo`).
    """

    def __init__(
        self,
        name: str,
        dynamics: DeltaDynamics,
        *,
        servo: JointFeedback | None = None,
        estimator: PayloadEstimator | None = None,
        compliance: DriveCompliance | None = None,
    ) -> None:
        if estimator is not None and estimator.dynamics is not dynamics:
            raise ValueError("the estimator must use the controller's model (the same DeltaDynamics)")
        if compliance is not None and not isinstance(servo, JointServo):
            raise ValueError(
                f"the deflection feedforward of compliant drives needs the servo layer (a JointServo), got {servo!r}"
            )
        self.name = name
        self.dynamics = dynamics
        self.servo = PDController() if servo is None else servo
        self.estimator = estimator
        self.compliance = compliance
        self._scheduled = isinstance(self.servo, JointServo) and self.servo.scheduled

    @property
    def payload_estimate(self) -> float:
        """The payload mass (kg) fed forward at the last call: 0 without an estimator."""
        return 0.0 if self.estimator is None else self.estimator.mass

    @property
    def feedforward_mass(self) -> float:
        """The apparent payload (kg) in the feedforward of the last call: the estimate plus the tare and the fitted
        platform-mass correction, as the model needs it; 0 without an estimator."""
        return 0.0 if self.estimator is None else self.estimator.apparent_mass

    def reset(self) -> None:
        self.servo.reset()
        if self.estimator is not None:
            self.estimator.reset()

    def schedule_servo(self, observation: Observation) -> None:
        """Every :data:`~controllers.servo.SCHEDULE_PERIOD`, place a scheduled servo's gains on the model's inertia at
        the reference's pose, without payload (:meth:`~controllers.servo.JointServo.schedule`), and its notch at the
        drive mode, if any, on that inertia with the payload fed forward (the mode falls with the load)."""
        if self._scheduled:
            angles = observation["reference_angles"]
            self.servo.follow_inertia(
                lambda: (
                    model_inertia(self.dynamics, angles, 0.0)
                    if self.servo.notch is None
                    else model_inertia_matrix(self.dynamics, angles, 0.0)
                ),
                None
                if self.servo.notch is None
                else lambda: model_inertia(self.dynamics, angles, max(0.0, self.feedforward_mass)),
            )

    def deflection(self, observation: Observation) -> NDArray[np.float64] | None:
        """The gearheads' deflection (rad), (3,), under the static load at this step's reference pose with the
        apparent payload of the last call (:func:`~controllers.compliance.static_deflection`); with backlash, half
        the band on the flank the reference's torque presses (:func:`~controllers.compliance.band_deflection`); None
        on rigid drives."""
        if self.compliance is None:
            return None
        return band_deflection(
            self.dynamics,
            self.compliance,
            observation["reference_angles"],
            observation["reference_velocities"],
            observation["reference_accelerations"],
            self.feedforward_mass,
        )

    def feedback(self, observation: Observation) -> NDArray[np.float64]:
        """The servo's torque (N m), (3,), scheduled first; on compliant drives with the rotors' reference
        (:meth:`deflection`)."""
        self.schedule_servo(observation)
        if self.compliance is None:
            return self.servo.feedback(observation)
        return self.servo.feedback(observation, self.deflection(observation))

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        tau0, phi = self.dynamics.torque_and_payload_regressor(
            observation["reference_angles"],
            observation["reference_velocities"],
            observation["reference_accelerations"],
        )
        feedback = self.feedback(observation)
        if self.estimator is None:
            return tau0 + feedback
        mass = self.estimator.update(observation, tau0, phi)
        return tau0 + mass * phi + feedback


ORACLE_KP = 6000.0
"""Proportional gain of the oracle's feedback (N m/rad)."""

ORACLE_DAMPING = 4.0
"""Damping the oracle's feedback keeps through the drive lag, Kd - Kp T (N m s/rad).

A lag T delays the feedback: to first order Kp e(t - T) = Kp e(t) - Kp T de/dt, so the lag takes Kp T of
damping away. The oracle's gains were chosen on the 1 ms lag of the default plant (Kp 6000, Kd 10, the best of
a small grid on episodes outside the evaluation's), which leaves 4 N m s/rad; :func:`oracle_gains` keeps that
on any lag. With Kd fixed at 10, a 2 ms lag leaves almost none and the bound rings (0.1 to 0.4 mm)."""


def oracle_gains(lag: float) -> tuple[float, float]:
    """The oracle's (Kp (N m/rad), Kd (N m s/rad)) on a drive with lag ``lag`` (s): Kd = ORACLE_DAMPING + Kp T."""
    require_in("lag", lag, 0.0, unit="s")
    return ORACLE_KP, ORACLE_DAMPING + ORACLE_KP * lag


COMPLIANT_KD_GRID = np.arange(0.0, 200.5, 0.5)
"""The derivative gains (N m s/rad) :func:`compliant_oracle_gains` chooses from."""


def compliant_oracle_gains(
    drives: CompliantDriveOracle, lag: float, *, period: float = CONTROL_PERIOD, rate_window: float = CONTROL_PERIOD
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The oracle's PD gains (Kp (N m/rad), Kd (N m s/rad), each per joint) on the compliant drives of ``drives``,
    from the linear loop of each joint's two masses.

    Each joint is its rotor (inertia and viscous friction) behind its gearhead's spring and damper to the arm, whose
    inertia is taken at home empty and with the rated payload (:func:`~controllers.servo.joint_inertia` of the arm
    side), driven through the first-order lag ``lag`` (s) by a command held over ``period`` (s), with the PD on the
    rotor's angle and its rate measured over ``rate_window`` (s; the backward difference of the samples when it is
    the period). Kp is :data:`ORACLE_KP`, halved until a Kd of :data:`COMPLIANT_KD_GRID` keeps every pole of the
    sampled loop inside the unit circle at both inertias; Kd is the one whose largest pole is least there, the
    gearhead's mode damped best. Through the lag and the sampling a larger Kd damps the mode less again (the windows
    of Kd on the preset, with and without its gearhead damping: docs/design.md section 4).
    """
    arm_inertias = [joint_inertia(drives.arm.torques, payload=payload) for payload in (0.0, RATED_PAYLOAD)]
    gains = []
    for joint in range(3):
        loops = [
            _sampled_compliant_joint(
                drives.stiffness[joint],
                drives.damping[joint],
                drives.rotor_inertia[joint],
                drives.viscous[joint],
                float(inertia[joint]),
                lag,
                period,
            )
            for inertia in arm_inertias
        ]
        for halvings in range(8):
            kp = ORACLE_KP * 0.5**halvings
            radii = [
                max(_largest_pole(*loop, kp, kd, period, rate_window) for loop in loops) for kd in COMPLIANT_KD_GRID
            ]
            best = int(np.argmin(radii))
            if radii[best] < 1.0:
                break
        else:
            raise ValueError(
                f"no stable oracle gains for joint {joint + 1}: at Kp {kp:g} N m/rad the least unstable Kd of the "
                f"grid leaves a pole at |z| = {radii[best]:.3f} (>= 1)"
            )
        gains.append((kp, float(COMPLIANT_KD_GRID[best])))
    kp, kd = zip(*gains, strict=True)
    return kp, kd


def _sampled_compliant_joint(
    stiffness: float,
    damping: float,
    rotor_inertia: float,
    viscous: float,
    arm_inertia: float,
    lag: float,
    period: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(A, B) of one compliant joint sampled with a zero-order hold over ``period`` (s): the state (phi, phi_dot, theta,
    theta_dot) and the drive's output with a lag, the input the held command (all SI)."""
    k, c = stiffness, damping
    lagging = lag > 0.0
    n = 5 if lagging else 4
    a = np.zeros((n + 1, n + 1))  # [A B; 0 0], whose exponential holds the sampled A and B
    a[0, 1] = a[2, 3] = 1.0
    a[1, :4] = np.array([-k, -(c + viscous), k, c]) / rotor_inertia
    a[3, :4] = np.array([k, c, -k, -c]) / arm_inertia
    a[1, 4] = 1.0 / rotor_inertia  # the drive's output, or without a lag the command itself
    if lagging:
        a[4, 4], a[4, 5] = -1.0 / lag, 1.0 / lag
    sampled = expm(a * period)
    return sampled[:n, :n], sampled[:n, n]


def _largest_pole(
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    kp: float,
    kd: float,
    period: float,
    rate_window: float,
) -> float:
    """The largest |pole| of the sampled joint (a, b) under u = -kp phi - kd (rate): with the backward difference over
    the period (the last sample phi_prev a state) when ``rate_window`` is the period, else the rotor's own rate."""
    n = len(b)
    closed = np.zeros((n + 1, n + 1))
    closed[:n, :n] = a
    closed[n, 0] = 1.0  # phi_prev
    feedback = np.zeros(n + 1)
    if math.isclose(rate_window, period):
        feedback[0], feedback[n] = -kp - kd / period, kd / period
    else:
        feedback[0], feedback[1] = -kp, -kd
    closed[:n] += np.outer(b, feedback)
    return float(np.max(np.abs(np.linalg.eigvals(closed))))


class OracleController:
    """Exact inverse of the plant, mechanism and drive, at the reference with the true payload: a bound.

    Knows the truth, unlike every other controller: the plant configuration (passed in), its physical
    parameters when randomized (:meth:`set_physical_parameters`), the mass of each object
    (:meth:`set_payload_masses`, given by the evaluation after ``env.reset``) and the reference ahead
    (:meth:`set_reference`). The object held is counted from the gripper's closing edges.

    Each step it takes the reference a short lead ahead (:class:`~controllers.drive.ReferencePredictor`: from the
    reference's samples when it has them, else predicted from this step's, which sees a jerk step one period late),
    takes the oracle's joint torque there and commands what makes the drive's lag deliver exactly that torque at the
    next control instant (:class:`~delta_env.drive.SampledLag`). The lead
    (:meth:`~delta_env.drive.SampledLag.hold_lead` of the plant's lag and physics step) makes the torque the plant
    integrates over the held period's physics steps the mean of what the reference wants at them: 0.25 ms on a
    direct drive at the default 0.5 ms step, 0.94 ms through the default 1 ms lag (docs/design.md section 6).
    Coulomb and Stribeck friction and the ripple are inverted by the oracle at the reference state. The feedback is a
    :class:`~controllers.servo.JointServo` either way, so that it compares the measured rate with the reference's
    rate measured alike (:class:`~controllers.drive.MeasuredReferenceRate`): on the reference its output is then
    zero, where the reference's instantaneous rate would leave kd window/2 times the acceleration (2.5 N m at 20 g
    through the encoders at Kd 10) pushing the arm off it. With ``servo="pd"`` it is a PD: with an exact
    feedforward it only has to correct integration error, and a large Kd mostly feeds the encoder's rate
    quantization (0.05 rad/s at 17 bit and 1 kHz, 3 N m at Kd = 60) into the arm, so the bound has its own gains,
    :func:`oracle_gains` of the plant's true lag (Kp 6000 N m/rad, Kd 10 N m s/rad at 1 ms).

    With ``servo="servo"`` (the registry's default, as for the model rows) the feedback is the servo layer
    (:mod:`controllers.servo`) on the plant's truth: gains placed on its exact inertia and true lag, its true Coulomb
    friction pushed at rest, so that the bound holds the place as well as the rows that run the servo layer.

    On compliant drives (``PlantRealism.compliance``) the feedforward is :class:`~delta_env.oracle.CompliantDriveOracle`
    at the lead: the rotor's torque that moves the arm along the reference through the gearhead, with the reference's
    jerk and snap from its samples (:meth:`~controllers.drive.ReferencePredictor.jet`). The motor encoders read the
    rotors, so the feedback compares them with the rotors' reference, the arms' plus the gearheads' deflection. With
    ``servo="servo"`` it is the model rows' servo on compliant drives (:func:`~controllers.servo.compliant_servo`)
    on the plant's truth: its drives' compliance, exact inertia, true lag and Coulomb friction, scheduled as theirs
    (:meth:`FeedforwardController.schedule_servo`: the gains on the exact inertia matrix at the reference, the notch
    on the exact inertia with the payload held); with ``"pd"``, the PD
    of :func:`compliant_oracle_gains` (docs/design.md section 4). A PD leaves the rotor where the friction at rest
    stops it, which the rows' integral and push at rest do not: it is no bound at the place.

    Args:
        plant: The configuration of the plant to invert (the env's ``plant_config``).
        servo: The feedback: ``"pd"``, a PD with :func:`oracle_gains` of the plant's lag (:func:`compliant_oracle_gains`
            on compliant drives), or ``"servo"``, the servo layer on the plant's truth; both follow
            :meth:`set_physical_parameters`.
        gains: Fixed feedback gains instead (:class:`~controllers.servo.ServoGains`), or None.
        period: Control period (s).
    """

    name = "Oracle+PD (bound)"

    def __init__(
        self,
        plant: PlantConfig,
        *,
        servo: Literal["pd", "servo"] = "pd",
        gains: ServoGains | None = None,
        period: float = CONTROL_PERIOD,
    ) -> None:
        if servo not in ("pd", "servo"):
            raise ValueError(f"servo must be 'pd' or 'servo', got {servo!r}")
        self.oracle = InverseDynamicsOracle(plant)
        self.compliant_drives = None if plant.realism.compliance is None else CompliantDriveOracle(plant)
        """The exact inverse of compliant drives (the rotors' motion and torque); None on rigid drives."""
        self._servo_kind = servo
        self._fixed_gains = gains
        self._timestep = plant.timestep
        self._encoder_bits = plant.realism.encoder_bits
        self._reference_ahead: Trajectory | None = None
        self._set_drive(plant.realism.actuator_lag, period)
        self.payload_masses: tuple[float, ...] = ()
        self._picks = 0
        self._holding = False

    def _set_drive(self, lag: float, period: float) -> None:
        """The sampled lag of the drive, the predictor of the reference at its hold lead and the feedback."""
        self.drive = SampledLag(lag, period)
        self.reference = ReferencePredictor(period, horizon=self.drive.hold_lead(self._timestep))
        self.reference.follow(self._reference_ahead)
        self.servo = self._feedback(lag, period)

    def _feedback(self, lag: float, period: float) -> JointServo:
        """The feedback on a plant with lag ``lag`` (s): fixed gains, the PD of :func:`oracle_gains` or
        :func:`compliant_oracle_gains` (no integral and no push at rest), or the servo layer on the plant's truth."""
        window = rate_window(self._encoder_bits, self._timestep)
        drives = self.compliant_drives
        if self._fixed_gains is not None:
            return JointServo(self._fixed_gains, period, rate_window=window)
        if self._servo_kind == "pd":
            if drives is not None:
                kp, kd = compliant_oracle_gains(drives, lag, period=period, rate_window=window)
            else:
                kp, kd = ((value,) * 3 for value in oracle_gains(lag))
            return JointServo(ServoGains(kp=kp, ki=(0.0,) * 3, kd=kd), period, rate_window=window)
        step = DEFAULT_FRICTION_WIDTH if self._encoder_bits is None else encoder_resolution(self._encoder_bits)
        inertia, breakaway = joint_inertia(self.oracle.torques), self.oracle.breakaway
        if drives is None:
            gains = servo_gains(inertia, breakaway, lag, period=period, friction_width=step)
            return JointServo(gains, period, rate_window=window)
        compliance = DriveCompliance(
            tuple(drives.rotor_inertia), tuple(drives.stiffness), tuple(drives.damping), tuple(drives.backlash)
        )
        return compliant_servo(
            inertia,
            breakaway,
            lag,
            compliance,
            friction_width=step,
            rate_window=window,
            period=period,
            rotor_friction=self.oracle.coulomb,
        )

    def set_payload_masses(self, masses: Sequence[float]) -> None:
        """The true masses (kg) of the objects of the next episode, in pick order (the truth)."""
        self.payload_masses = tuple(float(m) for m in masses)

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """The plant's true (e.g. randomized) masses, friction and lag, from ``env.plant.parameters``."""
        self.oracle.set_physical_parameters(parameters)
        if self.compliant_drives is not None:
            self.compliant_drives.set_physical_parameters(parameters)
        self._set_drive(parameters.actuator_lag, self.drive.period)

    def set_reference(self, trajectory: Trajectory | None) -> None:
        """The reference ahead (``env.trajectory``, the truth): the feedforward is taken from its samples
        (:meth:`~controllers.drive.ReferencePredictor.follow`); None predicts from each step's reference alone."""
        self._reference_ahead = trajectory
        self.reference.follow(trajectory)

    @property
    def payload_estimate(self) -> float:
        """The true mass (kg) of the object held, 0 when none."""
        return self.payload_masses[self._picks - 1] if self._holding else 0.0

    def reset(self) -> None:
        self.servo.reset()
        self.drive.reset()  # the plant's reset zeroes the drive's state
        self.reference.reset()
        self._picks = 0
        self._holding = False

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        holding = observation["gripper"].item(0) > 0.5
        if holding and not self._holding:
            self._picks += 1
            if self._picks > len(self.payload_masses):
                raise RuntimeError(
                    f"pick {self._picks} but only {len(self.payload_masses)} masses were given: call "
                    "set_payload_masses(info['payload_masses']) after env.reset"
                )
        self._holding = holding
        if self._fixed_gains is None and self.servo.scheduled:
            # the servo layer's schedule on the truth, as the rows' (FeedforwardController.schedule_servo): the exact
            # inertia at the reference without payload, its matrix behind a notch, the notch on it with the payload
            angles = observation["reference_angles"]
            if self.servo.notch is None:
                self.servo.follow_inertia(lambda: joint_inertia(self.oracle.torque, angles))
            else:
                self.servo.follow_inertia(
                    lambda: joint_inertia_matrix(self.oracle.torque, angles),
                    lambda: joint_inertia(self.oracle.torque, angles, self.payload_estimate),
                )
        if self.compliant_drives is None:
            torque_next = self.oracle.torque(*self.reference.next(observation), self.payload_estimate)
            return self.drive.command(torque_next) + self.servo.feedback(observation)
        rotors = self.compliant_drives.motion(*self.reference.jet(observation), self.payload_estimate)
        return self.drive.command(rotors.torque) + self.servo.feedback(observation, self._deflection_now(rotors))

    def _deflection_now(self, rotors: RotorMotion) -> NDArray[np.float64]:
        """The gearheads' deflection (rad), (3,), at this instant, which the motor encoders measure on top of the
        arms' reference: taken back from ``rotors`` (at the hold lead) by a Taylor step (off by lead^3 / 6 times the
        deflection's jerk: 3e-10 rad on the task's moves, 4e-7 rad next to a jerk step)."""
        lead = self.reference.horizon
        return rotors.deflection - lead * (rotors.deflection_rate - 0.5 * lead * rotors.deflection_acceleration)


class LagCompensatedController:
    """A model-based feedforward controller whose feedforward leads the drive's identified lag.

    command_k = SampledLag^-1(feedforward at the reference of t_{k+1}) + PD_k. The base controller runs as
    usual (its payload estimator, if any, updates on this step's observation); its feedforward is then
    evaluated at the reference one period ahead with the apparent payload it feeds forward (the estimate plus
    the tare, :attr:`FeedforwardController.feedforward_mass`).

    Args:
        name: Label in tables (e.g. ``"MId+F+R+RLS+lag+PD"``).
        base: The feedforward controller to compensate.
        time_constant: Identified lag per joint (s), shape (3,) or a scalar.
        period: Control period (s).
    """

    def __init__(
        self, name: str, base: FeedforwardController, time_constant: ArrayLike, period: float = CONTROL_PERIOD
    ) -> None:
        self.name = name
        self.base = base
        self.drive = SampledLag(time_constant, period)
        self.reference = ReferencePredictor(period)

    @property
    def payload_estimate(self) -> float:
        """The base's payload estimate (kg) at the last call."""
        return self.base.payload_estimate

    @property
    def estimator(self) -> PayloadEstimator | None:
        """The base's payload estimator, if any."""
        return self.base.estimator

    @property
    def dynamics(self) -> DeltaDynamics:
        """The base's model."""
        return self.base.dynamics

    def reset(self) -> None:
        self.base.reset()
        self.drive.reset()
        self.reference.reset()

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        feedback = self.base.feedback(observation)
        if self.base.estimator is not None:  # the base's payload estimate from this step's observation
            self.base.estimator.update(observation)
        tau0, phi = self.base.dynamics.torque_and_payload_regressor(*self.reference.next(observation))
        return self.drive.command(tau0 + self.base.feedforward_mass * phi) + feedback


Regressor = Literal["smoothed", "filtered", "reference"]


def controller_name(forearm_rods: bool, estimates_payload: bool, leads_lag: bool = False) -> str:
    """Label of a model-based controller: MId+F or MId+F+R feedforward + PD, with or without the RLS and the
    drive-lag lead."""
    return (
        ("MId+F+R" if forearm_rods else "MId+F")
        + ("+RLS" if estimates_payload else "")
        + ("+lag" if leads_lag else "")
        + "+PD"
    )


def model_controller(
    parameters: ModelParameters | None,
    *,
    forearm_rods: bool = False,
    regressor: Regressor | None = None,
    tare: float = 0.0,
    empty_moves: EmptyMoveSums | None = None,
    friction_velocity: float = FRICTION_VELOCITY,
    servo: JointFeedback | None = None,
    name: str | None = None,
    geometry: DeltaGeometry = NOMINAL_GEOMETRY,
    masses: DeltaMasses = NOMINAL_MASSES,
    drive_lag: ArrayLike | None = None,
    torque_delay: float = MEASURED_TORQUE_DELAY,
    compliance: DriveCompliance | None = None,
) -> FeedforwardController | LagCompensatedController:
    """A model feedforward + servo controller, optionally with the online payload estimator and the drive-lag lead.

    Args:
        parameters: Identified parameters of the robot's model; None is plain MKH.
        forearm_rods: The model with rod forearms (MId+F+R) instead of the paper's lumped forearms.
        regressor: Joint states of the payload estimator; None feeds forward mp = 0 (no estimator).
        tare: Apparent payload of the empty gripper (kg), subtracted by the estimator.
        empty_moves: Sums of the robot's earlier empty moves that seed the estimator's fit of its mass and friction
            errors (:class:`~controllers.payload.EmptyMoveSums`); None: none.
        friction_velocity: The estimator's friction band v_w (rad/s).
        servo: The feedback; None: ``PDController()``, the paper's PD.
        name: Label; by default :func:`controller_name`.
        geometry: Lengths of the robot (m) the model describes.
        masses: Datasheet masses of that robot (kg).
        drive_lag: Identified drive lag T (s) per joint (or one for all): the feedforward leads it
            (:class:`LagCompensatedController`); None feeds forward without a lead.
        torque_delay: Age of the torque readings against their encoder samples (s), for the payload estimator.
        compliance: Compliant drives' compliance, for the servo layer's deflection feedforward
            (:class:`FeedforwardController`); None: rigid drives.
    """
    dynamics = DeltaDynamics.of_robot(geometry, masses, parameters, forearm_rods=forearm_rods)
    estimator = None
    if regressor is not None:
        estimator = PayloadEstimator(
            dynamics,
            regressor=regressor,
            tare=tare,
            friction_velocity=friction_velocity,
            empty_moves=empty_moves,
            torque_delay=torque_delay,
        )
    label = name if name is not None else controller_name(forearm_rods, regressor is not None, drive_lag is not None)
    controller = FeedforwardController(label, dynamics, servo=servo, estimator=estimator, compliance=compliance)
    if drive_lag is None:
        return controller
    return LagCompensatedController(label, controller, drive_lag)
