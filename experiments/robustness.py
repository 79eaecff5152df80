"""Robustness study: ATE of CB-KNN ``off`` vs ``paper`` under map noise (fresh per frame, or persistent in the stored
map), depth noise and faster motion (frame stride), paired over seeds, at the cpu preset's 80x60.

    python experiments/robustness.py --work /work/gsjax_study/robustness --seeds 5 --frames 60

Conditions, each one `gsjax sweep` per sequence (``--grid cbknn.mode=off,paper`` and ``--seeds``: ``off`` and ``paper``
run on the same seeds, so each seed is a pair):

- clean, and fresh map noise: N(0, sigma) cm on every mean of the map a frame's tracking renders, drawn afresh per
  frame, the stored map untouched (``noise.map_means_cm``); ``map_strong`` (only when named in ``--conditions``)
  the same at 2 and 3 cm;
- persistent map noise: N(0, sigma) cm added once to every mean of the stored map as frame ``frames // 6`` starts
  (frame 10 of 60) and left there (``noise.persistent_means_cm``, ``noise.persistent_frame``): the paper's noisy
  Gaussian parameters;
- depth noise: N(0, sigma) cm on every valid input depth pixel (``noise.depth_cm``);
- stride: every s-th frame (``--stride``; not on the 4-frame Replica sample);
- alternatives: at that stride (fast motion, where a wider basin should pay), ``off`` tracking with the textbook
  basin wideners instead of CB-KNN, paired with the stride sweep's ``off`` on the same seeds: ``blur`` (residuals
  blurred by a 1.5 px Gaussian, :func:`gsjax.slam.presets.with_image_smoothing`) and ``pyramid`` (20 of the 30
  strided iterations replaced by full ones on residuals blurred at 2 then 1 px, ``with_coarse_to_fine``), as in
  ``experiments/landscapes.py``.

A sweep already finished in ``--work``, or kept in ``experiments/results/runs/robustness_80x60/``, is reused, so an
interrupted study continues; ``--sequences`` and ``--conditions`` select parts, and the rows of the CSVs below that
this run did not produce (and whose runs were not kept) stay as they were. Writes
``experiments/results/robustness_80x60.csv`` (mean and std over the seeds, n), ``robustness_80x60_paired.csv``
(paper - off per seed: the mean difference and its 95 % bootstrap interval, whether it excludes zero) and
``robustness_80x60.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import studies
from studies import AVAILABLE_FRAMES, RESULTS, SEQUENCES, mean_std, paired_rows, sweep, write_result_csv

# condition -> (factor, sweep flags); levels come from the grid values.
MAP_NOISE_CM = ("0", "1")
STRONG_MAP_NOISE_CM = ("2", "3")
PERSISTENT_NOISE_CM = ("1", "2")
DEPTH_NOISE_CM = ("2",)
STRIDES = (4,)
CONDITIONS = ("map", "persistent", "depth", "stride", "alternatives")
# run only when asked (``--conditions map_strong``): fresh map noise at the levels where CB-KNN's one win could grow
OPTIONAL_CONDITIONS = ("map_strong",)
# the cpu preset's flags for presets.with_image_smoothing and with_coarse_to_fine (its 30 strided iterations)
ALTERNATIVES = {
    "blur": ["--tracking.blur.radius_px", "6", "--tracking.blur.sigma_px", "1.5"],
    "pyramid": ["--tracking.blur.radius_px", "6", "--tracking.coarse.iters", "20", "--tracking.coarse.levels", "2",
                "--tracking.coarse.sigma_px", "1", "--tracking.strided_iters", "10"],
}
STUDY = "robustness_80x60"
# a result row's factor -> the condition (sweep name suffix) it came from
SWEEP_OF_FACTOR = {"clean": "map", "map_noise_cm": "map", "persistent_noise_cm": "persistent",
                   "depth_noise_cm": "depth"}


def sweep_name(row: dict) -> str:
    condition = SWEEP_OF_FACTOR.get(row["factor"], row["factor"] + row["level"])
    if row["factor"] == "map_noise_cm" and row["level"] in STRONG_MAP_NOISE_CM:
        condition = "map_strong"
    name = f"{row['sequence']}_{condition}"
    alternative = row.get("mode", row.get("b"))
    return f"{name}_{alternative}" if alternative in ALTERNATIVES else name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="where the sweeps run (outside git)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--sequences", default=",".join(SEQUENCES))
    parser.add_argument("--conditions", default=",".join(CONDITIONS))
    args = parser.parse_args()
    commands: list[str] = []
    rows = []
    conditions = args.conditions.split(",")
    unknown = sorted(set(conditions) - set(CONDITIONS) - set(OPTIONAL_CONDITIONS))
    if unknown:
        parser.error(f"unknown condition(s) {', '.join(unknown)}; choose from "
                     f"{', '.join(CONDITIONS + OPTIONAL_CONDITIONS)}")
    for name in args.sequences.split(","):
        frames = min(args.frames, AVAILABLE_FRAMES[name] or args.frames)
        base = [*SEQUENCES[name], "--max-frames", str(frames), "--seeds", str(args.seeds)]
        common = [*base, "--grid", "cbknn.mode=off,paper"]

        def run(tag, extra, flags=common):
            return sweep(args.work, f"{name}_{tag}", [*flags, *extra], commands, keep=STUDY)

        if "map" in conditions:
            for r in run("map", ["--grid", "noise.map_means_cm=" + ",".join(MAP_NOISE_CM)]):
                level = r["noise.map_means_cm"]
                clean = float(level) == 0.0  # the baseline of every factor
                rows.append(dict(r, sequence=name, factor="clean" if clean else "map_noise_cm",
                                 level="" if clean else level))
        if "map_strong" in conditions:
            for r in run("map_strong", ["--grid", "noise.map_means_cm=" + ",".join(STRONG_MAP_NOISE_CM)]):
                rows.append(dict(r, sequence=name, factor="map_noise_cm", level=r["noise.map_means_cm"]))
        if "persistent" in conditions:
            at = str(max(1, frames // 6))
            for r in run("persistent", ["--grid", "noise.persistent_means_cm=" + ",".join(PERSISTENT_NOISE_CM),
                                        "--noise.persistent_frame", at]):
                rows.append(dict(r, sequence=name, factor="persistent_noise_cm", level=r["noise.persistent_means_cm"]))
        if "depth" in conditions:
            for r in run("depth", ["--grid", "noise.depth_cm=" + ",".join(DEPTH_NOISE_CM)]):
                rows.append(dict(r, sequence=name, factor="depth_noise_cm", level=r["noise.depth_cm"]))
        if "stride" in conditions and frames > 8:
            for stride in STRIDES:
                for r in run(f"stride{stride}", ["--stride", str(stride)]):
                    rows.append(dict(r, sequence=name, factor="stride", level=str(stride)))
        if "alternatives" in conditions and frames > 8:
            stride = STRIDES[0]
            for alternative, flags in ALTERNATIVES.items():
                for r in run(f"stride{stride}_{alternative}", ["--stride", str(stride), "--cbknn", "off", *flags],
                             base):
                    rows.append(dict(r, sequence=name, factor="stride", level=str(stride),
                                     **{"cbknn.mode": alternative}))

    keys = ["sequence", "factor", "level"]
    table = []
    for key in dict.fromkeys(tuple(r[k] for k in [*keys, "cbknn.mode"]) for r in rows):
        group = [r for r in rows if tuple(r[k] for k in [*keys, "cbknn.mode"]) == key]
        ate, ate_std, n = mean_std(r["ate_rmse_cm"] for r in group)
        psnr, psnr_std, _ = mean_std(r["psnr_db"] for r in group)
        table.append(dict(sequence=key[0], factor=key[1], level=key[2], mode=key[3], ate_cm_mean=f"{ate:.4f}",
                          ate_cm_std=f"{ate_std:.4f}", psnr_db_mean=f"{psnr:.3f}", psnr_db_std=f"{psnr_std:.3f}",
                          n=n))
    paired = []
    for metric in ("ate_rmse_cm", "psnr_db"):
        for row in [r for b in ("paper", *ALTERNATIVES) for r in paired_rows(rows, keys, metric, b=b)]:
            paired.append({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})
    earlier, old_table = studies.carried_over(RESULTS / f"{STUDY}.csv", [*keys, "mode"], table, sweep_name)
    _, old_paired = studies.carried_over(RESULTS / f"{STUDY}_paired.csv", [*keys, "metric"], paired, sweep_name)
    table, paired = old_table + table, old_paired + paired
    write_result_csv(RESULTS / f"{STUDY}.csv", table, list(table[0]), earlier + commands)
    write_result_csv(RESULTS / f"{STUDY}_paired.csv", paired, list(paired[0]), earlier + commands)
    plot(paired, RESULTS / "robustness_80x60.png")


MODE_COLOURS = {"paper": "tab:orange", "blur": "tab:green", "pyramid": "tab:purple"}
FACTOR_ORDER = ("clean", "map_noise_cm", "persistent_noise_cm", "depth_noise_cm", "stride")


def _plot_order(row: dict) -> tuple:
    """Conditions in the study's order, levels ascending, ``paper`` before the alternatives."""
    factor = FACTOR_ORDER.index(row["factor"]) if row["factor"] in FACTOR_ORDER else len(FACTOR_ORDER)
    return factor, float(row["level"] or 0), list(MODE_COLOURS).index(row["b"]) if row["b"] in MODE_COLOURS else 0


