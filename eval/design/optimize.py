"""Geometry optimization with pymoo: an NSGA-II Pareto front and the paper's single-objective GA.

Design variables: the four lengths of the second paper's Table 1 (ra, rb, l1, l2), within
:class:`DesignBounds`. Objectives (all from :func:`eval.design.performance.evaluate`): the data-sheet
cylinder above the belt (maximized), the peak torque of the 3.8 kg standard cycles at 3 g (minimized) and the
picks per minute on the standard cycle at the rated payload with the design's own catalogue drive
(maximized; :mod:`eval.design.codesign`). Constraints (<= 0): the task region is dexterous (so no
singularity and no conditioning below the threshold inside it), the robot assembles with its arms
horizontal, the peak torque stays under the motor limit, the platform is wide enough for its ball joints
(:func:`delta_env.buildability.platform_radius_shortfall`, which also sets the lower bound of rb), and the
dexterous axis reaches the data-sheet cylinder's required top.

The paper does not print its weighted cost; :func:`weighted_cost` is our reading of it: the three
objectives, each relative to the nominal design, weighted equally (nominal cost 1).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.soo.nonconvex.ga import GA
from pymoo.core.callback import Callback
from pymoo.core.problem import ElementwiseProblem
from pymoo.indicators.hv import HV
from pymoo.optimize import minimize
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

from delta_env.buildability import min_platform_radius, platform_radius_shortfall
from delta_env.geometry import TORQUE_LIMIT, DeltaGeometry
from delta_env.validation import require_count, require_interval
from eval.design.performance import Performance, assembly_gap, evaluate

VARIABLES = ("ra", "rb", "l1", "l2")
"""Design variables, in the order of the optimizer's vectors (m)."""

OBJECTIVES = ("workspace_m3", "peak_torque_nm", "picks_per_min")
"""Objectives: workspace up, peak torque down, picks per minute up (pymoo minimizes their negatives)."""

CONSTRAINTS = 5
"""Number of constraints of :func:`constraint_vector`."""

PENALTY_TORQUE = 10.0 * TORQUE_LIMIT
"""Objective value (N m) given to a design whose task cycles cannot run: far beyond any feasible one."""

PENALTY_COST = 1000.0
"""Weighted cost given to a design without a dexterous cylinder (whose :func:`weighted_cost` is inf): far
beyond any feasible one (the nominal design costs 1)."""

MAX_SHORTFALL = 1.0
"""Constraint value (m) of a design whose task band is not even reachable on the axis."""

WEIGHTS = (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)
"""Weights of workspace, peak torque and pick rate in :func:`weighted_cost`: no objective preferred."""

PAPER_TARGETS = (0.15, 0.12, 0.08)
"""The second paper's reported gains over its nominal robot: +15 % workspace, -12 % torque, +8 % speed."""

HYPERVOLUME_REFERENCE = (0.0, 2.0, 0.0)
"""Reference point of the convergence hypervolume in nominal-relative objectives (-W/W0, T/T0, -P/P0): no
workspace, twice the nominal torque, no picks."""


