"""Where the error of a run enters: the unaligned camera error per frame, and what goes with it.

    python experiments/drift_curve.py RUN_DIR [RUN_DIR ...] --name 7scenes_150

For each finished ``gsjax run`` directory with ground truth: per frame, the camera error without alignment (the ground
truth started at the first estimated pose, :func:`gsjax.eval.trajectory.drift`) in cm and degrees and its change
from the previous frame, beside the tracking loss, the valid depth and the ground truth's motion (cm, degrees).
Writes ``experiments/results/drift_NAME.csv`` (one row per run and frame; the command in its header) and
``drift_NAME.png`` (the runs' curves, one panel per column).
"""

from __future__ import annotations

import argparse
import csv
import io
import shlex
import sys
from pathlib import Path

import numpy as np

from gsjax.camera import rotation_angle_np, se3_inverse_np
from gsjax.io.run_folder import read_run
from gsjax.report.figures import Series, series_png

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
COLUMNS = ("run", "frame", "error_cm", "error_deg", "change_cm", "tracking_loss", "depth_valid", "gt_motion_cm",
           "gt_motion_deg")


def rows_of(path: Path) -> list[dict]:
    """The per-frame rows of the run in ``path`` (empty without ground truth)."""
    run = read_run(path)
    found = run.drift()
    if found is None:
        return []
    gt = run.ground_truth_in_map()[1]  # the GT poses of found.frames, in order
    steps = se3_inverse_np(gt[:-1]) @ gt[1:]
    gt_cm = np.concatenate([[0.0], 100 * np.linalg.norm(steps[:, :3, 3], axis=1)])
    gt_deg = np.concatenate([[0.0], np.degrees(rotation_angle_np(steps[:, :3, :3]))])
    per_frame = run.metrics.per_frame
    series = lambda name, t: per_frame[name][t] if name in per_frame else None  # noqa: E731
    change = np.concatenate([[0.0], np.diff(found.error_m)])
    return [dict(run=run.name, frame=int(t), error_cm=100 * found.error_m[i], error_deg=found.error_deg[i],
                 change_cm=100 * change[i], tracking_loss=series("tracking_loss", t),
                 depth_valid=series("depth_valid", t), gt_motion_cm=gt_cm[i], gt_motion_deg=gt_deg[i])
            for i, t in enumerate(found.frames)]


def figure(rows: list[dict]) -> bytes:
    runs = list(dict.fromkeys(r["run"] for r in rows))
    panels = []
    for column, label in (("error_cm", "camera error, unaligned (cm)"), ("change_cm", "its change per frame (cm)"),
                          ("tracking_loss", "tracking loss"), ("gt_motion_cm", "motion per frame (cm, GT)"),
                          ("gt_motion_deg", "rotation per frame (deg, GT)")):
        lines = []
        for name in runs:
            mine = [r for r in rows if r["run"] == name and r[column] is not None]
            lines.append(Series(name, np.array([r["frame"] for r in mine]),
                                np.array([r[column] for r in mine], float)))
        panels.append((label, lines))
    return series_png(panels)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="finished gsjax run directories")
    parser.add_argument("--name", required=True, help="results/drift_NAME.csv and .png")
    args = parser.parse_args(argv)
    rows = [row for path in args.runs for row in rows_of(path)]
    if not rows:
        parser.error("no run with ground truth")
    buffer = io.StringIO()
    buffer.write("# python experiments/drift_curve.py " + shlex.join(sys.argv[1:] if argv is None else argv) + "\n")
    table = csv.DictWriter(buffer, COLUMNS, lineterminator="\n")
    table.writeheader()
    for row in rows:
        table.writerow({k: (f"{v:.5g}" if isinstance(v, float) else v) for k, v in row.items()})
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"drift_{args.name}.csv").write_text(buffer.getvalue())
    (RESULTS / f"drift_{args.name}.png").write_bytes(figure(rows))
    print(f"wrote {RESULTS / f'drift_{args.name}.csv'} and .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
