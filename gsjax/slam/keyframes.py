"""Mapping-window selection by keyframe overlap (method_spec A.8) and the released code's overlap smoothing (C.1)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics, backproject, project_points, se3_inverse
from gsjax.slam.config import CBKNNConfig, MappingConfig
from gsjax.slam.state import KeyframeBuffer

CURRENT = -1  # window entry that stands for the current frame


class Window(NamedTuple):
    """Mapping window of W = ``window_size`` entries, as :func:`select_window` makes it.

    Layout: randomly chosen overlapping keyframes, then the most recent keyframe, then the current frame (always
    valid).

    Attributes:
      index: [W] int32 slot of each entry in the keyframe buffer; ``CURRENT`` (-1) for the current frame.
      valid: [W] bool, whether the entry is a view to map on (entries without an overlapping keyframe, and the
        most recent keyframe's entry while the buffer is empty, are not).
    """

    index: jax.Array  # type: ignore[assignment]  # shadows tuple.index: the name is public
    valid: jax.Array


def sample_points(key: jax.Array, depth: jax.Array, w2c: jax.Array, intrinsics: Intrinsics, count: int) -> jax.Array:
    """World points back-projected from ``count`` pixels drawn uniformly, with replacement, among the valid ones.

    Args:
      key: PRNG key of the draw.
      depth: [H, W] depth (m); pixels with depth > 0 are valid. With none, the pixels are drawn among all of them
        and back-project to the camera centre.
      w2c: [4, 4] world-to-camera pose of the depth image (m).
      intrinsics: the camera of ``depth``.
      count: number of points (static).

    Returns:
      [count, 3] world points (m).
    """
    valid = (depth > 0).reshape(-1)
    total = jnp.sum(valid)
    probabilities = jnp.where(total > 0, valid / jnp.maximum(total, 1), 1.0 / valid.size)
    pixels = jax.random.choice(key, valid.size, (count,), p=probabilities)
    points = backproject(depth, intrinsics).reshape(-1, 3)[pixels]
    c2w = se3_inverse(w2c)
    return points @ c2w[:3, :3].T + c2w[:3, 3]


def smooth_points(key: jax.Array, points: jax.Array, config: CBKNNConfig) -> jax.Array:
    """The released code's 3D KNN smoothing of the overlap samples (method_spec C.1), with static shapes.

    Density from the ``smoothing_base_k`` nearest neighbours (self included); K per point grows linearly with the
    min-max normalised density from ``smoothing_min_k`` to ``smoothing_max_k``; each point becomes the unweighted
    mean of a random subset of ``max(1, floor(K (1 - dropout)))`` of its K nearest neighbours (unchanged if 1).
    K is capped at the number of points.

    Args:
      key: PRNG key of the random subsets.
      points: [N, 3] world points (m), e.g. from :func:`sample_points`.
      config: CB-KNN's config (``smoothing_base_k``, ``smoothing_min_k``, ``smoothing_max_k``,
        ``smoothing_dropout``).

    Returns:
      [N, 3] smoothed points (m), in the dtype of ``points``.
    """
    count = points.shape[0]
    k_max = min(config.smoothing_max_k, count)
    d2 = jnp.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=-1)
    neg_d2, neighbours = jax.lax.top_k(-d2, k_max)  # nearest first, self included
    base = min(config.smoothing_base_k, k_max)
    density = 1.0 / (jnp.mean(-neg_d2[:, :base], axis=-1) + 1e-6)
    normalised = (density - density.min()) / (density.max() - density.min() + 1e-6)
    k = jnp.clip(
        jnp.round(config.smoothing_min_k + normalised * (config.smoothing_max_k - config.smoothing_min_k)),
        config.smoothing_min_k,
        k_max,
    ).astype(jnp.int32)
    subset = jnp.maximum(1, jnp.floor(k * (1.0 - config.smoothing_dropout))).astype(jnp.int32)
    order_keys = jnp.where(jnp.arange(k_max)[None, :] < k[:, None], jax.random.uniform(key, (count, k_max)), 2.0)
    # Each key's rank among its row's: counted pairwise (k_max^2 comparisons, no sort to compile); the real keys are
    # distinct uniforms, and the padding's ties (2.0) rank at k or more, never chosen.
    rank = jnp.sum(order_keys[:, None, :] < order_keys[:, :, None], axis=-1)
    chosen = (rank < subset[:, None]).astype(points.dtype)
    mean = jnp.einsum("nk,nkc->nc", chosen, points[neighbours]) / subset[:, None]
    return jnp.where((subset > 1)[:, None], mean, points)


def overlap_fractions(points: jax.Array, keyframes: KeyframeBuffer, intrinsics: Intrinsics,
                      margin: float | jax.Array) -> jax.Array:
    """The fraction of the world points that project inside each keyframe (``margin`` px from the border, z > 0).

    Args:
      points: [N, 3] world points (m).
      keyframes: the keyframe buffer; every one of its F slots is measured, empty ones included (at their stored
        pose).
      intrinsics: the camera of the keyframes.
      margin: border (px) a projected point must clear, strictly, on every side.

    Returns:
      [F] float32 fraction in [0, 1] per keyframe slot.
    """
    cam = jnp.einsum("fij,nj->fni", keyframes.w2c[:, :3, :3], points) + keyframes.w2c[:, None, :3, 3]
    z = cam[..., 2]
    uv = project_points(cam.at[..., 2].set(jnp.where(z > 0, z, 1.0)), intrinsics)
    u, v = uv[..., 0], uv[..., 1]
    inside = (z > 0) & (u > margin) & (u < intrinsics.width - margin) & (v > margin) & (v < intrinsics.height - margin)
    return jnp.mean(inside, axis=-1)


def select_window(
    key: jax.Array,
    keyframes: KeyframeBuffer,
    depth: jax.Array,
    w2c: jax.Array,
    intrinsics: Intrinsics,
    mapping: MappingConfig,
    cbknn: CBKNNConfig,
) -> Window:
    """SplaTAM's window: keyframes (all but the most recent) that any of the current frame's sampled points
    project into, in random order, the first ``window_size - 2`` of them; then the most recent keyframe; then the
    current frame. Points come from the current depth at the estimated pose ``w2c``.

    Args:
      key: PRNG key (split for the point samples, their smoothing and the keyframes' order).
      keyframes: the keyframe buffer (the current frame not yet pushed).
      depth: [H, W] current depth (m; 0 = invalid).
      w2c: [4, 4] estimated world-to-camera pose of the current frame (m).
      intrinsics: the camera of the frames.
      mapping: the mapping config (``window_size``, ``overlap_samples``, ``overlap_margin`` in px).
      cbknn: CB-KNN's config: the samples are smoothed (:func:`smooth_points`) when its ``smooth_overlap`` holds.

    Returns:
      The window of ``mapping.window_size`` entries, as a :class:`Window`.
    """
    key_points, key_smooth, key_order = jax.random.split(key, 3)
    points = sample_points(key_points, depth, w2c, intrinsics, mapping.overlap_samples)
    smooth = cbknn.smooth_overlap
    if smooth is not False:  # (False: a concrete mode that never smooths them, outside jit)
        points = jax.lax.cond(smooth, lambda: smooth_points(key_smooth, points, cbknn), lambda: points)
    overlap = overlap_fractions(points, keyframes, intrinsics, mapping.overlap_margin)
    slots = jnp.arange(keyframes.capacity)
    eligible = (overlap > 0) & (slots < keyframes.count - 1)
    order = jnp.argsort(jnp.where(eligible, jax.random.uniform(key_order, overlap.shape), 2.0))
    chosen = order[: mapping.window_size - 2]
    chosen = jnp.pad(chosen, (0, max(0, mapping.window_size - 2 - chosen.shape[0])))
    chosen_valid = eligible[chosen] & (jnp.arange(chosen.shape[0]) < keyframes.capacity)
    index = jnp.concatenate([chosen, jnp.stack([keyframes.count - 1, jnp.int32(CURRENT)])]).astype(jnp.int32)
    valid = jnp.concatenate([chosen_valid, jnp.stack([keyframes.count > 0, jnp.bool_(True)])])
    return Window(index, valid)