@dataclass(frozen=True)
class DesignBounds:
    """Box bounds (min, max) of the design variables (m).

    The defaults span roughly -40 % to +50 % around the nominal robot: rb from the smallest platform whose ball
    joints do not touch (:func:`delta_env.buildability.min_platform_radius`, 45.6 mm) to 100 mm; ra above
    rb_max so that every design has its platform inside the base; l1 and l2 keep l2 > l1 with margin.
    """

    ra: tuple[float, float] = (0.12, 0.35)
    rb: tuple[float, float] = (min_platform_radius(), 0.10)
    l1: tuple[float, float] = (0.25, 0.55)
    l2: tuple[float, float] = (0.70, 1.40)

    def __post_init__(self) -> None:
        for name in VARIABLES:
            low, high = require_interval(name, getattr(self, name), 0.0, 5.0, unit="m")
            if not low < high:
                raise ValueError(f"bounds {name} must have min < max, got {getattr(self, name)!r} m")
            if low <= 0.0:
                raise ValueError(f"bounds {name} must be > 0 m, got {getattr(self, name)!r}")
        if self.rb[1] >= self.ra[0]:
            raise ValueError(
                f"bounds need rb max < ra min so every platform fits inside its base, got rb={self.rb!r}, "
                f"ra={self.ra!r} m"
            )
        if self.l2[0] <= self.l1[1]:
            raise ValueError(f"bounds need l2 min > l1 max, got l1={self.l1!r}, l2={self.l2!r} m")

    @property
    def lower(self) -> NDArray[np.float64]:
        """Lower bounds (m), in :data:`VARIABLES` order."""
        return np.array([getattr(self, name)[0] for name in VARIABLES])

    @property
    def upper(self) -> NDArray[np.float64]:
        """Upper bounds (m), in :data:`VARIABLES` order."""
        return np.array([getattr(self, name)[1] for name in VARIABLES])

    def contains(self, geometry: DeltaGeometry) -> bool:
        """Whether ``geometry`` lies in the box."""
        values = np.array([getattr(geometry, name) for name in VARIABLES])
        return bool(np.all(values >= self.lower - 1e-12) and np.all(values <= self.upper + 1e-12))


DEFAULT_BOUNDS = DesignBounds()


def geometry_of(x: NDArray[np.float64]) -> DeltaGeometry:
    """The geometry of a design vector (ra, rb, l1, l2) in m."""
    return DeltaGeometry(*(float(v) for v in x))


def objective_vector(performance: Performance) -> NDArray[np.float64]:
    """pymoo objectives (minimized): (-workspace, peak torque, -picks per minute), a penalty for a missing torque."""
    torque = performance.peak_torque_nm if math.isfinite(performance.peak_torque_nm) else PENALTY_TORQUE
    return np.array([-performance.workspace_m3, torque, -performance.picks_per_min])


def constraint_vector(performance: Performance) -> NDArray[np.float64]:
    """pymoo constraints (<= 0): task shortfall (m), assembly gap (m), torque excess (N m), platform radius
    shortfall for the ball joints (m), clearance shortfall (m)."""
    shortfall = min(performance.shortfall, MAX_SHORTFALL)
    torque = min(performance.peak_torque_nm, PENALTY_TORQUE)
    clearance = min(performance.clearance_shortfall, MAX_SHORTFALL)
    geometry = performance.geometry
    return np.array(
        [shortfall, assembly_gap(geometry), torque - TORQUE_LIMIT, platform_radius_shortfall(geometry), clearance]
    )


def weighted_cost(performance: Performance, nominal: Performance, weights: tuple[float, ...] = WEIGHTS) -> float:
    """The paper-style single cost: sum of w_j times each objective relative to nominal (nominal = 1).

    Workspace and pick rate enter as W0 / W and P0 / P (less costs more); a design without a dexterous cylinder
    or a drive costs +inf.
    """
    if performance.workspace_m3 <= 0.0 or performance.picks_per_min <= 0.0:
        return math.inf
    f = objective_vector(performance)
    terms = (
        nominal.workspace_m3 / performance.workspace_m3,
        f[1] / nominal.peak_torque_nm,
        nominal.picks_per_min / performance.picks_per_min,
    )
    return float(sum(w * t for w, t in zip(weights, terms, strict=True)))


def hypervolume(objectives: NDArray[np.float64], nominal: Performance) -> float:
    """Hypervolume of feasible designs' objectives ``(n, 3)`` (:func:`objective_vector`) relative to the nominal
    design's, against :data:`HYPERVOLUME_REFERENCE`; 0 for none."""
    objectives = np.asarray(objectives, dtype=float).reshape(-1, len(OBJECTIVES))
    if objectives.size == 0:
        return 0.0
    scale = np.array([nominal.workspace_m3, nominal.peak_torque_nm, nominal.picks_per_min])
    return float(HV(ref_point=np.array(HYPERVOLUME_REFERENCE))(objectives / scale))


