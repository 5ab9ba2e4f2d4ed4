"""Checks of a rendered matplotlib figure that the eye makes: every legend entry's colour is drawn somewhere in the
plots, outside every legend (a series hidden under another, empty or off the axes fails)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import matplotlib
import numpy as np
import pytest
from matplotlib.artist import Artist
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba_array
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from numpy.typing import NDArray

MIN_PIXELS = 40
"""Pixels of a legend entry's colour that the plots must show: a line of a few dozen pixels, far fewer than a
visible series draws at 120 dpi, far more than antialiased edges of other colours give by chance."""

TOLERANCE = 0.06
"""Largest difference per RGB channel (0-1) of a pixel counted as the entry's colour."""


def _drawn_colour(handle: Artist) -> NDArray[np.float64]:
    """The RGB (0-1) a legend handle's series is drawn in, blended over white by its alpha."""
    if isinstance(handle, Line2D) and handle.get_linestyle() in ("None", "none", ""):  # markers only
        face = to_rgba_array(handle.get_markerfacecolor())
        drawn = handle.get_markeredgecolor() if face.size == 0 or face[0, 3] == 0.0 else face
    elif isinstance(handle, Line2D | LineCollection):
        drawn = handle.get_color()
    else:
        drawn = handle.get_facecolor()
    red, green, blue, alpha = to_rgba_array(drawn, handle.get_alpha())[0]
    return alpha * np.array([red, green, blue]) + (1.0 - alpha)


def hidden_legend_entries(figure: Figure) -> list[str]:
    """The texts of ``figure``'s legend entries whose colour no visible axes shows on :data:`MIN_PIXELS` pixels
    outside every legend."""
    figure.canvas.draw()
    image = np.asarray(figure.canvas.buffer_rgba(), dtype=float)[..., :3] / 255.0
    height = image.shape[0]
    inside = np.zeros(image.shape[:2], dtype=bool)

    def rows_columns(box: matplotlib.transforms.Bbox, shrink: int = 0) -> tuple[slice, slice]:
        return (
            slice(max(int(height - box.y1) + shrink, 0), max(int(height - box.y0) + 1 - shrink, 0)),
            slice(max(int(box.x0) + shrink, 0), max(int(box.x1) + 1 - shrink, 0)),
        )

    for axis in figure.axes:
        if axis.get_visible() and axis.get_label() != "<colorbar>":
            inside[rows_columns(axis.get_window_extent(), shrink=2)] = True  # inside the spines
    legends = [*figure.legends, *(axis.get_legend() for axis in figure.axes if axis.get_legend() is not None)]
    for legend in legends:
        inside[rows_columns(legend.get_window_extent())] = False
    hidden = []
    for legend in legends:
        for handle, text in zip(legend.legend_handles, legend.get_texts(), strict=True):
            colour = _drawn_colour(handle)
            close = np.all(np.abs(image - colour) <= TOLERANCE, axis=-1) & inside
            if np.count_nonzero(close) < MIN_PIXELS:
                hidden.append(text.get_text())
    return hidden


@contextmanager
def kept_figures(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Figure]]:
    """The figures that code under test closes with ``pyplot.close(figure)``, kept open to be checked (and closed
    when the block ends)."""
    import matplotlib.pyplot as plt

    kept: list[Figure] = []
    close: Callable[..., None] = plt.close
    monkeypatch.setattr(plt, "close", kept.append)
    try:
        yield kept
    finally:
        monkeypatch.setattr(plt, "close", close)
        for figure in kept:
            close(figure)
