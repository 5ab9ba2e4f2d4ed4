"""Benchmark: what time-optimal timing buys on the 25/305/25 mm carry, and where the planner's time goes.

For payloads 0 to 8 kg, plans the standard carry (:func:`delta_env.cycles.standard_cycle`'s shape and heading,
centre (0, 0, -0.9) m) with :class:`controllers.timing.TimeOptimalPlanner` on an MId+F+R-like model
(forearm rods, rho1 = rho2 = 1, 2 N m s/rad viscous and 4 N m Coulomb friction per joint, about the plant's)
and a 1 ms drive lag, and prints per payload: raw and smoothed move time, peak Cartesian acceleration, peak
joint speed, the planner's wall time and where it went, and the uniform-scaling baseline: the shortest
T of today's quintic timing (tau = t / T) that keeps the same model within the same shrunk envelope.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence

import numpy as np

from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.timing import TimeOptimalPlanner
from delta_env import kinematics
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.drive import DriveLimits
from delta_env.geometry import GRAVITY
from delta_env.timing import TimeLaw, move_samples
from delta_env.trajectories import WORKING_HEIGHT, Segment
from eval.console import CommandParser

PAYLOADS = (0.0, 1.0, 2.0, 4.0, 8.0)
"""Payloads of the table (kg)."""

FRICTION = ModelParameters(viscous=(2.0, 2.0, 2.0), coulomb=(4.0, 4.0, 4.0))
"""Roughly the plant's joint friction."""


def standard_carry(heading: float = math.pi / 2) -> Segment:
    """The 25/305/25 mm carry from pick to place through (0, 0, -0.9) m, as in ``standard_cycle``."""
    centre = np.array([0.0, 0.0, WORKING_HEIGHT])
    half = 0.5 * STANDARD_TRAVEL * np.array([math.cos(heading), math.sin(heading), 0.0])
    return Segment(centre - half, centre + half, 1.0, STANDARD_LIFT, 0.3)


def uniform_law(samples: int, dt: float) -> TimeLaw:
    """tau = t / T with T = samples * dt; tau_dot is 0 at the two ends, where the shape's x' = x'' = 0."""
    tau = np.arange(samples + 1) / samples
    tau_dot = np.full(samples + 1, 1.0 / (samples * dt))
    tau_dot[[0, -1]] = 0.0
    return TimeLaw(dt, tau, tau_dot, np.zeros(samples + 1))


def uniform_baseline(planner: TimeOptimalPlanner, shape: Segment, payload: float) -> TimeLaw:
    """The shortest uniformly scaled quintic law (whole samples) that the planner's verification passes."""
    low, high = 2, 2
    while planner.utilisation(shape, uniform_law(high, planner.dt), payload).max() > 1.0:
        low, high = high, 2 * high
    while high - low > 1:
        middle = (low + high) // 2
        passes = planner.utilisation(shape, uniform_law(middle, planner.dt), payload).max() <= 1.0
        low, high = (low, middle) if passes else (middle, high)
    return uniform_law(high, planner.dt)


def peaks(dynamics: DeltaDynamics, shape: Segment, law: TimeLaw) -> tuple[float, float]:
    """Peak Cartesian acceleration (g) and peak joint speed (rad/s) of ``shape`` timed by ``law``."""
    x, xd, xdd = move_samples(shape, law)
    _, qd, _ = kinematics.cartesian_to_joint(dynamics.geometry, x, xd, xdd)
    return float(np.linalg.norm(xdd, axis=1).max() / GRAVITY), float(np.abs(qd).max())


def main(argv: Sequence[str] | None = None) -> int:
    summary, _, details = __doc__.partition("\n\n")
    CommandParser(
        prog="python scripts/plan_times.py",
        description=summary,
        epilog=details,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    ).parse_args(argv)
    dynamics = DeltaDynamics.nominal(FRICTION, forearm_rods=True)
    planner = TimeOptimalPlanner(dynamics, DriveLimits(), drive_lag=1e-3)
    shape = standard_carry()
    planner.plan(shape, 0.0)  # warm-up: imports and compiled paths outside the timing
    print(f"margin {planner.margin:.0%} of peak torque and max speed, smoothing {planner.smoothing * 1e3:.0f} ms")
    print(
        "| payload (kg) | raw (ms) | smoothed (ms) | peak acc (g) | peak speed (rad/s) | scale | plan (ms) "
        "| toppra / constraints / verification (ms) | uniform T (ms) | uniform peak acc (g) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for payload in PAYLOADS:
        clock = time.perf_counter()
        law = planner.plan(shape, payload)
        wall = time.perf_counter() - clock
        acceleration, speed = peaks(dynamics, shape, law)
        baseline = uniform_baseline(planner, shape, payload)
        stats = law.stats
        parts = f"{stats.toppra * 1e3:.0f} / {stats.constraints * 1e3:.0f} / {stats.verification * 1e3:.0f}"
        print(
            f"| {payload:g} | {law.raw.duration * 1e3:.1f} | {law.duration * 1e3:.0f} | {acceleration:.1f} "
            f"| {speed:.1f} | {stats.scale:.3f} | {wall * 1e3:.0f} | {parts} | {baseline.duration * 1e3:.0f} "
            f"| {peaks(dynamics, shape, baseline)[0]:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
