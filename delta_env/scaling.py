"""How the masses of a Delta robot follow its geometry: one rule for the model and the plant.

A design study that changed lengths but kept the masses would make a longer arm free, and an optimizer
would exploit it. The rule, applied to the nominal robot of docs/design.md section 4:

- upper arm: the nominal mass per unit length, m1 = m1_nom * l1 / l1_nom;
- forearm pair: the nominal mass per unit length, m2 = m2_nom * l2 / l2_nom;
- platform: a gripper of fixed mass (:data:`GRIPPER_MASS`, suction cup and valve) plus a plate with the
  nominal mass per unit area, the plate spanning the platform radius:
  m0 = GRIPPER_MASS + (m0_nom - GRIPPER_MASS) * (rb / rb_nom)^2;
- motors, gearboxes and the base do not move, so they do not enter the dynamics; the reflected rotor
  inertia (armature) and the drive friction are properties of the drive and stay as they are.

Inertias are not scaled separately: both the analytical model (rod arms, I = (m1/3 + m2) l1^2) and the
MuJoCo plant (tubes, rods and a disc of the design's lengths) compute them from these masses and the
design's lengths, so they follow the same rule.
"""

from __future__ import annotations

from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses

GRIPPER_MASS = 0.3
"""Part of the nominal platform mass m0 (kg) that is the suction gripper, the same on every design."""


def scaled_masses(
    geometry: DeltaGeometry,
    reference_geometry: DeltaGeometry = NOMINAL_GEOMETRY,
    reference_masses: DeltaMasses = NOMINAL_MASSES,
) -> DeltaMasses:
    """The masses (kg) of a robot with ``geometry`` built like the reference robot (module rule).

    Args:
        geometry: The design's lengths (m).
        reference_geometry: Lengths of the robot whose link densities are kept.
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
        m1=reference_masses.m1 * geometry.l1 / reference_geometry.l1,
        m2=reference_masses.m2 * geometry.l2 / reference_geometry.l2,
        m0=GRIPPER_MASS + plate,
    )
