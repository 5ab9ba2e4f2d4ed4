"""The figures of an evaluation run: made from the run folder's files, in this process or beside it."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import matplotlib.figure
import numpy as np
import pytest

from eval.comparison import plots
from eval.fault_tables import FAULT_COLUMNS, write_fault_csv
from eval.processes import pool_context
from tests.figure_checks import hidden_legend_entries, kept_figures

SAVED_FIRST = ("traces.npz",)
SAVED_LAST = ("table2_run.npz", "table2.csv", "episodes.csv", "faults.csv")


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _torques(steps: int, offset: float) -> np.ndarray:
    """Smooth torques (N m) of three joints, ``(steps, 3)``, as a pick-and-place cycle draws them."""
    time = 1e-3 * np.arange(steps)[:, None]
    return 30.0 * np.sin(2 * np.pi * 2.0 * time + np.array([0.0, 2.1, 4.2])) + offset


def _run_folder(folder: Path, faults: bool = True) -> Path:
    """A run folder with the files the figures are made from: three controllers, one estimating, the bound, 300 steps,
    one carry; PD's torques are MId+F+RLS's (lines that would coincide in one panel); with ``faults``, a fault of each
    outcome in ``faults.csv``, else its header only."""
    rng = np.random.default_rng(3)
    steps, keys, labels = 300, ["pd", "mid_f_rls", "oracle"], ["PD", "MId+F+RLS", "Oracle+PD (bound)"]
    (folder / "scenario.toml").write_text('name = "nominal"\n')
    angle = np.linspace(0.0, np.pi, steps)
    reference = np.stack((0.3 * np.cos(angle), 0.2 * np.sin(angle), -0.9 + 0.02 * np.sin(2 * angle)), -1)
    deviation = 0.002 * np.stack((np.sin(angle), np.zeros(steps), np.zeros(steps)), -1)  # at most 2 mm
    torques = {"pd": _torques(steps, 2.0), "mid_f_rls": _torques(steps, 2.0), "oracle": _torques(steps, 0.0)}
    np.savez_compressed(
        folder / "traces.npz",
        dt=1e-3,
        keys=np.array(keys),
        labels=np.array(labels),
        estimates_payload=np.array([False, True, False]),
        privileged=np.array([False, False, True]),
        **{f"{key}.tracking_error": 1e-3 * rng.random(steps) for key in keys},
        **{f"{key}.torque": torques[key] for key in keys},
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
        {"outcome": "latent", "kind": "drive_fault", "injected_at_s": 0.3, "ended_at_s": 0.35},
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
    """The figures :func:`eval.comparison.plots.make_plots` makes of :func:`_run_folder`."""
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


def test_every_figure_shows_what_its_legend_lists(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = _run_folder(tmp_path)
    with kept_figures(monkeypatch) as figures:
        plots.make_plots(folder)
        assert len(figures) == len(plots.FIGURES)
        for name, figure in zip(plots.FIGURES, figures, strict=True):
            assert hidden_legend_entries(figure) == [], name
        # one panel per controller, so that PD shows although its torques are MId+F+RLS's
        torque_profiles = figures[list(plots.FIGURES).index("torque_profiles.png")]
        titles = [axis.get_title() for axis in torque_profiles.axes if axis.get_visible()]
        assert [title.split(":")[0] for title in titles] == ["PD", "MId+F+RLS", "Oracle+PD (bound)"]
        assert titles[0] == "PD: 2.00 N m RMS from the bound over its first 0.30 s"  # every joint 2 N m above
        for axis in torque_profiles.axes:  # no legend over the data: one legend, the figure's, above the panels
            assert axis.get_legend() is None
        (legend,) = torque_profiles.legends
        top = min(axis.get_window_extent().y1 for axis in torque_profiles.axes if axis.get_visible())
        assert legend.get_window_extent().y0 >= top


def _legend_texts(figure: matplotlib.figure.Figure) -> set[str]:
    legends = [*figure.legends, *(axis.get_legend() for axis in figure.axes if axis.get_legend() is not None)]
    return {text.get_text() for legend in legends for text in legend.get_texts()}


def test_the_new_figures_list_what_they_show_beside_the_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = _run_folder(tmp_path)
    names = ("tracking_error.png", "paths_3d.png", "fault_timeline.png")
    with kept_figures(monkeypatch) as figures:
        for name in names:
            plots.FIGURES[name][1](folder, folder / name, "nominal")
        tracking, paths, timeline = figures
        for name, figure in zip(names, figures, strict=True):
            assert hidden_legend_entries(figure) == [], name
        assert _legend_texts(tracking) == {"object held", "tracking error", *(f"RMS {r:.2f} mm" for r in _rms(folder))}
        assert [axis.get_title(loc="left") for axis in tracking.axes] == ["PD", "MId+F+RLS", "Oracle+PD (bound)"]
        assert _legend_texts(paths) == {"reference", "platform (deviation from the reference x 10)"}  # 2 mm at most
        assert _legend_texts(timeline) == {
            "injected: torque_glitch",
            "injected: slip",
            "missed (hatched)",
            "latent (changed nothing; dotted)",
            "detection of the fault",
            "detection of a consequence",
            "false alarm",
        }
        # The legends of the panels sit beside them, off the data.
        for figure in (tracking, timeline):
            for axis in figure.axes:
                assert axis.get_legend().get_window_extent().x0 >= axis.get_window_extent().x1


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


def test_the_learning_curve_is_drawn_from_its_csv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rows = [
        {"timesteps": 1000 * n, "mean_reward": -50.0 / n, "std_reward": 5.0 / n, "min_reward": -60.0 / n,
         "max_reward": -40.0 / n, "episodes": 5}
        for n in (1, 2, 3)
    ]  # fmt: skip
    with kept_figures(monkeypatch) as figures:
        assert plots.learning_curve_figure(tmp_path) is None and not figures  # no evaluation yet
        _write_csv(tmp_path / plots.LEARNING_CURVE_FILE, rows)
        assert plots.learning_curve_figure(tmp_path) == tmp_path / "learning_curve.png"
        (figure,) = figures
        assert hidden_legend_entries(figure) == []
        assert _legend_texts(figure) == {"mean ± std", "mean return", "min and max"}
        (line,) = [line for line in figure.axes[0].lines if line.get_label() == "mean return"]
        np.testing.assert_allclose(line.get_xdata(), [1000, 2000, 3000])
        np.testing.assert_allclose(line.get_ydata(), [-50.0, -25.0, -50.0 / 3])
