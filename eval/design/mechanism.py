"""The pitch-screw linkage that sets the base radius of the reconfigurable Delta (the paper's eqs. 43-46).

Each chain's motor sits on a **rocker** of length R_r hinged on the base at F, R_f from the base centre. A
**coupler** of length d2 joins the motor axis A to a **nut** D that a vertical **pitch screw**, d3 from the
base centre, moves along its axis: turning the screw by n turns moves the nut by s = lead * n (the paper's
p phi, p per radian) from its lowest position, where it sits d1 above F. In the chain's radial-vertical
plane (u out from the base centre, w up, F at w = 0), eq. (43) closes the loop F-A-D:

    (R_f + R_r cos a4 - d3)^2 + (d1 + s - R_r sin a4)^2 = d2^2,

solved as k1 sin a4 + k2 cos a4 = k3 (eq. 44): a4 = asin(k3 / rho) - psi on one assembly branch,
pi - asin(k3 / rho) - psi on the other, rho = hypot(k1, k2), psi = atan2(k2, k1); both signs of cos a4
are kept (the paper's eq. 45 drops one). The motor axis A is then at (eq. 46)

    ra = R_f + R_r cos a4   out from the base centre (the effective base radius),
    w_A = R_r sin a4        above F (the motor-axis offset: the motors rise and fall with the rocker).

The three chains carry identical linkages set to the same travel, so the robot stays symmetric. The stroke
is the screw's: thread length minus nut length; the linkage must assemble over all of it and keep its
ratio dra/ds within [:data:`MIN_RATIO`, :data:`MAX_RATIO`] (away from its dead points). What moves with the
screw is the motor, its gearbox and the rocker, with the arm chain hanging from them; during a task the
screw is still and self-locking, so they are part of the base and the dynamic model keeps its form: only
ra and the height of the motor axes above the conveyor change (docs/design-study.md section 5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env.validation import require_in, require_positive

SCREW_LEAD = 0.004
"""Nut travel per screw turn (m): a Tr16x4 single-start trapezoidal screw, self-locking with a bronze nut (lead
angle 5.2 deg against a friction angle of 6-9 deg), so it holds the setting under the arm's loads without a brake."""

THREAD_LENGTH = 0.24
"""Threaded length of the screw (m)."""

NUT_LENGTH = 0.04
"""Length of the nut (m): the stroke is THREAD_LENGTH - NUT_LENGTH = 0.20 m, 50 turns."""

ROCKER_LENGTH = 0.30
"""R_r (m): F to the motor axis. At mid-stroke the rocker hangs straight down, so the motor axis moves radially
to first order and rises only as R_r (1 - cos) of its swing: 26 mm at the end of the nominal's stroke."""

COUPLER_LENGTH = 0.30
"""d2 (m): nut to motor axis."""

COUPLER_ANGLE = math.radians(45.0)
"""Elevation of the coupler from A up to the nut at mid-stroke (rad): 45 deg makes the nut travel and the radius
change 1:1 there (a steeper coupler moves the radius less per turn, a flatter one nears the nut's dead point)."""

MIN_RATIO = 0.25
"""Smallest |dra/ds| accepted over the stroke: below it the linkage nears the rocker's dead point, where turns
stop moving the motor."""

MAX_RATIO = 4.0
"""Largest |dra/ds| accepted: by virtual work the nut carries |dra/ds| times the radial load on the motor axis,
which grows without bound at the nut's dead point (coupler square to the screw)."""

_RATIO_SAMPLES = 201  # screw positions at which a new linkage's ratio is checked


