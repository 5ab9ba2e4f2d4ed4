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

On a plant with compliant drives (``PlantRealism.compliance``) the oracle inverts the same plant with rigid drives:
the rotor's inertia added to the arm's, the gearhead infinitely stiff. That is the torque at the joints of the
motion without the gearhead's deflection, not the exact torque of the compliant plant (which would need the
deflection's own dynamics, docs/design.md section 4); it is no bound there.

The payload is a point mass added to the platform's CoM. That is exact for the motor torques wherever the
payload is carried rigidly by a platform that only translates (a moment on the platform does no virtual
work), so on the ideal variant the analytical MKH model with the same payload matches the oracle to
round-off, and on the realistic one a payload hanging under the suction cup needs the same torques.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels
from delta_env.config import MAX_PAYLOAD_MASS, PhysicalParameters, PlantConfig
from delta_env.plant import DeltaPlant
from delta_env.robot import forearm_home_tilt


def rigid_drives(config: PlantConfig) -> PlantConfig:
    """``config`` with rigid drives: a compliant drive's rotor inertia added to the arm joint's ``armature`` and its
    gearhead dropped (``config`` itself if its drives are rigid)."""
    compliance = config.realism.compliance
    if compliance is None:
        return config
    armature = config.realism.armature + compliance.rotor_inertia
    return replace(config, realism=replace(config.realism, armature=armature, compliance=None))


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
