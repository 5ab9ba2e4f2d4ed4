# Over 500 lines: one command, from the base controller's setup through SB3's callbacks to the scored policy.
"""Train the residual policy of ``DeltaPickPlaceResidual-v0`` with stable-baselines3 (docs/design.md section 6).

    python -m eval.train_residual --seed 0 --timesteps 300000 --max-minutes 15

SAC by default (``--algo`` ppo, tqc or crossq selectable; TQC and CrossQ come from sb3-contrib), with the
hyperparameters of ``eval/hyperparams/residual.toml``. ``--hyperparams key:value ...`` overrides any of them
as the RL Zoo does; each value is a TOML value, as in the file (of bare words only ``auto`` and ``auto_<x>``
are strings; quote others), and a dotted key sets one entry of a table::

    --hyperparams learning_rate:1e-3 train_freq:4 gradient_steps:2 policy_kwargs.net_arch:[64,64]
    --hyperparams 'policy_kwargs:{ net_arch = [64, 64] }' ent_coef:auto_0.1

Every run folder (``--out``, default ``<runs root>/residual/<UTC time>``; :func:`eval.run_folder.runs_root`) holds:

- ``config.json``: the manifest (:func:`eval.run_folder.run_folder`): the resolved configuration (arguments,
  hyperparameters, residual settings, base controller parameters, seeds) with the command line, versions and git
  commit, the status and the start and end times, written as training starts and as it ends;
- ``checkpoints/``: periodic checkpoints (and the replay buffer of off-policy algorithms) for ``--resume``;
- ``evaluations.npz`` and ``best_model/``: SB3's EvalCallback on held-out seeds (validation), distinct
  from every training seed, and its best model;
- ``progress.csv``: training curves (TensorBoard event files go to ``--tensorboard DIR`` when given);
- ``final_policy.zip`` and ``best_policy.zip``: loadable by :func:`controllers.residual.load_residual_controller`;
- ``scores.json``: base vs residual on held-out test seeds (a third, disjoint set), after training
  (:func:`eval.scoring.score_policy`).

``--score-only POLICY`` scores a policy file without training, into its own run folder (``--out``, default
``<runs root>/residual_scores/<UTC time>``: ``config.json``, ``scenario.toml``, ``scores.json``), never beside the
policy file.

Seeds: training episodes draw their env seeds from ``TRAINING_SEEDS`` (per worker, from ``--seed``),
validation uses ``VALIDATION_SEEDS``, the final scores ``TEST_SEEDS`` and the tare calibration
``CALIBRATION_SEEDS``: four disjoint sets, all disjoint from ``python -m eval``'s defaults (seeds 0-9 and
its calibration seeds from 100000), so no evaluation episode (reference path, payload masses, noise) is
ever trained on.

Training episodes come from the ``randomized`` scenario by default (domain randomization of masses, friction
and drive lag on the nominal robot; ``--scenario`` chooses another). The base controller is the eval's
``mid_f_rls_lag`` row (``--base mid_f_rls`` for the one without the lead):
MId+F+R + PD with the payload RLS, its feedforward leading the identified drive lag, its parameters those
of the scenario's robot (``--scenario``, ``--geometry``; ``eval.parameter_files.identify_robot``) and
its tare calibrated on the scenario as the eval does (:mod:`eval.calibration` on payload-free episodes).
Both, and the robot's geometry and masses, are saved in the policy.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import inspect
import json
import math
import re
import time
import tomllib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.logger import configure, make_output_format
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from tqdm import tqdm

from controllers.base import Controller
from controllers.dynamics import ModelParameters
from controllers.registry import ControllerSetup
from controllers.residual import (
    ALGORITHMS,
    BaseSetup,
    DeltaResidualEnv,
    ResidualConfig,
    algorithm_class,
    save_residual_policy,
)
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from eval.calibration import DEFAULT_CALIBRATION_EPISODES, calibrate_tares
from eval.run_folder import Run, add_runs_dir_argument, command_line, run_folder, write_json
from eval.scenario_args import add_scenario_arguments, check_ranges, scenario_from_arguments
from eval.scoring import TEST_PAYLOADS, TEST_SEEDS, score_policy

HYPERPARAMETER_FILE = Path(__file__).resolve().parent / "hyperparams" / "residual.toml"
"""The SB3 hyperparameters of each algorithm, one TOML table per algorithm."""

TRAINING_SEEDS = range(10_000_000, 20_000_000)
"""Env seeds of the training episodes (drawn at random per worker)."""

VALIDATION_SEEDS = tuple(range(1_000_000, 1_000_006))
"""Held-out episodes of the EvalCallback during training (model selection)."""

CALIBRATION_SEEDS = tuple(range(3_000_000, 3_000_000 + DEFAULT_CALIBRATION_EPISODES))
"""Payload-free episodes of the base controller's tare (as many as the eval's)."""

CHECKPOINT_PREFIX = "residual"
"""CheckpointCallback names: residual_<n>_steps.zip and residual_replay_buffer_<n>_steps.pkl."""

HAS_RICH = importlib.util.find_spec("rich") is not None
"""SB3's progress bar needs tqdm and rich; without rich a plain tqdm bar is used."""

