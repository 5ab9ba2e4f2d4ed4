"""The figures of an evaluation run: made from the run folder's files, in this process or beside it."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np
import pytest

from eval import plots
from eval.processes import pool_context
from tests.figure_checks import hidden_legend_entries, kept_figures

SAVED_FIRST = ("traces.npz",)
SAVED_LAST = ("table2_run.npz", "table2.csv", "episodes.csv")


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _torques(steps: int, offset: float) -> np.ndarray:
    """Smooth torques (N m) of three joints, ``(steps, 3)``, as a pick-and-place cycle draws them."""
    time = 1e-3 * np.arange(steps)[:, None]
    return 30.0 * np.sin(2 * np.pi * 2.0 * time + np.array([0.0, 2.1, 4.2])) + offset


def _run_folder(folder: Path) -> Path:
    """A run folder with the files the figures are made from: three controllers, one estimating, the bound, 300 steps;
    PD's torques are MId+F+RLS's (lines that would coincide in one panel)."""
    rng = np.random.default_rng(3)
    steps, keys, labels = 300, ["pd", "mid_f_rls", "oracle"], ["PD", "MId+F+RLS", "Oracle+PD (bound)"]
    (folder / "scenario.toml").write_text('name = "nominal"\n')
    torques = {"pd": _torques(steps, 2.0), "mid_f_rls": _torques(steps, 2.0), "oracle": _torques(steps, 0.0)}
    np.savez_compressed(
        folder / "traces.npz",
        dt=1e-3,
        keys=np.array(keys),
        labels=np.array(labels),
        estimates_payload=np.array([False, True, False]),
        **{f"{key}.tracking_error": 1e-3 * rng.random(steps) for key in keys},
        **{f"{key}.torque": torques[key] for key in keys},
        **{f"{key}.payload_mass": np.full(steps + 1, 2.0) for key in keys},
        **{f"{key}.payload_estimate": 2.0 + 0.1 * rng.normal(size=steps) for key in keys},
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
        plotter.saved("table2.csv", "episodes.csv")
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
        assert titles[0] == "PD: 2.00 N m RMS from the bound"  # every joint 2 N m above the bound's torque
        for axis in torque_profiles.axes:  # no legend over the data: one legend, the figure's, above the panels
            assert axis.get_legend() is None
        (legend,) = torque_profiles.legends
        top = min(axis.get_window_extent().y1 for axis in torque_profiles.axes if axis.get_visible())
        assert legend.get_window_extent().y0 >= top
