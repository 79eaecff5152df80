"""`gsjax tune` against `gsjax sweep` over the same fields (issue 49, item 4): ATE reached, SLAM cost spent.

    python experiments/tune_vs_grid.py --out /tmp/tune_vs_grid            # both sequences, every start (~1 h)
    python experiments/tune_vs_grid.py --out /tmp/t --sequences noisy --starts lr_tenth

For each sequence (the noisy synthetic room, 7-Scenes' kitchen; the cpu preset at 80x60) both searches see the
first ``--tune-frames`` frames and are judged by the ATE of a ``gsjax run`` over ``--eval-frames`` frames:

* ``gsjax tune --objective residual`` (no ground truth) from each start: the preset, the tracking learning rates at a
  tenth (``lr_trans``, ``lr_rot`` tuned), CB-KNN's alpha at 4x (``paper`` mode, ``alpha`` tuned);
* ``gsjax sweep`` over the same fields, a log grid around the preset (it chooses by the tuning frames' ATE, which
  needs ground truth).

Prints a markdown table: the 40-frame ATE of the start, of what each search chose and of the preset; the SLAM
evaluations each spent (a tune step is one recorded run plus one hypergradient) and its wall time. Every command's
outputs stay under ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

KITCHEN = Path(__file__).resolve().parents[2] / "shared" / "data" / "7scenes_redkitchen"
SEQUENCES = {"noisy": ["--dataset", "synthetic", "--synthetic-noise"],
             "kitchen": ["--dataset", "7scenes", "--path", str(KITCHEN)]}
LR = 2e-3  # the cpu preset's lr_trans and lr_rot at 80 px
ALPHA = 0.2  # the paper's alpha (px at the preset's width)
# start name -> (mode, fields, starts)
STARTS = {
    "preset": ("off", ("tracking.lr_trans", "tracking.lr_rot"), {}),
    "lr_tenth": ("off", ("tracking.lr_trans", "tracking.lr_rot"),
                 {"tracking.lr_trans": LR / 10, "tracking.lr_rot": LR / 10}),
    "alpha_4x": ("paper", ("cbknn.params.alpha",), {"cbknn.params.alpha": 4 * ALPHA}),
}
GRIDS = {  # mode -> grid axes (values around the preset's)
    "off": {"tracking.lr_trans": [LR * f for f in (0.1, 0.3, 1.0, 3.0)],
            "tracking.lr_rot": [LR * f for f in (0.1, 0.3, 1.0, 3.0)]},
    "paper": {"cbknn.params.alpha": [ALPHA * f for f in (0.25, 0.5, 1.0, 2.0, 4.0)]},
}


def gsjax(*args: str) -> float:
    """Run ``gsjax ARGS``; return its wall time (s)."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gsjax", *args, "--no-progress"], check=True)
    return time.perf_counter() - start


def evaluate(out: Path, data: list[str], frames: int, mode: str, fields: dict[str, float]) -> float:
    """The ATE (cm) of a run over ``frames`` frames with ``fields`` set."""
    if not (out / "metrics.json").exists():
        overrides = [a for name, value in fields.items() for a in (f"--{name}", repr(float(value)))]
        gsjax("run", *data, "--cbknn", mode, "--max-frames", str(frames), "--out", str(out), "--overwrite",
              *overrides)
    return json.loads((out / "metrics.json").read_text())["trajectory"]["ate_rmse_c2w_cm"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sequences", default="noisy,kitchen")
    parser.add_argument("--starts", default="lr_tenth,preset,alpha_4x")
    parser.add_argument("--tune-frames", type=int, default=20)
    parser.add_argument("--eval-frames", type=int, default=40)
    parser.add_argument("--steps", type=int, default=6)
    options = parser.parse_args()
    rows = []
    for seq in options.sequences.split(","):
        data = SEQUENCES[seq]
        base = options.out / seq
        tune_frames = ["--max-frames", str(options.tune_frames)]
        for start in options.starts.split(","):
            mode, fields, starts = STARTS[start]
            preset_ate = evaluate(base / f"eval_preset_{mode}", data, options.eval_frames, mode, {})
            start_ate = evaluate(base / f"eval_start_{start}", data, options.eval_frames, mode, starts)
            tune_dir = base / f"tune_{start}"
            seconds = None
            if not (tune_dir / "tuned.json").exists():
                seconds = gsjax("tune", *data, *tune_frames, "--cbknn", mode, "--params", ",".join(fields),
                                *[a for n, v in starts.items() for a in (f"--{n}", repr(v))],
                                "--objective", "residual", "--steps", str(options.steps), "--out", str(tune_dir),
                                "--overwrite")
            tuned = json.loads((tune_dir / "tuned.json").read_text())
            tuned_ate = evaluate(base / f"eval_tuned_{start}", data, options.eval_frames, mode, tuned["fields"])
            rows.append(dict(sequence=seq, search=f"tune from {start}", evaluations=f"{tuned['steps'] + 1} runs + "
                             f"{tuned['steps'] + 1} hypergradients", seconds=seconds or tuned["seconds"],
                             chosen=tuned["fields"], start_ate=start_ate, ate=tuned_ate, preset_ate=preset_ate))
        for mode in sorted({STARTS[s][0] for s in options.starts.split(",")}):
            sweep_dir = base / f"sweep_{mode}"
            seconds = None
            if not (sweep_dir / "sweep.csv").exists():
                axes = [a for name, values in GRIDS[mode].items()
                        for a in ("--grid", f"{name}={','.join(f'{v:.6g}' for v in values)}")]
                seconds = gsjax("sweep", *data, *tune_frames, "--cbknn", mode, *axes, "--out", str(sweep_dir),
                                "--overwrite")
            with open(sweep_dir / "sweep.csv") as f:
                table = [r for r in csv.DictReader(f) if r["ate_rmse_cm"]]
            best = min(table, key=lambda r: float(r["ate_rmse_cm"]))
            chosen = {name: float(best[name]) for name in GRIDS[mode]}
            ate = evaluate(base / f"eval_grid_{mode}", data, options.eval_frames, mode, chosen)
            rows.append(dict(sequence=seq, search=f"grid ({mode})", evaluations=f"{len(table)} runs",
                             seconds=seconds, chosen=chosen, start_ate=None, ate=ate,
                             preset_ate=evaluate(base / f"eval_preset_{mode}", data, options.eval_frames, mode, {})))
    (options.out / "table.json").write_text(json.dumps(rows, indent=1))
    print("| sequence | search | SLAM evaluations | s | chosen | start ATE (cm) | ATE (cm) | preset ATE (cm) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        chosen = ", ".join(f"{k.split('.')[-1]} {v:.3g}" for k, v in r["chosen"].items())
        start = "" if r["start_ate"] is None else f"{r['start_ate']:.3f}"
        seconds = "" if r["seconds"] is None else f"{r['seconds']:.0f}"
        print(f"| {r['sequence']} | {r['search']} | {r['evaluations']} | {seconds} | {chosen} | {start} | "
              f"{r['ate']:.3f} | {r['preset_ate']:.3f} |")


if __name__ == "__main__":
    main()