HAS_TENSORBOARD = importlib.util.find_spec("tensorboard") is not None
"""``--tensorboard`` needs the tensorboard package."""

BARE_WORD = re.compile(r"auto(_[0-9.eE+-]+)?")
"""The ``--hyperparams`` values that are not TOML but read as strings: SB3's ``auto`` and ``auto_<initial>`` of
``ent_coef`` and ``target_entropy``. Any other word must be quoted (``'"value"'``)."""

SET_BY_THE_TOOL = frozenset({"seed", "device", "verbose", "tensorboard_log", "_init_setup_model"})
"""Constructor arguments the tool sets itself (``--seed``, ``--tensorboard``), not ``--hyperparams`` keys."""


def load_hyperparameters(algo: str, path: Path = HYPERPARAMETER_FILE) -> dict[str, Any]:
    """The SB3 keyword arguments of ``algo`` (one of ``ALGORITHMS``) from the hyperparameter file."""
    with path.open("rb") as file:
        tables = tomllib.load(file)
    if algo not in tables:
        raise ValueError(f"{path} has no [{algo}] table; it has {sorted(tables)}")
    return copy.deepcopy(tables[algo])


def parse_hyperparameter_value(key: str, text: str) -> Any:
    """The value of one ``--hyperparams key:value`` item: a TOML value (``1e-3``, ``[64, 64]``, ``true``,
    ``"auto"``, ``{ net_arch = [64, 64] }``), or the text itself for ``auto`` / ``auto_<initial>``
    (:data:`BARE_WORD`). A non-finite number is refused."""
    if BARE_WORD.fullmatch(text):
        return text
    try:
        value = tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError as error:
        hint = " (TOML writes true and false in lower case)" if text in ("True", "False") else ""
        raise ValueError(
            f"--hyperparams {key}: {text!r} is not a TOML value{hint}; quote a string, e.g. {key}:'\"{text}\"' "
            f"({error})"
        ) from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"--hyperparams {key}: {text!r} must be a finite number")
    return value


