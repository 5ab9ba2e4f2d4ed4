"""The analytical model's two-mass extension: compliant drives as the controller knows them (docs/design.md
section 4, "The two-mass model").

Per joint a rotor of reflected inertia J_m (motor side, angle phi_i at the joint's scale) drives the arm (angle
theta_i) through the gearhead's spring k_i and damper c_i. Linearized about a pose at rest, with the arm side's
joint-space inertia M(theta, m_p) of the rigid model, the coordinates q = (phi, theta) obey

    [J_m 0; 0 M] q_ddot + [C_m + C, -C; -C, C] q_dot + [K, -K; -K, K] q = [tau; 0],

K = diag(k), C = diag(c), C_m = diag(f_v) (the model's viscous friction, which acts on the rotor). The modes are the
roots s of det(M_q s^2 + C_q s + K_q) = 0: three at s = 0 (the arm and the rotors turning together, against
nothing) and three pairs s = -zeta omega +- i omega sqrt(1 - zeta^2), the drives' modes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from controllers.dynamics import DeltaDynamics
from delta_env.config import MAX_BACKLASH, MAX_STIFFNESS, MAX_VISCOUS, GearheadCompliance
from delta_env.validation import require_in

MAX_ROTOR_INERTIA = 10.0
"""Largest reflected rotor inertia accepted (kg m^2), as the plant's."""

SMALLEST_BACKLASH = 3e-5
"""Smallest backlash (rad) the controllers act on, 0.1 arcmin: a tenth of the reduced-backlash class of precision
planetary gearheads (1 arcmin), five steps of a 20-bit load encoder; the identification's estimate on a drive
without backlash is a few microradians (docs/measurements.md)."""


def _three(name: str, values: ArrayLike, low: float, high: float, unit: str, *, low_open: bool) -> tuple:
    """``values`` as three floats, each checked against [low, high] (or (low, high])."""
    floats = tuple(float(v) for v in np.broadcast_to(np.asarray(values, dtype=float), (3,)))
    for joint, value in enumerate(floats, start=1):
        require_in(f"{name}[{joint}]", value, low, high, unit=unit, low_open=low_open)
    return floats


@dataclass(frozen=True)
class DriveCompliance:
    """The drives' compliance as the controller knows it (nominal from a data sheet, or identified), at the joint.

    Attributes:
        rotor_inertia: Reflected rotor inertia J_m per joint (kg m^2), each in (0, 10].
        stiffness: Gearhead torsional stiffness k per joint (N m/rad), each in (0, 1e8].
        damping: Gearhead torsional damping c per joint (N m s/rad), each in [0, 1000].
        backlash: The gearhead's lost motion b per joint (rad), each in [0, 0.01]: the spring carries nothing while
            the twist phi - theta is within b / 2 of zero. Below :data:`SMALLEST_BACKLASH` the controllers treat it
            as none (:attr:`resolved_backlash`).
    """

    rotor_inertia: tuple[float, float, float]
    stiffness: tuple[float, float, float]
    damping: tuple[float, float, float]
    backlash: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "rotor_inertia",
            _three("rotor_inertia", self.rotor_inertia, 0.0, MAX_ROTOR_INERTIA, "kg m^2", low_open=True),
        )
        object.__setattr__(
            self, "stiffness", _three("stiffness", self.stiffness, 0.0, MAX_STIFFNESS, "N m/rad", low_open=True)
        )
        object.__setattr__(
            self, "damping", _three("damping", self.damping, 0.0, MAX_VISCOUS, "N m s/rad", low_open=False)
        )
        object.__setattr__(
            self, "backlash", _three("backlash", self.backlash, 0.0, MAX_BACKLASH, "rad", low_open=False)
        )

    @property
    def resolved_backlash(self) -> NDArray[np.float64]:
        """The backlash per joint (rad), (3,), that the controllers act on: :attr:`backlash`, zero where it is below
        :data:`SMALLEST_BACKLASH` (an identification's few-microradian estimate on a drive without any)."""
        backlash = np.asarray(self.backlash)
        return np.where(backlash >= SMALLEST_BACKLASH, backlash, 0.0)

    @classmethod
    def of_gearhead(cls, gearhead: GearheadCompliance) -> DriveCompliance:
        """The compliance a gearhead's data sheet states (:class:`delta_env.config.GearheadCompliance`)."""
        return cls(
            rotor_inertia=(gearhead.rotor_inertia,) * 3,
            stiffness=tuple(gearhead.stiffness_per_joint),
            damping=tuple(gearhead.damping_per_joint),
            backlash=(gearhead.backlash,) * 3,
        )

    @classmethod
    def nominal(cls) -> DriveCompliance:
        """The data sheet's drive: the SP+ 140 gearhead and the SGM7A-20A rotor (docs/design.md section 4)."""
        return cls.of_gearhead(GearheadCompliance())


