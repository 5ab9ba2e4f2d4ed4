"""Training a residual policy with stable-baselines3 (docs/design.md section 6): the resolved configuration of a
training (:class:`TrainingConfig`, built by ``python -m eval.residual``), the callbacks (checkpoints, the
held-out evaluations and their learning curve, a wall-time budget, a progress bar) and the run itself
(:func:`train`), whose run folder ``eval.residual.__main__`` describes."""

from __future__ import annotations

import importlib.util
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.logger import configure, make_output_format
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from controllers.base import Controller
from controllers.residual import PolicyBase, ResidualConfig, algorithm_class, save_residual_policy
from delta_env.scenario import Scenario
from eval.comparison.plots import LEARNING_CURVE_COLUMNS, LEARNING_CURVE_FILE, learning_curve_figure
from eval.console import progress_bar
from eval.residual.envs import CALIBRATION_SEEDS, TRAINING_SEEDS, VALIDATION_SEEDS, base_setup, make_env
from eval.residual.hyperparameters import HYPERPARAMETER_FILE, load_hyperparameters, override_hyperparameters
from eval.residual.resume import relabel_action_rate, relabelable, resume_mismatch, reward_change, trained_config
from eval.residual.scoring import TEST_PAYLOADS, TEST_SEEDS, score_policy, score_summary
from eval.run_folder import Run, append_csv_rows, command_run_folder, configuration_record, write_json

CHECKPOINT_PREFIX = "residual"
"""CheckpointCallback names: residual_<n>_steps.zip and residual_replay_buffer_<n>_steps.pkl."""

