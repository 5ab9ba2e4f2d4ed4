"""Benchmark: the cost of env.step and of the controllers against raw mj_step, in one run.

Prints ratios, not absolute times, because only ratios carry over between machines:
``physics ratio = time(n_substeps x mj_step) / time(env.step)`` (goal >= 0.5: the env costs at most
twice its physics) and ``controller cost = time(controller call) / time(one mj_step)`` (goal <= 1) for
every controller of ``python -m eval``, called on the observations of the same rollout: over the whole
episode and over the steps while the gripper holds (when the payload RLS runs). The model parameters
are representative values: the cost does not depend on them.

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
from controllers.dynamics import ModelParameters
from controllers.registry import CONTROLLER_LABELS, ESTIMATOR_REGRESSORS, ControllerSetup, build_controller
from delta_env.env import DeltaPickPlaceEnv

# Representative identified values (python -m eval.identify on the default plant, rounded).
SETUP = ControllerSetup(
    mid=ModelParameters(rho1=1.80, rho2=0.94),
    mid_f=ModelParameters(rho1=1.76, rho2=0.88, viscous=(1.97, 2.41, 1.73), coulomb=(4.07, 3.35, 4.46)),
    mid_f_rods=ModelParameters(rho1=1.95, rho2=0.951, viscous=(2.01, 2.41, 1.71), coulomb=(3.98, 3.38, 4.59)),
    drive_lag=(0.001, 0.001, 0.001),
    tares=dict.fromkeys(ESTIMATOR_REGRESSORS, -0.02),
)


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

    controllers = {label: build_controller(key, SETUP, env) for key, label in CONTROLLER_LABELS.items()}
    for controller in controllers.values():
        if hasattr(controller, "set_payload_masses"):
            controller.set_payload_masses(masses["payload_masses"])  # the oracle bound's truth
        controller.reset()

    env.reset(seed=0, options=masses)
    model = env.plant.model
    raw_data = mujoco.MjData(model)
    rows: dict[str, list[float]] = {"raw": [], "env": [], "mj_step": []} | {label: [] for label in controllers}
    holding: dict[str, list[float]] = {label: [] for label in controllers}
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
        for label, controller in controllers.items():
            calls = []
            for block_observation in block_observations:
                start = time.perf_counter()
                controller(block_observation)
                calls.append(time.perf_counter() - start)
            rows[label].append(statistics.fmean(calls))
            holding[label].extend(
                call for call, seen in zip(calls, block_observations, strict=True) if seen["gripper"][0] > 0.5
            )
    median = {name: statistics.median(values) for name, values in rows.items()}

    print(f"raw mj_step x{env.n_substeps}: {1e6 * median['raw']:8.1f} us")
    print(f"env.step:          {1e6 * median['env']:8.1f} us")
    print(f"physics ratio (raw / env.step) = {median['raw'] / median['env']:.2f}  (goal >= 0.5)")
    step = median["mj_step"]
    print(f"mj_step:           {1e6 * step:8.1f} us")
    print("controller cost per 1 kHz step, whole episode | while the gripper holds (goal <= 1 x mj_step):")
    for label in controllers:
        held = statistics.median(holding[label])
        print(
            f"  {label:<20} {1e6 * median[label]:7.1f} us = {median[label] / step:5.2f} x mj_step | "
            f"{1e6 * held:7.1f} us = {held / step:5.2f} x"
        )


if __name__ == "__main__":
    main()
