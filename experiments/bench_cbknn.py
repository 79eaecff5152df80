"""Overhead of CB-KNN over the canonical render, forward and forward+backward, on a SplaTAM-density map.

    python experiments/bench_cbknn.py [--sizes 80x60,160x120] [--variant mapped] [--repeats 7]

Prints the median time of repeated runs after warm-up for the canonical render and for CB-KNN (paper defaults:
alpha 0.2 px, K0 5, beta 0.3, motion 0.5, hybrid, first_k), and their ratio.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp

from gsjax.app.bench import median_seconds, weighted_outputs
from gsjax.camera import se3_exp
from gsjax.data.room import dense_surface_map
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster.cbknn import CBKNN


def bench(width: int, height: int, variant: str, cbknn: CBKNN | None, repeats: int) -> tuple[float, float]:
    gaussians, w2c, intrinsics = dense_surface_map(height, width, variant)
    weights = jax.random.normal(jax.random.PRNGKey(0), (height, width, 6))
    settings = RasterSettings()

    def loss(means, rgb, logit_opacities, log_scales, delta):
        g = Gaussians(means, log_scales, logit_opacities, rgb, gaussians.active)
        out = render(g, se3_exp(delta) @ w2c, intrinsics, settings, cbknn=cbknn, motion=0.5)
        return weighted_outputs(out, weights)

    params = (gaussians.means, gaussians.rgb, gaussians.logit_opacities, gaussians.log_scales, jnp.zeros(6))
    fwd = jax.jit(loss)
    fwd_bwd = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2, 3, 4)))
    return median_seconds(fwd, *params, repeats=repeats), median_seconds(fwd_bwd, *params, repeats=repeats)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="80x60,160x120")
    parser.add_argument("--variant", default="mapped")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    print(f"backend={jax.default_backend()} variant={args.variant} settings={RasterSettings()}")
    print(f"CB-KNN: {CBKNN()} motion=0.5; median of {args.repeats} runs after warm-up")
    print(f"{'size':>8s} | {'fwd ms':>8s} {'cbknn':>8s} {'ratio':>6s} | "
          f"{'fwd+bwd ms':>10s} {'cbknn':>8s} {'ratio':>6s}")
    for size in args.sizes.split(","):
        width, height = (int(x) for x in size.split("x"))
        base_f, base_fb = bench(width, height, args.variant, None, args.repeats)
        cb_f, cb_fb = bench(width, height, args.variant, CBKNN(), args.repeats)
        print(f"{size:>8s} | {1e3 * base_f:8.1f} {1e3 * cb_f:8.1f} {cb_f / base_f:6.2f} | "
              f"{1e3 * base_fb:10.1f} {1e3 * cb_fb:8.1f} {cb_fb / base_fb:6.2f}", flush=True)


if __name__ == "__main__":
    main()
