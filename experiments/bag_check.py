"""ROS bags against the folder layouts (issue 39), two checks:

``--sevenscenes DIR``: the 7-Scenes sample written as a ROS 1 bag with the RealSense driver's topic names (colour
``/camera/color/image_raw`` as raw ``rgb8`` holding the colour as gsjax's reader registers it to the depth camera,
depth ``/camera/aligned_depth_to_color/image_raw`` as ``16UC1`` millimetres, ``/camera/color/camera_info`` with the
depth camera's K) plus its ground truth as a TUM file; ``gsjax run --preset cpu`` on the folder and on the bag, one
after the other; prints whether the trajectories agree digit for digit and both ATEs.

``--memory-gb G``: a generated bag of about G GB (the synthetic room at 640x480, ten rendered frames repeated with
new stamps), then the process's resident memory while it is opened and every frame is read: it must not grow with
the bag's length.

    python experiments/bag_check.py --sevenscenes ../shared/data/7scenes_redkitchen --frames 40 --work /tmp/bags
    python experiments/bag_check.py --memory-gb 2 --work /tmp/bags
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def rss_mib() -> float:
    """The process's resident memory now (MiB), from /proc."""
    match = re.search(r"VmRSS:\s+(\d+) kB", Path("/proc/self/status").read_text())
    return int(match.group(1)) / 1024 if match else float("nan")


def sevenscenes(path: Path, frames: int, work: Path) -> dict:
    from gsjax.app.cli import main
    from gsjax.data import open_sequence, write_rosbag
    from gsjax.io.trajectory import write_tum_trajectory

    sequence = open_sequence("7scenes", path, max_frames=frames)  # colour registered to the depth camera
    bag = write_rosbag(sequence, work / "kitchen.bag", depth_scale=1000.0)
    times, c2w, valid = sequence.gt_trajectory()
    write_tum_trajectory(work / "kitchen_gt.txt", times[valid], c2w[valid])
    common = ["--preset", "cpu", "--max-frames", str(frames), "--no-progress", "--overwrite"]
    runs = {"folder": ["--dataset", "7scenes", "--path", str(path)],
            "bag": ["--dataset", "rosbag", "--path", str(bag), "--groundtruth", str(work / "kitchen_gt.txt")]}
    result = {}
    for name, source in runs.items():
        t0 = time.perf_counter()
        if main(["run", "--out", str(work / name), *source, *common]) != 0:
            raise SystemExit(f"the {name} run failed")
        metrics = json.loads((work / name / "metrics.json").read_text())
        poses = np.array([[float(x) for x in line.split()[1:]] for line in
                          (work / name / "trajectory.txt").read_text().splitlines() if line and line[0] != "#"])
        result[name] = dict(seconds=time.perf_counter() - t0, ate_cm=metrics["trajectory"]["ate_rmse_c2w_cm"],
                            psnr_db=metrics["render"]["mean"]["psnr_db"], poses=poses)
    difference = np.abs(result["bag"].pop("poses") - result["folder"].pop("poses"))
    first = np.flatnonzero(difference.max(axis=1) > 0)
    frame_bag, frame_folder = (open_sequence("rosbag", bag, max_frames=1).read_host(0),
                               open_sequence("7scenes", path, max_frames=1).read_host(0))
    result.update(identical=bool(difference.max() == 0), max_pose_difference=float(difference.max()),
                  first_differing_frame=int(first[0]) if first.size else None,
                  colour_difference_max=float(np.abs(frame_bag.color - frame_folder.color).max()),
                  depth_identical=bool(np.array_equal(frame_bag.depth, frame_folder.depth)))
    return result


def memory(gigabytes: float, work: Path) -> dict:
    from gsjax.data import open_sequence, write_rosbag
    from gsjax.data.sequence import Sequence
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence

    base = synthetic_sequence(SyntheticConfig(width=640, height=480, num_frames=10, supersample=1))
    rendered = [base.read_host(i) for i in range(10)]
    per_frame = 640 * 480 * (3 + 2)  # rgb8 + 16UC1 bytes
    count = int(gigabytes * 1e9 / per_frame)
    stamps = np.arange(count) / 30.0
    _, c2w, _ = base.gt_trajectory()
    sequence = Sequence(name="big", intrinsics=base.intrinsics, timestamps=stamps, c2w=c2w[np.arange(count) % 10],
                        pose_valid=np.ones(count, bool),
                        read_rgbd=lambda i: (rendered[i % 10].color, rendered[i % 10].depth))
    path = work / "big.bag"
    if path.exists():
        path.unlink()
    t0 = time.perf_counter()
    write_rosbag(sequence, path)
    written = time.perf_counter() - t0
    before = rss_mib()
    t0 = time.perf_counter()
    bag = open_sequence("rosbag", path, bag=None)
    opened, after_open = time.perf_counter() - t0, rss_mib()
    peak, samples = after_open, []
    t0 = time.perf_counter()
    for i in range(len(bag)):
        bag.read_host(i)
        if i % 100 == 0 or i == len(bag) - 1:
            now = rss_mib()
            samples.append((i, round(now, 1)))
            peak = max(peak, now)
    read = time.perf_counter() - t0
    return dict(bag_gb=path.stat().st_size / 1e9, frames=len(bag), write_s=written, open_s=opened, read_all_s=read,
                rss_before_open_mib=before, rss_after_open_mib=after_open, rss_peak_reading_mib=peak,
                rss_samples=samples)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sevenscenes", type=Path, default=None)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--memory-gb", type=float, default=None)
    parser.add_argument("--work", type=Path, required=True, help="a scratch folder (bags, runs)")
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from gsjax.app.runtime.cache import enable_compilation_cache

    enable_compilation_cache()
    args.work.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.sevenscenes is not None:
        if (args.work / "kitchen.bag").exists():
            (args.work / "kitchen.bag").unlink()
        results["sevenscenes"] = sevenscenes(args.sevenscenes, args.frames, args.work)
    if args.memory_gb is not None:
        results["memory"] = memory(args.memory_gb, args.work)
        (args.work / "big.bag").unlink()
    print(json.dumps(results, indent=1))
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))
    shutil.rmtree(args.work / "folder", ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
