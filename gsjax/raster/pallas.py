"""Pallas kernels for the rasterizer's hot path: the per-pixel front-to-back walk and the compositing.

Both are drop-in replacements for pieces of the XLA path (which stays the reference):

* :func:`walk_select`: the selection walk of :mod:`gsjax.raster.select` (alpha test, SplaTAM's stop rule, early
  termination per tile) and the extraction of each pixel's first K kept entries, one program per tile. It keeps
  the same packed "kept" bits as the XLA walk and pops them with lowest-set-bit arithmetic (the first K set bits,
  as the XLA path's popcount search finds them), so both paths select identical slots.
* :func:`composite_slots`: ``w_k = alpha_k prod_{j<k} (1 - alpha_j)`` and the blend of colour, depth, silhouette and
  depth^2 over the K slots of every pixel, with a ``custom_vjp`` whose backward kernel replays the walk front to
  back (storing T_k in the gradient buffer), then runs back to front with the suffix recurrence
  ``R_{k-1} = alpha_k v_k + (1 - alpha_k) R_k`` (no division by ``1 - alpha``). A ``custom_vjp`` has no forward
  mode: ``jax.jvp`` needs the XLA path (:meth:`gsjax.raster.RasterSettings.for_forward_mode`).

Lowering: ``pl.pallas_call`` with BlockSpecs and the Triton compiler parameters on GPU, ``interpret=True``
elsewhere. The same kernel body then runs on the pinned CPU jax (interpret mode, for the tests) and lowers on a
GPU jax; Triton handles the per-lane, data-dependent loop (the walk's early exit) that Mosaic GPU's
warpgroup model would need rewritten by hand. Every value a kernel builds is a power-of-two vector of pixels
(Triton's rule); refs may have any shape.
"""

from __future__ import annotations

import functools
import math
import warnings

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton

from gsjax.raster.project import ALPHA_MIN, gaussian_alpha

T_MIN = 1e-4  # the walk stops before transmittance would fall below this (as in gsjax.raster.select)
WORD = 32
_MAX_BLOCK = 256  # pixels per composite program


def on_gpu() -> bool:
    """Whether the default JAX backend is a GPU (where the kernels are compiled rather than interpreted).

    Returns:
      True when ``jax.default_backend()`` is ``"gpu"``.
    """
    return jax.default_backend() == "gpu"


def _call(kernel, *, grid, in_specs, out_specs, out_shape, num_warps: int):
    """``pl.pallas_call`` compiled by Triton where the program is lowered for a CUDA GPU and interpreted on any other
    platform. The lowering platform chooses (``lax.platform_dependent``), not the default backend, so a program
    compiled ahead of time for a GPU on a machine without one gets the Triton kernels (experiments/gpu_aot_check.py).
    """
    common = dict(grid=grid, in_specs=in_specs, out_specs=out_specs, out_shape=out_shape)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*[Tt]riton.*deprecated.*")
        compiled = pl.pallas_call(
            kernel, compiler_params=pltriton.CompilerParams(num_warps=num_warps, num_stages=1), **common)
        interpreted = pl.pallas_call(kernel, interpret=True, **common)
    return lambda *args: jax.lax.platform_dependent(*args, cuda=compiled, default=interpreted)


# --- selection walk ----------------------------------------------------------------------------------------------


def _walk_kernel(count_ref, u_ref, v_ref, a_ref, b_ref, c_ref, o_ref, px_ref, py_ref, bits_ref, local_ref, kept_ref,
                 t_ref, *, num_entries: int, k: int):
    px = px_ref[0, :]
    py = py_ref[0, :]
    zeros = jnp.zeros(px.shape, jnp.int32)
    num_words = num_entries // WORD
    for w in range(num_words):
        bits_ref[0, w, :] = zeros
    longest = jnp.minimum(count_ref[0], num_entries)

    def cond(state):
        m, transmittance, _ = state
        return (m < longest) & (jnp.max(transmittance) >= T_MIN)  # any pixel still open (Triton has no reduce_or)

    def body(state):
        m, transmittance, word = state
        alpha = gaussian_alpha(px - u_ref[0, m], py - v_ref[0, m], a_ref[0, m], b_ref[0, m], c_ref[0, m], o_ref[0, m])
        contributes = alpha >= ALPHA_MIN
        transmittance = jnp.where(contributes, transmittance * (1.0 - alpha), transmittance)
        keep = contributes & (transmittance >= T_MIN)
        bit = jax.lax.rem(m, WORD)
        word = word | jnp.left_shift(keep.astype(jnp.int32), bit)
        bits_ref[0, jax.lax.div(m, WORD), :] = word
        return m + 1, transmittance, jnp.where(bit == WORD - 1, zeros, word)

    init = (jnp.int32(0), jnp.ones(px.shape, jnp.float32), zeros)
    _, transmittance, _ = jax.lax.while_loop(cond, body, init)
    t_ref[0, :] = transmittance

    # First K kept entries of every pixel: pop the lowest set bit of its first non-zero word, K times, on the
    # [words, pixels] tile of bits (no gather, no scatter: each pixel's state is one column).
    words = bits_ref[0, :, :]
    kept_ref[0, :] = jnp.sum(jax.lax.population_count(words), axis=0)
    rows = jax.lax.broadcasted_iota(jnp.int32, words.shape, 0)

    def pop(slot, words):
        first = jnp.min(jnp.where(words != 0, rows, num_words), axis=0)  # num_words: none left
        at_first = rows == first[None, :]
        word = jnp.sum(jnp.where(at_first, words, 0), axis=0)
        bit = (WORD - 1) - jax.lax.clz(word & -word)  # -1 for an empty word
        local_ref[0, slot, :] = jnp.where(first < num_words, first * WORD + bit, -1)
        return jnp.where(at_first, words & (words - 1), words)

    jax.lax.fori_loop(0, k, pop, words)


