"""The report's plots (matplotlib, no pyplot): per-frame series (ATE, RPE, PSNR, Gaussian count, tracking loss), one
line per run, as SVG for the page or PNG for a file. (The trajectory plot is the run's own ``trajectory.png``.)"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from gsjax.io.plots import png_bytes, svg_bytes

# Fixed margins (inches) instead of a layout engine: constrained layout and a tight bounding box each draw the
# figure once more, which doubled a run's report time; the left margin holds six-digit tick labels and the y label.
_WIDTH, _LEFT, _RIGHT, _TOP, _BOTTOM, _PANEL, _GAP = 8.0, 0.95, 0.15, 0.15, 0.5, 2.3, 0.35


class Series(NamedTuple):
    """One line: ``label`` and its points ``x`` [n], ``y`` [n]."""

    label: str
    x: np.ndarray
    y: np.ndarray


def series_figure(panels: list[tuple[str, list[Series]]], xlabel: str = "frame", markers: bool = False) -> Figure:
    """Line plots stacked vertically, one per (y label, series) panel, sharing the x axis; a legend when a panel
    has several lines (one per run)."""
    height = _TOP + _BOTTOM + len(panels) * _PANEL + (len(panels) - 1) * _GAP
    fig = Figure(figsize=(_WIDTH, height))
    fig.subplots_adjust(left=_LEFT / _WIDTH, right=1 - _RIGHT / _WIDTH, top=1 - _TOP / height,
                        bottom=_BOTTOM / height, hspace=_GAP / _PANEL)
    for i, (ylabel, lines) in enumerate(panels):
        ax = fig.add_subplot(len(panels), 1, i + 1)
        for line in lines:
            ax.plot(line.x, line.y, linewidth=1.1, marker="." if markers else None, markersize=4, label=line.label)
        ax.set_ylabel(ylabel)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames
        ax.grid(True, linewidth=0.3)
        if len(lines) > 1:
            ax.legend(loc="best", fontsize=7, ncols=1 + len(lines) // 8)
        if i == len(panels) - 1:
            ax.set_xlabel(xlabel)
    fig.align_ylabels()
    return fig


def series_svg(panels: list[tuple[str, list[Series]]], xlabel: str = "frame", markers: bool = False) -> bytes:
    """:func:`series_figure` as SVG bytes (the report's inline plots: text stays text, sharp at any zoom)."""
    return svg_bytes(series_figure(panels, xlabel, markers))


def series_png(panels: list[tuple[str, list[Series]]], xlabel: str = "frame", markers: bool = False) -> bytes:
    """:func:`series_figure` as PNG bytes (a figure file)."""
    return png_bytes(series_figure(panels, xlabel, markers), tight=False)
