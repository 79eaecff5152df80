"""The accuracy gate of a speed change (issue 37, decision 1): ATE and PSNR of ``gsjax run --preset cpu`` on the
sequences of at least 40 frames, 3 seeds each, before and after, judged side by side.

    python experiments/accuracy_gate.py run --work DIR --label before --checkout /path/to/old/checkout
    python experiments/accuracy_gate.py run --work DIR --label after [--set tracking.reselect_every=10 ...]
    python experiments/accuracy_gate.py judge DIR/before.csv DIR/after.csv [--out experiments/results/FILE.md]

``run`` runs every (sequence, seed) with ``python -m gsjax run`` from ``--checkout`` (default: this one) into
``DIR/LABEL/SEQ_sSEED`` (a finished run is reused) and writes ``DIR/LABEL.csv`` (ATE cm, PSNR dB, wall s). ``judge``
prints the table: a change holds on a sequence when its mean ATE moves by at most max(2 x the before-std, 0.03 cm)
or improves, and its mean PSNR by at most 0.5 dB.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEVEN_SCENES = (ROOT.parent / "shared" / "data" / "7scenes_redkitchen").resolve()

# name -> gsjax run flags. The synthetic room's 200 frames run at 40x30 (downscale 4), as the long-run test does.
SEQUENCES = {
    "7scenes_40": ["--dataset", "7scenes", "--path", str(SEVEN_SCENES), "--max-frames", "40"],
    "7scenes_150": ["--dataset", "7scenes", "--path", str(SEVEN_SCENES), "--max-frames", "150"],
    "synthetic_noisy_60": ["--dataset", "synthetic", "--synthetic-noise", "--max-frames", "60"],
    "synthetic_200": ["--dataset", "synthetic", "--max-frames", "200", "--downscale", "4"],
}
ATE_FLOOR_CM = 0.03
PSNR_TOL_DB = 0.5


def run(args) -> int:
    checkout = Path(args.checkout).resolve()
    module = "gsjax" if (checkout / "gsjax" / "__main__.py").exists() else "gsjax.cli"
    env = dict(os.environ, PYTHONPATH=str(checkout))
    rows = []
    for name in args.sequences.split(","):
        for seed in range(args.seeds):
            out = Path(args.work) / args.label / f"{name}_s{seed}"
            metrics = out / "metrics.json"
            wall = None
            if not metrics.exists():
                argv = [sys.executable, "-m", module, "run", "--preset", "cpu", *SEQUENCES[name], "--seed", str(seed),
                        "--out", str(out), "--overwrite", "--no-progress"]
                for item in args.set:
                    field, value = item.split("=", 1)
                    argv += [f"--{field}", value]
                start = time.perf_counter()
                subprocess.run(argv, env=env, cwd="/tmp", check=True, stdout=subprocess.DEVNULL)
                wall = time.perf_counter() - start
            m = json.loads(metrics.read_text())
            ate = m["trajectory"]["ate_rmse_c2w_cm"]
            psnr = m["render"]["mean"]["psnr_db"]
            rows.append(dict(sequence=name, seed=seed, ate_cm=ate, psnr_db=psnr, wall_s=wall))
            print(f"{args.label} {name} seed {seed}: ATE {ate:.3f} cm, PSNR {psnr:.2f} dB"
                  + (f", {wall:.0f} s" if wall else ""), flush=True)
    with open(Path(args.work) / f"{args.label}.csv", "w", newline="") as f:
        f.write(f"# {' '.join(sys.argv)}\n# checkout {checkout}; sets {args.set}\n")
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return 0


def read(path: Path) -> dict[str, list[dict]]:
    with open(path) as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    by_sequence: dict[str, list[dict]] = {}
    for row in rows:
        by_sequence.setdefault(row["sequence"], []).append(row)
    return by_sequence


def judge(args) -> int:
    before, after = read(Path(args.before)), read(Path(args.after))
    lines = ["| sequence | seeds | ATE before (mean +- std) | ATE after | allowed change | PSNR before / after | "
             "holds |", "|---|---|---|---|---|---|---|"]
    holds_all = True
    for name in SEQUENCES:
        if name not in before or name not in after:
            continue
        b = [float(r["ate_cm"]) for r in before[name]]
        a = [float(r["ate_cm"]) for r in after[name]]
        pb = statistics.mean(float(r["psnr_db"]) for r in before[name])
        pa = statistics.mean(float(r["psnr_db"]) for r in after[name])
        std = statistics.stdev(b) if len(b) > 1 else 0.0
        allowed = max(2.0 * std, ATE_FLOOR_CM)
        holds = (statistics.mean(a) - statistics.mean(b) <= allowed) and abs(pa - pb) <= PSNR_TOL_DB
        holds_all &= holds
        lines.append(f"| {name} | {len(b)} / {len(a)} | {statistics.mean(b):.3f} +- {std:.3f} cm | "
                     f"{statistics.mean(a):.3f} +- {statistics.stdev(a) if len(a) > 1 else 0.0:.3f} cm | "
                     f"+{allowed:.3f} cm | {pb:.2f} / {pa:.2f} dB | {'yes' if holds else 'NO'} |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.out:
        Path(args.out).write_text(f"<!-- python experiments/accuracy_gate.py judge {args.before} {args.after} -->\n"
                                  + table)
    return 0 if holds_all else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run")
    p.add_argument("--work", required=True)
    p.add_argument("--label", required=True)
    p.add_argument("--checkout", default=str(ROOT))
    p.add_argument("--sequences", default=",".join(SEQUENCES))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p = sub.add_parser("judge")
    p.add_argument("before")
    p.add_argument("after")
    p.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    return run(args) if args.command == "run" else judge(args)


if __name__ == "__main__":
    sys.exit(main())
