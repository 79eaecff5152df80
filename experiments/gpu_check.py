"""Collect what ``experiments/gpu_check.sh`` measured into one JSON, ``OUT/gpu_check.json``, and print it.

    python experiments/gpu_check.py OUT

Reads ``OUT/steps.jsonl`` (status and seconds of each step), ``OUT/tests.jsonl`` (Pallas vs XLA differences from
tests/raster/test_gpu.py), ``OUT/bench.json`` (gsjax bench), ``OUT/run/metrics.json`` (the 40-frame run) and
``OUT/aot/gpu_aot.json`` (the ahead-of-time compiled programs, run on the GPU), and sets the issue's targets beside
the figures: a tracking iteration at 1200x680 <= 3 ms, >= 5 frames/s at full resolution, Pallas >= 3x faster than
XLA.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from gsjax.eval.run_metrics import read_run_metrics


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def _json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def collect(out: Path) -> dict:
    result = {"gpu": (out / "gpu.txt").read_text().strip() if (out / "gpu.txt").is_file() else None,
              "steps": _lines(out / "steps.jsonl"), "tests": _lines(out / "tests.jsonl")}
    bench = _json(out / "bench.json")
    result["bench"] = bench
    targets = {}
    if bench:
        rows = {(r["backend"], r["size"]): r for r in bench["rows"]}
        for size in sorted({r["size"] for r in bench["rows"]}):
            xla, pallas = rows.get(("xla", size)), rows.get(("pallas", size))
            if xla and pallas:
                targets[f"pallas_speedup_fwd_bwd_{size}"] = xla["fwd_bwd_ms"] / pallas["fwd_bwd_ms"]
                targets[f"pallas_speedup_track_iter_{size}"] = xla["track_iter_ms"] / pallas["track_iter_ms"]
        if ("pallas", "1200x680") in rows:
            targets["track_iter_ms_1200x680"] = rows[("pallas", "1200x680")]["track_iter_ms"]
    if (out / "run" / "metrics.json").is_file():
        metrics = read_run_metrics(out / "run" / "metrics.json")
        result["run"] = dict(
            {key: getattr(metrics, key) for key in ("frames", "width", "height", "frames_per_s", "seconds_per_frame",
                                                    "stage_timings_s", "num_gaussians", "frames_with_truncated_render",
                                                    "warnings")},
            ate_rmse_c2w_cm=metrics.ate_cm, render=dataclasses.asdict(metrics.render))
        targets["frames_per_s_full_resolution"] = metrics.frames_per_s
    aot = _json(out / "aot" / "gpu_aot.json")
    if aot:  # per program: compiled for the described H100 here, loaded and run on this GPU, vs jax.jit
        columns = ("name", "registers", "spill_stores", "shared_bytes", "occupancy")
        programs = {name: dict(compile_s=r.get("compile_s"), error=r.get("error"), run=r.get("run"),
                               kernels=[{k: kernel.get(k) for k in columns} for kernel in r.get("pallas_kernels", [])])
                    for name, r in aot.get("programs", {}).items()}
        result["aot"] = dict(error=aot.get("error"), programs=programs)
    result["targets"] = dict(targets, goals="track_iter_ms_1200x680 <= 3; frames/s >= 5 at full resolution; "
                                          "pallas speedup >= 3")
    return result


def main(argv: list[str]) -> int:
    out = Path(argv[1] if len(argv) > 1 else "outputs/gpu_check")
    result = collect(out)
    (out / "gpu_check.json").write_text(json.dumps(result, indent=2))
    print(json.dumps({k: result[k] for k in ("gpu", "steps", "targets")}, indent=2))
    print(f"wrote {out / 'gpu_check.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