def override_hyperparameters(hyperparameters: dict[str, Any], items: Sequence[str], algo: str) -> dict[str, Any]:
    """``hyperparameters`` with the ``--hyperparams`` items ``key:value`` applied (a new dict).

    A key must be a keyword argument of the algorithm's constructor; a dotted key (``policy_kwargs.net_arch``)
    sets one entry of a table-valued argument and leaves its other entries.
    """
    allowed = set(inspect.signature(algorithm_class(algo).__init__).parameters) - {"self", "policy", "env"}
    allowed -= SET_BY_THE_TOOL
    result = copy.deepcopy(hyperparameters)
    for item in items:
        key, separator, text = item.partition(":")
        if not separator or not key or not text:
            raise ValueError(f"--hyperparams items are key:value, got {item!r}")
        name, *path = key.split(".")
        if not all(path):
            raise ValueError(f"--hyperparams {key}: a dotted key needs a name between the dots")
        if name in SET_BY_THE_TOOL:
            raise ValueError(f"--hyperparams {key}: {name!r} is set by the tool (--seed, --tensorboard), not here")
        if name not in allowed:
            raise ValueError(f"--hyperparams {key}: {name!r} is not an argument of {algo}; known: {sorted(allowed)}")
        value = parse_hyperparameter_value(key, text)
        if not path:
            result[name] = value
            continue
        table, owner = result.setdefault(name, {}), name
        for part in [*path[:-1], None]:  # None: the table that takes the value
            if not isinstance(table, dict):
                raise ValueError(f"--hyperparams {key}: {owner!r} is {table!r}, not a table")
            if part is not None:
                table, owner = table.setdefault(part, {}), part
        table[path[-1]] = value
    return result


class EpisodeSeeds(gym.Wrapper):
    """Resets the wrapped env with seeds from a schedule, so that episode sets are disjoint by construction.

    ``seeds`` given: episodes cycle through them (held-out evaluation; :meth:`restart` rewinds).
    Otherwise episode seeds are drawn from ``TRAINING_SEEDS`` by a generator seeded with
    (``seed``, ``rank``); a reset with an explicit seed re-seeds that generator.
    """

    def __init__(self, env: gym.Env, *, seed: int = 0, rank: int = 0, seeds: Sequence[int] | None = None) -> None:
        super().__init__(env)
        if seeds is not None and len(seeds) == 0:
            raise ValueError("seeds must not be empty")
        self.fixed_seeds = None if seeds is None else tuple(int(s) for s in seeds)
        self.rank = int(rank)
        self._index = 0
        self._generator = np.random.default_rng([int(seed), self.rank])
        self.episode_seed: int | None = None

    def restart(self) -> None:
        """Start the fixed seed list again from its first seed."""
        self._index = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if self.fixed_seeds is not None:
            self.episode_seed = self.fixed_seeds[self._index % len(self.fixed_seeds)]
            self._index += 1
        else:
            if seed is not None:
                self._generator = np.random.default_rng([int(seed), self.rank])
            self.episode_seed = int(self._generator.integers(TRAINING_SEEDS.start, TRAINING_SEEDS.stop))
        observation, info = self.env.reset(seed=self.episode_seed, options=options)
        info["episode_seed"] = self.episode_seed
        return observation, info


BASE_KEYS = ("mid_f_rls_lag", "mid_f_rls")
"""Registry keys of the base controllers a residual can be trained on; the first, the strongest, is the default."""


def base_setup(
    env_kwargs: dict[str, Any],
    parameters: ModelParameters | None = None,
    drive_lag: tuple[float, float, float] | None = None,
    *,
    base: str = BASE_KEYS[0],
    runs_dir: Path | None = None,
) -> BaseSetup:
    """The base controller's setup: identified MId+F+R parameters (and drive lag) of the scenario's robot and
    its tare calibrated on the scenario.

    Args:
        env_kwargs: Keyword arguments of the calibration episodes' :class:`DeltaPickPlaceEnv`: ``n_cycles``
            and optionally ``scenario`` (a Scenario; None or absent is ``nominal``).
        parameters: Identified MId+F+R parameters; None loads (or identifies) those of the scenario's robot
            with :func:`eval.parameter_files.identify_robot` (kept under the runs root of ``runs_dir``,
            :func:`eval.run_folder.runs_root`), and with them its drive lag.
        drive_lag: Identified drive lag T (s) per joint, with ``parameters``.
        base: Registry key of the base: ``mid_f_rls_lag`` (the feedforward leads the identified drive lag)
            or ``mid_f_rls``.
    """
    if base not in BASE_KEYS:
        raise ValueError(f"base must be one of {BASE_KEYS}, got {base!r}")
    if not {"n_cycles"} <= set(env_kwargs) <= {"n_cycles", "scenario"}:
        raise ValueError(f"the tare calibration takes n_cycles and scenario only, got {sorted(env_kwargs)}")
    scenario = env_kwargs.get("scenario") or Scenario()
    robot = scenario.plant
    if parameters is None:
        from eval.parameter_files import identification_root, identify_robot

        result = identify_robot(robot, identification_root(runs_dir))
        parameters, drive_lag = result.mid_f_rods, result.drive_lag
    if base == "mid_f_rls_lag" and drive_lag is None:
        raise ValueError("the mid_f_rls_lag base needs the identified drive lag: pass drive_lag with parameters")
    # The registry builds this base; the lumped parameter sets are not used by it.
    setup = ControllerSetup(
        mid=parameters,
        mid_f=parameters,
        mid_f_rods=parameters,
        drive_lag=drive_lag,
        geometry=robot.geometry,
        masses=robot.masses,
    )
    calibration = calibrate_tares([base], setup, CALIBRATION_SEEDS, env_kwargs["n_cycles"], scenario=scenario)
    return BaseSetup(
        parameters,
        tare=calibration.tares[base],
        geometry=robot.geometry,
        masses=robot.masses,
        drive_lag=drive_lag if base == "mid_f_rls_lag" else None,
    )


