"""The figures of an evaluation run: made from the run folder's files, in this process or beside it."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import matplotlib.artist
import matplotlib.figure
import matplotlib.lines
import numpy as np
import pytest
from mpl_toolkits.mplot3d.art3d import Line3D

from eval import plots
from eval.faults import FAULT_COLUMNS, write_fault_csv
from eval.processes import pool_context

SAVED_FIRST = ("traces.npz",)
SAVED_LAST = ("table2_run.npz", "table2.csv", "episodes.csv", "faults.csv")


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _run_folder(folder: Path, faults: bool = True) -> Path:
    """A run folder with the files the figures are made from: two controllers, one estimating, 300 steps, one
    carry; with ``faults``, a fault of each outcome in ``faults.csv``, else its header only."""
    rng = np.random.default_rng(3)
    steps, keys, labels = 300, ["pd", "mid_f_rls"], ["PD", "MId+F+RLS"]
    (folder / "scenario.toml").write_text('name = "nominal"\n')
    angle = np.linspace(0.0, np.pi, steps)
    reference = np.stack((0.3 * np.cos(angle), 0.2 * np.sin(angle), -0.9 + 0.02 * np.sin(2 * angle)), -1)
    deviation = 0.002 * np.stack((np.sin(angle), np.zeros(steps), np.zeros(steps)), -1)  # at most 2 mm
    np.savez_compressed(
        folder / "traces.npz",
        dt=1e-3,
        keys=np.array(keys),
        labels=np.array(labels),
        estimates_payload=np.array([False, True]),
        **{f"{key}.tracking_error": 1e-3 * rng.random(steps) for key in keys},
        **{f"{key}.torque": rng.normal(size=(steps, 3)) for key in keys},
        **{f"{key}.payload_mass": np.full(steps + 1, 2.0) for key in keys},
        **{f"{key}.payload_estimate": 2.0 + 0.1 * rng.normal(size=steps) for key in keys},
        **{f"{key}.platform_position": reference + deviation for key in keys},
        **{f"{key}.{plots.REFERENCE_FIELD}": reference for key in keys},
        **{f"{key}.pick_indices": np.array([50, 400]) for key in keys},  # the second pick beyond the episode
        **{f"{key}.place_indices": np.array([200]) for key in keys},
    )
    np.savez_compressed(
        folder / "table2_run.npz",
        time=1e-3 * np.arange(steps),
        measured=rng.normal(size=(steps, 3)),
        mp_0=rng.normal(size=(steps, 3)),
        mp_hat=rng.normal(size=(steps, 3)),
        estimate=np.full(steps, 3.7),
        mass=np.full(steps, 3.8),
    )
    _write_csv(
        folder / "table2.csv",
        [
            {"joint": j, "mp_0_mean": 0.1 * j, "mp_0_std": 0.2, "mp_hat_mean": 0.01, "mp_hat_std": 0.05}
            for j in (1, 2, 3)
        ],
    )
    _write_csv(
        folder / "episodes.csv",
        [
            {"controller": label, "tracking_rms_mm": rms, "diverged": "False"}
            for label in labels
            for rms in (0.5, 0.7, 0.6)
        ],
    )
    fault_rows = [
        {"outcome": "detected", "kind": "torque_glitch", "injected_at_s": 0.1, "ended_at_s": 0.105},
        {"outcome": "missed", "kind": "slip", "injected_at_s": 0.15, "ended_at_s": 0.2},
        {"outcome": "consequence", "kind": "torque_glitch", "injected_at_s": 0.1, "ended_at_s": 0.105},
        {"outcome": "false_alarm", "kind": "collision"},
    ]
    detections = {
        "detected": (0.112, "torque_glitch"),
        "consequence": (0.12, "collision"),
        "false_alarm": (0.25, "collision"),
    }
    rows = [
        {
            **dict.fromkeys(FAULT_COLUMNS, ""),
            "controller": label,
            "key": key,
            "episode": 0,
            "seed": 0,
            **row,
            **dict(zip(("detected_at_s", "detected_kind"), detections.get(row["outcome"], ("", "")), strict=True)),
        }
        for key, label in zip(keys, labels, strict=True)
        for row in fault_rows
    ]
    write_fault_csv(folder / "faults.csv", rows if faults else [])
    return folder


def _figures(folder: Path) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in plots.FIGURES}


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The figures :func:`eval.plots.make_plots` makes of :func:`_run_folder`."""
    folder = _run_folder(tmp_path_factory.mktemp("all_at_once"))
    assert plots.make_plots(folder) == [folder / name for name in plots.FIGURES]
    return _figures(folder)


