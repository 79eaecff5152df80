"""Replica as rendered by NICE-SLAM (the layout SplaTAM and NICE-SLAM read).

``<scene>/results/frameNNNNNN.jpg`` (colour), ``<scene>/results/depthNNNNNN.png`` (16-bit, 6553.5 units per
metre, 0 invalid), ``<scene>/traj.txt`` (line k: row-major 4x4 camera-to-world pose of frame k, m), and
optionally ``cam_params.json`` one level up (``{"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}``), which
overrides the NICE-SLAM defaults 1200x680, fx = fy = 600, cx = 599.5, cy = 339.5, scale 6553.5. The timestamp of
a frame is its number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gsjax.camera import make_intrinsics
from gsjax.data.errors import DatasetError
from gsjax.data.listing import (
    FrameFiles,
    GivenIntrinsics,
    given_intrinsics,
    numbered_files,
    read_json_numbers,
    require_color_for_depth,
)
from gsjax.data.poses import read_pose_lines

DEFAULT_CAMERA = {"w": 1200, "h": 680, "fx": 600.0, "fy": 600.0, "cx": 599.5, "cy": 339.5, "scale": 6553.5}


def list_replica(path: Path, intrinsics: GivenIntrinsics = None) -> FrameFiles:
    """List a NICE-SLAM Replica scene directory (the one holding ``results/`` and ``traj.txt``)."""
    path = Path(path)
    colors = numbered_files(path / "results", r"frame(\d+)\.(?:jpg|png)", "frameNNNNNN.jpg")
    require_color_for_depth(colors, path / "results", r"depth(\d+)\.png", lambda n: path / "results" / f"frame{n:06d}")
    depth_paths = [p.with_name("depth" + p.name[len("frame") :]).with_suffix(".png") for p in colors.values()]
    numbers = np.array(list(colors), np.int64)
    c2w, valid = read_pose_lines(path / "traj.txt", int(numbers.max()) + 1)
    camera = dict(DEFAULT_CAMERA)
    params = path.parent / "cam_params.json"
    if params.exists():
        camera |= read_json_numbers(params, ("fx", "fy", "cx", "cy"), ("w", "h", "scale"), within="camera")
    intrinsics = given_intrinsics(intrinsics, depth_paths[0])
    if intrinsics is None:
        try:
            intrinsics = make_intrinsics(*(camera[key] for key in ("fx", "fy", "cx", "cy", "h", "w")))
        except ValueError as err:
            raise DatasetError(f"{params}: {err}") from None
    return FrameFiles(
        name=path.name,
        color_paths=list(colors.values()),
        depth_paths=depth_paths,
        timestamps=numbers.astype(np.float64),
        c2w=c2w[numbers],
        pose_valid=valid[numbers],
        intrinsics=intrinsics,
        depth_scale=float(camera["scale"]),
    )
