"""Configuration of the simulated plant: what is built, and what domain randomization may change.

Frozen dataclasses in SI units, checked on construction with :mod:`delta_env.validation`. The model
itself is built from a :class:`PlantConfig` by :mod:`delta_env.robot` and :mod:`delta_env.scene`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from delta_env.catalogue import MOTORS
from delta_env.drive import REPRESENTATIVE_GEAR_RATIO, DriveLimits
from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, TORQUE_LIMIT, DeltaGeometry, DeltaMasses
from delta_env.sensors import CONTROL_PERIOD, ENCODER_BITS, PHYSICS_TIMESTEP, control_substeps
from delta_env.validation import require_count, require_in, require_instance, require_interval, require_joint_vector

FOREARM_SPACING = 0.10
"""Distance (m) between the two rods of a parallelogram, along the motor axis (docs/design.md section 4)."""

SUCTION_CUP_OFFSET = 0.05
"""Depth (m) of the suction cup face below the platform centre E0 (site ``suction_cup``)."""

DEFAULT_PAYLOAD_SIZE = (0.10, 0.10, 0.08)
"""Edge lengths (m) of the payload box when the model is built; :meth:`DeltaPlant.place_payload` changes them."""

MIN_PAYLOAD_MASS = 1e-3
"""Smallest simulated payload mass (kg): a 0 kg object is simulated as 1 g so its free joint keeps a
positive-definite inertia. Carried at 6 g it adds about 0.03 N m, far below the 0.5 N m torque noise."""

RATED_PAYLOAD = 4.0
"""The robot's rated payload (kg, docs/design.md section 4): the heaviest object of the default tasks and of the
pick-rate data sheet."""

MAX_PAYLOAD_MASS = 5.0 * RATED_PAYLOAD
"""Largest payload mass (kg) accepted: 5x the rated payload."""

MAX_SCALE = 10.0
"""Largest per-joint friction multiplier accepted (dimensionless)."""

MAX_VISCOUS = 1000.0
"""Largest viscous friction coefficient accepted (N m s/rad), of the plant and of an identified model: at 1 rad/s
it is 2.5x the drive's peak torque. Coulomb friction is bounded by the peak torque TORQUE_LIMIT itself."""

MAX_LAG = 0.1
"""Largest current-loop time constant accepted (s)."""

ARCMIN = math.pi / (180.0 * 60.0)
"""One minute of arc in rad."""

MAX_BACKLASH = 0.01
"""Largest gearhead backlash accepted (rad), about 34 arcmin: ten times a standard-class planetary gearhead's."""

GEARHEAD_STIFFNESS = 53.0 / ARCMIN
"""Torsional stiffness (N m/rad) at the output of the gearhead of :class:`GearheadCompliance`: 53 N m/arcmin, the
maximum torsional rigidity Ct21 of a WITTENSTEIN alpha SP+ 140 MF precision planetary gearhead (Beckhoff AG2300
SP140 MF, the same gearhead built for Beckhoff: Beckhoff Information System, "AG2300 SP140 MF, Mechanical data"),
1 N m/arcmin = 60 * 180 / pi = 3437.7 N m/rad, so 1.822e5 N m/rad. Size 140 is the smallest SP+ whose maximum
acceleration torque T2B (468 to 792 N m by ratio) covers the drive's 400 N m peak (size 100: 282 to 378 N m); its
rated T2N (202 to 335 N m) covers the drive's 128 N m rated torque. The page lists the one-stage ratios (3 to 10);
the drive's 1:21 is a two-stage ratio, whose rigidity was not checked."""

GEARHEAD_DAMPING = 10.0
"""Torsional damping (N m s/rad) of the gearhead of :class:`GearheadCompliance`. No catalogue states it: chosen for
a damping ratio c / (2 sqrt(k J_m)) = 0.035 of the motor against a locked arm (k = :data:`GEARHEAD_STIFFNESS`,
J_m = :data:`ROTOR_INERTIA`), within the few per cent of structural damping of a geared drive."""

ROTOR_INERTIA = MOTORS["SGM7A-20A"].rotor_inertia * REPRESENTATIVE_GEAR_RATIO**2
"""Rotor inertia of the drive reflected to the joint (kg m^2): the SGM7A-20A's 2.47e-4 kg m^2
(:data:`delta_env.catalogue.MOTORS`, the motor :data:`delta_env.drive.REPRESENTATIVE_MOTOR` is sized after) times
the gear ratio 21 squared, 0.109 kg m^2."""

