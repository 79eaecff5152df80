"""A small alpha x K0 x beta grid of CB-KNN (``paper`` mode) on one sequence as one vmapped `gsjax sweep`, against
``off`` with the same seeds, under map noise.

    python experiments/cbknn_grid.py --work /tmp/gsjax_grid --seeds 1 --frames 18 --sequence 7scenes

Writes ``experiments/results/cbknn_grid.csv`` (mean and std of the ATE over the seeds per grid point, and the
``off`` baseline) and ``cbknn_grid.png`` (the sweep's own heat map: ATE over alpha x K0, a panel per beta).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from studies import RESULTS, SEQUENCES, mean_std, sweep, write_result_csv

ALPHA = ("0.05", "0.1", "0.2")  # px at the 40 px working width (the preset's 0.1 at 40 px)
K0 = ("4", "12")
BETA = ("0", "1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--frames", type=int, default=18)
    parser.add_argument("--map-noise-cm", default="1")
    parser.add_argument("--sequence", default="7scenes", choices=list(SEQUENCES))
    args = parser.parse_args()
    commands: list[str] = []
    base = [*SEQUENCES[args.sequence], "--max-frames", str(args.frames), "--seeds", str(args.seeds),
            "--noise.map_means_cm", args.map_noise_cm]
    off = sweep(args.work, f"{args.sequence}_off", [*base, "--cbknn", "off"], commands)
    grid = sweep(args.work, f"{args.sequence}_grid", [*base, "--cbknn", "paper", "--grid",
                                                      "cbknn.params.alpha=" + ",".join(ALPHA), "--grid",
                                                      "cbknn.params.k0=" + ",".join(K0), "--grid",
                                                      "cbknn.params.beta=" + ",".join(BETA)], commands)
    table = []
    ate, std, n = mean_std(r["ate_rmse_cm"] for r in off)
    table.append(dict(mode="off", alpha="", k0="", beta="", ate_cm_mean=f"{ate:.4f}", ate_cm_std=f"{std:.4f}",
                      seeds=n))
    keys = ("cbknn.params.alpha", "cbknn.params.k0", "cbknn.params.beta")
    for key in dict.fromkeys(tuple(r[k] for k in keys) for r in grid):
        group = [r for r in grid if tuple(r[k] for k in keys) == key]
        ate, std, n = mean_std(r["ate_rmse_cm"] for r in group)
        table.append(dict(mode="paper", alpha=key[0], k0=key[1], beta=key[2], ate_cm_mean=f"{ate:.4f}",
                          ate_cm_std=f"{std:.4f}", seeds=n))
    write_result_csv(RESULTS / "cbknn_grid.csv", table, list(table[0]), commands)
    shutil.copyfile(args.work / f"{args.sequence}_grid" / "sweep.png", RESULTS / "cbknn_grid.png")
    print(f"wrote {RESULTS / 'cbknn_grid.png'}")


if __name__ == "__main__":
    main()