def walk_select(features: tuple[jax.Array, ...], count: jax.Array, pixels: jax.Array,
                k: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The selection walk of every tile and its first ``k`` contributors, one Pallas program per tile.

    Args:
      features: tuple of six [B, M] float32 arrays (u, v, conic a, b, c, opacity) of every tile's depth-sorted
        candidates (opacity 0 for empty entries), M / 32 a power of two.
      count: [B] int32 list lengths (may exceed M: the walk stops at M).
      pixels: [B, T^2, 2] float32 pixel coordinates (u, v) of each tile's pixels.
      k: contributor slots per pixel (static).

    Returns:
      Three arrays: ``local`` [B, k, T^2] int32, the list positions of each pixel's first k kept entries in depth
        order, -1 past the last; ``num_kept`` [B, T^2] int32, the kept entries of the whole walk; and the float32
        transmittance [B, T^2] at the end of each tile's walk, which matches the XLA walk's wherever the pixel has
        not terminated.

    Raises:
      ValueError: on a GPU backend, when the tile area T^2 or the list's words M / 32 is not a power of two.
    """
    num_tiles, num_entries = features[0].shape
    per_tile = pixels.shape[1]
    words = num_entries // WORD
    if on_gpu() and not all(n & (n - 1) == 0 for n in (per_tile, words)):
        raise ValueError(f"the Pallas walk needs a power-of-two tile area and list words, got {per_tile} px, "
                         f"{words} words (RasterSettings.tile_size / tile_capacity)")
    entry = pl.BlockSpec((1, num_entries), lambda t: (t, 0))
    pixel = pl.BlockSpec((1, per_tile), lambda t: (t, 0))
    _, local, num_kept, transmittance = _call(
        functools.partial(_walk_kernel, num_entries=num_entries, k=k),
        grid=(num_tiles,),
        in_specs=[pl.BlockSpec((1,), lambda t: (t,))] + [entry] * 6 + [pixel] * 2,
        out_specs=[pl.BlockSpec((1, words, per_tile), lambda t: (t, 0, 0)),
                   pl.BlockSpec((1, k, per_tile), lambda t: (t, 0, 0)), pixel, pixel],
        out_shape=[
            jax.ShapeDtypeStruct((num_tiles, words, per_tile), jnp.int32),  # the kept bits (scratch)
            jax.ShapeDtypeStruct((num_tiles, k, per_tile), jnp.int32),
            jax.ShapeDtypeStruct((num_tiles, per_tile), jnp.int32),
            jax.ShapeDtypeStruct((num_tiles, per_tile), jnp.float32),
        ],
        num_warps=max(1, min(4, per_tile // 32)),
    )(count.astype(jnp.int32), *features, pixels[..., 0], pixels[..., 1])
    return local, num_kept, transmittance


# --- compositing -------------------------------------------------------------------------------------------------


def _block(num_pixels: int) -> int:
    """Pixels per composite program: the largest power of two <= 256 that divides the pixel count."""
    return math.gcd(num_pixels, _MAX_BLOCK)


def _composite_kernel(alpha_ref, r_ref, g_ref, b_ref, z_ref, cr_ref, cg_ref, cb_ref, d_ref, s_ref, q_ref, t_ref, *,
                      num_slots: int):
    zeros = jnp.zeros(t_ref.shape, jnp.float32)

    def body(k, carry):
        transmittance, cr, cg, cb, d, s, q = carry
        alpha = alpha_ref[k, :]
        w = alpha * transmittance
        wz = w * z_ref[k, :]
        return (transmittance * (1.0 - alpha), cr + w * r_ref[k, :], cg + w * g_ref[k, :], cb + w * b_ref[k, :],
                d + wz, s + w, q + wz * z_ref[k, :])

    init = (jnp.ones(t_ref.shape, jnp.float32),) + (zeros,) * 6
    transmittance, cr, cg, cb, d, s, q = jax.lax.fori_loop(0, num_slots, body, init)
    cr_ref[...], cg_ref[...], cb_ref[...] = cr, cg, cb
    d_ref[...], s_ref[...], q_ref[...], t_ref[...] = d, s, q, transmittance


def _composite_bwd_kernel(alpha_ref, r_ref, g_ref, b_ref, z_ref, gcr_ref, gcg_ref, gcb_ref, gd_ref, gs_ref, gq_ref,
                          gt_ref, da_ref, dr_ref, dg_ref, db_ref, dz_ref, *, num_slots: int):
    # Front to back: store T_k in the alpha-gradient buffer (read back below, then overwritten).
    def forward(k, transmittance):
        da_ref[k, :] = transmittance
        return transmittance * (1.0 - alpha_ref[k, :])

    jax.lax.fori_loop(0, num_slots, forward, jnp.ones(gt_ref.shape, jnp.float32))
    gcr, gcg, gcb, gd, gs, gq = (ref[...] for ref in (gcr_ref, gcg_ref, gcb_ref, gd_ref, gs_ref, gq_ref))

    # Back to front. v_k = dL/dw_k; R_k = the cotangent weight of everything behind slot k per unit of T_{k+1}.
    def backward(i, suffix):
        k = num_slots - 1 - i
        alpha, r, g, b, z = (ref[k, :] for ref in (alpha_ref, r_ref, g_ref, b_ref, z_ref))
        transmittance = da_ref[k, :]
        w = alpha * transmittance
        v = gcr * r + gcg * g + gcb * b + gd * z + gs + gq * z * z
        da_ref[k, :] = transmittance * (v - suffix)
        dr_ref[k, :] = w * gcr
        dg_ref[k, :] = w * gcg
        db_ref[k, :] = w * gcb
        dz_ref[k, :] = w * (gd + 2.0 * gq * z)
        return alpha * v + (1.0 - alpha) * suffix

    jax.lax.fori_loop(0, num_slots, backward, gt_ref[...])


def _slot_specs(num_slots: int, block: int):
    return pl.BlockSpec((num_slots, block), lambda i: (0, i)), pl.BlockSpec((block,), lambda i: (i,))


def _composite_forward(alpha, r, g, b, z):
    num_slots, num_pixels = alpha.shape
    block = _block(num_pixels)
    slot, pixel = _slot_specs(num_slots, block)
    out = jax.ShapeDtypeStruct((num_pixels,), jnp.float32)
    return _call(
        functools.partial(_composite_kernel, num_slots=num_slots),
        grid=(num_pixels // block,),
        in_specs=[slot] * 5,
        out_specs=[pixel] * 7,
        out_shape=[out] * 7,
        num_warps=max(1, min(4, block // 32)),
    )(alpha, r, g, b, z)


@jax.custom_vjp
def composite_slots(alpha: jax.Array, r: jax.Array, g: jax.Array, b: jax.Array,
                    z: jax.Array) -> tuple[jax.Array, ...]:
    """Front-to-back compositing of K slots per pixel, all inputs [K, P] float32 (slot-major, depth order).

    Differentiable in reverse mode (a Pallas backward kernel); no forward mode.

    Args:
      alpha: [K, P] float32 alpha of each slot (0 for an empty slot).
      r: [K, P] float32 red of each slot.
      g: [K, P] float32 green of each slot.
      b: [K, P] float32 blue of each slot.
      z: [K, P] float32 camera depth of each slot (m).

    Returns:
      Seven [P] float32 arrays, ``(color_r, color_g, color_b, depth, silhouette, depth_sq,
        final_transmittance)``: ``sum_k w_k x_k`` for x = r, g, b, z, 1 and z^2, with
        ``w_k = alpha_k prod_{j<k} (1 - alpha_j)``, and ``prod_k (1 - alpha_k)``.
    """
    return tuple(_composite_forward(alpha, r, g, b, z))


def _composite_fwd(alpha, r, g, b, z):
    return composite_slots(alpha, r, g, b, z), (alpha, r, g, b, z)


def _composite_bwd(residuals, cotangents):
    alpha, r, g, b, z = residuals
    num_slots, num_pixels = alpha.shape
    block = _block(num_pixels)
    slot, pixel = _slot_specs(num_slots, block)
    out = jax.ShapeDtypeStruct((num_slots, num_pixels), jnp.float32)
    return tuple(_call(
        functools.partial(_composite_bwd_kernel, num_slots=num_slots),
        grid=(num_pixels // block,),
        in_specs=[slot] * 5 + [pixel] * 7,
        out_specs=[slot] * 5,
        out_shape=[out] * 5,
        num_warps=max(1, min(4, block // 32)),
    )(alpha, r, g, b, z, *cotangents))


composite_slots.defvjp(_composite_fwd, _composite_bwd)
