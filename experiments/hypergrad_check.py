"""Each hypergradient way against central differences of whole SLAM runs, at several step sizes (issue 49).

    python experiments/hypergrad_check.py --regime lm                  # the noisy room at 80x60, 8 frames, LM
    python experiments/hypergrad_check.py --regime adam-smooth --downscale 4 --frames 4

A regime is a tracker setting on the noisy synthetic room (`cpu` preset at its width, CB-KNN `paper`):

* ``lm``: Levenberg-Marquardt, 20 steps on every pixel (poses are fixed points: what ``implicit`` assumes);
* ``adam-smooth``: Adam at a tenth of the preset's learning rates, 10 iterations (not converged: what ``unrolled``
  sees; the tests' regime);
* a ``+noise`` suffix adds 1 cm of fresh map noise and 1 cm of depth noise (CB-KNN's case).

For each field, the whole run is recorded at ``v (1 +- s)`` for each step ``s`` and both objectives are taken
(relative sensitivities ``v dJ/dv``); then every way (adjoint x truncation) takes both objectives' hypergradients
of the run at ``v``. The runs' differences are a derivative only where they agree between step sizes: the table's
last rows say how well they agree with each other, then each way's sign agreement and correlation with them.
Results accumulate in ``--out`` (a JSON file; a rerun computes only what it lacks).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from gsjax.config.paths import differentiable_entry, replace_path
from gsjax.config.text import apply_overrides
from gsjax.data import open_sequence
from gsjax.io.atomic import atomic_write_json
from gsjax.slam import hypergrad
from gsjax.slam.presets import preset, with_cbknn_mode

FIELDS = ("tracking.lr_trans", "tracking.lr_rot", "tracking.lambda_color", "tracking.lambda_depth",
          "cbknn.lambda_color_keyframe", "cbknn.params.alpha", "cbknn.params.k0", "cbknn.params.beta")
REGIMES = {
    "lm": {"tracking.optimizer": "lm", "tracking.iters": "20", "tracking.strided_iters": "0",
           "tracking.reselect_every": "1"},
    "adam-smooth": {"tracking.iters": "10", "tracking.strided_iters": "0", "tracking.lr_trans": "2e-4",
                    "tracking.lr_rot": "2e-4"},
}
NOISE = {"noise.map_means_cm": "1.0", "noise.depth_cm": "1.0"}
WAYS = ("implicit/frame", "implicit/window", "unrolled/frame", "unrolled/window")
OBJECTIVES = ("residual", "ate")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regime", default="lm", help="lm | adam-smooth, optionally with +noise")
    parser.add_argument("--downscale", type=int, default=2, help="of the 160x120 room (2: 80x60)")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--steps", default="0.05,0.2", help="relative steps of the runs' central differences")
    parser.add_argument("--ways", default=None, help=f"comma-separated of {', '.join(WAYS)} (default: those that "
                                                     "apply: implicit skips learning rates)")
    parser.add_argument("--fields", default=",".join(FIELDS))
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    base, _, noise = args.regime.partition("+")
    if base not in REGIMES or noise not in ("", "noise"):
        parser.error(f"--regime: one of {', '.join(REGIMES)}, optionally +noise; got {args.regime!r}")
    sequence = open_sequence("synthetic", max_frames=args.frames, downscale=args.downscale, sensor_noise=True)
    intrinsics = sequence.intrinsics
    config = with_cbknn_mode(preset("cpu", intrinsics.width), "paper")
    config = apply_overrides(config, {**REGIMES[base], **(NOISE if noise else {})})
    frames = [sequence.read_host(i) for i in range(len(sequence))]
    fields = [f for f in args.fields.split(",") if f]
    if base == "lm":  # LM has no learning rates
        fields = [f for f in fields if not f.startswith("tracking.lr_")]
    steps = [float(s) for s in args.steps.split(",")]
    ways = args.ways.split(",") if args.ways else list(WAYS)
    out_path = args.out or Path(__file__).parent / "results" / (
        f"hypergrad_check_{intrinsics.width}x{intrinsics.height}_{len(frames)}f_{args.regime}.json")
    results = json.loads(out_path.read_text()) if out_path.exists() else {}

    def save() -> None:
        out_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out_path, results, indent=1)

    for step in steps:
        for name in fields:
            key = f"runs {step} {name}"
            if key in results:
                continue
            value = float(differentiable_entry(config, name).value)
            ends = []
            for sign in (1, -1):
                window = hypergrad.record(frames, replace_path(config, name, value * (1 + sign * step)), intrinsics)
                ends.append({o: hypergrad.objective_value(window, config, intrinsics, o) for o in OBJECTIVES})
            results[key] = {o: (ends[0][o] - ends[1][o]) / (2 * step) for o in OBJECTIVES}
            save()
            print(key, results[key], flush=True)

    window = hypergrad.record(frames, config, intrinsics)
    for way in ways:
        adjoint, truncation = way.split("/")
        for objective in OBJECTIVES:
            key = f"{way} {objective}"
            if key in results:
                continue
            start = time.perf_counter()
            result = hypergrad.hypergradient(window, config, intrinsics, fields, objective=objective,
                                             adjoint=adjoint, truncation=truncation, mode="reverse")
            results[key] = {n: float(differentiable_entry(config, n).value) * result.gradient[n] for n in fields}
            results[key + " s"] = time.perf_counter() - start
            save()
            print(key, results[key], flush=True)
    print(table(results, fields, steps, ways))


def table(results: dict, fields: list[str], steps: list[float], ways: list[str]) -> str:
    """Markdown: per objective, each field's runs' differences and each way's value (relative, x 1e3), then each
    way's sign agreement and correlation with the runs' differences at each step, and the runs' with each other."""
    lines = []
    for objective in OBJECTIVES:
        runs = {s: np.array([results[f"runs {s} {n}"][objective] for n in fields]) for s in steps}
        found = [w for w in ways if f"{w} {objective}" in results]
        way_values = {w: np.array([results[f"{w} {objective}"][n] for n in fields]) for w in found}
        lines += [f"\n{objective} (v dJ/dv x 1e3)\n",
                  "| field | " + " | ".join(f"runs {s:g}" for s in steps) + " | " + " | ".join(found) + " |",
                  "|---" * (1 + len(steps) + len(found)) + "|"]
        for i, name in enumerate(fields):
            cells = [f"{1e3 * runs[s][i]:+.3f}" for s in steps] + [f"{1e3 * way_values[w][i]:+.3f}" for w in found]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        for s in steps:
            cells = []
            for w in found:
                signs = int(np.sum(np.sign(way_values[w]) == np.sign(runs[s])))
                cells.append(f"{signs}/{len(fields)}, {np.corrcoef(way_values[w], runs[s])[0, 1]:+.2f}")
            lines.append(f"| signs, corr. with runs {s:g} | " + " | ".join([""] * len(steps)) + " | "
                         + " | ".join(cells) + " |")
        for a, b in zip(steps, steps[1:]):
            signs = int(np.sum(np.sign(runs[a]) == np.sign(runs[b])))
            lines.append(f"| runs {a:g} against runs {b:g}: {signs}/{len(fields)} signs, "
                         f"corr. {np.corrcoef(runs[a], runs[b])[0, 1]:+.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