@pytest.mark.parametrize("beside", [False, True])
def test_a_plotter_makes_each_figure_once_its_files_are_saved(
    tmp_path: Path, made: dict[str, bytes], beside: bool
) -> None:
    folder = _run_folder(tmp_path)
    with plots.Plotter(folder, pool_context() if beside else None) as plotter:
        plotter.saved(*SAVED_FIRST)
        if not beside:
            assert (folder / "torque_profiles.png").exists() and not (folder / "payload_estimate.png").exists()
        plotter.saved(*SAVED_LAST)
        assert (folder / "error_bars.png").exists()
    assert _figures(folder) == made


@pytest.mark.parametrize("beside", [False, True])
def test_a_plotter_raises_when_a_figure_is_not_made(tmp_path: Path, beside: bool) -> None:
    folder = _run_folder(tmp_path)
    context = pool_context() if beside else None
    with pytest.raises(RuntimeError, match="figures"), plots.Plotter(folder, context) as plotter:
        plotter.saved("traces.npz", "table2.csv", "episodes.csv")


def test_a_plotter_raises_when_its_process_fails(tmp_path: Path) -> None:
    folder = _run_folder(tmp_path)
    (folder / "traces.npz").write_bytes(b"not a zip file")
    with pytest.raises(RuntimeError, match="exit code 1"), plots.Plotter(folder, pool_context()) as plotter:
        plotter.saved(*SAVED_FIRST, *SAVED_LAST[:1])


def test_a_plotter_takes_files_after_its_process_made_its_figures(tmp_path: Path, made: dict[str, bytes]) -> None:
    """The process's figures may all be made before the caller saves its last files (a slow caller)."""
    folder = _run_folder(tmp_path)
    with plots.Plotter(folder, pool_context()) as plotter:
        plotter.saved("traces.npz", "table2_run.npz")
        deadline = time.monotonic() + 120.0
        while not all((folder / name).exists() for name in plots.SERIES_FIGURES) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # past the last figure's write
        plotter.saved("table2.csv", "episodes.csv", "faults.csv")
    assert _figures(folder) == made


def test_a_plotter_stops_its_process_when_the_caller_fails(tmp_path: Path) -> None:
    folder = _run_folder(tmp_path)
    with pytest.raises(KeyError, match="the caller"), plots.Plotter(folder, pool_context()) as plotter:
        raise KeyError("the caller")
    assert plotter.exitcode is not None and plotter.exitcode != 0  # stopped, not ended
    assert not any((folder / name).exists() for name in plots.FIGURES)


def _artists(figure: matplotlib.figure.Figure) -> list[matplotlib.artist.Artist]:
    return [artist for axis in figure.axes for artist in (*axis.lines, *axis.collections, *axis.patches)]


def _has_data(artist: matplotlib.artist.Artist) -> bool:
    """Whether ``artist`` draws something: a line with a finite point, a patch or collection with a finite path."""
    if isinstance(artist, Line3D):
        return bool(np.isfinite(np.asarray(artist.get_data_3d(), dtype=float)).all(axis=0).any())
    if isinstance(artist, matplotlib.lines.Line2D):
        points = np.asarray(artist.get_xydata(), dtype=float)
        return bool(np.isfinite(points).all(axis=1).any())
    paths = artist.get_paths() if hasattr(artist, "get_paths") else [artist.get_path()]
    return any(len(path.vertices) and np.isfinite(path.vertices).all() for path in paths)