MAX_STIFFNESS = 1e8
"""Largest gearhead stiffness accepted (N m/rad): 500x :data:`GEARHEAD_STIFFNESS`."""


@dataclass(frozen=True)
class GearheadCompliance:
    """A compliant drive: the motor's rotor on its own joint, coupled to the arm through the gearhead's torsional
    spring and damper (docs/design.md section 4, "Compliant drives").

    Everything is at the joint (after the gearbox): the rotor joint's angle is the motor shaft's angle divided by
    ``gear_ratio``, its inertia the rotor's reflected one, and the gearhead passes
    k (phi - theta - d) + c (phi_dot - theta_dot) from the rotor (phi) to the arm (theta), with d the deflection
    taken up by the backlash: 0 inside the band |phi - theta| <= backlash / 2, the excess beyond it. The drive's
    torque, its friction, Stribeck and ripple act on the rotor; the motor encoder reads the rotor.

    Attributes:
        rotor_inertia: Reflected rotor inertia (kg m^2) on the motor side; the arm joint keeps ``armature``.
        stiffness: Torsional stiffness at the output (N m/rad), per joint times ``stiffness_scale``.
        damping: Torsional damping at the output (N m s/rad), per joint times ``damping_scale``.
        stiffness_scale: Per-joint multipliers of ``stiffness`` (dimensionless), each in (0, 10].
        damping_scale: Per-joint multipliers of ``damping`` (dimensionless), each in [0, 10].
        backlash: Total lost motion at the output (rad), in [0, 0.01]; 0 is none. The SP+ 140 data sheet gives at
            most 3 arcmin (standard) or 1 arcmin (reduced).
        gear_ratio: Reduction between the motor shaft and the joint (dimensionless), in [1, 1000]: the motor
            encoder's resolution at the joint is its step divided by this.
        load_encoder_bits: Resolution (bits per revolution) of an encoder on the arm (the load side), reported as
            the observation's ``load_angles``; None: no load encoder.
    """

    rotor_inertia: float = ROTOR_INERTIA
    stiffness: float = GEARHEAD_STIFFNESS
    damping: float = GEARHEAD_DAMPING
    stiffness_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    damping_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    backlash: float = 0.0
    gear_ratio: float = REPRESENTATIVE_GEAR_RATIO
    load_encoder_bits: int | None = None

    def __post_init__(self) -> None:
        require_in("rotor_inertia", self.rotor_inertia, 0.0, 10.0, unit="kg m^2", low_open=True)
        require_in("stiffness", self.stiffness, 0.0, MAX_STIFFNESS, unit="N m/rad", low_open=True)
        require_in("damping", self.damping, 0.0, MAX_VISCOUS, unit="N m s/rad")
        require_joint_vector("stiffness_scale", self.stiffness_scale, 0.0, MAX_SCALE, low_open=True)
        require_joint_vector("damping_scale", self.damping_scale, 0.0, MAX_SCALE)
        require_in("backlash", self.backlash, 0.0, MAX_BACKLASH, unit="rad")
        require_in("gear_ratio", self.gear_ratio, 1.0, 1000.0)
        if self.load_encoder_bits is not None:
            require_count("load_encoder_bits", self.load_encoder_bits, 8, 32)

    @property
    def stiffness_per_joint(self) -> NDArray[np.float64]:
        """Stiffness per joint (N m/rad), shape (3,)."""
        return self.stiffness * np.asarray(self.stiffness_scale, dtype=float)

    @property
    def damping_per_joint(self) -> NDArray[np.float64]:
        """Damping per joint (N m s/rad), shape (3,)."""
        return self.damping * np.asarray(self.damping_scale, dtype=float)


