"""Inverse dynamics of the Delta robot: the Kuo & Huang model (MKH) and its identified forms.

docs/design.md section 3. Active arm: homogeneous rod m1; each forearm pair: m2 at the elbow and m2 at the
platform; platform m0 plus payload mp. With Mt = m0 + mp + 3 m2, I = (m1/3 + m2) l1^2 and
G_i = -(m1/2 + m2) g l1 cos th_i (theta > 0 turns an arm down, so holding torques are negative):

    Mt (xdd + g e_z) = 2 A^T lambda                      (platform, Lagrange multipliers lambda)
    tau_i = rho1 I thdd_i + rho2 G_i - 2 k_i lambda_i + fv_i thd_i + fc_i sign(thd_i)

with A, k from ``delta_env.kinematics.constraint_terms``. MKH is rho1 = rho2 = 1 without friction;
MId fits (rho1, rho2) and MId+F adds the friction (the paper's eqs. (6) and (8)).

Beyond the paper, ``forearm_rods=True`` treats each forearm pair as homogeneous thin rods of mass 2 m2
instead of two end points. Both give the same centre-of-mass motion and gravity; the rods have a third of
the rotational inertia about their centre (2 m2 l2^2 / 12 instead of 2 m2 l2^2 / 4), so the lumped model
over-counts it by 2 m2 l2^2 / 6. With u_i = x - J'_i (the forearm, |u_i| = l2) that difference adds

    tau_rods = -(m2 / 3) sum_i (d u_dot_i / d thd)^T (u_ddot_i - u_i (u_i . u_ddot_i) / l2^2),
    d u_dot_i / d thd = J - dJ'_i/dth_i e_i^T,

the virtual work of the missing angular momentum rate of each pair (J: platform Jacobian). This is what
rho1 cannot absorb: it depends on the platform's motion, not on the joint's alone; on the realistic plant
it is the largest model error along the payload regressor (the payload estimator's tare).

Every function takes a leading batch shape ``(...)``: joint vectors are ``(..., 3)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.compiled_model import MODEL_CONSTANTS, single_sample_model
from delta_env import kernels, kinematics
from delta_env.config import MAX_VISCOUS
from delta_env.geometry import (
    GRAVITY,
    NOMINAL_GEOMETRY,
    NOMINAL_MASSES,
    TORQUE_LIMIT,
    DeltaGeometry,
    DeltaMasses,
)
from delta_env.validation import require_in

MAX_RHO = 1000.0
"""Largest rho1, rho2 accepted (dimensionless): identified values lie near 1-2 (the paper's grid spans [0.5, 3]),
but rho1 = 1 + armature / arm inertia of a design with a small, light arm reaches about 40 (the design study);
beyond 1000 a file holds no Delta robot."""


@dataclass(frozen=True)
class ModelParameters:
    """Identified corrections to MKH (docs/design.md sections 3 and 7); the defaults give plain MKH.

    Attributes:
        rho1: Scale of the joint inertia I (dimensionless, in (0, MAX_RHO]): the forearms' missing inertia.
        rho2: Scale of the gravity torque G (dimensionless, in (0, MAX_RHO]): the missing potential energy.
        viscous: Viscous friction fv_i per joint (N m s/rad, in [0, MAX_VISCOUS], as the plant's).
        coulomb: Coulomb friction fc_i per joint (N m, in [0, TORQUE_LIMIT]: more and the drive could not move it).
    """

    rho1: float = 1.0
    rho2: float = 1.0
    viscous: tuple[float, float, float] = (0.0, 0.0, 0.0)
    coulomb: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        require_in("rho1", self.rho1, 0.0, MAX_RHO, low_open=True)
        require_in("rho2", self.rho2, 0.0, MAX_RHO, low_open=True)
        for name, high, unit in (("viscous", MAX_VISCOUS, "N m s/rad"), ("coulomb", TORQUE_LIMIT, "N m")):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3:
                raise ValueError(f"{name} must have one value per joint (3), got {getattr(self, name)!r}")
            for joint, value in enumerate(values, start=1):
                require_in(f"{name}[{joint}]", value, 0.0, high, unit=unit)
            object.__setattr__(self, name, values)


class DeltaDynamics:
    """Joint torques of the analytical Delta model, optionally with identified parameters.

    Args:
        geometry: Lengths of the robot (m).
        m1: Upper arm mass (kg), a homogeneous rod.
        m2: Half of one forearm pair (kg), lumped at the elbow and at the platform.
        m0: Platform mass without payload (kg).
        g: Gravitational acceleration (m/s^2), along -z.
        parameters: Identified (rho1, rho2, fv, fc); None gives plain MKH.
        forearm_rods: Forearm pairs as homogeneous rods rather than lumped end masses (the module
            docstring); False is the paper's model.
    """

    def __init__(
        self,
        geometry: DeltaGeometry,
        m1: float,
        m2: float,
        m0: float,
        g: float = GRAVITY,
        parameters: ModelParameters | None = None,
        *,
        forearm_rods: bool = False,
    ) -> None:
        self.geometry = geometry
        self.masses = DeltaMasses(m1=m1, m2=m2, m0=m0)  # validates the masses
        require_in("g", g, 0.0, unit="m/s^2")
        self.g = float(g)
        self.parameters = ModelParameters() if parameters is None else parameters
        l1 = geometry.l1
        self.inertia = (m1 / 3.0 + m2) * l1**2
        """I (kg m^2), the same for every joint."""
        self.platform_mass = m0 + 3.0 * m2
        """Mt without payload (kg)."""
        self.gravity_amplitude = -(m1 / 2.0 + m2) * self.g * l1
        """G_i / cos th_i (N m), unscaled: G_i = gravity_amplitude cos th_i."""
        self._scaled_inertia = self.parameters.rho1 * self.inertia
        self._scaled_gravity = self.parameters.rho2 * self.gravity_amplitude
        self._viscous = np.array(self.parameters.viscous)
        self._coulomb = np.array(self.parameters.coulomb)
        self._has_friction = bool(np.any(self._viscous) or np.any(self._coulomb))
        self._gravity_vector = np.array([0.0, 0.0, self.g])
        self.forearm_rods = bool(forearm_rods)
        self._rod_coefficient = -m2 / 3.0 if self.forearm_rods else 0.0
        """-(2 m2) / 6 (kg): the inertia the lumped pair over-counts, per l2^2."""
        self._model_constants = np.array(
            [
                (
                    geometry.l1,
                    geometry.r,
                    geometry.l2,
                    self.g,
                    self._scaled_inertia,
                    self._scaled_gravity,
                    self.platform_mass,
                    self.parameters.viscous,
                    self.parameters.coulomb,
                    self.forearm_rods,
                    self._rod_coefficient,
                )
            ],
            dtype=MODEL_CONSTANTS,
        ).view(np.uint8)

    @classmethod
    def nominal(cls, parameters: ModelParameters | None = None, *, forearm_rods: bool = False) -> DeltaDynamics:
        """The model with the datasheet geometry and masses (docs/design.md section 4)."""
        return cls.of_robot(NOMINAL_GEOMETRY, NOMINAL_MASSES, parameters, forearm_rods=forearm_rods)

    @classmethod
    def of_robot(
        cls,
        geometry: DeltaGeometry,
        masses: DeltaMasses,
        parameters: ModelParameters | None = None,
        *,
        forearm_rods: bool = False,
    ) -> DeltaDynamics:
        """The model of a robot with these lengths (m) and datasheet masses (kg)."""
        return cls(geometry, m1=masses.m1, m2=masses.m2, m0=masses.m0, parameters=parameters, forearm_rods=forearm_rods)

    def with_parameters(self, parameters: ModelParameters | None) -> DeltaDynamics:
        """The same analytical model (geometry, masses, forearms) with other identified parameters."""
        m = self.masses
        return DeltaDynamics(
            self.geometry, m1=m.m1, m2=m.m2, m0=m.m0, g=self.g, parameters=parameters, forearm_rods=self.forearm_rods
        )

    def __repr__(self) -> str:
        m = self.masses
        return (
            f"DeltaDynamics({self.geometry}, m1={m.m1}, m2={m.m2}, m0={m.m0}, g={self.g}, "
            f"parameters={self.parameters}, forearm_rods={self.forearm_rods})"
        )

    def inverse_dynamics(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """Motor torques (N m), ``(..., 3)``, in the Lagrange-multiplier form.

        tau = rho1 I thdd + rho2 G - 2 K lambda + fv thd + fc sign(thd); sign(0) = 0.

        Args:
            theta: Motor angles (rad), ``(..., 3)``.
            theta_dot: Motor rates (rad/s), ``(..., 3)``.
            theta_ddot: Motor accelerations (rad/s^2), ``(..., 3)``.
            payload: Payload mass mp (kg, >= 0), a scalar or broadcastable to the batch ``(...)``.

        Raises:
            ValueError: on a negative or non-finite payload, bad shapes, non-finite or unreachable
                joint states.
        """
        total_mass = self._total_mass(payload)
        theta, theta_dot, theta_ddot = _as_floats(theta, theta_dot, theta_ddot)
        solution, k, rods = self._multiplier_basis(theta, theta_dot, theta_ddot)
        # -2 K lambda with lambda = Mt w / 2
        return self._joint_space_torque(theta, theta_dot, theta_ddot) - total_mass * k * solution + rods

    def inverse_dynamics_virtual_work(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """The same torques (N m) by virtual work.

        tau = rho1 I thdd + rho2 G + J^T Mt (xdd + g e_z) + fv thd + fc sign(thd): a check of
        :meth:`inverse_dynamics` through the Jacobian J = -A^{-1} K instead of the multipliers;
        slower (forward kinematics twice). Arguments as in :meth:`inverse_dynamics`.
        """
        total_mass = self._total_mass(payload)
        theta, theta_dot, theta_ddot = _as_floats(theta, theta_dot, theta_ddot)
        xyz, _, xyz_ddot = kinematics.joint_to_cartesian(self.geometry, theta, theta_dot, theta_ddot)
        jac = kinematics.jacobian(self.geometry, theta)
        platform_force = total_mass * (xyz_ddot + self._gravity_vector)  # N
        torque = self._joint_space_torque(theta, theta_dot, theta_ddot) + np.einsum(
            "...ji,...j->...i", jac, platform_force
        )
        if self.forearm_rods:
            forearm = xyz[..., None, :] - kinematics.elbow_points(self.geometry, theta)
            elbow_rate, across = self._forearm_acceleration_across(forearm, theta, theta_dot, theta_ddot, xyz_ddot)
            torque = torque + self._rod_coefficient * (
                np.einsum("...ji,...j->...i", jac, across.sum(axis=-2)) - np.sum(elbow_rate * across, axis=-1)
            )
        return torque

    def lagrange_multipliers(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """Lagrange multipliers lambda = 1/2 A^{-T} Mt (xdd + g e_z) (N/m), ``(..., 3)``.

        The forearm pair of chain i pushes the platform with the force 2 lambda_i a_i (N), a_i = x - J'_i.
        Arguments as in :meth:`inverse_dynamics`.
        """
        total_mass = self._total_mass(payload)
        solution, _, _ = self._multiplier_basis(*_as_floats(theta, theta_dot, theta_ddot))
        return 0.5 * total_mass * solution

    def payload_regressor(self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike) -> NDArray[np.float64]:
        """phi = J^T (xdd + g e_z) (N m/kg), ``(..., 3)``, so that tau(mp) = tau(0) + mp phi.

        This is the paper's eq. (10) without dividing by K, which blows up near serial singularities.
        """
        solution, k, _ = self._multiplier_basis(*_as_floats(theta, theta_dot, theta_ddot))
        # J^T = -K A^{-T}
        return -k * solution

    def identification_regressor(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Regressor of the model, linear in the identified parameters (docs/design.md section 3).

        tau_i = rows[..., i, :] . (rho1, rho2, fv_i, fc_i) + known[..., i]

        Returns:
            rows: ``(..., 3, 4)``, per joint [I thdd_i (N m), G_i (N m), thd_i (rad/s), sign thd_i].
            known: -2 k_i lambda_i (N m), ``(..., 3)``, the platform's share, plus the rod correction with
                ``forearm_rods``: what is not scaled.
        """
        total_mass = self._total_mass(payload)
        theta, theta_dot, theta_ddot = _as_floats(theta, theta_dot, theta_ddot)
        solution, k, rods = self._multiplier_basis(theta, theta_dot, theta_ddot)
        known = -total_mass * k * solution + rods
        shape = known.shape
        rows = np.stack(
            (
                np.broadcast_to(self.inertia * theta_ddot, shape),
                np.broadcast_to(self.gravity_amplitude * np.cos(theta), shape),
                np.broadcast_to(theta_dot, shape),
                np.broadcast_to(np.sign(theta_dot), shape),
            ),
            axis=-1,
        )
        return rows, known

    def torque_and_payload_regressor(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One joint state's torque without payload and payload regressor, for the 1 kHz controllers.

        The same numbers as ``inverse_dynamics(..., payload=0.0)`` and :meth:`payload_regressor`
        (identified rho1, rho2 and friction included), so that tau(mp) = tau0 + mp phi, but for a single
        sample in scalar float math: forward kinematics, A, k, xdd and A^{-T} once, about 20x cheaper
        than the batched NumPy path on one sample.

        Args:
            theta: Motor angles (rad), ``(3,)``.
            theta_dot: Motor rates (rad/s), ``(3,)``.
            theta_ddot: Motor accelerations (rad/s^2), ``(3,)``.

        Returns:
            tau0: Torques at mp = 0 (N m), ``(3,)``.
            phi: J^T (xdd + g e_z) (N m/kg), ``(3,)``.

        Raises:
            ValueError: on non-finite states, collinear elbows, unreachable angles or det A = 0.
        """
        terms = self._single_sample_terms(theta, theta_dot, theta_ddot)
        return terms[0], terms[1]

    def torque_regressor_and_force_map(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`torque_and_payload_regressor` of one joint state, and the map of a joint torque to the platform
        force that would cause it: F = J^-T tau = -A^T K^-1 tau (N per N m, ``(3, 3)``), for an observer of external
        forces. Raises as :meth:`torque_and_payload_regressor`."""
        terms = self._single_sample_terms(theta, theta_dot, theta_ddot)
        # column i of A^T is a_i: F = -sum_i a_i tau_i / k_i
        return terms[0], terms[1], -terms[2:5].T / terms[5]

    @property
    def model_constants(self) -> NDArray[np.uint8]:
        """The model as :func:`single_sample_model` takes it: the bytes of its :data:`MODEL_CONSTANTS` record
        (``.view(MODEL_CONSTANTS)`` reads the fields), for compiled callers that evaluate the model themselves
        (read-only by convention)."""
        return self._model_constants

    def _single_sample_terms(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike
    ) -> NDArray[np.float64]:
        """The compiled single-sample model's rows (:func:`single_sample_model`), or ValueError naming the state."""
        t1, t2, t3 = _three_floats(theta)
        w1, w2, w3 = _three_floats(theta_dot)
        u1, u2, u3 = _three_floats(theta_ddot)
        status, terms = single_sample_model(self._model_constants, t1, t2, t3, w1, w2, w3, u1, u2, u3)
        if status != kernels.VALID:
            raise ValueError(
                f"{kernels.INVALID_STATE[status]}: theta={theta!r}, theta_dot={theta_dot!r}, theta_ddot={theta_ddot!r}"
            )
        return terms

    def _total_mass(self, payload: ArrayLike) -> float | NDArray[np.float64]:
        """Mt = m0 + mp + 3 m2 (kg): a float, or an array with a trailing axis for the joints."""
        if isinstance(payload, (float, int)):  # the 1 kHz controller's path: no array
            if not (math.isfinite(payload) and payload >= 0.0):
                raise ValueError(f"payload must be a finite mass >= 0 kg, got {payload!r}")
            return self.platform_mass + payload
        payload = np.asarray(payload, dtype=float)
        if not np.all(np.isfinite(payload) & (payload >= 0.0)):
            raise ValueError(f"payload must be finite masses >= 0 kg, got {payload}")
        return self.platform_mass + payload[..., None]

    def _multiplier_basis(
        self, theta: NDArray[np.float64], theta_dot: NDArray[np.float64], theta_ddot: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | float]:
        """w = A^{-T} (xdd + g e_z) (1/s^2), k (m^2/rad) and tau_rods (N m; 0 for lumped forearms).

        lambda = Mt w / 2 and phi = -k w. One forward kinematics and one solve with A^T serve both the
        platform and, with rod forearms, the pairs' angular momentum: J^T s = -K A^{-T} s.
        """
        xyz, _, xyz_ddot = kinematics.joint_to_cartesian(self.geometry, theta, theta_dot, theta_ddot)
        a, k = kinematics.constraint_terms(self.geometry, xyz, theta)
        a_transposed = np.swapaxes(a, -1, -2)
        platform = xyz_ddot + self._gravity_vector
        if not self.forearm_rods:
            return np.linalg.solve(a_transposed, platform[..., None])[..., 0], k, 0.0
        # The rows of A are the forearms u_i = x - J'_i.
        elbow_rate, across = self._forearm_acceleration_across(a, theta, theta_dot, theta_ddot, xyz_ddot)
        solution = np.linalg.solve(a_transposed, np.stack((platform, across.sum(axis=-2)), axis=-1))
        rods = self._rod_coefficient * (-k * solution[..., 1] - np.sum(elbow_rate * across, axis=-1))
        return solution[..., 0], k, rods

    def _forearm_acceleration_across(
        self,
        forearm: NDArray[np.float64],
        theta: NDArray[np.float64],
        theta_dot: NDArray[np.float64],
        theta_ddot: NDArray[np.float64],
        xyz_ddot: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """dJ'_i/dth_i (m/rad) and u_ddot_i across the forearm u_i (m/s^2), each ``(..., 3 chains, 3)``."""
        elbow_rate, elbow_curvature = kinematics.elbow_derivatives(self.geometry, theta)
        forearm_ddot = (
            xyz_ddot[..., None, :] - elbow_curvature * theta_dot[..., None] ** 2 - elbow_rate * theta_ddot[..., None]
        )
        along = np.sum(forearm * forearm_ddot, axis=-1) / self.geometry.l2**2
        return elbow_rate, forearm_ddot - forearm * along[..., None]

    def _joint_space_torque(
        self, theta: NDArray[np.float64], theta_dot: NDArray[np.float64], theta_ddot: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """rho1 I thdd + rho2 G + fv thd + fc sign(thd) (N m): everything but the platform's share."""
        torque = self._scaled_inertia * theta_ddot + self._scaled_gravity * np.cos(theta)
        if self._has_friction:
            torque = torque + self._viscous * theta_dot + self._coulomb * np.sign(theta_dot)
        return torque


def _three_floats(value: ArrayLike) -> list[float]:
    """A joint vector (3,) as Python floats; ``tolist`` is the cheapest exit from NumPy."""
    values = value.tolist() if isinstance(value, np.ndarray) else [float(v) for v in value]
    if len(values) != 3:
        raise ValueError(f"expected a joint vector of 3 values, got {value!r}")
    return values


def _as_floats(*arrays: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """Float arrays without copies; shapes and finiteness are checked by the kinematics."""
    return tuple(np.asarray(array, dtype=float) for array in arrays)
