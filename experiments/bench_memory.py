"""Peak memory of one tracking iteration and one mapping iteration at full resolution, by XLA's buffer assignment
(compile only, nothing runs, so it is cheap on any machine): per backend, with the compositing in bounded batches
of tiles (``RasterSettings.slots_per_batch``, the default) and unbounded (everything at once, as before).

    python experiments/bench_memory.py [--sizes 640x480,1200x680] [--backends xla,pallas] [--k 96]

Writes experiments/results/bench_memory.json. The peak is arguments + outputs + temporaries of the compiled
program on this machine's backend (a GPU's buffer assignment differs in detail, not in what dominates).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from gsjax.app.bench import bench_map, parse_size, peak_mib
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings
from gsjax.slam.config import SlamConfig
from gsjax.slam.tracking import TrackingProblem, tracking_objective
from gsjax.slam.views import render_view

UNBOUNDED = 1 << 40


def compiled_peaks(width: int, height: int, backend: str, slots_per_batch: int, k: int) -> dict:
    config = SlamConfig()
    config = dataclasses.replace(config, raster=dataclasses.replace(
        config.raster, backend=backend, max_contributors=k, slots_per_batch=slots_per_batch))
    g, w2c, intrinsics = bench_map(width, height)
    color = jnp.zeros((height, width, 3), jnp.float32)
    depth = jnp.ones((height, width), jnp.float32)

    def track_iteration(delta):
        objective = tracking_objective(TrackingProblem(g, color, depth, w2c, intrinsics, False, 0.0), config)
        return jax.value_and_grad(objective.loss)(delta)

    def map_iteration(fields):
        def loss(fields):
            view = render_view(Gaussians(*fields, g.active), w2c, intrinsics, config.raster, config.cbknn, False, 0.0)
            return jnp.sum(jnp.abs(view.color - color)) + jnp.sum(jnp.abs(view.depth - depth))

        return jax.value_and_grad(loss)(fields)

    fields = (g.means, g.log_scales, g.logit_opacities, g.rgb)
    track = jax.jit(track_iteration).lower(jnp.zeros(6, jnp.float32)).compile()
    mapping = jax.jit(map_iteration).lower(fields).compile()
    return dict(size=f"{width}x{height}", backend=backend, k=k, gaussians=int(g.capacity),
                batched=slots_per_batch != UNBOUNDED,
                track_iter_peak_mib=peak_mib(track), map_iter_peak_mib=peak_mib(mapping))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="640x480,1200x680")
    parser.add_argument("--backends", default="xla,pallas")
    parser.add_argument("--k", type=int, default=96)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_memory.json")
    args = parser.parse_args()
    rows = []
    for size in args.sizes.split(","):
        width, height = parse_size(size)
        for backend in args.backends.split(","):
            for slots in (RasterSettings().slots_per_batch, UNBOUNDED):
                rows.append(compiled_peaks(width, height, backend, slots, args.k))
                print(rows[-1], flush=True)
    args.out.write_text(json.dumps(dict(device=jax.default_backend(), jax=jax.__version__, rows=rows), indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