@dataclass(frozen=True)
class PlantRealism:
    """Drive effects of the plant that the analytical model does not know (docs/design.md section 4 table).

    The defaults are plausible for a geared industrial Delta, not tuned for any method; every effect can be
    turned off with 0 (or None). Torques are at the joint (after the gearbox).

    Attributes:
        armature: Reflected rotor inertia per motor joint (kg m^2); MuJoCo ``armature``.
        viscous: Viscous friction coefficient (N m s/rad); MuJoCo ``damping`` times ``viscous_scale``.
        viscous_scale: Per-joint multipliers of ``viscous`` (dimensionless), each in (0, 10].
        coulomb: Coulomb friction (N m); MuJoCo ``frictionloss`` times ``coulomb_scale``.
        coulomb_scale: Per-joint multipliers of ``coulomb`` (dimensionless), each in (0, 10].
        stribeck_excess: Extra friction near zero speed as a fraction of Coulomb, decaying as
            exp(-(v / stribeck_velocity)^2) (dimensionless); applied through ``qfrc_applied``.
        stribeck_velocity: Decay speed of the Stribeck excess (rad/s).
        ripple_amplitude: Position-dependent torque ripple (gear / cogging) amplitude (N m).
        ripple_periods: Ripple periods per joint revolution.
        actuator_lag: Time constant of the first-order current loop (s); 0 means direct torque. MuJoCo
            ``dyntype="filterexact"`` (the exact discretization of ``filter``: Euler would turn a 0.5 ms
            lag at a 0.5 ms timestep into a one-step delay).
        torque_noise_std: Measured-torque white noise (N m); observation side, used by the env.
        encoder_bits: Absolute encoder resolution (bits), or None for exact angles; observation side, used by the
            env. Defaults to :data:`delta_env.sensors.ENCODER_BITS`. On the joint of a rigid drive, on the motor
            shaft of a compliant one.
        compliance: A compliant drive (:class:`GearheadCompliance`): the rotor on its own joint behind the
            gearhead's spring, and the friction, Stribeck, ripple and drive torque on it; None (default): the motor,
            gearbox and arm are one rigid body.
    """

    armature: float = 0.10
    viscous: float = 2.0
    viscous_scale: tuple[float, float, float] = (1.0, 1.2, 0.85)
    coulomb: float = 4.0
    coulomb_scale: tuple[float, float, float] = (1.0, 0.85, 1.15)
    stribeck_excess: float = 0.5
    stribeck_velocity: float = 0.05
    ripple_amplitude: float = 1.0
    ripple_periods: int = 180
    actuator_lag: float = 0.001
    torque_noise_std: float = 0.5
    encoder_bits: int | None = ENCODER_BITS
    compliance: GearheadCompliance | None = None

    def __post_init__(self) -> None:
        require_in("armature", self.armature, 0.0, 10.0, unit="kg m^2")
        require_in("viscous", self.viscous, 0.0, MAX_VISCOUS, unit="N m s/rad")
        require_joint_vector("viscous_scale", self.viscous_scale, 0.0, MAX_SCALE, low_open=True)
        require_in("coulomb", self.coulomb, 0.0, TORQUE_LIMIT, unit="N m")
        require_joint_vector("coulomb_scale", self.coulomb_scale, 0.0, MAX_SCALE, low_open=True)
        require_in("stribeck_excess", self.stribeck_excess, 0.0, 10.0)
        require_in("stribeck_velocity", self.stribeck_velocity, 0.0, 10.0, unit="rad/s", low_open=True)
        require_in("ripple_amplitude", self.ripple_amplitude, 0.0, TORQUE_LIMIT, unit="N m")
        require_count("ripple_periods", self.ripple_periods, 0, 100_000)
        require_in("actuator_lag", self.actuator_lag, 0.0, MAX_LAG, unit="s")
        require_in("torque_noise_std", self.torque_noise_std, 0.0, TORQUE_LIMIT, unit="N m")
        if self.encoder_bits is not None:
            require_count("encoder_bits", self.encoder_bits, 8, 32)
        if self.compliance is not None:
            require_instance("compliance", self.compliance, GearheadCompliance)

    @classmethod
    def off(cls) -> PlantRealism:
        """Every effect turned off: the drive is an ideal torque source, sensors are exact."""
        return cls(
            armature=0.0,
            viscous=0.0,
            coulomb=0.0,
            stribeck_excess=0.0,
            ripple_amplitude=0.0,
            actuator_lag=0.0,
            torque_noise_std=0.0,
            encoder_bits=None,
        )

    @property
    def viscous_per_joint(self) -> NDArray[np.float64]:
        """Viscous friction per motor joint (N m s/rad), shape (3,)."""
        return self.viscous * np.asarray(self.viscous_scale, dtype=float)

    @property
    def coulomb_per_joint(self) -> NDArray[np.float64]:
        """Coulomb friction per motor joint (N m), shape (3,)."""
        return self.coulomb * np.asarray(self.coulomb_scale, dtype=float)

    @property
    def acts_on_plant(self) -> bool:
        """True if any effect changes the plant's dynamics (the observation-side ones excluded)."""
        return self.compliance is not None or any(
            value > 0.0
            for value in (self.armature, self.viscous, self.coulomb, self.ripple_amplitude, self.actuator_lag)
        )


