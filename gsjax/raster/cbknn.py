"""CB-KNN: per-pixel adaptive kernel smoothing applied to the contributor slots before compositing.

Implements the paper's per-pixel method as resolved in method_spec D.4-D.7 (the authors' released code does not
contain it). For every pixel p with kernel size K_p (from the adaptive K map, D.7), a set G_p of K_p contributor
slots is *transiently* corrected; the canonical Gaussians are never modified:

* centroid ``C_p = mean_{k in G_p} u_k`` of the slots' 2D centres (px);
* position smoothing (flag ``position``): ``u'_k = u_k + alpha * dir_k`` with the unit direction
  ``dir_k = stop_gradient((C_p - u_k) / (|C_p - u_k| + eps))`` (``shift_mode="unit"``, alpha in px), or
  ``u'_k = u_k + alpha * (C_p - u_k)`` (``shift_mode="fraction"``, alpha a fraction); the camera depth is kept
  (``d'_k = z_k``, D.4 #4), so only the 2D centre moves;
* colour smoothing (flag ``colour``): every slot of G_p takes the consensus ``c_bar = sum_k w_k c_k`` with
  ``w_k = f_k / sum_j f_j``, where ``f_k = min(0.99, o_k g_k(p; u_k))`` is evaluated at the *unshifted* centres;
* compositing: the corrected slots use ``f'_k = min(0.99, o_k g_k(p; u'_k))`` and ``c'_k``; with
  ``truncate=False`` (hybrid, default) every other contributor is composited unchanged behind them, in depth
  order, with the transmittance the corrected slots leave; with ``truncate=True`` only G_p is composited (the
  paper-literal equations E5-E7).

Hybrid mode keeps the canonical walk's early-termination rule for the uncorrected contributors (the slots were
chosen by the canonical render): a small approximation, since the corrected slots change the transmittance.

G_p is the first K_p contributors in depth order (``select="first_k"``, D.4 #1a) or the K_p contributors with the
largest canonical blend weights ``f_i T_i`` (``select="top_weight"``, D.4 #1b), kept in depth order.

Adaptive K (D.7): per ``cell`` x ``cell`` pixel cell, ``rho`` = number of visible Gaussian centres in the cell
divided by the mean over non-empty cells, and ``K = clip(round(k0 max(0.5, 1 + beta gamma / (rho + eps))),
k_min, k_max)``; ``gamma`` in [0, 1] is the inter-frame motion (:func:`motion_from_poses`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import camera_center, rotation_angle
from gsjax.config.fields import check_fields, param
from gsjax.raster.composite import Slots, slot_alpha
from gsjax.raster.project import Projected

SELECT_MODES = ("first_k", "top_weight")
SHIFT_MODES = ("unit", "fraction")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CBKNN:
    """CB-KNN configuration. Float fields are traced (vmap-able, no recompilation when they change); the rest are
    static flags and shapes.

    Attributes:
      alpha: shift magnitude: px for ``shift_mode="unit"``, a fraction of the distance for ``"fraction"``.
      k0: base kernel size K_0 (5 Replica, 8 TUM/ScanNet).
      beta: weight of the motion term in the adaptive K.
      eps: stabiliser in the shift direction and in ``gamma / (rho + eps)``.
      tau_t: camera-centre motion (m) that gives gamma = 1.
      tau_r: rotation (deg) that gives gamma = 1.
      k_min: lower bound of K.
      k_max: upper bound of K, and the most slots a pixel corrects (at most the rasterizer's ``max_contributors``).
      cell: side (px) of the cells over which rho and K are computed.
      position: apply the position smoothing (shift the slots of G_p towards their centroid).
      colour: apply the colour smoothing (the slots of G_p take their consensus colour).
      truncate: composite only the corrected slots (paper-literal) instead of the hybrid default.
      select: ``"first_k"`` or ``"top_weight"`` (which contributors form G_p).
      shift_mode: ``"unit"`` or ``"fraction"``.
      straight_through_k: K per cell passes the derivative of its unrounded value ``clip(k0 max(0.5, 1 + beta gamma
        / (rho + eps)), k_min, k_max)`` and a pixel's slot K_p (the next one after G_p) the derivative of its
        membership, so that ``k0`` and ``beta`` have a gradient (hypergradients, :mod:`gsjax.slam.hypergrad`); the
        rounded K and every render's value stay as they are. False: K's derivative is 0 (a step function).
    """

    alpha: float = param(0.2, "px", low=0.0, unit_by=("shift_mode", {"unit": "px", "fraction": "ratio"}))
    k0: float = param(5.0, "count", low=0.0, low_open=True)
    beta: float = param(0.3, "weight", low=0.0)
    eps: float = param(1e-6, "ratio", low=0.0, low_open=True)
    tau_t: float = param(0.05, "m", low=0.0, low_open=True)
    tau_r: float = param(5.0, "deg", low=0.0, low_open=True)
    k_min: int = param(2, "count", static=True, low=1)
    k_max: int = param(16, "count", static=True, low=1)
    cell: int = param(8, "px", static=True, low=1)
    position: bool = param(True, "flag", static=True)
    colour: bool = param(True, "flag", static=True)
    truncate: bool = param(False, "flag", static=True)
    select: str = param("first_k", "choice", static=True, choices=SELECT_MODES)
    shift_mode: str = param("unit", "choice", static=True, choices=SHIFT_MODES)
    straight_through_k: bool = param(False, "flag", static=True)

    def __post_init__(self):
        check_fields(self, "CBKNN")
        if self.k_min > self.k_max:
            raise ValueError(f"CBKNN.k_min ({self.k_min}) must not exceed k_max ({self.k_max})")


class CBKNNStats(NamedTuple):
    """CB-KNN diagnostics of one render.

    Attributes:
      k_map: [cells_y, cells_x] int32 kernel size K per cell.
      rho_map: [cells_y, cells_x] float32 normalised density (1 = mean of non-empty cells, 0 = empty).
      mean_shift_px: mean |u'_k - u_k| (px) over the corrected slots.
      fraction_fewer_than_k: fraction of image pixels with fewer contributors than their K.
    """

    k_map: jax.Array
    rho_map: jax.Array
    mean_shift_px: jax.Array
    fraction_fewer_than_k: jax.Array


def motion_from_poses(w2c_prev2: jax.Array, w2c_prev1: jax.Array, tau_t: float | jax.Array,
                      tau_r: float | jax.Array) -> jax.Array:
    """Inter-frame motion gamma in [0, 1] between the two previous world-to-camera poses (D.4 #8).

    ``gamma = clip(max(|c_1 - c_2| / tau_t, angle(R_1 R_2^T) / tau_r), 0, 1)`` with camera centres c (m) and the
    relative rotation angle in degrees; ``tau_t`` in m, ``tau_r`` in degrees. Callers use gamma = 0 before frame 2.

    Args:
      w2c_prev2: [4, 4] world-to-camera pose (m) of the frame two back (c_2, R_2).
      w2c_prev1: [4, 4] world-to-camera pose (m) of the previous frame (c_1, R_1).
      tau_t: camera-centre motion (m) that gives gamma = 1 (``CBKNN.tau_t``).
      tau_r: rotation (deg) that gives gamma = 1 (``CBKNN.tau_r``).

    Returns:
      gamma, [] float32 (the poses' dtype), in [0, 1].
    """
    translation = jnp.linalg.norm(camera_center(w2c_prev1) - camera_center(w2c_prev2))
    angle_deg = rotation_angle(w2c_prev1[:3, :3] @ w2c_prev2[:3, :3].T) * (180.0 / math.pi)
    return jnp.clip(jnp.maximum(translation / tau_t, angle_deg / tau_r), 0.0, 1.0)


def density_map(projected: Projected, height: int, width: int, cell: int) -> jax.Array:
    """rho [cells_y, cells_x]: visible Gaussian centres per cell over the mean of non-empty cells (no gradient).

    Pixel j covers u in [j - 0.5, j + 0.5), so cell c holds centres with ``floor((u + 0.5) / cell) = c``.

    Args:
      projected: the :class:`~gsjax.raster.project.Projected` Gaussians (``uv`` and ``visible`` are read); a
        visible centre counts when it lies in the image, u in [-0.5, width - 0.5) and v in [-0.5, height - 0.5).
      height: image height (px).
      width: image width (px).
      cell: cell side (px).

    Returns:
      rho [cells_y, cells_x] float32, ``cells_y = ceil(height / cell)`` and ``cells_x = ceil(width / cell)``: 0 in
        empty cells, and 0 everywhere when no visible centre is in the image.
    """
    cells_y, cells_x = math.ceil(height / cell), math.ceil(width / cell)
    uv = jax.lax.stop_gradient(projected.uv)
    inside = projected.visible & (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5)
    inside &= (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)
    col = jnp.clip(jnp.floor((uv[:, 0] + 0.5) / cell), 0, cells_x - 1).astype(jnp.int32)
    row = jnp.clip(jnp.floor((uv[:, 1] + 0.5) / cell), 0, cells_y - 1).astype(jnp.int32)
    index = jnp.where(inside, row * cells_x + col, cells_y * cells_x)
    counts = jnp.zeros(cells_y * cells_x + 1, jnp.float32).at[index].add(1.0)[:-1]
    nonempty = counts > 0
    mean = jnp.sum(counts) / jnp.maximum(jnp.sum(nonempty), 1)
    return (counts / jnp.maximum(mean, 1e-12)).reshape(cells_y, cells_x)


def kernel_size_map(rho: jax.Array, cbknn: CBKNN, motion: float | jax.Array) -> jax.Array:
    """K per cell [cells_y, cells_x]: ``clip(round(k0 max(0.5, 1 + beta gamma / (rho + eps))), k_min, k_max)``.

    ``round`` is round-half-to-even. The ratio is capped before rounding so empty cells (rho = 0) stay finite. With
    ``cbknn.straight_through_k`` K is float32 (its values the same integers) and carries the derivative of the
    unrounded, clipped ``k0 max(...)``.

    Args:
      rho: normalised density (:func:`density_map`), [cells_y, cells_x] (any shape: elementwise).
      cbknn: the configuration (``k0``, ``beta``, ``eps``, ``k_min`` and ``k_max`` are read).
      motion: inter-frame motion gamma in [0, 1] (:func:`motion_from_poses`), a scalar.

    Returns:
      K of ``rho``'s shape, int32 in [k_min, k_max] (float32 with ``straight_through_k``).
    """
    factor = jnp.maximum(0.5, 1.0 + cbknn.beta * motion / (rho + cbknn.eps))
    k = jnp.clip(jnp.round(jnp.minimum(cbknn.k0 * factor, float(cbknn.k_max) + 1.0)), cbknn.k_min, cbknn.k_max)
    if not cbknn.straight_through_k:
        return k.astype(jnp.int32)
    unrounded = jnp.clip(cbknn.k0 * factor, cbknn.k_min, cbknn.k_max)
    return k + (unrounded - jax.lax.stop_gradient(unrounded))


def pixel_cells(pixels: jax.Array, height: int, width: int, cell: int) -> jax.Array:
    """Cell index (row-major over the cell grid) of each pixel (u, v) [P, 2].

    Args:
      pixels: [P, 2] (u, v) of each pixel (px), non-negative integers (truncated to int32).
      height: image height (px).
      width: image width (px).
      cell: cell side (px).

    Returns:
      [P] int32 ``row * cells_x + col``, an index into the flattened [cells_y, cells_x] grid of :func:`density_map`;
        pixels past the image (tile padding) fall in the last row or column of cells.
    """
    cells_y, cells_x = math.ceil(height / cell), math.ceil(width / cell)
    col = jnp.clip(pixels[:, 0].astype(jnp.int32) // cell, 0, cells_x - 1)
    row = jnp.clip(pixels[:, 1].astype(jnp.int32) // cell, 0, cells_y - 1)
    return row * cells_x + col


class Corrected(NamedTuple):
    """Per-slot compositing inputs after the correction, all [K, P] (depth is unchanged).

    Attributes:
      alpha: [K, P] f'_k for the slots of G_p; the other slots keep their canonical alpha (hybrid), or 0 with
        ``truncate=True``.
      r: [K, P] red channel: G_p's consensus with colour smoothing (``colour``), else unchanged.
      g: [K, P] green channel, as ``r``.
      b: [K, P] blue channel, as ``r``.
      corrected: [K, P] bool, the slots of G_p.
      shift_px: [K, P] |u' - u| (px), 0 outside G_p or without position smoothing (no gradient).
    """

    alpha: jax.Array
    r: jax.Array
    g: jax.Array
    b: jax.Array
    corrected: jax.Array
    shift_px: jax.Array


def _safe_divide(numerator, denominator):
    """numerator / denominator, 0 where the denominator is 0 (finite gradients either way)."""
    nonzero = denominator > 0
    return jnp.where(nonzero, numerator / jnp.where(nonzero, denominator, 1.0), 0.0)


def correction_mask(slots: Slots, weights: jax.Array, k_pixel: jax.Array, cbknn: CBKNN) -> jax.Array:
    """[K, P] bool: which slots form G_p (no gradient). ``weights`` [K, P] are the canonical blend weights.

    Args:
      slots: the contributor :class:`~gsjax.raster.composite.Slots` [K, P] in depth order (only ``valid`` is
        read).
      weights: [K, P] canonical blend weights (read only with ``select="top_weight"``).
      k_pixel: [P] kernel size K_p of each pixel (int32, or float32 with ``straight_through_k``).
      cbknn: the configuration (``select`` and ``k_max`` are read).

    Returns:
      [K, P] bool, True for the valid slots of G_p: among the first K_p slots (``"first_k"``), or the K_p with the
        largest weights, at most ``k_max``, ties to the nearer slot (``"top_weight"``).
    """
    return _mask_of(slots, _slot_ranks(slots, weights, cbknn), k_pixel)


def _mask_of(slots: Slots, ranks: jax.Array, k_pixel: jax.Array) -> jax.Array:
    """[K, P] bool: the valid slots ranked below their pixel's K_p (:func:`correction_mask`)."""
    return slots.valid & (ranks < jax.lax.stop_gradient(k_pixel)[None, :])


def _slot_ranks(slots: Slots, weights: jax.Array, cbknn: CBKNN) -> jax.Array:
    """[K, P] each slot's place in G_p's order of choice (0 first): its depth order (``first_k``), or its rank by
    canonical weight (``top_weight``; slots past the ``k_max`` heaviest rank ``k_max``). No gradient."""
    num_slots = slots.valid.shape[0]
    if cbknn.select == "first_k":
        return jnp.broadcast_to(jnp.arange(num_slots)[:, None], slots.valid.shape)
    # top_weight: the k_pixel largest canonical blend weights (ties to the nearer slot), kept in depth order.
    k_top = min(cbknn.k_max, num_slots)
    key = jnp.where(slots.valid, jax.lax.stop_gradient(weights), -1.0).T  # [P, K]
    _, top = jax.lax.top_k(key, k_top)  # [P, k_top] slot positions, best first
    ranks = jnp.full(key.shape, k_top, jnp.int32).at[jnp.arange(top.shape[0])[:, None], top].set(
        jnp.arange(k_top, dtype=jnp.int32)[None, :])
    return ranks.T


def _membership_tangent(slots: Slots, ranks: jax.Array, k_pixel: jax.Array) -> jax.Array:
    """[K, P] zeros that carry the derivative of each slot's membership of G_p with respect to K_p
    (``straight_through_k``: the slot ranked K_p, the next one after G_p, enters at rate 1)."""
    ramp = jnp.clip(k_pixel[None, :] - ranks + 0.5, 0.0, 1.0)
    return jnp.where(slots.valid, ramp - jax.lax.stop_gradient(ramp), 0.0)


def correct_slots(
    slots: Slots, pixels: jax.Array, alpha: jax.Array, weights: jax.Array, k_pixel: jax.Array, cbknn: CBKNN
) -> Corrected:
    """Apply D.5 to the slots of every pixel.

    Args:
      slots: projected contributor :class:`~gsjax.raster.composite.Slots` [K, P] (depth order).
      pixels: [P, 2] (u, v) of each pixel (px).
      alpha: canonical per-slot alpha f_k [K, P] (:func:`~gsjax.raster.composite.slot_alpha`).
      weights: canonical blend weights [K, P] (:func:`~gsjax.raster.composite.blend_weights`).
      k_pixel: [P] kernel size K_p per pixel (int32, or float32 with ``straight_through_k``).
      cbknn: the configuration.

    Returns:
      The corrected slots as a :class:`Corrected`, every field [K, P], to composite with the slots' depths.
    """
    ranks = _slot_ranks(slots, weights, cbknn)
    mask = _mask_of(slots, ranks, k_pixel)
    tangent = _membership_tangent(slots, ranks, k_pixel) if cbknn.straight_through_k else None
    num_slots = alpha.shape[0]
    # first_k only ever corrects the first k_max slots (and the next one's membership only moves K_p's derivative,
    # zero at k_max): work on that prefix and pass the rest through.
    width = min(cbknn.k_max, num_slots) if cbknn.select == "first_k" else num_slots
    head = lambda x: x[:width]  # noqa: E731
    new_alpha, r, g, b, shift_px = _correct(
        jax.tree_util.tree_map(head, slots), pixels, head(alpha), head(mask), cbknn,
        None if tangent is None else head(tangent)
    )
    rest_alpha = jnp.zeros_like(alpha[width:]) if cbknn.truncate else alpha[width:]
    join = lambda first, rest: jnp.concatenate([first, rest], axis=0)  # noqa: E731
    return Corrected(
        alpha=join(new_alpha, rest_alpha),
        r=join(r, slots.r[width:]),
        g=join(g, slots.g[width:]),
        b=join(b, slots.b[width:]),
        corrected=mask,
        shift_px=join(shift_px, jnp.zeros_like(alpha[width:])),
    )


def _correct(slots: Slots, pixels, alpha, mask, cbknn: CBKNN, tangent=None):
    """D.5 on slots [W, P] with G_p given by ``mask``: (alpha', r', g', b', |shift| px), each [W, P]. ``tangent``
    (zeros, or None) carries the derivative of the slots' membership (:func:`_membership_tangent`)."""
    m = mask.astype(alpha.dtype)
    if tangent is not None:
        m = m + tangent

    def chosen(inside, outside):  # where(mask, inside, outside), its derivative in the membership too
        value = jnp.where(mask, inside, outside)
        return value if tangent is None else value + tangent * (inside - outside)

    count = jnp.sum(m, axis=0)
    centroid_u = _safe_divide(jnp.sum(m * slots.u, axis=0), count)  # [P]
    centroid_v = _safe_divide(jnp.sum(m * slots.v, axis=0), count)
    offset_u, offset_v = centroid_u[None] - slots.u, centroid_v[None] - slots.v
    scale: jax.Array | float
    if cbknn.shift_mode == "unit":
        # The direction carries no gradient: its Jacobian is singular (~1/eps) where a centre sits on C_p.
        offset_u, offset_v = jax.lax.stop_gradient(offset_u), jax.lax.stop_gradient(offset_v)
        scale = cbknn.alpha / (jnp.sqrt(offset_u * offset_u + offset_v * offset_v) + cbknn.eps)
    else:
        scale = cbknn.alpha
    shift_u, shift_v = scale * offset_u, scale * offset_v
    if cbknn.position:
        # (With the membership's derivative, the slot after G_p is shifted too: its entering is that derivative.)
        within = jnp.ones_like(mask) if tangent is not None else mask
        shifted_alpha = slot_alpha(
            slots, pixels, u=jnp.where(within, slots.u + shift_u, slots.u),
            v=jnp.where(within, slots.v + shift_v, slots.v)
        )
        shift_px = jax.lax.stop_gradient(jnp.where(mask, jnp.sqrt(shift_u * shift_u + shift_v * shift_v), 0.0))
    else:
        shifted_alpha = alpha
        shift_px = jnp.zeros_like(alpha)
    colours: tuple[jax.Array, ...] = (slots.r, slots.g, slots.b)
    if cbknn.colour:
        consensus_weights = _safe_divide(m * alpha, jnp.sum(m * alpha, axis=0, keepdims=True))
        colours = tuple(chosen(jnp.sum(consensus_weights * c, axis=0, keepdims=True), c) for c in colours)
    fallback = jnp.zeros_like(alpha) if cbknn.truncate else alpha
    return (chosen(shifted_alpha, fallback),) + colours + (shift_px,)
