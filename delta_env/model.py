"""The "real robot": a MuJoCo Delta generated from parameters, and its physics wrapper (DESIGN.md section 4).

Two variants share one generator, :func:`build_mjcf`:

- ``ideal`` satisfies the Kuo-Huang (MKH) assumptions of the analytical model exactly (platform on three
  slides, one forearm rod per chain whose mass m2 sits at its lower end, upper arm with the lumped inertia
  (m1/3 + m2) l1^2), so that the analytical dynamics can be validated against MuJoCo to round-off.
- ``realistic`` is a true parallelogram Delta (two rods per chain, free-joint platform held level only by
  the parallelograms) with the drive effects of :class:`PlantRealism` that the analytical model ignores.

Conventions follow DESIGN.md section 1: chain i = 1, 2, 3 at azimuth alpha_i, motor hinge axis
t_i = e_z x u_i so that the motor joint's qpos is theta_i and theta_i > 0 turns the arm down.
:class:`DeltaPlant` caches every id and address once and is the only code that touches MuJoCo state.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field, replace
from typing import Literal

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kinematics
from delta_env.geometry import (
    CHAIN_AZIMUTHS,
    GRAVITY,
    NOMINAL_GEOMETRY,
    NOMINAL_MASSES,
    TORQUE_LIMIT,
    DeltaGeometry,
    DeltaMasses,
)

FOREARM_SPACING = 0.10
"""Distance (m) between the two rods of a parallelogram, along the motor axis (DESIGN.md section 4)."""

SUCTION_CUP_OFFSET = 0.05
"""Depth (m) of the suction cup face below the platform centre E0 (site ``suction_cup``)."""

DEFAULT_PAYLOAD_SIZE = (0.10, 0.10, 0.08)
"""Edge lengths (m) of the payload box when the model is built; :meth:`DeltaPlant.place_payload` changes them."""

MIN_PAYLOAD_MASS = 1e-3
"""Smallest simulated payload mass (kg): a 0 kg object is simulated as 1 g so its free joint keeps a
positive-definite inertia. Carried at 6 g it adds about 0.03 N m, far below the 0.5 N m torque noise."""

MAX_PAYLOAD_MASS = 20.0
"""Largest payload mass (kg) accepted: 5x the 4 kg rating of DESIGN.md section 4."""

CHAIN_LABELS = ("1", "2", "3")
"""Chain suffixes used in element names (``motor_1`` ... ``motor_3``), DESIGN.md numbering."""

_ROD_LABELS = ("a", "b")  # rod a sits at +FOREARM_SPACING/2 along t_i, rod b at -FOREARM_SPACING/2
_POINT_INERTIA = 1e-12  # kg m^2: "point" bodies of the ideal variant; adds ~1e-10 N m at 100 rad/s^2
_UPPER_ARM_SPLIT = {"hub": 0.30, "tube": 0.50, "bar": 0.20}  # fractions of m1 in the realistic upper arm
_FOREARM_ROD_RADIUS = 0.006  # m, thin carbon tube
_PLATFORM_THICKNESS = 0.02  # m
_STRIBECK_SIGN_SLOPE = 4.0  # smooth sign tanh(4 v / v_s): its slope stays explicit-stable at 1 kHz
_FLOOR_HEIGHT = -1.25  # m, visual only (no contacts)
_MATERIALS = {
    "base": (0.35, 0.37, 0.4, 1.0),
    "arm": (0.9, 0.55, 0.1, 1.0),
    "rod": (0.15, 0.15, 0.15, 1.0),
    "platform": (0.7, 0.72, 0.75, 1.0),
    "cup": (0.2, 0.4, 0.8, 1.0),
    "payload": (0.75, 0.6, 0.4, 1.0),
}


def _require_finite_in(name: str, value: float, low: float, high: float, *, low_open: bool = False) -> None:
    ok = math.isfinite(value) and (value > low if low_open else value >= low) and value <= high
    if not ok:
        bracket = "(" if low_open else "["
        raise ValueError(f"{name} must be a finite number in {bracket}{low}, {high}], got {value!r}")


def _require_scales(name: str, values: tuple[float, float, float]) -> None:
    if len(values) != 3:
        raise ValueError(f"{name} must have 3 entries (one per joint), got {values!r}")
    for index, value in enumerate(values):
        _require_finite_in(f"{name}[{index}]", value, 0.0, 10.0, low_open=True)


@dataclass(frozen=True)
class PlantRealism:
    """Drive effects of the plant that the analytical model does not know (DESIGN.md section 4 table).

    The defaults are plausible for a geared industrial Delta, not tuned for any method; every effect can be
    turned off with 0 (or None). Torques are at the joint (after the gearbox).

    Attributes:
        armature: Reflected rotor inertia per motor joint (kg m^2); MuJoCo ``armature``.
        viscous: Viscous friction coefficient (N m s/rad); MuJoCo ``damping`` times ``viscous_scale``.
        viscous_scale: Per-joint multipliers of ``viscous`` (dimensionless).
        coulomb: Coulomb friction (N m); MuJoCo ``frictionloss`` times ``coulomb_scale``.
        coulomb_scale: Per-joint multipliers of ``coulomb`` (dimensionless).
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
            observation side, used by the env.
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
    encoder_bits: int | None = 17

    def __post_init__(self) -> None:
        _require_finite_in("armature", self.armature, 0.0, 10.0)
        _require_finite_in("viscous", self.viscous, 0.0, 1000.0)
        _require_scales("viscous_scale", self.viscous_scale)
        _require_finite_in("coulomb", self.coulomb, 0.0, TORQUE_LIMIT)
        _require_scales("coulomb_scale", self.coulomb_scale)
        _require_finite_in("stribeck_excess", self.stribeck_excess, 0.0, 10.0)
        _require_finite_in("stribeck_velocity", self.stribeck_velocity, 0.0, 10.0, low_open=True)
        _require_finite_in("ripple_amplitude", self.ripple_amplitude, 0.0, TORQUE_LIMIT)
        if not isinstance(self.ripple_periods, int) or not 0 <= self.ripple_periods <= 100_000:
            raise ValueError(f"ripple_periods must be an int in [0, 100000], got {self.ripple_periods!r}")
        _require_finite_in("actuator_lag", self.actuator_lag, 0.0, 0.1)
        _require_finite_in("torque_noise_std", self.torque_noise_std, 0.0, TORQUE_LIMIT)
        if self.encoder_bits is not None and (
            not isinstance(self.encoder_bits, int) or not 8 <= self.encoder_bits <= 32
        ):
            raise ValueError(f"encoder_bits must be None or an int in [8, 32], got {self.encoder_bits!r}")

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
    """Everything :func:`build_mjcf` needs; one source of truth for the plant.

    Attributes:
        geometry: Lengths of the robot (m); the nominal "datasheet" values by default.
        masses: True masses of the plant (kg); the env may perturb them per episode.
        variant: ``"ideal"`` (MKH assumptions, for validation) or ``"realistic"`` (parallelograms).
        realism: Drive effects; the ideal variant requires them off on the plant side
            (use :meth:`PlantConfig.ideal`).
        timestep: Physics timestep (s); 0.5 ms holds the loops closed (DESIGN.md section 4).
        payload_body: Include the pick-and-place payload body and its ``suction`` weld.
    """

    geometry: DeltaGeometry = NOMINAL_GEOMETRY
    masses: DeltaMasses = NOMINAL_MASSES
    variant: Literal["ideal", "realistic"] = "realistic"
    realism: PlantRealism = field(default_factory=PlantRealism)
    timestep: float = 0.0005
    payload_body: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.geometry, DeltaGeometry):
            raise ValueError(f"geometry must be a DeltaGeometry, got {type(self.geometry).__name__}")
        if not isinstance(self.masses, DeltaMasses):
            raise ValueError(f"masses must be a DeltaMasses, got {type(self.masses).__name__}")
        if self.variant not in ("ideal", "realistic"):
            raise ValueError(f"variant must be 'ideal' or 'realistic', got {self.variant!r}")
        if not isinstance(self.realism, PlantRealism):
            raise ValueError(f"realism must be a PlantRealism, got {type(self.realism).__name__}")
        if self.variant == "ideal" and self.realism.acts_on_plant:
            raise ValueError(
                "the ideal variant must satisfy the MKH assumptions: armature, viscous, coulomb, "
                "ripple_amplitude and actuator_lag must be 0 (use PlantConfig.ideal() or PlantRealism.off())"
            )
        g = self.geometry
        if g.l2 <= g.r + g.l1:
            raise ValueError(
                f"the robot cannot assemble with its arms horizontal: l2={g.l2} must exceed ra - rb + l1={g.r + g.l1} m"
            )
        _require_finite_in("timestep", self.timestep, 1e-5, 2e-3)
        if not isinstance(self.payload_body, bool):
            raise ValueError(f"payload_body must be a bool, got {self.payload_body!r}")

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
        """Platform height z (m) with all arms horizontal (theta = 0)."""
        g = self.geometry
        return -math.sqrt(g.l2**2 - (g.r + g.l1) ** 2)


