"""Differentiable front-to-back compositing over the selected contributor slots.

Everything that depends on Gaussian parameters or the pose is recomputed here with gradients
(:func:`gsjax.raster.project.splat`, the same function the selection used): once per Gaussian and gathered into
the slots (:func:`splat_table`, :func:`gather`), or, when only the pose is differentiated, once per slot from the
gathered raw parameters (:func:`splat_slots`: its backward pass is elementwise, with no scatter into the Gaussians).
Colour, depth (sum w z), silhouette (sum w) and depth^2 (sum w z^2) come from one pass, with blending weights
``w_k = alpha_k prod_{j<k} (1 - alpha_j)``; :func:`blend` runs it on XLA or in the Pallas kernel (the backend choice
lives here, as the selection's lives in :mod:`gsjax.raster.select`).

Layout: slot-major [K, P] with one array per quantity; on XLA:CPU this vectorises several times better than
[P, K, features], and the scan over slots runs along the leading axis.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics
from gsjax.gaussians import Gaussians
from gsjax.raster import pallas
from gsjax.raster.project import DILATION, Splat, gaussian_alpha, sanitized, splat, to_camera


class Slots(NamedTuple):
    """Per-pixel contributor slots, projected; every field [K, P] (slot-major), P pixels, K slots.

    Attributes:
      u, v: centres (px); conic_a, conic_b, conic_c: inverse 2D covariance; opacity; r, g, b: colour;
      depth: camera z (m); valid: bool (False for empty slots, whose other entries are harmless constants).
    """

    u: jax.Array
    v: jax.Array
    conic_a: jax.Array
    conic_b: jax.Array
    conic_c: jax.Array
    opacity: jax.Array
    r: jax.Array
    g: jax.Array
    b: jax.Array
    depth: jax.Array
    valid: jax.Array


class Composite(NamedTuple):
    """Per-pixel compositing result for P pixels: color [P, 3], depth [P], silhouette [P], depth_sq [P]."""

    color: jax.Array
    depth: jax.Array
    silhouette: jax.Array
    depth_sq: jax.Array


def splat_table(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, near: float | jax.Array,
                dilation: float | jax.Array = DILATION) -> Slots:
    """Project every Gaussian (with gradients) -> :class:`Slots` with fields [N], one per Gaussian slot."""
    g = sanitized(gaussians)
    x, y, z = to_camera(g.means[:, 0], g.means[:, 1], g.means[:, 2], w2c)
    s = splat(x, y, z, g.log_scales, g.logit_opacities, intrinsics, near, dilation)
    return _slots(s, g.rgb[:, 0], g.rgb[:, 1], g.rgb[:, 2], jnp.ones_like(s.u, bool))


def _slots(s: Splat, r, g, b, valid) -> Slots:
    return Slots(u=s.u, v=s.v, conic_a=s.conic_a, conic_b=s.conic_b, conic_c=s.conic_c, opacity=s.opacity,
                 r=r, g=g, b=b, depth=s.depth, valid=valid)


def splat_slots(gaussians: Gaussians, ids: jax.Array, w2c: jax.Array, intrinsics: Intrinsics,
                near: float | jax.Array, dilation: float | jax.Array = DILATION) -> Slots:
    """:class:`Slots` [K, P] projected per slot from the raw parameters of the Gaussians ``ids`` [K, P] (-1 =
    empty), with gradients w.r.t. ``w2c`` only (the map is held fixed).

    The same values as ``gather(splat_table(...), ids)``, but the backward pass is elementwise per slot plus a sum
    into the 12 pose entries, with no scatter into the N Gaussians (what tracking needs).
    """
    g = sanitized(jax.lax.stop_gradient(gaussians))
    raw = jnp.stack([g.means[:, 0], g.means[:, 1], g.means[:, 2], g.log_scales, g.logit_opacities, g.rgb[:, 0],
                     g.rgb[:, 1], g.rgb[:, 2]])[:, jnp.maximum(ids, 0)]  # [8, K, P]
    x, y, z = to_camera(raw[0], raw[1], raw[2], w2c)
    return _slots(splat(x, y, z, raw[3], raw[4], intrinsics, near, dilation), raw[5], raw[6], raw[7], ids >= 0)


def gather(table: Slots, ids: jax.Array) -> Slots:
    """The rows of a per-Gaussian ``table`` (:func:`splat_table`) at slot indices ``ids`` [K, P] (-1 = empty).

    One gather per column: on XLA:CPU a stacked [F, N] table gathered at once made the render's fwd+bwd 1.5-2x
    slower (bench_raster, 80x60 and 160x120; the frame's step unchanged), as a packed feature axis does elsewhere.
    Empty slots hold zeros (their ``valid`` is False, so their alpha is 0 whatever they hold).
    """
    # Empty slots read past the end (filled with 0), so the backward pass drops them: clamped to Gaussian 0, half of
    # all slots would add into that one entry, and on XLA:CPU such a hot index makes each scatter-add ~5x slower.
    index = jnp.where(ids >= 0, ids, table.u.shape[0])
    columns = [jnp.take(column, index, mode="fill", fill_value=0) for column in table[:-1]]
    return Slots(*columns, valid=ids >= 0)  # type: ignore[misc]  # mypy cannot count a list's items


def slot_alpha(slots: Slots, pixels: jax.Array, u: jax.Array | None = None, v: jax.Array | None = None) -> jax.Array:
    """alpha [K, P] of every slot at its pixel, ``pixels`` [P, 2] (0 for empty slots).

    ``u``, ``v`` [K, P] override the slot centres (CB-KNN evaluates shifted centres).
    """
    u = slots.u if u is None else u
    v = slots.v if v is None else v
    alpha = gaussian_alpha(
        pixels[None, :, 0] - u, pixels[None, :, 1] - v, slots.conic_a, slots.conic_b, slots.conic_c, slots.opacity
    )
    return jnp.where(slots.valid, alpha, 0.0)


def blend_weights(alpha: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Front-to-back weights ``w_k = alpha_k T_k`` [K, P] and the final transmittance [P], for alpha [K, P].

    A ``lax.scan`` over the K slots (vectorised over pixels): on XLA:CPU it beats cumulative-product forms, and it
    is exact (no log/exp round trip).
    """

    def step(transmittance, alpha_k):
        return transmittance * (1.0 - alpha_k), alpha_k * transmittance

    final, weights = jax.lax.scan(step, jnp.ones(alpha.shape[1:], alpha.dtype), alpha)
    return weights, final


def composite(weights: jax.Array, r: jax.Array, g: jax.Array, b: jax.Array, depth: jax.Array) -> Composite:
    """Blend per-slot colours and depths [K, P] with weights [K, P]."""
    wz = weights * depth
    return Composite(
        color=jnp.stack([jnp.sum(weights * r, 0), jnp.sum(weights * g, 0), jnp.sum(weights * b, 0)], axis=-1),
        depth=jnp.sum(wz, 0),
        silhouette=jnp.sum(weights, 0),
        depth_sq=jnp.sum(wz * depth, 0),
    )


def blend(alpha: jax.Array, r: jax.Array, g: jax.Array, b: jax.Array, depth: jax.Array,
          use_pallas: bool) -> tuple[Composite, jax.Array]:
    """Composite slots [K, P] front to back -> (Composite, final transmittance [P]): :func:`blend_weights` and
    :func:`composite` on XLA, or the fused Pallas kernel (:func:`gsjax.raster.pallas.composite_slots`)."""
    if use_pallas:
        cr, cg, cb, d, sil, dsq, final = pallas.composite_slots(alpha, r, g, b, depth)
        return Composite(jnp.stack([cr, cg, cb], axis=-1), d, sil, dsq), final
    weights, final = blend_weights(alpha)
    return composite(weights, r, g, b, depth), final