@dataclass
class Archive:
    """Every design evaluated, in order: vectors (m), objectives, constraints and figures."""

    x: list[NDArray[np.float64]] = field(default_factory=list)
    f: list[NDArray[np.float64]] = field(default_factory=list)
    g: list[NDArray[np.float64]] = field(default_factory=list)
    performance: list[Performance] = field(default_factory=list)

    def add(self, x: NDArray[np.float64], performance: Performance) -> tuple[NDArray, NDArray]:
        f, g = objective_vector(performance), constraint_vector(performance)
        self.x.append(np.array(x, dtype=float))
        self.f.append(f)
        self.g.append(g)
        self.performance.append(performance)
        return f, g

    @classmethod
    def merged(cls, archives: Sequence[Archive]) -> Archive:
        """One archive of every evaluation of ``archives``, in their order (the front of every search at once)."""
        merged = cls()
        for archive in archives:
            merged.x += archive.x
            merged.f += archive.f
            merged.g += archive.g
            merged.performance += archive.performance
        return merged

    def pareto_indices(self) -> NDArray[np.int_]:
        """Indices of the feasible, non-dominated, distinct designs among everything evaluated."""
        feasible = np.flatnonzero([np.all(g <= 0.0) for g in self.g])
        if feasible.size == 0:
            return feasible
        objectives = np.array([self.f[i] for i in feasible])
        _, unique = np.unique(np.round(objectives, 12), axis=0, return_index=True)
        candidates = feasible[np.sort(unique)]
        front = NonDominatedSorting().do(np.array([self.f[i] for i in candidates]), only_non_dominated_front=True)
        return candidates[np.sort(front)]


class DesignProblem(ElementwiseProblem):
    """The three-objective problem; also the single-objective one when ``cost`` is given.

    Args:
        bounds: Box of the design variables.
        archive: Collects every evaluation.
        cost: Maps a design's performance to one cost (single-objective GA), or None for three objectives.
        evaluate_design: The figures of a geometry (:func:`eval.design.performance.evaluate`).
    """

    def __init__(
        self,
        bounds: DesignBounds,
        archive: Archive,
        cost: Callable[[Performance], float] | None = None,
        evaluate_design: Callable[[DeltaGeometry], Performance] = evaluate,
    ) -> None:
        super().__init__(n_var=4, n_obj=1 if cost else 3, n_ieq_constr=CONSTRAINTS, xl=bounds.lower, xu=bounds.upper)
        self.archive = archive
        self.cost = cost
        self.evaluate_design = evaluate_design

    def _evaluate(self, x: NDArray[np.float64], out: dict, *args: object, **kwargs: object) -> None:
        performance = self.evaluate_design(geometry_of(x))
        f, g = self.archive.add(x, performance)
        if self.cost is not None:
            cost = self.cost(performance)
            f = np.array([cost if math.isfinite(cost) else PENALTY_COST])
        out["F"], out["G"] = f, g


class _Progress(Callback):
    """Per generation: the convergence record, and an update of the tqdm ``bar`` unless it is None."""

    def __init__(self, bar: object, record: Callable[[object], dict[str, float]]) -> None:
        super().__init__()
        self.bar, self.record, self.history = bar, record, []

    def notify(self, algorithm: object) -> None:
        counts = {"generation": algorithm.n_gen, "evaluations": algorithm.evaluator.n_eval}
        self.history.append({**counts, **self.record(algorithm)})
        if self.bar is not None:
            self.bar.update()


@dataclass(frozen=True)
class ParetoResult:
    """NSGA-II outcome.

    Attributes:
        archive: Every evaluation.
        front: Archive indices of the Pareto designs (feasible, non-dominated, distinct).
        convergence: Per generation: evaluations and hypervolume of the feasible population.
    """

    archive: Archive
    front: NDArray[np.int_]
    convergence: list[dict[str, float]]


