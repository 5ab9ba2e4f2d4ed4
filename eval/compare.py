"""``python -m eval.compare RUN RUN [...]``: the rows of two or more run folders side by side, with differences.

The first folder is the baseline: for every row (a controller; in a sweep, a scenario and a controller) and
metric, each other folder's value, its difference from the baseline's and the relative change. The folders must be
of one kind (the ``tool`` of their manifests, ``config.json``: :mod:`eval.run_folder`), one that has rows per
controller:

- ``eval`` (``python -m eval``): per controller, the mean over its episodes that did not diverge
  (``episodes.csv``), as in the run's summary;
- ``sweep`` (``python -m eval.sweep``): per scenario and controller, the means of ``summary.csv``.

Prints a short table of ``--metrics`` (rounded to 3 significant digits); ``--out FILE.csv`` writes every metric the
folders share, unrounded. A path that is not a run folder, folders of different kinds or of a kind without such
rows are refused with a one-line error (exit code 2).

Usage: python -m eval.compare RUN RUN [RUN ...] [--metrics tracking_rms_mm,torque_rms_nm] [--out FILE.csv]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from eval import metrics
from eval.console import CommandParser, UsageError, command_main
from eval.run_folder import MANIFEST, read_csv_rows, write_csv

DEFAULT_METRICS = ("tracking_rms_mm", "torque_rms_nm")
"""Metrics of the printed table unless ``--metrics`` names others."""

ABSENT = "-"
"""The printed table's cell of a row that a run does not have."""

Rows = dict[str, dict[str, float]]
"""Metric values by row name and metric name."""


class CompareError(ValueError):
    """A folder that cannot be compared: the message names it and what was expected."""


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def eval_rows(folder: Path) -> Rows:
    """Per controller of a ``python -m eval`` run, the mean of each metric of :data:`eval.metrics.METRIC_LABELS`
    over its episodes that did not diverge."""
    episodes = _table(folder, "episodes.csv")
    rows: Rows = {}
    for label, group in metrics.group_by(episodes, "controller").items():
        kept = [row for row in group if row["diverged"] != "True"]
        rows[str(label)] = {
            name: metrics.mean_std([_number(row[name]) for row in kept])[0]
            for name in metrics.METRIC_LABELS
            if name in group[0]
        }
    return rows


def sweep_rows(folder: Path) -> Rows:
    """Per scenario and controller of a ``python -m eval.sweep`` run (``"<scenario> / <controller>"``), the means
    of each metric of :data:`eval.metrics.METRIC_LABELS` in its ``summary.csv``."""
    return {
        f"{row['scenario']} / {row['label']}": {
            name: _number(row[f"{name}_mean"]) for name in metrics.METRIC_LABELS if f"{name}_mean" in row
        }
        for row in _table(folder, "summary.csv")
    }


READERS: dict[str, Callable[[Path], Rows]] = {"eval": eval_rows, "sweep": sweep_rows}
"""The rows of each kind of run folder (its manifest's ``tool``) that can be compared."""


def _table(folder: Path, name: str) -> list[dict[str, str]]:
    path = folder / name
    if not path.is_file():
        raise CompareError(f"{folder} has no {name}: the run did not write its rows")
    return read_csv_rows(path)


@dataclass(frozen=True)
class RunRows:
    """One run folder's rows.

    Attributes:
        folder: The run folder.
        kind: Its manifest's ``tool``.
        status: Its manifest's ``status`` (finished, failed, interrupted, running).
        rows: Metric values by row and metric.
    """

    folder: Path
    kind: str
    status: str
    rows: Rows


def manifest_kind(folder: Path) -> tuple[str, str]:
    """The ``tool`` and ``status`` of the manifest of run folder ``folder``.

    Raises:
        CompareError: if ``folder`` is not a run folder (no directory, no readable manifest).
    """
    if not folder.exists():
        raise CompareError(f"{folder} is not a run folder: no such directory")
    if not folder.is_dir():
        raise CompareError(f"{folder} is not a run folder: not a directory")
    path = folder / MANIFEST
    try:
        manifest = json.loads(path.read_text())
        return str(manifest["tool"]), str(manifest.get("status", "unknown"))
    except FileNotFoundError:
        raise CompareError(f"{folder} is not a run folder: it has no {MANIFEST}") from None
    except (json.JSONDecodeError, KeyError, TypeError):
        raise CompareError(f"{folder} is not a run folder: {path} is not a run manifest (no 'tool')") from None


