"""What a hypergradient costs against the tracking it differentiates, at the working resolution (issue 49).

    python experiments/hypergrad_cost.py --frames 10            # 7-Scenes' kitchen at 80x60, the cpu preset

Records the window (SLAM one frame at a time), then times, each the best of 3 calls after a warm-up call: every
frame's tracking alone (the run's program: while loops), and the objective's hypergradient with respect to 1-4 of
the tracking learning rates and loss weights for each adjoint, truncation and mode (forward: a tangent per field;
``--implicit-only``: the implicit adjoint alone). Prints the seconds and the ratio to tracking; the peak memory is
the process's (run it under ``/usr/bin/time -v``).
"""

from __future__ import annotations

import argparse
import functools
import time
from pathlib import Path

import jax

from gsjax.app.cli import build_parser, common
from gsjax.app.runtime.cache import enable_compilation_cache, exported_call
from gsjax.slam import hypergrad
from gsjax.slam.system import frame_input, sanitize_frame
from gsjax.slam.tracking import track_guarded

KITCHEN = Path(__file__).resolve().parents[2] / "shared" / "data" / "7scenes_redkitchen"
FIELDS = ("tracking.lr_trans", "tracking.lr_rot", "tracking.lambda_color", "tracking.lambda_depth")


def timed(fn, repeats: int = 2) -> float:
    jax.block_until_ready(fn())  # compile and warm
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--objective", default="ate", choices=("ate", "residual"))
    parser.add_argument("--window", action="store_true", help="also the window truncation (slow)")
    parser.add_argument("--implicit-only", action="store_true", help="time the implicit adjoint only")
    options = parser.parse_args()
    enable_compilation_cache()
    args = build_parser().parse_args(["run", "--dataset", "7scenes", "--path", str(KITCHEN), "--max-frames",
                                      str(options.frames), "--out", "unused"])
    args.overrides = {}
    sequence, _ = common.open_run_sequence(args)
    config = common.configure(args, sequence.intrinsics.width)
    intrinsics = sequence.intrinsics
    frames = [sequence.read_host(i) for i in range(options.frames)]
    window = hypergrad.record(frames, config, intrinsics, call=exported_call())

    @jax.jit
    def tracking(window):
        def one(_, inputs):
            state, frame, _ = inputs
            given = frame_input(state, sanitize_frame(frame), config, intrinsics)
            return None, track_guarded(given.problem, config, state.previous_tracking_loss).w2c
        return jax.lax.scan(one, None, (window.states, window.frames, window.outputs))[1]

    base = timed(lambda: tracking(window), 3)
    print(f"{intrinsics.width}x{intrinsics.height}, {options.frames} frames: tracking alone {base:.2f} s")
    cases = [("implicit", "frame", "reverse", 3)] + ([("implicit", "window", "reverse", 3)] if options.window else [])
    if not options.implicit_only:
        cases += [("unrolled", "frame", "forward", n) for n in (1, 2, 3, 4)] + [("unrolled", "frame", "reverse", 3)]
        cases += [("unrolled", "window", "reverse", 3)] if options.window else []
    for adjoint, truncation, mode, count in cases:
        call = functools.partial(hypergrad.hypergradient, window, config, intrinsics, FIELDS[:count],
                                 objective=options.objective, adjoint=adjoint, truncation=truncation, mode=mode)
        seconds = timed(lambda c=call: c().value, 3)
        grads = ", ".join(f"{k} {v:.3g}" for k, v in call().gradient.items())
        print(f"{adjoint} {truncation} {mode}, {count} field(s): {seconds:.2f} s ({seconds / base:.2f}x tracking); "
              f"{grads}")
    again = timed(lambda: tracking(window), 3)
    print(f"tracking alone again {again:.2f} s (the ratios are against the first)")


if __name__ == "__main__":
    main()
