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

    :func:`splat_table` makes a per-Gaussian table of the same fields, each [N].

    Attributes:
      u: centre's column (px).
      v: centre's row (px).
      conic_a: entry a of the inverse 2D covariance [[a, b], [b, c]] (1/px^2).
      conic_b: entry b of the inverse 2D covariance (1/px^2).
      conic_c: entry c of the inverse 2D covariance (1/px^2).
      opacity: sigmoid(logit_opacity), in (0, 1).
      r: colour's red channel.
      g: colour's green channel.
      b: colour's blue channel.
      depth: camera z (m).
      valid: bool, False for empty slots (whose other entries are harmless constants).
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
    """Per-pixel compositing result for P pixels, with blending weights w over each pixel's slots.

    Attributes:
      color: [P, 3] sum w c (r, g, b).
      depth: [P] sum w z (m), not normalised by the silhouette.
      silhouette: [P] sum w, in [0, 1].
      depth_sq: [P] sum w z^2 (m^2).
    """

    color: jax.Array
    depth: jax.Array
    silhouette: jax.Array
    depth_sq: jax.Array


def splat_table(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, near: float | jax.Array,
                dilation: float | jax.Array = DILATION) -> Slots:
    """Project every Gaussian (with gradients) -> :class:`Slots` with fields [N], one per Gaussian slot.

    Args:
      gaussians: :class:`~gsjax.gaussians.Gaussians` with N slots (free slots are replaced by
        :func:`~gsjax.raster.project.sanitized`'s constants).
      w2c: [4, 4] world-to-camera rigid transform (m).
      intrinsics: :class:`~gsjax.camera.Intrinsics` of the image (px).
      near: near plane (m).
      dilation: added to the diagonal of the 2D covariance (px^2).

    Returns:
      The per-Gaussian table, a :class:`Slots` with every field [N] and ``valid`` all True, differentiable w.r.t.
        the Gaussians and ``w2c``; :func:`gather` takes its rows into slots.
    """
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

    Args:
      gaussians: :class:`~gsjax.gaussians.Gaussians` with N slots (under ``stop_gradient``).
      ids: [K, P] int32 Gaussian index of each slot, -1 for an empty slot.
      w2c: [4, 4] world-to-camera rigid transform (m); gradients flow to it, not to the Gaussians.
      intrinsics: :class:`~gsjax.camera.Intrinsics` of the image (px).
      near: near plane (m).
      dilation: added to the diagonal of the 2D covariance (px^2).

    Returns:
      The slots, a :class:`Slots` with every field [K, P]; empty slots hold Gaussian 0's values with ``valid``
        False.
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

    Args:
      table: the per-Gaussian :class:`Slots` of :func:`splat_table`, every field [N].
      ids: [K, P] int32 Gaussian index of each slot, -1 for an empty slot.

    Returns:
      The slots, a :class:`Slots` with every field [K, P] (``valid`` is ``ids >= 0``); the gradient flows back
        into ``table``.
    """
    # Empty slots read past the end (filled with 0), so the backward pass drops them: clamped to Gaussian 0, half of
    # all slots would add into that one entry, and on XLA:CPU such a hot index makes each scatter-add ~5x slower.
    index = jnp.where(ids >= 0, ids, table.u.shape[0])
    columns = [jnp.take(column, index, mode="fill", fill_value=0) for column in table[:-1]]
    return Slots(*columns, valid=ids >= 0)  # type: ignore[misc]  # mypy cannot count a list's items


def slot_alpha(slots: Slots, pixels: jax.Array, u: jax.Array | None = None, v: jax.Array | None = None) -> jax.Array:
    """alpha [K, P] of every slot at its pixel, ``pixels`` [P, 2] (0 for empty slots).

    ``u``, ``v`` [K, P] override the slot centres (CB-KNN evaluates shifted centres).

    Args:
      slots: :class:`Slots` [K, P].
      pixels: [P, 2] (u, v) of each pixel (px).
      u: None for the slots' own centres, or [K, P] centre columns (px) to use instead.
      v: None for the slots' own centres, or [K, P] centre rows (px) to use instead.

    Returns:
      alpha [K, P] in [0, 0.99] (:func:`~gsjax.raster.project.gaussian_alpha`, no 1/255 threshold), 0 where
        ``valid`` is False.
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

    Args:
      alpha: [K, P] per-slot alpha, slots in depth order (front first).

    Returns:
      A pair of arrays: the weights ``w_k = alpha_k prod_{j<k} (1 - alpha_j)`` [K, P] and the final transmittance
        ``prod_k (1 - alpha_k)`` [P], both of ``alpha``'s dtype.
    """

    def step(transmittance, alpha_k):
        return transmittance * (1.0 - alpha_k), alpha_k * transmittance

    final, weights = jax.lax.scan(step, jnp.ones(alpha.shape[1:], alpha.dtype), alpha)
    return weights, final


def composite(weights: jax.Array, r: jax.Array, g: jax.Array, b: jax.Array, depth: jax.Array) -> Composite:
    """Blend per-slot colours and depths [K, P] with weights [K, P].

    Args:
      weights: [K, P] blending weights w (:func:`blend_weights`).
      r: [K, P] red channel of each slot.
      g: [K, P] green channel of each slot.
      b: [K, P] blue channel of each slot.
      depth: [K, P] camera z of each slot (m).

    Returns:
      Per-pixel sums over the slots as a :class:`Composite`: colour [P, 3], depth [P] (m), silhouette [P] and
        depth_sq [P] (m^2).
    """
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
    :func:`composite` on XLA, or the fused Pallas kernel (:func:`gsjax.raster.pallas.composite_slots`).

    Args:
      alpha: [K, P] per-slot alpha, slots in depth order (front first).
      r: [K, P] red channel of each slot.
      g: [K, P] green channel of each slot.
      b: [K, P] blue channel of each slot.
      depth: [K, P] camera z of each slot (m).
      use_pallas: a static bool: the Pallas kernel (float32 inputs; reverse mode only, no ``jax.jvp``) if True,
        else XLA.

    Returns:
      A pair: the :class:`Composite` of the P pixels and the final transmittance ``prod_k (1 - alpha_k)`` [P].
    """
    if use_pallas:
        cr, cg, cb, d, sil, dsq, final = pallas.composite_slots(alpha, r, g, b, depth)
        return Composite(jnp.stack([cr, cg, cb], axis=-1), d, sil, dsq), final
    weights, final = blend_weights(alpha)
    return composite(weights, r, g, b, depth), final