def read_runs(folders: Sequence[Path]) -> list[RunRows]:
    """The rows of ``folders``, all of one kind that :data:`READERS` reads.

    Raises:
        CompareError: if a folder is not a run folder, if the folders are of different kinds, or of a kind without
            rows per controller.
    """
    kinds = [(Path(folder), *manifest_kind(Path(folder))) for folder in folders]
    if len({kind for _, kind, _ in kinds}) > 1:
        described = ", ".join(f"{folder} is {kind!r}" for folder, kind, _ in kinds)
        raise CompareError(f"run folders of different kinds: {described}")
    kind = kinds[0][1]
    if kind not in READERS:
        raise CompareError(
            f"{kinds[0][0]} is a {kind!r} run; eval.compare reads runs of the kinds {', '.join(map(repr, READERS))}"
        )
    return [RunRows(folder, kind, status, READERS[kind](folder)) for folder, kind, status in kinds]


def difference(value: float, baseline: float) -> tuple[float, float]:
    """``value - baseline`` and the relative change ``value / baseline - 1`` (NaN where the baseline is 0 or not
    finite)."""
    relative = value / baseline - 1.0 if baseline != 0.0 and math.isfinite(baseline) else math.nan
    return value - baseline, relative


def row_names(runs: Sequence[RunRows]) -> list[str]:
    """Every row of ``runs``: the baseline's in its order, then the others' new ones."""
    return list(dict.fromkeys(name for run in runs for name in run.rows))


def shared_metrics(runs: Sequence[RunRows]) -> list[str]:
    """The metrics of :data:`eval.metrics.METRIC_LABELS` that every run has, in that order."""
    present = [{name for row in run.rows.values() for name in row} for run in runs]
    return [name for name in metrics.METRIC_LABELS if all(name in names for names in present)]


def comparison_rows(runs: Sequence[RunRows], names: Sequence[str]) -> list[dict[str, object]]:
    """One CSV row per row of the runs and metric of ``names``: each run's value (``run_<i>``, 1 the baseline), and
    for the others the difference from the baseline (``difference_<i>``) and the relative change
    (``change_percent_<i>``, %)."""
    baseline = runs[0]
    table = []
    for row in row_names(runs):
        for name in names:
            base = baseline.rows.get(row, {}).get(name, math.nan)
            entry: dict[str, object] = {"row": row, "metric": name, "metric_label": metrics.metric_label(name)}
            entry["run_1"] = base
            for index, run in enumerate(runs[1:], start=2):
                value = run.rows.get(row, {}).get(name, math.nan)
                change, relative = difference(value, base)
                entry.update(
                    {f"run_{index}": value, f"difference_{index}": change, f"change_percent_{index}": 100.0 * relative}
                )
            table.append(entry)
    return table


def _signed(value: float, digits: int = 3) -> str:
    text = metrics.format_number(value, digits)
    return text if text.startswith("-") or text in ("n/a", "0") else f"+{text}"


def _changed(value: float, change: float, percent: float) -> str:
    """A run's value with its difference from the baseline and the relative change: "5.55 (+0.249, +4.7 %)"."""
    if not math.isfinite(change):
        return metrics.format_number(value)
    relative = f", {_signed(percent, 2)} %" if math.isfinite(percent) else ""
    return f"{metrics.format_number(value)} ({_signed(change)}{relative})"


def markdown(runs: Sequence[RunRows], names: Sequence[str]) -> str:
    """The table of ``names`` (metrics): a line per row; per metric, the baseline's value and each other run's with
    its difference from the baseline and the relative change, rounded to 3 (the change to 2) significant digits."""
    header = ["Row"]
    for name in names:
        label = metrics.metric_label(name)
        header += [f"{label}, 1"] + [f"{index} (vs 1)" for index in range(2, len(runs) + 1)]
    entries = {(entry["row"], entry["metric"]): entry for entry in comparison_rows(runs, names)}
    lines = []
    for row in row_names(runs):
        line = [row]
        for name in names:
            entry = entries[row, name]
            for index, run in enumerate(runs, start=1):
                value = float(entry[f"run_{index}"])
                if row not in run.rows:
                    line.append(ABSENT)
                elif index == 1:
                    line.append(metrics.format_number(value))
                else:
                    change, percent = float(entry[f"difference_{index}"]), float(entry[f"change_percent_{index}"])
                    line.append(_changed(value, change, percent))
        lines.append(line)
    return metrics.markdown_table(header, lines)