@dataclass(frozen=True)
class SingleObjectiveResult:
    """GA outcome.

    Attributes:
        archive: Every evaluation.
        best: Archive index of the best design.
        convergence: Per generation: best and mean weighted cost of the feasible population.
    """

    archive: Archive
    best: int
    convergence: list[dict[str, float]]


@dataclass(frozen=True)
class SearchSettings:
    """Size and seed of a genetic search.

    Attributes:
        population: Population size, >= 4.
        generations: Generations, >= 1.
        seed: Seed of pymoo's random operators.
    """

    population: int = 40
    generations: int = 25
    seed: int = 0

    def __post_init__(self) -> None:
        require_count("population", self.population, minimum=4)
        require_count("generations", self.generations, minimum=1)


def _no_feasible(archive: Archive, what: str) -> RuntimeError:
    g = np.array(archive.g)
    names = (
        "task region shortfall (m)",
        "assembly gap l2 - (ra - rb + l1) short by (m)",
        "torque excess (N m)",
        "platform radius short of the ball joints' by (m)",
        "data-sheet cylinder top short by (m)",
    )
    worst = ", ".join(f"{name}: best {value:.3g}" for name, value in zip(names, g.min(axis=0), strict=True))
    return RuntimeError(f"{what}: no feasible design in {len(g)} evaluations ({worst}); widen the bounds")


def _search(
    problem: DesignProblem,
    algorithm: object,
    settings: SearchSettings,
    progress: object,
    record: Callable[[object], dict[str, float]],
) -> list[dict[str, float]]:
    """Run ``algorithm`` on ``problem``; the per-generation convergence record."""
    callback = _Progress(progress, record)
    minimize(problem, algorithm, ("n_gen", settings.generations), seed=settings.seed, callback=callback, verbose=False)
    return callback.history


def pareto_front(
    nominal: Performance,
    settings: SearchSettings = SearchSettings(),
    *,
    bounds: DesignBounds = DEFAULT_BOUNDS,
    progress: object = None,
) -> ParetoResult:
    """NSGA-II over ``bounds``; reproducible for a seed.

    Args:
        nominal: The nominal design's figures (normalizes the hypervolume).
        settings: Population, generations and seed.
        bounds: Box of the design variables.
        progress: A tqdm bar updated once per generation, or None.

    Raises:
        RuntimeError: if no evaluated design satisfies the constraints.
    """
    archive = Archive()

    def record(algorithm: object) -> dict[str, float]:
        pop = algorithm.pop
        return {"hypervolume": hypervolume(pop.get("F")[pop.get("FEAS").ravel()], nominal)}

    history = _search(DesignProblem(bounds, archive), NSGA2(pop_size=settings.population), settings, progress, record)
    front = archive.pareto_indices()
    if front.size == 0:
        raise _no_feasible(archive, "NSGA-II")
    return ParetoResult(archive=archive, front=front, convergence=history)


def single_objective(
    nominal: Performance,
    settings: SearchSettings = SearchSettings(),
    *,
    bounds: DesignBounds = DEFAULT_BOUNDS,
    progress: object = None,
) -> SingleObjectiveResult:
    """A GA on :func:`weighted_cost` over ``bounds``; arguments as :func:`pareto_front`."""
    archive = Archive()

    def cost(performance: Performance) -> float:
        return weighted_cost(performance, nominal)

    def record(algorithm: object) -> dict[str, float]:
        pop = algorithm.pop
        feasible = pop.get("FEAS").ravel()
        values = pop.get("F")[feasible, 0]
        if values.size == 0:
            return {"best_cost": math.nan, "mean_cost": math.nan}
        return {"best_cost": float(values.min()), "mean_cost": float(values.mean())}

    algorithm = GA(pop_size=settings.population, eliminate_duplicates=True)
    history = _search(DesignProblem(bounds, archive, cost=cost), algorithm, settings, progress, record)
    feasible = [i for i, g in enumerate(archive.g) if np.all(g <= 0.0)]
    if not feasible:
        raise _no_feasible(archive, "GA")
    best = min(feasible, key=lambda i: cost(archive.performance[i]))
    return SingleObjectiveResult(archive=archive, best=best, convergence=history)


