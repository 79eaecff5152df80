"""How large must the tile capacity M and the per-pixel slot count K be? Measured on realistic dense maps.

For each map variant of ``maps.py`` (fresh SplaTAM init, mapped with semi-transparent edges, a receding camera,
three semi-transparent layers) and each resolution, this prints what an exact render needs -- the largest tile
list, the largest number of contributors per pixel before the stop rule, and the fraction of pixels that never
reach T < 1e-4 (those need their whole tile list) -- and then, for candidate settings, how many pixels each
truncates and the largest transmittance lost at a cut.

    python experiments/raster_defaults.py [--sizes 80x60,160x120,320x240]
"""

from __future__ import annotations

import argparse

import numpy as np

from gsjax.app.runtime.cache import enable_compilation_cache
from gsjax.data.room import dense_surface_map
from gsjax.raster import RasterSettings, render

VARIANTS = ("fresh", "mapped", "receding", "layered")
CANDIDATES = (
    dict(tile_size=8, tile_capacity=128, max_contributors=32),
    dict(tile_size=8, tile_capacity=256, max_contributors=64),
    dict(tile_size=8, tile_capacity=512, max_contributors=64),  # the defaults
    dict(tile_size=8, tile_capacity=768, max_contributors=128),
    dict(tile_size=4, tile_capacity=256, max_contributors=64),
)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="80x60,160x120,320x240")
    args = parser.parse_args(argv)
    enable_compilation_cache()
    print(f"default settings: {RasterSettings()}\n")
    exact = RasterSettings(tile_capacity=2048, max_contributors=256, intersections_per_gaussian=16.0)
    header = f"{'variant':9s} {'size':8s} {'gaussians':>9s} | needs: {'max tile list':>13s} {'max contrib':>11s} " \
             f"{'p99 contrib':>11s} {'never T<1e-4':>12s}"
    print(header)
    rows = []
    for variant in VARIANTS:
        for size in args.sizes.split(","):
            width, height = (int(x) for x in size.split("x"))
            gaussians, w2c, intrinsics = dense_surface_map(height, width, variant)
            out = render(gaussians, w2c, intrinsics, exact)
            assert not bool(out.stats.truncated), "the exact reference settings truncated"
            # Largest tile list and the per-pixel contributor distribution, from the exact render's internals.
            from gsjax.raster.binning import TileGrid, bin_gaussians
            from gsjax.raster.project import project
            from gsjax.raster.select import select_contributors

            grid = TileGrid.for_image(height, width, exact.tile_size)
            projected = project(gaussians, w2c, intrinsics, exact.near)
            tiles = bin_gaussians(projected.uv, projected.extent, projected.depth, projected.visible, grid,
                                  exact.tile_capacity, exact.intersection_capacity(gaussians.capacity, grid))
            sel = select_contributors(projected, tiles, grid, exact.max_contributors, exact.tiles_per_batch)
            kept = np.asarray(sel.num_kept)[np.asarray(grid.in_image())]
            sil = np.asarray(out.silhouette)
            print(f"{variant:9s} {size:8s} {int(gaussians.num_active()):9d} | {'':6s} {int(tiles.count.max()):13d} "
                  f"{int(kept.max()):11d} {np.percentile(kept, 99):11.0f} {np.mean(sil < 1 - 1e-4):12.3f}")
            for cand in CANDIDATES:
                s = RasterSettings(**cand)
                st = render(gaussians, w2c, intrinsics, s).stats
                rows.append((variant, size, cand, int(st.tiles_overflowed), int(st.pixels_out_of_k),
                             int(st.pixels_truncated), float(st.max_residual_transmittance)))
    print(f"\n{'variant':9s} {'size':8s} {'T':>2s} {'M':>4s} {'K':>4s} | {'tiles over M':>12s} {'px out of K':>11s} "
          f"{'px truncated':>12s} {'max residual T':>14s}")
    for variant, size, cand, over, out_k, trunc, resid in rows:
        print(f"{variant:9s} {size:8s} {cand['tile_size']:2d} {cand['tile_capacity']:4d} {cand['max_contributors']:4d} "
              f"| {over:12d} {out_k:11d} {trunc:12d} {resid:14.2e}")


if __name__ == "__main__":
    main()
