"""Train the residual policy of ``DeltaPickPlaceResidual-v0`` with stable-baselines3 (docs/design.md section 6).

    python -m eval.train_residual --seed 0 --timesteps 300000 --max-minutes 15

SAC by default (``--algo`` ppo, tqc or crossq selectable; TQC and CrossQ come from sb3-contrib), with the
hyperparameters of ``eval/hyperparams/residual.toml`` (:mod:`eval.hyperparameters`). ``--hyperparams key:value
...`` overrides any of them as the RL Zoo does; each value is a TOML value, as in the file (of bare words only
``auto`` and ``auto_<x>`` are strings; quote others), and a dotted key sets one entry of a table::

    --hyperparams learning_rate:1e-3 train_freq:4 gradient_steps:2 policy_kwargs.net_arch:[64,64]
    --hyperparams 'policy_kwargs:{ net_arch = [64, 64] }' ent_coef:auto_0.1

Every run folder (``--out``, default ``<runs root>/residual/<UTC time>``; :func:`eval.run_folder.runs_root`) holds:

- ``config.json``: the manifest (:func:`eval.run_folder.run_folder`): the resolved configuration (arguments,
  hyperparameters, residual settings, base controller parameters, seeds) with the command line, versions and git
  commit, the status and the start and end times, written as training starts and as it ends;
- ``checkpoints/``: periodic checkpoints (and the replay buffer of off-policy algorithms) for ``--resume``;
- ``evaluations.npz`` and ``best_model/``: SB3's EvalCallback on held-out seeds (validation), distinct
  from every training seed, and its best model;
- ``learning_curve.csv`` (a row per evaluation, appended as it is made: policy steps, mean, std, min and max
  return) and ``learning_curve.png``, drawn from that file at the end of training (:mod:`eval.plots`);
- ``progress.csv``: training curves (TensorBoard event files go to ``--tensorboard DIR`` when given);
- ``final_policy.zip`` and ``best_policy.zip``: loadable by :func:`controllers.residual.load_residual_controller`;
- ``scores.json``: base vs residual on held-out test seeds (a third, disjoint set), after training
  (:func:`eval.scoring.score_policy`).

``--score-only POLICY`` scores a policy file without training, into its own run folder (``--out``, default
``<runs root>/residual_scores/<UTC time>``: ``config.json``, ``scenario.toml``, ``scores.json``), never beside the
policy file.

Seeds: training episodes draw their env seeds from ``TRAINING_SEEDS`` (per worker, from ``--seed``), validation
uses ``VALIDATION_SEEDS``, the final scores ``TEST_SEEDS`` and the tare calibration ``CALIBRATION_SEEDS``
(:mod:`eval.residual_envs`, :mod:`eval.scoring`): four disjoint sets, all disjoint from ``python -m eval``'s
defaults (seeds 0-9 and its calibration seeds from 100000), so no evaluation episode (reference path, payload
masses, noise) is ever trained on.

Training episodes come from the ``randomized`` scenario by default (domain randomization of masses, friction
and drive lag on the nominal robot; ``--scenario`` chooses another). The base controller is the eval's
``mid_f_rls_lag`` row (``--base mid_f_rls`` for the one without the lead):
MId+F+R with its feedback (the servo layer by default, ``--servo pd`` the paper's PD) and the payload RLS, its
feedforward leading the identified drive lag, its parameters those
of the scenario's robot (``--scenario``, ``--geometry``; ``eval.parameter_files.identify_robot``) and
its tare calibrated on the scenario as the eval does (:mod:`eval.calibration` on payload-free episodes).
Both, and the robot's geometry and masses, are saved in the policy.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from dataclasses import fields as fields_of
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.logger import configure, make_output_format
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from controllers.base import Controller
from controllers.residual import (
    ALGORITHMS,
    PolicyBase,
    ResidualConfig,
    algorithm_class,
    read_policy_settings,
    save_residual_policy,
)
from controllers.residual.env import action_rate_penalty
from controllers.residual.features import PREVIOUS_ACTION
from delta_env.scenario import Scenario
from eval.console import CommandParser, command_main, plural, progress_bar, resolved_arguments
from eval.hyperparameters import HYPERPARAMETER_FILE, load_hyperparameters, override_hyperparameters
from eval.plots import LEARNING_CURVE_COLUMNS, LEARNING_CURVE_FILE, learning_curve_figure
from eval.residual_envs import (
    BASE_KEYS,
    CALIBRATION_SEEDS,
    TRAINING_SEEDS,
    VALIDATION_SEEDS,
    base_setup,
    make_env,
)
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    append_csv_rows,
    command_run_folder,
    write_json,
)
from eval.scenario_args import add_scenario_arguments, add_servo_argument, check_ranges, scenario_from_arguments
from eval.scoring import TEST_PAYLOADS, TEST_SEEDS, score_policy

CHECKPOINT_PREFIX = "residual"
"""CheckpointCallback names: residual_<n>_steps.zip and residual_replay_buffer_<n>_steps.pkl."""

HAS_RICH = importlib.util.find_spec("rich") is not None
"""SB3's progress bar needs tqdm and rich; without rich a plain tqdm bar is used."""

