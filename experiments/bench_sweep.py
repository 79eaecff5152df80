"""Wall time of one `gsjax sweep` of N configs against N separate `gsjax run` processes, from an empty compilation
cache (a user's first sweep) and from a warm one, and against the sweep's floor.

    python experiments/bench_sweep.py --frames 10 --out /tmp/bench_sweep [--configs 4] [--grid alpha_k0|counts|modes]

Every command runs as its own process, as a user would type it, with ``GSJAX_CACHE_DIR`` pointing at a fresh
directory (cold) or at the one the cold pass filled (warm). The floor on a CPU (issue 47, decision 1) is what a sweep
cannot share: the first separate run's whole wall time (start-up, compilation, its SLAM, its outputs) plus the SLAM
compute of the other runs. Grids: ``alpha_k0`` (CB-KNN's alpha x K0), ``counts`` (``tracking.iters`` x
``mapping.iters``, traced: one program) and ``modes`` (``cbknn.mode``: off, code_parity and paper; traced, but
``paper`` compiles CB-KNN's correction in: two programs). Writes ``bench_sweep_N[_GRID].json`` and prints a table.
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
TRACKING_ITERS = ("8", "10", "12", "14")  # the cpu preset's 10 full iterations, around it
MAPPING_ITERS = ("24", "30")
MODES = ("off", "code_parity", "paper")


def grid(kind: str, configs: int) -> list[dict[str, str]]:
    """The configs of a grid, as dotted overrides, in sweep order (first axis slowest)."""
    if kind == "alpha_k0":
        return [{"cbknn.params.alpha": a, "cbknn.params.k0": k} for a in ALPHAS[: configs // 2] for k in K0S]
    if kind == "counts":
        return [{"tracking.iters": t, "mapping.iters": m} for t in TRACKING_ITERS[: configs // 2]
                for m in MAPPING_ITERS]
    return [{"cbknn.mode": m} for m in MODES]  # the three modes, whatever --configs says


def grid_flags(configs: list[dict[str, str]]) -> list[str]:
    """``--grid`` flags whose product (in sweep order) is ``configs``; ValueError when it is not a product."""
    fields = list(configs[0])
    axes = {f: list(dict.fromkeys(c[f] for c in configs)) for f in fields}
    import itertools

    if [dict(zip(fields, combo)) for combo in itertools.product(*axes.values())] != configs:
        raise ValueError("not a product grid")
    return [token for f, values in axes.items() for token in ("--grid", f"{f}={','.join(values)}")]


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
    parser.add_argument("--configs", type=int, default=8, choices=(2, 3, 4, 6, 8),
                        help="alpha_k0: the first configs/2 alphas x both K0; counts: configs/2 tracking.iters x "
                             "both mapping.iters; modes: the three modes (3)")
    parser.add_argument("--grid", default="alpha_k0", choices=("alpha_k0", "counts", "modes"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    data = ["--dataset", "synthetic", "--max-frames", str(args.frames), "--cbknn", args.cbknn, "--no-progress"]
    configs = grid(args.grid, args.configs)
    results = dict(frames=args.frames, configs=len(configs), grid=args.grid, cbknn=args.cbknn,
                   cpu_count=os.cpu_count(), devices=args.devices, passes={})
    caches = {name: Path(tempfile.mkdtemp(prefix=f"gsjax_bench_{name}_")) for name in ("sweep", "separate")}
    try:
        for cache_state in ("cold", "warm"):
            out = args.out / cache_state
            shutil.rmtree(out, ignore_errors=True)
            sweep_s = _gsjax(["sweep", "--out", str(out / "sweep"), *data, *grid_flags(configs)]
                             + (["--devices", str(args.devices)] if args.devices else []), caches["sweep"])
            summary = json.loads((out / "sweep" / "sweep.json").read_text())
            separate = []
            for i, overrides in enumerate(configs):
                run_out = out / "separate" / f"{i:03d}"
                wall = _gsjax(["run", "--out", str(run_out), *data,
                               *(token for name, value in overrides.items() for token in (f"--{name}", value))],
                              caches["separate"])
                timings = read_run_metrics(run_out / "metrics.json").stage_timings_s
                separate.append(dict(wall_s=wall, slam_s=timings["slam_s"],
                                     compile_s_estimate=timings.get("compile_s_estimate"),
                                     outputs_s=timings["outputs_s"]))
            separate_s = sum(r["wall_s"] for r in separate)
            floor = separate[0]["wall_s"] + sum(r["slam_s"] for r in separate[1:])
            results["passes"][cache_state] = dict(
                sweep_wall_s=sweep_s, sweep_slam_s=summary["timings"]["slam_s"], programs=summary["programs"],
                sweep_first_chunk_s=summary["timings"]["first_chunk_s"],
                sweep_outputs_s=summary["timings"]["outputs_s"],
                separate_wall_s=separate_s, separate_slam_s=sum(r["slam_s"] for r in separate),
                separate_outputs_s=sum(r["outputs_s"] for r in separate), separate=separate,
                ratio=sweep_s / separate_s, floor_s=floor, ratio_to_floor=sweep_s / floor)
            p = results["passes"][cache_state]
            print(f"{cache_state}: sweep {sweep_s:.1f} s ({p['programs']} program(s); SLAM {p['sweep_slam_s']:.1f} s, "
                  f"outputs {p['sweep_outputs_s']:.1f} s) vs {len(configs)} runs {separate_s:.1f} s (SLAM "
                  f"{p['separate_slam_s']:.1f} s, outputs {p['separate_outputs_s']:.1f} s): ratio {p['ratio']:.2f}; "
                  f"floor {floor:.1f} s, sweep / floor {p['ratio_to_floor']:.2f}", flush=True)
    finally:
        for cache in caches.values():
            shutil.rmtree(cache, ignore_errors=True)
    name = f"bench_sweep_{len(configs)}" + ("" if args.grid == "alpha_k0" else f"_{args.grid}") + ".json"
    (args.out / name).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out / name}")


if __name__ == "__main__":
    main()
