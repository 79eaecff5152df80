"""The fixed cost of a ``gsjax run``: what a warm run spends beyond its frames' SLAM time, piece by piece.

    python experiments/fixed_cost.py [--frames 8] [--repeats 3] [--checkout DIR] [-- extra gsjax run flags]

Runs ``python -m gsjax run --preset cpu --dataset synthetic --max-frames N`` (one chunk by default) in a fresh
process ``--repeats`` times after one warm-up run (so the compilation cache is warm), and reports the medians of:

* ``process_s``: the whole process, from start to exit (what a user waits for);
* ``import_s``: importing the command line (``gsjax.app.cli``) and what a run imports later;
* JAX's own events (``jax.monitoring``): tracing to jaxprs, lowering to MLIR, the persistent-cache lookup and the
  loading of the cached executables (``cache_retrieval``), backend compiles (a warm run should have none);
* the run's stage timings (``metrics.json``): reading frames, SLAM (chunks, compilation included), checkpoints,
  outputs, the report;
* ``fixed_s``: ``process_s`` minus the frames' steady SLAM time (``slam_s`` minus the first chunk's compilation
  estimate, or, for a one-chunk run, minus ``--steady-frame-s`` x frames when given).

The script runs from the checkout given (default: this one), so two heads are measured the same way.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Run inside the measured process: JAX's event listeners, then the command line, then a JSON line of totals.
_PROBE = r"""
import json, sys, time
t0 = time.perf_counter()
import jax.monitoring as monitoring
totals = {}
def on_duration(event, duration, **kwargs):
    totals[event] = totals.get(event, 0.0) + duration
monitoring.register_event_duration_secs_listener(on_duration)
t_jax = time.perf_counter()
from gsjax.app import cli
t_cli = time.perf_counter()
status = cli.main(sys.argv[1:])
t_end = time.perf_counter()
mods = set(sys.modules)
print("FIXED_COST " + json.dumps(dict(status=status, import_jax_s=t_jax - t0, import_cli_s=t_cli - t_jax,
                                      main_s=t_end - t_cli, events=totals,
                                      loaded={m: m in mods for m in ("matplotlib", "orbax.checkpoint", "optimistix",
                                                                      "scipy.stats", "viser", "playwright", "cv2")})))
"""

EVENTS = {
    "trace_s": "/jax/core/compile/jaxpr_trace_duration",
    "lower_s": "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "backend_compile_s": "/jax/core/compile/backend_compile_duration",
    "cache_retrieval_s": "/jax/compilation_cache/cache_retrieval_time_sec",
}


def one_run(checkout: Path, out: Path, frames: int, extra: list[str]) -> dict:
    argv = [sys.executable, "-c", _PROBE, "run", "--preset", "cpu", "--dataset", "synthetic", "--max-frames",
            str(frames), "--out", str(out), "--overwrite", "--no-progress", *extra]
    env = dict(os.environ, PYTHONPATH=str(checkout))
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, cwd=tempfile.gettempdir(), capture_output=True, text=True)
    process = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"gsjax run failed:\n{done.stderr[-3000:]}")
    probe = json.loads(next(line for line in done.stdout.splitlines() if line.startswith("FIXED_COST "))[11:])
    metrics = json.loads((out / "metrics.json").read_text())
    timings = metrics["stage_timings_s"]
    row = dict(process_s=process, import_s=probe["import_jax_s"] + probe["import_cli_s"], main_s=probe["main_s"])
    row.update({name: probe["events"].get(event, 0.0) for name, event in EVENTS.items()})
    row.update({f"run_{k}": v for k, v in timings.items() if v is not None})
    row["loaded"] = probe["loaded"]
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--checkout", type=Path, default=ROOT)
    parser.add_argument("--steady-frame-s", type=float, default=None,
                        help="a steady frame's SLAM time, to subtract from a one-chunk run")
    parser.add_argument("--out", type=Path, default=None, help="write the medians as JSON here")
    parser.add_argument("extra", nargs="*", help="more gsjax run flags (after --)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as work:
        out = Path(work) / "run"
        one_run(args.checkout, out, args.frames, args.extra)  # warm the compilation cache
        rows = [one_run(args.checkout, out, args.frames, args.extra) for _ in range(args.repeats)]
    keys = [k for k in rows[0] if k != "loaded"]
    median = {k: statistics.median(r.get(k, 0.0) for r in rows) for k in keys}
    if args.steady_frame_s is not None:
        median["fixed_s"] = median["process_s"] - args.steady_frame_s * args.frames
    for k, v in median.items():
        print(f"  {k:28s} {v:7.2f} s")
    print("  modules loaded:", ", ".join(m for m, on in rows[0]["loaded"].items() if on))
    if args.out:
        args.out.write_text(json.dumps(dict(checkout=str(args.checkout), frames=args.frames, medians=median,
                                            loaded=rows[0]["loaded"]), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