@dataclass(frozen=True)
class PitchScrewLinkage:
    """One chain's reconfiguration linkage (module docstring); lengths in m.

    Attributes:
        pivot_radius: R_f, base centre to the rocker's hinge F.
        rocker_length: R_r, F to the motor axis A.
        coupler_length: d2, A to the nut D.
        screw_radius: d3, base centre to the screw axis.
        nut_start_height: d1, height of the nut above F at zero travel.
        lead: Nut travel per screw turn (m/turn).
        thread_length: Threaded length of the screw.
        nut_length: Length of the nut; the stroke is ``thread_length - nut_length``.
        branch: Assembly branch of eq. (44), +1 or -1 (module docstring).
    """

    pivot_radius: float
    rocker_length: float
    coupler_length: float
    screw_radius: float
    nut_start_height: float
    lead: float = SCREW_LEAD
    thread_length: float = THREAD_LENGTH
    nut_length: float = NUT_LENGTH
    branch: int = 1

    def __post_init__(self) -> None:
        for name in ("pivot_radius", "rocker_length", "coupler_length", "lead", "nut_length"):
            require_positive(name, getattr(self, name), "m")
        require_in("screw_radius", self.screw_radius, unit="m")
        require_in("nut_start_height", self.nut_start_height, unit="m")
        require_in("thread_length", self.thread_length, self.nut_length, math.inf, unit="m", low_open=True)
        if self.branch not in (1, -1):
            raise ValueError(f"branch must be +1 or -1, got {self.branch!r}")
        travel = np.linspace(0.0, self.stroke, _RATIO_SAMPLES)
        ratio = np.abs(self.ratio(travel))  # raises if the linkage does not assemble somewhere on the stroke
        worst = int(np.argmin(np.minimum(ratio / MIN_RATIO, MAX_RATIO / ratio)))
        if not MIN_RATIO <= ratio[worst] <= MAX_RATIO:
            raise ValueError(
                f"the linkage nears a dead point at travel {travel[worst]:.4f} m: |dra/ds| = {ratio[worst]:.3f}, "
                f"must stay in [{MIN_RATIO}, {MAX_RATIO}] over the stroke [0, {self.stroke:.4f}] m"
            )

    @classmethod
    def for_design(
        cls,
        ra: float,
        *,
        rocker_length: float = ROCKER_LENGTH,
        coupler_length: float = COUPLER_LENGTH,
        coupler_angle: float = COUPLER_ANGLE,
        lead: float = SCREW_LEAD,
        thread_length: float = THREAD_LENGTH,
        nut_length: float = NUT_LENGTH,
    ) -> PitchScrewLinkage:
        """The linkage built around a design: at mid-stroke the rocker hangs straight down with the motor axis
        at the design's ``ra`` (m), and the coupler rises at ``coupler_angle`` (rad) outward to a screw outside
        the motors (reachable, and clear of the other chains)."""
        require_positive("ra", ra, "m")
        require_in("coupler_angle", coupler_angle, 0.0, math.pi / 2, unit="rad", low_open=True, high_open=True)
        half_stroke = (thread_length - nut_length) / 2.0
        nut_mid_height = -rocker_length + coupler_length * math.sin(coupler_angle)
        geometry = {
            "pivot_radius": ra,
            "rocker_length": rocker_length,
            "coupler_length": coupler_length,
            "screw_radius": ra + coupler_length * math.cos(coupler_angle),
            "nut_start_height": nut_mid_height - half_stroke,
            "lead": lead,
            "thread_length": thread_length,
            "nut_length": nut_length,
        }
        # the branch on which the rocker hangs straight down (a4 = -pi/2) at mid-stroke
        lengths = {key: geometry[key] for key in ("pivot_radius", "rocker_length", "coupler_length", "screw_radius")}
        for branch in (1, -1):
            angle = _loop_angle(**lengths, nut_height=nut_mid_height, branch=branch)
            if abs(float(angle) + math.pi / 2) < 1e-9:
                return cls(**geometry, branch=branch)
        raise AssertionError("no branch hangs the rocker down at mid-stroke")  # the construction guarantees one

    @property
    def stroke(self) -> float:
        """Nut travel from end stop to end stop (m)."""
        return self.thread_length - self.nut_length

    @property
    def turns(self) -> float:
        """Screw turns over the whole stroke."""
        return self.stroke / self.lead

    def travel(self, turns: float) -> float:
        """Nut travel (m) after ``turns`` screw turns from the lower end stop, in [0, :attr:`turns`]."""
        return self.lead * require_in("turns", turns, 0.0, self.turns)

    def rocker_angle(self, travel: ArrayLike) -> NDArray[np.float64]:
        """a4 (rad) at nut travel ``travel`` (m), each in [0, :attr:`stroke`]."""
        s = self._checked(travel)
        return _loop_angle(
            pivot_radius=self.pivot_radius,
            rocker_length=self.rocker_length,
            coupler_length=self.coupler_length,
            screw_radius=self.screw_radius,
            nut_height=self.nut_start_height + s,
            branch=self.branch,
        )

    def base_radius(self, travel: ArrayLike) -> NDArray[np.float64]:
        """Effective base radius ra = R_f + R_r cos a4 (m) at nut travel ``travel`` (m)."""
        return self.pivot_radius + self.rocker_length * np.cos(self.rocker_angle(travel))

    def motor_height(self, travel: ArrayLike) -> NDArray[np.float64]:
        """Height of the motor axis above the rocker hinge F, R_r sin a4 (m), at nut travel ``travel`` (m)."""
        return self.rocker_length * np.sin(self.rocker_angle(travel))

    def height_offset(self, travel: ArrayLike) -> NDArray[np.float64]:
        """Rise of the motor axes (m) from their height at mid-stroke, where the robot's base frame is set."""
        return self.motor_height(travel) - self.motor_height(self.stroke / 2.0)

    def ratio(self, travel: ArrayLike) -> NDArray[np.float64]:
        """dra/ds at nut travel ``travel`` (m): radius change per unit nut travel (differentiated eq. 43)."""
        angle = self.rocker_angle(travel)
        s = np.asarray(travel, dtype=float)
        gap_u = self.pivot_radius + self.rocker_length * np.cos(angle) - self.screw_radius  # A - D
        gap_w = self.rocker_length * np.sin(angle) - (self.nut_start_height + s)
        # |A - D|^2 = d2^2: (A - D) . dA/da da + (A - D) . (0, -1) ds = 0
        along_rocker = self.rocker_length * (-gap_u * np.sin(angle) + gap_w * np.cos(angle))
        with np.errstate(divide="ignore", invalid="ignore"):  # a dead point: infinite or undefined, refused
            angle_rate = gap_w / along_rocker
        return -self.rocker_length * np.sin(angle) * angle_rate

    def _checked(self, travel: ArrayLike) -> NDArray[np.float64]:
        s = np.asarray(travel, dtype=float)
        outside = ~((s >= 0.0) & (s <= self.stroke))
        if np.any(outside):
            bad = float(s[outside].flat[0]) if s.ndim else float(s)
            raise ValueError(f"screw travel must be a finite number in [0, {self.stroke:g}] m, got {bad!r}")
        return s


