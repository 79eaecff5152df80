"""Tile binning: which Gaussians may touch each tile, as fixed-capacity, depth-sorted candidate lists (no grad).

Each visible Gaussian is expanded into one (tile, Gaussian) intersection per tile its contribution box covers,
in increasing depth; a stable sort by tile id then leaves every tile's intersections in depth order. Shapes are
static: at most ``intersection_capacity`` intersections (the farthest are dropped first, and counted) and at most
``tile_capacity`` candidates per tile (the farthest dropped; ``count`` keeps the true number).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class TileGrid:
    """A grid of square tiles covering an image (static shapes).

    Attributes:
      tile_size: tile side (px).
      tiles_x: number of tiles across, ``ceil(width / tile_size)`` from :meth:`for_image` (the last column of tiles
        may extend past the image).
      tiles_y: number of tiles down, ``ceil(height / tile_size)`` from :meth:`for_image` (the last row of tiles may
        extend past the image).
      width: image width (px).
      height: image height (px).
    """

    tile_size: int
    tiles_x: int
    tiles_y: int
    width: int
    height: int

    @staticmethod
    def for_image(height: int, width: int, tile_size: int) -> "TileGrid":
        """The fewest tiles of side ``tile_size`` that cover a ``height x width`` image.

        Args:
          height: image height (px).
          width: image width (px).
          tile_size: tile side (px).

        Returns:
          A grid of ``ceil(width / tile_size) x ceil(height / tile_size)`` tiles (across x down).
        """
        return TileGrid(tile_size, math.ceil(width / tile_size), math.ceil(height / tile_size), width, height)

    @property
    def num_tiles(self) -> int:
        """Number of tiles, ``tiles_x * tiles_y`` (static)."""
        return self.tiles_x * self.tiles_y

    @property
    def pixels_per_tile(self) -> int:
        """Pixels per tile, ``tile_size^2`` (static)."""
        return self.tile_size * self.tile_size

    def pixel_coords(self) -> jax.Array:
        """(u, v) of every pixel of the grid, tile-major then row-major within a tile (pixel centres at integers).

        Returns:
          [num_tiles, tile_size^2, 2] float32 (u, v) (px), padding pixels past the image included.
        """
        t = self.tile_size
        local_v, local_u = jnp.divmod(jnp.arange(t * t), t)
        tile_y, tile_x = jnp.divmod(jnp.arange(self.num_tiles), self.tiles_x)
        u = tile_x[:, None] * t + local_u[None, :]
        v = tile_y[:, None] * t + local_v[None, :]
        return jnp.stack([u, v], axis=-1).astype(jnp.float32)

    def untile(self, values: jax.Array) -> jax.Array:
        """[num_tiles * tile_size^2, ...] in tile-major order -> [height, width, ...] (padding cropped).

        Args:
          values: [num_tiles * tile_size^2, ...] per-pixel values in the order of :meth:`pixel_coords`.

        Returns:
          [height, width, ...] image of ``values`` (same dtype), the padding pixels past the image dropped.
        """
        t = self.tile_size
        rest = values.shape[1:]
        grid = values.reshape((self.tiles_y, self.tiles_x, t, t) + rest)
        grid = jnp.moveaxis(grid, 2, 1).reshape((self.tiles_y * t, self.tiles_x * t) + rest)
        return grid[: self.height, : self.width]

    def in_image(self) -> jax.Array:
        """Which tile-major pixels lie inside the image (not padding).

        Returns:
          [num_tiles * tile_size^2] bool, in the order of :meth:`pixel_coords`.
        """
        uv = self.pixel_coords().reshape(-1, 2)
        return (uv[:, 0] < self.width) & (uv[:, 1] < self.height)


class TileLists(NamedTuple):
    """Per-tile candidate lists.

    Attributes:
      ids: [num_tiles, tile_capacity] int32 Gaussian indices in increasing depth; -1 marks an empty entry.
      count: [num_tiles] int32 number of intersections binned to the tile (may exceed tile_capacity).
      intersections: scalar int32, total intersections of visible Gaussians with tiles.
      intersections_dropped: scalar int32, intersections beyond ``intersection_capacity`` (the farthest).
    """

    ids: jax.Array
    count: jax.Array  # type: ignore[assignment]  # shadows tuple.count: the name is public
    intersections: jax.Array
    intersections_dropped: jax.Array

    def incomplete(self) -> jax.Array:
        """Which tiles' lists may be missing candidates behind their last entry.

        Returns:
          [num_tiles] bool: True where ``count`` exceeds the list length (tile_capacity) or any intersection was
            dropped (``intersections_dropped > 0``, then every tile).
        """
        capacity = self.ids.shape[-1]
        return (self.count > capacity) | (self.intersections_dropped > 0)


def tile_ranges(uv: jax.Array, extent: jax.Array, grid: TileGrid) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Inclusive tile ranges covered by each Gaussian's box: (lo [N, 2], hi [N, 2]) tile (x, y), and [N] non-empty.

    A pixel j is covered when ``u - extent <= j <= u + extent``; boxes are clipped to the image.

    Args:
      uv: [N, 2] box centres (u, v) (px).
      extent: [N, 2] box half-width and half-height (px).
      grid: the tile grid.

    Returns:
      Three arrays, lo [N, 2] int32 and hi [N, 2] int32, the first and last tile (x, y) covered, and nonempty [N]
        bool, whether the box covers any image pixel (where False, lo and hi are meaningless).
    """
    size = jnp.array([grid.width - 1, grid.height - 1], jnp.float32)
    first = jnp.clip(jnp.ceil(uv - extent), 0.0, size)
    last = jnp.clip(jnp.floor(uv + extent), 0.0, size)
    nonempty = jnp.all(jnp.ceil(uv - extent) <= jnp.floor(uv + extent), axis=-1)
    nonempty &= jnp.all((uv + extent >= 0.0) & (uv - extent <= size), axis=-1)
    lo = first.astype(jnp.int32) // grid.tile_size
    hi = last.astype(jnp.int32) // grid.tile_size
    return lo, hi, nonempty


