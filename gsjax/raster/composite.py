"""Differentiable front-to-back compositing over the selected contributor slots.

Everything that depends on Gaussian parameters or the pose is recomputed here from the projection (which carries
gradients), at the slots chosen by :mod:`gsjax.raster.select`. Colour, depth (sum w z), silhouette (sum w) and
depth^2 (sum w z^2) come from one pass, with blending weights ``w_k = alpha_k prod_{j<k} (1 - alpha_j)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.raster.project import Projected, gaussian_alpha


class Slots(NamedTuple):
    """Per-pixel contributor slots, gathered from the projection. P pixels, K slots.

    Attributes:
      uv: [P, K, 2] centres (px); conic: [P, K, 3]; opacity: [P, K]; rgb: [P, K, 3]; depth: [P, K] (m);
      valid: [P, K] bool (False for empty slots, whose other entries are zeros).
    """

    uv: jax.Array
    conic: jax.Array
    opacity: jax.Array
    rgb: jax.Array
    depth: jax.Array
    valid: jax.Array


class Composite(NamedTuple):
    """Per-pixel compositing result for P pixels: color [P, 3], depth [P], silhouette [P], depth_sq [P]."""

    color: jax.Array
    depth: jax.Array
    silhouette: jax.Array
    depth_sq: jax.Array


def gather_slots(projected: Projected, ids: jax.Array) -> Slots:
    """Gather the projected Gaussians at slot indices ``ids`` [P, K] (-1 = empty)."""
    valid = ids >= 0
    table = jnp.concatenate(
        [projected.uv, projected.conic, projected.opacity[:, None], projected.rgb, projected.depth[:, None]], axis=-1
    )
    g = jnp.where(valid[..., None], table[jnp.maximum(ids, 0)], 0.0)
    return Slots(g[..., 0:2], g[..., 2:5], g[..., 5], g[..., 6:9], g[..., 9], valid)


def slot_alpha(slots: Slots, pixels: jax.Array, uv: jax.Array | None = None) -> jax.Array:
    """alpha [P, K] of every slot at its pixel ``pixels`` [P, 2] (0 for empty slots).

    ``uv`` [P, K, 2] overrides the slot centres (CB-KNN evaluates shifted centres).
    """
    uv = slots.uv if uv is None else uv
    dx = pixels[:, None, 0] - uv[..., 0]
    dy = pixels[:, None, 1] - uv[..., 1]
    return jnp.where(slots.valid, gaussian_alpha(dx, dy, slots.conic, slots.opacity), 0.0)


def blend_weights(alpha: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Front-to-back weights ``w_k = alpha_k T_k`` [P, K] and the final transmittance [P].

    A ``lax.scan`` over the K slots (vectorised over pixels): on XLA:CPU it beats cumulative-product forms, and it
    is exact (no log/exp round trip).
    """

    def step(transmittance, alpha_k):
        return transmittance * (1.0 - alpha_k), alpha_k * transmittance

    final, weights = jax.lax.scan(step, jnp.ones(alpha.shape[:-1], alpha.dtype), jnp.moveaxis(alpha, -1, 0))
    return jnp.moveaxis(weights, 0, -1), final


def composite(weights: jax.Array, rgb: jax.Array, depth: jax.Array) -> Composite:
    """Blend per-slot colours [P, K, 3] and depths [P, K] with weights [P, K]."""
    return Composite(
        color=jnp.einsum("pk,pkc->pc", weights, rgb),
        depth=jnp.sum(weights * depth, axis=-1),
        silhouette=jnp.sum(weights, axis=-1),
        depth_sq=jnp.sum(weights * depth * depth, axis=-1),
    )
