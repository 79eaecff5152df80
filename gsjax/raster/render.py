"""``render``: the one entry point of the rasterizer (project -> bin -> select -> composite).

Semantics: SplaTAM's rasterizer (method_spec A.3) with DESIGN 2.2.1's conventions. See :func:`render`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics, rigidity_error
from gsjax.config.fields import is_checkable
from gsjax.gaussians import Gaussians, check_gaussians
from gsjax.raster import cbknn as cb
from gsjax.raster.binning import TileGrid, bin_gaussians
from gsjax.raster.composite import blend, blend_weights, gather, slot_alpha, splat_slots, splat_table
from gsjax.raster.project import project
from gsjax.raster.select import select_contributors
from gsjax.raster.settings import RasterSettings

_RIGID_TOL = 1e-3
class RenderStats(NamedTuple):
    """Diagnostics of one render (int32/float32/bool scalars).

    Attributes:
      tiles_overflowed: tiles with more intersecting Gaussians than ``tile_capacity``.
      intersections_dropped: (tile, Gaussian) pairs beyond the intersection buffer (the farthest ones).
      pixels_out_of_k: pixels with more than ``max_contributors`` contributors before the stop rule.
      pixels_truncated: pixels whose walk was cut early (out of K, or the end of an incomplete tile list).
      max_residual_transmittance: largest transmittance left at such a cut (0 when nothing was cut); it bounds
        the silhouette (and colour) weight lost to truncation.
      max_contributors: largest number of contributors of any pixel (counted through the whole tile list).
      truncated: any pixel truncated.
      cbknn: :class:`gsjax.raster.cbknn.CBKNNStats` when CB-KNN was applied, else None.
    """

    tiles_overflowed: jax.Array
    intersections_dropped: jax.Array
    pixels_out_of_k: jax.Array
    pixels_truncated: jax.Array
    max_residual_transmittance: jax.Array
    max_contributors: jax.Array
    truncated: jax.Array
    cbknn: cb.CBKNNStats | None = None


class Render(NamedTuple):
    """Output of :func:`render`; w are the compositing weights (alpha times transmittance), z camera depths.

    Attributes:
      color: [H, W, 3] float32 ``sum w rgb`` (background 0).
      depth: [H, W] float32 ``sum w z`` (m), not normalised by the silhouette.
      silhouette: [H, W] float32 ``sum w``, in [0, 1].
      depth_sq: [H, W] float32 ``sum w z^2`` (m^2).
      stats: the render's diagnostics.
    """

    color: jax.Array
    depth: jax.Array
    silhouette: jax.Array
    depth_sq: jax.Array
    stats: RenderStats


def check_render_inputs(gaussians: Gaussians, w2c: jax.typing.ArrayLike, intrinsics: Intrinsics,
                        settings: RasterSettings, cbknn: cb.CBKNN | None = None,
                        motion: float | jax.Array = 0.0) -> None:
    """Validate render's arguments; ValueError naming the argument.

    Shape and type checks always run; value checks (finiteness, rigidity, positivity) only when the values are
    concrete, i.e. they are skipped when ``render`` is called under an outer ``jax.jit``/``vmap``/``grad`` trace.

    Args:
      gaussians: the map (:func:`gsjax.gaussians.check_gaussians`: fields' shapes and dtypes, finite active slots).
      w2c: [4, 4] floating-point world-to-camera pose (m); when concrete, finite and rigid within 1e-3.
      intrinsics: a :class:`gsjax.camera.Intrinsics` (:meth:`gsjax.camera.Intrinsics.check`).
      settings: a :class:`gsjax.raster.RasterSettings`.
      cbknn: None, or a :class:`gsjax.raster.cbknn.CBKNN` whose ``k_max`` does not exceed
        ``settings.max_contributors``.
      motion: a scalar, in [0, 1] when concrete.

    Raises:
      ValueError: naming the first argument that is not valid.
    """
    check_gaussians(gaussians)
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics must be a gsjax.camera.Intrinsics, got {type(intrinsics).__name__}")
    intrinsics.check()
    if not isinstance(settings, RasterSettings):
        raise ValueError(f"settings must be a gsjax.raster.RasterSettings, got {type(settings).__name__}")
    w2c_shape = tuple(np.shape(w2c))
    if w2c_shape != (4, 4):
        raise ValueError(f"w2c must be a [4, 4] world-to-camera matrix, got shape {list(w2c_shape)}")
    if not jnp.issubdtype(jnp.result_type(w2c), jnp.floating):
        raise ValueError(f"w2c must be floating point, got {jnp.result_type(w2c)}")
    if is_checkable(w2c):
        w2c_np = np.asarray(w2c, np.float64)
        if not np.isfinite(w2c_np).all():
            raise ValueError("w2c has non-finite entries")
        err = float(rigidity_error(w2c_np))
        if err > _RIGID_TOL:
            raise ValueError(f"w2c is not a rigid transform (rotation/last-row error {err:.3g} > {_RIGID_TOL})")
    if cbknn is not None:
        if not isinstance(cbknn, cb.CBKNN):
            raise ValueError(f"cbknn must be a gsjax.raster.cbknn.CBKNN or None, got {type(cbknn).__name__}")
        if cbknn.k_max > settings.max_contributors:
            raise ValueError(
                f"cbknn.k_max ({cbknn.k_max}) exceeds settings.max_contributors ({settings.max_contributors})"
            )
    if np.ndim(motion) != 0:
        raise ValueError(f"motion must be a scalar in [0, 1], got shape {list(np.shape(motion))}")
    if is_checkable(motion) and not (0.0 <= float(np.asarray(motion)) <= 1.0):
        raise ValueError(f"motion must lie in [0, 1], got {float(np.asarray(motion))!r}")


def render(
    gaussians: Gaussians,
    w2c: jax.Array,
    intrinsics: Intrinsics,
    settings: RasterSettings = RasterSettings(),
    cbknn: cb.CBKNN | None = None,
    motion: float | jax.Array = 0.0,
    selection: SlotSelection | None = None,
    smooth: bool | jax.Array = True,
) -> Render:
    """Render a Gaussian map from a world-to-camera pose, optionally with CB-KNN smoothing.

    Args:
      gaussians: :class:`~gsjax.gaussians.Gaussians` with N slots (inactive slots are ignored).
      w2c: [4, 4] world-to-camera rigid transform (m).
      intrinsics: :class:`~gsjax.camera.Intrinsics`; the output is ``intrinsics.height x intrinsics.width``.
      settings: :class:`RasterSettings` (static shapes plus the traced near plane).
      cbknn: ``None`` for the canonical render, or a :class:`gsjax.raster.cbknn.CBKNN` to smooth each pixel's
        contributors transiently (the Gaussians are not modified); see :mod:`gsjax.raster.cbknn`.
      motion: inter-frame motion gamma in [0, 1] for CB-KNN's adaptive K (ignored without ``cbknn``).
      selection: ``None`` selects each pixel's contributors at ``w2c``; a :class:`SlotSelection` made at a nearby
        pose (:func:`select_slots`, same intrinsics and settings) composites those slots instead (no binning, no walk).
      smooth: with ``cbknn``, whether to apply its correction: a [] bool that may be traced (a keyframe in SLAM's
        ``paper`` mode), so that one compiled render serves both (False composites canonically: the render equals
        ``cbknn=None``'s, with ``stats.cbknn`` all zeros). Ignored without ``cbknn``.

    Returns:
      The render, a :class:`Render` with colour [H, W, 3], depth [H, W] = sum w z (not normalised by the
        silhouette), silhouette [H, W] = sum w, depth_sq [H, W] = sum w z^2, and truncation diagnostics in
        ``stats``.

    Conventions: pixel (row i, column j) is evaluated at (u, v) = (j, i); a camera point projects to
    u = fx X/Z + cx, v = fy Y/Z + cy. Each Gaussian has 2D covariance s^2 J J^T + 0.3 px^2 (``settings.dilation``;
    J's X/Z, Y/Z clamped to 1.3 tan(fov/2)), alpha = min(0.99, o g) with a straight-through gradient at the clamp,
    and contributes exactly where alpha >= 1/255. Front to back in camera depth, a pixel stops before a contributor that
    would leave its transmittance below 1e-4 (that contributor is not added); background is 0; Gaussians with z <= near
    are culled.

    Pure and traceable: ``jax.jit``, ``jax.grad`` (w.r.t. every Gaussian field and the pose) and ``jax.vmap``
    (over poses, stacked maps or CB-KNN parameters) all work on both backends, ``jax.jvp`` on the XLA path
    (``settings.for_forward_mode()``); only shapes are static. Arguments are validated
    here (ValueError naming the argument); value checks are skipped under an outer trace (see
    :func:`check_render_inputs`).
    """
    check_render_inputs(gaussians, w2c, intrinsics, settings, cbknn, motion)
    if selection is not None:
        grid = TileGrid.for_image(intrinsics.height, intrinsics.width, settings.tile_size)
        expected = (settings.max_contributors, grid.num_tiles * grid.pixels_per_tile)
        if not isinstance(selection, SlotSelection) or tuple(np.shape(selection.ids)) != expected:
            got = list(np.shape(selection.ids)) if isinstance(selection, SlotSelection) else type(selection).__name__
            raise ValueError(f"selection must be a SlotSelection with ids of shape {list(expected)} (K x the tile "
                             f"grid's pixels, from select_slots with the same intrinsics and settings), got {got}")
    if np.ndim(smooth) != 0:
        raise ValueError(f"smooth must be a scalar bool, got shape {list(np.shape(smooth))}")
    # A concrete True (the default) smooths without a branch; anything else is a branch on the traced flag.
    branch = None if smooth is True else jnp.asarray(smooth, bool)
    return _render(gaussians, jnp.asarray(w2c, jnp.float32), intrinsics, settings, cbknn,
                   jnp.asarray(motion, jnp.float32), selection, branch)


class SlotSelection(NamedTuple):
    """The contributor slots of every pixel, chosen at one pose (:func:`select_slots`), for compositing at poses
    near it (``render(..., selection=...)``). P = the tile grid's pixels in tile-major order.

    Attributes:
      ids: [K, P] int32 Gaussian indices front to back, slot-major; -1 marks an empty slot.
      num_kept: [P] int32 contributors of each pixel at that pose (counted through its whole tile list).
      out_of_k: [P] bool, the walk was cut by K.
      cut_by_list: [P] bool, the walk was cut by the end of an incomplete tile list.
      residual_list: [P] float32 transmittance left at the end of the list (meaningful where ``cut_by_list``).
      tiles_overflowed: [] int32, as :class:`RenderStats`.
      intersections_dropped: [] int32, as :class:`RenderStats`.
    """

    ids: jax.Array
    num_kept: jax.Array
    out_of_k: jax.Array
    cut_by_list: jax.Array
    residual_list: jax.Array
    tiles_overflowed: jax.Array
    intersections_dropped: jax.Array


def empty_selection(intrinsics: Intrinsics, settings: RasterSettings, batch: tuple[int, ...] = ()) -> SlotSelection:
    """A :class:`SlotSelection` of ``batch``-shaped stacks with every slot empty, of the shapes :func:`select_slots`
    gives for ``intrinsics`` and ``settings`` (a placeholder a loop carries until its first selection).

    Args:
      intrinsics: the camera (its image size sets the tile grid).
      settings: the rasterizer settings (``tile_size`` and K = ``max_contributors`` are read).
      batch: leading shape of the stack; () for one selection.

    Returns:
      The selection: ids ``[*batch, K, P]`` int32 all -1; num_kept ``[*batch, P]`` int32 zeros; out_of_k
        and cut_by_list ``[*batch, P]`` bool False; residual_list ``[*batch, P]`` float32 zeros;
        tiles_overflowed and intersections_dropped ``[*batch]`` int32 zeros. P is the tile grid's pixels.
    """
    grid = TileGrid.for_image(intrinsics.height, intrinsics.width, settings.tile_size)
    pixels = batch + (grid.num_tiles * grid.pixels_per_tile,)
    return SlotSelection(ids=jnp.full(batch + (settings.max_contributors,) + pixels[-1:], -1, jnp.int32),
                         num_kept=jnp.zeros(pixels, jnp.int32), out_of_k=jnp.zeros(pixels, bool),
                         cut_by_list=jnp.zeros(pixels, bool), residual_list=jnp.zeros(pixels, jnp.float32),
                         tiles_overflowed=jnp.zeros(batch, jnp.int32),
                         intersections_dropped=jnp.zeros(batch, jnp.int32))


def select_slots(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics,
                 settings: RasterSettings = RasterSettings()) -> SlotSelection:
    """The first-K contributors of every pixel at ``w2c`` (project, bin and the selection walk of :func:`render`,
    no gradient), to composite at nearby poses with ``render(..., selection=...)``.

    At the pose it was chosen at, ``render(g, w2c, ..., selection=select_slots(g, w2c, ...))`` is ``render(g, w2c,
    ...)``. At another pose the same slots are composited, in the same order, with everything that depends on the
    pose (centres, footprints, alphas, depths and their gradients) recomputed there: exact for those slots, but a
    Gaussian that would enter or leave a pixel's first K there does not, and the stop rule is not re-applied. The
    tracker uses it to skip binning and the walk on most iterations (``tracking.reselect_every``).

    Args:
      gaussians: the map, as :func:`render`.
      w2c: [4, 4] world-to-camera rigid transform (m) to select at.
      intrinsics: the camera; the renders that use the selection must have the same.
      settings: the rasterizer settings; the renders that use the selection must have the same.

    Returns:
      The slots of every pixel of the tile grid (no gradient flows through it).

    Raises:
      ValueError: naming the argument, as :func:`render`.
    """
    check_render_inputs(gaussians, w2c, intrinsics, settings)
    # A choice, not a function to differentiate: reverse mode through a loop that selects keeps nothing of the walk.
    gaussians, w2c = jax.lax.stop_gradient((gaussians, jnp.asarray(w2c, jnp.float32)))
    return _select(gaussians, w2c, intrinsics, _selection_settings(settings))


def _selection_settings(settings: RasterSettings) -> RasterSettings:
    """The settings with what the selection does not read set alike, so that renders differing only there share
    one traced selection (tracing it is a large part of tracing a SLAM step)."""
    return dataclasses.replace(settings, pose_only=False, slots_per_batch=RasterSettings.slots_per_batch)


def _as_float32(gaussians: Gaussians) -> Gaussians:
    return jax.tree_util.tree_map(lambda x: x if x.dtype == jnp.bool_ else jnp.asarray(x, jnp.float32), gaussians)


@jax.jit
def _select(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, settings: RasterSettings) -> SlotSelection:
    gaussians = jax.lax.stop_gradient(_as_float32(gaussians))
    w2c = jax.lax.stop_gradient(w2c)
    grid = TileGrid.for_image(intrinsics.height, intrinsics.width, settings.tile_size)
    with jax.named_scope("project"):
        projected = project(gaussians, w2c, intrinsics, settings.near, settings.dilation)
    with jax.named_scope("bin"):
        tiles = bin_gaussians(
            projected.uv,
            projected.extent,
            projected.depth,
            projected.visible,
            grid,
            settings.tile_capacity,
            settings.intersection_capacity(gaussians.capacity, grid),
        )
    with jax.named_scope("select"):
        selection = select_contributors(
            projected, tiles, grid, settings.max_contributors, settings.tiles_per_batch, settings.uses_pallas
        )
    return SlotSelection(*selection, tiles_overflowed=jnp.sum(tiles.count > settings.tile_capacity, dtype=jnp.int32),
                         intersections_dropped=tiles.intersections_dropped)


def strided_selection(selection: SlotSelection, height: int, width: int, tile_size: int, strided_tile_size: int,
                      row: int | jax.Array, col: int | jax.Array) -> SlotSelection:
    """The slots of every other pixel from (``row``, ``col``) (0 or 1, may be traced) of a ``selection`` made for an
    image ``height`` x ``width`` with ``tile_size`` tiles, laid out for that strided image
    (:meth:`gsjax.camera.Intrinsics.strided`) with ``strided_tile_size`` tiles. The strided render's contributors are
    the full render's at those pixels, so this is the strided image's own selection at the same pose.

    Args:
      selection: a selection of one image (ids [K, P], not stacked) made with ``tile_size`` tiles.
      height: the full image's height (px).
      width: the full image's width (px).
      tile_size: the full image's tile side (px).
      strided_tile_size: the strided image's tile side (px).
      row: first row of the strided pixels, 0 or 1 (may be traced).
      col: first column of the strided pixels, 0 or 1 (may be traced).

    Returns:
      The selection of the ``height // 2`` x ``width // 2`` strided image: ids [K, P'] and the per-pixel fields
        [P'] for the P' pixels of its tile grid; ``tiles_overflowed`` and ``intersections_dropped`` are the full
        image's.
    """
    full = TileGrid.for_image(height, width, tile_size)
    part = TileGrid.for_image(height // 2, width // 2, strided_tile_size)
    # (u, v) of each strided pixel, tile-major (numpy: shapes are static, and this runs under jit)
    t = part.tile_size
    local_v, local_u = np.divmod(np.arange(t * t), t)
    tile_y, tile_x = np.divmod(np.arange(part.num_tiles), part.tiles_x)
    u_part = (tile_x[:, None] * t + local_u[None, :]).reshape(-1)
    v_part = (tile_y[:, None] * t + local_v[None, :]).reshape(-1)
    tables = []
    for r in (0, 1):
        for c in (0, 1):
            u, v = 2 * u_part + c, 2 * v_part + r  # the full image's pixel, inside its padded tile grid
            f = full.tile_size
            tables.append((v // f * full.tiles_x + u // f) * full.pixels_per_tile + (v % f) * f + u % f)
    index = jnp.asarray(np.stack(tables).astype(np.int32))[2 * row + col]  # [P']
    per_pixel = lambda x: x[..., index]  # noqa: E731
    return selection._replace(ids=selection.ids[:, index], num_kept=per_pixel(selection.num_kept),
                              out_of_k=per_pixel(selection.out_of_k), cut_by_list=per_pixel(selection.cut_by_list),
                              residual_list=per_pixel(selection.residual_list))


@jax.jit
def _render(
    gaussians: Gaussians,
    w2c: jax.Array,
    intrinsics: Intrinsics,
    settings: RasterSettings,
    cbknn: cb.CBKNN | None,
    motion: jax.Array,
    selection: SlotSelection | None = None,
    smooth: jax.Array | None = None,
) -> Render:
    gaussians = _as_float32(gaussians)
    grid = TileGrid.for_image(intrinsics.height, intrinsics.width, settings.tile_size)
    if selection is None:
        selection = _select(gaussians, w2c, intrinsics, _selection_settings(settings))
    in_image = grid.in_image()
    with jax.named_scope("composite"):
        pixels = grid.pixel_coords().reshape(-1, 2)
        k_pixel = None
        if cbknn is not None:
            def kernel_sizes():
                projected = project(gaussians, w2c, intrinsics, settings.near, settings.dilation)
                rho = cb.density_map(projected, grid.height, grid.width, cbknn.cell)
                return rho, cb.kernel_size_map(rho, cbknn, motion)

            def no_kernel():
                cells = (-(-grid.height // cbknn.cell), -(-grid.width // cbknn.cell))
                return jnp.zeros(cells, jnp.float32), jnp.zeros(cells, jnp.float32 if cbknn.straight_through_k
                                                                 else jnp.int32)

            rho, k_map = kernel_sizes() if smooth is None else jax.lax.cond(smooth, kernel_sizes, no_kernel)
            k_pixel = k_map.reshape(-1)[cb.pixel_cells(pixels, grid.height, grid.width, cbknn.cell)]
        if settings.pose_only:
            def source(ids):
                return splat_slots(gaussians, ids, w2c, intrinsics, settings.near, settings.dilation)
        else:
            table = splat_table(gaussians, w2c, intrinsics, settings.near, settings.dilation)
            source = lambda ids: gather(table, ids)  # noqa: E731
        out, final_transmittance, shift_sum, num_corrected = _composite_batched(
            source, selection.ids, pixels, in_image, k_pixel, cbknn, settings, grid, smooth
        )
        cbknn_stats = None
        if cbknn is not None:
            assert k_pixel is not None  # set with cbknn above
            cbknn_stats = cb.CBKNNStats(
                k_map=jax.lax.stop_gradient(k_map).astype(jnp.int32),
                rho_map=rho,
                mean_shift_px=shift_sum / jnp.maximum(num_corrected, 1),
                fraction_fewer_than_k=jnp.sum(in_image & (selection.num_kept < k_pixel)) / jnp.sum(in_image),
            )
    truncated = in_image & (selection.out_of_k | selection.cut_by_list)
    # Where K cut the walk, what is left is the transmittance after the K-th contributor, i.e. after compositing.
    residual = jnp.where(
        selection.out_of_k,
        jax.lax.stop_gradient(final_transmittance),
        jnp.where(selection.cut_by_list, selection.residual_list, 0.0),
    )
    stats = RenderStats(
        tiles_overflowed=selection.tiles_overflowed,
        intersections_dropped=selection.intersections_dropped,
        pixels_out_of_k=jnp.sum(in_image & selection.out_of_k, dtype=jnp.int32),
        pixels_truncated=jnp.sum(truncated, dtype=jnp.int32),
        max_residual_transmittance=jnp.max(jnp.where(truncated, residual, 0.0)),
        max_contributors=jnp.max(jnp.where(in_image, selection.num_kept, 0)),
        truncated=jnp.any(truncated),
        cbknn=cbknn_stats,
    )
    return Render(
        color=grid.untile(out.color),
        depth=grid.untile(out.depth),
        silhouette=grid.untile(out.silhouette),
        depth_sq=grid.untile(out.depth_sq),
        stats=stats,
    )


def _composite_pixels(source, ids, pixels, in_image, k_pixel, cbknn, use_pallas: bool, smooth=None):
    """Slots, alpha and blend of pixels [P] with slots ``ids`` [K, P] (``source(ids)`` gives the :class:`Slots`);
    CB-KNN (method_spec D.5, D.7) when ``cbknn``, where ``smooth`` (a traced [] bool; None: always) holds. Returns
    (Composite, canonical final transmittance [P], CB-KNN shift sum (px), number of corrected slots)."""
    slots = source(ids)
    alpha = slot_alpha(slots, pixels)
    if cbknn is None:
        out, final = blend(alpha, slots.r, slots.g, slots.b, slots.depth, use_pallas)
        return out, final, jnp.float32(0.0), jnp.int32(0)

    def corrected():
        # CB-KNN needs the canonical weights themselves (consensus colour, top-weight selection).
        weights, final = blend_weights(alpha)
        fixed = cb.correct_slots(slots, pixels, alpha, weights, k_pixel, cbknn)
        shift_sum = jnp.sum(jnp.where(in_image[None, :], fixed.shift_px, 0.0))
        count = jnp.sum(fixed.corrected & in_image[None, :], dtype=jnp.int32)
        return (fixed.alpha, fixed.r, fixed.g, fixed.b), final, shift_sum, count

    def canonical():
        return (alpha, slots.r, slots.g, slots.b), jnp.zeros_like(alpha[0]), jnp.float32(0.0), jnp.int32(0)

    # Only the correction is branched on: the slots, their alpha and the blend are compiled once for both.
    (a, r, g, b), final, shift_sum, count = (corrected() if smooth is None
                                             else jax.lax.cond(smooth, corrected, canonical))
    out, blended_final = blend(a, r, g, b, slots.depth, use_pallas)
    if smooth is not None:
        final = jnp.where(smooth, final, blended_final)
    return out, final, shift_sum, count


def _composite_batched(source, ids, pixels, in_image, k_pixel, cbknn, settings: RasterSettings, grid: TileGrid,
                       smooth=None):
    """:func:`_composite_pixels` over all pixels, in equal batches of tiles when the K x P slots exceed
    ``settings.slots_per_batch`` (each batch rematerialised in the backward pass, so memory stays bounded)."""
    use_pallas = settings.uses_pallas
    num_slots = ids.shape[0]
    num_batches = min(grid.num_tiles, -(-num_slots * ids.shape[1] // settings.slots_per_batch))
    if num_batches == 1:
        return _composite_pixels(source, ids, pixels, in_image, k_pixel, cbknn, use_pallas, smooth)
    tiles = -(-grid.num_tiles // num_batches)
    num_batches = -(-grid.num_tiles // tiles)  # no batch of padding only
    width = tiles * grid.pixels_per_tile
    fill = num_batches * width - ids.shape[1]
    k_pixel = jnp.zeros(ids.shape[1], jnp.int32) if k_pixel is None else k_pixel
    per_pixel = (
        jnp.pad(ids, ((0, 0), (0, fill)), constant_values=-1).reshape(num_slots, num_batches, width).swapaxes(0, 1),
        jnp.pad(pixels, ((0, fill), (0, 0))).reshape(num_batches, width, 2),
        jnp.pad(in_image, (0, fill)).reshape(num_batches, width),
        jnp.pad(k_pixel, (0, fill)).reshape(num_batches, width),
    )

    @jax.checkpoint
    def batch(args):
        return _composite_pixels(source, *args, cbknn, use_pallas, smooth)

    out, final, shift_sum, num_corrected = jax.lax.map(batch, per_pixel)
    crop = lambda x: x.reshape((-1,) + x.shape[2:])[: ids.shape[1]]  # noqa: E731
    return jax.tree_util.tree_map(crop, out), crop(final), jnp.sum(shift_sum), jnp.sum(num_corrected)
