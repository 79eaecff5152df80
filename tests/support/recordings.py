"""Tiny on-disk datasets for the reader tests, written in each layout from exact synthetic renders.

Each writer takes :func:`tiny_scene` frames (8-bit colour, float depth, camera-to-world poses) and writes them with
the layout's own conventions (names, depth units, pose format), independently of the readers' code.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np

from gsjax.camera import make_intrinsics
from gsjax.data.synthetic import camera_trajectory, render_view

HEIGHT, WIDTH = 24, 32


def shared_data() -> Path:
    """The real sequences of ../shared/data (or $GSJAX_SHARED_DATA); tests using them skip when they are absent."""
    env = os.environ.get("GSJAX_SHARED_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"


def tiny_scene(count: int = 3, height: int = HEIGHT, width: int = WIDTH, step: float = 0.1):
    """(intrinsics, colour uint8 [n, H, W, 3] RGB, depth float64 [n, H, W] m, c2w [n, 4, 4]) of the synthetic room."""
    intrinsics = make_intrinsics(0.8 * width, 0.8 * width, (width - 1) / 2, (height - 1) / 2, height, width)
    c2w = camera_trajectory(np.arange(count) * step)
    renders = [render_view(pose, intrinsics) for pose in c2w]
    colors = np.stack([np.round(c * 255).astype(np.uint8) for c, _ in renders])
    depths = np.stack([d.astype(np.float64) for _, d in renders])
    return intrinsics, colors, depths, c2w


def imwrite_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1]))


def imwrite_depth(path: Path, depth_m: np.ndarray, scale: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.round(depth_m * scale).astype(np.uint16))


def k_text(intrinsics, size: int = 3) -> str:
    k = np.eye(size)
    k[0, 0], k[1, 1] = float(intrinsics.fx), float(intrinsics.fy)
    k[0, 2], k[1, 2] = float(intrinsics.cx), float(intrinsics.cy)
    return "\n".join(" ".join(f"{x:.10f}" for x in row) for row in k) + "\n"


def matrix_text(c2w: np.ndarray) -> str:
    return "\n".join(" ".join(f"{x:.12e}" for x in row) for row in c2w) + "\n"


def write_replica(root: Path, scene, with_cam_params: bool = True) -> Path:
    """NICE-SLAM layout: root/cam_params.json, root/room0/results/frame%06d.png + depth%06d.png, traj.txt."""
    intrinsics, colors, depths, c2w = scene
    folder = root / "room0"
    for i in range(len(colors)):
        imwrite_rgb(folder / "results" / f"frame{i:06d}.png", colors[i])
        imwrite_depth(folder / "results" / f"depth{i:06d}.png", depths[i], 6553.5)
    (folder / "traj.txt").write_text("".join(" ".join(f"{x:.12e}" for x in pose.ravel()) + "\n" for pose in c2w))
    if with_cam_params:
        camera = {"w": intrinsics.width, "h": intrinsics.height, "scale": 6553.5}
        camera |= {k: float(getattr(intrinsics, k)) for k in ("fx", "fy", "cx", "cy")}
        (root / "cam_params.json").write_text(json.dumps({"camera": camera}))
    return folder


def write_scannet(root: Path, scene, color_factor: int = 2) -> Path:
    """ScanNet export: color/N.png at ``color_factor`` x the depth size (each depth pixel a block of identical colour
    pixels), depth/N.png (mm), pose/N.txt, intrinsic/intrinsic_depth.txt (4x4)."""
    intrinsics, colors, depths, c2w = scene
    folder = root / "scene0000_00"
    for i in range(len(colors)):
        big = np.repeat(np.repeat(colors[i], color_factor, axis=0), color_factor, axis=1)
        imwrite_rgb(folder / "color" / f"{i}.png", big)
        imwrite_depth(folder / "depth" / f"{i}.png", depths[i], 1000.0)
        (folder / "pose" / f"{i}.txt").parent.mkdir(parents=True, exist_ok=True)
        (folder / "pose" / f"{i}.txt").write_text(matrix_text(c2w[i]))
    (folder / "intrinsic").mkdir(parents=True, exist_ok=True)
    (folder / "intrinsic" / "intrinsic_depth.txt").write_text(k_text(intrinsics, 4))
    return folder


def write_sevenscenes(root: Path, scene) -> Path:
    """7-Scenes / 3DMatch frames: frame-%06d.color.png, .depth.png (mm), .pose.txt, camera-intrinsics.txt."""
    intrinsics, colors, depths, c2w = scene
    folder = root / "seq-01"
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(len(colors)):
        imwrite_rgb(folder / f"frame-{i:06d}.color.png", colors[i])
        imwrite_depth(folder / f"frame-{i:06d}.depth.png", depths[i], 1000.0)
        (folder / f"frame-{i:06d}.pose.txt").write_text(matrix_text(c2w[i]))
    (folder / "camera-intrinsics.txt").write_text(k_text(intrinsics))
    return folder


def quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Rotation matrix -> (qx, qy, qz, qw), via the trace formula (fine for the test trajectories' rotations)."""
    w = 0.5 * np.sqrt(max(1.0 + np.trace(rotation), 1e-12))
    x = (rotation[2, 1] - rotation[1, 2]) / (4 * w)
    y = (rotation[0, 2] - rotation[2, 0]) / (4 * w)
    z = (rotation[1, 0] - rotation[0, 1]) / (4 * w)
    return np.array([x, y, z, w])


def write_tum_by_hand(root: Path, scene, name: str = "rgbd_dataset_freiburg1_tiny", depth_offset: float = 0.007):
    """TUM layout as the dataset ships it: colour and depth stamps that differ slightly, groundtruth at 100 Hz not
    aligned with the frames (each frame's pose is also written at its colour stamp + 3 ms), no intrinsics.json."""
    intrinsics, colors, depths, c2w = scene
    folder = root / name
    rgb_lines, depth_lines, gt_lines = ["# color images"], ["# depth maps"], ["# timestamp tx ty tz qx qy qz qw"]
    for i in range(len(colors)):
        t_rgb = 1305031102.175304 + i / 30.0
        t_depth = t_rgb + depth_offset
        imwrite_rgb(folder / "rgb" / f"{t_rgb:.6f}.png", colors[i])
        imwrite_depth(folder / "depth" / f"{t_depth:.6f}.png", depths[i], 5000.0)
        rgb_lines.append(f"{t_rgb:.6f} rgb/{t_rgb:.6f}.png")
        depth_lines.append(f"{t_depth:.6f} depth/{t_depth:.6f}.png")
        pose = (*c2w[i, :3, 3], *quaternion_xyzw(c2w[i, :3, :3]))
        gt_lines.append(f"{t_rgb + 0.003:.4f} " + " ".join(f"{x:.9f}" for x in pose))
        gt_lines.append(f"{t_rgb + 0.013:.4f} 9 9 9 0 0 0 1")  # a sample 13 ms later: must lose to the nearer one
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (folder / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    return folder
