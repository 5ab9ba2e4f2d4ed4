"""Benchmark: the cost of env.step and of the controllers against raw mj_step, in one run.

Prints ratios, not absolute times, because only ratios carry over between machines:
``physics ratio = time(n_substeps x mj_step) / time(env.step)`` (goal >= 0.7: the env's own work costs
less than half its physics) and ``controller cost = time(controller call) / time(one mj_step)`` (goal <= 1)
for every controller of ``python -m eval``, called on the observations of the same rollout: over the whole
episode and over the steps while the gripper holds (when the payload RLS runs). The model parameters are
representative values: the cost does not depend on them.

Times are the CPU time of this thread (``time.thread_time``), which other processes on a busy machine do not
inflate by taking the core away. The rollout is cut into blocks; every block times the physics, the env and
each controller back to back, so that each ratio is formed within one block. The median over the blocks is
printed with the spread (the lowest and the highest block).

Usage: python scripts/bench.py [--steps N] [--blocks B]
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time
from collections.abc import Callable, Sequence

import mujoco
import numpy as np

from controllers.base import PDController, Privileged
from controllers.dynamics import ModelParameters
from controllers.registry import (
    CONTROLLER_LABELS,
    ESTIMATOR_REGRESSORS,
    ControllerSetup,
    build_controller,
    fault_monitor,
)
from delta_env.env import DeltaPickPlaceEnv
from eval.scenario_args import check_ranges

# Representative identified values (python -m eval.identification on the default plant, rounded).
SETUP = ControllerSetup(
    mid=ModelParameters(rho1=1.80, rho2=0.94),
    mid_f=ModelParameters(rho1=1.76, rho2=0.88, viscous=(1.97, 2.41, 1.73), coulomb=(4.07, 3.35, 4.46)),
    mid_f_rods=ModelParameters(rho1=1.95, rho2=0.951, viscous=(2.01, 2.41, 1.71), coulomb=(3.98, 3.38, 4.59)),
    drive_lag=(0.001, 0.001, 0.001),
    tares=dict.fromkeys(ESTIMATOR_REGRESSORS, -0.02),
)


def per_call_seconds(function: Callable[[], object], calls: int) -> float:
    """Mean CPU time (s) of one call over ``calls`` calls."""
    start = time.thread_time()
    for _ in range(calls):
        function()
    return (time.thread_time() - start) / calls


def runs(flags: Sequence[bool]) -> list[tuple[int, int, bool]]:
    """(start, stop, flag) of the runs of equal consecutive ``flags``."""
    edges = [0] + [n for n in range(1, len(flags)) if flags[n] != flags[n - 1]] + [len(flags)]
    return [(start, stop, flags[start]) for start, stop in itertools.pairwise(edges)]


def spread(ratios: Sequence[float]) -> str:
    """``median [lowest, highest]`` of per-block ratios."""
    return f"{statistics.median(ratios):5.2f} [{min(ratios):5.2f}, {max(ratios):5.2f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200, help="control steps per timing block")
    parser.add_argument("--blocks", type=int, default=12, help="timing blocks (the median is reported)")
    args = parser.parse_args()
    check_ranges(parser, args, {"steps": 1, "blocks": 1})

    env = DeltaPickPlaceEnv(n_cycles=3)
    masses = {"payload_masses": np.full(3, 2.0)}
    # The actions of a PD rollout, replayed below: env.step and raw mj_step see the same motion.
    pd = PDController()
    observation, _ = env.reset(seed=0, options=masses)
    actions, observations = [], []
    for _ in range(args.steps * args.blocks):
        actions.append(pd(observation))
        observations.append(observation)
        observation, *_ = env.step(actions[-1])

    # The controllers proper, without the fault monitor every row runs behind: the monitor is timed on its own.
    controllers = {label: build_controller(key, SETUP, env).controller for key, label in CONTROLLER_LABELS.items()}
    for controller in controllers.values():
        if isinstance(controller, Privileged):
            controller.set_payload_masses(masses["payload_masses"])  # the oracle bound's truth
            controller.set_reference(env.trajectory)  # the reference the observations replay
        controller.reset()
        # One-off costs (loading compiled code) are not per-step costs: past the payload estimator's first
        # equation, which waits for the joint smoother's lag.
        for observation in observations[:20]:
            controller(observation)
        controller.reset()

    env.reset(seed=0, options=masses)
    model = env.plant.model
    raw_data = mujoco.MjData(model)
    physics: list[float] = []
    raw_seconds: list[float] = []
    mj_step_seconds: list[float] = []
    whole: dict[str, list[float]] = {label: [] for label in controllers}
    monitor = fault_monitor(SETUP)
    monitor_cost: list[float] = []
    holding: dict[str, list[float]] = {label: [] for label in controllers}
    for block in range(args.blocks):
        block_actions = actions[block * args.steps : (block + 1) * args.steps]
        # Raw physics from the env's current state with the same torques, then the env itself.
        mujoco.mj_copyData(raw_data, model, env.plant.data)
        start = time.thread_time()
        for action in block_actions:
            raw_data.ctrl[:] = action
            mujoco.mj_step(model, raw_data, env.n_substeps)
        raw = (time.thread_time() - start) / args.steps
        mujoco.mj_copyData(raw_data, model, env.plant.data)
        step = per_call_seconds(lambda: mujoco.mj_step(model, raw_data), args.steps)
        start = time.thread_time()
        for action in block_actions:
            env.step(action)
        physics.append(raw / ((time.thread_time() - start) / args.steps))
        raw_seconds.append(raw)
        mj_step_seconds.append(step)
        block_observations = observations[block * args.steps : (block + 1) * args.steps]
        held = [seen["gripper"][0] > 0.5 for seen in block_observations]
        for label, controller in controllers.items():
            total = held_seconds = 0.0
            for start_index, stop_index, holds in runs(held):
                start = time.thread_time()
                for block_observation in block_observations[start_index:stop_index]:
                    controller(block_observation)
                seconds = time.thread_time() - start
                total += seconds
                held_seconds += seconds if holds else 0.0
            whole[label].append(total / args.steps / step)
            if any(held):
                holding[label].append(held_seconds / sum(held) / step)
        # The monitor sees each observation with the command that was sent before it, as in an episode.
        start = time.thread_time()
        for index in range(block * args.steps, (block + 1) * args.steps):
            monitor.update(observations[index], actions[index - 1] if index else None)
        monitor_cost.append((time.thread_time() - start) / args.steps / step)

    print(f"raw mj_step x{env.n_substeps}: {1e6 * statistics.median(raw_seconds):6.1f} us per control step")
    print(f"mj_step:        {1e6 * statistics.median(mj_step_seconds):6.1f} us")
    print(f"ratios: median [lowest, highest] over {args.blocks} blocks of {args.steps} steps")
    print(f"physics ratio (raw / env.step) = {spread(physics)}  (goal >= 0.7)")
    print("controller cost per 1 kHz step in mj_step, whole episode | while the gripper holds (goal <= 1):")
    for label in controllers:
        print(f"  {label:<26} {spread(whole[label])} | {spread(holding[label])}")
    print(f"fault monitor (every row's), per step in mj_step, healthy readings: {spread(monitor_cost)}")


if __name__ == "__main__":
    main()
