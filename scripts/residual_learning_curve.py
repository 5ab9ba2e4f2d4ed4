"""Learning-curve benchmark of the residual policy: policy steps and training wall time to a tracking gain.

    python scripts/residual_learning_curve.py --recipe old new --seed 0 --runs 3 --max-minutes 20
    python scripts/residual_learning_curve.py --algo crossq --hyperparams policy_kwargs.net_arch:[256,256] \\
        --label crossq256 --seed 0 --runs 1 --max-minutes 12 --out /tmp/rl-runs/crossq256
    python scripts/residual_learning_curve.py --recipe new --runs 1 -- --reward-scale 0.1

Each recipe trains ``--runs`` times, from the training seeds ``--seed`` to ``--seed + --runs - 1``, with
:func:`eval.residual.training.train` (one env, ``DummyVecEnv``), and every ``--eval-freq``
policy steps pauses to save the policy (``validation_policy.zip`` in the run's folder) and score it with
:func:`eval.residual.scoring.score_policy` on the held-out validation episodes (``VALIDATION_SEEDS``, the ``randomized``
scenario unless other training arguments follow ``--``; ``--scenario``'s alone with ``--mix``): the base controller
alone and with the residual, as the file records them, run by the experiment engine (:func:`eval.work.run_grid`, in
this process: a pool's fresh workers would plan an online timing's tables again at every evaluation), tracking RMS
and torque RMS pooled over every control step. A threshold counts as reached at the
first evaluation whose tracking RMS is that much lower than the base's with torque RMS at most
``--max-torque-change`` above the base's.

The training wall time excludes the evaluations (and the base controller's identification and tare
calibration, done once per invocation); ``--max-minutes`` caps each run's training wall time. A run stops
once every threshold is reached unless ``--full-curve``.

Output (``--out``, default ``<runs root>/learning_curve/<UTC time>``, with the manifest ``config.json`` of the last
invocation, :mod:`eval.run_folder`): ``curve.csv`` gets one row per evaluation as
it comes, ``runs.csv`` one row per finished run; invoked again with the same ``--out``, finished runs
(label and seed) are skipped and an unfinished one restarts; ``settings.json`` records each label's recipe and the
common settings, and a folder made under others is refused. The table of every run in the folder is printed at the
end and written to ``table.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from controllers.residual import ALGORITHMS, PolicyBase, ResidualConfig, save_residual_policy
from eval.console import CommandParser, UsageError, command_main, resolved_arguments
from eval.residual.__main__ import parse_args
from eval.residual.envs import VALIDATION_SEEDS, base_setup
from eval.residual.scoring import score_policy
from eval.residual.training import train
from eval.run_folder import add_runs_dir_argument, append_csv_rows, command_line, read_csv_rows, run_folder
from eval.scenario_args import check_ranges

RECIPES: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "old": ("sac", ("train_freq:2", "gradient_steps:1", "learning_rate:3e-4"), ("--residual-limit", "40")),
    "new": ("sac", (), ()),
}
"""Named recipes: algorithm, ``--hyperparams`` items on top of its table in ``eval/residual/hyperparams/residual.toml``
and more training arguments. ``old`` is the shipped policy's (SAC at 3e-4, 40 N m, one update per two samples: it
was trained on two envs with one update per vector step); ``new`` the tool's defaults."""

THRESHOLDS = (0.5, 0.7)
"""Tracking-RMS reductions against the base (fractions) whose first crossing is reported."""

CURVE_FIELDS = (
    "label", "algo", "hyperparams", "train_args", "seed", "policy_steps", "train_wall_s", "eval_wall_s",
    "base_tracking_rms_mm", "tracking_rms_mm", "tracking_reduction", "base_torque_rms_nm", "torque_rms_nm",
    "torque_change",
)  # fmt: skip
RUN_FIELDS = ("label", "seed", "policy_steps", "train_wall_s", "stopped")