HAS_TENSORBOARD = importlib.util.find_spec("tensorboard") is not None
"""``--tensorboard`` needs the tensorboard package."""


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


REWARD_FIELDS = ("reward_scale", "torque_weight", "action_rate_weight", "plant_torque_weight")
"""The :class:`ResidualConfig` fields a replay buffer's rewards were computed with."""


def trained_config(checkpoint: Path) -> ResidualConfig | None:
    """The residual settings of the run a checkpoint comes from, from the ``config.json`` of its run folder (fields
    its record predates take their defaults); None when no record is found (a checkpoint outside a run folder)."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        record = folder / "config.json"
        if record.is_file():
            return ResidualConfig.from_dict(json.loads(record.read_text())["config"]["residual_config"])
    return None


def reward_change(checkpoint: Path, config: ResidualConfig) -> str | None:
    """What of the reward (:data:`REWARD_FIELDS`) differs between the run a checkpoint comes from and ``config``,
    as a sentence; None when nothing differs or no record is found."""
    trained = trained_config(checkpoint)
    if trained is None:
        return None
    changed = [
        f"{key} {getattr(trained, key)} -> {getattr(config, key)}"
        for key in REWARD_FIELDS
        if getattr(trained, key) != getattr(config, key)
    ]
    return f"the reward changed since {checkpoint}: {', '.join(changed)}" if changed else None


def relabelable(trained: ResidualConfig, config: ResidualConfig) -> bool:
    """Whether a replay buffer filled under ``trained`` can be relabelled for ``config``: of the reward
    (:data:`REWARD_FIELDS`) and the residual's scale only ``action_rate_weight`` changed. The other terms depend on
    the plant's response, which a buffer does not keep."""
    fixed = [key for key in (*REWARD_FIELDS, "residual_limit") if key != "action_rate_weight"]
    return all(getattr(trained, key) == getattr(config, key) for key in fixed)


def relabel_action_rate(buffer: ReplayBuffer, trained: ResidualConfig, config: ResidualConfig) -> None:
    """Recompute, in place, the action-rate term of the rewards in ``buffer`` (filled under ``trained``) for
    ``config``: the term is a function of a transition's action and of the previous action its observation holds
    (:data:`~controllers.residual.features.PREVIOUS_ACTION`), so the relabelled rewards are those the transitions
    would have had under ``config``, to float32 round-off.

    Raises:
        ValueError: if the buffer cannot be relabelled (:func:`relabelable`).
    """
    if not relabelable(trained, config):
        raise ValueError(
            f"only action_rate_weight can be relabelled in a replay buffer: it was filled under {trained}, not {config}"
        )
    filled = buffer.buffer_size if buffer.full else buffer.pos
    actions = buffer.actions[:filled]
    previous = buffer.observations[:filled, ..., PREVIOUS_ACTION]
    change = action_rate_penalty(actions, previous, config) - action_rate_penalty(actions, previous, trained)
    buffer.rewards[:filled] += (config.reward_scale * change).astype(buffer.rewards.dtype)


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
    a ``curve`` path, appends each evaluation's scores to that CSV file (:data:`eval.plots.LEARNING_CURVE_COLUMNS`)."""

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
    """The resolved configuration of ``python -m eval.train_residual`` (a training, or with ``score_only`` the
    scores of a policy file), recorded as it is in the run's manifest (:meth:`manifest`); the options are described
    by ``--help``.

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
        base: The base controller's key (:data:`~eval.residual_envs.BASE_KEYS`).
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

    def manifest(self) -> dict[str, Any]:
        """The configuration as the manifest records it: every field, the scenarios by name (their files are
        beside), the residual's settings as a table."""
        fields = {field.name: getattr(self, field.name) for field in fields_of(self)}
        return {
            **fields,
            "scenario": self.scenario.name,
            "mixture": [scenario.name for scenario in self.mixture],
            "residual": asdict(self.residual),
        }


