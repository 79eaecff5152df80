"""``gsjax eval``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from gsjax.app.cli import common
from gsjax.config.names import BAGS, DATASETS


def add(sub) -> None:
    p = sub.add_parser("eval", help="trajectory metrics (ATE, RPE) of an estimate against ground truth",
                       parents=[common.COMMON])
    p.add_argument("--est", type=Path, required=True,
                   help="estimated trajectory, TUM format (camera-to-world), or a run's folder (its trajectory.txt)")
    p.add_argument("--gt", type=Path, required=True,
                   help="ground truth: a TUM trajectory file, or a dataset directory (with --dataset)")
    p.add_argument("--dataset", choices=DATASETS + BAGS, default=None,
                   help="layout of the --gt directory; its GT poses are taken at the dataset's frame timestamps "
                        "(the frame numbers for replica, scannet and 7scenes, which have no timestamps); rosbag: "
                        "--gt is a bag and its /tf between --gt-frames is the ground truth")
    p.add_argument("--gt-frames", type=common.frame_pair, default=None, metavar="PARENT,CHILD",
                   help="with --dataset rosbag: the /tf transform PARENT -> CHILD is the camera-to-world pose")
    p.add_argument("--out", type=Path, default=None, help="metrics JSON (default: <est without suffix>.metrics.json)")
    p.add_argument("--scale", action="store_true", help="also align the scale (similarity / Umeyama)")
    p.add_argument("--max-dt", type=float, default=0.02, help="timestamp association tolerance in s (default 0.02)")
    p.add_argument("--plots", type=Path, default=None, help="also write trajectory and error plots into this directory")
    p.set_defaults(func=run)


def _read_ground_truth(gt: Path, dataset: str | None, gt_frames: tuple[str, str] | None = None):
    """(timestamps [M] s, c2w [M, 4, 4] float64, valid [M] bool or None) from a TUM file, a dataset directory or a
    bag's /tf."""
    if (dataset in BAGS) != (gt_frames is not None):
        raise common.UserError("--dataset rosbag and --gt-frames PARENT,CHILD go together (the bag's /tf is its "
                               "ground truth)")
    if dataset in BAGS:
        if not gt.exists():
            raise common.UserError(f"--gt {gt}: no such bag file or folder")
        from gsjax.data.rosbag import read_bag_trajectory

        return (*read_bag_trajectory(gt, *gt_frames), None)
    if gt.is_dir():
        if dataset is None:
            raise common.UserError(
                f"--gt {gt} is a directory: --gt DIR needs --dataset {{{','.join(DATASETS)}}} "
                f"(the layout is not guessed), or give a TUM trajectory file"
            )
        from gsjax.data import open_sequence

        return common.dataset_warnings(lambda: open_sequence(dataset, gt).gt_trajectory())[0]  # reads no image
    if not gt.is_file():
        raise common.UserError(f"--gt {gt}: no such file")
    if dataset is not None:
        raise common.UserError(f"--dataset {dataset} needs --gt DIR, a dataset directory; {gt} is a file")
    from gsjax.io.trajectory import read_tum_trajectory

    return (*read_tum_trajectory(gt), None)


def run(args) -> int:
    import numpy as np

    from gsjax.eval.association import associate_timestamps
    from gsjax.eval.trajectory import ate_rmse_c2w, evaluate_trajectory
    from gsjax.io.atomic import atomic_write_json
    from gsjax.io.trajectory import read_tum_trajectory

    if args.est.is_dir():
        from gsjax.io.run_folder import TRAJECTORY

        if not (args.est / TRAJECTORY).is_file():
            raise common.UserError(f"--est {args.est}: a folder without {TRAJECTORY} (not a finished gsjax run)")
        args.est = args.est / TRAJECTORY
    if not args.est.is_file():
        raise common.UserError(f"--est {args.est}: no such file")
    if not (np.isfinite(args.max_dt) and args.max_dt >= 0):
        raise common.UserError(f"--max-dt must be a number >= 0, got {args.max_dt}")
    gt_t, gt_c2w, gt_valid = _read_ground_truth(args.gt, args.dataset, args.gt_frames)
    est_t, est_c2w = read_tum_trajectory(args.est)
    metrics = evaluate_trajectory(
        est_t, est_c2w, gt_t, gt_c2w, gt_valid=gt_valid, max_dt=args.max_dt, with_scale=args.scale
    )
    sources = {"est": str(args.est), "gt": str(args.gt)}
    if args.dataset is not None:
        sources["gt_dataset"] = args.dataset
    metrics = {**sources, **dataclasses.asdict(metrics)}
    out = args.out if args.out is not None else args.est.with_suffix(".metrics.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out, metrics)

    for key, value in metrics.items():
        if isinstance(value, float):
            print(f"{key:26s} {value:.6g}")
        elif isinstance(value, (int, bool)) or value is None:
            print(f"{key:26s} {value}")
    print(f"wrote {out}")

    if args.plots is not None:
        from gsjax.io.plots import plot_errors_over_time, plot_trajectory_top_view

        est_idx, gt_idx = associate_timestamps(est_t, gt_t, args.max_dt)
        used = None if gt_valid is None else gt_valid[gt_idx]
        ate = ate_rmse_c2w(est_c2w[est_idx], gt_c2w[gt_idx], used, with_scale=args.scale)
        est_aligned = ate.alignment.apply_points(est_c2w[est_idx][ate.used, :3, 3])
        args.plots.mkdir(parents=True, exist_ok=True)
        title = f"ATE RMSE (c2w) {100 * ate.value_m:.2f} cm"
        for path in (
            plot_trajectory_top_view(args.plots / "trajectory_top.png", est_aligned, gt_c2w[gt_idx][ate.used, :3, 3],
                                     title=title),
            plot_errors_over_time(args.plots / "ate_over_time.png", est_t[est_idx][ate.used],
                                  {"ATE (cm)": 100 * ate.errors_m}, ylabel="ATE (cm)", title=title),
        ):
            print(f"wrote {path}")
    return 0