@dataclass(frozen=True)
class PlantConfig:
    """Everything the model builder (:func:`delta_env.scene.build_model`) needs; one source of truth.

    Attributes:
        geometry: Lengths of the robot (m); the nominal "datasheet" values by default.
        masses: True masses of the plant (kg); the env may perturb them per episode.
        variant: ``"ideal"`` (MKH assumptions, for validation) or ``"realistic"`` (parallelograms).
        realism: Drive effects; the ideal variant requires them off on the plant side
            (use :meth:`PlantConfig.ideal`).
        timestep: Physics timestep (s) in [1e-5, CONTROL_PERIOD] that divides CONTROL_PERIOD (1 ms / n);
            0.5 ms holds the loops closed (docs/design.md section 4).
        payload_body: Include the pick-and-place payload body and its ``suction`` weld.
        drive: Torque-speed envelope and thermal limit of each joint's drive; MuJoCo's ``ctrlrange`` is its
            peak torque, the env enforces the rest.
        collisions: Turn on contacts among the robot's links and its base (realistic variant only;
            :func:`delta_env.robot.collision_geom_names`), as the design verification does; off, robot parts pass
            through each other.
    """

    geometry: DeltaGeometry = NOMINAL_GEOMETRY
    masses: DeltaMasses = NOMINAL_MASSES
    variant: Literal["ideal", "realistic"] = "realistic"
    realism: PlantRealism = field(default_factory=PlantRealism)
    timestep: float = PHYSICS_TIMESTEP
    payload_body: bool = True
    drive: DriveLimits = field(default_factory=DriveLimits)
    collisions: bool = False

    def __post_init__(self) -> None:
        require_instance("geometry", self.geometry, DeltaGeometry)
        require_instance("masses", self.masses, DeltaMasses)
        if self.variant not in ("ideal", "realistic"):
            raise ValueError(f"variant must be 'ideal' or 'realistic', got {self.variant!r}")
        require_instance("realism", self.realism, PlantRealism)
        if self.variant == "ideal" and self.realism.acts_on_plant:
            raise ValueError(
                "the ideal variant must satisfy the MKH assumptions: armature, viscous, coulomb, "
                "ripple_amplitude and actuator_lag must be 0 and compliance None "
                "(use PlantConfig.ideal() or PlantRealism.off())"
            )
        _ = self.geometry.home_height  # raises ValueError if the robot cannot assemble with its arms horizontal
        require_in("timestep", self.timestep, 1e-5, CONTROL_PERIOD, unit="s")
        control_substeps(self.timestep)  # the env's check, so that a scenario is refused as the env would
        if not isinstance(self.payload_body, bool):
            raise ValueError(f"payload_body must be a bool, got {self.payload_body!r}")
        require_instance("drive", self.drive, DriveLimits)
        compliance = self.realism.compliance
        if compliance is not None:
            # MuJoCo integrates a tendon's spring explicitly: stable while omega h < 2 for every mode. The locked-arm
            # mode sqrt(k / J_m) is the stiffest one's lower bound; a free arm raises it by sqrt(1 + J_m / J_a).
            locked = math.sqrt(float(np.max(compliance.stiffness_per_joint)) / compliance.rotor_inertia)
            if locked * self.timestep > 1.0:
                raise ValueError(
                    f"the gearhead's locked-arm mode sqrt(k / J_m) = {locked:.0f} rad/s is too fast for the timestep "
                    f"{self.timestep} s: it must stay below 1 / timestep = {1.0 / self.timestep:.0f} rad/s (a smaller "
                    "timestep, a softer gearhead or a heavier rotor)"
                )
        if not isinstance(self.collisions, bool):
            raise ValueError(f"collisions must be a bool, got {self.collisions!r}")
        if self.collisions and self.variant != "realistic":
            raise ValueError("collisions need the realistic variant (the ideal one has no parallelograms to collide)")

    @classmethod
    def ideal(
        cls,
        geometry: DeltaGeometry = NOMINAL_GEOMETRY,
        masses: DeltaMasses = NOMINAL_MASSES,
        **kwargs: object,
    ) -> PlantConfig:
        """The MKH-exact variant with every realism effect off."""
        return cls(geometry=geometry, masses=masses, variant="ideal", realism=PlantRealism.off(), **kwargs)

    @property
    def home_height(self) -> float:
        """Platform height z (m) with all arms horizontal (theta = 0); see :attr:`DeltaGeometry.home_height`."""
        return self.geometry.home_height


