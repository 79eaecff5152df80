"""Rasterizer throughput: forward and forward+backward per render on a SplaTAM-density map.

Prints, per resolution: compile time (fwd, fwd+bwd), the median of repeated runs after warm-up (fwd, fwd+bwd w.r.t. all
fields and the pose, and fwd+bwd w.r.t. the pose only as tracking uses it), the candidates
per pixel (the mean length of the depth-sorted tile lists, capped at M, and the longest list, which bounds the
selection loop), the fwd+bwd cost per pixel-candidate (time / (pixels x mean list length)), and the peak resident
memory of the process.

    python experiments/bench_raster.py [--sizes 80x60,160x120,320x240,640x480] [--variant mapped] [--repeats 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import time

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.bench import weighted_outputs
from gsjax.data.room import dense_surface_map
from gsjax.raster import RasterSettings, render
from gsjax.raster.binning import TileGrid, bin_gaussians
from gsjax.raster.project import project


def _timed(fn, *args, repeats: int):
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return first, float(np.median(times))


def bench(width: int, height: int, variant: str, settings: RasterSettings, repeats: int) -> dict:
    gaussians, w2c, intrinsics = dense_surface_map(height, width, variant)
    weights = jax.random.normal(jax.random.PRNGKey(0), (height, width, 6))

    def loss(means, rgb, logit_opacities, log_scales, delta):
        g = gaussians.__class__(means, log_scales, logit_opacities, rgb, gaussians.active)
        from gsjax.camera import se3_exp

        out = render(g, se3_exp(delta) @ w2c, intrinsics, settings)
        return weighted_outputs(out, weights)

    params = (gaussians.means, gaussians.rgb, gaussians.logit_opacities, gaussians.log_scales, jnp.zeros(6))
    fwd = jax.jit(lambda g, w: render(g, w, intrinsics, settings))
    fwd_bwd = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2, 3, 4)))
    compile_fwd, t_fwd = _timed(fwd, gaussians, w2c, repeats=repeats)
    compile_bwd, t_bwd = _timed(fwd_bwd, *params, repeats=repeats)
    def pose_loss(delta):  # tracking: the gradient w.r.t. the pose only, on the pose_only path tracking uses
        from gsjax.camera import se3_exp

        out = render(gaussians, se3_exp(delta) @ w2c, intrinsics, dataclasses.replace(settings, pose_only=True))
        return weighted_outputs(out, weights)

    pose_bwd = jax.jit(jax.value_and_grad(pose_loss))
    _, t_pose = _timed(pose_bwd, jnp.zeros(6), repeats=repeats)
    stats = fwd(gaussians, w2c).stats
    pixels = width * height
    grid = TileGrid.for_image(height, width, settings.tile_size)
    projected = project(gaussians, w2c, intrinsics, settings.near)
    tiles = bin_gaussians(projected.uv, projected.extent, projected.depth, projected.visible, grid,
                          settings.tile_capacity, settings.intersection_capacity(gaussians.capacity, grid))
    lengths = np.minimum(np.asarray(tiles.count), settings.tile_capacity)
    return dict(
        size=f"{width}x{height}",
        gaussians=int(gaussians.num_active()),
        mean_list=float(lengths.mean()),
        longest=int(lengths.max()),
        k=settings.max_contributors,
        compile_s=compile_fwd + compile_bwd,
        fwd_ms=1e3 * t_fwd,
        fwd_bwd_ms=1e3 * t_bwd,
        pose_fwd_bwd_ms=1e3 * t_pose,
        ns_per_px_cand=1e9 * t_bwd / (pixels * float(lengths.mean())),
        truncated_px=int(stats.pixels_truncated),
        max_contrib=int(stats.max_contributors),
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="80x60,160x120,320x240,640x480")
    parser.add_argument("--variant", default="mapped", choices=["fresh", "mapped", "layered"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tile-size", type=int, default=RasterSettings().tile_size)
    parser.add_argument("--tile-capacity", type=int, default=RasterSettings().tile_capacity)
    parser.add_argument("--k", type=int, default=RasterSettings().max_contributors)
    args = parser.parse_args(argv)
    # No persistent compilation cache here: the compile column measures real compilation.
    settings = RasterSettings(tile_size=args.tile_size, tile_capacity=args.tile_capacity, max_contributors=args.k)
    print(f"backend={jax.default_backend()} devices={jax.devices()} variant={args.variant} settings={settings}")
    print(f"median of {args.repeats} runs after one warm-up run; fwd+bwd = value_and_grad w.r.t. all fields + pose; "
          "pose_fwd_bwd = w.r.t. the pose only (tracking)")
    cols = ["size", "gaussians", "mean_list", "longest", "k", "compile_s", "fwd_ms", "fwd_bwd_ms", "ns_per_px_cand",
            "pose_fwd_bwd_ms", "truncated_px", "max_contrib", "peak_rss_mb"]
    print(" | ".join(f"{c:>12s}" for c in cols))
    for size in args.sizes.split(","):
        width, height = (int(x) for x in size.split("x"))
        row = bench(width, height, args.variant, settings, args.repeats)
        print(" | ".join(f"{row[c]:>12.1f}" if isinstance(row[c], float) else f"{row[c]:>12}" for c in cols),
              flush=True)


if __name__ == "__main__":
    main()
