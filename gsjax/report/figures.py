"""The report's plots, as PNG bytes (matplotlib Agg, no pyplot): trajectories against ground truth and per-frame
series (ATE, RPE, PSNR, Gaussian count, tracking loss), one line per run."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from gsjax.eval.trajectory import ate_rmse_c2w
from gsjax.io.plots import png_bytes, trajectory_top_view
from gsjax.report.run_record import RunRecord


class Series(NamedTuple):
    """One line: ``label`` and its points ``x`` [n], ``y`` [n]."""

    label: str
    x: np.ndarray
    y: np.ndarray


def trajectory_png(run: RunRecord) -> bytes:
    """Top view of the estimated camera centres against the ground truth (the estimate aligned onto it, as the
    ATE is computed), or of the estimate alone without ground truth (or fewer than 3 poses with it)."""
    est = run.map_c2w()
    pairs = run.ground_truth()
    try:
        ate = ate_rmse_c2w(est[pairs[0]], pairs[1]) if pairs is not None else None
    except ValueError:
        ate = None
    if ate is None:
        return png_bytes(trajectory_top_view(est[:, :3, 3], None, title=f"{run.name}: estimate (no ground truth)"))
    rows, gt = pairs[0][ate.used], pairs[1][ate.used]
    est_aligned = ate.alignment.apply_points(est[rows, :3, 3])
    return png_bytes(trajectory_top_view(est_aligned, gt[:, :3, 3],
                                         title=f"{run.name}: ATE RMSE {100 * ate.value_m:.2f} cm"))


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
