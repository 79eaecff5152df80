"""Rendering a view for the SLAM stages: the canonical render, or CB-KNN's smoothed one for keyframes."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, SlotSelection, render
from gsjax.raster.render import strided_selection
from gsjax.slam.config import CBKNNConfig, SlamConfig
from gsjax.slam.presets import at_width


class RenderedView(NamedTuple):
    """What the losses and densification read from a render: color [H, W, 3], depth (sum w z) [H, W],
    silhouette [H, W], depth_sq [H, W], ``truncated`` (any pixel cut by the rasterizer's capacities) and
    ``truncation_residual`` (the largest transmittance left at such a cut)."""

    color: jax.Array
    depth: jax.Array
    silhouette: jax.Array
    depth_sq: jax.Array
    truncated: jax.Array
    truncation_residual: jax.Array


def _view(out) -> RenderedView:
    return RenderedView(out.color, out.depth, out.silhouette, out.depth_sq, out.stats.truncated,
                        out.stats.max_residual_transmittance)


def render_view(
    gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, raster: RasterSettings, cbknn: CBKNNConfig,
    smooth: bool | jax.Array, gamma: float | jax.Array, selection: SlotSelection | None = None
) -> RenderedView:
    """Render ``gaussians`` at ``w2c`` with the ``raster`` settings; with CB-KNN's per-pixel smoothing (``cbknn``'s
    parameters, motion ``gamma``) where ``smooth`` (a traced bool) is true. ``selection``: contributor slots chosen
    at a nearby pose (:func:`gsjax.raster.select_slots`), or None to choose them at ``w2c``.

    When ``cbknn`` never smooths renders (a mode other than ``paper``), this is the canonical render and ``smooth``
    is ignored, so no second render path is compiled.
    """
    def canonical():
        return _view(render(gaussians, w2c, intrinsics, raster, selection=selection))

    if not cbknn.smooth_renders:
        return canonical()
    return jax.lax.cond(
        smooth,
        lambda: _view(render(gaussians, w2c, intrinsics, raster, cbknn=cbknn.params, motion=gamma,
                             selection=selection)),
        canonical,
    )


def strided_setup(config: SlamConfig, intrinsics: Intrinsics) -> SlamConfig:
    """``config`` for renders on every other pixel of ``intrinsics``' image (:meth:`Intrinsics.strided`): a quarter
    of the dilation (the 2D covariances shrink by 4 in those pixels), half the tile side (the tile lists stay the
    full image's) and the pixel-sized settings at half the width. The render is then the full render's pixels
    there, at a fraction of its cost."""
    raster = dataclasses.replace(config.raster, dilation=config.raster.dilation / 4.0,
                                 tile_size=_strided_tile(config.raster.tile_size))
    return at_width(dataclasses.replace(config, raster=raster), intrinsics.width // 2, intrinsics.width)


def _strided_tile(tile_size: int) -> int:
    """The tile side (px) of strided renders: half the full image's, so the tile lists stay the full image's."""
    return max(tile_size // 2, 1)


def strided_slots(selection: SlotSelection, raster: RasterSettings, intrinsics: Intrinsics,
                  phase: int | jax.Array) -> SlotSelection:
    """The slots of strided grid ``phase`` (0-3, may be traced; see :func:`strided_frame`) taken from ``selection``,
    made for the full image of ``intrinsics`` under ``raster``: the strided render's own selection at that pose, laid
    out for :func:`strided_setup`'s tiles."""
    return strided_selection(selection, intrinsics.height, intrinsics.width, raster.tile_size,
                             _strided_tile(raster.tile_size), phase // 2, phase % 2)


def strided_observation(image: jax.Array, row: int | jax.Array, col: int | jax.Array) -> jax.Array:
    """Every other pixel of ``image`` [H, W, ...] from (``row``, ``col``) (0 or 1, may be traced): [H // 2, W // 2,
    ...], the pixels of :meth:`Intrinsics.strided`."""
    h, w = image.shape[0] // 2, image.shape[1] // 2
    blocks = image[: 2 * h, : 2 * w].reshape(h, 2, w, 2, *image.shape[2:])
    return jnp.take(jnp.take(blocks, row, axis=1), col, axis=2)


def strided_frame(color: jax.Array, depth: jax.Array, intrinsics: Intrinsics,
                  phase: int | jax.Array) -> tuple[jax.Array, jax.Array, Intrinsics]:
    """(colour [H // 2, W // 2, 3], depth [H // 2, W // 2], their intrinsics) of strided grid ``phase`` (0-3, may be
    traced): every other pixel from (row, col) = (phase // 2, phase % 2)."""
    row, col = phase // 2, phase % 2
    return strided_observation(color, row, col), strided_observation(depth, row, col), intrinsics.strided(row, col)


def is_keyframe(frame: jax.Array, num_frames: int | jax.Array, every: int) -> jax.Array:
    """SplaTAM's keyframe rule (A.10): frame 0, every ``every``-th frame ((t+1) % every == 0), the second-to-last."""
    return (frame == 0) | ((frame + 1) % every == 0) | (frame == num_frames - 2)