def plot(paired: list[dict], path: Path) -> None:
    """Paired differences paper (or an alternative) - off (ATE, cm) with their 95 % intervals, a panel per sequence."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ate = [r for r in paired if r["metric"] == "ate_rmse_cm"]
    sequences = list(dict.fromkeys(r["sequence"] for r in ate))
    fig = Figure(figsize=(7.5, 0.8 + 2.8 * len(sequences)), layout="constrained")
    FigureCanvasAgg(fig)
    for i, sequence in enumerate(sequences):
        ax = fig.add_subplot(len(sequences), 1, i + 1)
        mine = sorted((r for r in ate if r["sequence"] == sequence), key=_plot_order)
        labels = [f"{r['factor']} {r['level']} (n={r['n']})".replace("  ", " ") for r in mine]
        y = np.array([float(r["difference"]) for r in mine])
        low = y - np.array([float(r["ci_low"]) for r in mine])
        high = np.array([float(r["ci_high"]) for r in mine]) - y
        x = np.arange(len(mine))
        for mode, colour in MODE_COLOURS.items():
            at = np.array([r["b"] == mode for r in mine])
            if at.any():
                ax.errorbar(x[at], y[at], yerr=[np.nan_to_num(low[at]), np.nan_to_num(high[at])], fmt="o",
                            capsize=3, color=colour, label=f"{mode} - off")
        ax.legend(fontsize=7)
        ax.axhline(0.0, color="grey", linewidth=0.8)
        ax.set_xticks(x, labels, rotation=20, fontsize=7)
        ax.set_ylabel("ATE mode - off (cm)")
        ax.set_title(f"{sequence}: mean paired difference, 95 % bootstrap interval", fontsize=9)
        ax.grid(True, linewidth=0.3)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
