"""Reconfiguring a design for each task with its pitch screws: the best screw setting per task profile.

Each design carries the linkage of :class:`eval.design.mechanism.PitchScrewLinkage` built around it: at
mid-stroke its motor axes sit at the design's ra and height. A screw setting (the nut's travel s in the
stroke) gives a base radius ra(s) and a rise of the motor axes; rb, l1, l2 and the masses stay, and the
conveyor stays where it is, so in the base frame it lies that rise lower. Every setting is judged by
:func:`eval.design.performance.evaluate` on the profile's task.

For each profile the best setting is a bounded scalar optimization over the stroke: a grid of
:data:`GRID_SETTINGS` settings, then Brent's bounded method (``scipy.optimize.minimize_scalar``) between the best
grid setting's neighbours, to :data:`TRAVEL_TOLERANCE`. The best *fixed* setting is the one setting, feasible
for every profile, that minimizes the profiles' mean objective relative to their own bests, found the same way.
What reconfiguring gains is each profile's objective at its own best setting against the fixed one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from delta_env.catalogue import DriveOption
from delta_env.geometry import DeltaGeometry
from delta_env.trajectories import WORKING_HEIGHT
from delta_env.validation import require_count, require_in, require_positive
from delta_env.workspace import DEXTEROUS
from eval.design.codesign import LIGHT_PAYLOAD, choose_drive
from eval.design.mechanism import PitchScrewLinkage
from eval.design.performance import STANDARD_TRAVEL_HALF, Performance, evaluate

GRID_SETTINGS = 21
"""Screw settings of the grid over the stroke (10 mm of nut travel apart on the default 200 mm stroke)."""

TRAVEL_TOLERANCE = 1e-4
"""Nut travel (m) to which the best settings are refined: 0.1 mm, under 0.14 mm of base radius."""

OBJECTIVES: dict[str, tuple[str, str, str, bool]] = {
    "peak_torque": ("peak_torque_nm", "peak torque", "N m", False),
    "workspace": ("workspace_m3", "workspace", "m³", True),
    "speed": ("picks_per_min_light", f"pick rate at {LIGHT_PAYLOAD} kg", "picks/min", True),
}
"""Objective name -> (Performance field, what it is, unit, True if maximized)."""


@dataclass(frozen=True)
class TaskProfile:
    """A task the robot is reconfigured for.

    Attributes:
        name: Short name.
        payload: Carried mass (kg).
        zone_radius: Radius (m) of the axis-centred task disc that must be dexterous.
        objective: A key of :data:`OBJECTIVES`.
    """

    name: str
    payload: float
    zone_radius: float
    objective: str

    def __post_init__(self) -> None:
        require_in("payload", self.payload, 0.0, math.inf, unit="kg")
        require_in("zone_radius", self.zone_radius, STANDARD_TRAVEL_HALF, math.inf, unit="m", low_open=True)
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {sorted(OBJECTIVES)}, got {self.objective!r}")

    @property
    def label(self) -> str:
        """What the objective measures, e.g. "cycle time"."""
        return OBJECTIVES[self.objective][1]

    @property
    def unit(self) -> str:
        """Unit of the objective."""
        return OBJECTIVES[self.objective][2]

    @property
    def maximized(self) -> bool:
        """True if a larger objective is better."""
        return OBJECTIVES[self.objective][3]

    def value(self, performance: Performance) -> float:
        """The objective in its own sense and unit; NaN when the task is infeasible."""
        return getattr(performance, OBJECTIVES[self.objective][0]) if performance.feasible else math.nan

    def cycles(self, belt_height: float = WORKING_HEIGHT) -> tuple[tuple[tuple[float, float, float], float], ...]:
        """Standard cycles on the belt (``belt_height`` m in the base frame) spread over the zone: across and along
        it at the centre, and at both sides."""
        offset = 0.9 * math.sqrt(self.zone_radius**2 - STANDARD_TRAVEL_HALF**2)
        z = belt_height
        return (
            ((0.0, 0.0, z), math.pi / 2),
            ((0.0, 0.0, z), 0.0),
            ((offset, 0.0, z), math.pi / 2),
            ((-offset, 0.0, z), math.pi / 2),
        )


PROFILES = (
    TaskProfile("heavy payload, small zone", payload=8.0, zone_radius=0.25, objective="peak_torque"),
    TaskProfile("light payload, wide zone", payload=0.5, zone_radius=0.47, objective="workspace"),
    TaskProfile("fastest cycle", payload=LIGHT_PAYLOAD, zone_radius=0.35, objective="speed"),
)
"""The three task profiles: 8 kg (twice the rating) near the centre, torque down; 0.5 kg over a 0.94 m disc
(wider than the conveyors' 0.92 m; the nominal robot's buildable workspace reaches no 0.96 m disc on its belt at
any screw setting), workspace up; the light payload (0.1 kg, :data:`eval.design.codesign.LIGHT_PAYLOAD`)
over a 0.7 m disc, picks/min up."""


@dataclass(frozen=True)
class ProfileOutcome:
    """One profile's result; NaN fields when no setting is feasible.

    Attributes:
        profile: The task.
        best_travel: Its best screw setting, nut travel (m) in the stroke.
        best_ra: The base radius there (m).
        best_value: Its objective there (the profile's unit).
        fixed_value: Its objective at the best fixed setting.
        gain_percent: Improvement of reconfiguring over the fixed setting (%, >= 0): the share of the fixed
            setting's objective saved (minimized) or 1 - fixed / best (maximized).
        limit: What stops the optimum: "lower end stop", "upper end stop", "feasibility" (an infeasible
            setting within :data:`TRAVEL_TOLERANCE`) or "" (an interior optimum).
    """

    profile: TaskProfile
    best_travel: float
    best_ra: float
    best_value: float
    fixed_value: float
    gain_percent: float
    limit: str


@dataclass(frozen=True)
class Reconfiguration:
    """The study's result.

    Attributes:
        base: The design whose base radius is set by the screws.
        linkage: Its linkage.
        travel: The grid's nut travels (m), ``(S,)``.
        settings: The base radius at each, ra(travel) (m), ``(S,)``.
        values: Objective of each profile at each grid setting, ``(P, S)`` (NaN where infeasible).
        fixed_travel: The best fixed setting (m of nut travel), NaN if none is feasible for every profile.
        fixed_ra: The base radius there (m).
        outcomes: One per profile.
        evaluations: Settings evaluated (profile x setting), grid and refinement.
    """

    base: DeltaGeometry
    linkage: PitchScrewLinkage
    travel: NDArray[np.float64]
    settings: NDArray[np.float64]
    values: NDArray[np.float64]
    fixed_travel: float
    fixed_ra: float
    outcomes: tuple[ProfileOutcome, ...]
    evaluations: int


def refine(
    score: Callable[[float], float], grid: NDArray[np.float64], grid_scores: NDArray[np.float64], tolerance: float
) -> tuple[float, float]:
    """The minimum of ``score`` on [grid[0], grid[-1]]: Brent's bounded method between the neighbours of the best
    grid point, which stays the answer if nothing inside beats it (so an optimum at an end stop is the end stop).

    Args:
        score: Objective to minimize; +inf where infeasible.
        grid: Increasing settings, ``(S,)``, S >= 2.
        grid_scores: ``score`` at each, ``(S,)``.
        tolerance: Absolute tolerance on the setting, > 0.

    Returns:
        (setting, score there); (NaN, inf) if every grid point is infeasible.
    """
    require_positive("tolerance", tolerance)
    finite = np.isfinite(grid_scores)
    if not finite.any():
        return math.nan, math.inf
    best = int(np.argmin(np.where(finite, grid_scores, np.inf)))
    # an infeasible setting as a finite value worse than any feasible grid one, so Brent's steps stay defined
    worst = float(np.max(grid_scores[finite]))
    penalty = worst + abs(worst) + 1.0

    def penalized(x: float) -> float:
        value = score(x)
        return value if math.isfinite(value) else penalty

    low, high = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    found = minimize_scalar(penalized, bounds=(low, high), method="bounded", options={"xatol": tolerance})
    inside = score(float(found.x))
    if math.isfinite(inside) and inside < grid_scores[best]:
        return float(found.x), inside
    return float(grid[best]), float(grid_scores[best])


def study(
    base: DeltaGeometry,
    profiles: tuple[TaskProfile, ...] = PROFILES,
    *,
    linkage: PitchScrewLinkage | None = None,
    grid_settings: int = GRID_SETTINGS,
    tolerance: float = TRAVEL_TOLERANCE,
) -> Reconfiguration:
    """Best screw setting per profile and the gain over the best fixed setting (module docstring).

    Args:
        base: The design; rb, l1, l2 are kept and its ra is the one at mid-stroke.
        profiles: Task profiles, at least one.
        linkage: The screws' linkage; :meth:`PitchScrewLinkage.for_design` of ``base.ra`` when None.
        grid_settings: Grid settings over the stroke, >= 3.
        tolerance: Nut travel (m) to which the optima are refined, > 0.
    """
    require_count("grid_settings", grid_settings, minimum=3)
    require_positive("tolerance", tolerance, "m")
    if not profiles:
        raise ValueError("profiles must hold at least one TaskProfile, got none")
    linkage = PitchScrewLinkage.for_design(base.ra) if linkage is None else linkage
    built = choose_drive(base).option  # the design's own drive, chosen at its mid-stroke ra
    drives = None if built is None else (built,)
    evaluated: dict[tuple[int, float], float] = {}

    def value(p: int, travel: float) -> float:
        """Profile p's objective at a screw setting (NaN if infeasible), each setting evaluated once."""
        key = (p, travel)
        if key not in evaluated:
            performance = _performance(base, linkage, travel, profiles[p], drives)
            evaluated[key] = math.nan if performance is None else profiles[p].value(performance)
        return evaluated[key]

    def score(p: int, travel: float) -> float:
        """Profile p's objective as a quantity to minimize; +inf if infeasible."""
        v = value(p, travel)
        return math.inf if math.isnan(v) else (-v if profiles[p].maximized else v)

    travel = np.linspace(0.0, linkage.stroke, grid_settings)
    values = np.array([[value(p, float(s)) for s in travel] for p in range(len(profiles))])
    bests = []
    for p in range(len(profiles)):
        grid_scores = np.array([score(p, float(s)) for s in travel])
        bests.append(refine(lambda s, p=p: score(p, s), travel, grid_scores, tolerance))
    best_values = [math.nan if math.isinf(b[1]) else value(p, b[0]) for p, b in enumerate(bests)]

    def relative(p: int, travel: float) -> float:
        """Profile p's objective at ``travel`` relative to its best (>= 1, larger is worse); inf if infeasible."""
        v = value(p, travel)
        if math.isnan(v):
            return math.inf
        return best_values[p] / v if profiles[p].maximized else v / best_values[p]

    def mean_relative(travel: float) -> float:
        return float(np.mean([relative(p, travel) for p in range(len(profiles))]))

    fixed_travel = math.nan
    for _ in range(2):  # a setting the fixed search passed may beat a profile's own refined best: take it, search again
        if not all(math.isfinite(v) for v in best_values):
            break
        fixed_travel, _ = refine(mean_relative, travel, np.array([mean_relative(float(s)) for s in travel]), tolerance)
        seen = [min((score(p, s), s) for (q, s) in list(evaluated) if q == p) for p in range(len(profiles))]
        better = [seen[p][0] < score(p, bests[p][0]) for p in range(len(profiles))]
        if not any(better):
            break
        bests = [(seen[p][1], seen[p][0]) if better[p] else bests[p] for p in range(len(profiles))]
        best_values = [value(p, b[0]) for p, b in enumerate(bests)]
    outcomes = []
    for p, profile in enumerate(profiles):
        best_travel = bests[p][0]
        if math.isnan(best_travel):
            outcomes.append(ProfileOutcome(profile, math.nan, math.nan, math.nan, math.nan, math.nan, ""))
            continue
        at_fixed = relative(p, fixed_travel) if math.isfinite(fixed_travel) else math.nan
        outcomes.append(
            ProfileOutcome(
                profile=profile,
                best_travel=best_travel,
                best_ra=float(linkage.base_radius(best_travel)),
                best_value=best_values[p],
                fixed_value=value(p, fixed_travel) if math.isfinite(fixed_travel) else math.nan,
                gain_percent=100.0 * (1.0 - 1.0 / at_fixed),
                limit=_limit(lambda s, p=p: score(p, s), best_travel, linkage.stroke, tolerance),
            )
        )
    return Reconfiguration(
        base=base,
        linkage=linkage,
        travel=travel,
        settings=linkage.base_radius(travel),
        values=values,
        fixed_travel=fixed_travel,
        fixed_ra=float(linkage.base_radius(fixed_travel)) if math.isfinite(fixed_travel) else math.nan,
        outcomes=tuple(outcomes),
        evaluations=len(evaluated),
    )


def _performance(
    base: DeltaGeometry,
    linkage: PitchScrewLinkage,
    travel: float,
    profile: TaskProfile,
    drives: tuple[DriveOption, ...] | None,
) -> Performance | None:
    """The design with its screws at ``travel`` (m) on the profile's task, the conveyor staying put in the world,
    with the drives it was built with (a screw setting moves the motors, it does not change them); None where
    the motor axes come inside the platform radius (no robot to evaluate)."""
    ra = float(linkage.base_radius(travel))
    if ra <= base.rb:
        return None
    belt = WORKING_HEIGHT - float(linkage.height_offset(travel))
    return evaluate(
        replace(base, ra=ra),
        payload=profile.payload,
        criteria=DEXTEROUS,
        task_radius=profile.zone_radius,
        cycles=profile.cycles(belt),
        belt_height=belt,
        drives=drives,
    )


def _limit(score: Callable[[float], float], best: float, stroke: float, tolerance: float) -> str:
    """What stops the optimum at ``best`` (see :attr:`ProfileOutcome.limit`)."""
    if best <= tolerance:
        return "lower end stop"
    if best >= stroke - tolerance:
        return "upper end stop"
    neighbours = (max(best - 2.0 * tolerance, 0.0), min(best + 2.0 * tolerance, stroke))
    return "feasibility" if any(math.isinf(score(s)) for s in neighbours) else ""
