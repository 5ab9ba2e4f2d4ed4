"""How the masses and link sections of a Delta robot follow its geometry: one rule for the model and the plant.

A design study that changed lengths but kept the masses would make a longer arm free, and one that kept the
links' cross-sections (mass proportional to length) would make it cheap: its stiffness would fall like
1 / l^3 and nothing would notice. The rule keeps each link as stiff as the nominal one, with geometrically
similar tube sections (every diameter and wall of a section scaled by one factor s, so A ~ s^2, I ~ s^4):

- upper arm, a cantilever bent by the forearms' pull at its tip: its tip stiffness 3 E I / l1^3 stays the
  nominal one, so I ~ l1^3, s ~ l1^(3/4) and m1 = m1_nom * (l1 / l1_nom)^(5/2) (A l1 ~ l1^(3/2) l1);
- forearm rods, two-force members between ball joints: their axial stiffness E A / l2 stays the nominal one,
  so A ~ l2, s ~ l2^(1/2) and m2 = m2_nom * (l2 / l2_nom)^2; the Euler buckling load pi^2 E I / l2^2 ~ l2^2 / l2^2
  stays the nominal one too;
- platform: a gripper of fixed mass (:data:`GRIPPER_MASS`, suction cup and valve) plus a plate with the
  nominal mass per unit area, the plate spanning the platform radius:
  m0 = GRIPPER_MASS + (m0_nom - GRIPPER_MASS) * (rb / rb_nom)^2;
- the parts a link carries (the arm's hub and elbow bar, the rods' ball-joint cups) scale with it, a
  conservative simplification; motors, gearboxes and the base do not move, so they do not enter the dynamics.

The plant builds its tubes and rods with the scaled radii (:func:`upper_arm_tube_radius`,
:func:`forearm_rod_radius`), and both the analytical model (rod arms, I = (m1/3 + m2) l1^2) and the plant
compute inertias from these masses and lengths, so they follow the same rule. At the nominal lengths every
factor is 1: the nominal robot keeps its masses and sections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.validation import require_in, require_positive

GRIPPER_MASS = 0.3
"""Part of the nominal platform mass m0 (kg) that is the suction gripper, the same on every design."""

UPPER_ARM_MASS_EXPONENT = 2.5
"""m1 ~ l1^(5/2): constant tip stiffness with similar tube sections (module docstring)."""

FOREARM_MASS_EXPONENT = 2.0
"""m2 ~ l2^2: constant axial stiffness (and buckling load) with similar tube sections (module docstring)."""


@dataclass(frozen=True)
class TubeSection:
    """A round tube's cross-section and material.

    Attributes:
        outer_radius: Outer radius (m).
        inner_radius: Inner radius (m), in [0, outer_radius).
        modulus: Young's modulus E (Pa).
    """

    outer_radius: float
    inner_radius: float
    modulus: float

    def __post_init__(self) -> None:
        require_positive("outer_radius", self.outer_radius, "m")
        require_in("inner_radius", self.inner_radius, 0.0, self.outer_radius, unit="m", high_open=True)
        require_positive("modulus", self.modulus, "Pa")

    @property
    def area(self) -> float:
        """Cross-section area (m^2)."""
        return math.pi * (self.outer_radius**2 - self.inner_radius**2)

    @property
    def second_moment(self) -> float:
        """Second moment of area about a diameter (m^4)."""
        return math.pi / 4.0 * (self.outer_radius**4 - self.inner_radius**4)

    def scaled(self, factor: float) -> TubeSection:
        """The geometrically similar section with every radius times ``factor`` (> 0)."""
        require_positive("factor", factor)
        return TubeSection(self.outer_radius * factor, self.inner_radius * factor, self.modulus)


NOMINAL_UPPER_ARM_TUBE = TubeSection(outer_radius=0.025, inner_radius=0.016, modulus=70e9)
"""The nominal upper arm's tube: aluminium (E = 70 GPa), 50 mm outer diameter; the 16 mm inner radius gives the
tube share of m1 (1.0 kg over 0.84 l1 = 0.31 m, 2700 kg/m^3 -> 1.2e-3 m^2) rounded."""

NOMINAL_FOREARM_ROD = TubeSection(outer_radius=0.006, inner_radius=0.004, modulus=120e9)
"""The nominal forearm rod: a pultruded carbon-fibre tube 12/8 mm (E about 120 GPa along the fibres, assumed)."""


def upper_arm_section(l1: float, reference_l1: float = NOMINAL_GEOMETRY.l1) -> TubeSection:
    """The upper arm's tube section of an arm ``l1`` (m) long: the nominal one times (l1 / l1_nom)^(3/4)."""
    require_positive("l1", l1, "m")
    return NOMINAL_UPPER_ARM_TUBE.scaled((l1 / reference_l1) ** ((UPPER_ARM_MASS_EXPONENT - 1.0) / 2.0))


def forearm_section(l2: float, reference_l2: float = NOMINAL_GEOMETRY.l2) -> TubeSection:
    """The forearm rod's section of a rod ``l2`` (m) long: the nominal one times (l2 / l2_nom)^(1/2)."""
    require_positive("l2", l2, "m")
    return NOMINAL_FOREARM_ROD.scaled((l2 / reference_l2) ** ((FOREARM_MASS_EXPONENT - 1.0) / 2.0))


def upper_arm_tube_radius(l1: float) -> float:
    """Outer radius (m) of the plant's upper-arm tube for an arm ``l1`` (m) long."""
    return upper_arm_section(l1).outer_radius


def forearm_rod_radius(l2: float) -> float:
    """Outer radius (m) of the plant's forearm rods for rods ``l2`` (m) long."""
    return forearm_section(l2).outer_radius


def arm_tip_stiffness(l1: float) -> float:
    """Tip stiffness 3 E I / l1^3 (N/m) of the upper arm's tube, a cantilever ``l1`` (m) long."""
    section = upper_arm_section(l1)
    return 3.0 * section.modulus * section.second_moment / l1**3


def rod_axial_stiffness(l2: float) -> float:
    """Axial stiffness E A / l2 (N/m) of one forearm rod ``l2`` (m) long."""
    section = forearm_section(l2)
    return section.modulus * section.area / l2


def scaled_masses(
    geometry: DeltaGeometry,
    reference_geometry: DeltaGeometry = NOMINAL_GEOMETRY,
    reference_masses: DeltaMasses = NOMINAL_MASSES,
) -> DeltaMasses:
    """The masses (kg) of a robot with ``geometry`` built as stiff as the reference robot (module rule).

    Args:
        geometry: The design's lengths (m).
        reference_geometry: Lengths of the robot whose link stiffness and plate density are kept.
        reference_masses: Its masses; its platform must be heavier than :data:`GRIPPER_MASS`.

    Raises:
        ValueError: if the reference platform is not heavier than the gripper.
    """
    if reference_masses.m0 <= GRIPPER_MASS:
        raise ValueError(
            f"reference_masses.m0 must exceed the gripper mass {GRIPPER_MASS} kg, got {reference_masses.m0!r} kg"
        )
    plate = (reference_masses.m0 - GRIPPER_MASS) * (geometry.rb / reference_geometry.rb) ** 2
    return DeltaMasses(
        m1=reference_masses.m1 * (geometry.l1 / reference_geometry.l1) ** UPPER_ARM_MASS_EXPONENT,
        m2=reference_masses.m2 * (geometry.l2 / reference_geometry.l2) ** FOREARM_MASS_EXPONENT,
        m0=GRIPPER_MASS + plate,
    )
