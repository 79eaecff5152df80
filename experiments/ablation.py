"""The paper's ablation (its Table 6) on our data: which part of CB-KNN matters. Position smoothing only, colour
smoothing only, both; a fixed K (beta = 0: K = K0 everywhere) vs the adaptive K; truncate (paper-literal) vs
hybrid compositing; against ``off``, over several seeds, on the noisy synthetic room and the 7-Scenes sample, with
map noise (CB-KNN's use case: tracking against noisy Gaussians).

    python experiments/ablation.py --work /work/gsjax_study/ablation --seeds 3 --frames 60 --map-noise-cm 1

Map noise is fresh per frame, or with ``--persistent`` added once to the stored map at frame ``frames // 6``.
Writes ``experiments/results/ablation_80x60.csv`` (mean and std over the seeds, n), ``ablation_80x60_paired.csv``
(each variant - off per seed, mean and 95 % bootstrap interval) and ``ablation_80x60.png``; with ``--persistent``
``ablation_80x60_persistent.*`` instead, its sweeps kept apart. (The 40x30 study of 2026-12-01 wrote
``ablation.csv``.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from studies import AVAILABLE_FRAMES, RESULTS, SEQUENCES, mean_std, paired_rows, sweep, write_result_csv

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
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--map-noise-cm", default="1")
    parser.add_argument("--persistent", action="store_true", help="the map noise persists in the stored map")
    parser.add_argument("--sequences", default=",".join(SEQUENCES))
    parser.add_argument("--variants", default=",".join(VARIANTS), help="a subset of " + ",".join(VARIANTS))
    args = parser.parse_args()
    if unknown := set(args.variants.split(",")) - set(VARIANTS):
        parser.error(f"--variants: unknown {', '.join(sorted(unknown))} (choose from {', '.join(VARIANTS)})")
    variants = {name: VARIANTS[name] for name in args.variants.split(",")}
    study = "ablation_80x60_persistent" if args.persistent else "ablation_80x60"
    commands: list[str] = []
    rows = []
    for name in args.sequences.split(","):
        frames = min(args.frames, AVAILABLE_FRAMES[name] or args.frames)
        noise = (["--noise.persistent_means_cm", args.map_noise_cm, "--noise.persistent_frame",
                  str(max(1, frames // 6))] if args.persistent else ["--noise.map_means_cm", args.map_noise_cm])
        for variant, (mode, extra) in variants.items():
            argv = [*SEQUENCES[name], "--max-frames", str(frames), "--seeds", str(args.seeds), "--cbknn", mode,
                    *noise, *extra]
            if mode == "paper":  # adaptive K (the preset's beta) and a fixed K (beta = 0) in one program
                argv += ["--grid", "cbknn.params.beta=0.3,0"]
            tag = f"{name}_{variant}" + ("_persistent" if args.persistent else "")
            for r in sweep(args.work, tag, argv, commands, keep=study):
                k = "fixed" if r.get("cbknn.params.beta") == "0" else "adaptive"
                label = variant if mode == "off" else f"{variant}/{k}_K"
                rows.append(dict(r, sequence=name, variant=label))
    table = []
    for key in dict.fromkeys((r["sequence"], r["variant"]) for r in rows):
        group = [r for r in rows if (r["sequence"], r["variant"]) == key]
        ate, ate_std, n = mean_std(r["ate_rmse_cm"] for r in group)
        psnr, psnr_std, _ = mean_std(r["psnr_db"] for r in group)
        table.append(dict(sequence=key[0], variant=key[1], ate_cm_mean=f"{ate:.4f}", ate_cm_std=f"{ate_std:.4f}",
                          psnr_db_mean=f"{psnr:.3f}", psnr_db_std=f"{psnr_std:.3f}", n=n))
    paired = []
    for variant in dict.fromkeys(r["variant"] for r in rows if r["variant"] != "off"):
        for row in paired_rows(rows, ["sequence"], "ate_rmse_cm", a="off", b=variant, label="variant"):
            paired.append({"variant": variant, **{k: (f"{v:.4f}" if isinstance(v, float) else v)
                                                  for k, v in row.items()}})
    write_result_csv(RESULTS / f"{study}.csv", table, list(table[0]), commands)
    write_result_csv(RESULTS / f"{study}_paired.csv", paired, list(paired[0]), commands)
    plot(table, RESULTS / f"{study}.png")


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
