"""A small catalogue of servo motors and planetary gearboxes, from which a design's drive is chosen.

**Motors** (:data:`MOTORS`): Yaskawa Sigma-7 rotary servomotors for 200 V, without brake, from the ratings tables
("Ratings of Servomotors without Gears") of Yaskawa's Sigma-7-Series rotary servomotor product manual: the
medium-inertia SGM7J (400 to 750 W) and the low-inertia SGM7A (1.5 to 3 kW) series. Each entry gives the rated
and the instantaneous maximum torque, the rated speed (3000 min^-1), the maximum speed (6000 min^-1) and the
motor moment of inertia without brake, as the tables list them (typical values at a 100 degC winding for the
torques; the SGM7A-30A's maximum speed carries a footnote of the table that was not checked). The corner speed,
up to which the peak torque is available, is taken as the rated speed, as for
:data:`delta_env.drive.REPRESENTATIVE_MOTOR` (a 2 kW motor of the SGM7A-20A's size); the linear fall to zero
torque at the maximum speed is this project's model of the torque-speed curve (docs/design.md section 4).

**Gearboxes** (:data:`GEAR_RATIOS`): the ratios of the usual precision planetary gearhead series, one stage up
to 1:10 and two stages above, with 97 % efficiency per stage (:data:`STAGE_EFFICIENCY`): representative
catalogue values of such gearheads, not one vendor's data sheet. The gearhead's own input inertia is not
modelled: a drive's armature is the rotor's inertia times the ratio squared, a lower bound.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from delta_env.drive import RPM, DriveLimits, ServoMotor
from delta_env.validation import require_in

_RATED_SPEED = 3000.0 * RPM
_MAX_SPEED = 6000.0 * RPM

MOTORS: Mapping[str, ServoMotor] = {
    name: ServoMotor(peak, rated, _RATED_SPEED, _MAX_SPEED, inertia * 1e-4)
    for name, rated, peak, inertia in (
        ("SGM7J-04A", 1.27, 4.46, 0.486),
        ("SGM7J-06A", 1.91, 6.69, 0.800),
        ("SGM7J-08A", 2.39, 8.36, 1.59),
        ("SGM7A-15A", 4.90, 14.7, 2.00),
        ("SGM7A-20A", 6.36, 19.1, 2.47),
        ("SGM7A-25A", 7.96, 23.9, 3.19),
        ("SGM7A-30A", 9.80, 29.4, 7.00),
    )
}
"""The motors by model name (module docstring): rated and peak torque (N m), 3000 and 6000 min^-1, rotor inertia."""

GEAR_RATIOS = (3.0, 4.0, 5.0, 7.0, 10.0, 16.0, 20.0, 25.0, 28.0, 35.0, 40.0, 50.0, 70.0, 100.0)
"""Reductions of the planetary gearheads (dimensionless): one stage up to :data:`MAX_ONE_STAGE_RATIO`, two above."""

MAX_ONE_STAGE_RATIO = 10.0
"""Largest reduction of a one-stage planetary gearhead."""

STAGE_EFFICIENCY = 0.97
"""Torque efficiency of one planetary stage at full load (dimensionless)."""


def gear_efficiency(ratio: float) -> float:
    """Torque efficiency of a planetary gearhead of ``ratio`` in [1, 100]: one stage up to 1:10, else two."""
    require_in("ratio", ratio, 1.0, MAX_ONE_STAGE_RATIO**2)
    return STAGE_EFFICIENCY if ratio <= MAX_ONE_STAGE_RATIO else STAGE_EFFICIENCY**2


@dataclass(frozen=True)
class DriveOption:
    """A motor behind a planetary gearhead: one joint's drive.

    Attributes:
        motor_name: The motor's model name (a key of :data:`MOTORS` for the catalogue's options).
        motor: Its data-sheet values.
        ratio: Gear reduction, in [1, 100].
    """

    motor_name: str
    motor: ServoMotor
    ratio: float

    def __post_init__(self) -> None:
        gear_efficiency(self.ratio)

    @property
    def efficiency(self) -> float:
        """The gearhead's torque efficiency (dimensionless)."""
        return gear_efficiency(self.ratio)

    @property
    def limits(self) -> DriveLimits:
        """The joint-side envelope and thermal limit (:meth:`DriveLimits.of`)."""
        return DriveLimits.of(self.motor, self.ratio, self.efficiency)

    @property
    def armature(self) -> float:
        """The rotor's inertia reflected to the joint (kg m^2): rotor inertia times the ratio squared."""
        return self.motor.rotor_inertia * self.ratio**2

    @property
    def label(self) -> str:
        """``"<motor> 1:<ratio>"``."""
        return f"{self.motor_name} 1:{self.ratio:g}"


def drive_options(
    motors: Mapping[str, ServoMotor] = MOTORS, ratios: Iterable[float] = GEAR_RATIOS
) -> tuple[DriveOption, ...]:
    """Every motor behind every ratio, motors in catalogue order, ratios ascending.

    Raises:
        ValueError: if there is no motor or no ratio, or a ratio lies outside [1, 100].
    """
    ratios = sorted(float(r) for r in ratios)
    if not motors or not ratios:
        raise ValueError(f"drive options need >= 1 motor and >= 1 ratio, got {len(motors)} and {len(ratios)}")
    return tuple(DriveOption(name, motor, ratio) for name, motor in motors.items() for ratio in ratios)


CATALOGUE = drive_options()
"""Every catalogue motor behind every catalogue ratio (98 drives)."""
