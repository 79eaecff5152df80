"""``RasterSettings``: the rasterizer's settings (tile size and capacities, contributor slots, batching, near plane,
dilation, backend); shape parameters static, the rest traced."""

from __future__ import annotations

import dataclasses
import math

import jax

from gsjax.config.fields import check_fields, param
from gsjax.raster import pallas
from gsjax.raster.binning import TileGrid
from gsjax.raster.project import DILATION

BACKENDS = ("auto", "xla", "pallas")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RasterSettings:
    """Rasterizer settings. Shape parameters are static; ``near`` is a traced value.

    Attributes:
      tile_size: tile side (px).
      tile_capacity: M, depth-sorted candidates kept per tile.
      max_contributors: K, contributor slots per pixel (the first K along the front-to-back walk).
      intersections_per_gaussian: a in the size of the static buffer of (tile, Gaussian) pairs,
        ``L = max(min(ceil(a N), ceil(b H W)), min(N, tile_capacity) * num_tiles)`` for N slots: a few per Gaussian,
        bounded by a few per pixel when the map holds many more Gaussians than are in view (a SLAM map's capacity),
        and never less than every tile's full list when N is small. Pairs beyond L (the farthest) are counted
        in the stats.
      intersections_per_pixel: b in that size L, pairs per pixel (see ``intersections_per_gaussian``).
      tiles_per_batch: at most this many tiles are processed together in the XLA selection pass (bounds its
        memory; the tiles are split into equal batches).
      near: near-plane distance (m); Gaussians with camera z <= near are culled.
      slots_per_batch: at most this many per-pixel slots (K x pixels) are composited together; larger images are
        composited in equal batches of tiles, each recomputed in the backward pass, so the slot arrays' memory is
        bounded whatever the image size (at the cost of a second forward of the compositing).
      backend: ``"xla"`` (the reference), ``"pallas"`` (Pallas kernels for the selection walk and the compositing;
        compiled on a GPU, interpreted elsewhere, which is slow and meant for tests) or ``"auto"`` (pallas on a
        GPU, xla elsewhere). Same outputs either way; the pallas path has no forward mode (see
        :meth:`for_forward_mode`), and compiled for a GPU it needs a power-of-two tile area (8x8, 16x16).
      pose_only: the map is held fixed: no gradient reaches the Gaussians, only ``w2c`` (tracking). The slots are
        then projected from the Gaussians' raw parameters per slot (:func:`gsjax.raster.composite.splat_slots`)
        instead of gathered from a per-Gaussian projection, so the backward pass needs no scatter-add into the N
        Gaussians. The same render either way.
      dilation: px^2 added to every 2D covariance (3DGS's low-pass filter, 0.3), traced. Rendering every other
        pixel of an image exactly (a strided grid: focal lengths and principal point halved, see
        :func:`gsjax.camera.Intrinsics.strided`) takes a quarter of it. It stays when a preset changes width (a
        property of the pixel grid, not of the scene).

    The defaults render dense SplaTAM-like maps without truncation (measured in ``experiments/raster_defaults.py``);
    whatever the settings, truncation is reported in ``Render.stats``.
    """

    tile_size: int = param(8, "px", static=True, low=1)
    tile_capacity: int = param(512, "count", static=True, low=1)
    max_contributors: int = param(64, "count", static=True, low=1)
    intersections_per_gaussian: float = param(4.0, "ratio", static=True, low=0.0, low_open=True)
    intersections_per_pixel: float = param(16.0, "ratio", static=True, low=0.0, low_open=True)
    tiles_per_batch: int = param(512, "count", static=True, low=1)
    near: float = param(0.2, "m", low=0.0, low_open=True)
    slots_per_batch: int = param(1 << 25, "count", static=True, low=1)
    backend: str = param("auto", "choice", static=True, choices=BACKENDS)
    pose_only: bool = param(False, "flag", static=True)
    dilation: float = param(DILATION, "px^2", low=0.0)

    def __post_init__(self):
        check_fields(self, "RasterSettings")

    @property
    def uses_pallas(self) -> bool:
        """Whether renders run the Pallas kernels (``"pallas"``, or ``"auto"`` on a GPU)."""
        return self.backend == "pallas" or (self.backend == "auto" and pallas.on_gpu())

    def for_forward_mode(self) -> "RasterSettings":
        """These settings for forward-mode differentiation: ``jax.jvp``/``jax.jacfwd`` need the XLA path (the
        Pallas compositing is a ``custom_vjp``). The two paths give the same renders.

        Returns:
          A copy with ``backend="xla"`` when these settings would use Pallas, else these settings.
        """
        return dataclasses.replace(self, backend="xla") if self.uses_pallas else self

    def intersection_capacity(self, num_gaussians: int, grid: TileGrid) -> int:
        """The static number L of (tile, Gaussian) pairs binned (see ``intersections_per_gaussian``).

        Args:
          num_gaussians: N, the map's slots.
          grid: the image's tile grid (its size and number of tiles).

        Returns:
          L, a Python int.
        """
        per_gaussian = math.ceil(self.intersections_per_gaussian * num_gaussians)
        per_pixel = math.ceil(self.intersections_per_pixel * grid.width * grid.height)
        full_lists = min(num_gaussians, self.tile_capacity) * grid.num_tiles
        return max(min(per_gaussian, per_pixel), full_lists)
