"""Map optimisation over a keyframe window (method_spec A.9): Gaussians only, a fresh Adam per frame."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from gsjax.camera import Intrinsics
from gsjax.gaussians import Gaussians
from gsjax.raster import select_slots
from gsjax.raster.render import empty_selection
from gsjax.slam.config import SlamConfig
from gsjax.slam.densify import prune
from gsjax.slam.keyframes import CURRENT, Window
from gsjax.slam.loops import counted_scan, loop_caps
from gsjax.slam.losses import mapping_loss
from gsjax.slam.optimizers import MAP_PARAMS, finite_only_if_loss_is, map_optimizer, nonfinite_steps
from gsjax.slam.state import KeyframeBuffer
from gsjax.slam.views import render_view, strided_frame, strided_setup, strided_slots


class WindowFrames(NamedTuple):
    """The renderable views of a window, V entries (one per :class:`gsjax.slam.keyframes.Window` entry).

    Attributes:
      color: [V, H, W, 3] float32 colour in [0, 1] (keyframes decoded from uint8).
      depth: [V, H, W] float32 depth (m; 0 = invalid), keyframes' to the mm.
      w2c: [V, 4, 4] float32 estimated world-to-camera poses (m).
      gamma: [V] float32 CB-KNN's motion gamma of each view's tracking.
      keyframe: [V] bool, the view is a keyframe (its renders are smoothed in ``paper`` mode): true for stored
        keyframes, the current frame's flag for the current frame.
      valid: [V] bool, the window's ``valid`` (only valid views are drawn).
    """

    color: jax.Array
    depth: jax.Array
    w2c: jax.Array
    gamma: jax.Array
    keyframe: jax.Array
    valid: jax.Array


def gather_window_frames(
    window: Window, keyframes: KeyframeBuffer, color: jax.Array, depth: jax.Array, w2c: jax.Array,
    gamma: jax.Array, current_is_keyframe: jax.Array
) -> WindowFrames:
    """Gather the window's views from the keyframe buffer and the current frame.

    Args:
      window: the mapping window (:func:`gsjax.slam.keyframes.select_window`), W entries.
      keyframes: the keyframe buffer the window's slots index.
      color: [H, W, 3] float32 colour of the current frame in [0, 1].
      depth: [H, W] float32 depth of the current frame (m; 0 = invalid).
      w2c: [4, 4] float32 estimated world-to-camera pose of the current frame (m).
      gamma: [] float32 CB-KNN's motion gamma of the current frame.
      current_is_keyframe: [] bool, whether the current frame is a keyframe.

    Returns:
      W views as :class:`WindowFrames` (V = W), in the window's order (an invalid entry holds some slot's
        content and is never drawn).
    """
    current = window.index == CURRENT
    slot = jnp.maximum(window.index, 0)

    def pick(stored, now):
        mask = current.reshape(current.shape + (1,) * (stored.ndim - 1))
        return jnp.where(mask, now[None], stored)

    return WindowFrames(
        color=pick(keyframes.color_at(slot), color),
        depth=pick(keyframes.depth_at(slot), depth),
        w2c=pick(keyframes.w2c[slot], w2c),
        gamma=pick(keyframes.gamma[slot], gamma),
        keyframe=jnp.where(current, current_is_keyframe, True),
        valid=window.valid,
    )


class MapResult(NamedTuple):
    """The optimised map, the loss of the last iteration, and the iterations skipped because the loss or a
    gradient was not finite (they take no step, so nothing non-finite reaches the map).

    Attributes:
      gaussians: the map after the last step, of the same capacity (pruned slots inactive).
      loss: [] float32 mapping loss of the last iteration (on every pixel, before its step).
      nonfinite: [] int32 iterations that took no step because the loss or a gradient was not finite.
    """

    gaussians: Gaussians
    loss: jax.Array
    nonfinite: jax.Array




def map_window(
    key: jax.Array,
    gaussians: Gaussians,
    views: WindowFrames,
    intrinsics: Intrinsics,
    config: SlamConfig,
    scene_radius: float | jax.Array,
    first_map: bool | jax.Array = False,
) -> MapResult:
    """``config.mapping.strided_iters`` iterations on every other pixel (the four strided grids in turn, see
    :func:`gsjax.slam.views.strided_setup`), then ``config.mapping.iters`` on every pixel, each on one view drawn
    uniformly from the valid window entries; pruning at ``prune_iters`` (counted over all of them; after the
    gradient, before the step, as SplaTAM). ``first_map`` (traced bool): the frame-0 map, whose means take the
    step ``lr_means_first``. With ``mapping.reselect_every`` R > 1 the contributor slots of every window view are
    chosen at iterations 0, R, 2R, ... and composited in between.

    Args:
      key: PRNG key of the view drawn at each iteration.
      gaussians: the map to optimise (after densification), N slots.
      views: the window's views (:func:`gather_window_frames`).
      intrinsics: the camera of the views (full resolution).
      config: the SLAM config (``mapping``, ``raster`` and ``cbknn`` are read).
      scene_radius: the scene radius (m) pruning compares scales with, a scalar.
      first_map: (traced bool) whether this is the first map (no keyframe stored yet), whose means take
        ``lr_means_first``.

    Returns:
      The optimised map (N slots), the last loss and the skipped iterations, as a :class:`MapResult`.
    """
    cfg = config.mapping
    caps = loop_caps(config)
    optimizer = map_optimizer(config.mapping, jnp.where(first_map, cfg.lr_means_first, cfg.lr_means),
                              caps.differentiable)
    params = {name: getattr(gaussians, name) for name in MAP_PARAMS}
    smooth_stage = jnp.logical_and(config.cbknn.smooth_renders, config.cbknn.map_keyframes)
    # A view per iteration slot of both loops (the first n of a longer draw are the draw of n, so the views do not
    # depend on the caps); the full iterations read theirs after the strided ones.
    picks = jax.random.categorical(key, jnp.where(views.valid, 0.0, -jnp.inf),
                                   shape=(caps.mapping_strided + caps.mapping,))
    strided_config = strided_setup(config, intrinsics)

    def full_view(g, view_index, smooth, it, selection):
        view = render_view(g, views.w2c[view_index], intrinsics, config.raster, config.cbknn, smooth,
                           views.gamma[view_index], selection, caps.smoothing)
        return view, views.color[view_index], views.depth[view_index]

    def strided_view(g, view_index, smooth, it, selection):
        color, depth, intrinsics_s = strided_frame(views.color[view_index], views.depth[view_index], intrinsics, it % 4)
        if selection is not None:
            selection = strided_slots(selection, config.raster, intrinsics, it % 4)
        view = render_view(g, views.w2c[view_index], intrinsics_s, strided_config.raster, strided_config.cbknn,
                           smooth, views.gamma[view_index], selection, caps.smoothing)
        return view, color, depth

    def loss_fn(params, active, view_index, it, view_at, selection):
        g = Gaussians(params["means"], params["log_scales"], params["logit_opacities"], params["rgb"], active)
        smooth = views.keyframe[view_index] & smooth_stage
        view, color, depth = view_at(g, view_index, smooth, it, selection)
        return mapping_loss(view, color, depth, cfg.lambda_color, cfg.lambda_depth, cfg.ssim_weight)

    def select_all(params, active):  # every valid window view's slots on the map as it is now
        g = Gaussians(params["means"], params["log_scales"], params["logit_opacities"], params["rgb"], active)
        empty = empty_selection(intrinsics, config.raster)

        def one(view):
            w2c, valid = view
            return jax.lax.cond(valid, lambda: select_slots(g, w2c, intrinsics, config.raster), lambda: empty)

        # a loop, not vmap: the selection is traced once for the whole step, and batching its trace would redo it
        return jax.lax.map(one, (views.w2c, views.valid))

    def iteration(view_at, it, view_index, carry):
        params, active, opt_state, selections, _ = carry
        selection = None
        if caps.mapping_reselect:
            selections = jax.lax.cond(it % cfg.reselect_every == 0, lambda: select_all(params, active),
                                      lambda: selections)
            selection = jax.tree.map(lambda x: x[view_index], selections)
        loss, grads = jax.value_and_grad(loss_fn)(params, active, view_index, it, view_at, selection)
        # Free slots render nothing; only the active entries' gradients decide whether the step is finite.
        grads = {name: jnp.where(active.reshape(active.shape + (1,) * (g.ndim - 1)), g, 0.0)
                 for name, g in grads.items()}
        at_prune = jnp.isin(it, jnp.asarray(cfg.prune_iters, jnp.int32)) if cfg.prune_iters else jnp.bool_(False)
        pruned = prune(Gaussians(params["means"], params["log_scales"], params["logit_opacities"], params["rgb"],
                                 active), cfg, scene_radius).active
        active = jnp.where(at_prune, pruned, active)
        updates, opt_state = optimizer.update(finite_only_if_loss_is(loss, grads), opt_state)
        params = optax.apply_updates(params, updates)
        params["rgb"] = jnp.where(cfg.clamp_rgb, jnp.clip(params["rgb"], 0.0, 1.0), params["rgb"])
        return params, active, opt_state, selections, loss

    selections = None
    if caps.mapping_reselect:
        selections = empty_selection(intrinsics, config.raster, views.w2c.shape[:1])
    carry = (params, gaussians.active, optimizer.init(params), selections, jnp.float32(0.0))
    carry = counted_scan(lambda i, c: iteration(strided_view, i, picks[i], c), carry, cfg.strided_iters,
                         caps.mapping_strided, differentiable=caps.differentiable)
    strided = jnp.minimum(cfg.strided_iters, caps.mapping_strided)
    carry = counted_scan(lambda i, c: iteration(full_view, strided + i, picks[strided + i], c), carry, cfg.iters,
                         caps.mapping, differentiable=caps.differentiable)
    params, active, opt_state, _, last_loss = carry
    nonfinite = nonfinite_steps(opt_state)
    out = Gaussians(params["means"], params["log_scales"], params["logit_opacities"], params["rgb"], active)
    return MapResult(out, last_loss, nonfinite)