def make_env(
    *,
    config: ResidualConfig,
    env_kwargs: dict[str, Any],
    base: BaseSetup | None,
    seed: int = 0,
    rank: int = 0,
    seeds: Sequence[int] | None = None,
    base_factory: Callable[[], Controller] | None = None,
) -> Callable[[], gym.Env]:
    """A picklable env factory for SB3 vector envs (one torch thread per worker: the machine is shared).

    Args:
        config: Residual settings.
        env_kwargs: Keyword arguments of :class:`DeltaPickPlaceEnv`.
        base: Setup of the default base controller (None: ``base_factory`` must be given).
        seed: Seed of the training episode seeds.
        rank: Worker index.
        seeds: Fixed held-out seeds instead of drawn training seeds.
        base_factory: Builds the base controller instead of ``base`` (tests).
    """

    def factory() -> gym.Env:
        torch.set_num_threads(1)
        controller = base_factory() if base_factory is not None else base.controller()
        env = DeltaResidualEnv(base=controller, config=config, env=DeltaPickPlaceEnv(**env_kwargs))
        return Monitor(EpisodeSeeds(env, seed=seed, rank=rank, seeds=seeds))

    return factory


def resume_mismatch(checkpoint: Path, scenario: str, base: str) -> str | None:
    """What differs between the run a checkpoint comes from and a resumed run's ``scenario`` and ``base``
    (as a sentence), from the ``config.json`` of its run folder; None when nothing differs or no record is
    found (a checkpoint outside a run folder)."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        record = folder / "config.json"
        if record.is_file():
            arguments = json.loads(record.read_text())["config"]["arguments"]
            trained = {"scenario": arguments.get("scenario"), "base": arguments.get("base", "mid_f_rls")}
            resumed = {"scenario": scenario, "base": base}
            changed = [f"{key} {trained[key]} -> {resumed[key]}" for key in trained if trained[key] != resumed[key]]
            return f"{checkpoint} was trained with another setting: {', '.join(changed)}" if changed else None
    return None


class LatestReplayCheckpoint(CheckpointCallback):
    """CheckpointCallback that keeps only the newest replay buffer (each is ~100 MB; models are kept)."""

    def _on_step(self) -> bool:
        result = super()._on_step()
        if self.save_replay_buffer and self.n_calls % self.save_freq == 0:
            newest = Path(self._checkpoint_path("replay_buffer_", extension="pkl"))
            for path in newest.parent.glob(f"{self.name_prefix}_replay_buffer_*_steps.pkl"):
                if path != newest:
                    path.unlink()
        return result


class HeldOutEvalCallback(EvalCallback):
    """EvalCallback that replays the same held-out episodes (``EpisodeSeeds.restart``) at every evaluation."""

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self.eval_env.env_method("restart")
        return super()._on_step()


class WallTimeLimit(BaseCallback):
    """Stops training once a wall-time budget (minutes) is spent."""

    def __init__(self, minutes: float) -> None:
        super().__init__()
        self.minutes = minutes
        self.deadline = math.inf

    def _on_training_start(self) -> None:
        self.deadline = time.monotonic() + 60.0 * self.minutes

    def _on_step(self) -> bool:
        return time.monotonic() < self.deadline


class TqdmProgress(BaseCallback):
    """Plain-tqdm progress bar, for when rich (which SB3's ``progress_bar=True`` needs) is not installed."""

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.locals["total_timesteps"] - self.model.num_timesteps, unit="step")

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def _callbacks(args: argparse.Namespace, out: Path, eval_env: VecEnv) -> list[BaseCallback]:
    n_envs = args.n_envs
    callbacks: list[BaseCallback] = [
        LatestReplayCheckpoint(
            save_freq=max(args.checkpoint_freq // n_envs, 1),
            save_path=str(out / "checkpoints"),
            name_prefix=CHECKPOINT_PREFIX,
            save_replay_buffer=issubclass(algorithm_class(args.algo), OffPolicyAlgorithm),
        ),
        HeldOutEvalCallback(
            eval_env,
            n_eval_episodes=len(VALIDATION_SEEDS),
            eval_freq=max(args.eval_freq // n_envs, 1),
            log_path=str(out),
            best_model_save_path=str(out / "best_model"),
            deterministic=True,
            verbose=int(args.verbose),
        ),
    ]
    if args.max_minutes is not None:
        callbacks.append(WallTimeLimit(args.max_minutes))
    if args.progress and not HAS_RICH:
        callbacks.append(TqdmProgress())
    return callbacks


def residual_config(args: argparse.Namespace) -> ResidualConfig:
    """The residual settings of the command line."""
    return ResidualConfig(
        residual_limit=args.residual_limit,
        action_period=args.action_period,
        reward_scale=args.reward_scale,
    )


def train(
    args: argparse.Namespace,
    base_factory: Callable[[], Controller] | None = None,
    *,
    base: BaseSetup | None = None,
    callbacks: Sequence[BaseCallback] = (),
) -> Path:
    """Train per ``args`` (see :func:`parse_args`); returns the run folder.

    Args:
        args: Parsed command-line arguments.
        base_factory: Builds the base controller instead of the one of ``args.base`` (tests).
        base: The setup of ``args.base`` already identified and calibrated (:func:`base_setup`), so that
            several runs share one; None makes it.
        callbacks: More SB3 callbacks (after the checkpoint, evaluation and wall-time ones).
    """
    torch.set_num_threads(args.torch_threads)
    with run_folder(
        "residual",
        command_line("eval.train_residual"),
        {"arguments": {**vars(args), "scenario": args.scenario.name}},
        out=args.out,
        runs_dir=args.runs_dir,
        scenarios=[args.scenario],
    ) as run:
        _train(args, run, base_factory, base, callbacks)
    return run.folder


def _train(
    args: argparse.Namespace,
    run: Run,
    base_factory: Callable[[], Controller] | None,
    base: BaseSetup | None,
    callbacks: Sequence[BaseCallback],
) -> None:
    """The training of :func:`train` into ``run``'s folder."""
    out = run.folder
    config = residual_config(args)
    env_kwargs = {"n_cycles": args.cycles, "scenario": args.scenario}
    if base is None and base_factory is None:
        base = base_setup(env_kwargs, base=args.base, runs_dir=args.runs_dir)
    hyperparameters = override_hyperparameters(load_hyperparameters(args.algo), args.hyperparams, args.algo)

    command = run.manifest["command"]
    resolved = {
        "arguments": {**vars(args), "scenario": args.scenario.name},
        "hyperparameter_file": HYPERPARAMETER_FILE.name,
        "residual_config": asdict(config),
        "env_kwargs": {**env_kwargs, "scenario": args.scenario.name},
        "scenario": {"name": args.scenario.name, "file": "scenario.toml", "robot": args.scenario.robot_identity},
        "hyperparameters": hyperparameters,
        "base_controller": "custom (base_factory)" if base is None else base.to_dict(),
        "seeds": {
            "training": f"per worker from default_rng([seed, rank]) in {TRAINING_SEEDS}",
            "calibration": list(CALIBRATION_SEEDS),
            "validation": list(VALIDATION_SEEDS),
            "test": list(TEST_SEEDS),
            "test_payloads": list(TEST_PAYLOADS),
        },
    }
    run.record(config=resolved)

    set_random_seed(args.seed)
    factories = [
        make_env(
            config=config,
            env_kwargs=env_kwargs,
            base=base,
            seed=args.seed,
            rank=rank,
            base_factory=base_factory,
        )
        for rank in range(args.n_envs)
    ]
    vec_env = SubprocVecEnv(factories) if args.n_envs > 1 else DummyVecEnv(factories)
    eval_env = DummyVecEnv(
        [
            make_env(
                config=config,
                env_kwargs=env_kwargs,
                base=base,
                seeds=VALIDATION_SEEDS,
                base_factory=base_factory,
            )
        ]
    )
    algorithm = algorithm_class(args.algo)
    formats = ["stdout", "csv"] if args.verbose else ["csv"]
    if args.resume is not None:
        mismatch = resume_mismatch(args.resume, args.scenario.name, args.base)
        if mismatch is not None:
            warnings.warn(f"{mismatch}; training goes on with the new one", stacklevel=1)
        model = algorithm.load(args.resume, env=vec_env, device="cpu")
        off_policy = isinstance(model, OffPolicyAlgorithm)
        replay = args.resume.with_name(f"{CHECKPOINT_PREFIX}_replay_buffer_{model.num_timesteps}_steps.pkl")
        if off_policy and replay.is_file():
            model.load_replay_buffer(replay)
        elif off_policy:
            # Only the newest replay buffer is kept: an older checkpoint restarts with an empty one.
            warnings.warn(f"no replay buffer at {replay}: resuming with an empty one", stacklevel=1)
            replay = None
        resolved["resumed_from"] = {
            "checkpoint": str(args.resume),
            "setting_changed": mismatch,
            "num_timesteps": model.num_timesteps,
            "replay_buffer": replay if off_policy else None,
        }
        run.record(config=resolved)
    else:
        model = algorithm("MlpPolicy", vec_env, seed=args.seed, device="cpu", verbose=0, **hyperparameters)
    logger = configure(str(out), formats)
    if args.tensorboard is not None:
        # One event folder per run under DIR, for `tensorboard --logdir DIR`.
        logger.output_formats.append(make_output_format("tensorboard", str(args.tensorboard / out.name)))
    model.set_logger(logger)

    all_callbacks = [*_callbacks(args, out, eval_env), *callbacks]
    # SubprocVecEnv for training, DummyVecEnv for the held-out episodes: intended, not worth a warning.
    warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
    remaining = max(args.timesteps - model.num_timesteps, 0)
    start = time.monotonic()
    model.learn(
        total_timesteps=remaining,
        callback=all_callbacks,
        reset_num_timesteps=args.resume is None,
        progress_bar=args.progress and HAS_RICH,
    )
    wall_time = time.monotonic() - start
    notes = {"command": command, "seed": args.seed, "timesteps": model.num_timesteps}
    notes["wall_time_s"] = round(wall_time, 1)
    save_residual_policy(model, out / "final_policy.zip", config, args.algo, base=base, extra=notes)
    best = out / "best_model" / "best_model.zip"
    if best.is_file():
        best_model = algorithm.load(best, device="cpu")
        save_residual_policy(best_model, out / "best_policy.zip", config, args.algo, base=base, extra=notes)
    vec_env.close()
    eval_env.close()
    run.record(training={"wall_time_s": round(wall_time, 1), "num_timesteps": model.num_timesteps})
    if args.score:
        policy = out / ("best_policy.zip" if best.is_file() else "final_policy.zip")
        scores = score_policy(policy, env_kwargs, base_factory=base_factory)
        write_json(out / "scores.json", scores)
        print(json.dumps(scores["summary"], indent=2))


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m eval.train_residual",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--algo", choices=ALGORITHMS, default="sac")
    parser.add_argument("--seed", type=int, default=0, help="seed of the model and of the training episodes")
    parser.add_argument("--timesteps", type=int, default=300_000, help="total policy steps (100 Hz by default)")
    parser.add_argument(
        "--n-envs", type=int, default=1, help="parallel envs; SubprocVecEnv when > 1 (train_freq counts vector steps)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="run folder (default <runs root>/residual/<UTC time>, with --score-only residual_scores/<UTC time>)",
    )
    add_runs_dir_argument(parser)
    parser.add_argument("--resume", type=Path, default=None, help="checkpoint zip to continue from")
    parser.add_argument("--max-minutes", type=float, default=None, help="stop training after this wall time")
    parser.add_argument("--checkpoint-freq", type=int, default=50_000, help="policy steps between checkpoints")
    parser.add_argument("--eval-freq", type=int, default=20_000, help="policy steps between held-out evaluations")
    # Domain randomization on by default: a residual trained on one plant learns that plant's errors.
    add_scenario_arguments(parser, default="randomized")
    parser.add_argument(
        "--base", choices=BASE_KEYS, default=BASE_KEYS[0], help="base controller (eval key; default: %(default)s)"
    )
    parser.add_argument(
        "--cycles",
        "--n-cycles",  # the old spelling, kept as an alias
        dest="cycles",
        type=int,
        default=None,
        help="pick-and-place cycles per episode (default: the scenario's)",
    )
    parser.add_argument("--residual-limit", type=float, default=ResidualConfig.residual_limit, help="N m at a = 1")
    parser.add_argument("--action-period", type=int, default=ResidualConfig.action_period, help="control steps")
    parser.add_argument("--reward-scale", type=float, default=ResidualConfig.reward_scale)
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="override hyperparameters of the TOML file: key:value with a TOML value, dotted keys for table entries",
    )
    parser.add_argument("--tensorboard", type=Path, default=None, help="TensorBoard log folder (needs tensorboard)")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    parser.add_argument("--no-score", dest="score", action="store_false", help="skip the final test scores")
    parser.add_argument("--verbose", action="store_true", help="print SB3 logs to stdout")
    parser.add_argument(
        "--score-only", type=Path, default=None, help="no training: score this policy zip on the test seeds"
    )
    args = parser.parse_args(argv)
    counts = {"seed": 0, "timesteps": 1, "n_envs": 1, "cycles": 1, "checkpoint_freq": 1, "eval_freq": 1}
    check_ranges(parser, args, {**counts, "torch_threads": 1}, ("max_minutes",))
    args.scenario = scenario_from_arguments(args, parser)
    if args.cycles is None:
        args.cycles = args.scenario.task.n_cycles
    if args.tensorboard is not None and not HAS_TENSORBOARD:
        parser.error("--tensorboard needs the tensorboard package (pip install tensorboard)")
    try:
        residual_config(args)
    except ValueError as error:
        parser.error(f"--residual-limit, --action-period, --reward-scale: {error}")
    try:
        override_hyperparameters(load_hyperparameters(args.algo), args.hyperparams, args.algo)
    except (ValueError, ImportError) as error:
        parser.error(str(error))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.score_only is None:
        train(args)
        return 0
    with run_folder(
        "residual_scores",
        command_line("eval.train_residual", argv),
        {"arguments": {**vars(args), "scenario": args.scenario.name}},
        out=args.out,
        runs_dir=args.runs_dir,
        scenarios=[args.scenario],
    ) as run:
        scores = score_policy(args.score_only, {"n_cycles": args.cycles, "scenario": args.scenario})
        write_json(run.folder / "scores.json", scores)
        print(json.dumps(scores["summary"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
