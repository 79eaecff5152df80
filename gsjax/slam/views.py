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
    """What the losses and densification read from a render (:class:`gsjax.raster.Render` and two of its stats).

    w are the compositing weights (alpha times transmittance), z camera depths.

    Attributes:
      color: [H, W, 3] float32 ``sum w rgb`` (background 0).
      depth: [H, W] float32 ``sum w z`` (m), not normalised by the silhouette.
      silhouette: [H, W] float32 ``sum w``, in [0, 1].
      depth_sq: [H, W] float32 ``sum w z^2`` (m^2).
      truncated: [] bool, some pixel's walk was cut by the rasterizer's capacities (``RenderStats.truncated``).
      truncation_residual: [] float32 largest transmittance left at such a cut (0 when nothing was cut;
        ``RenderStats.max_residual_transmittance``).
    """

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
    smooth: bool | jax.Array, gamma: float | jax.Array, selection: SlotSelection | None = None,
    can_smooth: bool = True,
) -> RenderedView:
    """Render ``gaussians`` at ``w2c``, with CB-KNN's per-pixel smoothing where ``smooth`` is true.

    The correction applies where ``smooth`` holds in ``paper`` mode (the mode may be traced): one render, whose
    CB-KNN correction is a branch on that flag; a concrete mode other than ``paper`` renders canonically only.

    Args:
      gaussians: the map, as :func:`gsjax.raster.render`.
      w2c: [4, 4] world-to-camera rigid transform (m).
      intrinsics: the camera; the render is ``intrinsics.height`` x ``intrinsics.width``.
      raster: the rasterizer settings.
      cbknn: CB-KNN's config: its mode says whether renders may be smoothed (``paper``), its ``params`` how.
      smooth: [] bool (may be traced): smooth this render with CB-KNN (a keyframe in ``paper`` mode).
      gamma: [] CB-KNN's inter-frame motion in [0, 1] for its adaptive K (may be traced); read only when smoothing.
      selection: contributor slots chosen at a nearby pose (:func:`gsjax.raster.select_slots`, same intrinsics and
        settings), or None to choose them at ``w2c``.
      can_smooth: (static) whether the program carries the correction at all (``SlamConfig.caps.smoothing``);
        False renders canonically whatever ``smooth`` says.

    Returns:
      the render's colour, depth, silhouette, depth_sq and truncation diagnostics.
    """
    paper = cbknn.smooth_renders
    if paper is False or not can_smooth:  # a mode other than paper (concrete, or by the caps): canonical only
        return _view(render(gaussians, w2c, intrinsics, raster, selection=selection))
    params = cbknn.params
    if params.k_max > raster.max_contributors:
        # A config smooths only with k_max <= max_contributors (SlamConfig checks it in paper mode); with a traced
        # mode the smoothing is compiled all the same, and never runs.
        params = dataclasses.replace(params, k_max=raster.max_contributors,
                                     k_min=min(params.k_min, raster.max_contributors))
    return _view(render(gaussians, w2c, intrinsics, raster, cbknn=params, motion=gamma, selection=selection,
                        smooth=jnp.logical_and(smooth, paper)))


