"""Inverse dynamics of the Delta robot: the Kuo & Huang model (MKH) and its identified forms.

DESIGN.md section 3. Active arm: homogeneous rod m1; each forearm pair: m2 at the elbow and m2 at the
platform; platform m0 plus payload mp. With Mt = m0 + mp + 3 m2, I = (m1/3 + m2) l1^2 and
G_i = -(m1/2 + m2) g l1 cos th_i (theta > 0 turns an arm down, so holding torques are negative):

    Mt (xdd + g e_z) = 2 A^T lambda                      (platform, Lagrange multipliers lambda)
    tau_i = rho1 I thdd_i + rho2 G_i - 2 k_i lambda_i + fv_i thd_i + fc_i sign(thd_i)

with A, k from ``delta_env.kinematics.constraint_terms``. MKH is rho1 = rho2 = 1 without friction;
MId fits (rho1, rho2) and MId+F adds the friction (the paper's eqs. (6) and (8)).

Every function takes a leading batch shape ``(...)``: joint vectors are ``(..., 3)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.geometry import GRAVITY, NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses


def _require_finite(name: str, value: float, *, minimum: float, strict: bool) -> None:
    ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        relation = ">" if strict else ">="
        raise ValueError(f"{name} must be a finite number {relation} {minimum}, got {value!r}")


@dataclass(frozen=True)
class ModelParameters:
    """Identified corrections to MKH (DESIGN.md sections 3 and 7); the defaults give plain MKH.

    Attributes:
        rho1: Scale of the joint inertia I (dimensionless, > 0): the forearms' missing inertia.
        rho2: Scale of the gravity torque G (dimensionless, > 0): the missing potential energy.
        viscous: Viscous friction fv_i per joint (N m s/rad, >= 0).
        coulomb: Coulomb friction fc_i per joint (N m, >= 0).
    """

    rho1: float = 1.0
    rho2: float = 1.0
    viscous: tuple[float, float, float] = (0.0, 0.0, 0.0)
    coulomb: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        _require_finite("rho1", self.rho1, minimum=0.0, strict=True)
        _require_finite("rho2", self.rho2, minimum=0.0, strict=True)
        for name in ("viscous", "coulomb"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3:
                raise ValueError(f"{name} must have one value per joint (3), got {getattr(self, name)!r}")
            for joint, value in enumerate(values, start=1):
                _require_finite(f"{name}[{joint}]", value, minimum=0.0, strict=False)
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
    """

    def __init__(
        self,
        geometry: DeltaGeometry,
        m1: float,
        m2: float,
        m0: float,
        g: float = GRAVITY,
        parameters: ModelParameters | None = None,
    ) -> None:
        self.geometry = geometry
        self.masses = DeltaMasses(m1=m1, m2=m2, m0=m0)  # validates the masses
        _require_finite("g", g, minimum=0.0, strict=False)
        self.g = float(g)
        self.parameters = ModelParameters() if parameters is None else parameters
        l1 = geometry.l1
        self.inertia = (m1 / 3.0 + m2) * l1**2
        """I (kg m^2), the same for every joint."""
        self.platform_mass = m0 + 3.0 * m2
        """Mt without payload (kg)."""
        self._gravity_amplitude = -(m1 / 2.0 + m2) * self.g * l1  # G_i = amplitude * cos th_i, N m
        self._scaled_inertia = self.parameters.rho1 * self.inertia
        self._scaled_gravity = self.parameters.rho2 * self._gravity_amplitude
        self._viscous = np.array(self.parameters.viscous)
        self._coulomb = np.array(self.parameters.coulomb)
        self._has_friction = bool(np.any(self._viscous) or np.any(self._coulomb))
        self._gravity_vector = np.array([0.0, 0.0, self.g])

    @classmethod
    def nominal(cls, parameters: ModelParameters | None = None) -> DeltaDynamics:
        """The model with the datasheet geometry and masses (DESIGN.md section 4)."""
        m = NOMINAL_MASSES
        return cls(NOMINAL_GEOMETRY, m1=m.m1, m2=m.m2, m0=m.m0, parameters=parameters)

    def __repr__(self) -> str:
        m = self.masses
        return (
            f"DeltaDynamics({self.geometry}, m1={m.m1}, m2={m.m2}, m0={m.m0}, g={self.g}, "
            f"parameters={self.parameters})"
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
        solution, k = self._multiplier_basis(theta, theta_dot, theta_ddot)
        # -2 K lambda with lambda = Mt w / 2
        return self._joint_space_torque(theta, theta_dot, theta_ddot) - total_mass * k * solution

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
        _, _, xyz_ddot = kinematics.joint_to_cartesian(self.geometry, theta, theta_dot, theta_ddot)
        jac = kinematics.jacobian(self.geometry, theta)
        platform_force = total_mass * (xyz_ddot + self._gravity_vector)  # N
        return self._joint_space_torque(theta, theta_dot, theta_ddot) + np.einsum(
            "...ji,...j->...i", jac, platform_force
        )

    def lagrange_multipliers(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> NDArray[np.float64]:
        """Lagrange multipliers lambda = 1/2 A^{-T} Mt (xdd + g e_z) (N/m), ``(..., 3)``.

        The forearm pair of chain i pushes the platform with the force 2 lambda_i a_i (N), a_i = x - J'_i.
        Arguments as in :meth:`inverse_dynamics`.
        """
        total_mass = self._total_mass(payload)
        solution, _ = self._multiplier_basis(*_as_floats(theta, theta_dot, theta_ddot))
        return 0.5 * total_mass * solution

    def payload_regressor(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike
    ) -> NDArray[np.float64]:
        """phi = J^T (xdd + g e_z) (N m/kg), ``(..., 3)``, so that tau(mp) = tau(0) + mp phi.

        This is the paper's eq. (10) without dividing by K, which blows up near serial singularities.
        """
        solution, k = self._multiplier_basis(*_as_floats(theta, theta_dot, theta_ddot))
        # J^T = -K A^{-T}
        return -k * solution

    def identification_regressor(
        self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike, payload: ArrayLike = 0.0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Regressor of the model, linear in the identified parameters (DESIGN.md section 3).

        tau_i = rows[..., i, :] . (rho1, rho2, fv_i, fc_i) + known[..., i]

        Returns:
            rows: ``(..., 3, 4)``, per joint [I thdd_i (N m), G_i (N m), thd_i (rad/s), sign thd_i].
            known: -2 k_i lambda_i (N m), ``(..., 3)``, the platform's share, which is not scaled.
        """
        total_mass = self._total_mass(payload)
        theta, theta_dot, theta_ddot = _as_floats(theta, theta_dot, theta_ddot)
        solution, k = self._multiplier_basis(theta, theta_dot, theta_ddot)
        known = -total_mass * k * solution
        shape = known.shape
        rows = np.stack(
            (
                np.broadcast_to(self.inertia * theta_ddot, shape),
                np.broadcast_to(self._gravity_amplitude * np.cos(theta), shape),
                np.broadcast_to(theta_dot, shape),
                np.broadcast_to(np.sign(theta_dot), shape),
            ),
            axis=-1,
        )
        return rows, known

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
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """w = A^{-T} (xdd + g e_z) (1/s^2) and k (m^2/rad): lambda = Mt w / 2 and phi = -k w."""
        # One forward kinematics; constraint_terms only re-evaluates the elbows.
        xyz, _, xyz_ddot = kinematics.joint_to_cartesian(self.geometry, theta, theta_dot, theta_ddot)
        a, k = kinematics.constraint_terms(self.geometry, xyz, theta)
        rhs = (xyz_ddot + self._gravity_vector)[..., None]
        return np.linalg.solve(np.swapaxes(a, -1, -2), rhs)[..., 0], k

    def _joint_space_torque(
        self, theta: NDArray[np.float64], theta_dot: NDArray[np.float64], theta_ddot: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """rho1 I thdd + rho2 G + fv thd + fc sign(thd) (N m): everything but the platform's share."""
        torque = self._scaled_inertia * theta_ddot + self._scaled_gravity * np.cos(theta)
        if self._has_friction:
            torque = torque + self._viscous * theta_dot + self._coulomb * np.sign(theta_dot)
        return torque


def _as_floats(*arrays: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """Float arrays without copies; shapes and finiteness are checked by the kinematics."""
    return tuple(np.asarray(array, dtype=float) for array in arrays)
