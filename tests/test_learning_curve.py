"""The residual learning-curve benchmark's bookkeeping (scripts/residual_learning_curve.py), on synthetic curves."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from eval.console import UsageError
from eval.run_folder import append_csv_rows, read_csv_rows

pytest.importorskip("stable_baselines3", reason="the benchmark trains with the rl extra (stable-baselines3)")

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "residual_learning_curve.py"
spec = importlib.util.spec_from_file_location("residual_learning_curve", SCRIPT)
curve = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = curve  # dataclasses look their module up there
spec.loader.exec_module(curve)


def synthetic_rows(label: str, seed: int, reductions: list[float], torque_changes: list[float]) -> list[dict]:
    """Curve rows as read back from curve.csv (strings), one per 10k policy steps, 60 s of training each."""
    return [
        {
            "label": label,
            "seed": str(seed),
            "policy_steps": str(10_000 * (i + 1)),
            "train_wall_s": str(60.0 * (i + 1)),
            "tracking_reduction": str(reduction),
            "torque_change": str(torque),
        }
        for i, (reduction, torque) in enumerate(zip(reductions, torque_changes, strict=True))
    ]


def test_first_crossing_needs_the_reduction_and_the_torque_bound() -> None:
    rows = synthetic_rows("new", 0, [0.2, 0.55, 0.72, 0.75, 0.8], [0.0, 0.01, 0.03, 0.015, 0.0])
    assert curve.first_crossing(rows, 0.5, 0.02) == curve.Crossing(20_000, 120.0)
    # 0.72 at 30k costs 3 % more torque: the first crossing of 70 % within +2 % is at 40k.
    assert curve.first_crossing(rows, 0.7, 0.02) == curve.Crossing(40_000, 240.0)
    assert curve.first_crossing(rows, 0.7, 0.05) == curve.Crossing(30_000, 180.0)
    assert curve.first_crossing(rows, 0.9, 0.02) is None
    assert curve.first_crossing(list(reversed(rows)), 0.5, 0.02) == curve.Crossing(20_000, 120.0), "step order"
    # A curve that reaches the threshold and falls back still crossed it first where it did.
    dip = synthetic_rows("new", 0, [0.6, 0.3, 0.4], [0.0, 0.0, 0.0])
    assert curve.first_crossing(dip, 0.5, 0.02) == curve.Crossing(10_000, 60.0)


def test_summary_table_gives_each_seed_and_the_median() -> None:
    rows = (
        synthetic_rows("new", 0, [0.55, 0.72], [0.0, 0.0])
        + synthetic_rows("new", 1, [0.3, 0.6, 0.71], [0.0, 0.0, 0.0])
        + synthetic_rows("new", 2, [0.1, 0.2], [0.0, 0.0])
    )
    table = curve.summary_table(rows, 0.02).splitlines()
    assert table[2] == "| new | 0 | 10000 | 1.0 | 20000 | 2.0 | 72.0 % | +0.0 % | 20000 | 2.0 |"
    assert table[4] == "| new | 2 | - | - | - | - | 20.0 % | +0.0 % | 20000 | 2.0 |"
    # Two of three seeds reached each threshold; the unreached one ranks last, so the median is the slower seed.
    assert table[5] == "| new | median | 20000 | 2.0 | 30000 | 3.0 |  |  |  |  |"


def test_unfinished_runs_restart_and_finished_ones_are_kept(tmp_path: Path) -> None:
    path = tmp_path / "curve.csv"
    for row in synthetic_rows("new", 0, [0.5], [0.0]) + synthetic_rows("new", 1, [0.4, 0.6], [0.0, 0.0]):
        append_csv_rows(path, curve.CURVE_FIELDS, [{field: row.get(field, "") for field in curve.CURVE_FIELDS}])
    curve.drop_unfinished(path, {("new", "0")})
    assert [(r["seed"], r["policy_steps"]) for r in read_csv_rows(path)] == [("0", "10000")]


def test_named_recipes_exist_in_the_hyperparameter_file() -> None:
    from eval.residual.__main__ import parse_args
    from eval.residual.hyperparameters import load_hyperparameters, override_hyperparameters

    for algo, items, train_args in curve.RECIPES.values():
        override_hyperparameters(load_hyperparameters(algo), items, algo)
        parse_args(list(train_args))
    old = curve.recipes_from_arguments(curve.parse_arguments(["--recipe", "old", "--", "--cycles", "2"]))[0]
    assert old.train_args == ("--residual-limit", "40", "--cycles", "2")


def test_a_folder_of_other_settings_or_another_recipe_under_the_same_label_is_refused(tmp_path: Path) -> None:
    args = curve.parse_arguments(["--recipe", "new", "--max-minutes", "5", "--out", str(tmp_path)])
    recipes = curve.recipes_from_arguments(args)
    curve.check_settings(tmp_path, args, recipes)
    curve.check_settings(tmp_path, args, recipes)  # the same again: resumes
    longer = curve.parse_arguments(["--recipe", "new", "--max-minutes", "15", "--out", str(tmp_path)])
    with pytest.raises(UsageError, match="max_minutes"):
        curve.check_settings(tmp_path, longer, recipes)
    renamed = [curve.Recipe("new", "sac", ("train_freq:1",), ())]
    with pytest.raises(UsageError, match="'new' runs of"):
        curve.check_settings(tmp_path, args, renamed)


def test_training_seeds_are_seed_and_runs_like_the_other_command_lines() -> None:
    args = curve.parse_arguments(["--seed", "2", "--runs", "2", "--eval-freq", "500"])
    assert (args.seeds, args.eval_freq) == ([2, 3], 500)
    assert curve.parse_arguments([]).seeds == [0, 1, 2]
    with pytest.raises(SystemExit):
        curve.parse_arguments(["--runs", "0"])
