"""Delta robot parameters: geometry, nominal ("datasheet") masses and limits, in SI units.

The values are the nominal ones of docs/design.md section 4, the only ones the controllers may know.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from delta_env.validation import require_positive

GRAVITY = 9.81
"""Gravitational acceleration (m/s^2), acting along -z of the base frame."""

TORQUE_LIMIT = 400.0
"""Peak torque (N m) of the default drive at the joint (after the gearbox); the whole envelope is
:class:`delta_env.drive.DriveLimits`."""

CHAIN_AZIMUTHS = np.array([0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0])
"""Azimuth alpha_i (rad) of chain i = 1, 2, 3 about the base z axis."""

CHAIN_COS: tuple[float, float, float] = tuple(math.cos(alpha) for alpha in CHAIN_AZIMUTHS.tolist())
"""cos(alpha_i) of the three chain azimuths: x component of the outward chain direction u_i."""

CHAIN_SIN: tuple[float, float, float] = tuple(math.sin(alpha) for alpha in CHAIN_AZIMUTHS.tolist())
"""sin(alpha_i) of the three chain azimuths: y component of the outward chain direction u_i."""


@dataclass(frozen=True)
class DeltaGeometry:
    """Lengths of a Delta robot (m).

    Attributes:
        ra: Base radius, centre O to each motor axis.
        rb: Platform radius, platform centre E0 to each forearm attachment.
        l1: Upper (active) arm length, motor axis to elbow.
        l2: Forearm (parallelogram rod) length, elbow to platform.
    """

    ra: float = 0.20
    rb: float = 0.05
    l1: float = 0.37
    l2: float = 0.95

    def __post_init__(self) -> None:
        for name in ("ra", "rb", "l1", "l2"):
            require_positive(name, getattr(self, name), "m")
        if self.rb >= self.ra:
            raise ValueError(f"rb must be < ra (the platform sits inside the base), got rb={self.rb}, ra={self.ra}")
        if self.l2 <= self.l1:
            raise ValueError(f"l2 must be > l1 for a reachable elbow-out workspace, got l1={self.l1}, l2={self.l2}")

    @property
    def r(self) -> float:
        """Radius ra - rb of the equivalent robot with a point platform (m)."""
        return self.ra - self.rb

    @property
    def home_height(self) -> float:
        """Platform height z (m) at home, all arms horizontal (theta = 0): -sqrt(l2^2 - (r + l1)^2).

        Raises:
            ValueError: if the forearms cannot reach below the base with the arms horizontal.
        """
        reach_sq = self.l2**2 - (self.r + self.l1) ** 2
        if reach_sq <= 0.0:
            raise ValueError(
                f"the robot cannot assemble with its arms horizontal: l2={self.l2} must exceed "
                f"ra - rb + l1={self.r + self.l1} m"
            )
        return -math.sqrt(reach_sq)


@dataclass(frozen=True)
class DeltaMasses:
    """Lumped masses of the analytical (Kuo & Huang) model (kg).

    Attributes:
        m1: Upper arm, a homogeneous rod of length l1.
        m2: Half of one forearm pair: lumped once at the elbow and once at the platform.
        m0: Moving platform with the suction gripper, without payload.
    """

    m1: float = 2.0
    m2: float = 0.2
    m0: float = 0.8

    def __post_init__(self) -> None:
        for name in ("m1", "m2", "m0"):
            require_positive(name, getattr(self, name), "kg")


NOMINAL_GEOMETRY = DeltaGeometry()
"""The nominal robot's lengths (docs/design.md section 4): the default of every scenario and controller."""

NOMINAL_MASSES = DeltaMasses()
"""The nominal robot's datasheet masses of the analytical model: what the controllers may know of its masses."""
