"""Ground truth is for evaluation only: ``gsjax run`` on a recording with ground truth and on the same recording
without it gives the same trajectory, map and per-frame outputs bit for bit (the trajectory file differs only by
the world frame it is written in), on the synthetic room (TUM layout) and on the real 7-Scenes sample."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.run_folder.checkpoints import Checkpoints
from gsjax.data import open_sequence, write_tum
from gsjax.io.trajectory import read_tum_trajectory
from tests.support.recordings import shared_data
from tests.support.tiny_slam import CHUNK, FRAMES, TINY_OVERRIDES, tiny_sequence

RUN_OPTIONS = ["--chunk", str(CHUNK), "--no-progress"] + [
    token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]


def run(dataset: str, path: Path, out: Path, downscale: int = 1) -> dict:
    """``gsjax run`` as the tiny tests run it: 40x30 frames, the tiny config (the suite's one SLAM program)."""
    argv = ["run", "--dataset", dataset, "--path", str(path), "--out", str(out), "--downscale", str(downscale)]
    assert main(argv + RUN_OPTIONS) == 0
    return json.loads((out / "metrics.json").read_text())


def per_frame_outputs(out: Path) -> dict:
    """The newest checkpoint's per-frame outputs by name, as lists (compared whole with ==)."""
    checkpoints = Checkpoints(out / "checkpoints")
    try:
        return {name: values.tolist() for name, values in checkpoints.outputs(checkpoints.latest())._asdict().items()}
    finally:
        checkpoints.close()


def rigidity(c2w: np.ndarray) -> float:
    """The largest entry of |R^T R - I|."""
    return float(np.abs(c2w[:3, :3].T @ c2w[:3, :3] - np.eye(3)).max())


def assert_same_slam(dataset: str, with_gt: Path, without_gt: Path, tmp_path: Path, downscale: int = 1) -> None:
    gt_c2w = open_sequence(dataset, with_gt).gt_trajectory()[1]
    metrics = run(dataset, with_gt, tmp_path / "gt", downscale)
    metrics_no_gt = run(dataset, without_gt, tmp_path / "no_gt", downscale)
    assert metrics["trajectory"]["num_evaluated"] == FRAMES and metrics_no_gt["trajectory"] is None
    assert per_frame_outputs(tmp_path / "gt") == per_frame_outputs(tmp_path / "no_gt")  # w2c included, bit for bit
    assert (tmp_path / "gt" / "map.ply").read_bytes() == (tmp_path / "no_gt" / "map.ply").read_bytes()
    for key in ("keyframes", "num_gaussians", "render"):
        assert metrics[key] == metrics_no_gt[key], key
    assert metrics["keyframes"] == 2  # frames 0 and 4 (also the second-to-last), whatever the ground truth
    # With ground truth the trajectory is written in the dataset's world frame, without it in the first camera's.
    stamps, c2w = read_tum_trajectory(tmp_path / "gt" / "trajectory.txt")
    stamps_no_gt, c2w_no_gt = read_tum_trajectory(tmp_path / "no_gt" / "trajectory.txt")
    np.testing.assert_array_equal(stamps, stamps_no_gt)
    expected = gt_c2w[0] @ c2w_no_gt
    np.testing.assert_allclose(c2w[:, :3, 3], expected[:, :3, 3], atol=2e-6)
    # Rotations are written as unit quaternions: a GT rotation that is not exactly orthonormal (7-Scenes'
    # KinectFusion poses deviate by up to 1.5e-4) comes out orthonormalised.
    np.testing.assert_allclose(c2w[:, :3, :3], expected[:, :3, :3], atol=2e-6 + 2 * rigidity(gt_c2w[0]))


def test_synthetic_room_with_and_without_ground_truth(tmp_path):
    with_gt = write_tum(tiny_sequence(), tmp_path / "data" / "room")
    without_gt = tmp_path / "data" / "room_no_gt"
    shutil.copytree(with_gt, without_gt)
    (without_gt / "groundtruth.txt").unlink()
    assert_same_slam("tum", with_gt, without_gt, tmp_path)


def test_sevenscenes_kitchen_with_and_without_ground_truth(tmp_path):
    source = shared_data() / "7scenes_redkitchen"
    if not source.is_dir():
        pytest.skip(f"{source} is not present")
    with_gt, without_gt = tmp_path / "data" / "kitchen", tmp_path / "data" / "kitchen_no_gt"
    for folder, kinds in ((with_gt, ("color.jpg", "depth.png", "pose.txt")), (without_gt, ("color.jpg", "depth.png"))):
        folder.mkdir(parents=True)
        shutil.copy(source / "camera-intrinsics.txt", folder)
        for k in range(FRAMES):
            for kind in kinds:
                shutil.copy(source / f"frame-{k:06d}.{kind}", folder)
    assert_same_slam("7scenes", with_gt, without_gt, tmp_path, downscale=16)  # 640x480 -> 40x30, the tiny shape