def design_roles(result: ParetoResult, nominal: Performance) -> dict[str, int]:
    """Designs of the front for each role whose claim their figures bear out (archive indices; one design may
    fill several roles):

    - ``compromise``: closest to the ideal point in objectives relative to the front's range;
    - ``paper targets``: the design that beats all three of :data:`PAPER_TARGETS` (workspace gain, torque
      reduction, pick-rate gain P / P0 - 1) by the largest common factor;
    - ``low torque``: least peak torque among designs with at least the nominal workspace and less peak torque
      than the nominal robot;
    - ``large workspace``: largest workspace among designs with at most the nominal peak torque and more
      workspace than the nominal robot;
    - ``weighted-cost optimum``: :func:`weighted_cost_optimum`.

    A role no front design bears out is left out (:func:`unfilled_roles` names it).
    """
    front = result.front
    f = np.array([result.archive.f[i] for i in front])
    span = np.ptp(f, axis=0)
    span[span == 0.0] = 1.0
    distance = np.linalg.norm((f - f.min(axis=0)) / span, axis=1)
    roles = {"compromise": int(front[np.argmin(distance)])}
    workspace, torque = -f[:, 0], f[:, 1]
    gains = np.column_stack(
        (
            workspace / nominal.workspace_m3 - 1.0,
            1.0 - torque / nominal.peak_torque_nm,
            -f[:, 2] / nominal.picks_per_min - 1.0,
        )
    )
    margin = np.min(gains / np.array(PAPER_TARGETS), axis=1)
    if margin.max() >= 1.0:
        roles["paper targets"] = int(front[np.argmax(margin)])
    lighter = np.flatnonzero((workspace >= nominal.workspace_m3) & (torque < nominal.peak_torque_nm))
    if lighter.size:
        roles["low torque"] = int(front[lighter[np.argmin(torque[lighter])]])
    wider = np.flatnonzero((torque <= nominal.peak_torque_nm) & (workspace > nominal.workspace_m3))
    if wider.size:
        roles["large workspace"] = int(front[wider[np.argmax(workspace[wider])]])
    roles["weighted-cost optimum"] = weighted_cost_optimum(result, nominal)
    return roles


ROLES = ("compromise", "paper targets", "low torque", "large workspace", "weighted-cost optimum")
"""The roles of :func:`design_roles`, in the order a design filling several is named by the first."""


def choose_designs(roles: dict[str, int]) -> dict[str, int]:
    """The distinct designs of ``roles`` (:func:`design_roles`), each named once, by its first role."""
    chosen: dict[str, int] = {}
    for name, index in roles.items():
        if index not in chosen.values():
            chosen[name] = index
    return chosen


def unfilled_roles(roles: dict[str, int]) -> list[str]:
    """The roles of :data:`ROLES` that no front design bears out."""
    return [name for name in ROLES if name not in roles]


def shared_roles(roles: dict[str, int]) -> dict[str, str]:
    """The roles filled by a design already named by an earlier role: ``{role: the design's name}``."""
    chosen = choose_designs(roles)
    names = {index: name for name, index in chosen.items()}
    return {role: names[index] for role, index in roles.items() if role not in chosen}


def weighted_cost_optimum(result: ParetoResult, nominal: Performance) -> int:
    """Archive index of the front design of least :func:`weighted_cost`: the least over every feasible design
    evaluated, since the cost grows with each objective (so its minimum is never dominated)."""
    return int(min(result.front, key=lambda i: weighted_cost(result.archive.performance[i], nominal)))
