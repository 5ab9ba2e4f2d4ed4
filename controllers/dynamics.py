# Over 500 lines: the model in its batched form and its compiled single-sample form for the 1 kHz loop.
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

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels, kinematics
from delta_env.config import MAX_VISCOUS
from delta_env.geometry import (
    CHAIN_COS,
    CHAIN_SIN,
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
        )

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
    def model_constants(self) -> NDArray:
        """The model as :func:`single_sample_model` takes it: a one-element :data:`MODEL_CONSTANTS` array, for
        compiled callers that evaluate the model themselves (read-only by convention)."""
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


# The single-sample model, compiled: the 1 kHz controllers evaluate it twice per step (at the reference and
# at the estimated joint state), and in CPython one evaluation alone costs about half a physics step.
MODEL_CONSTANTS = np.dtype(
    [
        ("l1", np.float64),
        ("r", np.float64),
        ("l2", np.float64),
        ("g", np.float64),
        ("inertia", np.float64),
        ("gravity", np.float64),
        ("platform_mass", np.float64),
        ("viscous", np.float64, 3),
        ("coulomb", np.float64, 3),
        ("forearm_rods", np.bool_),
        ("rod_coefficient", np.float64),
    ]
)
"""The constants of :func:`single_sample_model` (:attr:`DeltaDynamics.model_constants`): lengths l1, r, l2 (m), g
(m/s^2), the scaled rho1 I (kg m^2) and rho2 G amplitude (N m), Mt without payload (kg), fv_i (N m s/rad), fc_i
(N m), whether the forearms are rods and -m2 / 3 (kg) if so."""


