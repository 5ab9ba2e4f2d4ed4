"""Exact closed-chain inverse dynamics of the MuJoCo plant: ground truth and the "exact feedforward" bound.

``mj_inverse`` alone does not distribute load through closed chains: with the loop constraints on, it
attributes ~0 force to them. The oracle therefore (docs/design.md section 4):

1. makes the state consistent: motor angles and rates fixed, passive coordinates assembled so every loop
   closes, J_c qvel = 0, and J_c qacc = -Jdot_c qvel with the motor accelerations fixed
   (Jdot_c qvel from ``mj_jacDot`` of the connected sites);
2. runs ``mj_inverse`` with the constraint solver disabled, which gives M qacc + c - qfrc_passive
   (armature, gravity, Coriolis, viscous friction included);
3. adds back what MuJoCo models as constraints or applied forces: Coulomb frictionloss
   (fc_i sign(theta_dot_i)) and the Stribeck excess and ripple that :class:`DeltaPlant` applies;
4. solves the square system [S  J_c^T] [tau; lambda] = rhs for the three motor torques (S selects
   the motor dofs; lambda are the loop forces).

This class returns the torque that must act at the joints. The drive's first-order lag is inverted on top of
it, exactly at the control instants, by :class:`delta_env.drive.SampledLag`, aimed at the torque of the instant
(:meth:`~delta_env.drive.SampledLag.hold_lead`) that gives the held period's physics steps the wanted mean
(the bound controller, ``controllers.feedforward.OracleController``, does all three). Coulomb friction enters
as fc_i sign(theta_dot_i), so at exactly zero rate (sticking, where friction is indeterminate) it is 0. The
ripple is a known function of the angle and is inverted at the reference angle: off the reference by delta it
errs by amplitude * periods * delta (0.02 N m for 0.1 mrad). Stribeck and ripple are those of the instantaneous
state, whereas the plant holds them over a control step.

On a plant with compliant drives (``PlantRealism.compliance``) this class inverts the same plant with rigid drives
(:func:`rigid_drives`: the rotor's inertia added to the arm's, the gearhead infinitely stiff), the torque of the
motion without the gearhead's deflection. The exact inverse of the compliant plant is
:class:`CompliantDriveOracle` (docs/design.md section 4, "The exact inverse of a compliant drive"): the torque the
gearhead must pass to the arm from this class on the arm alone (:func:`arm_behind_gearheads`), the gearhead's
deflection that passes it, the rotor's motion, and the rotor's torque.

The payload is a point mass added to the platform's CoM. That is exact for the motor torques wherever the
payload is carried rigidly by a platform that only translates (a moment on the platform does no virtual
work), so on the ideal variant the analytical MKH model with the same payload matches the oracle to
round-off, and on the realistic one a payload hanging under the suction cup needs the same torques.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels
from delta_env.config import MAX_PAYLOAD_MASS, PhysicalParameters, PlantConfig
from delta_env.plant import DeltaPlant
from delta_env.robot import CHAIN_LABELS, forearm_home_tilt

IMPLICIT_INTEGRATORS = (mujoco.mjtIntegrator.mjINT_IMPLICIT, mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
"""MuJoCo's integrators that take the velocity derivative of the passive forces into the step."""

DERIVATIVE_STEP = 1e-4
"""Time step (s) of the central differences that give the arm torque's first two time derivatives along the
reference (:meth:`CompliantDriveOracle.motion`): their truncation error, step^2 / 12 times the torque's fourth
derivative, and their round-off, about 1e-12 N m / step^2, stay below 0.01 N m/s^2 on the task's moves away from their
jerk steps, 1e-7 rad/s^2 of the gearhead's deflection."""


def rigid_drives(config: PlantConfig) -> PlantConfig:
    """``config`` with rigid drives: a compliant drive's rotor inertia added to the arm joint's ``armature`` and its
    gearhead dropped (``config`` itself if its drives are rigid)."""
    compliance = config.realism.compliance
    if compliance is None:
        return config
    armature = config.realism.armature + compliance.rotor_inertia
    return replace(config, realism=replace(config.realism, armature=armature, compliance=None))


def arm_behind_gearheads(config: PlantConfig) -> PlantConfig:
    """The arm side of a plant with compliant drives as a plant of its own: rigid drives without the rotor and without
    the friction, Stribeck excess and ripple that act on it; the arm joints keep their ``armature``. Its joint torques
    are what the gearheads must pass.

    Raises:
        ValueError: if ``config``'s drives are rigid.
    """
    realism = config.realism
    if realism.compliance is None:
        raise ValueError("config must have compliant drives (realism.compliance), got rigid ones")
    arm = replace(realism, compliance=None, viscous=0.0, coulomb=0.0, stribeck_excess=0.0, ripple_amplitude=0.0)
    return replace(config, realism=arm)


