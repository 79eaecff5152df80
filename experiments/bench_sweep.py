"""Wall time of one `gsjax sweep` of N configs against N separate `gsjax run` processes, from an empty compilation
cache (a user's first sweep) and from a warm one, and where the time goes.

    python experiments/bench_sweep.py --frames 10 --out /tmp/bench_sweep [--configs 4]

Every command runs as its own process, as a user would type it, with ``GSJAX_CACHE_DIR`` pointing at a fresh
directory (cold) or at the one the cold pass filled (warm). Writes ``bench_sweep_N.json`` (N configs) and prints a
table.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gsjax.eval.run_metrics import read_run_metrics

ALPHAS = ("0.05", "0.1", "0.2", "0.3")
K0S = ("4", "8")


def _gsjax(argv: list[str], cache: Path) -> float:
    env = dict(os.environ, GSJAX_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gsjax", *argv], env=env, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--cbknn", default="paper")
    parser.add_argument("--devices", type=int, default=None, help="gsjax sweep --devices (default: its own)")
    parser.add_argument("--configs", type=int, default=8, choices=(2, 4, 6, 8),
                        help="the first configs/2 alphas x both K0")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    data = ["--dataset", "synthetic", "--max-frames", str(args.frames), "--cbknn", args.cbknn, "--no-progress"]
    alphas = ALPHAS[: args.configs // 2]
    configs = [(a, k) for a in alphas for k in K0S]
    results = dict(frames=args.frames, configs=len(configs), cbknn=args.cbknn, cpu_count=os.cpu_count(),
                   devices=args.devices, passes={})
    caches = {name: Path(tempfile.mkdtemp(prefix=f"gsjax_bench_{name}_")) for name in ("sweep", "separate")}
    try:
        for cache_state in ("cold", "warm"):
            out = args.out / cache_state
            shutil.rmtree(out, ignore_errors=True)
            sweep_s = _gsjax(["sweep", "--out", str(out / "sweep"), *data, "--grid", "cbknn.params.alpha=" +
                              ",".join(alphas), "--grid", "cbknn.params.k0=" + ",".join(K0S)]
                             + (["--devices", str(args.devices)] if args.devices else []), caches["sweep"])
            summary = json.loads((out / "sweep" / "sweep.json").read_text())
            separate = []
            for i, (alpha, k0) in enumerate(configs):
                run_out = out / "separate" / f"{i:03d}"
                wall = _gsjax(["run", "--out", str(run_out), *data, "--cbknn.params.alpha", alpha,
                               "--cbknn.params.k0", k0], caches["separate"])
                timings = read_run_metrics(run_out / "metrics.json").stage_timings_s
                separate.append(dict(wall_s=wall, slam_s=timings["slam_s"],
                                     compile_s_estimate=timings.get("compile_s_estimate"),
                                     outputs_s=timings["outputs_s"]))
            separate_s = sum(r["wall_s"] for r in separate)
            results["passes"][cache_state] = dict(
                sweep_wall_s=sweep_s, sweep_slam_s=summary["timings"]["slam_s"],
                sweep_first_chunk_s=summary["timings"]["first_chunk_s"],
                sweep_outputs_s=summary["timings"]["outputs_s"],
                separate_wall_s=separate_s, separate_slam_s=sum(r["slam_s"] for r in separate),
                separate_outputs_s=sum(r["outputs_s"] for r in separate), separate=separate,
                ratio=sweep_s / separate_s)
            p = results["passes"][cache_state]
            print(f"{cache_state}: sweep {sweep_s:.1f} s (SLAM {p['sweep_slam_s']:.1f} s, outputs "
                  f"{p['sweep_outputs_s']:.1f} s) vs {len(configs)} runs {separate_s:.1f} s (SLAM "
                  f"{p['separate_slam_s']:.1f} s, outputs {p['separate_outputs_s']:.1f} s): ratio {p['ratio']:.2f}",
                  flush=True)
    finally:
        for cache in caches.values():
            shutil.rmtree(cache, ignore_errors=True)
    (args.out / f"bench_sweep_{len(configs)}.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out / f'bench_sweep_{len(configs)}.json'}")


if __name__ == "__main__":
    main()
