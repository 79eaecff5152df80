"""The report's plots, as PNG bytes (matplotlib Agg, no pyplot): per-frame series (ATE, RPE, PSNR, Gaussian
count, tracking loss), one line per run. (The trajectory plot is the run's own ``trajectory.png``.)"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from gsjax.io.plots import png_bytes


class Series(NamedTuple):
    """One line: ``label`` and its points ``x`` [n], ``y`` [n]."""

    label: str
    x: np.ndarray
    y: np.ndarray


def series_png(panels: list[tuple[str, list[Series]]], xlabel: str = "frame", markers: bool = False) -> bytes:
    """Line plots stacked vertically, one per (y label, series) panel, sharing the x axis; a legend when a panel
    has several lines (one per run)."""
    fig = Figure(figsize=(8, 0.4 + 2.6 * len(panels)), layout="constrained")
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
    return png_bytes(fig)