SETTINGS_NAME = "settings.json"
"""The file of an output folder that records its recipes and common settings (:func:`check_settings`)."""


@dataclass(frozen=True)
class Recipe:
    """What one benchmark row trains: a label, the algorithm, ``--hyperparams`` items and other training arguments."""

    label: str
    algo: str
    hyperparams: tuple[str, ...]
    train_args: tuple[str, ...]


@dataclass(frozen=True)
class Crossing:
    """The first evaluation that reached a threshold: policy steps and training wall time (s)."""

    policy_steps: int
    train_wall_s: float


def first_crossing(rows: Sequence[dict[str, Any]], threshold: float, max_torque_change: float) -> Crossing | None:
    """The first row (in policy-step order) with ``tracking_reduction >= threshold`` and ``torque_change <=
    max_torque_change`` (fractions), or None when no row qualifies."""
    for row in sorted(rows, key=lambda r: int(r["policy_steps"])):
        if float(row["tracking_reduction"]) >= threshold and float(row["torque_change"]) <= max_torque_change:
            return Crossing(int(row["policy_steps"]), float(row["train_wall_s"]))
    return None


def validation_scores(policy_path: Path, env_kwargs: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Pooled tracking and torque RMS of the validation episodes of the policy file ``policy_path``: ``"base"`` (its
    base alone) and ``"residual"`` (the policy on it), by :func:`eval.residual.scoring.score_policy`."""
    scores = score_policy(policy_path, env_kwargs, seeds=VALIDATION_SEEDS, payloads=())
    return {row: scores["summary"][row] for row in ("base", "residual")}


class ValidationCurve(BaseCallback):
    """Every ``eval_every`` policy steps, saves the policy to ``policy_path``, scores it on the validation episodes
    and appends a curve row; stops training once ``max_minutes`` of training wall time (evaluations excluded) are
    spent or, with ``stop_when_reached``, once every threshold is reached."""

    def __init__(
        self,
        *,
        recipe: Recipe,
        seed: int,
        base: PolicyBase,
        config: ResidualConfig,
        env_kwargs: dict[str, Any],
        policy_path: Path,
        curve_path: Path,
        eval_every: int,
        max_minutes: float,
        max_torque_change: float,
        stop_when_reached: bool,
    ) -> None:
        super().__init__()
        self.recipe, self.seed, self.base, self.config, self.env_kwargs = recipe, seed, base, config, env_kwargs
        self.policy_path, self.curve_path, self.eval_every = policy_path, curve_path, eval_every
        self.max_seconds, self.max_torque_change = 60.0 * max_minutes, max_torque_change
        self.stop_when_reached = stop_when_reached
        self.rows: list[dict[str, Any]] = []
        self.start = 0.0
        self.eval_seconds = 0.0
        self.next_evaluation = eval_every
        self.stopped = "timesteps"

    def train_seconds(self) -> float:
        """Wall time (s) since training started, evaluations excluded."""
        return time.monotonic() - self.start - self.eval_seconds

    def _on_training_start(self) -> None:
        self.start = time.monotonic()

    def evaluate(self) -> dict[str, Any]:
        """Score the current policy and append its row to the curve file."""
        train_wall = self.train_seconds()
        began = time.monotonic()
        save_residual_policy(self.model, self.policy_path, self.config, self.recipe.algo, base=self.base)
        rows = validation_scores(self.policy_path, self.env_kwargs)
        eval_wall = time.monotonic() - began
        self.eval_seconds += eval_wall
        base, scores = rows["base"], rows["residual"]
        row = {
            "label": self.recipe.label,
            "algo": self.recipe.algo,
            "hyperparams": " ".join(self.recipe.hyperparams),
            "train_args": " ".join(self.recipe.train_args),
            "seed": self.seed,
            "policy_steps": self.num_timesteps,
            "train_wall_s": round(train_wall, 1),
            "eval_wall_s": round(eval_wall, 1),
            "base_tracking_rms_mm": round(base["tracking_rms_mm"], 5),
            "tracking_rms_mm": round(scores["tracking_rms_mm"], 5),
            "tracking_reduction": round(1.0 - scores["tracking_rms_mm"] / base["tracking_rms_mm"], 4),
            "base_torque_rms_nm": round(base["torque_rms_nm"], 4),
            "torque_rms_nm": round(scores["torque_rms_nm"], 4),
            "torque_change": round(scores["torque_rms_nm"] / base["torque_rms_nm"] - 1.0, 4),
        }
        append_csv_rows(self.curve_path, CURVE_FIELDS, [row])
        self.rows.append(row)
        print(
            f"{row['label']} seed {self.seed}: {row['policy_steps']} steps, {row['train_wall_s']:.0f} s training, "
            f"tracking {-100 * row['tracking_reduction']:+.1f} %, torque {100 * row['torque_change']:+.1f} %",
            flush=True,
        )
        return row

    def _on_step(self) -> bool:
        if self.train_seconds() >= self.max_seconds:
            self.evaluate()
            self.stopped = "max_minutes"
            return False
        if self.num_timesteps < self.next_evaluation:
            return True
        self.next_evaluation += self.eval_every
        self.evaluate()
        reached = all(first_crossing(self.rows, t, self.max_torque_change) for t in THRESHOLDS)
        if self.stop_when_reached and reached:
            self.stopped = "thresholds_reached"
            return False
        return True


def drop_unfinished(curve_path: Path, finished: set[tuple[str, str]]) -> None:
    """Remove from the curve file the rows of runs (label, seed) that did not finish: they restart. The kept rows
    are written to a new file that then replaces the old one, so an interruption loses none of them."""
    rows = read_csv_rows(curve_path)
    kept = [row for row in rows if (row["label"], row["seed"]) in finished]
    if len(kept) == len(rows):
        return
    partial = curve_path.with_suffix(".partial")
    partial.unlink(missing_ok=True)
    append_csv_rows(partial, CURVE_FIELDS, kept)
    os.replace(partial, curve_path)


def check_settings(out: Path, args: argparse.Namespace, recipes: Sequence[Recipe]) -> None:
    """Record the benchmark's settings in ``out/settings.json``; refuse (SystemExit) a folder whose runs were made
    under other settings or another recipe of the same label, whose rows would otherwise mix with these."""
    path = out / SETTINGS_NAME
    settings = json.loads(path.read_text()) if path.is_file() else {"recipes": {}}
    # "eval_every" is --eval-freq's name in the settings files written before the flag took train_residual's name.
    common = {"timesteps": args.timesteps, "eval_every": args.eval_freq, "max_minutes": args.max_minutes}
    common["max_torque_change"] = args.max_torque_change
    common["full_curve"] = args.full_curve
    if settings.get("common", common) != common:
        raise UsageError(f"{out} holds runs made with {settings['common']}, not {common}: use another --out")
    for recipe in recipes:
        current = {"algo": recipe.algo, "hyperparams": list(recipe.hyperparams), "train_args": list(recipe.train_args)}
        recorded = settings["recipes"].setdefault(recipe.label, current)
        if recorded != current:
            raise UsageError(f"{out} holds {recipe.label!r} runs of {recorded}, not {current}: use another --out")
    settings["common"] = common
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(settings, indent=2) + "\n")
    os.replace(partial, path)


def summary_table(curve_rows: Sequence[dict[str, str]], max_torque_change: float) -> str:
    """Markdown table: per recipe and seed, steps and training minutes to each threshold, best reduction and
    its torque change; then the median over seeds per recipe (a run that never reached a threshold counts as
    not reached, and the median is reported only when most seeds reached it)."""
    header = ["recipe", "seed"]
    for threshold in THRESHOLDS:
        header += [f"steps to {threshold:.0%}", f"min to {threshold:.0%}"]
    header += ["best reduction", "torque at best", "last steps", "last min"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    labels = list(dict.fromkeys(row["label"] for row in curve_rows))
    for label in labels:
        per_seed: dict[str, list[dict[str, str]]] = {}
        for row in curve_rows:
            if row["label"] == label:
                per_seed.setdefault(row["seed"], []).append(row)
        crossings: dict[float, list[Crossing | None]] = {t: [] for t in THRESHOLDS}
        for seed, rows in per_seed.items():
            cells = [label, seed]
            for threshold in THRESHOLDS:
                crossing = first_crossing(rows, threshold, max_torque_change)
                crossings[threshold].append(crossing)
                cells += (
                    ["-", "-"]
                    if crossing is None
                    else [f"{crossing.policy_steps}", f"{crossing.train_wall_s / 60:.1f}"]
                )
            best = max(rows, key=lambda r: float(r["tracking_reduction"]))
            last = max(rows, key=lambda r: int(r["policy_steps"]))
            cells += [
                f"{100 * float(best['tracking_reduction']):.1f} %",
                f"{100 * float(best['torque_change']):+.1f} %",
                last["policy_steps"],
                f"{float(last['train_wall_s']) / 60:.1f}",
            ]
            lines.append("| " + " | ".join(cells) + " |")
        if len(per_seed) > 1:
            cells = [label, "median"]
            for threshold in THRESHOLDS:
                reached = [c for c in crossings[threshold] if c is not None]
                if 2 * len(reached) > len(crossings[threshold]):
                    # Unreached seeds rank above every reached one.
                    steps = [c.policy_steps if c else float("inf") for c in crossings[threshold]]
                    walls = [c.train_wall_s if c else float("inf") for c in crossings[threshold]]
                    cells += [f"{statistics.median(steps):.0f}", f"{statistics.median(walls) / 60:.1f}"]
                else:
                    cells += ["-", "-"]
            cells += ["", "", "", ""]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def recipes_from_arguments(args: argparse.Namespace) -> list[Recipe]:
    """The recipes to run: the named ones, or one from ``--algo`` and ``--hyperparams``."""
    train_args = tuple(args.train_args)
    if args.recipe:
        return [
            Recipe(name, algo, items, (*recipe_args, *train_args))
            for name in args.recipe
            for algo, items, recipe_args in [RECIPES[name]]
        ]
    label = args.label or " ".join([args.algo, *args.hyperparams, *train_args])
    return [Recipe(label, args.algo, tuple(args.hyperparams), train_args)]


def run(recipe: Recipe, seed: int, args: argparse.Namespace, out: Path, shared: dict[str, Any]) -> None:
    """Train one recipe from one seed with the validation curve; appends its rows and its run row."""
    folder = out / "runs" / f"{recipe.label.replace(' ', '_').replace('/', '_')}_seed{seed}"
    train_arguments = parse_args(
        [
            "--algo", recipe.algo, "--seed", str(seed), "--timesteps", str(args.timesteps), "--n-envs", "1",
            "--eval-freq", str(args.timesteps + 1), "--checkpoint-freq", str(args.timesteps + 1),
            "--no-progress", "--no-score", "--out", str(folder), "--force",
            *(["--runs-dir", str(args.runs_dir)] if args.runs_dir is not None else []),
            *(["--hyperparams", *recipe.hyperparams] if recipe.hyperparams else []),
            *recipe.train_args,
        ]
    )  # fmt: skip
    env_kwargs = {"n_cycles": train_arguments.cycles, "scenario": train_arguments.scenario}
    key = (train_arguments.scenario.name, train_arguments.base, train_arguments.cycles)
    if key not in shared:
        shared[key] = base_setup(
            env_kwargs, base=train_arguments.base, runs_dir=train_arguments.runs_dir, servo=train_arguments.servo
        )
    base = shared[key]
    curve = ValidationCurve(
        recipe=recipe,
        seed=seed,
        base=base,
        config=train_arguments.residual,
        env_kwargs=env_kwargs,
        policy_path=folder / "validation_policy.zip",
        curve_path=out / "curve.csv",
        eval_every=args.eval_freq,
        max_minutes=args.max_minutes,
        max_torque_change=args.max_torque_change,
        stop_when_reached=not args.full_curve,
    )
    train(train_arguments, base=base, callbacks=[curve])
    if not curve.rows or curve.rows[-1]["policy_steps"] != curve.num_timesteps:
        curve.evaluate()
    run_row = {
        "label": recipe.label,
        "seed": seed,
        "policy_steps": curve.num_timesteps,
        "train_wall_s": round(curve.train_seconds(), 1),
        "stopped": curve.stopped,
    }
    append_csv_rows(out / "runs.csv", RUN_FIELDS, [run_row])


def parse_arguments(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = CommandParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recipe", nargs="+", choices=sorted(RECIPES), default=None, help="named recipes")
    parser.add_argument("--algo", choices=ALGORITHMS, default="sac", help="without --recipe")
    parser.add_argument("--hyperparams", nargs="+", default=[], metavar="KEY:VALUE", help="without --recipe")
    parser.add_argument("--label", default=None, help="name of the --algo recipe in the tables")
    parser.add_argument("--seed", type=int, default=0, help="training seed of the first run (default 0)")
    parser.add_argument("--runs", type=int, default=3, help="runs per recipe, one per training seed (default 3)")
    parser.add_argument("--timesteps", type=int, default=1_000_000, help="policy steps per run at most")
    parser.add_argument("--eval-freq", type=int, default=10_000, help="policy steps between held-out evaluations")
    parser.add_argument("--max-minutes", type=float, default=20.0, help="training wall time per run at most")
    parser.add_argument(
        "--max-torque-change", type=float, default=0.02, help="torque RMS rise allowed at a crossing (fraction)"
    )
    parser.add_argument("--full-curve", action="store_true", help="go on after every threshold is reached")
    parser.add_argument("--out", type=Path, default=None, help="default <runs root>/learning_curve/<UTC time>")
    add_runs_dir_argument(parser)
    parser.add_argument("train_args", nargs="*", help="after --: more arguments of python -m eval.residual")
    args = parser.parse_args(argv)
    if args.recipe and (args.hyperparams or args.label):
        parser.error("--hyperparams and --label go with --algo, not with --recipe")
    check_ranges(parser, args, {"seed": 0, "runs": 1, "timesteps": 1, "eval_freq": 1}, ("max_minutes",))
    return resolved_arguments(args, seeds=list(range(args.seed, args.seed + args.runs)))


@command_main("python scripts/residual_learning_curve.py")
def main(argv: Sequence[str] | None = None) -> int:
    args = parse_arguments(argv)
    command = command_line("scripts/residual_learning_curve.py", argv)
    with run_folder("learning_curve", command, vars(args), out=args.out, runs_dir=args.runs_dir, reuse=True) as run:
        benchmark(args, run.folder)
    return 0


def benchmark(args: argparse.Namespace, out: Path) -> None:
    """Run the recipes and seeds of ``args`` (:func:`parse_arguments`) not yet finished in ``out``; print the
    table of every run there."""
    recipes = recipes_from_arguments(args)
    check_settings(out, args, recipes)
    finished = {(row["label"], row["seed"]) for row in read_csv_rows(out / "runs.csv")}
    drop_unfinished(out / "curve.csv", finished)
    shared: dict[str, Any] = {}
    for recipe in recipes:
        for seed in args.seeds:
            if (recipe.label, str(seed)) in finished:
                print(f"{recipe.label} seed {seed}: done before, skipped")
                continue
            run(recipe, seed, args, out, shared)
    table = summary_table(read_csv_rows(out / "curve.csv"), args.max_torque_change)
    (out / "table.md").write_text(table + "\n")
    print(f"{table}\n\nRun folder: {out}")


if __name__ == "__main__":
    raise SystemExit(main())
