"""Plots with matplotlib's Agg backend (no pyplot, no global state): trajectory top view, errors over time, sweep
heat maps, landscapes (1-D and 2-D) and CB-KNN's K and rho maps.

Each function builds its own Figure, renders it to PNG in memory (:func:`png_bytes`) and writes the file atomically.
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from gsjax.io.atomic import atomic_write_bytes

if TYPE_CHECKING:
    import numpy.typing as npt

_AXES = {"x": 0, "y": 1, "z": 2}


def png_bytes(fig: Figure, dpi: int = 120, tight: bool = True) -> bytes:
    """The figure as PNG bytes (cropped to a tight bounding box unless ``tight`` is False: that draws it twice)."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight" if tight else None)
    return buf.getvalue()


def svg_bytes(fig: Figure) -> bytes:
    """The figure as SVG bytes, the same for the same figure: no date, fixed element ids, text kept as text (the
    viewer's sans-serif font) rather than outlines."""
    FigureCanvasSVG(fig)
    buf = io.BytesIO()
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": "gsjax"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()


def _save(fig: Figure, path: str | os.PathLike, dpi: int) -> Path:
    return atomic_write_bytes(path, png_bytes(fig, dpi))


def top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two coordinate axes with the largest extent of ``positions`` [N, 3], in increasing order."""
    extent = np.nanmax(positions, axis=0) - np.nanmin(positions, axis=0)
    first, second = sorted(int(i) for i in np.argsort(extent)[-2:])
    return first, second


def plot_trajectory_top_view(
    path: str | os.PathLike,
    est_positions: npt.ArrayLike,
    gt_positions: npt.ArrayLike | None,
    plane: str = "auto",
    title: str | None = None,
    dpi: int = 120,
) -> Path:
    """Top view of the estimated camera centres (already aligned to the GT) and the GT centres, with the
    per-frame offsets drawn as thin grey segments.

    Args:
      est_positions, gt_positions: [N, 3] camera centres (m), row i of one matching row i of the other;
        ``gt_positions`` may be None (a sequence without ground truth: the estimate alone).
      plane: "xy", "xz", "yz", or "auto" (the two axes along which the GT extends most).
    """
    est = np.asarray(est_positions, np.float64)
    has_gt = gt_positions is not None
    gt = np.asarray(gt_positions if has_gt else est_positions, np.float64)
    if est.shape != gt.shape or est.ndim != 2 or est.shape[1] != 3:
        raise ValueError(f"positions must both have shape [N, 3], got {list(est.shape)} and {list(gt.shape)}")
    if plane == "auto":
        a, b = top_view_axes(gt)
    elif len(plane) == 2 and all(c in _AXES for c in plane) and plane[0] != plane[1]:
        a, b = _AXES[plane[0]], _AXES[plane[1]]
    else:
        raise ValueError(f"plane must be 'auto' or two of x/y/z such as 'xz', got {plane!r}")
    names = "xyz"
    fig = Figure(figsize=(6, 6))
    ax = fig.add_subplot()
    if has_gt:
        offsets = np.stack([est[:, [a, b]], gt[:, [a, b]]], axis=1)  # [N, 2 ends, 2 coords]
        ax.add_collection(LineCollection(list(offsets), colors="0.75", linewidths=0.5, zorder=1))
        ax.plot(gt[:, a], gt[:, b], color="black", linewidth=1.5, label="ground truth", zorder=2)
    label = "estimate (aligned)" if has_gt else "estimate"
    ax.plot(est[:, a], est[:, b], color="tab:blue", linewidth=1.2, label=label, zorder=3)
    ax.scatter(gt[:1, a], gt[:1, b], color="black", marker="o", s=25, zorder=4, label="start")
    ax.set_xlabel(f"{names[a]} (m)")
    ax.set_ylabel(f"{names[b]} (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, linewidth=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    return _save(fig, path, dpi)


def plot_errors_over_time(
    path: str | os.PathLike,
    times: npt.ArrayLike,
    series: dict[str, np.ndarray],
    xlabel: str = "time (s)",
    ylabel: str = "error",
    title: str | None = None,
    dpi: int = 120,
) -> Path:
    """Line plot of one or more error series over time.

    Args:
      times: [N] x values (s, or frame index with a matching ``xlabel``).
      series: label -> [N] values, e.g. {"ATE (cm)": errors_cm}.
    """
    times = np.asarray(times, np.float64)
    fig = Figure(figsize=(8, 3.5))
    ax = fig.add_subplot()
    for label, values in series.items():
        values = np.asarray(values, np.float64)
        if values.shape != times.shape:
            raise ValueError(f"series {label!r} has shape {list(values.shape)}, times {list(times.shape)}")
        ax.plot(times, values, linewidth=1.0, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, linewidth=0.3)
    if len(series) > 1:
        ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    return _save(fig, path, dpi)


def plot_sweep_heatmap(path: str | os.PathLike, rows: list[dict], fields: list[str], metric: str = "ate_rmse_cm",
                       title: str | None = None, dpi: int = 120) -> Path:
    """Heat map of ``metric`` (the mean over the rows of a cell, i.e. over seeds) over the first two swept ``fields``
    (x: first, y: second), one panel per combination of the other fields' values; the cells are annotated (a blank
    cell: no value)."""
    x_field = fields[0] if fields else None
    y_field = fields[1] if len(fields) > 1 else None
    rest = fields[2:]

    def values_of(field):
        return list(dict.fromkeys(str(r[field]) for r in rows)) if field else [""]

    xs, ys = values_of(x_field), values_of(y_field)
    panels = list(dict.fromkeys(tuple(str(r[f]) for f in rest) for r in rows)) or [()]
    # one colour scale for every panel, so a single colour bar; constrained layout keeps the labels apart
    fig = Figure(figsize=(min(4 + 0.9 * len(xs), 12) * min(len(panels), 3) / 1.5, 1.5 + 0.6 * len(ys)
                          * math.ceil(len(panels) / 3)), layout="constrained")
    finite = [float(r[metric]) for r in rows if r[metric] is not None and np.isfinite(float(r[metric]))]
    vmin, vmax = (min(finite), max(finite)) if finite else (0.0, 1.0)
    axes = []
    for n, panel in enumerate(panels):
        ax = fig.add_subplot(math.ceil(len(panels) / 3), min(len(panels), 3), n + 1)
        axes.append(ax)
        grid = np.full((len(ys), len(xs)), np.nan)
        for j, yv in enumerate(ys):
            for i, xv in enumerate(xs):
                picked = [float(r[metric]) for r in rows if r[metric] is not None
                          and (x_field is None or str(r[x_field]) == xv) and (y_field is None or str(r[y_field]) == yv)
                          and tuple(str(r[f]) for f in rest) == panel]
                if picked:
                    grid[j, i] = float(np.mean(picked))
        image = ax.imshow(grid, cmap="viridis_r", vmin=vmin, vmax=vmax, aspect="auto", origin="lower")
        for j in range(len(ys)):
            for i in range(len(xs)):
                if np.isfinite(grid[j, i]):
                    light = (grid[j, i] - vmin) < 0.5 * (vmax - vmin)  # viridis_r is light at low values
                    ax.text(i, j, f"{grid[j, i]:.3g}", ha="center", va="center", fontsize=7,
                            color="black" if light else "white")
        ax.set_xticks(range(len(xs)), xs, fontsize=7)
        ax.set_yticks(range(len(ys)), ys, fontsize=7)
        ax.set_xlabel(x_field or "")
        ax.set_ylabel(y_field or "")
        if rest:
            ax.set_title(", ".join(f"{f}={v}" for f, v in zip(rest, panel)), fontsize=8)
    fig.colorbar(image, ax=axes, label=metric)
    if title:
        fig.suptitle(title)
    return _save(fig, path, dpi)


def _landscape_colours(modes: list[str]) -> dict[str, str]:
    """A colour per landscape mode: ``off`` and ``paper`` as always, others from the tab10 cycle."""
    fixed = {"off": "tab:blue", "paper": "tab:orange"}
    others = iter(f"C{i}" for i in range(2, 10))  # C0, C1 are tab:blue, tab:orange
    return {mode: fixed.get(mode) or next(others, "0.3") for mode in modes}


def plot_tuning(path: str | os.PathLike, rows: list[dict], fields: list[str], objective: str,
                dpi: int = 120) -> Path:
    """``gsjax tune``'s steps: the objective (top) and each field relative to its start (bottom, log scale)."""
    steps = [row["step"] for row in rows]
    fig = Figure(figsize=(7, 6), layout="constrained")
    top = fig.add_subplot(2, 1, 1)
    top.plot(steps, [row["objective"] for row in rows], marker=".", color="C0")
    best = min(range(len(rows)), key=lambda i: rows[i]["objective"])
    top.plot([steps[best]], [rows[best]["objective"]], marker="*", markersize=12, color="C3", linestyle="none",
             label=f"lowest, step {steps[best]}")
    top.set_ylabel(f"objective ({objective})")
    top.legend(loc="best", fontsize=8)
    top.grid(True, linewidth=0.3)
    bottom = fig.add_subplot(2, 1, 2, sharex=top)
    for i, name in enumerate(fields):
        start = rows[0][name]
        ratios = [row[name] / start if start else row[name] for row in rows]
        bottom.plot(steps, ratios, marker=".", color=f"C{i % 10}", label=f"{name} (start {start:.4g})")
    bottom.set_yscale("log")
    bottom.set_xlabel("step")
    bottom.set_ylabel("value / start")
    bottom.legend(loc="best", fontsize=7)
    bottom.grid(True, which="both", linewidth=0.3)
    return _save(fig, path, dpi)


