"""Densification into free slots and pruning (method_spec A.7, A.9), all on device with static shapes."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics, se3_inverse
from gsjax.gaussians import Gaussians, gaussians_from_rgbd
from gsjax.slam.config import DensifyConfig, MappingConfig
from gsjax.slam.views import RenderedView


def densify_mask(view: RenderedView, depth_gt: jax.Array, config: DensifyConfig) -> jax.Array:
    """Where to add Gaussians.

    ``(S < sil_threshold) | ((D > D_gt) & (E > factor * median(E)))`` with ``E = |D_gt - D| [D_gt > 0]`` (the median
    over all pixels, zeros included, as SplaTAM), restricted to valid observed depth. D is SplaTAM's unnormalised
    rendered depth (sum w z).

    Args:
      view: the render of the map at the frame's estimated pose (its silhouette S and depth D, [H, W]).
      depth_gt: [H, W] observed depth D_gt (m); 0 or non-finite = invalid.
      config: the densification config (``sil_threshold``, ``depth_error_factor``).

    Returns:
      [H, W] bool mask of the pixels to add a Gaussian at.
    """
    error = jnp.where(depth_gt > 0, jnp.abs(depth_gt - view.depth), 0.0)
    behind = (view.depth > depth_gt) & (error > config.depth_error_factor * jnp.median(error))
    return ((view.silhouette < config.sil_threshold) | behind) & (depth_gt > 0) & jnp.isfinite(depth_gt)


class Insertion(NamedTuple):
    """The map after insertion, and how many Gaussians were ``added`` and ``dropped`` (no free slot).

    Attributes:
      gaussians: the map, of the same capacity N, with the new Gaussians in its formerly free slots.
      added: [] int32 Gaussians written into free slots.
      dropped: [] int32 active new Gaussians that found no free slot (not inserted).
    """

    gaussians: Gaussians
    added: jax.Array
    dropped: jax.Array


def insert(gaussians: Gaussians, new: Gaussians) -> Insertion:
    """Write the active entries of ``new`` into the free slots of ``gaussians``, in order, without a host round trip.

    Entries that find no free slot are dropped and counted (the shell grows the capacity between chunks so that
    this does not happen; it never happens silently).

    Args:
      gaussians: the map, N slots.
      new: the Gaussians to insert, any number of slots; only the active ones are written, in slot order, into
        the free slots of ``gaussians`` in increasing order.

    Returns:
      The map (N slots) and the counts added and dropped, as an :class:`Insertion`.
    """
    capacity = gaussians.capacity
    free = ~gaussians.active
    free_rank = jnp.cumsum(free) - 1
    num_free = jnp.sum(free)
    # free_slots[r] = index of the r-th free slot.
    free_slots = jnp.zeros(capacity, jnp.int32).at[jnp.where(free, free_rank, capacity)].set(
        jnp.arange(capacity, dtype=jnp.int32), mode="drop"
    )
    rank = jnp.cumsum(new.active) - 1
    fits = new.active & (rank < num_free)
    target = jnp.where(fits, free_slots[jnp.clip(rank, 0, capacity - 1)], capacity)

    def put(field_old, field_new):
        return field_old.at[target].set(field_new, mode="drop")

    merged = Gaussians(
        means=put(gaussians.means, new.means),
        log_scales=put(gaussians.log_scales, new.log_scales),
        logit_opacities=put(gaussians.logit_opacities, new.logit_opacities),
        rgb=put(gaussians.rgb, new.rgb),
        active=gaussians.active.at[target].set(True, mode="drop"),
    )
    num_new = jnp.sum(new.active, dtype=jnp.int32)
    added = jnp.sum(fits, dtype=jnp.int32)
    return Insertion(merged, added, num_new - added)


def densify(
    gaussians: Gaussians,
    view: RenderedView,
    color: jax.Array,
    depth: jax.Array,
    w2c: jax.Array,
    intrinsics: Intrinsics,
    config: DensifyConfig,
) -> Insertion:
    """Add one Gaussian per pixel of :func:`densify_mask` (SplaTAM's initialisation, back-projected with the
    estimated pose ``w2c``).

    Pixels whose colour is not finite are left out, so no non-finite Gaussian enters the map. The new Gaussians
    are made by :func:`gsjax.gaussians.gaussians_from_rgbd` and written by :func:`insert`.

    Args:
      gaussians: the map, N slots.
      view: the render of ``gaussians`` at ``w2c`` (read by :func:`densify_mask`).
      color: [H, W, 3] observed colour in [0, 1].
      depth: [H, W] observed depth (m); 0 or non-finite = invalid.
      w2c: [4, 4] estimated world-to-camera pose of the frame (m).
      intrinsics: the camera of the frame.
      config: the densification config (thresholds and ``init_opacity``).

    Returns:
      The map (N slots) and the counts added and dropped, as an :class:`Insertion`.
    """
    mask = densify_mask(view, depth, config) & jnp.all(jnp.isfinite(color), axis=-1)  # no non-finite Gaussian
    new = gaussians_from_rgbd(color, depth, intrinsics, se3_inverse(w2c), mask, opacity=config.init_opacity)
    return insert(gaussians, new)


def prune(gaussians: Gaussians, config: MappingConfig, scene_radius: float | jax.Array) -> Gaussians:
    """Free the slots of Gaussians with opacity below ``prune_opacity`` or scale above
    ``prune_scale_ratio * scene_radius`` (method_spec A.9).

    Args:
      gaussians: the map, N slots.
      config: the mapping config (``prune_opacity``, ``prune_scale_ratio``).
      scene_radius: the scene radius (m), a scalar.

    Returns:
      The map with those slots inactive; every other field is unchanged.
    """
    remove = (gaussians.opacities < config.prune_opacity) | (
        gaussians.scales > config.prune_scale_ratio * scene_radius
    )
    return Gaussians(
        gaussians.means, gaussians.log_scales, gaussians.logit_opacities, gaussians.rgb, gaussians.active & ~remove
    )
