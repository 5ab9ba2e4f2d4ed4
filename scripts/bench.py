"""Benchmark: the cost of env.step and of the controllers against raw mj_step, in one run.

Prints ratios, not absolute times, because only ratios carry over between machines:
``physics ratio = time(n_substeps x mj_step) / time(env.step)`` (goal >= 0.5: the env costs at most
twice its physics) and ``controller cost = time(controller call) / time(one mj_step)``.

Usage: python scripts/bench.py [--steps N] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import mujoco
import numpy as np

from controllers.base import PDController
from delta_env.env import DeltaPickPlaceEnv


def per_call_seconds(function: Callable[[], object], calls: int) -> float:
    """Mean wall time (s) of one call over ``calls`` calls."""
    start = time.perf_counter()
    for _ in range(calls):
        function()
    return (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200, help="control steps per timing block")
    parser.add_argument("--blocks", type=int, default=12, help="timing blocks (median is reported)")
    args = parser.parse_args()

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

    env.reset(seed=0, options=masses)
    model = env.plant.model
    raw_data = mujoco.MjData(model)
    rows: dict[str, list[float]] = {"raw": [], "env": [], "mj_step": [], "PD": []}
    for block in range(args.blocks):
        block_actions = actions[block * args.steps : (block + 1) * args.steps]
        # Raw physics from the env's current state with the same torques, then the env itself.
        mujoco.mj_copyData(raw_data, model, env.plant.data)
        start = time.perf_counter()
        for action in block_actions:
            raw_data.ctrl[:] = action
            mujoco.mj_step(model, raw_data, env.n_substeps)
        rows["raw"].append((time.perf_counter() - start) / args.steps)
        mujoco.mj_copyData(raw_data, model, env.plant.data)
        rows["mj_step"].append(per_call_seconds(lambda: mujoco.mj_step(model, raw_data), args.steps))
        start = time.perf_counter()
        for action in block_actions:
            env.step(action)
        rows["env"].append((time.perf_counter() - start) / args.steps)
        block_observations = observations[block * args.steps : (block + 1) * args.steps]
        start = time.perf_counter()
        for block_observation in block_observations:
            pd(block_observation)
        rows["PD"].append((time.perf_counter() - start) / args.steps)
    median = {name: statistics.median(values) for name, values in rows.items()}

    print(f"raw mj_step x{env.n_substeps}: {1e6 * median['raw']:8.1f} us")
    print(f"env.step:          {1e6 * median['env']:8.1f} us")
    print(f"physics ratio (raw / env.step) = {median['raw'] / median['env']:.2f}  (goal >= 0.5)")
    for name in ("PD",):
        ratio = median[name] / median["mj_step"]
        print(f"controller {name:<12} {1e6 * median[name]:8.1f} us = {ratio:.2f} x mj_step  (goal <= 1)")


if __name__ == "__main__":
    main()