@numba.njit(cache=True)
def single_sample_model(
    constants: NDArray,
    t1: float,
    t2: float,
    t3: float,
    w1: float,
    w2: float,
    w3: float,
    u1: float,
    u2: float,
    u3: float,
) -> tuple[int, NDArray[np.float64]]:
    """tau0 and phi of one joint state, rows 0 and 1 of the returned ``(6, 3)``, then the rows a_1..a_3 of A (m) and
    k (m); a status code first (:data:`delta_env.kernels.INVALID_STATE`).

    Written out in scalars (docs/design.md sections 2 and 3): forward kinematics, A, k, xdd and A^{-T} once.
    ``constants`` is a one-element :data:`MODEL_CONSTANTS` array (:attr:`DeltaDynamics.model_constants`).
    """
    terms = np.zeros((6, 3))
    if not math.isfinite(t1 + t2 + t3 + w1 + w2 + w3 + u1 + u2 + u3):
        return kernels.NOT_FINITE, terms
    model = constants[0]
    l1, r, l2 = model.l1, model.r, model.l2
    ca1, ca2, ca3 = CHAIN_COS
    sa1, sa2, sa3 = CHAIN_SIN
    c1, c2, c3 = math.cos(t1), math.cos(t2), math.cos(t3)
    s1, s2, s3 = math.sin(t1), math.sin(t2), math.sin(t3)
    # Elbows J'_i (docs/design.md section 2) and forward kinematics.
    p1x, p1y, p1z = kernels.elbow(t1, 0, r, l1)
    p2x, p2y, p2z = kernels.elbow(t2, 1, r, l1)
    p3x, p3y, p3z = kernels.elbow(t3, 2, r, l1)
    status, x, y, z = kernels.lower_intersection(p1x, p1y, p1z, p2x, p2y, p2z, p3x, p3y, p3z, l2)
    if status != kernels.VALID:
        return status, terms

    # Rows a_i = x - J'_i of A; k_i = -a_i . dJ'_i/dth_i with dJ'_i/dth_i = -l1 (s ca, s sa, c).
    a1x, a1y, a1z = x - p1x, y - p1y, z - p1z
    a2x, a2y, a2z = x - p2x, y - p2y, z - p2z
    a3x, a3y, a3z = x - p3x, y - p3y, z - p3z
    k1 = l1 * (s1 * (a1x * ca1 + a1y * sa1) + c1 * a1z)
    k2 = l1 * (s2 * (a2x * ca2 + a2y * sa2) + c2 * a2z)
    k3 = l1 * (s3 * (a3x * ca3 + a3y * sa3) + c3 * a3z)
    # A^{-1} = [g1 g2 g3] / det A by columns, g1 = a2 x a3, g2 = a3 x a1, g3 = a1 x a2.
    g1x, g1y, g1z = a2y * a3z - a2z * a3y, a2z * a3x - a2x * a3z, a2x * a3y - a2y * a3x
    g2x, g2y, g2z = a3y * a1z - a3z * a1y, a3z * a1x - a3x * a1z, a3x * a1y - a3y * a1x
    g3x, g3y, g3z = a1y * a2z - a1z * a2y, a1z * a2x - a1x * a2z, a1x * a2y - a1y * a2x
    det = a1x * g1x + a1y * g1y + a1z * g1z
    if det == 0.0 or not math.isfinite(det):
        return kernels.SINGULAR, terms
    inv_det = 1.0 / det

    # A xd = -K thd.
    b1, b2, b3 = -k1 * w1 * inv_det, -k2 * w2 * inv_det, -k3 * w3 * inv_det
    vx, vy, vz = b1 * g1x + b2 * g2x + b3 * g3x, b1 * g1y + b2 * g2y + b3 * g3y, b1 * g1z + b2 * g2z + b3 * g3z
    # A xdd = -|v_i|^2 + a_i . J'_thth,i thd_i^2 - k_i thdd_i, v_i = xd - J'_th,i thd_i,
    # J'_th,i = -l1 (s ca, s sa, c) and J'_thth,i = l1 (-c ca, -c sa, s).
    q1x, q1y, q1z = vx + l1 * s1 * ca1 * w1, vy + l1 * s1 * sa1 * w1, vz + l1 * c1 * w1
    q2x, q2y, q2z = vx + l1 * s2 * ca2 * w2, vy + l1 * s2 * sa2 * w2, vz + l1 * c2 * w2
    q3x, q3y, q3z = vx + l1 * s3 * ca3 * w3, vy + l1 * s3 * sa3 * w3, vz + l1 * c3 * w3
    r1 = (l1 * (s1 * a1z - c1 * (a1x * ca1 + a1y * sa1)) * w1 * w1 - k1 * u1) - (q1x * q1x + q1y * q1y + q1z * q1z)
    r2 = (l1 * (s2 * a2z - c2 * (a2x * ca2 + a2y * sa2)) * w2 * w2 - k2 * u2) - (q2x * q2x + q2y * q2y + q2z * q2z)
    r3 = (l1 * (s3 * a3z - c3 * (a3x * ca3 + a3y * sa3)) * w3 * w3 - k3 * u3) - (q3x * q3x + q3y * q3y + q3z * q3z)
    r1, r2, r3 = r1 * inv_det, r2 * inv_det, r3 * inv_det
    fx = r1 * g1x + r2 * g2x + r3 * g3x
    fy = r1 * g1y + r2 * g2y + r3 * g3y
    xdd_z = r1 * g1z + r2 * g2z + r3 * g3z
    fz = xdd_z + model.g  # xdd + g e_z
    # phi = J^T (xdd + g e_z) = -K A^{-T} (xdd + g e_z); row i of A^{-T} is g_i / det A.
    phi1 = -k1 * inv_det * (g1x * fx + g1y * fy + g1z * fz)
    phi2 = -k2 * inv_det * (g2x * fx + g2y * fy + g2z * fz)
    phi3 = -k3 * inv_det * (g3x * fx + g3y * fy + g3z * fz)

    inertia, gravity, mass = model.inertia, model.gravity, model.platform_mass
    fv1, fv2, fv3 = model.viscous[0], model.viscous[1], model.viscous[2]
    fc1, fc2, fc3 = model.coulomb[0], model.coulomb[1], model.coulomb[2]
    # sign(0) = 0, as np.sign in inverse_dynamics.
    tau1 = inertia * u1 + gravity * c1 + fv1 * w1 + fc1 * ((w1 > 0.0) - (w1 < 0.0)) + mass * phi1
    tau2 = inertia * u2 + gravity * c2 + fv2 * w2 + fc2 * ((w2 > 0.0) - (w2 < 0.0)) + mass * phi2
    tau3 = inertia * u3 + gravity * c3 + fv3 * w3 + fc3 * ((w3 > 0.0) - (w3 < 0.0)) + mass * phi3

    if model.forearm_rods:
        # u_ddot_i = xdd - J'_thth,i thd_i^2 - J'_th,i thdd_i, its part across the rod, then the virtual work
        # through d u_dot_i / d thd = J - J'_th,i e_i^T (module docstring). J'_thth = -l1 (c ca, c sa, -s)
        # and J'_th = -l1 (s ca, s sa, c).
        inv_l2_sq = 1.0 / (l2 * l2)
        ux1, uy1, uz1, own1 = _across_forearm(fx, fy, xdd_z, a1x, a1y, a1z, c1, s1, ca1, sa1, w1, u1, l1, inv_l2_sq)
        ux2, uy2, uz2, own2 = _across_forearm(fx, fy, xdd_z, a2x, a2y, a2z, c2, s2, ca2, sa2, w2, u2, l1, inv_l2_sq)
        ux3, uy3, uz3, own3 = _across_forearm(fx, fy, xdd_z, a3x, a3y, a3z, c3, s3, ca3, sa3, w3, u3, l1, inv_l2_sq)
        sx, sy, sz = 0.0 + ux1 + ux2 + ux3, 0.0 + uy1 + uy2 + uy3, 0.0 + uz1 + uz2 + uz3
        rod = model.rod_coefficient
        # J^T s = -K A^{-T} s, as phi.
        tau1 += rod * (-k1 * inv_det * (g1x * sx + g1y * sy + g1z * sz) - own1)
        tau2 += rod * (-k2 * inv_det * (g2x * sx + g2y * sy + g2z * sz) - own2)
        tau3 += rod * (-k3 * inv_det * (g3x * sx + g3y * sy + g3z * sz) - own3)
    terms[0, 0], terms[0, 1], terms[0, 2] = tau1, tau2, tau3
    terms[1, 0], terms[1, 1], terms[1, 2] = phi1, phi2, phi3
    terms[2, 0], terms[2, 1], terms[2, 2] = a1x, a1y, a1z
    terms[3, 0], terms[3, 1], terms[3, 2] = a2x, a2y, a2z
    terms[4, 0], terms[4, 1], terms[4, 2] = a3x, a3y, a3z
    terms[5, 0], terms[5, 1], terms[5, 2] = k1, k2, k3
    return kernels.VALID, terms


@numba.njit(cache=True, inline="always")
def _across_forearm(
    ax_: float,
    ay_: float,
    az_: float,
    px: float,
    py: float,
    pz: float,
    c: float,
    s: float,
    ca: float,
    sa: float,
    w: float,
    u: float,
    l1: float,
    inv_l2_sq: float,
) -> tuple[float, float, float, float]:
    """u_ddot_i across forearm i (m/s^2) and J'_th,i . u_ddot_perp_i, for one chain of the rod correction."""
    cx, cy, cz = c * ca, c * sa, -s
    dx, dy, dz = s * ca, s * sa, c
    ww, uu = l1 * w * w, l1 * u
    ux, uy, uz = ax_ + ww * cx + uu * dx, ay_ + ww * cy + uu * dy, az_ + ww * cz + uu * dz
    along = (px * ux + py * uy + pz * uz) * inv_l2_sq
    ux, uy, uz = ux - along * px, uy - along * py, uz - along * pz
    return ux, uy, uz, -l1 * (dx * ux + dy * uy + dz * uz)