@dataclass(frozen=True)
class PhysicalParameters:
    """The plant parameters that domain randomization edits in place, per episode.

    Attributes:
        masses: True masses m1, m2, m0 (kg); the bodies get the inertial properties that build_mjcf gives
            for these masses (same shapes).
        friction_scale: Per-joint multipliers of viscous, Coulomb and Stribeck friction (dimensionless).
        actuator_lag: Current-loop time constant (s); must be > 0 if the plant was built with a lag.
    """

    masses: DeltaMasses
    friction_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    actuator_lag: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.masses, DeltaMasses):
            raise ValueError(f"masses must be a DeltaMasses, got {type(self.masses).__name__}")
        _require_scales("friction_scale", self.friction_scale)
        _require_finite_in("actuator_lag", self.actuator_lag, 0.0, 0.1)


@dataclass(frozen=True)
class RandomizationRanges:
    """Per-episode domain randomization (DESIGN.md section 4; the env keeps it off by default).

    Attributes:
        mass_fraction: m1, m2 and m0 are each scaled by U[1 - f, 1 + f] (dimensionless).
        friction_fraction: Each joint's friction is scaled by U[1 - f, 1 + f] (dimensionless).
        actuator_lag: Bounds (s) of a uniform lag draw, or None to keep the built lag.
    """

    mass_fraction: float = 0.10
    friction_fraction: float = 0.30
    actuator_lag: tuple[float, float] | None = (0.0005, 0.002)

    def __post_init__(self) -> None:
        _require_finite_in("mass_fraction", self.mass_fraction, 0.0, 0.9)
        _require_finite_in("friction_fraction", self.friction_fraction, 0.0, 0.9)
        if self.actuator_lag is not None:
            low, high = self.actuator_lag
            _require_finite_in("actuator_lag[0]", low, 0.0, 0.1, low_open=True)
            _require_finite_in("actuator_lag[1]", high, low, 0.1)


# ------------------------------------------------------------------------------------------------
# MJCF generation
# ------------------------------------------------------------------------------------------------


def _num(*values: float) -> str:
    """Numbers in the shortest text that round-trips exactly (so the model has the config's values)."""
    return " ".join(repr(float(v)) for v in values)


def _quat_z(angle: float) -> tuple[float, ...]:
    return (math.cos(angle / 2.0), 0.0, 0.0, math.sin(angle / 2.0))


def _quat_y(angle: float) -> tuple[float, ...]:
    return (math.cos(angle / 2.0), 0.0, math.sin(angle / 2.0), 0.0)


def forearm_home_tilt(geometry: DeltaGeometry) -> float:
    """Angle (rad) of the forearms from the vertical, inward about t_i, at home (theta = 0)."""
    z_home = -math.sqrt(geometry.l2**2 - (geometry.r + geometry.l1) ** 2)
    return math.atan2(geometry.r + geometry.l1, -z_home)


def ideal_upper_arm_inertial(geometry: DeltaGeometry, masses: DeltaMasses) -> tuple[float, float, float]:
    """Mass (kg), CoM distance from the motor axis (m) and inertia about the CoM (kg m^2) of the ideal arm.

    The arm carries m1 (homogeneous rod) plus the elbow half m2 of its forearm pair, so that the gravity
    torque is -(m1/2 + m2) g l1 cos(theta) and the inertia about the motor axis is (m1/3 + m2) l1^2.
    """
    mass = masses.m1 + masses.m2
    com = (masses.m1 / 2.0 + masses.m2) * geometry.l1 / mass
    inertia_about_com = (masses.m1 / 3.0 + masses.m2) * geometry.l1**2 - mass * com**2
    return mass, com, inertia_about_com


def _attribute(value: object) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (tuple, list, np.ndarray)):
        return _num(*value)
    return _num(value)  # type: ignore[arg-type]


