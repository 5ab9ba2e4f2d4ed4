"""The study's front: NSGA-II and the weighted-cost GA on several seeds, every archive merged.

Each optimizer runs once per seed, the runs in processes (:func:`eval.processes.run_jobs`); the archives of
all of them are merged before the non-dominated filter (:meth:`eval.design.optimize.Archive.merged`), so the
front, and every design chosen from it, is non-dominated against every design any run evaluated. Convergence
is each run's per-generation record: NSGA-II's population hypervolume (:func:`eval.design.optimize.hypervolume`)
and the GA's best and mean weighted cost; :func:`convergence_summary` says whether the hypervolume still rises
at the last generation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from eval.design.optimize import (
    DEFAULT_BOUNDS,
    Archive,
    DesignBounds,
    ParetoResult,
    SearchSettings,
    hypervolume,
    pareto_front,
    single_objective,
)
from eval.design.performance import Performance
from eval.processes import run_jobs

NSGA2_NAME = "NSGA-II"
"""Name of the three-objective search in the convergence record."""

GA_NAME = "GA"
"""Name of the weighted-cost search in the convergence record."""

SEARCH_SEEDS = 3
"""Seeds of each optimizer in a default study: the fewest that show a seed-to-seed spread."""

RISE_WINDOW = 0.2
"""Share of the generations over which :func:`convergence_summary` measures the hypervolume's last rise."""

STILL_RISING = 0.005
"""Relative hypervolume rise over the last :data:`RISE_WINDOW` of the generations above which a run is read as
still rising (0.5 %)."""


@dataclass(frozen=True)
class SearchJob:
    """One optimizer on one seed: ``optimizer`` is :data:`NSGA2_NAME` or :data:`GA_NAME`."""

    optimizer: str
    nominal: Performance
    settings: SearchSettings
    bounds: DesignBounds


@dataclass(frozen=True)
class SearchRun:
    """What one job found: every evaluation and the per-generation record."""

    optimizer: str
    seed: int
    archive: Archive
    convergence: list[dict[str, float]]


def run_job(job: SearchJob) -> SearchRun:
    """Run ``job`` (a process pool's unit of work)."""
    search = {NSGA2_NAME: pareto_front, GA_NAME: single_objective}[job.optimizer]
    result = search(job.nominal, job.settings, bounds=job.bounds)
    return SearchRun(job.optimizer, job.settings.seed, result.archive, result.convergence)


@dataclass(frozen=True)
class MergedSearch:
    """Every run and their merged front.

    Attributes:
        runs: NSGA-II on each seed, then the GA on the first.
        result: The merged archive (the runs' archives in ``runs`` order) and its front; ``convergence`` holds
            every run's records, each with its optimizer and seed.
    """

    runs: tuple[SearchRun, ...]
    result: ParetoResult

    def source(self, index: int) -> tuple[str, int]:
        """(optimizer, seed) of the run that evaluated the merged archive's design ``index``."""
        ends = np.cumsum([len(run.archive.x) for run in self.runs])
        run = self.runs[int(np.searchsorted(ends, index, side="right"))]
        return run.optimizer, run.seed


def search(
    nominal: Performance,
    population: int,
    generations: int,
    seeds: Sequence[int],
    *,
    workers: int = 1,
    bounds: DesignBounds = DEFAULT_BOUNDS,
    progress: object = None,
) -> MergedSearch:
    """NSGA-II on each of ``seeds`` and the GA on the first, on ``workers`` processes, merged into one front.

    The GA minimizes one cost and adds its designs to the front; the front's convergence over seeds is
    NSGA-II's. One GA run instead of one per seed keeps the default study within its 10 minutes.

    Args:
        nominal: The nominal design's figures (the GA's cost and the hypervolume are relative to it).
        population: Population of every run, >= 4.
        generations: Generations of every run, >= 1.
        seeds: Seeds of the runs, at least one, distinct.
        workers: Processes, >= 1.
        bounds: Box of the design variables.
        progress: A tqdm bar advanced once per finished run, or None.

    Raises:
        ValueError: for no seeds or repeated ones.
        RuntimeError: if a run finds no feasible design.
    """
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be at least one, all distinct, got {list(seeds)!r}")
    jobs = [SearchJob(NSGA2_NAME, nominal, SearchSettings(population, generations, seed), bounds) for seed in seeds]
    jobs.append(SearchJob(GA_NAME, nominal, SearchSettings(population, generations, seeds[0]), bounds))
    runs = tuple(run_jobs(run_job, jobs, workers=workers, progress=progress))
    archive = Archive.merged([run.archive for run in runs])
    records = [{"optimizer": run.optimizer, "seed": run.seed, **row} for run in runs for row in run.convergence]
    return MergedSearch(runs, ParetoResult(archive=archive, front=archive.pareto_indices(), convergence=records))