HAS_RICH = importlib.util.find_spec("rich") is not None
"""SB3's progress bar needs tqdm and rich; without rich a plain tqdm bar is used."""


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
    """EvalCallback that replays the same held-out episodes (``EpisodeSeeds.restart``) at every evaluation and, with
    a ``curve`` path, appends each evaluation's scores to that CSV file
    (:data:`eval.comparison.plots.LEARNING_CURVE_COLUMNS`)."""

    def __init__(self, *args: Any, curve: Path | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.curve = curve

    def _on_step(self) -> bool:
        evaluates = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if evaluates:
            self.eval_env.env_method("restart")
        keep_going = super()._on_step()
        if evaluates and self.curve is not None:
            returns = np.asarray(self.evaluations_results[-1], dtype=float)
            row = {
                "timesteps": self.num_timesteps,
                "mean_reward": float(returns.mean()),
                "std_reward": float(returns.std()),
                "min_reward": float(returns.min()),
                "max_reward": float(returns.max()),
                "episodes": returns.size,
            }
            append_csv_rows(self.curve, LEARNING_CURVE_COLUMNS, [row])
        return keep_going


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
        self.bar = progress_bar(self.locals["total_timesteps"] - self.model.num_timesteps, "training", "step")

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def _callbacks(config: TrainingConfig, out: Path, eval_env: VecEnv) -> list[BaseCallback]:
    n_envs = config.n_envs
    callbacks: list[BaseCallback] = [
        LatestReplayCheckpoint(
            save_freq=max(config.checkpoint_freq // n_envs, 1),
            save_path=str(out / "checkpoints"),
            name_prefix=CHECKPOINT_PREFIX,
            save_replay_buffer=issubclass(algorithm_class(config.algo), OffPolicyAlgorithm),
        ),
        HeldOutEvalCallback(
            eval_env,
            n_eval_episodes=len(VALIDATION_SEEDS),
            eval_freq=max(config.eval_freq // n_envs, 1),
            log_path=str(out),
            best_model_save_path=str(out / "best_model"),
            deterministic=True,
            verbose=int(config.verbose),
            curve=out / LEARNING_CURVE_FILE,
        ),
    ]
    if config.max_minutes is not None:
        callbacks.append(WallTimeLimit(config.max_minutes))
    if config.progress and not HAS_RICH:
        callbacks.append(TqdmProgress())
    return callbacks


RESIDUAL_OPTIONS = (
    "residual_limit",
    "action_period",
    "reward_scale",
    "torque_weight",
    "action_rate_weight",
    "off_at_rest",
    "fade_speed",
    "plant_torque_weight",
)
"""The command line's options that set the :class:`ResidualConfig` of a training (its field names)."""


@dataclass(frozen=True)
class TrainingConfig:
    """The resolved configuration of ``python -m eval.residual`` (a training, or with ``score_only`` the
    scores of a policy file), recorded as it is in the run's manifest (:func:`eval.run_folder.configuration_record`);
    the options are described by ``--help``.

    Attributes:
        algo: The SB3 algorithm (:data:`~controllers.residual.ALGORITHMS`).
        seed: Seed of the model and of the training episodes.
        timesteps: Total policy steps.
        n_envs: Parallel training envs.
        out: ``--out``, or None.
        force: Write into an existing, non-empty ``out``.
        runs_dir: ``--runs-dir``, or None.
        resume: The checkpoint to continue from, or None.
        max_minutes: Wall-time budget of the training (min), or None.
        checkpoint_freq: Policy steps between checkpoints.
        eval_freq: Policy steps between held-out evaluations.
        scenario: The training episodes' scenario (on ``geometry``'s robot, released as ``release`` says).
        geometry: The geometry file of ``--geometry``, or None.
        release: ``--release``, or None.
        base: The base controller's key (:data:`~eval.residual.envs.BASE_KEYS`).
        servo: The base's feedback (:data:`controllers.setup.SERVOS`).
        cycles: Pick-and-place cycles per episode of ``scenario``.
        mix: ``--mix``: the mixed scenarios as given.
        residual: The residual's settings (:data:`RESIDUAL_OPTIONS`).
        hyperparams: ``--hyperparams`` overrides, ``key:value``.
        tensorboard: TensorBoard log folder, or None.
        torch_threads: Threads of torch's CPU operations.
        progress: Show progress bars.
        score: Score the policy on the test seeds after training.
        verbose: Print SB3's logs.
        score_only: The policy file to score instead of training, or None.
        mixture: The scenarios of ``mix``.
        mixture_cycles: Cycles per episode of each of ``mixture``.
    """

    algo: str
    seed: int
    timesteps: int
    n_envs: int
    out: Path | None
    force: bool
    runs_dir: Path | None
    resume: Path | None
    max_minutes: float | None
    checkpoint_freq: int
    eval_freq: int
    scenario: Scenario
    geometry: str | None
    release: str | None
    base: str
    servo: str
    cycles: int
    mix: tuple[str, ...]
    residual: ResidualConfig
    hyperparams: tuple[str, ...]
    tensorboard: Path | None
    torch_threads: int
    progress: bool
    score: bool
    verbose: bool
    score_only: Path | None
    mixture: tuple[Scenario, ...]
    mixture_cycles: tuple[int, ...]


def train(
    config: TrainingConfig,
    base_factory: Callable[[], Controller] | None = None,
    *,
    base: PolicyBase | None = None,
    callbacks: Sequence[BaseCallback] = (),
) -> Path:
    """Train per ``config`` (:func:`eval.residual.__main__.parse_args`); returns the run folder.

    Args:
        config: The resolved configuration.
        base_factory: Builds the base controller instead of the one of ``config.base`` (tests).
        base: The setup of ``config.base`` already identified and calibrated
            (:func:`eval.residual.envs.base_setup`), so that several runs share one; None makes it.
        callbacks: More SB3 callbacks (after the checkpoint, evaluation and wall-time ones).
    """
    torch.set_num_threads(config.torch_threads)
    with command_run_folder(
        "residual",
        "eval.residual",
        None,
        config,
        {"arguments": configuration_record(config)},
        scenarios=[config.scenario, *config.mixture],
    ) as run:
        summary = _train(config, run, base_factory, base, callbacks)
    print(f"{summary}\nRun folder: {run.folder}")
    return run.folder


def _train(
    config: TrainingConfig,
    run: Run,
    base_factory: Callable[[], Controller] | None,
    base: PolicyBase | None,
    callbacks: Sequence[BaseCallback],
) -> str:
    """The training of :func:`train` into ``run``'s folder; returns its summary: what was trained, and the scores."""
    out = run.folder
    residual = config.residual
    env_kwargs = {"n_cycles": config.cycles, "scenario": config.scenario}
    mixture = [
        {"n_cycles": cycles, "scenario": scenario}
        for cycles, scenario in zip(config.mixture_cycles, config.mixture, strict=True)
    ]
    if base is None and base_factory is None:
        base = base_setup(env_kwargs, base=config.base, runs_dir=config.runs_dir, servo=config.servo)
    hyperparameters = override_hyperparameters(load_hyperparameters(config.algo), config.hyperparams, config.algo)

    command = run.manifest["command"]
    resolved = {
        "arguments": configuration_record(config),
        "hyperparameter_file": HYPERPARAMETER_FILE.name,
        "residual_config": asdict(residual),
        "env_kwargs": {**env_kwargs, "scenario": config.scenario.name},
        "mixture": [{**kwargs, "scenario": kwargs["scenario"].name} for kwargs in mixture],
        "scenario": {"name": config.scenario.name, "file": "scenario.toml", "robot": config.scenario.robot_identity},
        "hyperparameters": hyperparameters,
        "base_controller": "custom (base_factory)" if base is None else base.to_table(),
        "seeds": {
            "training": f"per worker from default_rng([seed, rank]) in {TRAINING_SEEDS}",
            "calibration": list(CALIBRATION_SEEDS),
            "validation": list(VALIDATION_SEEDS),
            "test": list(TEST_SEEDS),
            "test_payloads": list(TEST_PAYLOADS),
        },
    }
    run.record(config=resolved)

    set_random_seed(config.seed)
    factories = [
        make_env(
            config=residual,
            env_kwargs=env_kwargs,
            base=base,
            seed=config.seed,
            rank=rank,
            base_factory=base_factory,
            mixture=mixture,
        )
        for rank in range(config.n_envs)
    ]
    vec_env = SubprocVecEnv(factories) if config.n_envs > 1 else DummyVecEnv(factories)
    eval_env = DummyVecEnv(
        [
            make_env(
                config=residual,
                env_kwargs=env_kwargs,
                base=base,
                seeds=VALIDATION_SEEDS,
                base_factory=base_factory,
                mixture=mixture,
            )
        ]
    )
    algorithm = algorithm_class(config.algo)
    formats = ["stdout", "csv"] if config.verbose else ["csv"]
    if config.resume is not None:
        mismatch = resume_mismatch(config.resume, config.scenario.name, config.base)
        if mismatch is not None:
            warnings.warn(f"{mismatch}; training goes on with the new one", stacklevel=1)
        # The --hyperparams given apply to the resumed model, except its networks, which the checkpoint fixes.
        overrides = override_hyperparameters({}, config.hyperparams, config.algo)
        policy_kwargs = overrides.pop("policy_kwargs", {})
        model = algorithm.load(config.resume, env=vec_env, device="cpu", **overrides)
        changed = {key: value for key, value in policy_kwargs.items() if model.policy_kwargs.get(key) != value}
        if changed:
            raise ValueError(
                f"--hyperparams policy_kwargs {changed}: the checkpoint {config.resume} has {model.policy_kwargs}"
            )
        off_policy = isinstance(model, OffPolicyAlgorithm)
        replay = config.resume.with_name(f"{CHECKPOINT_PREFIX}_replay_buffer_{model.num_timesteps}_steps.pkl")
        reward = reward_change(config.resume, residual)
        trained = trained_config(config.resume)
        relabel = reward is not None and trained is not None and relabelable(trained, residual)
        if off_policy and reward is not None and not (relabel and replay.is_file()):
            # its transitions carry the old reward: the critic would learn from two rewards at once
            warnings.warn(f"{reward}: resuming with an empty replay buffer", stacklevel=1)
            replay = None
        elif off_policy and replay.is_file():
            model.load_replay_buffer(replay)
            if relabel:
                relabel_action_rate(model.replay_buffer, trained, residual)
        elif off_policy:
            # Only the newest replay buffer is kept: an older checkpoint restarts with an empty one.
            warnings.warn(f"no replay buffer at {replay}: resuming with an empty one", stacklevel=1)
            replay = None
        resolved["resumed_from"] = {
            "checkpoint": str(config.resume),
            "setting_changed": mismatch,
            "num_timesteps": model.num_timesteps,
            "replay_buffer": replay if off_policy else None,
            "replay_buffer_relabelled": off_policy and replay is not None and relabel,
            "hyperparameters_changed": overrides,
        }
        run.record(config=resolved)
    else:
        model = algorithm("MlpPolicy", vec_env, seed=config.seed, device="cpu", verbose=0, **hyperparameters)
    logger = configure(str(out), formats)
    if config.tensorboard is not None:
        # One event folder per run under DIR, for `tensorboard --logdir DIR`.
        logger.output_formats.append(make_output_format("tensorboard", str(config.tensorboard / out.name)))
    model.set_logger(logger)

    all_callbacks = [*_callbacks(config, out, eval_env), *callbacks]
    # SubprocVecEnv for training, DummyVecEnv for the held-out episodes: intended, not worth a warning.
    warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
    remaining = max(config.timesteps - model.num_timesteps, 0)
    start = time.monotonic()
    model.learn(
        total_timesteps=remaining,
        callback=all_callbacks,
        reset_num_timesteps=config.resume is None,
        progress_bar=config.progress and HAS_RICH,
    )
    wall_time = time.monotonic() - start
    notes = {"command": command, "seed": config.seed, "timesteps": model.num_timesteps}
    notes["wall_time_s"] = round(wall_time, 1)
    save_residual_policy(model, out / "final_policy.zip", residual, config.algo, base=base, extra=notes)
    best = out / "best_model" / "best_model.zip"
    if best.is_file():
        best_model = algorithm.load(best, device="cpu")
        save_residual_policy(best_model, out / "best_policy.zip", residual, config.algo, base=base, extra=notes)
    vec_env.close()
    eval_env.close()
    learning_curve_figure(out)
    run.record(training={"wall_time_s": round(wall_time, 1), "num_timesteps": model.num_timesteps})
    policies = "final_policy.zip" + (" and best_policy.zip" if best.is_file() else "")
    lines = [
        f"Trained {config.algo.upper()} on {config.scenario.name} for {model.num_timesteps:,} steps in "
        f"{f'{wall_time:.0f} s' if wall_time < 120 else f'{wall_time / 60:.1f} min'}: {policies}."
    ]
    if config.score and base is None:
        lines.append(
            "No scores: the policy was trained on a custom base (base_factory), which its file does not record."
        )
    elif config.score:
        policy = out / ("best_policy.zip" if best.is_file() else "final_policy.zip")
        with progress_bar(desc="test episodes", unit="episode", disable=not config.progress) as bar:
            scores = score_policy(policy, env_kwargs, progress=bar)
        write_json(out / "scores.json", scores)
        lines.append(score_summary(scores))
    return "\n".join(lines)