def train(
    config: TrainingConfig,
    base_factory: Callable[[], Controller] | None = None,
    *,
    base: PolicyBase | None = None,
    callbacks: Sequence[BaseCallback] = (),
) -> Path:
    """Train per ``config`` (see :func:`parse_args`); returns the run folder.

    Args:
        config: The resolved configuration.
        base_factory: Builds the base controller instead of the one of ``config.base`` (tests).
        base: The setup of ``config.base`` already identified and calibrated (:func:`base_setup`), so that
            several runs share one; None makes it.
        callbacks: More SB3 callbacks (after the checkpoint, evaluation and wall-time ones).
    """
    torch.set_num_threads(config.torch_threads)
    with command_run_folder(
        "residual",
        "eval.train_residual",
        None,
        config,
        {"arguments": config.manifest()},
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
        "arguments": config.manifest(),
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


def score_summary(scores: dict[str, Any]) -> str:
    """The scores of :func:`eval.scoring.score_policy` as a few lines of rounded numbers: each row's pooled
    tracking and torque RMS and worst place error, the residual's change over its base and the episodes it improved."""
    summary = scores["summary"]
    rows = {"base": scores["base"], "residual": scores["residual"]}
    width = max(map(len, rows.values()))
    lines = [
        f"Scores of {Path(scores['policy']).name} on {plural(len(scores['episodes']), 'held-out episode')} "
        f"({plural(len(scores['seeds']), 'seed')}, {plural(len(scores['payloads']), 'fixed payload')}), pooled over "
        "every control step:"
    ]
    for name, label in rows.items():
        row = summary[name]
        lines.append(
            f"  {label:<{width}}  tracking RMS {row['tracking_rms_mm']:.3f} mm (max {row['tracking_max_mm']:.2f} mm), "
            f"torque RMS {row['torque_rms_nm']:.2f} N m, place error at most {row['place_error_max_mm']:.3f} mm"
        )
    improved, total = summary["episodes_improved"].split("/")
    lines.append(
        f"  residual vs base: tracking {100 * summary['tracking_rms_change']:+.1f} %, torque "
        f"{100 * summary['torque_rms_change']:+.1f} %; better on {improved} of {plural(int(total), 'episode')}"
    )
    return "\n".join(lines)


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    summary, _, details = __doc__.partition("\n\n")
    parser = CommandParser(
        prog="python -m eval.train_residual",
        description=summary,
        epilog=details,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--algo",
        choices=ALGORITHMS,
        default="sac",
        help="SB3 algorithm, its hyperparameters from eval/hyperparams/residual.toml (default: %(default)s)",
    )
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
    add_force_argument(parser)
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
    add_servo_argument(parser)
    parser.add_argument(
        "--cycles", type=int, default=None, help="pick-and-place cycles per episode (default: the scenario's)"
    )
    parser.add_argument(
        "--mix",
        nargs="+",
        default=[],
        metavar="SCENARIO",
        help="more scenarios of the same robot (presets or TOML files, on --geometry, released as --release) whose "
        "episodes training and validation mix with --scenario's, each episode's seed picking one (seed mod their "
        "number); the base is --scenario's, and so are the final scores",
    )
    parser.add_argument("--residual-limit", type=float, default=ResidualConfig.residual_limit, help="N m at a = 1")
    parser.add_argument("--action-period", type=int, default=ResidualConfig.action_period, help="control steps")
    parser.add_argument(
        "--reward-scale",
        type=float,
        default=ResidualConfig.reward_scale,
        help="factor on the plant env's reward, so that rewards per policy step are of order 1 (default %(default)s)",
    )
    parser.add_argument(
        "--torque-weight",
        type=float,
        default=ResidualConfig.torque_weight,
        help="reward weight ((N m)^-2) of the squared torque per control step, added to the plant env's (default 0)",
    )
    parser.add_argument(
        "--action-rate-weight",
        type=float,
        default=ResidualConfig.action_rate_weight,
        help="reward weight ((N m)^-2) of the squared change of the residual torque per policy step (default 0)",
    )
    parser.add_argument(
        "--off-at-rest",
        action="store_true",
        help="no residual while the reference is at rest (the waits in position, the dwells): the servo holds it",
    )
    parser.add_argument(
        "--plant-torque-weight",
        type=float,
        default=ResidualConfig.plant_torque_weight,
        help="reward weight ((N m)^-2) of the squared applied torque per control step, in place of the plant env's "
        "(default %(default)s, the plant env's; 0: the reward's torque terms are --torque-weight's and "
        "--action-rate-weight's)",
    )
    parser.add_argument(
        "--fade-speed",
        type=float,
        default=ResidualConfig.fade_speed,
        help="rad/s: the residual scaled by min(1, fastest reference joint rate / this), so that it ramps down "
        "as a move comes to rest (default 0: no fade)",
    )
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="override hyperparameters of the TOML file: key:value with a TOML value, dotted keys for table entries",
    )
    parser.add_argument("--tensorboard", type=Path, default=None, help="TensorBoard log folder (needs tensorboard)")
    parser.add_argument(
        "--torch-threads", type=int, default=1, help="threads of torch's CPU operations, >= 1 (default %(default)s)"
    )
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    parser.add_argument("--no-score", dest="score", action="store_false", help="skip the final test scores")
    parser.add_argument("--verbose", action="store_true", help="print SB3 logs to stdout")
    parser.add_argument(
        "--score-only",
        type=Path,
        default=None,
        metavar="POLICY",
        help="no training: score this policy zip on the test seeds",
    )
    return parser


