"""How well a trajectory explains the raw images: the ground truth's and a run's, side by side.

    python experiments/gt_consistency.py RUN_DIR [RUN_DIR ...] --dataset 7scenes --path DIR --name 7scenes_150

A trajectory that is right maps frame i's depth onto frame j's: back-project frame i's valid depth pixels (the native
resolution, every ``--step``-th pixel), move them by the relative pose T_j^-1 T_i, project them into frame j and
compare with j's depth (the median absolute difference, mm) and, where they are visible there (depth within 3 cm),
with j's colour (the mean absolute difference of grey levels, 0-255; colour registered to depth as the reader does).
Only relative poses enter, so neither trajectory is aligned to the other. Pairs (i, i + gap) for each gap, spread
evenly over the sequence. Writes ``experiments/results/gt_consistency_NAME.csv`` (the command in its header) and
``.png``.

Both numbers grow with the gap (more of the view is new, occlusions, the sensor's own errors); what matters is which
trajectory is lower at the same pairs. The ground truth of 7-Scenes is KinectFusion's tracking, not a measurement.
"""

from __future__ import annotations

import argparse
import csv
import io
import shlex
import sys
from pathlib import Path

import numpy as np

from gsjax.camera import backproject, invert_transform
from gsjax.data import open_sequence
from gsjax.io.run_folder import read_run
from gsjax.report.figures import Series, series_png

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
COLUMNS = ("trajectory", "gap", "pairs", "depth_median_mm", "grey_mean_abs")
VISIBLE_M = 0.03


def pair_errors(depth_i, grey_i, depth_j, grey_j, j_from_i: np.ndarray, intrinsics, step: int) -> tuple[float, float]:
    """(median |depth difference| in mm, mean |grey difference|) of frame i's sampled valid pixels seen in frame j."""
    points = np.asarray(backproject(depth_i, intrinsics), np.float64)[::step, ::step]
    valid = depth_i[::step, ::step] > 0
    moved = points[valid] @ j_from_i[:3, :3].T + j_from_i[:3, 3]
    z = moved[:, 2]
    ahead = z > 1e-3
    u = np.round(float(intrinsics.fx) * moved[:, 0] / np.where(ahead, z, 1) + float(intrinsics.cx)).astype(int)
    v = np.round(float(intrinsics.fy) * moved[:, 1] / np.where(ahead, z, 1) + float(intrinsics.cy)).astype(int)
    height, width = depth_j.shape
    inside = ahead & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    u, v, z = u[inside], v[inside], z[inside]
    seen = depth_j[v, u]
    measured = seen > 0
    difference = np.abs(seen[measured] - z[measured])
    visible = difference < VISIBLE_M
    grey_from_i = grey_i[::step, ::step][valid][inside][measured][visible]
    grey_in_j = grey_j[v[measured][visible], u[measured][visible]]
    return float(1000 * np.median(difference)), float(np.mean(np.abs(grey_in_j - grey_from_i)))


def consistency(sequence, trajectories: dict[str, np.ndarray], gaps: list[int], pairs: int, step: int) -> list[dict]:
    """Rows (trajectory, gap, pairs, depth_median_mm, grey_mean_abs): the means over ``pairs`` pairs per gap of
    :func:`pair_errors`, for each camera-to-world trajectory [T, 4, 4] in ``trajectories``."""
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def frame(t: int):
        if t not in cache:
            host = sequence.read_host(t)
            grey = 255 * (np.asarray(host.color, np.float64) @ np.array([0.299, 0.587, 0.114]))
            cache[t] = (np.asarray(host.depth, np.float32), grey)
        return cache[t]

    rows = []
    for gap in gaps:
        starts = np.unique(np.linspace(0, len(sequence) - 1 - gap, pairs).round().astype(int))
        for name, c2w in trajectories.items():
            errors = [pair_errors(*frame(i), *frame(i + gap), invert_transform(c2w[i + gap]) @ c2w[i],
                                  sequence.intrinsics, step) for i in starts]
            depth_mm, grey = np.mean(errors, axis=0)
            rows.append(dict(trajectory=name, gap=gap, pairs=len(starts), depth_median_mm=float(depth_mm),
                             grey_mean_abs=float(grey)))
    return rows


def figure(rows: list[dict]) -> bytes:
    names = list(dict.fromkeys(r["trajectory"] for r in rows))
    panels = []
    for column, label in (("depth_median_mm", "depth, median |diff| (mm)"), ("grey_mean_abs", "grey, mean |diff|")):
        lines = [Series(name, np.array([r["gap"] for r in rows if r["trajectory"] == name]),
                        np.array([r[column] for r in rows if r["trajectory"] == name])) for name in names]
        panels.append((label, lines))
    return series_png(panels, xlabel="frame gap", markers=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished gsjax run directories on this sequence")
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--path", required=True)
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--name", required=True, help="results/gt_consistency_NAME.csv and .png")
    parser.add_argument("--gaps", default="5,10,20,40,70,100")
    parser.add_argument("--pairs", type=int, default=12, help="pairs per gap")
    parser.add_argument("--step", type=int, default=2, help="use every step-th pixel of frame i")
    args = parser.parse_args(argv)
    sequence = open_sequence(args.dataset, args.path, max_frames=args.max_frames)
    timestamps, gt_c2w, gt_valid = sequence.gt_trajectory()
    if not gt_valid.all():
        parser.error("the sequence's ground truth has invalid poses")
    trajectories = {"ground truth": gt_c2w}
    for path in args.runs:
        run = read_run(path)
        if len(run.est_c2w) != len(sequence) or not np.allclose(run.timestamps, timestamps):
            parser.error(f"{path}: its frames are not the sequence's {len(sequence)} (use the run's --max-frames)")
        trajectories[run.name] = run.est_c2w
    gaps = [int(g) for g in args.gaps.split(",")]
    rows = consistency(sequence, trajectories, gaps, args.pairs, args.step)
    buffer = io.StringIO()
    buffer.write("# python experiments/gt_consistency.py " + shlex.join(sys.argv[1:] if argv is None else argv) + "\n")
    table = csv.DictWriter(buffer, COLUMNS, lineterminator="\n")
    table.writeheader()
    for row in rows:
        table.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"gt_consistency_{args.name}.csv").write_text(buffer.getvalue())
    (RESULTS / f"gt_consistency_{args.name}.png").write_bytes(figure(rows))
    print(buffer.getvalue(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