class _Mjcf:
    """MJCF text under construction, and the home-keyframe qpos in body order."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.home_qpos: list[float] = []
        self.depth = 0

    def comment(self, text: str) -> None:
        indent = "  " * self.depth
        wrapped = textwrap.wrap(text, width=100 - len(indent))
        wrapped[0] = f"<!-- {wrapped[0]}"
        wrapped[-1] = f"{wrapped[-1]} -->"
        self.lines.extend(indent + ("" if index == 0 else "     ") + line for index, line in enumerate(wrapped))

    def element(self, tag: str, **attributes: object) -> None:
        self.lines.append("  " * self.depth + f"<{tag}{self._format(attributes)}/>")

    def open(self, tag: str, **attributes: object) -> None:
        self.lines.append("  " * self.depth + f"<{tag}{self._format(attributes)}>")
        self.depth += 1

    def close(self, tag: str) -> None:
        self.depth -= 1
        self.lines.append("  " * self.depth + f"</{tag}>")

    @staticmethod
    def _format(attributes: dict[str, object]) -> str:
        # Python names for XML attributes: class_ -> class.
        return "".join(f' {key.rstrip("_")}="{_attribute(value)}"' for key, value in attributes.items())


def _chain_frame(alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """u_i (outward) and t_i = e_z x u_i (motor axis) of the chain at azimuth ``alpha``."""
    return np.array([math.cos(alpha), math.sin(alpha), 0.0]), np.array([-math.sin(alpha), math.cos(alpha), 0.0])


def _rods(config: PlantConfig) -> tuple[tuple[str, float], ...]:
    """(label, offset along t_i in m) of the forearm rods of one chain."""
    if config.variant == "ideal":
        return (("", 0.0),)
    return ((_ROD_LABELS[0], FOREARM_SPACING / 2.0), (_ROD_LABELS[1], -FOREARM_SPACING / 2.0))


def _write_platform(x: _Mjcf, config: PlantConfig) -> None:
    g, m = config.geometry, config.masses
    disc = (math.hypot(g.rb, FOREARM_SPACING / 2.0) + 0.015, _PLATFORM_THICKNESS / 2.0)
    x.comment("Moving platform; its origin is E0. simple=false: its mass changes at run time (oracle, DR).")
    x.open("body", name="platform", pos=(0.0, 0.0, config.home_height), simple="false")
    if config.variant == "ideal":
        x.comment("MKH: the platform only translates and is a point mass m0.")
        for axis_name, axis in (("x", (1, 0, 0)), ("y", (0, 1, 0)), ("z", (0, 0, 1))):
            x.element("joint", name=f"platform_{axis_name}", class_="platform_slide", axis=axis)
            x.home_qpos.append(0.0)
        x.element("inertial", pos=(0, 0, 0), mass=m.m0, diaginertia=(_POINT_INERTIA,) * 3)
        x.element("geom", name="platform_disc", class_="visual", type="cylinder", size=disc, material="platform")
    else:
        x.comment("Free joint: the parallelograms alone keep the platform level.")
        x.element("freejoint", name="platform")
        x.home_qpos.extend([0.0, 0.0, config.home_height, 1.0, 0.0, 0.0, 0.0])
        x.element("geom", name="platform_disc", type="cylinder", size=disc, mass=m.m0, material="platform")
    cup = (0.0, 0.0, -_PLATFORM_THICKNESS / 2.0, 0.0, 0.0, -SUCTION_CUP_OFFSET)
    x.element("geom", name="suction_cup", class_="visual", type="cylinder", fromto=cup, size=0.02, material="cup")
    x.element("site", name="suction_cup", pos=(0.0, 0.0, -SUCTION_CUP_OFFSET))
    for label, alpha in zip(CHAIN_LABELS, CHAIN_AZIMUTHS, strict=True):
        u, t = _chain_frame(alpha)
        for rod, offset in _rods(config):
            x.element("site", name=f"platform_{label}{rod}", pos=g.rb * u + offset * t)
    x.close("body")


def _write_upper_arm_inertia(x: _Mjcf, config: PlantConfig, label: str) -> None:
    g, m = config.geometry, config.masses
    parts = {
        "hub": ((0.0, -0.045, 0.0, 0.0, 0.045, 0.0), 0.05),
        "tube": ((0.12 * g.l1, 0.0, 0.0, 0.96 * g.l1, 0.0, 0.0), 0.025),
        "bar": ((g.l1, -FOREARM_SPACING / 2.0 - 0.015, 0.0, g.l1, FOREARM_SPACING / 2.0 + 0.015, 0.0), 0.018),
    }
    ideal = config.variant == "ideal"
    if ideal:
        mass, com, inertia = ideal_upper_arm_inertial(g, m)
        x.comment("MKH: rod m1 plus the elbow half m2 of the forearm pair, lumped exactly; the geoms are visual.")
        x.element("inertial", pos=(com, 0.0, 0.0), mass=mass, diaginertia=(_POINT_INERTIA, inertia, inertia))
    else:
        x.comment("Hub + tube + elbow bar: total m1, CoM and inertia unlike the MKH homogeneous rod.")
    for part, (fromto, radius) in parts.items():
        role = {"class_": "visual"} if ideal else {"mass": _UPPER_ARM_SPLIT[part] * m.m1}
        x.element(
            "geom",
            name=f"upper_arm_{label}_{part}",
            type="cylinder",
            fromto=fromto,
            size=radius,
            material="arm",
            **role,
        )


def _write_chain(x: _Mjcf, config: PlantConfig, index: int) -> None:
    g, m, realism = config.geometry, config.masses, config.realism
    label, alpha = CHAIN_LABELS[index], float(CHAIN_AZIMUTHS[index])
    u, _ = _chain_frame(alpha)
    x.comment(f"Chain {label}: local x = u_{label} (outward), y = t_{label} (motor axis), z up.")
    x.open("body", name=f"upper_arm_{label}", pos=g.ra * u, quat=_quat_z(alpha))
    x.element(
        "joint",
        name=f"motor_{label}",
        class_="motor",
        damping=realism.viscous_per_joint[index],
        frictionloss=realism.coulomb_per_joint[index],
    )
    x.home_qpos.append(0.0)
    x.element(
        "geom",
        name=f"motor_{label}_housing",
        class_="visual",
        type="cylinder",
        fromto=(0, -0.08, 0, 0, 0.08, 0),
        size=0.07,
        material="base",
    )
    _write_upper_arm_inertia(x, config, label)
    for rod, offset in _rods(config):
        name = f"{label}{rod}"
        x.open("body", name=f"forearm_{name}", pos=(g.l1, offset, 0.0), quat=_quat_y(forearm_home_tilt(g)))
        x.element("joint", name=f"elbow_{name}_pitch", class_="elbow", axis=(0, 1, 0))
        x.element("joint", name=f"elbow_{name}_roll", class_="elbow", axis=(1, 0, 0))
        x.home_qpos.extend([0.0, 0.0])
        rod_line = (0.0, 0.0, 0.0, 0.0, 0.0, -g.l2)
        if config.variant == "ideal":
            x.comment("MKH: the platform half m2 of the pair, a point at the lower end; the geom is visual.")
            x.element("inertial", pos=(0.0, 0.0, -g.l2), mass=m.m2, diaginertia=(_POINT_INERTIA,) * 3)
        role = {"class_": "visual"} if config.variant == "ideal" else {"mass": m.m2}
        x.element(
            "geom",
            name=f"forearm_{name}_rod",
            type="cylinder",
            fromto=rod_line,
            size=_FOREARM_ROD_RADIUS,
            material="rod",
            **role,
        )
        x.element("site", name=f"forearm_{name}_end", pos=(0.0, 0.0, -g.l2))
        x.close("body")
    x.close("body")


def _write_payload(x: _Mjcf, config: PlantConfig) -> None:
    half = np.asarray(DEFAULT_PAYLOAD_SIZE) / 2.0
    position = (0.0, 0.0, config.home_height - SUCTION_CUP_OFFSET - half[2])
    x.comment(
        "Pick-and-place object, mass and size set at run time (DeltaPlant.place_payload). gravcomp=1 "
        "floats it where it is put while not carried (0 while carried); simple=false lets its mass change."
    )
    x.open("body", name="payload", pos=position, gravcomp=1.0, simple="false")
    x.element("freejoint", name="payload")
    x.element("geom", name="payload_box", type="box", size=half, mass=1.0, material="payload")
    x.close("body")
    x.home_qpos.extend([*position, 1.0, 0.0, 0.0, 0.0])


def _write_header(x: _Mjcf, config: PlantConfig) -> None:
    dt, realism = config.timestep, config.realism
    x.element("compiler", angle="radian", autolimits="true")
    x.comment(
        "timestep 0.5 ms with implicitfast: with the stiffest safe loop closures below the loop gap stays "
        "below 1e-5 m in a 6 g cycle with 3.8 kg (at 1 ms it is ~3e-5 m; DESIGN.md section 4). Dense "
        "Jacobians: MuJoCo 4.0.0's sparse Cholesky gave the Newton solver wrong factors (#3767, fixed in 4.0.1)."
    )
    x.element(
        "option",
        timestep=dt,
        integrator="implicitfast",
        gravity=(0.0, 0.0, -GRAVITY),
        solver="Newton",
        jacobian="dense",
    )
    x.open("visual")
    x.element("global", offwidth="1280", offheight="720")
    x.close("visual")
    x.open("default")
    x.comment(
        "Loop closures: solref timeconst = 2 x timestep is the refsafe minimum (the stiffest stable "
        "closure), solimp 0.9999 makes them nearly hard. MuJoCo's defaults open the loops by ~8 mm."
    )
    x.element("equality", solref=(2.0 * dt, 1.0), solimp=(0.9999, 0.9999, 0.001, 0.5, 2.0))
    x.comment("No contacts anywhere: robot parts and the payload pass through each other.")
    x.element("geom", contype="0", conaffinity="0", group="1")
    x.element("site", size="0.008", group="4", rgba="1 0.3 0.1 1")
    x.open("default", class_="motor")
    x.comment(
        "Coulomb friction (frictionloss) is a constraint too: at MuJoCo's default solref (20 ms) it acts as a "
        "stiff viscous term below ~1 rad/s and even reverses while a joint brakes; the refsafe minimum "
        "2 x timestep makes it behave like Coulomb friction down to ~0.1 rad/s."
    )
    x.element("joint", type="hinge", axis=(0, 1, 0), armature=realism.armature, solreffriction=(2.0 * dt, 1.0))
    x.close("default")
    x.open("default", class_="elbow")
    x.element("joint", type="hinge")
    x.close("default")
    x.open("default", class_="platform_slide")
    x.element("joint", type="slide")
    x.close("default")
    x.open("default", class_="visual")
    x.element("geom", group="2", mass="0")
    x.close("default")
    x.close("default")
    x.open("asset")
    x.element(
        "texture",
        name="grid",
        type="2d",
        builtin="checker",
        width="512",
        height="512",
        rgb1=(0.25, 0.27, 0.3),
        rgb2=(0.3, 0.32, 0.35),
    )
    x.element("material", name="floor", texture="grid", texrepeat="8 8", reflectance="0.1")
    for name, rgba in _MATERIALS.items():
        x.element("material", name=name, rgba=rgba)
    x.close("asset")


def _write_constraints_and_actuators(x: _Mjcf, config: PlantConfig) -> None:
    x.open("equality")
    x.comment("Loop closures: a ball joint between each forearm end and its platform point.")
    for label in CHAIN_LABELS:
        for rod, _ in _rods(config):
            x.element(
                "connect", name=f"loop_{label}{rod}", site1=f"forearm_{label}{rod}_end", site2=f"platform_{label}{rod}"
            )
    if config.payload_body:
        x.comment("Suction gripper: DeltaPlant.attach_payload sets relpose to the pose at the pick.")
        x.element(
            "weld", name="suction", body1="platform", body2="payload", active="false", relpose=(0, 0, 0, 1, 0, 0, 0)
        )
    x.close("equality")
    x.open("actuator")
    lag = config.realism.actuator_lag
    if lag > 0.0:
        x.comment(
            "Current loop: first-order lag integrated exactly (filterexact), accurate for lags down to one "
            "timestep; the joint torque is the filtered command."
        )
        dynamics = {"dyntype": "filterexact", "dynprm": lag}
    else:
        dynamics = {"dyntype": "none"}
    for label in CHAIN_LABELS:
        x.element(
            "general",
            name=f"motor_{label}",
            joint=f"motor_{label}",
            **dynamics,
            gaintype="fixed",
            gainprm=1.0,
            biastype="none",
            ctrllimited="true",
            ctrlrange=(-TORQUE_LIMIT, TORQUE_LIMIT),
        )
    x.close("actuator")


def build_mjcf(config: PlantConfig) -> str:
    """MJCF text of the plant described by ``config`` (Menagerie style, every element named).

    The model's reference configuration qpos0 is the assembled home pose (arms horizontal, loops closed,
    payload hanging under the suction cup), which the ``home`` keyframe repeats explicitly.
    """
    if not isinstance(config, PlantConfig):
        raise ValueError(f"config must be a PlantConfig, got {type(config).__name__}")
    x = _Mjcf()
    x.open("mujoco", model=f"delta_{config.variant}")
    x.comment("Generated by delta_env.model.build_mjcf: edit the PlantConfig, not this text.")
    _write_header(x, config)
    x.open("worldbody")
    x.element("light", name="key", pos=(0, -1, 2), dir=(0, 0.4, -1), directional="true")
    camera = np.array([2.2, -2.2, 0.4])
    forward = np.array([0.0, 0.0, -0.7]) - camera
    right = np.cross(forward, [0.0, 0.0, 1.0])
    up = np.cross(right, forward)
    x.element("camera", name="overview", pos=camera, xyaxes=(*right / np.linalg.norm(right), *up / np.linalg.norm(up)))
    x.element("geom", name="floor", type="plane", pos=(0.0, 0.0, _FLOOR_HEIGHT), size=(2, 2, 0.05), material="floor")
    x.element(
        "geom",
        name="base_plate",
        type="cylinder",
        pos=(0, 0, 0.06),
        size=(config.geometry.ra + 0.12, 0.02),
        material="base",
    )
    _write_platform(x, config)
    for index in range(3):
        _write_chain(x, config, index)
    if config.payload_body:
        _write_payload(x, config)
    x.close("worldbody")
    _write_constraints_and_actuators(x, config)
    x.open("keyframe")
    x.comment("Arms horizontal, loops closed, at rest (the same as qpos0).")
    x.element("key", name="home", qpos=x.home_qpos)
    x.close("keyframe")
    x.close("mujoco")
    return "\n".join(x.lines) + "\n"


# ------------------------------------------------------------------------------------------------
# Physics wrapper
# ------------------------------------------------------------------------------------------------


def _quat_conjugate(quat: NDArray[np.float64]) -> NDArray[np.float64]:
    return quat * np.array([1.0, -1.0, -1.0, -1.0])


def _quat_multiply(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    result = np.empty(4)
    mujoco.mju_mulQuat(result, a, b)
    return result


def _quat_to_matrix(quat: NDArray[np.float64]) -> NDArray[np.float64]:
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, quat)
    return matrix.reshape(3, 3)


class DeltaPlant:
    """MuJoCo model and data of the Delta, with named access and the 1 kHz stepping hot path.

    Every id and address is cached once here (dm_control style); the env and the oracle read and write
    MuJoCo state only through this class. Freshness of the measurements after :meth:`step`:

    - ``joint_angles``, ``joint_velocities``, ``platform_position``, ``payload_position`` read qpos/qvel:
      always current.
    - ``loop_gap`` reads ``site_xpos``, which ``mj_step`` computes before integrating: after
      :meth:`step` it is one physics step (``timestep``) stale unless ``refresh=True``.

    Attributes:
        config: The configuration the model was built from.
        xml: The generated MJCF text.
        model: ``mujoco.MjModel``.
        data: ``mujoco.MjData``.
    """

    def __init__(self, config: PlantConfig | None = None) -> None:
        self.config = PlantConfig() if config is None else config
        self.xml = build_mjcf(self.config)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)  # mj_setConst overwrites the state of the data it gets
        model, data = self.model, self.data

        def ident(kind: mujoco.mjtObj, name: str) -> int:
            return mujoco.mj_name2id(model, kind, name)

        joint, body, site = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_SITE
        motor_joints = [ident(joint, f"motor_{label}") for label in CHAIN_LABELS]
        self._motor_qpos = model.jnt_qposadr[motor_joints].copy()
        self._motor_dofs = model.jnt_dofadr[motor_joints].copy()
        self._platform_body = ident(body, "platform")
        first_platform_joint = model.body_jntadr[self._platform_body]
        self._platform_qpos = int(model.jnt_qposadr[first_platform_joint])
        self._platform_dof = int(model.jnt_dofadr[first_platform_joint])
        self._platform_free = self.config.variant == "realistic"
        # Ideal: slides measure the displacement from the body's home position.
        self._platform_offset = np.zeros(3) if self._platform_free else model.body_pos[self._platform_body].copy()

        rods = [""] if self.config.variant == "ideal" else list(_ROD_LABELS)
        self._loop_sites = np.array(
            [
                (ident(site, f"forearm_{label}{rod}_end"), ident(site, f"platform_{label}{rod}"))
                for label in CHAIN_LABELS
                for rod in rods
            ]
        )
        self._loop_bodies = model.site_bodyid[self._loop_sites]
        self._elbow_qpos = np.array(
            [
                [model.jnt_qposadr[ident(joint, f"elbow_{label}{rod}_{axis}")] for axis in ("pitch", "roll")]
                for label in CHAIN_LABELS
                for rod in rods
            ]
        )
        self._rods_per_chain = len(rods)
        self._tilt = forearm_home_tilt(self.config.geometry)
        self._cos_alpha, self._sin_alpha = np.cos(CHAIN_AZIMUTHS), np.sin(CHAIN_AZIMUTHS)

        # Degrees of freedom of the robot (the payload's free joint excluded), split into motors and the
        # passive ones that assemble() solves for.
        self._payload_body = ident(body, "payload") if self.config.payload_body else -1
        robot_dofs = np.array([dof for dof in range(model.nv) if model.dof_bodyid[dof] != self._payload_body])
        self._passive_dofs = np.setdiff1d(robot_dofs, self._motor_dofs)
        n_rows = 3 * len(self._loop_sites)
        if n_rows != len(self._passive_dofs):
            raise RuntimeError(f"model has {n_rows} loop rows for {len(self._passive_dofs)} passive dofs")
        self._jac_a = np.zeros((3, model.nv))
        self._jac_b = np.zeros((3, model.nv))
        self._loop_jac = np.zeros((n_rows, model.nv))
        self._loop_jac_dot = np.zeros((n_rows, model.nv))

        if self.config.payload_body:
            self._payload_qpos = int(model.jnt_qposadr[model.body_jntadr[self._payload_body]])
            self._payload_dof = int(model.jnt_dofadr[model.body_jntadr[self._payload_body]])
            self._payload_geom = int(model.body_geomadr[self._payload_body])
            self._suction = ident(mujoco.mjtObj.mjOBJ_EQUALITY, "suction")

        # Domain-randomizable parameters: the nominal ones come from the config.
        self._robot_bodies = np.array([b for b in range(1, model.nbody) if b != self._payload_body])
        self._has_lag = self.config.realism.actuator_lag > 0.0
        self._parameters = self.nominal_parameters
        self._set_disturbance_coefficients(self.config.realism)

        # Views into mjData for the hot path (the buffers never move).
        self._qpos, self._qvel = data.qpos, data.qvel
        self._ctrl, self._qfrc_applied = data.ctrl, data.qfrc_applied
        self._loop_points = [(data.site_xpos[a], data.site_xpos[b]) for a, b in self._loop_sites]
        self.reset()

    # --------------------------------------------------------------------------------------------
    # State
    # --------------------------------------------------------------------------------------------

    @property
    def n_loop_rows(self) -> int:
        """Number of loop-closure constraint rows (3 per connect)."""
        return 3 * len(self._loop_sites)

    @property
    def motor_dofs(self) -> NDArray[np.int_]:
        """Addresses of the three motor joints in qvel (read-only copy), shape (3,)."""
        return self._motor_dofs.copy()

    @property
    def motor_qpos_addresses(self) -> NDArray[np.int_]:
        """Addresses of the three motor joints in qpos (read-only copy), shape (3,)."""
        return self._motor_qpos.copy()

    def reset(self, theta: ArrayLike | None = None) -> None:
        """Reset the data (time 0, no forces), detach and float the payload, and assemble at ``theta``.

        Args:
            theta: Motor angles (rad), shape (3,); home (arms horizontal) when None.
        """
        mujoco.mj_resetData(self.model, self.data)
        if self.config.payload_body:
            self.model.body_gravcomp[self._payload_body] = 1.0
        self.assemble(np.zeros(3) if theta is None else theta)

    def assemble(self, theta: ArrayLike, theta_dot: ArrayLike | None = None) -> None:
        """Put the robot at motor angles ``theta`` with every loop closed, moving at ``theta_dot``.

        Positions are analytic (:meth:`assembly_coordinates`), so the loops close to round-off; velocities
        solve J_c qvel = 0 with the motor rates fixed. A carried payload follows the platform rigidly; a
        free one is left where it is. Actuator states are zeroed and ``mj_forward`` brings every derived
        quantity up to date.

        Args:
            theta: Motor angles (rad), shape (3,).
            theta_dot: Motor rates (rad/s), shape (3,); zero when None.

        Raises:
            ValueError: if the angles are not finite or the forearms cannot reach a common point.
        """
        theta = _joint_vector("theta", theta)
        theta_dot = np.zeros(3) if theta_dot is None else _joint_vector("theta_dot", theta_dot)
        platform, elbows = self.assembly_coordinates(theta)
        self._assemble(theta, theta_dot, platform, elbows)

    def assembly_coordinates(self, theta: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Platform position (m) and elbow (pitch, roll) angles (rad) that close every loop at ``theta``.

        Vectorized over a leading batch shape: ``theta`` (..., 3) gives (..., 3) and (..., 3 chains, 2).
        The platform is the forward kinematics; both rods of a parallelogram are parallel to x - J'_i.

        Raises:
            ValueError: if the forearms cannot reach a common point, or one would lie along its motor axis.
        """
        theta = np.asarray(theta, dtype=float)
        g = self.config.geometry
        xyz = kinematics.forward(g, theta)
        direction = (xyz[..., None, :] - kinematics.elbow_points(g, theta)) / g.l2
        # In the arm frame (x = u_i, y = t_i), then in the forearm body's frame at zero elbow angles,
        # which is the arm frame turned by R_y(theta + tilt); there the rod points along -z and the two
        # hinges give the direction (-sin p cos r, sin r, -cos p cos r).
        radial = direction[..., 0] * self._cos_alpha + direction[..., 1] * self._sin_alpha
        tangential = -direction[..., 0] * self._sin_alpha + direction[..., 1] * self._cos_alpha
        turn = theta + self._tilt
        local_x = np.cos(turn) * radial - np.sin(turn) * direction[..., 2]
        local_z = np.sin(turn) * radial + np.cos(turn) * direction[..., 2]
        if np.any(np.abs(tangential) >= 1.0 - 1e-9):
            raise ValueError(f"theta={theta.tolist()} puts a forearm along its motor axis (gimbal lock)")
        elbows = np.stack((np.arctan2(-local_x, -local_z), np.arcsin(tangential)), axis=-1)
        return xyz, elbows

    def _assemble(self, theta: NDArray, theta_dot: NDArray, platform: NDArray, elbows: NDArray) -> NDArray[np.float64]:
        """Write a configuration from :meth:`assembly_coordinates` and solve the velocities (no checks).

        Returns the loop Jacobian at the new configuration (the buffer of :meth:`loop_jacobian`).
        """
        model, data = self.model, self.data
        data.qpos[self._motor_qpos] = theta
        if self._platform_free:
            data.qpos[self._platform_qpos : self._platform_qpos + 7] = [*platform, 1.0, 0.0, 0.0, 0.0]
        else:
            data.qpos[self._platform_qpos : self._platform_qpos + 3] = platform - self._platform_offset
        data.qpos[self._elbow_qpos] = np.repeat(elbows, self._rods_per_chain, axis=0)
        carried = self.payload_attached
        if carried:
            self._put_payload_on_platform()
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jac = self.loop_jacobian()
        data.qvel[self._motor_dofs] = theta_dot
        data.qvel[self._passive_dofs] = np.linalg.solve(
            jac[:, self._passive_dofs], -jac[:, self._motor_dofs] @ theta_dot
        )
        if carried:
            self._match_payload_velocity()
        if model.na:
            data.act[:] = 0.0
        mujoco.mj_forward(model, data)
        return jac

    def loop_jacobian(self) -> NDArray[np.float64]:
        """Jacobian (n_loop_rows, nv) of the loop residuals (forearm end minus platform point, m).

        Uses the current ``site_xpos`` and ``cdof``: call after ``mj_kinematics`` and ``mj_comPos``
        (``mj_forward`` does both). The returned array is reused by the next call.
        """
        for k, (rod_site, platform_site) in enumerate(self._loop_sites):
            mujoco.mj_jacSite(self.model, self.data, self._jac_a, None, rod_site)
            mujoco.mj_jacSite(self.model, self.data, self._jac_b, None, platform_site)
            np.subtract(self._jac_a, self._jac_b, out=self._loop_jac[3 * k : 3 * k + 3])
        return self._loop_jac

    def loop_bias_acceleration(self) -> NDArray[np.float64]:
        """Jdot_c qvel (m/s^2) of the loop residuals, shape (n_loop_rows,), from ``mj_jacDot``.

        Needs the velocity stage (``cvel``, ``cdof_dot``) of the current state: call after ``mj_forward``.
        """
        model, data = self.model, self.data
        for k, ((rod_site, platform_site), (rod_body, platform_body)) in enumerate(
            zip(self._loop_sites, self._loop_bodies, strict=True)
        ):
            mujoco.mj_jacDot(model, data, self._jac_a, None, data.site_xpos[rod_site], rod_body)
            mujoco.mj_jacDot(model, data, self._jac_b, None, data.site_xpos[platform_site], platform_body)
            np.subtract(self._jac_a, self._jac_b, out=self._loop_jac_dot[3 * k : 3 * k + 3])
        return self._loop_jac_dot @ data.qvel

    def joint_angles(self) -> NDArray[np.float64]:
        """Motor angles theta (rad), shape (3,); current."""
        return self._qpos[self._motor_qpos]

    def joint_velocities(self) -> NDArray[np.float64]:
        """Motor rates theta_dot (rad/s), shape (3,); current."""
        return self._qvel[self._motor_dofs]

    def platform_position(self) -> NDArray[np.float64]:
        """Platform centre E0 (m), shape (3,), from qpos; current."""
        return self._qpos[self._platform_qpos : self._platform_qpos + 3] + self._platform_offset

    def loop_gap(self, refresh: bool = False) -> float:
        """Largest distance (m) between the two points of any loop-closure connect.

        Args:
            refresh: Recompute the kinematics first (``mj_kinematics``, a few microseconds). Without it
                the value is that of ``site_xpos``: after :meth:`step`, the state one physics step ago.
        """
        if refresh:
            mujoco.mj_kinematics(self.model, self.data)
        # Python floats: one exit from NumPy, then six distances in scalar math (a third of mju_dist3 calls).
        positions = self.data.site_xpos.tolist()
        largest = 0.0  # squared; a NaN distance fails the comparison as before
        for rod_end, platform_point in self._loop_sites.tolist():
            (x1, y1, z1), (x2, y2, z2) = positions[rod_end], positions[platform_point]
            dx, dy, dz = x1 - x2, y1 - y2, z1 - z2
            squared = dx * dx + dy * dy + dz * dz
            if squared > largest:
                largest = squared
        return math.sqrt(largest)

    # --------------------------------------------------------------------------------------------
    # Stepping (1 kHz hot path)
    # --------------------------------------------------------------------------------------------

    def motor_disturbance(self, theta: NDArray[np.float64], theta_dot: NDArray[np.float64]) -> NDArray:
        """Stribeck excess and torque ripple (N m) on the motor joints, shape (3,).

        Stribeck: -excess * fc_i * exp(-(v / v_s)^2) * tanh(4 v / v_s); the tanh is a smooth sign whose
        slope at zero speed (4 excess fc_i / v_s, 160 N m s/rad by default) stays well inside the explicit
        stability limit of a 1 kHz zero-order hold, so it does not chatter. Ripple:
        amplitude * sin(periods * theta). Accepts any leading batch shape ``(..., 3)``.
        """
        v = np.asarray(theta_dot) * self._inv_stribeck_velocity
        ripple = self._ripple_amplitude * np.sin(self._ripple_periods * np.asarray(theta))
        return ripple - self._stribeck_gain * np.exp(-v * v) * np.tanh(v * _STRIBECK_SIGN_SLOPE)

    def step(self, torque_command: NDArray[np.float64], n_substeps: int) -> None:
        """Command motor torques (N m, shape (3,)) and advance ``n_substeps`` physics steps.

        MuJoCo clips the command to +-TORQUE_LIMIT and passes it through the current-loop lag, if any.
        Stribeck excess and ripple (:meth:`motor_disturbance`) are computed once from the state at the call
        and held over the substeps (zero-order hold, like a drive's 1 kHz torque update); this method owns
        ``qfrc_applied`` on the motor dofs. No input validation: this is the 1 kHz hot path, so the
        disturbance is written out with scalar math (a third of the cost of the NumPy form).
        """
        self._ctrl[:] = torque_command
        if self._has_disturbance:
            qpos, qvel, applied = self._qpos, self._qvel, self._qfrc_applied
            amplitude, periods = self._ripple_amplitude, self._ripple_periods
            for qpos_address, dof, gain in self._disturbance_terms:
                v = qvel.item(dof) * self._inv_stribeck_velocity
                ripple = amplitude * math.sin(periods * qpos.item(qpos_address))
                applied[dof] = ripple - gain * math.exp(-v * v) * math.tanh(v * _STRIBECK_SIGN_SLOPE)
        mujoco.mj_step(self.model, self.data, n_substeps)

    # --------------------------------------------------------------------------------------------
    # Payload
    # --------------------------------------------------------------------------------------------

    def _require_payload(self) -> None:
        if not self.config.payload_body:
            raise RuntimeError("this plant was built with payload_body=False")

    @property
    def payload_attached(self) -> bool:
        """True while the suction weld holds the payload (False without a payload body)."""
        return self.config.payload_body and bool(self.data.eq_active[self._suction])

    @property
    def payload_mass(self) -> float:
        """Simulated payload mass (kg); at least MIN_PAYLOAD_MASS."""
        self._require_payload()
        return float(self.model.body_mass[self._payload_body])

    def payload_position(self) -> NDArray[np.float64]:
        """Centre of the payload box (m), shape (3,), from qpos; current."""
        self._require_payload()
        return self._qpos[self._payload_qpos : self._payload_qpos + 3].copy()

    def suction_cup_position(self) -> NDArray[np.float64]:
        """Suction cup face (m), SUCTION_CUP_OFFSET below E0 (the platform stays level), shape (3,)."""
        return self.platform_position() - np.array([0.0, 0.0, SUCTION_CUP_OFFSET])

    def place_payload(self, position: ArrayLike, mass: float, size: ArrayLike = DEFAULT_PAYLOAD_SIZE) -> None:
        """Teleport the (released) payload to ``position`` at rest, with a new mass and box size.

        The box gets the homogeneous inertia of its size; gravity compensation makes it float there.

        Args:
            position: Centre of the box (m), shape (3,).
            mass: Payload mass (kg) in [0, MAX_PAYLOAD_MASS]; simulated as at least MIN_PAYLOAD_MASS.
            size: Edge lengths of the box (m), shape (3,), each in (0, 1].

        Raises:
            ValueError: for a bad position, mass or size. RuntimeError: while the payload is attached.
        """
        self._require_payload()
        if self.payload_attached:
            raise RuntimeError("release the payload before placing it")
        position = _joint_vector("position", position)
        _require_finite_in("mass", float(mass), 0.0, MAX_PAYLOAD_MASS)
        size = _joint_vector("size", size)
        for index, edge in enumerate(size):
            _require_finite_in(f"size[{index}]", float(edge), 0.0, 1.0, low_open=True)
        model, data = self.model, self.data
        simulated_mass = max(float(mass), MIN_PAYLOAD_MASS)
        model.body_mass[self._payload_body] = simulated_mass
        squares = size**2
        model.body_inertia[self._payload_body] = simulated_mass / 12.0 * (squares.sum() - squares)
        model.geom_size[self._payload_geom] = size / 2.0
        model.geom_rbound[self._payload_geom] = float(np.linalg.norm(size / 2.0))
        model.body_gravcomp[self._payload_body] = 1.0
        self._set_const()
        data.qpos[self._payload_qpos : self._payload_qpos + 7] = [*position, 1.0, 0.0, 0.0, 0.0]
        data.qvel[self._payload_dof : self._payload_dof + 6] = 0.0
        mujoco.mj_forward(model, data)

    def attach_payload(self) -> None:
        """Activate the suction weld at the current relative pose; gravity compensation off.

        The payload takes the platform's velocity (a suction pick is a short impulse the weld would
        otherwise deliver in one constraint time constant).
        """
        self._require_payload()
        platform_position, platform_quat = self._platform_pose()
        payload_position = self._qpos[self._payload_qpos : self._payload_qpos + 3]
        payload_quat = self._qpos[self._payload_qpos + 3 : self._payload_qpos + 7]
        relative_position = _quat_to_matrix(platform_quat).T @ (payload_position - platform_position)
        relative_quat = _quat_multiply(_quat_conjugate(platform_quat), payload_quat)
        eq_data = self.model.eq_data[self._suction]
        eq_data[0:3] = 0.0  # anchor: the payload's origin, in the payload frame
        eq_data[3:6] = relative_position  # where that anchor sits in the platform frame
        eq_data[6:10] = relative_quat
        self.data.eq_active[self._suction] = 1
        self.model.body_gravcomp[self._payload_body] = 0.0
        self._match_payload_velocity()

    def release_payload(self) -> None:
        """Deactivate the suction weld; the payload stops and floats where it is (gravcomp on)."""
        self._require_payload()
        self.data.eq_active[self._suction] = 0
        self.model.body_gravcomp[self._payload_body] = 1.0
        self._qvel[self._payload_dof : self._payload_dof + 6] = 0.0

    def _platform_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if self._platform_free:
            quat = self._qpos[self._platform_qpos + 3 : self._platform_qpos + 7].copy()
            return self.platform_position(), quat / np.linalg.norm(quat)
        return self.platform_position(), np.array([1.0, 0.0, 0.0, 0.0])

    def _put_payload_on_platform(self) -> None:
        platform_position, platform_quat = self._platform_pose()
        eq_data = self.model.eq_data[self._suction]
        position = platform_position + _quat_to_matrix(platform_quat) @ eq_data[3:6]
        quat = _quat_multiply(platform_quat, eq_data[6:10])
        self._qpos[self._payload_qpos : self._payload_qpos + 7] = [*position, *quat]

    def _match_payload_velocity(self) -> None:
        """Give the payload the rigid-body velocity of the platform at its position."""
        platform_position, platform_quat = self._platform_pose()
        if self._platform_free:
            linear = self._qvel[self._platform_dof : self._platform_dof + 3]
            angular = _quat_to_matrix(platform_quat) @ self._qvel[self._platform_dof + 3 : self._platform_dof + 6]
        else:
            linear = self._qvel[self._platform_dof : self._platform_dof + 3]
            angular = np.zeros(3)
        payload_position = self._qpos[self._payload_qpos : self._payload_qpos + 3]
        payload_quat = self._qpos[self._payload_qpos + 3 : self._payload_qpos + 7]
        velocity = linear + np.cross(angular, payload_position - platform_position)
        self._qvel[self._payload_dof : self._payload_dof + 3] = velocity
        self._qvel[self._payload_dof + 3 : self._payload_dof + 6] = _quat_to_matrix(payload_quat).T @ angular

    # --------------------------------------------------------------------------------------------
    # Domain randomization: every per-episode model edit happens here
    # --------------------------------------------------------------------------------------------

    @property
    def nominal_parameters(self) -> PhysicalParameters:
        """The parameters of ``config`` (what :meth:`restore_nominal` sets)."""
        return PhysicalParameters(masses=self.config.masses, actuator_lag=self.config.realism.actuator_lag)

    @property
    def parameters(self) -> PhysicalParameters:
        """The parameters the model currently has."""
        return self._parameters

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """Edit masses, friction and lag of the model in place (the state is kept).

        The new inertial properties come from compiling the MJCF of the modified config, so they are
        exactly what :func:`build_mjcf` would give; derived constants are refreshed with ``mj_setConst``.
        Takes a few milliseconds: call it between episodes.

        Raises:
            ValueError: for a lag on a plant built without one (or the reverse).
        """
        if not isinstance(parameters, PhysicalParameters):
            raise ValueError(f"parameters must be PhysicalParameters, got {type(parameters).__name__}")
        if (parameters.actuator_lag > 0.0) != self._has_lag:
            raise ValueError(
                f"actuator_lag must be {'> 0' if self._has_lag else '0'} for this plant "
                f"(built with actuator_lag={self.config.realism.actuator_lag}), got {parameters.actuator_lag}"
            )
        nominal = self.config.realism
        scale = np.asarray(parameters.friction_scale)
        realism = replace(
            nominal,
            viscous_scale=tuple(float(v) for v in np.asarray(nominal.viscous_scale) * scale),
            coulomb_scale=tuple(float(v) for v in np.asarray(nominal.coulomb_scale) * scale),
            actuator_lag=parameters.actuator_lag,
        )
        edited = mujoco.MjModel.from_xml_string(
            build_mjcf(replace(self.config, masses=parameters.masses, realism=realism))
        )
        model, bodies = self.model, self._robot_bodies
        for name in ("body_mass", "body_inertia", "body_ipos", "body_iquat"):
            getattr(model, name)[bodies] = getattr(edited, name)[bodies]
        for name in ("dof_damping", "dof_frictionloss", "dof_armature"):
            getattr(model, name)[self._motor_dofs] = getattr(edited, name)[self._motor_dofs]
        model.actuator_dynprm[:] = edited.actuator_dynprm
        self._set_const()
        self._set_disturbance_coefficients(realism)
        self._parameters = parameters

    def randomize(self, rng: np.random.Generator, ranges: RandomizationRanges | None = None) -> PhysicalParameters:
        """Draw and set new physical parameters (DESIGN.md section 4 ranges by default); returns them."""
        ranges = RandomizationRanges() if ranges is None else ranges
        nominal = self.config.masses

        def draw(fraction: float, size: int | None = None) -> NDArray[np.float64]:
            return rng.uniform(1.0 - fraction, 1.0 + fraction, size)

        m1, m2, m0 = (nominal.m1, nominal.m2, nominal.m0) * draw(ranges.mass_fraction, 3)
        lag = self.config.realism.actuator_lag
        if ranges.actuator_lag is not None:
            if not self._has_lag:
                raise ValueError("this plant has no actuator lag to randomize: use actuator_lag=None")
            lag = float(rng.uniform(*ranges.actuator_lag))
        parameters = PhysicalParameters(
            masses=DeltaMasses(m1=float(m1), m2=float(m2), m0=float(m0)),
            friction_scale=tuple(float(v) for v in draw(ranges.friction_fraction, 3)),
            actuator_lag=lag,
        )
        self.set_physical_parameters(parameters)
        return parameters

    def restore_nominal(self) -> None:
        """Undo :meth:`randomize`: the parameters of ``config`` again."""
        self.set_physical_parameters(self.nominal_parameters)

    def _set_const(self) -> None:
        """Refresh the model constants derived from masses (mass matrix of simple bodies, constraint
        softness through body_invweight0) after an edit; about 20 us."""
        mujoco.mj_setConst(self.model, self._scratch)
        # mj_setConst derives flg_gravcomp from body_gravcomp, which is 0 while the payload is carried.
        self.model.flg_gravcomp = self.config.payload_body

    def _set_disturbance_coefficients(self, realism: PlantRealism) -> None:
        self._stribeck_gain = realism.stribeck_excess * realism.coulomb_per_joint
        self._inv_stribeck_velocity = 1.0 / realism.stribeck_velocity
        self._ripple_amplitude = realism.ripple_amplitude
        self._ripple_periods = float(realism.ripple_periods)
        self._has_disturbance = bool(np.any(self._stribeck_gain > 0.0) or realism.ripple_amplitude > 0.0)
        self._disturbance_terms = tuple(
            (int(address), int(dof), float(gain))
            for address, dof, gain in zip(self._motor_qpos, self._motor_dofs, self._stribeck_gain, strict=True)
        )


def _joint_vector(name: str, value: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(value, dtype=float)
    if array.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array.tolist()}")
    return array
