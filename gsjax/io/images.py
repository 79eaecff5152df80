"""Image helpers: colour/depth PNGs, a colour-mapped depth image and render-vs-input panels (numpy + OpenCV).

Colour images are [H, W, 3] floats in [0, 1] (RGB; clipped and rounded to 8 bits on output); depth images are
[H, W] metres with 0 / non-finite = invalid. The ``*_png`` writers encode in memory and write atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import matplotlib
import numpy as np

from gsjax.io.atomic import atomic_write_bytes


def to_uint8(color) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8 (clipped, rounded to nearest)."""
    color = np.asarray(color, np.float64)
    if color.ndim != 3 or color.shape[-1] != 3:
        raise ValueError(f"colour image must have shape [H, W, 3], got {list(color.shape)}")
    return np.round(np.clip(np.nan_to_num(color), 0.0, 1.0) * 255.0).astype(np.uint8)


def _depth_and_valid(depth) -> tuple[np.ndarray, np.ndarray]:
    """(depth [H, W] float64 m, valid [H, W] bool: finite and > 0); ValueError for another shape."""
    depth = np.asarray(depth, np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth image must have shape [H, W], got {list(depth.shape)}")
    return depth, np.isfinite(depth) & (depth > 0)


def _percentile_range(depth: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """1st and 99th percentile of the valid depths (m), or (0, 1) when none is valid."""
    return tuple(np.percentile(depth[valid], [1, 99])) if valid.any() else (0.0, 1.0)


def colorize_depth(depth, vmin: float | None = None, vmax: float | None = None, cmap: str = "turbo") -> np.ndarray:
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


def render_panel(color, color_gt, depth=None, depth_gt=None, gap: int = 4) -> np.ndarray:
    """Side-by-side uint8 panel: ``[render | input]`` colours, and below them ``[render | input]`` depths (shared
    colour range from the input depth) when both depths are given. White ``gap`` px between tiles."""
    tiles = [[to_uint8(color), to_uint8(color_gt)]]
    if tiles[0][0].shape != tiles[0][1].shape:
        raise ValueError(f"render and input shapes differ: {tiles[0][0].shape} vs {tiles[0][1].shape}")
    if (depth is None) != (depth_gt is None):
        raise ValueError("give both depth and depth_gt, or neither")
    if depth is not None:
        lo, hi = _percentile_range(*_depth_and_valid(depth_gt))
        tiles.append([colorize_depth(depth, lo, hi), colorize_depth(depth_gt, lo, hi)])
    h, w, _ = tiles[0][0].shape
    rows, cols = len(tiles), 2
    panel = np.full((rows * h + (rows - 1) * gap, cols * w + (cols - 1) * gap, 3), 255, np.uint8)
    for r, row in enumerate(tiles):
        for c, tile in enumerate(row):
            if tile.shape != (h, w, 3):
                raise ValueError(f"all tiles must be {h}x{w}, got {tile.shape[:2]}")
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


def save_color_png(path: str | os.PathLike, color) -> Path:
    """Write a colour image [H, W, 3] in [0, 1] as an 8-bit RGB PNG, atomically."""
    return save_rgb_png(path, to_uint8(color))


def save_depth_png(path: str | os.PathLike, depth, scale: float = 1000.0) -> Path:
    """Write depth [H, W] (m) as a 16-bit PNG holding ``round(depth * scale)`` (1000: mm; TUM uses 5000), invalid
    pixels as 0, atomically. Raises ValueError if a valid depth does not fit in 16 bits at this scale."""
    depth, valid = _depth_and_valid(depth)
    counts = np.round(np.where(valid, depth, 0.0) * scale)
    if counts.max(initial=0) > 65535:
        raise ValueError(f"{path}: depth up to {depth[valid].max():.3f} m does not fit a 16-bit PNG at scale {scale}")
    return atomic_write_bytes(path, _encode_png(counts.astype(np.uint16)))
