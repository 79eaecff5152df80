"""The paper's ablation (its Table 6) on our data: which part of CB-KNN matters. Position smoothing only, colour
smoothing only, both; a fixed K (beta = 0: K = K0 everywhere) vs the adaptive K; truncate (paper-literal) vs
hybrid compositing; against ``off``, over several seeds, on the noisy synthetic room and the 7-Scenes sample, with
map noise (CB-KNN's use case: tracking against noisy Gaussians).

    python experiments/ablation.py --work /tmp/gsjax_ablation --seeds 2 --frames 18 --map-noise-cm 1

Writes ``experiments/results/ablation.csv`` and ``ablation.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from studies import RESULTS, SEQUENCES, mean_std, sweep, write_result_csv

# variant -> (CB-KNN mode, extra overrides); "adaptive" rows also sweep beta = 0 (fixed K) in the same program.
VARIANTS = {
    "off": ("off", []),
    "both": ("paper", []),
    "position_only": ("paper", ["--cbknn.params.colour", "false"]),
    "colour_only": ("paper", ["--cbknn.params.position", "false"]),
    "truncate": ("paper", ["--cbknn.params.truncate", "true"]),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--frames", type=int, default=18)
    parser.add_argument("--map-noise-cm", default="1")
    parser.add_argument("--sequences", default=",".join(SEQUENCES))
    args = parser.parse_args()
    commands: list[str] = []
    rows = []
    for name in args.sequences.split(","):
        for variant, (mode, extra) in VARIANTS.items():
            argv = [*SEQUENCES[name], "--max-frames", str(args.frames), "--seeds", str(args.seeds), "--cbknn", mode,
                    "--noise.map_means_cm", args.map_noise_cm, *extra]
            if mode == "paper":  # adaptive K (the preset's beta) and a fixed K (beta = 0) in one program
                argv += ["--grid", "cbknn.params.beta=0.3,0"]
            for r in sweep(args.work, f"{name}_{variant}", argv, commands):
                k = "fixed" if r.get("cbknn.params.beta") == "0" else "adaptive"
                label = variant if mode == "off" else f"{variant}/{k}_K"
                rows.append(dict(r, sequence=name, variant=label))
    table = []
    for key in dict.fromkeys((r["sequence"], r["variant"]) for r in rows):
        group = [r for r in rows if (r["sequence"], r["variant"]) == key]
        ate, ate_std, n = mean_std(r["ate_rmse_cm"] for r in group)
        psnr, psnr_std, _ = mean_std(r["psnr_db"] for r in group)
        table.append(dict(sequence=key[0], variant=key[1], ate_cm_mean=f"{ate:.4f}", ate_cm_std=f"{ate_std:.4f}",
                          psnr_db_mean=f"{psnr:.3f}", psnr_db_std=f"{psnr_std:.3f}", seeds=n))
    write_result_csv(RESULTS / "ablation.csv", table, list(table[0]), commands)
    plot(table, RESULTS / "ablation.png")


def plot(table: list[dict], path: Path) -> None:
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    sequences = list(dict.fromkeys(r["sequence"] for r in table))
    fig = Figure(figsize=(5.5 * len(sequences), 3.8), layout="constrained")
    FigureCanvasAgg(fig)
    for i, sequence in enumerate(sequences):
        ax = fig.add_subplot(1, len(sequences), i + 1)
        rows = [r for r in table if r["sequence"] == sequence]
        y = np.arange(len(rows))
        ax.barh(y, [float(r["ate_cm_mean"]) for r in rows], xerr=[float(r["ate_cm_std"]) for r in rows],
                color=["tab:blue" if r["variant"] == "off" else "tab:orange" for r in rows], capsize=2)
        ax.set_yticks(y, [r["variant"] for r in rows], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("ATE RMSE (cm), mean +- std over seeds")
        ax.set_title(sequence, fontsize=9)
        ax.grid(True, axis="x", linewidth=0.3)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