def _sort_pairs(tile: jax.Array, rank: jax.Array, num_tiles: int, n: int) -> tuple[jax.Array, jax.Array]:
    """Sort (tile, depth rank) pairs lexicographically. One packed integer key when it fits (several times faster
    on XLA:CPU than a two-key sort), else a two-key sort. Invalid pairs carry tile == num_tiles."""
    span = (num_tiles + 1) * n
    if span <= 2**32 - 1:
        dtype = jnp.int32 if span <= 2**31 - 1 else jnp.uint32
        packed = jax.lax.sort(tile.astype(dtype) * dtype(n) + rank.astype(dtype))
        return (packed // dtype(n)).astype(jnp.int32), (packed % dtype(n)).astype(jnp.int32)
    tile_sorted, rank_sorted = jax.lax.sort((tile, rank), num_keys=2)
    return tile_sorted, rank_sorted


def bin_gaussians(
    uv: jax.Array,
    extent: jax.Array,
    depth: jax.Array,
    visible: jax.Array,
    grid: TileGrid,
    tile_capacity: int,
    intersection_capacity: int,
) -> TileLists:
    """Depth-sorted, fixed-capacity candidate lists per tile.

    Args:
      uv: [N, 2] centres (px).
      extent: [N, 2] box half sizes (px).
      depth: [N] camera z (m, > 0 where visible).
      visible: [N] bool, which Gaussians to bin.
      grid: the tile grid.
      tile_capacity: list length M per tile (static).
      intersection_capacity: static bound on the total number of (tile, Gaussian) pairs.

    Returns:
      Candidate lists of the ``grid.num_tiles`` tiles as a :class:`TileLists`, ids [num_tiles, tile_capacity] (no
        gradient).
    """
    uv, extent, depth = (jax.lax.stop_gradient(x) for x in (uv, extent, depth))
    n = uv.shape[0]
    lo, hi, nonempty = tile_ranges(uv, extent, grid)
    visible = visible & nonempty
    span = hi - lo + 1  # [N, 2] tiles across / down
    counts = jnp.where(visible, span[:, 0] * span[:, 1], 0)

    # Depth order (ties by index). Positive float32 bit patterns order like the integers they spell.
    depth_key = jnp.where(visible, jax.lax.bitcast_convert_type(depth, jnp.int32), jnp.iinfo(jnp.int32).max)
    order = jax.lax.sort((depth_key, jnp.arange(n, dtype=jnp.int32)), num_keys=1, is_stable=True)[1]
    sorted_counts = counts[order]
    ends = jnp.cumsum(sorted_counts)  # exclusive end of each Gaussian's run of intersection slots
    total = ends[-1]

    # Expand: slot l belongs to the depth rank r with ends[r-1] <= l < ends[r], i.e. r = #{ends <= l}.
    capacity = intersection_capacity
    slot = jnp.arange(capacity, dtype=jnp.int32)
    rank = jnp.cumsum(jnp.zeros(capacity + 1, jnp.int32).at[jnp.minimum(ends, capacity)].add(1))[:capacity]
    rank = jnp.minimum(rank, n - 1)
    gid = order[rank]
    local = slot - (ends[rank] - sorted_counts[rank])
    across = span[gid, 0]
    tile_x = lo[gid, 0] + local % across
    tile_y = lo[gid, 1] + local // across
    valid = slot < total
    tile = jnp.where(valid, tile_y * grid.tiles_x + tile_x, grid.num_tiles)

    tile_sorted, rank_sorted = _sort_pairs(tile, rank, grid.num_tiles, n)
    per_tile = jnp.zeros(grid.num_tiles + 1, jnp.int32).at[tile].add(1)[: grid.num_tiles]
    starts = jnp.cumsum(per_tile) - per_tile
    entry = jnp.arange(tile_capacity, dtype=jnp.int32)
    pos = jnp.minimum(starts[:, None] + entry[None, :], capacity - 1)
    ids = jnp.where(entry[None, :] < per_tile[:, None], order[rank_sorted[pos]], -1)
    dropped = jnp.maximum(total - capacity, 0)
    return TileLists(ids.astype(jnp.int32), per_tile, total, dropped)
