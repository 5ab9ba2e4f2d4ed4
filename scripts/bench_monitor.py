"""Benchmark: the fault monitor's cost per 1 kHz step, in microseconds and against one raw mj_step, in one run.

Replays the observations and commands of two recorded episodes (a monitored ``mid_f_rls`` row on the default
scenario) through a fresh :func:`~controllers.registry.fault_monitor`: one without faults (healthy readings, the
common case) and one with sensor and drive faults (every check's replacement and CUSUM paths run too). Each timing
block replays a whole episode and times one mj_step beside it, so that the ratio is formed within the block; the
median over the blocks is printed with the spread (the lowest and the highest block). Times are the CPU time of
this thread (``time.thread_time``), which other processes on a busy machine do not inflate.

Usage: python scripts/bench_monitor.py [--blocks B]
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np

from controllers.base import Observation
from controllers.dynamics import ModelParameters
from controllers.monitor import MonitoredController
from controllers.registry import ControllerSetup, build_controller, fault_monitor
from delta_env.env import DeltaPickPlaceEnv
from delta_env.faults import FaultSpec
from eval.scenario_args import check_ranges

# Representative identified values (python -m eval.identification on the default plant, rounded), as scripts/bench.py.
SETUP = ControllerSetup(
    mid=ModelParameters(rho1=1.80, rho2=0.94),
    mid_f=ModelParameters(rho1=1.76, rho2=0.88, viscous=(1.97, 2.41, 1.73), coulomb=(4.07, 3.35, 4.46)),
    mid_f_rods=ModelParameters(rho1=1.95, rho2=0.951, viscous=(2.01, 2.41, 1.71), coulomb=(3.98, 3.38, 4.59)),
    drive_lag=(0.001, 0.001, 0.001),
)

FAULTS = (
    FaultSpec("encoder_stuck", carry_fraction=(0.5, 0.5), duration=(0.03, 0.03), joint=0),
    FaultSpec("encoder_glitch", carry_fraction=(0.8, 0.8), size=(0.02, 0.02), joint=2),
    FaultSpec("torque_glitch", carry_fraction=(0.3, 0.3), size=(50.0, 50.0), joint=1),
    FaultSpec("drive_fault", carry_fraction=(0.2, 0.2), size=(0.0, 0.0), duration=(0.03, 0.03), joint=0),
    FaultSpec("sensor_nan", carry_fraction=(0.9, 0.9), duration=(0.002, 0.002), joint=1, sensor="torque"),
    FaultSpec("collision", carry_fraction=(0.6, 0.6), size=(400.0, 400.0), duration=(0.03, 0.03)),
)
"""The faulty episode's faults, spread over its carries."""


def recorded_steps(faults: tuple[FaultSpec, ...], seed: int) -> list[tuple[Observation, np.ndarray | None]]:
    """(observation, command sent before it) of each step of a monitored ``mid_f_rls`` episode."""
    env = DeltaPickPlaceEnv(faults=list(faults), n_cycles=3, release="timed")
    controller = build_controller("mid_f_rls", SETUP)
    assert isinstance(controller, MonitoredController)
    observation, _ = env.reset(seed=seed)
    controller.reset()
    steps: list[tuple[Observation, np.ndarray | None]] = []
    command = None
    done = False
    while not done:
        steps.append((observation, command))
        command = controller(observation)
        observation, _, terminated, truncated, _ = env.step(command)
        done = terminated or truncated
    return steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--blocks", type=int, default=9, help="timing blocks per episode (the median is reported)")
    args = parser.parse_args()
    check_ranges(parser, args, {"blocks": 1})

    episodes = {"healthy": recorded_steps((), seed=3), "faulty": recorded_steps(FAULTS, seed=3)}
    env = DeltaPickPlaceEnv()
    env.reset(seed=0)
    model, data = env.plant.model, env.plant.data
    monitor = fault_monitor(SETUP)
    for name, steps in episodes.items():
        monitor.reset()
        for observation, command in steps:  # one-off costs (loading compiled code) are not per-step costs
            monitor.update(observation, command)
        micros: list[float] = []
        ratios: list[float] = []
        for _ in range(args.blocks):
            monitor.reset()
            start = time.thread_time()
            for observation, command in steps:
                monitor.update(observation, command)
            seconds = (time.thread_time() - start) / len(steps)
            start = time.thread_time()
            for _ in range(len(steps)):
                mujoco.mj_step(model, data)
            mj_step = (time.thread_time() - start) / len(steps)
            micros.append(1e6 * seconds)
            ratios.append(seconds / mj_step)
        print(
            f"{name:8s} ({len(steps)} steps, {len(monitor.events)} detections): "
            f"{statistics.median(micros):5.2f} us per step [{min(micros):5.2f}, {max(micros):5.2f}], "
            f"{statistics.median(ratios):5.2f} mj_step [{min(ratios):5.2f}, {max(ratios):5.2f}]"
        )


if __name__ == "__main__":
    main()