def _legend(runs: Sequence[RunRows]) -> list[str]:
    return [
        f"{index}{' (baseline)' if index == 1 else ''}: {run.folder}"
        + ("" if run.status == "finished" else f" (status {run.status})")
        for index, run in enumerate(runs, start=1)
    ]


@dataclass(frozen=True)
class CompareConfig:
    """The resolved configuration of a comparison of run folders (``python -m eval.compare``).

    Attributes:
        runs: The run folders, the baseline first; two or more.
        metrics: The printed table's metrics (:data:`eval.metrics.METRIC_LABELS`), in order.
        out: The CSV file of every shared metric, or None.
    """

    runs: tuple[Path, ...]
    metrics: tuple[str, ...]
    out: Path | None


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    parser = CommandParser(
        prog="python -m eval.compare", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run folders, the baseline first")
    parser.add_argument(
        "--metrics",
        default=",".join(DEFAULT_METRICS),
        help=f"comma-separated metrics of the printed table (default {','.join(DEFAULT_METRICS)}; one of "
        f"{', '.join(metrics.METRIC_LABELS)})",
    )
    parser.add_argument("--out", type=Path, default=None, help="CSV file of every shared metric (default: none)")
    return parser


def resolve(arguments: argparse.Namespace) -> CompareConfig:
    """The configuration of the parsed command line ``arguments`` (left as they are).

    Raises:
        UsageError: for fewer than two run folders or an unknown metric.
    """
    if len(arguments.runs) < 2:
        raise UsageError(f"compare needs two run folders or more, got {len(arguments.runs)}: {arguments.runs[0]}")
    chosen = tuple(name.strip() for name in arguments.metrics.split(",") if name.strip())
    unknown = [name for name in chosen if name not in metrics.METRIC_LABELS]
    if unknown or not chosen:
        raise UsageError(
            f"--metrics {arguments.metrics!r}: unknown {', '.join(unknown) or 'none given'}; "
            f"allowed: {', '.join(metrics.METRIC_LABELS)}"
        )
    return CompareConfig(runs=tuple(arguments.runs), metrics=chosen, out=arguments.out)


def parse_args(argv: Sequence[str] | None) -> CompareConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``).

    Raises:
        UsageError: as :func:`resolve`.
    """
    return resolve(argument_parser().parse_args(argv))


def feedbacks(runs: Sequence[RunRows]) -> list[str | None]:
    """The feedback each run's model rows ran (its manifest's ``servo``; None where it does not say)."""
    found = []
    for run in runs:
        manifest = json.loads((run.folder / MANIFEST).read_text())
        found.append(manifest.get("config", {}).get("servo", manifest.get("servo")))
    return found


@command_main("python -m eval.compare")
def main(argv: Sequence[str] | None = None) -> int:
    """Compare the run folders of ``argv``; 0 on success (a usage error: one line on stderr and exit code 2)."""
    config = parse_args(argv)
    try:
        runs = read_runs(config.runs)
    except CompareError as error:
        raise UsageError(str(error)) from None
    shared = shared_metrics(runs)
    missing = [name for name in config.metrics if name not in shared]
    if missing:
        raise UsageError(
            f"--metrics: {', '.join(missing)} not in every run folder; shared: {', '.join(shared) or 'none'}"
        )
    if config.out is not None:
        try:  # before anything is printed: a folder that cannot be made is the user's to fix
            config.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise UsageError(f"--out {config.out}: cannot write it ({error.strerror or error})") from None
    print(f"Comparison of {len(runs)} {runs[0].kind!r} runs:")
    print("\n".join(_legend(runs)))
    servos = feedbacks(runs)
    if len(set(servos)) > 1:
        print(
            "Note: the runs' model rows ran different feedback (--servo: "
            + ", ".join(f"{index}: {servo or 'not recorded'}" for index, servo in enumerate(servos, start=1))
            + "); their labels are the same."
        )
    print()
    print(markdown(runs, config.metrics))
    if config.out is not None:
        write_csv(config.out, comparison_rows(runs, shared))
        print(f"\nEvery shared metric: {config.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