def plot_landscape(path: str | os.PathLike, document: dict, title: str | None = None, dpi: int = 120) -> Path:
    """Loss (top row) and gradient (bottom row) per axis of a ``landscape.json`` document, one line per mode, each
    mode's basin of convergence marked by dashed lines at +- its width (dotted: the basin to its fixed point)."""
    axes = list(document["axes"])
    fig = Figure(figsize=(4 * len(axes), 6), layout="constrained")
    colours = _landscape_colours(document.get("modes", ["off", "paper"]))
    for i, name in enumerate(axes):
        entry = document["axes"][name]
        offsets = np.asarray(entry["offsets"])
        for row, key in enumerate(("loss", "grad")):
            ax = fig.add_subplot(2, len(axes), row * len(axes) + i + 1)
            for mode, colour in colours.items():
                if mode not in entry:
                    continue
                fixed = f", fixed {entry[mode]['basin_fixed']:g}" if "basin_fixed" in entry[mode] else ""
                ax.plot(offsets, entry[mode][key], color=colour, linewidth=1.2, marker=".", markersize=3,
                        label=f"{mode} (basin {entry[mode]['basin']:g}{fixed} {entry['unit']})")
                for basin, style in ((entry[mode]["basin"], "--"), (entry[mode].get("basin_fixed", 0), ":")):
                    if row == 0 and basin > 0:
                        for side in (-1, 1):
                            ax.axvline(side * basin, color=colour, linestyle=style, linewidth=0.8)
            if key == "grad":
                ax.axhline(0.0, color="0.5", linewidth=0.5)
            ax.set_xlabel(f"{name} ({entry['unit']})")
            ax.set_ylabel("tracking loss" if key == "loss" else f"d loss / d {name} (per {entry['unit']})")
            ax.grid(True, linewidth=0.3)
            if row == 0:
                ax.legend(loc="best", fontsize=7)
    if title:
        fig.suptitle(title)
    return _save(fig, path, dpi)