def strided_setup(config: SlamConfig, intrinsics: Intrinsics) -> SlamConfig:
    """``config`` for renders on every other pixel of ``intrinsics``' image (:meth:`Intrinsics.strided`).

    A quarter of the dilation (the 2D covariances shrink by 4 in those pixels), half the tile side (the tile lists
    stay the full image's) and the pixel-sized settings at half the width. The render is then the full render's
    pixels there, at a fraction of its cost.

    Args:
      config: the SLAM config for the full image.
      intrinsics: the full image's camera (its width sets the scale of the pixel-sized settings).

    Returns:
      ``config`` with ``raster.dilation`` divided by 4, ``raster.tile_size`` halved (at least 1 px) and the fields
        that follow the width scaled from ``intrinsics.width`` to ``intrinsics.width // 2`` px
        (:func:`gsjax.slam.presets.at_width`).
    """
    raster = dataclasses.replace(config.raster, dilation=config.raster.dilation / 4.0,
                                 tile_size=_strided_tile(config.raster.tile_size))
    return at_width(dataclasses.replace(config, raster=raster), intrinsics.width // 2, intrinsics.width)


def _strided_tile(tile_size: int) -> int:
    """The tile side (px) of strided renders: half the full image's, so the tile lists stay the full image's."""
    return max(tile_size // 2, 1)


def strided_slots(selection: SlotSelection, raster: RasterSettings, intrinsics: Intrinsics,
                  phase: int | jax.Array) -> SlotSelection:
    """The slots of strided grid ``phase`` taken from ``selection``, made for the full image.

    The result is the strided render's own selection at the pose ``selection`` was chosen at, laid out for
    :func:`strided_setup`'s tiles (:func:`gsjax.raster.render.strided_selection`).

    Args:
      selection: the full image's contributor slots (:func:`gsjax.raster.select_slots` with ``intrinsics`` and
        ``raster``).
      raster: the full image's rasterizer settings (its ``tile_size`` is read).
      intrinsics: the full image's camera.
      phase: the strided grid, 0-3 (may be traced): pixels from (row, col) = (``phase // 2``, ``phase % 2``), as
        :func:`strided_frame`.

    Returns:
      the slots of the strided image's pixels; ``tiles_overflowed`` and ``intersections_dropped`` stay the full
        image's.
    """
    return strided_selection(selection, intrinsics.height, intrinsics.width, raster.tile_size,
                             _strided_tile(raster.tile_size), phase // 2, phase % 2)


def strided_observation(image: jax.Array, row: int | jax.Array, col: int | jax.Array) -> jax.Array:
    """Every other pixel of ``image`` from (``row``, ``col``): the pixels of :meth:`Intrinsics.strided`.

    Args:
      image: [H, W, ...] an image; an odd last row or column is never taken.
      row: row offset, 0 or 1 (may be traced).
      col: column offset, 0 or 1 (may be traced).

    Returns:
      [H // 2, W // 2, ...] pixels (2 i + ``row``, 2 j + ``col``) of ``image``, of its dtype.
    """
    h, w = image.shape[0] // 2, image.shape[1] // 2
    blocks = image[: 2 * h, : 2 * w].reshape(h, 2, w, 2, *image.shape[2:])
    return jnp.take(jnp.take(blocks, row, axis=1), col, axis=2)


def strided_frame(color: jax.Array, depth: jax.Array, intrinsics: Intrinsics,
                  phase: int | jax.Array) -> tuple[jax.Array, jax.Array, Intrinsics]:
    """A frame's strided grid ``phase``: every other pixel from (row, col) = (``phase // 2``, ``phase % 2``).

    Args:
      color: [H, W, 3] the frame's colour.
      depth: [H, W] the frame's depth (m).
      intrinsics: the frame's camera.
      phase: the strided grid, 0-3 (may be traced).

    Returns:
      the colour [H // 2, W // 2, 3] and depth [H // 2, W // 2] at pixels (2 i + row, 2 j + col)
        (:func:`strided_observation`), and their camera ``intrinsics.strided(row, col)``.
    """
    row, col = phase // 2, phase % 2
    return strided_observation(color, row, col), strided_observation(depth, row, col), intrinsics.strided(row, col)


def is_keyframe(frame: jax.Array, num_frames: int | jax.Array, every: int) -> jax.Array:
    """SplaTAM's keyframe rule (A.10): frame 0, every ``every``-th frame ((t+1) % every == 0), the second-to-last.

    Args:
      frame: [] int32 the frame's index t (may be traced).
      num_frames: the sequence's length (decides the second-to-last frame; may be traced).
      every: a keyframe every this many frames (``keyframe_every``), a Python int.

    Returns:
      bool, frame ``frame`` is a keyframe: [] for a scalar ``frame`` and ``num_frames`` (else their broadcast
        shape).
    """
    return (frame == 0) | ((frame + 1) % every == 0) | (frame == num_frames - 2)