def _loop_angle(
    *,
    pivot_radius: float,
    rocker_length: float,
    coupler_length: float,
    screw_radius: float,
    nut_height: ArrayLike,
    branch: int,
) -> NDArray[np.float64]:
    """a4 (rad, in [-pi, pi)) solving eq. (44) with the nut ``nut_height`` above F, on ``branch``; ValueError if
    it cannot close."""
    e = np.asarray(nut_height, dtype=float)
    offset = pivot_radius - screw_radius
    k1 = -2.0 * rocker_length * e
    k2 = np.full_like(e, 2.0 * rocker_length * offset)
    k3 = coupler_length**2 - offset**2 - rocker_length**2 - e**2
    rho = np.hypot(k1, k2)
    reach = k3 / rho
    if np.any(np.abs(reach) > 1.0):
        bad = float(np.asarray(e)[np.abs(reach) > 1.0].flat[0])
        raise ValueError(
            f"the linkage cannot close with the nut {bad:.4f} m above the hinge: the coupler ({coupler_length} m) "
            "cannot reach the motor axis"
        )
    psi = np.arctan2(k2, k1)
    base = np.arcsin(reach)
    angle = base - psi if branch > 0 else math.pi - base - psi
    return np.remainder(angle + math.pi, 2.0 * math.pi) - math.pi
