"""Robustness study: ATE of CB-KNN ``off`` vs ``paper`` under map noise, depth noise and faster motion (frame
stride), over several seeds, on the noisy synthetic room and the 7-Scenes kitchen sample.

    python experiments/robustness.py --work /tmp/gsjax_robustness --seeds 5 --frames 18

Map noise: N(0, sigma) cm on every mean of the map a frame's tracking renders (noise.map_means_cm, drawn afresh
per frame; the stored map is untouched). Depth noise: N(0, sigma) cm on every valid input depth pixel
(noise.depth_cm). Stride: every s-th frame (``--stride``). Each factor is one `gsjax sweep` per sequence (the noise
levels and seeds as one vmapped program per CB-KNN mode). Writes ``experiments/results/robustness.csv`` (mean and
std of the ATE over the seeds) and ``robustness.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from studies import RESULTS, SEQUENCES, mean_std, sweep, write_result_csv

MAP_NOISE_CM = ("0", "1", "2")
DEPTH_NOISE_CM = ("2", "4")  # 0 is the map-noise sweep's 0 row
STRIDES = (2, 4, 8)  # 1 likewise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="where the sweeps run (outside git)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=18)
    parser.add_argument("--sequences", default=",".join(SEQUENCES))
    args = parser.parse_args()
    common = ["--max-frames", str(args.frames), "--seeds", str(args.seeds), "--grid", "cbknn.mode=off,paper"]
    commands: list[str] = []
    rows = []
    for name in args.sequences.split(","):
        data = SEQUENCES[name]
        found = sweep(args.work, f"{name}_map", [*data, *common, "--grid",
                                                   "noise.map_means_cm=" + ",".join(MAP_NOISE_CM)], commands)
        for r in found:
            rows.append(dict(r, sequence=name, factor="map_noise_cm", level=r["noise.map_means_cm"]))
            if float(r["noise.map_means_cm"]) == 0.0:  # the clean run is level 0 of every factor
                rows.append(dict(r, sequence=name, factor="depth_noise_cm", level="0"))
                rows.append(dict(r, sequence=name, factor="stride", level="1"))
        found = sweep(args.work, f"{name}_depth", [*data, *common, "--grid",
                                                     "noise.depth_cm=" + ",".join(DEPTH_NOISE_CM)], commands)
        rows += [dict(r, sequence=name, factor="depth_noise_cm", level=r["noise.depth_cm"]) for r in found]
        for stride in STRIDES:
            found = sweep(args.work, f"{name}_stride{stride}", [*data, *common, "--stride", str(stride)], commands)
            rows += [dict(r, sequence=name, factor="stride", level=str(stride)) for r in found]

    table = []
    for key in dict.fromkeys((r["sequence"], r["factor"], r["level"], r["cbknn.mode"]) for r in rows):
        group = [r for r in rows if (r["sequence"], r["factor"], r["level"], r["cbknn.mode"]) == key]
        ate, ate_std, n = mean_std(r["ate_rmse_cm"] for r in group)
        psnr, psnr_std, _ = mean_std(r["psnr_db"] for r in group)
        table.append(dict(sequence=key[0], factor=key[1], level=key[2], mode=key[3], ate_cm_mean=f"{ate:.4f}",
                          ate_cm_std=f"{ate_std:.4f}", psnr_db_mean=f"{psnr:.3f}", psnr_db_std=f"{psnr_std:.3f}",
                          seeds=n))
    write_result_csv(RESULTS / "robustness.csv", table, list(table[0]), commands)
    plot(table, RESULTS / "robustness.png")


def plot(table: list[dict], path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    sequences = list(dict.fromkeys(r["sequence"] for r in table))
    factors = list(dict.fromkeys(r["factor"] for r in table))
    fig = Figure(figsize=(4.2 * len(factors), 3.4 * len(sequences)), layout="constrained")
    FigureCanvasAgg(fig)
    for i, sequence in enumerate(sequences):
        for j, factor in enumerate(factors):
            ax = fig.add_subplot(len(sequences), len(factors), i * len(factors) + j + 1)
            for mode, colour, shift in (("off", "tab:blue", -0.02), ("paper", "tab:orange", 0.02)):
                pts = sorted((float(r["level"]), float(r["ate_cm_mean"]), float(r["ate_cm_std"])) for r in table
                             if (r["sequence"], r["factor"], r["mode"]) == (sequence, factor, mode))
                if not pts:
                    continue
                x, y, e = map(np.asarray, zip(*pts))
                ax.errorbar(x * (1 + shift) if factor == "stride" else x + shift * (x.max() or 1), y, yerr=e,
                            color=colour, marker="o", markersize=3, capsize=2, label=mode)
            if factor == "stride":
                ax.set_xscale("log", base=2)
            ax.set_xlabel(factor.replace("_", " "))
            ax.set_ylabel("ATE RMSE (cm), mean +- std")
            ax.set_title(sequence, fontsize=9)
            ax.grid(True, linewidth=0.3)
            ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
