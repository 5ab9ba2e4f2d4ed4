"""Configuration of the simulated plant: what is built, and what domain randomization may change.

Frozen dataclasses in SI units, checked on construction with :mod:`delta_env.validation`. The model
itself is built from a :class:`PlantConfig` by :mod:`delta_env.robot` and :mod:`delta_env.scene`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from delta_env.drive import DriveLimits
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
        encoder_bits: Absolute encoder resolution on the joint (bits), or None for exact angles;
            observation side, used by the env. Defaults to :data:`delta_env.sensors.ENCODER_BITS`.
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
        return any(
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
                "ripple_amplitude and actuator_lag must be 0 (use PlantConfig.ideal() or PlantRealism.off())"
            )
        _ = self.geometry.home_height  # raises ValueError if the robot cannot assemble with its arms horizontal
        require_in("timestep", self.timestep, 1e-5, CONTROL_PERIOD, unit="s")
        control_substeps(self.timestep)  # the env's check, so that a scenario is refused as the env would
        if not isinstance(self.payload_body, bool):
            raise ValueError(f"payload_body must be a bool, got {self.payload_body!r}")
        require_instance("drive", self.drive, DriveLimits)
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
    """

    masses: DeltaMasses
    friction_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    actuator_lag: float = 0.0

    def __post_init__(self) -> None:
        require_instance("masses", self.masses, DeltaMasses)
        require_joint_vector("friction_scale", self.friction_scale, 0.0, MAX_SCALE, low_open=True)
        require_in("actuator_lag", self.actuator_lag, 0.0, MAX_LAG, unit="s")


@dataclass(frozen=True)
class RandomizationRanges:
    """Per-episode domain randomization (docs/design.md section 4; the env keeps it off by default).

    Attributes:
        mass_fraction: m1, m2 and m0 are each scaled by U[1 - f, 1 + f] (dimensionless), f in [0, 0.9].
        friction_fraction: Each joint's friction is scaled by U[1 - f, 1 + f] (dimensionless), f in [0, 0.9].
        actuator_lag: Bounds (s) of a uniform lag draw, 0 < low <= high <= 0.1, or None to keep the built lag.
    """

    mass_fraction: float = 0.10
    friction_fraction: float = 0.30
    actuator_lag: tuple[float, float] | None = (0.0005, 0.002)

    def __post_init__(self) -> None:
        require_in("mass_fraction", self.mass_fraction, 0.0, 0.9)
        require_in("friction_fraction", self.friction_fraction, 0.0, 0.9)
        if self.actuator_lag is not None:
            low, _ = require_interval("actuator_lag", self.actuator_lag, 0.0, MAX_LAG, unit="s")
            require_in("actuator_lag[0]", low, 0.0, MAX_LAG, unit="s", low_open=True)

    def draw(self, rng: np.random.Generator, nominal: DeltaMasses, actuator_lag: float) -> PhysicalParameters:
        """Physical parameters around the ``nominal`` masses (kg); the built ``actuator_lag`` (s) kept without a
        lag range."""

        def scales(fraction: float) -> NDArray[np.float64]:
            return rng.uniform(1.0 - fraction, 1.0 + fraction, 3)

        m1, m2, m0 = (nominal.m1, nominal.m2, nominal.m0) * scales(self.mass_fraction)
        lag = actuator_lag if self.actuator_lag is None else float(rng.uniform(*self.actuator_lag))
        return PhysicalParameters(
            masses=DeltaMasses(m1=float(m1), m2=float(m2), m0=float(m0)),
            friction_scale=tuple(float(v) for v in scales(self.friction_fraction)),
            actuator_lag=lag,
        )