def plot_landscape2d(path: str | os.PathLike, document: dict, title: str | None = None, dpi: int = 120) -> Path:
    """The ``grid2d`` of a ``landscape.json`` document: per mode, the loss as a heat map over the two axes, outlined
    where the tracker converged to the reference (white) and to its fixed point (red, dashed), the reference (+) and
    the fixed point (x, its offsets along the two axes) marked."""
    plane = document["grid2d"]
    (a, b), (unit_a, unit_b) = plane["axes"], plane["units"]
    x, y = np.asarray(plane["offsets"][a]), np.asarray(plane["offsets"][b])
    modes = [m for m in document.get("modes", ["off", "paper"]) if m in plane]
    fig = Figure(figsize=(4.2 * len(modes), 3.8), layout="constrained")
    for i, mode in enumerate(modes):
        entry = plane[mode]
        ax = fig.add_subplot(1, len(modes), i + 1)
        # [i][j] = (x[i], y[j]): transposed so x runs along the image's columns.
        shown = ax.pcolormesh(x, y, np.asarray(entry["loss"]).T, cmap="viridis", shading="nearest")
        fig.colorbar(shown, ax=ax, shrink=0.85, label="tracking loss")
        for key, colour, style, name in (("converged", "white", "-", "reference"),
                                         ("converged_fixed", "red", "--", "fixed point")):
            # Padded with "not converged" half a step beyond the grid, so the outline closes along its edges.
            mask = np.pad(np.asarray(entry[key], np.float64).T, 1)
            if mask.any():
                ax.contour(_padded(x), _padded(y), mask, levels=[0.5], colors=colour, linestyles=style,
                           linewidths=1.2)
            ax.plot([], [], color=colour, linestyle=style, label=f"converged to the {name}")
        ax.plot([0], [0], marker="+", color="white", markersize=10, linestyle="none", label="reference")
        fixed = document.get("fixed_point", {}).get(mode)
        if fixed is not None:
            ax.plot([fixed["offsets"][a]], [fixed["offsets"][b]], marker="x", color="red", markersize=8,
                    linestyle="none", label="fixed point")
        ax.set_xlabel(f"{a} ({unit_a})")
        ax.set_ylabel(f"{b} ({unit_b})")
        ax.set_title(f"{mode}: basin r {entry['basin']:.2f} (fixed {entry['basin_fixed']:.2f}), "
                     f"area {100 * entry['area']:.0f} % ({100 * entry['area_fixed']:.0f} %)", fontsize=8)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=4, fontsize=7, facecolor="0.6")
    if title:
        fig.suptitle(title, fontsize=9)
    return _save(fig, path, dpi)


