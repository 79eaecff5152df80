"""Per-config time of the SLAM scan over one chunk of 8 frames: the plain program vs ``jax.vmap`` over B stacked
configs (what ``gsjax sweep --vmap-width B`` runs), after compilation, on the synthetic room.

    python experiments/bench_vmap.py --mode off --width 40 --batches 0,1,4

B = 0 is the plain (unbatched) program. Prints the first call (compile + run) and the steady per-chunk and
per-config times.
"""

from __future__ import annotations

import argparse
import time

import jax

from gsjax.app.runtime.cache import enable_compilation_cache
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.slam.driver import pad_chunk, run_batch_chunk, stack_trees
from gsjax.slam.presets import preset, with_cbknn_mode
from gsjax.slam.state import initial_state, keyframe_capacity_for
from gsjax.slam.system import run_chunk


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", default="off")
    parser.add_argument("--width", type=int, default=40)
    parser.add_argument("--batches", default="0,1,4")
    args = parser.parse_args()
    enable_compilation_cache()
    sequence = synthetic_sequence(SyntheticConfig(width=args.width, height=args.width * 3 // 4, num_frames=8))
    k = sequence.intrinsics
    config = with_cbknn_mode(preset("cpu", args.width), args.mode)
    frames, valid = pad_chunk([sequence.read_host(i) for i in range(8)], 8)
    state = initial_state(2 * k.height * k.width, k.height, k.width, keyframe_capacity_for(8, 5), 8, 0)
    for b in (int(x) for x in args.batches.split(",")):
        if b == 0:
            call = lambda: run_chunk(state, frames, valid, config, k)  # noqa: E731
        else:
            states, configs = stack_trees([state] * b), stack_trees([config] * b)
            call = lambda: run_batch_chunk(states, frames, valid, configs, k, None)  # noqa: E731
        t0 = time.perf_counter()
        jax.block_until_ready(call())
        t1 = time.perf_counter()
        jax.block_until_ready(call())
        t2 = time.perf_counter()
        print(f"mode {args.mode} {args.width}px batch {b}: first call {t1 - t0:.1f} s, steady {t2 - t1:.2f} s per "
              f"chunk, {(t2 - t1) / max(b, 1):.2f} s per config", flush=True)


if __name__ == "__main__":
    main()