def resolve(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> TrainingConfig:
    """The configuration of the parsed command line ``arguments`` (left as they are): the scenarios, their cycles
    and the residual's settings resolved; a bad value is a parser error."""
    counts = {"seed": 0, "timesteps": 1, "n_envs": 1, "cycles": 1, "checkpoint_freq": 1, "eval_freq": 1}
    check_ranges(parser, arguments, {**counts, "torch_threads": 1}, ("max_minutes",))
    scenario = scenario_from_arguments(arguments, parser)
    mixture = tuple(
        scenario_from_arguments(resolved_arguments(arguments, scenario=name), parser) for name in arguments.mix
    )
    for mixed in mixture:
        if mixed.robot_identity != scenario.robot_identity:
            parser.error(f"--mix {mixed.name}: not the robot of --scenario {scenario.name}, whose base it uses")
    if arguments.tensorboard is not None and not HAS_TENSORBOARD:
        parser.error("--tensorboard needs the tensorboard package (pip install tensorboard)")
    try:
        residual = ResidualConfig(**{name: getattr(arguments, name) for name in RESIDUAL_OPTIONS})
    except ValueError as error:
        flags = ", ".join("--" + name.replace("_", "-") for name in RESIDUAL_OPTIONS if name != "off_at_rest")
        parser.error(f"{flags}: {error}")
    try:
        override_hyperparameters(load_hyperparameters(arguments.algo), arguments.hyperparams, arguments.algo)
    except (ValueError, ImportError) as error:
        parser.error(str(error))
    if arguments.score_only is not None and arguments.mix:
        parser.error("--mix is for training: --score-only scores the episodes of --scenario")
    if arguments.score_only is not None:
        try:
            base = read_policy_settings(arguments.score_only).base
        except (FileNotFoundError, ValueError) as error:
            parser.error(f"--score-only {arguments.score_only}: {error}")
        if base is None:
            parser.error(
                f"--score-only {arguments.score_only}: trained on a custom base, which the file does not record"
            )
    given = {name: value for name, value in vars(arguments).items() if name not in RESIDUAL_OPTIONS}
    return TrainingConfig(
        **{
            **given,
            "scenario": scenario,
            "cycles": scenario.task.n_cycles if arguments.cycles is None else arguments.cycles,
            "mix": tuple(arguments.mix),
            "residual": residual,
            "hyperparams": tuple(arguments.hyperparams),
            "mixture": mixture,
            "mixture_cycles": tuple(arguments.cycles or mixed.task.n_cycles for mixed in mixture),
        }
    )


def parse_args(argv: Sequence[str] | None = None) -> TrainingConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


@command_main("python -m eval.train_residual")
def main(argv: Sequence[str] | None = None) -> int:
    config = parse_args(argv)
    if config.score_only is None:
        train(config)
        return 0
    with command_run_folder(
        "residual_scores",
        "eval.train_residual",
        argv,
        config,
        {"arguments": config.manifest()},
        scenarios=[config.scenario],
    ) as run:
        with progress_bar(desc="test episodes", unit="episode", disable=not config.progress) as bar:
            scores = score_policy(
                config.score_only, {"n_cycles": config.cycles, "scenario": config.scenario}, progress=bar
            )
        write_json(run.folder / "scores.json", scores)
    print(f"{score_summary(scores)}\nRun folder: {run.folder}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