def _legend_entries(figure: matplotlib.figure.Figure) -> dict[str, bool]:
    """Each legend entry of ``figure`` (its axes' and its own) and whether an artist of that label draws data."""
    legends = [*figure.legends, *(axis.get_legend() for axis in figure.axes if axis.get_legend() is not None)]
    artists = _artists(figure)
    return {
        text.get_text(): any(artist.get_label() == text.get_text() and _has_data(artist) for artist in artists)
        for legend in legends
        for text in legend.get_texts()
    }


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> list[matplotlib.figure.Figure]:
    """The figures the plots draw, kept open (their ``plt.close`` is skipped) to be inspected."""
    figures: list[matplotlib.figure.Figure] = []
    monkeypatch.setattr(plots.plt, "close", figures.append)
    return figures


def test_the_new_figures_have_data_for_every_legend_entry(
    tmp_path: Path, drawn: list[matplotlib.figure.Figure]
) -> None:
    folder = _run_folder(tmp_path)
    names = ("tracking_error.png", "paths_3d.png", "fault_timeline.png")
    for name in names:
        plots.FIGURES[name][1](folder, folder / name, "nominal")
        assert (folder / name).stat().st_size > 10_000, name
    tracking, paths, timeline = (_legend_entries(figure) for figure in drawn)
    assert set(tracking) == {"object held", "tracking error", *(f"RMS {rms:.2f} mm" for rms in _rms(folder))}
    assert set(paths) == {"reference", "platform (deviation from the reference x 10)"}  # 2 mm at most
    assert set(timeline) == {
        "injected: torque_glitch",
        "injected: slip",
        "missed (hatched)",
        "detection of the fault",
        "detection of a consequence",
        "false alarm",
    }
    for entries in (tracking, paths, timeline):
        assert all(entries.values()), entries
    # The legends of the panels sit beside them, off the data.
    for figure in (drawn[0], drawn[2]):
        renderer = figure.canvas.get_renderer()
        for axis in figure.axes:
            legend = axis.get_legend().get_window_extent(renderer)
            assert legend.x0 >= axis.get_window_extent(renderer).x1


def _rms(folder: Path) -> list[float]:
    with np.load(folder / "traces.npz") as traces:
        return [float(np.sqrt(np.mean((1e3 * traces[f"{key}.tracking_error"]) ** 2))) for key in traces["keys"]]


def test_a_run_without_faults_has_no_fault_timeline(tmp_path: Path) -> None:
    folder = _run_folder(tmp_path, faults=False)
    made = plots.make_plots(folder)
    assert folder / "fault_timeline.png" not in made and not (folder / "fault_timeline.png").exists()
    assert made == [folder / name for name in plots.FIGURES if name != "fault_timeline.png"]


@pytest.mark.parametrize(("deviation", "scale"), [(0.005, 5), (0.0003, 100), (0.04, 1), (0.0, 1), (np.nan, 1)])
def test_the_path_deviation_is_magnified_to_a_few_centimetres(deviation: float, scale: int) -> None:
    assert plots.deviation_scale(deviation) == scale


def test_the_learning_curve_is_drawn_from_its_csv(tmp_path: Path, drawn: list[matplotlib.figure.Figure]) -> None:
    assert plots.learning_curve_figure(tmp_path) is None and not drawn  # no evaluation yet
    rows = [
        {"timesteps": 1000 * n, "mean_reward": -50.0 / n, "std_reward": 5.0 / n, "min_reward": -60.0 / n,
         "max_reward": -40.0 / n, "episodes": 5}
        for n in (1, 2, 3)
    ]  # fmt: skip
    _write_csv(tmp_path / plots.LEARNING_CURVE_FILE, rows)
    assert plots.learning_curve_figure(tmp_path) == tmp_path / "learning_curve.png"
    entries = _legend_entries(drawn[0])
    assert set(entries) == {"mean ± std", "mean return", "min and max"} and all(entries.values()), entries
    (line,) = [line for line in drawn[0].axes[0].lines if line.get_label() == "mean return"]
    np.testing.assert_allclose(line.get_xdata(), [1000, 2000, 3000])
