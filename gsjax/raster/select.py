"""Per-pixel selection of the first K contributing Gaussians from the tile lists (indices only, no gradient).

Each pixel walks its tile's depth-sorted list with SplaTAM's rules: a candidate contributes when
``alpha >= 1/255``; the walk stops at the first contributor whose addition would leave ``T (1 - alpha) < 1e-4``
(that one is not added). Because transmittance only decreases, a candidate is *kept* exactly when it contributes
and the transmittance after it is still >= 1e-4.

The walk is a loop over the M list entries, 32 at a time, vectorised over all pixels of all tiles (on XLA:CPU a
loop over the list axis is several times faster than cumulative sums along it); it ends at the longest list, or as
soon as every pixel has terminated. It records one "kept" bit per (entry, pixel), packed into 32-bit words as it
goes, and the first K set bits of every pixel are extracted with popcount arithmetic (:func:`first_set_bits`),
which is far cheaper on CPU than a scatter-based compaction.

Truncation is measured, never silent: a pixel with more than K kept contributors, or whose walk reached the end
of an incomplete tile list (capacity overflow) without stopping, is flagged, with the transmittance at the cut.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.raster import pallas
from gsjax.raster.binning import TileGrid, TileLists
from gsjax.raster.project import ALPHA_MIN, Projected, gaussian_alpha

T_MIN = pallas.T_MIN  # the walk stops before transmittance would fall below this
_WORD = pallas.WORD


class Selection(NamedTuple):
    """First-K contributors of every pixel, P = num_tiles * tile_size^2 pixels in tile-major order.

    Attributes:
      ids: [K, P] int32 Gaussian indices in depth order, slot-major; -1 marks an empty slot.
      num_kept: [P] int32 contributors before the stop rule (counted through the whole tile list, can exceed K).
      out_of_k: [P] bool, more than K contributors: the walk is cut after the K-th (the transmittance left there
        is the compositing's final transmittance).
      cut_by_list: [P] bool, the walk reached the end of an incomplete tile list without stopping.
      residual_list: [P] float32 transmittance left at the end of the list (meaningful where ``cut_by_list``).
    """

    ids: jax.Array
    num_kept: jax.Array
    out_of_k: jax.Array
    cut_by_list: jax.Array
    residual_list: jax.Array


def first_set_bits(words: jax.Array, k: int) -> jax.Array:
    """Positions of the first ``k`` set bits of P bit strings, each packed into W 32-bit words.

    Slot s lies in the first word whose running popcount exceeds s; its position there is found by a binary
    search on the popcounts of the word's halves. All of it is elementwise over [k, P] with a short unrolled loop
    over the W words: one vectorised pass, several times faster on XLA:CPU than popping the lowest set bit k times.
    It runs inside a loop of at most one pass (none when no bit is set), whose output XLA materialises: fused
    into the gathers that read the positions, the same arithmetic runs unvectorised, several times slower.

    Args:
      words: [W, P] uint32 bit strings, one per column: bit j (least significant first) of word w is position
        ``32 w + j``.
      k: number of set bits to find per string (static).

    Returns:
      [k, P] int32 positions of each string's first ``k`` set bits in increasing order; -1 past its last set bit.
    """
    num_words = words.shape[0]
    counts = jax.lax.population_count(words).astype(jnp.int32)
    running = jnp.cumsum(counts, axis=0)  # [W, P] set bits up to and including each word
    total = running[-1]

    def positions():
        slot = jnp.arange(k, dtype=jnp.int32)[:, None]
        index = jnp.zeros((k,) + words.shape[1:], jnp.int32)  # the word holding the slot
        rank = slot  # the slot's rank among the set bits of that word
        for w in range(num_words):
            past = running[w][None] <= slot  # every set bit up to word w comes before the slot
            index = index + past.astype(jnp.int32)
            rank = rank - jnp.where(past, counts[w][None], 0)
        word = jnp.zeros(index.shape, jnp.uint32)
        for w in range(num_words):
            word = jnp.where(index == w, words[w][None], word)
        bit = jnp.zeros_like(rank)
        for half in (16, 8, 4, 2, 1):
            mask = jnp.uint32((1 << half) - 1)
            low = jax.lax.population_count(word & mask).astype(jnp.int32)
            upper = rank >= low
            rank = jnp.where(upper, rank - low, rank)
            word = jnp.where(upper, word >> half, word & mask)
            bit = bit + jnp.where(upper, half, 0)
        return jnp.where(slot < total[None], index * _WORD + bit, -1)

    def cond(state):
        done, _ = state
        return ~done & jnp.any(total > 0)

    out = jnp.full((k,) + words.shape[1:], -1, jnp.int32)
    return jax.lax.while_loop(cond, lambda state: (jnp.bool_(True), positions()), (jnp.bool_(False), out))[1]


def _walk(features, ids, count, pixels, incomplete, k):
    """Tiles [b]: features [b, M, 6] = (u, v, a, b, c, opacity), ids [b, M], count [b] list lengths,
    pixels [b, T^2, 2], incomplete [b]. A while loop over the list's 32-entry words (forward only, no gradient)
    that stops at the longest list, or earlier once every pixel has terminated. Returns :func:`_first_k`'s tuple.

    Each step walks one word of 32 entries for every pixel: the 32 alphas as one op [32, b, T^2], then the
    transmittance product in list order and the packing of the kept bits as one unrolled chain that XLA fuses into a
    single loop: the same float32 operations in the same order as an entry-by-entry walk (so the same bits), with 32x
    fewer loop steps, each a single pass over the pixels. (Written as 32 separate alpha evaluations, XLA:CPU compiled
    each into its own kernel: a render's program had 142 fusions instead of 99 and took ~1.5x as long to compile.)
    Per-pixel state is laid out [b, T^2] (tile features broadcast along the minor axis): on XLA:CPU this is about 5x
    faster than [T^2, b] for 8x8 tiles.
    """
    shape = pixels.shape[:2]
    num_words = features.shape[1] // _WORD
    longest = (jnp.minimum(jnp.max(count), features.shape[1]) + _WORD - 1) // _WORD
    # [6, num_words, 32, b]: one contiguous block of tile features per quantity and word.
    entries = jnp.transpose(features.reshape(shape[0], num_words, _WORD, 6), (3, 1, 2, 0))
    px, py = pixels[..., 0], pixels[..., 1]

    def cond(state):
        w, transmittance, _ = state
        return (w < longest) & jnp.any(transmittance >= T_MIN)

    def body(state):
        w, transmittance, words = state
        u, v, a, b, c, o = jax.lax.dynamic_index_in_dim(entries, w, axis=1, keepdims=False)[..., None]
        alphas = gaussian_alpha(px - u, py - v, a, b, c, o)  # [32, b, T^2]
        word = jnp.zeros(shape, jnp.uint32)
        for j in range(_WORD):
            alpha = alphas[j]
            contributes = alpha >= ALPHA_MIN  # empty entries have opacity 0
            # SplaTAM's test: the running product T (1 - alpha) in float32 (it only decreases; underflow is harmless).
            transmittance = jnp.where(contributes, transmittance * (1.0 - alpha), transmittance)
            keep = contributes & (transmittance >= T_MIN)
            word = word | (keep.astype(jnp.uint32) << j)
        return w + 1, transmittance, jax.lax.dynamic_update_index_in_dim(words, word, w, axis=0)

    init = (jnp.int32(0), jnp.ones(shape, jnp.float32), jnp.zeros((num_words,) + shape, jnp.uint32))
    _, transmittance, words = jax.lax.while_loop(cond, body, init)
    return _first_k(words.reshape(num_words, -1), transmittance, ids, incomplete, k)


def _first_k(words, transmittance, ids, incomplete, k):
    """From the kept bits of a walk, words [M / 32, b * T^2] (uint32), and the transmittance [b, T^2] at its end:
    :func:`_selected`'s tuple."""
    shape = transmittance.shape
    num_kept = jnp.sum(jax.lax.population_count(words), axis=0).astype(jnp.int32).reshape(shape)
    local = first_set_bits(words, k).reshape((k,) + shape)  # [k, b, T^2]
    return _selected(local, num_kept, transmittance, ids, incomplete, k)


def _selected(local, num_kept, transmittance, ids, incomplete, k):
    """From each pixel's first-k list positions ``local`` [k, b, T^2] (-1 past the last), its kept count and the
    transmittance [b, T^2] at the end of its walk: the selected ids [k, b, T^2] (slot-major, as the composite
    reads them) and, per pixel [b, T^2], num_kept, out_of_k, cut_by_list and that transmittance."""
    shape = transmittance.shape
    num_entries = ids.shape[1]
    # transmittance includes the contributor that triggered the stop (and any later ones), so a pixel terminated
    # exactly when its final transmittance is below the threshold.
    terminated = transmittance < T_MIN
    # Each tile's list gets a -1 entry at its end, which empty slots read: the ids are then one gather of the
    # positions, which XLA materialises once (a where on ``local`` after it would be fused, and the extraction
    # recomputed, into every consumer of the ids).
    padded = jnp.pad(ids, ((0, 0), (0, 1)), constant_values=-1)
    position = jnp.where(local >= 0, local, num_entries)
    flat_index = jnp.arange(shape[0], dtype=jnp.int32)[None, :, None] * (num_entries + 1) + position
    selected = padded.reshape(-1)[flat_index]  # [k, b, T^2] slot-major
    out_of_k = num_kept > k
    cut_by_list = incomplete[:, None] & ~terminated & ~out_of_k
    return selected, num_kept, out_of_k, cut_by_list, transmittance


def _walk_pallas(features, ids, count, pixels, incomplete, k):
    """:func:`_walk` as one Pallas kernel (:func:`gsjax.raster.pallas.walk_select`, one program per tile, the
    first-k extraction included). The transmittance differs from the XLA walk's only where a pixel terminated (a
    tile stops at its own end). The lists are padded to a power-of-two number of 32-bit words (Triton's shapes)."""
    words = ids.shape[1] // _WORD
    pad = _WORD * (1 << (words - 1).bit_length()) - ids.shape[1]
    features = jnp.pad(features, ((0, 0), (0, pad), (0, 0)))
    ids = jnp.pad(ids, ((0, 0), (0, pad)), constant_values=-1)
    local, num_kept, transmittance = pallas.walk_select(tuple(jnp.moveaxis(features, -1, 0)), count, pixels, k)
    return _selected(jnp.moveaxis(local, 1, 0), num_kept, transmittance, ids, incomplete, k)


def select_contributors(
    projected: Projected, tiles: TileLists, grid: TileGrid, k: int, tiles_per_batch: int, use_pallas: bool = False
) -> Selection:
    """First ``k`` contributors of every pixel of ``grid``: the XLA walk processes ``tiles_per_batch`` tiles at a
    time; with ``use_pallas`` the walk is a Pallas kernel over all tiles (its state is per program, so no batching).

    Args:
      projected: the projected Gaussians (``uv``, ``conic`` and ``opacity`` are read; no gradient flows).
      tiles: the depth-sorted tile lists of ``grid`` (:func:`gsjax.raster.binning.bin_gaussians`).
      grid: the tile grid of the image.
      k: contributor slots per pixel (``max_contributors``).
      tiles_per_batch: most tiles the XLA walk processes at a time (bounds its memory; ignored with
        ``use_pallas``).
      use_pallas: walk with the Pallas kernel (:func:`gsjax.raster.pallas.walk_select`) instead of XLA.

    Returns:
      The first-k contributors of the P = ``grid.num_tiles * tile_size^2`` pixels, tile-major, as a
        :class:`Selection`.
    """
    table = jax.lax.stop_gradient(
        jnp.concatenate([projected.uv, projected.conic, projected.opacity[:, None]], axis=-1)
    )
    ids = tiles.ids
    pad = -ids.shape[1] % _WORD
    ids = jnp.pad(ids, ((0, 0), (0, pad)), constant_values=-1)
    features = jnp.where((ids >= 0)[..., None], table[jnp.maximum(ids, 0)], 0.0)  # [B, M, 6]
    args: tuple[jax.Array, jax.Array, jax.Array, jax.Array, jax.Array] = (
        features, ids, tiles.count, grid.pixel_coords(), tiles.incomplete())
    # Bound memory on large images: at most tiles_per_batch tiles at a time, in equal batches (least padding).
    num_batches = -(-grid.num_tiles // tiles_per_batch)
    batch = -(-grid.num_tiles // num_batches)
    if use_pallas:
        selected, *per_pixel = _walk_pallas(*args, k=k)
    elif num_batches == 1:
        selected, *per_pixel = _walk(*args, k=k)
    else:
        fill = num_batches * batch - grid.num_tiles
        padded = jax.tree_util.tree_map(lambda x: jnp.pad(x, [(0, fill)] + [(0, 0)] * (x.ndim - 1)), args)
        batched = jax.tree_util.tree_map(lambda x: x.reshape((num_batches, batch) + x.shape[1:]), padded)
        selected, *per_pixel = jax.lax.map(lambda a: _walk(*a, k=k), batched)  # type: ignore[misc]  # a: 5 arrays
        selected = jnp.moveaxis(selected, 0, 1).reshape((k, -1) + selected.shape[3:])[:, : grid.num_tiles]
        per_pixel = [x.reshape((-1,) + x.shape[2:])[: grid.num_tiles] for x in per_pixel]
    num_pixels = grid.num_tiles * grid.pixels_per_tile
    return Selection(selected.reshape(k, num_pixels), *(x.reshape(num_pixels) for x in per_pixel))