@dataclass(frozen=True)
class DriveMode:
    """One mode of the compliant drives about a pose.

    Attributes:
        frequency_hz: Natural frequency omega / (2 pi) (Hz), |s| / (2 pi) of the pole s.
        damping_ratio: zeta = -Re(s) / |s| (dimensionless).
        shape: The mode's shape (rotor angles, then arm angles), shape (6,), complex, largest entry 1.
    """

    frequency_hz: float
    damping_ratio: float
    shape: NDArray[np.complex128]

    @property
    def damped_frequency_hz(self) -> float:
        """omega sqrt(1 - zeta^2) / (2 pi) (Hz), the frequency a free response rings at."""
        return self.frequency_hz * float(np.sqrt(max(0.0, 1.0 - self.damping_ratio**2)))


@dataclass(frozen=True)
class TwoMassLinearization:
    """The two-mass dynamics about a pose at rest, in q = (phi_1..3, theta_1..3) (rad).

    Attributes:
        mass: M_q = blockdiag(J_m, M(theta, m_p)) (kg m^2), shape (6, 6).
        damping: C_q (N m s/rad), shape (6, 6).
        stiffness: K_q (N m/rad), shape (6, 6).
    """

    mass: NDArray[np.float64]
    damping: NDArray[np.float64]
    stiffness: NDArray[np.float64]

    def modes(self) -> tuple[DriveMode, ...]:
        """The oscillating modes, lowest natural frequency first (the three rigid ones at s = 0 left out).

        The poles are the eigenvalues of the first-order form [0, I; -M_q^-1 K_q, -M_q^-1 C_q]; a mode damped past
        critical does not oscillate and is not listed.
        """
        size = len(self.mass)
        state = np.zeros((2 * size, 2 * size))
        state[:size, size:] = np.eye(size)
        state[size:, :size] = -np.linalg.solve(self.mass, self.stiffness)
        state[size:, size:] = -np.linalg.solve(self.mass, self.damping)
        poles, vectors = scipy.linalg.eig(state)
        scale = np.max(np.abs(poles))
        # the rigid modes' poles are 0 up to round-off of order sqrt(eps) |s|max (Jordan blocks)
        oscillating = np.nonzero(poles.imag > 1e-6 * scale)[0]
        modes = []
        for index in oscillating[np.argsort(np.abs(poles[oscillating]))]:
            pole = poles[index]
            shape = vectors[:size, index]
            shape = shape / shape[np.argmax(np.abs(shape))]
            modes.append(DriveMode(float(abs(pole) / (2.0 * np.pi)), float(-pole.real / abs(pole)), shape))
        return tuple(modes)

    def first_mode(self) -> DriveMode:
        """The lowest oscillating mode.

        Raises:
            ValueError: if every mode is damped past critical.
        """
        modes = self.modes()
        if not modes:
            raise ValueError("no oscillating mode: every drive mode is damped past critical")
        return modes[0]


def static_deflection(
    dynamics: DeltaDynamics, compliance: DriveCompliance, theta: ArrayLike, payload: float
) -> NDArray[np.float64]:
    """The gearheads' deflection phi - theta (rad), (3,), under the arms' static load at the pose ``theta`` (rad) with
    ``payload`` (kg): the model's torque at rest there (gravity's, the arms' and the payload's; the rotor's inertia
    and friction take none) over each gearhead's stiffness, plus half the backlash in the torque's direction (the
    rotor rests on that flank; :attr:`DriveCompliance.resolved_backlash`). The servo holds the rotors this far past
    the arms' reference (docs/design.md section 6, "The deflection feedforward")."""
    load = static_load(dynamics, theta, payload)
    return load / np.asarray(compliance.stiffness) + 0.5 * np.sign(load) * compliance.resolved_backlash


def static_load(dynamics: DeltaDynamics, theta: ArrayLike, payload: float) -> NDArray[np.float64]:
    """The model's joint torque at rest (N m), (3,), at ``theta`` (rad) with ``payload`` (kg): the arms' static load."""
    zero = np.zeros(3)
    torque, regressor = dynamics.torque_and_payload_regressor(theta, zero, zero)
    return torque + payload * regressor


