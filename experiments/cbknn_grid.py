"""A small alpha x K0 x beta grid of CB-KNN (``paper`` mode) on one sequence as one vmapped `gsjax sweep`, against
``off`` with the same seeds, under map noise.

    python experiments/cbknn_grid.py --work /work/gsjax_study/grid --seeds 3 --frames 60 --sequence 7scenes

Writes ``experiments/results/cbknn_grid_80x60.csv`` (mean and std of the ATE over the seeds per grid point, n, and
the ``off`` baseline; each point's paired difference from ``off`` per seed with its 95 % bootstrap and t intervals;
the mean render PSNR) and ``cbknn_grid_80x60.png`` (paper - off over alpha x K0, a panel per beta, the points whose
intervals exclude zero starred). (The 40x30 study of 2026-12-01 wrote ``cbknn_grid.csv``.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from studies import RESULTS, SEQUENCES, mean_std, sweep, write_result_csv

from gsjax.eval.stats import paired_difference

ALPHA = ("0.1", "0.2", "0.4")  # px at the 80 px working width (the preset's 0.2)
K0 = ("4", "12")
BETA = ("0", "1")
KEEP = "cbknn_grid_80x60"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--map-noise-cm", default="1")
    parser.add_argument("--sequence", default="7scenes", choices=list(SEQUENCES))
    args = parser.parse_args()
    commands: list[str] = []
    base = [*SEQUENCES[args.sequence], "--max-frames", str(args.frames), "--seeds", str(args.seeds),
            "--noise.map_means_cm", args.map_noise_cm]
    off = sweep(args.work, f"{args.sequence}_off", [*base, "--cbknn", "off"], commands, keep=KEEP)
    grid = sweep(args.work, f"{args.sequence}_grid", [*base, "--cbknn", "paper", "--grid",
                                                      "cbknn.params.alpha=" + ",".join(ALPHA), "--grid",
                                                      "cbknn.params.k0=" + ",".join(K0), "--grid",
                                                      "cbknn.params.beta=" + ",".join(BETA)], commands, keep=KEEP)
    table = []
    ate, std, n = mean_std(r["ate_rmse_cm"] for r in off)
    psnr, _, _ = mean_std(r["psnr_db"] for r in off)
    table.append(dict(mode="off", alpha="", k0="", beta="", ate_cm_mean=f"{ate:.4f}", ate_cm_std=f"{std:.4f}", n=n,
                      difference="", ci_low="", ci_high="", t_low="", t_high="", excludes_zero="",
                      psnr_db_mean=f"{psnr:.3f}"))
    baseline = {r["seed"]: float(r["ate_rmse_cm"]) for r in off}
    keys = ("cbknn.params.alpha", "cbknn.params.k0", "cbknn.params.beta")
    for key in dict.fromkeys(tuple(r[k] for k in keys) for r in grid):
        group = [r for r in grid if tuple(r[k] for k in keys) == key]
        ate, std, n = mean_std(r["ate_rmse_cm"] for r in group)
        psnr, _, _ = mean_std(r["psnr_db"] for r in group)
        seeds = [r["seed"] for r in group if r["seed"] in baseline]
        found = paired_difference([baseline[s] for s in seeds],
                                  [float(r["ate_rmse_cm"]) for r in group if r["seed"] in baseline])
        table.append(dict(mode="paper", alpha=key[0], k0=key[1], beta=key[2], ate_cm_mean=f"{ate:.4f}",
                          ate_cm_std=f"{std:.4f}", n=n, difference=f"{found.mean:.4f}", ci_low=f"{found.low:.4f}",
                          ci_high=f"{found.high:.4f}", t_low=f"{found.t_low:.4f}", t_high=f"{found.t_high:.4f}",
                          excludes_zero=found.excludes_zero, psnr_db_mean=f"{psnr:.3f}"))
    write_result_csv(RESULTS / "cbknn_grid_80x60.csv", table, list(table[0]), commands)
    plot(table, RESULTS / "cbknn_grid_80x60.png", args.sequence)


def plot(table: list[dict], path: Path, sequence: str) -> None:
    """paper - off (ATE, cm) over alpha x K0, a panel per beta; a star where both 95 % intervals exclude zero."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    grid = [r for r in table if r["mode"] == "paper"]
    alphas, k0s, betas = (list(dict.fromkeys(r[k] for r in grid)) for k in ("alpha", "k0", "beta"))
    reach = max(abs(float(r["difference"])) for r in grid)
    fig = Figure(figsize=(4.2 * len(betas) + 1, 3.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = []
    for n, beta in enumerate(betas):
        ax = fig.add_subplot(1, len(betas), n + 1)
        axes.append(ax)
        cells = np.full((len(k0s), len(alphas)), np.nan)
        for r in (r for r in grid if r["beta"] == beta):
            j, i = k0s.index(r["k0"]), alphas.index(r["alpha"])
            cells[j, i] = float(r["difference"])
            star = " *" if r["excludes_zero"] else ""
            ax.text(i, j, f"{cells[j, i]:+.3f}{star}\n[{float(r['ci_low']):+.3f}, {float(r['ci_high']):+.3f}]",
                    ha="center", va="center", fontsize=7,
                    color="white" if abs(cells[j, i]) > 0.6 * reach else "black")
        image = ax.imshow(cells, cmap="RdBu_r", vmin=-reach, vmax=reach, aspect="auto", origin="lower")
        ax.set_xticks(range(len(alphas)), alphas, fontsize=7)
        ax.set_yticks(range(len(k0s)), k0s, fontsize=7)
        ax.set_xlabel("alpha (px at 80 px wide)")
        ax.set_ylabel("K0")
        ax.set_title(f"beta = {beta}", fontsize=8)
    fig.colorbar(image, ax=axes, label="ATE paper - off (cm)")
    n = grid[0]["n"]
    fig.suptitle(f"{sequence}: paper - off per seed, mean and 95 % bootstrap interval (n = {n}; * both intervals "
                 "exclude 0)", fontsize=9)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