def _padded(offsets: np.ndarray) -> np.ndarray:
    """Grid offsets with a point half a step beyond each end."""
    return np.concatenate([[1.5 * offsets[0] - 0.5 * offsets[1]], offsets, [1.5 * offsets[-1] - 0.5 * offsets[-2]]])


def plot_cbknn_maps(path: str | os.PathLike, k_map: npt.ArrayLike, rho_map: npt.ArrayLike, cell: int,
                    title: str | None = None, dpi: int = 120) -> Path:
    """CB-KNN's adaptive kernel size K (left) and normalised density rho (right) per ``cell`` x ``cell`` px cell,
    each with its colour bar. ``k_map`` [cells_y, cells_x] int, ``rho_map`` the same shape (1 = mean of the
    non-empty cells, 0 = empty)."""
    k_map, rho_map = np.asarray(k_map), np.asarray(rho_map, np.float64)
    fig = Figure(figsize=(9, 3.4), layout="constrained")
    for i, (image, name, cmap) in enumerate(((k_map, f"K per {cell} px cell", "viridis"),
                                             (rho_map, f"density rho per {cell} px cell", "magma"))):
        ax = fig.add_subplot(1, 2, i + 1)
        shown = ax.imshow(image, cmap=cmap, interpolation="nearest")
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(shown, ax=ax, shrink=0.85)
    if title:
        fig.suptitle(title, fontsize=9)
    return _save(fig, path, dpi)