def loaded_flank(
    dynamics: DeltaDynamics,
    compliance: DriveCompliance,
    theta: ArrayLike,
    theta_dot: ArrayLike,
    theta_ddot: ArrayLike,
    payload: float,
    load: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The backlash flank each rotor must press along a reference (+1 or -1 per joint, (3,)): the sign of the torque
    the gearhead passes to the arm there, the model's joint torque at ``theta`` (rad), ``theta_dot`` (rad/s) and
    ``theta_ddot`` (rad/s^2) with ``payload`` (kg) less what the rotor takes itself, its inertia torque
    J_m theta_ddot and the drive's friction (the model's viscous and Coulomb terms act on the rotor); at rest (a
    joint's rate zero) the sign of ``load``, the static load (N m) there (:func:`static_load`), as in
    :func:`static_deflection` (docs/design.md section 6, "Backlash")."""
    theta_dot, theta_ddot = np.asarray(theta_dot, dtype=float), np.asarray(theta_ddot, dtype=float)
    torque, regressor = dynamics.torque_and_payload_regressor(theta, theta_dot, theta_ddot)
    parameters = dynamics.parameters
    rotor = np.asarray(compliance.rotor_inertia) * theta_ddot
    friction = np.asarray(parameters.viscous) * theta_dot + np.asarray(parameters.coulomb) * np.sign(theta_dot)
    arm_torque = torque + payload * regressor - rotor - friction
    return np.sign(np.where(theta_dot == 0.0, load, arm_torque))


def band_deflection(
    dynamics: DeltaDynamics,
    compliance: DriveCompliance,
    theta: ArrayLike,
    theta_dot: ArrayLike,
    theta_ddot: ArrayLike,
    payload: float,
) -> NDArray[np.float64]:
    """The rotors' deflection past the arms' reference (rad), (3,), on gearheads with backlash: the static load's
    elastic deflection g / k of :func:`static_deflection`, and half the band on the flank the reference's torque
    presses (:func:`loaded_flank`), so that the rotor's reference crosses the band when the arm's planned torque
    reverses instead of leaving the crossing to the servo's error (docs/design.md section 6, "Backlash"). At rest it is
    :func:`static_deflection`; without a resolved backlash it is the elastic part alone."""
    load = static_load(dynamics, theta, payload)
    elastic = load / np.asarray(compliance.stiffness)
    band = compliance.resolved_backlash
    if not band.any():
        return elastic
    return elastic + 0.5 * band * loaded_flank(dynamics, compliance, theta, theta_dot, theta_ddot, payload, load)


def joint_space_inertia(dynamics: DeltaDynamics, theta: ArrayLike, payload: float = 0.0) -> NDArray[np.float64]:
    """The arm side's joint-space inertia M(theta, m_p) (kg m^2), shape (3, 3), of the analytical model.

    The inverse dynamics is linear in the joint accelerations, so about a state at rest its column j is
    tau(theta, 0, e_j) - tau(theta, 0, 0) exactly (the friction terms vanish at rest, sign(0) = 0).

    Args:
        dynamics: The analytical model (its rho1 scales the arms' inertia: give it one that holds no rotor).
        theta: Arm angles (rad), shape (3,).
        payload: Payload mass (kg), >= 0.
    """
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (3,):
        raise ValueError(f"theta must have shape (3,), got {theta.shape}")
    rest = np.zeros(3)
    torques = dynamics.inverse_dynamics(np.stack([theta] * 4), np.zeros((4, 3)), np.vstack([rest, np.eye(3)]), payload)
    return (torques[1:] - torques[0]).T


def two_mass_linearization(
    dynamics: DeltaDynamics, compliance: DriveCompliance, theta: ArrayLike, payload: float = 0.0
) -> TwoMassLinearization:
    """The two-mass dynamics about the pose ``theta`` (rad) at rest with ``payload`` (kg) (module docstring).

    Gravity's own stiffness (its change with the pose, tens of N m/rad against the gearheads' 1e5) is left out, so
    the rigid modes stay at s = 0; the model's viscous friction ``dynamics.parameters.viscous`` damps the rotors.
    """
    arm_inertia = joint_space_inertia(dynamics, theta, payload)
    stiffness = np.diag(compliance.stiffness)
    damping = np.diag(compliance.damping)
    mass = np.zeros((6, 6))
    mass[:3, :3] = np.diag(compliance.rotor_inertia)
    mass[3:, 3:] = 0.5 * (arm_inertia + arm_inertia.T)
    damping_q = np.block([[damping, -damping], [-damping, damping]])
    damping_q[:3, :3] += np.diag(dynamics.parameters.viscous)
    stiffness_q = np.block([[stiffness, -stiffness], [-stiffness, stiffness]])
    return TwoMassLinearization(mass, damping_q, stiffness_q)


def drive_modes(
    dynamics: DeltaDynamics, compliance: DriveCompliance, theta: ArrayLike, payload: float = 0.0
) -> tuple[DriveMode, ...]:
    """The drives' oscillating modes about ``theta`` (rad) with ``payload`` (kg), lowest first."""
    return two_mass_linearization(dynamics, compliance, theta, payload).modes()


def first_mode(
    dynamics: DeltaDynamics, compliance: DriveCompliance, theta: ArrayLike, payload: float = 0.0
) -> DriveMode:
    """The drives' lowest mode about ``theta`` (rad) with ``payload`` (kg)."""
    return two_mass_linearization(dynamics, compliance, theta, payload).first_mode()


def first_mode_map(
    dynamics: DeltaDynamics, compliance: DriveCompliance, theta: ArrayLike, payloads: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The first mode over poses and payloads: its natural frequency (Hz) and damping ratio, each ``(N, P)``.

    Args:
        dynamics: The analytical model of the arm side.
        compliance: The drives.
        theta: Arm angles of the poses (rad), ``(N, 3)``.
        payloads: Payload masses (kg), ``(P,)``.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    payloads = np.atleast_1d(np.asarray(payloads, dtype=float))
    frequency, damping = np.empty((len(theta), len(payloads))), np.empty((len(theta), len(payloads)))
    for n, pose in enumerate(theta):
        for p, payload in enumerate(payloads):
            mode = first_mode(dynamics, compliance, pose, float(payload))
            frequency[n, p], damping[n, p] = mode.frequency_hz, mode.damping_ratio
    return frequency, damping
