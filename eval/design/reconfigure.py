"""The second paper's reconfigurable mechanism: the effective base radius ra, set between tasks.

A pitch screw moves the motors radially, so ra can change between tasks while rb, l1 and l2 stay; the masses
that move do not change (the motors are on the base). For each task profile the best setting of ra is found
on a grid over :data:`RA_TRAVEL` around the base design, and compared with the best *fixed* ra: the single
setting, feasible for every profile, that is best on average (each profile's objective relative to its own
best). What reconfiguring gains is the profile's objective at its own best setting against the fixed one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from delta_env.geometry import DeltaGeometry
from delta_env.trajectories import WORKING_HEIGHT
from delta_env.validation import require_count, require_in, require_positive
from delta_env.workspace import DEXTEROUS
from eval.design.performance import STANDARD_TRAVEL_HALF, Performance, evaluate

RA_TRAVEL = 0.08
"""Pitch-screw travel (m) either side of the base design's ra: a 160 mm stroke, as wide as the nominal
base allows while ra stays well above rb."""

RA_SETTINGS = 9
"""Settings of ra tested over the travel (20 mm apart)."""


@dataclass(frozen=True)
class TaskProfile:
    """A task the robot is reconfigured for.

    Attributes:
        name: Short name.
        payload: Carried mass (kg).
        zone_radius: Radius (m) of the axis-centred task disc that must be dexterous.
        objective: ``"peak_torque"`` (minimized), ``"workspace"`` or ``"pick_rate"`` (maximized: picks
            per minute at the rated payload, :mod:`eval.design.codesign`).
    """

    name: str
    payload: float
    zone_radius: float
    objective: str

    def __post_init__(self) -> None:
        require_in("payload", self.payload, 0.0, math.inf, unit="kg")
        require_in("zone_radius", self.zone_radius, STANDARD_TRAVEL_HALF, math.inf, unit="m", low_open=True)
        if self.objective not in ("peak_torque", "workspace", "pick_rate"):
            raise ValueError(f"objective must be 'peak_torque', 'workspace' or 'pick_rate', got {self.objective!r}")

    def score(self, performance: Performance) -> float:
        """The objective as a quantity to minimize (workspace and pick rate negated); +inf when infeasible."""
        if not performance.feasible:
            return math.inf
        if self.objective == "peak_torque":
            return performance.peak_torque_nm
        if self.objective == "workspace":
            return -performance.workspace_m3
        return -performance.picks_per_min

    def cycles(self) -> tuple[tuple[tuple[float, float, float], float], ...]:
        """Standard cycles spread over the zone: across and along it at the centre, and at both sides."""
        offset = 0.9 * math.sqrt(self.zone_radius**2 - STANDARD_TRAVEL_HALF**2)
        z = WORKING_HEIGHT
        return (
            ((0.0, 0.0, z), math.pi / 2),
            ((0.0, 0.0, z), 0.0),
            ((offset, 0.0, z), math.pi / 2),
            ((-offset, 0.0, z), math.pi / 2),
        )


MAXIMIZED = ("workspace", "pick_rate")
"""Objectives of :class:`TaskProfile` that are maximized."""

PROFILES = (
    TaskProfile("heavy payload, small zone", payload=8.0, zone_radius=0.25, objective="peak_torque"),
    TaskProfile("light payload, wide zone", payload=0.5, zone_radius=0.50, objective="workspace"),
    TaskProfile("fastest cycle", payload=1.0, zone_radius=0.35, objective="pick_rate"),
)
"""The three task profiles: 8 kg (twice the rating) near the centre, torque down; 0.5 kg over a 1.0 m disc,
workspace up; 1 kg over a 0.7 m disc, cycle time down."""


@dataclass(frozen=True)
class ProfileOutcome:
    """One profile's result.

    Attributes:
        profile: The task.
        best_ra: Its best setting (m), or NaN if no setting is feasible.
        best_value: Its objective there (N m, m^3 or picks/min).
        fixed_value: Its objective at the best fixed setting.
        gain_percent: Improvement of reconfiguring over the fixed setting (%, >= 0): the share of the fixed
            setting's objective saved (torque, time) or 1 - W_fixed / W_best (workspace).
    """

    profile: TaskProfile
    best_ra: float
    best_value: float
    fixed_value: float
    gain_percent: float


@dataclass(frozen=True)
class Reconfiguration:
    """The study's result.

    Attributes:
        base: The design whose ra is adjusted.
        settings: The ra values tested (m), ``(S,)``.
        values: Objective of each profile at each setting, ``(P, S)`` (NaN where infeasible).
        fixed_ra: The best fixed setting (m), NaN if none is feasible for every profile.
        outcomes: One per profile.
    """

    base: DeltaGeometry
    settings: np.ndarray
    values: np.ndarray
    fixed_ra: float
    outcomes: tuple[ProfileOutcome, ...]


def study(
    base: DeltaGeometry,
    profiles: tuple[TaskProfile, ...] = PROFILES,
    *,
    travel: float = RA_TRAVEL,
    settings: int = RA_SETTINGS,
) -> Reconfiguration:
    """Best ra per profile and the gain over the best fixed ra (module docstring).

    Args:
        base: The design whose ra is adjusted; rb, l1, l2 are kept.
        profiles: Task profiles, at least one.
        travel: Adjustment either side of ``base.ra`` (m), > 0; settings must keep ra > rb.
        settings: Settings tested, >= 2.
    """
    require_positive("travel", travel, "m")
    require_count("settings", settings, minimum=2)
    if not profiles:
        raise ValueError("profiles must hold at least one TaskProfile, got none")
    if base.ra - travel <= base.rb:
        raise ValueError(
            f"travel {travel} m takes ra below rb: ra - travel = {base.ra - travel:.3f} m <= rb = {base.rb} m"
        )
    ras = np.linspace(base.ra - travel, base.ra + travel, settings)
    scores = np.array(
        [
            [
                profile.score(
                    evaluate(
                        replace(base, ra=float(ra)),
                        payload=profile.payload,
                        criteria=DEXTEROUS,
                        task_radius=profile.zone_radius,
                        cycles=profile.cycles(),
                    )
                )
                for ra in ras
            ]
            for profile in profiles
        ]
    )
    signs = np.array([-1.0 if profile.objective in MAXIMIZED else 1.0 for profile in profiles])[:, None]
    values = np.where(np.isfinite(scores), signs * scores, np.nan)  # the objectives in their own sense
    own = np.argmin(scores, axis=1)
    best = values[np.arange(len(profiles)), own]
    # each setting's objective relative to the profile's best (>= 1, larger is worse)
    with np.errstate(invalid="ignore", divide="ignore"):
        relative = np.where(signs > 0, values / best[:, None], best[:, None] / values)
    all_feasible = np.all(np.isfinite(values), axis=0)
    fixed = int(np.nanargmin(np.where(all_feasible, relative.mean(axis=0), np.nan))) if all_feasible.any() else None
    outcomes = []
    for p, profile in enumerate(profiles):
        if not np.isfinite(best[p]):
            outcomes.append(ProfileOutcome(profile, math.nan, math.nan, math.nan, math.nan))
            continue
        fixed_value = float(values[p, fixed]) if fixed is not None else math.nan
        gain = 100.0 * (1.0 - 1.0 / relative[p, fixed]) if fixed is not None else math.nan
        outcomes.append(ProfileOutcome(profile, float(ras[own[p]]), float(best[p]), fixed_value, float(gain)))
    return Reconfiguration(
        base=base,
        settings=ras,
        values=values,
        fixed_ra=float(ras[fixed]) if fixed is not None else math.nan,
        outcomes=tuple(outcomes),
    )
