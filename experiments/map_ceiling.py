"""What the map alone can reach: the synthetic room mapped at its ground-truth poses (no tracking), its final map
rendered at those poses, as the long run measures a tracked one.

    python experiments/map_ceiling.py --frames 1000 --downscale 4

The ``cpu`` preset at the working width, ``gsjax.slam.run(..., poses=GT)``; PSNR is SplaTAM's (masked by valid depth)
on frames t = 0 and (t + 1) % 5 == 0, as ``gsjax run`` evaluates. Writes
``experiments/results/map_ceiling_FRAMES.json`` (the command inside).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.runtime.cache import enable_compilation_cache
from gsjax.camera import invert_transform
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.eval.image import render_metrics_splatam
from gsjax.io.atomic import atomic_write_json
from gsjax.raster import render
from gsjax.slam import driver
from gsjax.slam.presets import preset

eval_render = jax.jit(render)

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
EVAL_EVERY = 5
BLOCK = 100


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--downscale", type=int, default=4)
    args = parser.parse_args(argv)
    enable_compilation_cache()
    base = SyntheticConfig(num_frames=args.frames)
    sequence = synthetic_sequence(SyntheticConfig(width=base.width // args.downscale,
                                                  height=base.height // args.downscale, num_frames=args.frames))
    config = preset("cpu", sequence.intrinsics.width)
    w2c = invert_transform(sequence.gt_trajectory()[1]).astype(np.float32)
    t0 = time.perf_counter()
    result = driver.run(sequence, config, sequence.intrinsics, poses=w2c)
    seconds = time.perf_counter() - t0
    frames = [t for t in range(args.frames) if t == 0 or (t + 1) % EVAL_EVERY == 0]
    psnr = []
    for t in frames:
        frame = sequence.read_host(t)
        out = eval_render(result.state.gaussians, jnp.asarray(w2c[t]), sequence.intrinsics, config.raster)
        psnr.append(float(render_metrics_splatam(out.color, out.depth, jnp.asarray(frame.color),
                                                 jnp.asarray(frame.depth))["psnr_db"]))
    blocks = {f"{b}-{b + BLOCK - 1}": float(np.mean([p for t, p in zip(frames, psnr) if b <= t < b + BLOCK]))
              for b in range(0, args.frames, BLOCK)}
    document = dict(command=shlex.join(["python", "experiments/map_ceiling.py",
                                        *(sys.argv[1:] if argv is None else argv)]),
                    frames=args.frames, width=sequence.intrinsics.width, height=sequence.intrinsics.height,
                    psnr_db=float(np.mean(psnr)), psnr_db_per_block=blocks,
                    gaussians=int(result.state.gaussians.num_active()), seconds=seconds)
    RESULTS.mkdir(parents=True, exist_ok=True)
    atomic_write_json(RESULTS / f"map_ceiling_{args.frames}.json", document)
    print(document)
    return 0


if __name__ == "__main__":
    sys.exit(main())
