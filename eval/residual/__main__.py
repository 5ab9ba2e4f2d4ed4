"""Train the residual policy of ``DeltaPickPlaceResidual-v0`` with stable-baselines3 (docs/design.md section 6).

    python -m eval.residual --seed 0 --timesteps 300000 --max-minutes 15

SAC by default (``--algo`` ppo, tqc or crossq selectable; TQC and CrossQ come from sb3-contrib), with the
hyperparameters of ``eval/residual/hyperparams/residual.toml`` (:mod:`eval.residual.hyperparameters`). ``--hyperparams
key:value ...`` overrides any of them as the RL Zoo does; each value is a TOML value, as in the file (of bare words only
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
  return) and ``learning_curve.png``, drawn from that file at the end of training (:mod:`eval.comparison.plots`);
- ``progress.csv``: training curves (TensorBoard event files go to ``--tensorboard DIR`` when given);
- ``final_policy.zip`` and ``best_policy.zip``: loadable by :func:`controllers.residual.load_residual_controller`;
- ``scores.json``: base vs residual on held-out test seeds (a third, disjoint set), after training
  (:func:`eval.residual.scoring.score_policy`).

``--score-only POLICY`` scores a policy file without training, into its own run folder (``--out``, default
``<runs root>/residual_scores/<UTC time>``: ``config.json``, ``scenario.toml``, ``scores.json``), never beside the
policy file.

Seeds: training episodes draw their env seeds from ``TRAINING_SEEDS`` (per worker, from ``--seed``), validation
uses ``VALIDATION_SEEDS``, the final scores ``TEST_SEEDS`` and the tare calibration ``CALIBRATION_SEEDS``
(:mod:`eval.residual.envs`, :mod:`eval.residual.scoring`): four disjoint sets, all disjoint from ``python -m eval``'s
defaults (seeds 0-9 and its calibration seeds from 100000), so no evaluation episode (reference path, payload
masses, noise) is ever trained on.

Training episodes come from the ``randomized`` scenario by default (domain randomization of masses, friction
and drive lag on the nominal robot; ``--scenario`` chooses another). The base controller is the eval's
``mid_f_rls_lag`` row (``--base mid_f_rls`` for the one without the lead):
MId+F+R with its feedback (the servo layer by default, ``--servo pd`` the paper's PD) and the payload RLS, its
feedforward leading the identified drive lag, its parameters those
of the scenario's robot (``--scenario``, ``--geometry``; ``eval.identification.parameter_files.identify_robot``) and
its tare calibrated on the scenario as the eval does (:mod:`eval.calibration` on payload-free episodes).
Both, and the robot's geometry and masses, are saved in the policy.
"""

from __future__ import annotations

import argparse
import importlib.util
from collections.abc import Sequence
from pathlib import Path

from controllers.residual import ALGORITHMS, ResidualConfig, read_policy_settings
from eval.console import CommandParser, command_main, progress_bar, resolved_arguments
from eval.residual.envs import BASE_KEYS
from eval.residual.hyperparameters import load_hyperparameters, override_hyperparameters
from eval.residual.scoring import score_policy, score_summary
from eval.residual.training import RESIDUAL_OPTIONS, TrainingConfig, train
from eval.run_folder import (
    add_force_argument,
    add_runs_dir_argument,
    command_run_folder,
    configuration_record,
    write_json,
)
from eval.scenario_args import add_scenario_arguments, add_servo_argument, check_ranges, scenario_from_arguments

HAS_TENSORBOARD = importlib.util.find_spec("tensorboard") is not None
"""``--tensorboard`` needs the tensorboard package."""


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    summary, _, details = __doc__.partition("\n\n")
    parser = CommandParser(
        prog="python -m eval.residual",
        description=summary,
        epilog=details,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--algo",
        choices=ALGORITHMS,
        default="sac",
        help="SB3 algorithm, its hyperparameters from eval/residual/hyperparams/residual.toml (default: %(default)s)",
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


@command_main("python -m eval.residual")
def main(argv: Sequence[str] | None = None) -> int:
    config = parse_args(argv)
    if config.score_only is None:
        train(config)
        return 0
    with command_run_folder(
        "residual_scores",
        "eval.residual",
        argv,
        config,
        {"arguments": configuration_record(config)},
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
