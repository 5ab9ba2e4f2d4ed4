"""Sweep throughput (episodes/s) of both backends with 1 and 2 workers, and a cluster projection.

Runs the same grid (one scenario, PD and MId+F+R+RLS+PD, ``--episodes`` seeds from ``--seed``) into a fresh
results table for each (backend, workers) and prints, per configuration: the wall time including start-up (pool or Ray),
the start-up time (until the first episode is written), the steady rate after it, with ratios to the
local backend with one worker (episodes run in this process), and the mean CPU time of an episode. On a
machine shared with other jobs the wall rates carry their load; the CPU time does not. The projection
scales to ``--nodes`` nodes of ``--cpus-per-node`` workers twice: from the measured steady rate per Ray
worker, and from the CPU time per episode (one idle core per worker), each plus the Ray start-up, for a sweep of
``--projected-episodes`` episodes.

Usage: python scripts/sweep_throughput.py [--seed 0 --episodes 20] [--scenario nominal] [--geometry FILE]
                                         [--nodes 10 --cpus-per-node 2] [--projected-episodes 10000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from eval.console import CommandParser
from eval.engine import prepare
from eval.scenario_args import add_scenario_arguments, check_ranges, scenario_from_arguments
from eval.sweep.runner import ResultsTable, run_sweep
from eval.sweep.work import setup_digest
from eval.work import WorkUnit, code_version

CONFIGURATIONS = (("local", 1), ("local", 2), ("ray", 1), ("ray", 2))


class Clock:
    """Stands in for the progress bar: records when each episode is written."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def update(self, n: int = 1) -> None:
        if n > 0:  # run_sweep first reports the units already done (none here)
            self.times.append(time.perf_counter())


def measure(units: list[WorkUnit], backend: str, workers: int, setup, version: str) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        clock = Clock()
        table = ResultsTable(Path(folder) / "results.csv")
        started = time.perf_counter()
        content = units[0].scenario.content_hash
        setups = {content: setup}
        digests = {(content, unit.controller): setup_digest(setup, unit.controller) for unit in units}
        counts = run_sweep(units, setups, table, version, digests, backend=backend, workers=workers, progress=clock)
        wall = time.perf_counter() - started
        cpu = statistics.fmean(float(row["cpu_seconds"]) for row in table.load())
    if counts["failed"]:
        raise RuntimeError(f"{counts['failed']} episodes failed in the {backend} x {workers} run")
    finished = clock.times
    first, last = finished[0], finished[-1]
    return {
        "wall_s": wall,
        "startup_s": first - started,
        "rate_total": len(units) / wall,
        "rate_steady": (len(finished) - 1) / (last - first),
        "cpu_s": cpu,
    }


def main() -> int:
    parser = CommandParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scenario_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per controller (default 20)")
    parser.add_argument("--nodes", type=int, default=10, help="nodes of the projected cluster (default 10)")
    parser.add_argument("--cpus-per-node", type=int, default=2, help="workers per projected node (default 2)")
    parser.add_argument(
        "--projected-episodes", type=int, default=10_000, help="episodes of the projected sweep (default 10000)"
    )
    args = parser.parse_args()
    counts = {"seed": 0, "episodes": 1, "nodes": 1, "cpus_per_node": 1, "projected_episodes": 1}
    check_ranges(parser, args, counts)
    scenario = scenario_from_arguments(args, parser)
    controllers = ("pd", "mid_f_rls")
    setup = prepare(scenario, controllers).setup
    version = code_version()
    units = [
        WorkUnit(scenario, key, seed) for key in controllers for seed in range(args.seed, args.seed + args.episodes)
    ]
    print(f"{len(units)} episodes of {scenario.name} ({scenario.task.n_cycles} cycles), PD and MId+F+R+RLS+PD")
    load_before = f"{os.getloadavg()[0]:.2f}"
    results = {}
    for backend, workers in CONFIGURATIONS:
        results[backend, workers] = measure(units, backend, workers, setup, version)
    base = results["local", 1]["rate_steady"]
    print(f"load average before / after: {load_before} / {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(
        "| backend | workers | wall (s) | start-up (s) | episodes/s incl. start-up | steady episodes/s | ratio "
        "| CPU s/episode |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (backend, workers), r in results.items():
        print(
            f"| {backend} | {workers} | {r['wall_s']:.1f} | {r['startup_s']:.1f} | {r['rate_total']:.2f} "
            f"| {r['rate_steady']:.2f} | {r['rate_steady'] / base:.2f} | {r['cpu_s']:.3f} |"
        )
    ray2 = results["ray", 2]
    workers = args.nodes * args.cpus_per_node
    for basis, per_worker in (("measured steady rate", ray2["rate_steady"] / 2), ("CPU time", 1.0 / ray2["cpu_s"])):
        minutes = (ray2["startup_s"] + args.projected_episodes / (per_worker * workers)) / 60
        print(
            f"Projection from the {basis} ({per_worker:.2f} episodes/s per worker): {args.projected_episodes} "
            f"episodes on {args.nodes} nodes x {args.cpus_per_node} workers take {minutes:.1f} min"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