@dataclass(frozen=True)
class PhysicalParameters:
    """The plant parameters that domain randomization edits in place, per episode.

    Attributes:
        masses: True masses m1, m2, m0 (kg); the bodies get the inertial properties that the model
            builder gives for these masses (same shapes).
        friction_scale: Per-joint multipliers of viscous, Coulomb and Stribeck friction (dimensionless),
            each in (0, 10].
        actuator_lag: Current-loop time constant (s); must be > 0 if the plant was built with a lag.
        stiffness_scale: Per-joint multipliers of a compliant drive's gearhead stiffness (dimensionless), each in
            (0, 10]; other than 1 only on a compliant plant.
        damping_scale: Per-joint multipliers of its gearhead damping (dimensionless), each in [0, 10]; likewise.
    """

    masses: DeltaMasses
    friction_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    actuator_lag: float = 0.0
    stiffness_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    damping_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        require_instance("masses", self.masses, DeltaMasses)
        require_joint_vector("friction_scale", self.friction_scale, 0.0, MAX_SCALE, low_open=True)
        require_in("actuator_lag", self.actuator_lag, 0.0, MAX_LAG, unit="s")
        require_joint_vector("stiffness_scale", self.stiffness_scale, 0.0, MAX_SCALE, low_open=True)
        require_joint_vector("damping_scale", self.damping_scale, 0.0, MAX_SCALE)

    @property
    def scales_gearhead(self) -> bool:
        """True if the gearhead's stiffness or damping differ from the plant's nominal ones."""
        return self.stiffness_scale != (1.0, 1.0, 1.0) or self.damping_scale != (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class RandomizationRanges:
    """Per-episode domain randomization (docs/design.md section 4; the env keeps it off by default).

    Attributes:
        mass_fraction: m1, m2 and m0 are each scaled by U[1 - f, 1 + f] (dimensionless), f in [0, 0.9].
        friction_fraction: Each joint's friction is scaled by U[1 - f, 1 + f] (dimensionless), f in [0, 0.9].
        actuator_lag: Bounds (s) of a uniform lag draw, 0 < low <= high <= 0.1, or None to keep the built lag.
        stiffness_fraction: Each joint's gearhead stiffness is scaled by U[1 - f, 1 + f] (dimensionless), f in
            [0, 0.9]; a compliant plant only. 0 (default) draws nothing.
        damping_fraction: Each joint's gearhead damping is scaled by U[1 - f, 1 + f] (dimensionless), f in [0, 0.9];
            likewise.
    """

    mass_fraction: float = 0.10
    friction_fraction: float = 0.30
    actuator_lag: tuple[float, float] | None = (0.0005, 0.002)
    stiffness_fraction: float = 0.0
    damping_fraction: float = 0.0

    def __post_init__(self) -> None:
        require_in("mass_fraction", self.mass_fraction, 0.0, 0.9)
        require_in("friction_fraction", self.friction_fraction, 0.0, 0.9)
        require_in("stiffness_fraction", self.stiffness_fraction, 0.0, 0.9)
        require_in("damping_fraction", self.damping_fraction, 0.0, 0.9)
        if self.actuator_lag is not None:
            low, _ = require_interval("actuator_lag", self.actuator_lag, 0.0, MAX_LAG, unit="s")
            require_in("actuator_lag[0]", low, 0.0, MAX_LAG, unit="s", low_open=True)

    def draw(self, rng: np.random.Generator, nominal: DeltaMasses, actuator_lag: float) -> PhysicalParameters:
        """Physical parameters around the ``nominal`` masses (kg); the built ``actuator_lag`` (s) kept without a
        lag range. The gearhead's scales are drawn last and only with a fraction > 0, so that ranges without them
        draw as before."""

        def scales(fraction: float) -> NDArray[np.float64]:
            return rng.uniform(1.0 - fraction, 1.0 + fraction, 3)

        def gearhead_scales(fraction: float) -> tuple[float, float, float]:
            return tuple(float(v) for v in scales(fraction)) if fraction > 0.0 else (1.0, 1.0, 1.0)

        m1, m2, m0 = (nominal.m1, nominal.m2, nominal.m0) * scales(self.mass_fraction)
        lag = actuator_lag if self.actuator_lag is None else float(rng.uniform(*self.actuator_lag))
        friction_scale = tuple(float(v) for v in scales(self.friction_fraction))
        return PhysicalParameters(
            masses=DeltaMasses(m1=float(m1), m2=float(m2), m0=float(m0)),
            friction_scale=friction_scale,
            actuator_lag=lag,
            stiffness_scale=gearhead_scales(self.stiffness_fraction),
            damping_scale=gearhead_scales(self.damping_fraction),
        )

    @property
    def draws_gearhead(self) -> bool:
        """True if the ranges scale a compliant drive's gearhead."""
        return self.stiffness_fraction > 0.0 or self.damping_fraction > 0.0
