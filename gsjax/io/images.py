"""Image helpers: colour/depth PNGs, colour-mapped depth and error images and labelled render-vs-input panels
(numpy + OpenCV).

Colour images are [H, W, 3] floats in [0, 1] (RGB; clipped and rounded to 8 bits on output); depth images are
[H, W] metres with 0 / non-finite = invalid. The ``*_png`` writers encode in memory and write atomically.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import matplotlib
import numpy as np

from gsjax.io.atomic import atomic_write_bytes

if TYPE_CHECKING:
    import numpy.typing as npt


def to_uint8(color: npt.ArrayLike) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8 (clipped, rounded to nearest); uint8 passes through."""
    color = np.asarray(color)
    if color.ndim != 3 or color.shape[-1] != 3:
        raise ValueError(f"colour image must have shape [H, W, 3], got {list(color.shape)}")
    if color.dtype == np.uint8:
        return color
    return np.round(np.clip(np.nan_to_num(color.astype(np.float64)), 0.0, 1.0) * 255.0).astype(np.uint8)


def _depth_and_valid(depth) -> tuple[np.ndarray, np.ndarray]:
    """(depth [H, W] float64 m, valid [H, W] bool: finite and > 0); ValueError for another shape."""
    depth = np.asarray(depth, np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth image must have shape [H, W], got {list(depth.shape)}")
    return depth, np.isfinite(depth) & (depth > 0)


def _percentile_range(depth: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """1st and 99th percentile of the valid depths (m), or (0, 1) when none is valid."""
    return tuple(np.percentile(depth[valid], [1, 99])) if valid.any() else (0.0, 1.0)


def colorize_depth(depth: npt.ArrayLike, vmin: float | None = None, vmax: float | None = None,
                   cmap: str = "turbo") -> np.ndarray:
    """Depth [H, W] (m) -> uint8 RGB [H, W, 3] through a matplotlib colour map; invalid pixels are black.

    The range defaults to the 1st-99th percentile of the valid depths (so one outlier does not wash the image out).
    """
    depth, valid = _depth_and_valid(depth)
    if vmin is None or vmax is None:
        lo, hi = _percentile_range(depth, valid)
        vmin = lo if vmin is None else vmin
        vmax = hi if vmax is None else vmax
    scaled = np.clip((np.where(valid, depth, vmin) - vmin) / max(vmax - vmin, 1e-12), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](scaled)[..., :3]
    return to_uint8(np.where(valid[..., None], rgb, 0.0))


# Fixed ranges of the error maps, so that panels of different frames and runs compare by eye.
COLOR_ERROR_RANGE = 0.25  # mean |render - input| over the channels, colour units in [0, 1]
DEPTH_ERROR_RANGE_M = 0.10
LABEL_HEIGHT = 22  # px of the label strip above each tile


def colorize_error(error: npt.ArrayLike, vmax: float, valid: npt.ArrayLike | None = None,
                   cmap: str = "inferno") -> np.ndarray:
    """Absolute error [H, W] -> uint8 RGB [H, W, 3] through ``cmap`` over [0, vmax] (clipped); pixels outside
    ``valid`` (and non-finite ones) are black."""
    error = np.asarray(error, np.float64)
    shown = np.isfinite(error) if valid is None else np.asarray(valid, bool) & np.isfinite(error)
    rgb = matplotlib.colormaps[cmap](np.clip(np.where(shown, error, 0.0) / vmax, 0.0, 1.0))[..., :3]
    return to_uint8(np.where(shown[..., None], rgb, 0.0))


def _labelled(tile: np.ndarray, label: str) -> np.ndarray:
    """``tile`` [h, w, 3] uint8 under a white strip of ``LABEL_HEIGHT`` px holding ``label`` in black."""
    strip = np.full((LABEL_HEIGHT, tile.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, label, (4, LABEL_HEIGHT - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, tile], axis=0)


def render_panel(color: npt.ArrayLike, color_gt: npt.ArrayLike, depth: npt.ArrayLike | None = None,
                 depth_gt: npt.ArrayLike | None = None, *, min_width: int = 320, gap: int = 4) -> np.ndarray:
    """A labelled uint8 panel of a render against its input, for people to read.

    Columns ``render | input | |render - input|``; rows colour, then depth when both depths are given (shared
    colour range from the input's valid depth; the depth error only where the input depth is valid). The error
    maps use fixed ranges (``COLOR_ERROR_RANGE``, ``DEPTH_ERROR_RANGE_M``) named in their labels. Each tile is
    enlarged by nearest neighbour by the smallest integer factor that makes it at least ``min_width`` px wide
    (small cpu-preset images), under a ``LABEL_HEIGHT`` px label strip; ``gap`` px of white between tiles.

    Args:
      color, color_gt: [H, W, 3] in [0, 1]; depth, depth_gt: [H, W] m (0 / non-finite = invalid) or None.
    """
    color, color_gt = np.asarray(color, np.float64), np.asarray(color_gt, np.float64)
    if color.shape != color_gt.shape:
        raise ValueError(f"render and input shapes differ: {color.shape} vs {color_gt.shape}")
    if (depth is None) != (depth_gt is None):
        raise ValueError("give both depth and depth_gt, or neither")
    color_error = np.mean(np.abs(np.nan_to_num(color) - np.nan_to_num(color_gt)), axis=-1)
    rows = [[(to_uint8(color), "render"), (to_uint8(color_gt), "input"),
             (colorize_error(color_error, COLOR_ERROR_RANGE), f"|render - input| 0-{COLOR_ERROR_RANGE:g}")]]
    if depth is not None:
        depth, rendered_valid = _depth_and_valid(depth)
        depth_gt, valid = _depth_and_valid(depth_gt)
        if depth.shape != depth_gt.shape or depth.shape != color.shape[:2]:
            raise ValueError(f"depth shapes {depth.shape}, {depth_gt.shape} do not match the colour's "
                             f"{color.shape[:2]}")
        lo, hi = _percentile_range(depth_gt, valid)
        error = np.abs(np.where(rendered_valid, depth, 0.0) - np.where(valid, depth_gt, 0.0))
        rows.append([(colorize_depth(depth, lo, hi), "render depth"), (colorize_depth(depth_gt, lo, hi),
                     f"input depth {lo:.2f}-{hi:.2f} m"),
                     (colorize_error(error, DEPTH_ERROR_RANGE_M, valid),
                      f"|depth error| 0-{100 * DEPTH_ERROR_RANGE_M:g} cm")])
    zoom = max(1, -(-min_width // color.shape[1]))
    tiles = [[_labelled(np.repeat(np.repeat(image, zoom, axis=0), zoom, axis=1), label) for image, label in row]
             for row in rows]
    h, w, _ = tiles[0][0].shape
    panel = np.full((len(tiles) * h + (len(tiles) - 1) * gap, 3 * w + 2 * gap, 3), 255, np.uint8)
    for r, row in enumerate(tiles):
        for c, tile in enumerate(row):
            panel[r * (h + gap) : r * (h + gap) + h, c * (w + gap) : c * (w + gap) + w] = tile
    return panel


def _encode_png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"OpenCV could not encode an image of shape {image.shape} and dtype {image.dtype} as PNG")
    return buf.tobytes()


def save_rgb_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write a uint8 RGB image [H, W, 3] as PNG, atomically."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"expected a uint8 [H, W, 3] image, got {image.dtype} {list(image.shape)}")
    return atomic_write_bytes(path, _encode_png(cv2.cvtColor(image, cv2.COLOR_RGB2BGR)))


def save_color_png(path: str | os.PathLike, color: npt.ArrayLike) -> Path:
    """Write a colour image [H, W, 3] in [0, 1] as an 8-bit RGB PNG, atomically."""
    return save_rgb_png(path, to_uint8(color))


def save_depth_png(path: str | os.PathLike, depth: npt.ArrayLike, scale: float = 1000.0) -> Path:
    """Write depth [H, W] (m) as a 16-bit PNG holding ``round(depth * scale)`` (1000: mm; TUM uses 5000), invalid
    pixels as 0, atomically. Raises ValueError if a valid depth does not fit in 16 bits at this scale."""
    depth, valid = _depth_and_valid(depth)
    counts = np.round(np.where(valid, depth, 0.0) * scale)
    if counts.max(initial=0) > 65535:
        raise ValueError(f"{path}: depth up to {depth[valid].max():.3f} m does not fit a 16-bit PNG at scale {scale}")
    return atomic_write_bytes(path, _encode_png(counts.astype(np.uint16)))