class InverseDynamicsOracle:
    """Motor torques that produce a given joint motion on the MuJoCo plant of ``config``.

    The oracle owns a plant built from ``config`` without a payload body and with the constraint solver
    disabled (with rigid drives: :func:`rigid_drives`); :meth:`set_physical_parameters` keeps it in step with a
    randomized plant.

    Args:
        config: The plant configuration (variant, geometry, masses, realism) to invert.
    """

    def __init__(self, config: PlantConfig | None = None) -> None:
        config = PlantConfig() if config is None else config
        if not isinstance(config, PlantConfig):
            raise ValueError(f"config must be a PlantConfig, got {type(config).__name__}")
        self.plant = DeltaPlant(replace(rigid_drives(config), payload_body=False))
        self.config = self.plant.config
        model = self.plant.model
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        self._platform_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "platform")
        self._platform_mass = float(model.body_mass[self._platform_body])
        motor_dofs = self.plant.motor_dofs
        self._motor_dofs = motor_dofs
        self._passive_dofs = np.setdiff1d(np.arange(model.nv), motor_dofs)
        self._set_friction()
        # Views of the model and data buffers the 1 kHz path reads and writes (they never move).
        self._body_mass = model.body_mass
        data = self.plant.data
        self._qvel, self._qacc, self._qfrc_inverse = data.qvel, data.qacc, data.qfrc_inverse
        self._no_bias = np.zeros(self.plant.loops.n_rows)
        # Columns of the square system [S  J_c^T]: the first three select the motor dofs.
        self._system = np.zeros((model.nv, model.nv))
        self._system[motor_dofs, np.arange(3)] = 1.0
        geometry = self.config.geometry
        self._r, self._l1, self._l2 = geometry.r, geometry.l1, geometry.l2
        self._tilt = forearm_home_tilt(geometry)
        # The one-sample batch of torque() and views of its row.
        self._theta, self._platform, self._elbows = np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3, 2))
        self._platform_row, self._elbows_row = self._platform[0], self._elbows[0]

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """Use the same (e.g. randomized) masses and friction as a plant; see DeltaPlant.set_physical_parameters.
        A compliant plant's gearhead scales do not apply to the rigid drives."""
        self.plant.set_physical_parameters(
            replace(parameters, stiffness_scale=(1.0, 1.0, 1.0), damping_scale=(1.0, 1.0, 1.0))
        )
        self._platform_mass = float(self.plant.model.body_mass[self._platform_body])
        self._set_friction()

    def _set_friction(self) -> None:
        """Coulomb frictionloss fc_i (N m) of the motor joints and the plant's Stribeck and ripple constants."""
        self._frictionloss = self.plant.model.dof_frictionloss[self._motor_dofs].copy()
        self._disturbance = self.plant.disturbance_coefficients.view(np.uint8)

    @property
    def coulomb(self) -> NDArray[np.float64]:
        """The plant's Coulomb friction per motor joint (N m), (3,): its ``frictionloss``, randomized with it."""
        return self._frictionloss.copy()

    @property
    def breakaway(self) -> NDArray[np.float64]:
        """The torque (N m), (3,), that takes each motor joint out of rest: its Coulomb friction plus the largest
        share of the plant's Stribeck excess on the way (:data:`delta_env.kernels.STRIBECK_PEAK`), randomized with
        them."""
        return self._frictionloss + kernels.STRIBECK_PEAK * self.plant.disturbance_coefficients["stribeck_gain"][0]

    def torques(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """Motor torques (N m) that give ``theta_ddot`` at (``theta``, ``theta_dot``) with ``payload`` carried.

        Args:
            theta: Motor angles (rad), shape (3,) or (N, 3).
            theta_dot: Motor rates (rad/s), same shape.
            theta_ddot: Motor accelerations (rad/s^2), same shape.
            payload: Carried payload mass (kg) in [0, MAX_PAYLOAD_MASS], a scalar or shape (N,).

        Returns:
            Torques at the joints, shape (3,) or (N, 3).

        Raises:
            ValueError: for mismatched shapes, non-finite values, a bad payload or unreachable angles.
        """
        theta, theta_dot, theta_ddot = (np.asarray(value, dtype=float) for value in (theta, theta_dot, theta_ddot))
        if theta.ndim not in (1, 2) or theta.shape[-1] != 3:
            raise ValueError(f"theta must have shape (3,) or (N, 3), got {theta.shape}")
        for name, value in (("theta_dot", theta_dot), ("theta_ddot", theta_ddot)):
            if value.shape != theta.shape:
                raise ValueError(f"{name} must have the shape of theta {theta.shape}, got {value.shape}")
        for name, value in (("theta", theta), ("theta_dot", theta_dot), ("theta_ddot", theta_ddot)):
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{name} must be finite")
        payload = np.asarray(payload, dtype=float)
        if payload.ndim > theta.ndim - 1:
            raise ValueError(f"payload must be a scalar or have shape (N,), got shape {payload.shape}")
        payloads = np.broadcast_to(payload, theta.shape[:-1]).reshape(-1)
        if not (np.all(np.isfinite(payloads)) and np.all((payloads >= 0.0) & (payloads <= MAX_PAYLOAD_MASS))):
            raise ValueError(f"payload must be a finite mass in [0, {MAX_PAYLOAD_MASS}] kg, got {payload}")
        # Kinematics for the whole batch at once; the MuJoCo part runs sample by sample.
        platform, elbows = self.plant.assembly_coordinates(theta)
        samples = zip(
            theta.reshape(-1, 3),
            theta_dot.reshape(-1, 3),
            theta_ddot.reshape(-1, 3),
            payloads,
            platform.reshape(-1, 3),
            elbows.reshape(-1, 3, 2),
            strict=True,
        )
        tau = np.stack([self._torques_one(*sample) for sample in samples])
        return tau.reshape(theta.shape)

    def torque(self, theta: NDArray, theta_dot: NDArray, theta_ddot: NDArray, payload: float) -> NDArray[np.float64]:
        """:meth:`torques` of one sample without input checks: the 1 kHz path of the bound controller.

        Same result as :meth:`torques`, bit for bit (the same :func:`delta_env.kernels.assembly`), without the
        NumPy set-up around it that costs more than the MuJoCo part for a single sample. The inputs must be
        finite (3,) arrays.

        Raises:
            ValueError: for unreachable angles.
        """
        self._theta[0] = theta
        status, _ = kernels.assembly(self._theta, self._r, self._l1, self._l2, self._tilt, self._platform, self._elbows)
        if status != kernels.VALID:
            raise ValueError(f"{kernels.INVALID_STATE[status]} at theta={theta.tolist()}")
        return self._torques_one(theta, theta_dot, theta_ddot, payload, self._platform_row, self._elbows_row)

    def _torques_one(
        self,
        theta: NDArray,
        theta_dot: NDArray,
        theta_ddot: NDArray,
        payload: float,
        platform: NDArray,
        elbows: NDArray,
    ) -> NDArray[np.float64]:
        plant = self.plant
        model, data = plant.model, plant.data
        motor_dofs, passive_dofs = self._motor_dofs, self._passive_dofs
        # The payload rides at the platform's CoM: mass only (a translating body's inertia does no work).
        self._body_mass[self._platform_body] = self._platform_mass + payload
        try:
            jac = plant.configure(theta, platform, elbows)
            # J_c qvel = 0 with the motor rates fixed, then J_c qacc = -Jdot_c qvel with the motor accelerations
            # fixed; mj_jacDot needs the velocity stage of the new state.
            _close_loops(jac, self._no_bias, theta_dot, motor_dofs, passive_dofs, self._qvel)
            mujoco.mj_comVel(model, data)
            _close_loops(jac, plant.loops.bias_acceleration(), theta_ddot, motor_dofs, passive_dofs, self._qacc)
            mujoco.mj_inverse(model, data)
        finally:
            self._body_mass[self._platform_body] = self._platform_mass
        return _motor_torques(
            self._system,
            jac,
            self._qfrc_inverse,
            motor_dofs,
            theta,
            theta_dot,
            self._frictionloss,
            self._disturbance,
        )


@numba.njit(cache=True)
def _close_loops(
    jac: NDArray[np.float64],
    bias: NDArray[np.float64],
    motor: NDArray[np.float64],
    motor_dofs: NDArray[np.int64],
    passive_dofs: NDArray[np.int64],
    out: NDArray[np.float64],
) -> None:
    """Write ``motor`` (3,) at ``motor_dofs`` of ``out`` (nv,) and the passive entries that solve
    J_c out = -bias: the velocities (bias 0) or the accelerations (bias Jdot_c qvel) that keep the loops closed."""
    n = len(passive_dofs)
    passive_jac = np.empty((n, n))
    rhs = np.empty(n)
    for row in range(n):
        for column in range(n):
            passive_jac[row, column] = jac[row, passive_dofs[column]]
        driven = 0.0
        for joint in range(3):
            driven += jac[row, motor_dofs[joint]] * motor[joint]
        rhs[row] = -bias[row] - driven
    passive = np.linalg.solve(passive_jac, rhs)
    for joint in range(3):
        out[motor_dofs[joint]] = motor[joint]
    for column in range(n):
        out[passive_dofs[column]] = passive[column]


@numba.njit(cache=True)
def _motor_torques(
    system: NDArray[np.float64],
    jac: NDArray[np.float64],
    qfrc_inverse: NDArray[np.float64],
    motor_dofs: NDArray[np.int64],
    theta: NDArray[np.float64],
    theta_dot: NDArray[np.float64],
    frictionloss: NDArray[np.float64],
    disturbance: NDArray[np.uint8],
) -> NDArray[np.float64]:
    """Motor torques (N m), (3,), from [S  J_c^T] [tau; lambda] = qfrc_inverse + Coulomb - Stribeck and ripple.

    The right-hand side adds the forces MuJoCo keeps outside ``qfrc_inverse``: Coulomb friction (a constraint,
    fc_i sign(theta_dot_i)) and the plant's ``qfrc_applied`` (:func:`delta_env.kernels.motor_disturbance` with the
    bytes of the plant's ``disturbance`` record). ``system`` (nv, nv) holds S in its first three columns; the others
    receive J_c^T.
    """
    rhs = qfrc_inverse.copy()
    coefficients = disturbance.view(kernels.DISTURBANCE)[0]
    for joint in range(3):
        rate = theta_dot[joint]
        sign = 1.0 if rate > 0.0 else (-1.0 if rate < 0.0 else 0.0)
        dof = motor_dofs[joint]
        rhs[dof] += frictionloss[joint] * sign
        rhs[dof] -= kernels.motor_disturbance(coefficients, joint, theta[joint], rate)
    for row in range(jac.shape[0]):
        for column in range(jac.shape[1]):
            system[column, 3 + row] = jac[row, column]
    return np.linalg.solve(system, rhs)[:3]


@dataclass(frozen=True)
class RotorMotion:
    """The motion of the rotors of compliant drives that moves the arms along a reference, and the drive torque it
    takes (:meth:`CompliantDriveOracle.motion`); every field per joint, shape (3,), at the joint's scale.

    Attributes:
        deflection: Gearhead deflection L = phi - theta (rad), the backlash's half band included.
        deflection_rate: Its rate (rad/s).
        deflection_acceleration: Its acceleration (rad/s^2).
        gearhead_torque: Torque the gearhead passes to the arm (N m): the arm's joint torque tau_a.
        torque: Drive torque on the rotor (N m).
    """

    deflection: NDArray[np.float64]
    deflection_rate: NDArray[np.float64]
    deflection_acceleration: NDArray[np.float64]
    gearhead_torque: NDArray[np.float64]
    torque: NDArray[np.float64]


class CompliantDriveOracle:
    """Drive torques that move the arms of a plant with compliant drives along a reference: its exact inverse.

    The arm's joint torque tau_a(t) is :class:`InverseDynamicsOracle`'s on the arm alone
    (:func:`arm_behind_gearheads`); the gearhead passes k delta + c L_dot, L = phi - theta its deflection and delta
    the part beyond the backlash's half band b / 2, so along the reference (docs/design.md section 4)

        delta = (tau_a - eps tau_a' + eps^2 tau_a'') / k,    L = delta + sign(delta) b / 2,    eps = c / k,
        L_dot = (tau_a' - eps tau_a'') / k,    L_ddot = tau_a'' / k:

    the solution of c L_dot + k delta = tau_a without its transient (which decays as exp(-t / eps), eps = 55 us on
    the preset), truncated where the next terms are eps^3 tau_a^(3) / k in L and eps tau_a^(3) / k in L_ddot. The
    rotor then needs

        tau_m = J_m phi_ddot + b_v phi_dot + f_c sign(phi_dot) - (Stribeck and ripple at phi, phi_dot) + tau_a.

    tau_a' and tau_a'' are central differences (:data:`DERIVATIVE_STEP`) of tau_a along the reference's Taylor curve
    to its snap: the reference must be C4 for them to exist. A jerk step makes L_dot step, which takes an impulse of
    the rotor's torque (J_m times the step of tau_a' over k; with damping a pulse of that area over about eps); an
    acceleration step makes L step, which no finite torque does. Where tau_a changes sign the rotor crosses the
    backlash's band at once here (the exact inverse crosses it at L_dot = tau_a / c). The rotors' friction and
    inertia and the gearheads come from the compliant plant's model, randomized with it
    (:meth:`set_physical_parameters`).

    Args:
        config: A plant configuration with compliant drives.

    Raises:
        ValueError: if ``config``'s drives are rigid.
    """

    def __init__(self, config: PlantConfig) -> None:
        if not isinstance(config, PlantConfig):
            raise ValueError(f"config must be a PlantConfig, got {type(config).__name__}")
        self.arm = InverseDynamicsOracle(arm_behind_gearheads(config))
        """The inverse dynamics of the arm side."""
        self.plant = DeltaPlant(replace(config, payload_body=False))
        """The compliant plant inverted: its model holds the rotors' and gearheads' parameters."""
        model = self.plant.model
        self._gearheads = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, f"gearhead_{n}") for n in CHAIN_LABELS]
        self._read_drives()

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """Use the same (e.g. randomized) masses, friction and gearheads as a plant; see
        DeltaPlant.set_physical_parameters."""
        self.plant.set_physical_parameters(parameters)
        self.arm.set_physical_parameters(parameters)
        self._read_drives()

    def _read_drives(self) -> None:
        """The rotors' inertia and viscous and Coulomb friction, and the gearheads' stiffness, damping and half band,
        from the plant's model (its Stribeck and ripple: :meth:`DeltaPlant.motor_disturbance`)."""
        model, rotors = self.plant.model, self.plant.rotor_dofs
        self.rotor_inertia = model.dof_armature[rotors].copy()
        self.viscous = model.dof_damping[rotors].copy()
        self.coulomb = model.dof_frictionloss[rotors].copy()
        self.stiffness = model.tendon_stiffness[self._gearheads].copy()
        self.damping = model.tendon_damping[self._gearheads].copy()
        self.backlash = np.full(3, self.plant.config.realism.compliance.backlash)
        """The gearheads' backlash per joint (rad)."""
        self._half_band = 0.5 * self.plant.config.realism.compliance.backlash
        # MuJoCo's implicit integrators take a fixed tendon's damping into the step's matrix M + h D only where M has
        # entries: the rotor and the arm are separate trees, so D keeps c on each joint and drops the coupling -c.
        # Each joint then moves as if its inertia were h c larger (2.5e-3 kg m^2 on the preset: 2.3 % of J_m).
        implicit = model.opt.integrator in IMPLICIT_INTEGRATORS
        self.step_inertia = model.opt.timestep * self.damping if implicit else np.zeros(3)

    def motion(
        self,
        theta: NDArray,
        theta_dot: NDArray,
        theta_ddot: NDArray,
        jerk: NDArray,
        snap: NDArray,
        payload: float,
    ) -> RotorMotion:
        """The rotors' motion and drive torques that move the arms along a reference, at one instant. No input checks
        (the 1 kHz path of the bound controller).

        Args:
            theta: The arms' reference angles (rad), (3,), finite as every input.
            theta_dot: Their rates (rad/s), (3,).
            theta_ddot: Their accelerations (rad/s^2), (3,).
            jerk: Their jerks (rad/s^3), (3,).
            snap: Their snaps (rad/s^4), (3,).
            payload: Carried payload mass (kg) in [0, MAX_PAYLOAD_MASS].

        Raises:
            ValueError: for unreachable angles.
        """
        step = DERIVATIVE_STEP
        torques = []
        for s in (-step, 0.0, step):  # the reference's Taylor curve at t + s
            angle = theta + s * (theta_dot + s * (0.5 * theta_ddot + s * (jerk / 6.0 + s * snap / 24.0)))
            rate = theta_dot + s * (theta_ddot + s * (0.5 * jerk + s * snap / 6.0))
            acceleration = theta_ddot + s * (jerk + 0.5 * s * snap)
            torques.append(self.arm.torque(angle, rate, acceleration, payload) + self.step_inertia * acceleration)
        before, tau, after = torques
        tau_dot = (after - before) / (2.0 * step)
        tau_ddot = (after - 2.0 * tau + before) / step**2
        k = self.stiffness
        eps = self.damping / k
        beyond = (tau - eps * tau_dot + eps**2 * tau_ddot) / k
        deflection = beyond + np.sign(beyond) * self._half_band
        deflection_rate = (tau_dot - eps * tau_ddot) / k
        deflection_acceleration = tau_ddot / k
        rotor_angle, rotor_rate = theta + deflection, theta_dot + deflection_rate
        torque = (
            (self.rotor_inertia + self.step_inertia) * (theta_ddot + deflection_acceleration)
            + self.viscous * rotor_rate
            + self.coulomb * np.sign(rotor_rate)
            - self.plant.motor_disturbance(rotor_angle, rotor_rate)
            + tau
        )
        return RotorMotion(deflection, deflection_rate, deflection_acceleration, tau, torque)