def front_hypervolume(archive: Archive, nominal: Performance) -> float:
    """Hypervolume (:func:`eval.design.optimize.hypervolume`) of ``archive``'s front."""
    return hypervolume(np.array([archive.f[i] for i in archive.pareto_indices()]), nominal)


@dataclass(frozen=True)
class SeedConvergence:
    """One NSGA-II run's convergence.

    Attributes:
        seed: Its seed.
        final: Population hypervolume at the last generation.
        rise: Its relative rise over the last :data:`RISE_WINDOW` of the generations.
        front: Hypervolume of the run's own front (everything it evaluated).
    """

    seed: int
    final: float
    rise: float
    front: float

    @property
    def still_rising(self) -> bool:
        """Whether the rise exceeds :data:`STILL_RISING`."""
        return self.rise > STILL_RISING


def convergence_summary(merged: MergedSearch, nominal: Performance) -> list[SeedConvergence]:
    """Each NSGA-II run's final hypervolume, its last rise and its own front's hypervolume."""
    summaries = []
    for run in merged.runs:
        if run.optimizer != NSGA2_NAME:
            continue
        values = [row["hypervolume"] for row in run.convergence]
        window = max(1, round(RISE_WINDOW * len(values)))
        earlier = values[max(0, len(values) - 1 - window)]
        rise = values[-1] / earlier - 1.0 if earlier > 0.0 else float("inf")
        summaries.append(SeedConvergence(run.seed, values[-1], rise, front_hypervolume(run.archive, nominal)))
    return summaries


def convergence_text(merged: MergedSearch, nominal: Performance) -> str:
    """A paragraph of the summary: hypervolume per seed, whether it still rises, and what merging adds."""
    seeds = convergence_summary(merged, nominal)
    finals = np.array([s.final for s in seeds])
    window = max(1, round(RISE_WINDOW * len(merged.runs[0].convergence)))
    rising = sum(s.still_rising for s in seeds)
    origins = [merged.source(i)[0] for i in merged.result.front]
    return (
        f"NSGA-II population hypervolume at the last generation, seeds {', '.join(str(s.seed) for s in seeds)}: "
        f"{', '.join(f'{s.final:.4f}' for s in seeds)} (mean {finals.mean():.4f} ± {finals.std():.4f}); rise over "
        f"the last {window} generations: {', '.join(f'{100 * s.rise:+.2f} %' for s in seeds)}: still rising "
        f"(> {100 * STILL_RISING:.1f} %) in {rising} of {len(seeds)} seeds. Hypervolume of each seed's own front "
        f"{', '.join(f'{s.front:.4f}' for s in seeds)}; of the merged front "
        f"{front_hypervolume(merged.result.archive, nominal):.4f} ({len(merged.result.front)} designs of "
        f"{len(merged.result.archive.x)} evaluated: {origins.count(NSGA2_NAME)} from NSGA-II, "
        f"{origins.count(GA_NAME)} from the GA)."
    )


def plot_convergence(merged: MergedSearch, nominal: Performance, path: Path) -> None:
    """GA cost and NSGA-II hypervolume per generation, one line per seed, and the merged front's hypervolume
    (the second paper's Fig. 9)."""
    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    seeds = sorted({run.seed for run in merged.runs})
    for run in merged.runs:
        colour = colours[seeds.index(run.seed) % len(colours)]
        generations = [row["generation"] for row in run.convergence]
        if run.optimizer == GA_NAME:
            left.plot(generations, [row["best_cost"] for row in run.convergence], "-", color=colour)
            left.plot(generations, [row["mean_cost"] for row in run.convergence], ":", color=colour)
        else:
            values = [row["hypervolume"] for row in run.convergence]
            right.plot(generations, values, "-", color=colour, label=f"seed {run.seed}")
    right.axhline(
        front_hypervolume(merged.result.archive, nominal), color="k", lw=1.0, ls="--", label="merged front (all runs)"
    )
    left.axhline(1.0, color="grey", lw=0.8)
    left.set(
        xlabel="generation", ylabel="weighted cost (nominal = 1)", title="GA: best (solid), feasible mean (dotted)"
    )
    right.set(xlabel="generation", ylabel="hypervolume (nominal-relative objectives)", title="NSGA-II population")
    right.legend(fontsize=8)
    for axis in (left, right):
        axis.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
