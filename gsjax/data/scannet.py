"""ScanNet, as exported by its SensReader: ``color/N.jpg``, ``depth/N.png`` (16-bit millimetres, 0 invalid),
``pose/N.txt`` (4x4 camera-to-world, m; ``-inf`` where ScanNet's reconstruction lost track: flagged invalid) and
``intrinsic/intrinsic_depth.txt`` (4x4; else ``intrinsic_color.txt`` rescaled to the depth size).

Frames have the depth camera's size and intrinsics: colour (1296x968) is resampled to it with INTER_AREA, as
NICE-SLAM and SplaTAM do (the two cameras are only approximately registered). The timestamp of a frame is its
number. The image size is the first depth image's.
"""

from __future__ import annotations

from pathlib import Path

from gsjax.camera import Intrinsics
from gsjax.data.errors import DatasetError
from gsjax.data.images import image_size
from gsjax.data.listing import (
    FrameFiles,
    GivenIntrinsics,
    files_per_frame,
    given_intrinsics,
    intrinsics_from_matrix,
    numbered_files,
    require_color_for_depth,
)
from gsjax.data.poses import read_matrix

DEPTH_SCALE = 1000.0  # raw units per metre


def list_scannet(path: Path, intrinsics: GivenIntrinsics = None) -> FrameFiles:
    """List a ScanNet scene export directory (holding ``color/``, ``depth/``, ``pose/``, ``intrinsic/``)."""
    path = Path(path)
    colors = numbered_files(path / "color", r"(\d+)\.(?:jpg|png)", "N.jpg")
    require_color_for_depth(colors, path / "depth", r"(\d+)\.png", lambda n: path / "color" / str(n))
    stems = [p.stem for p in colors.values()]
    depth_paths = [path / "depth" / f"{stem}.png" for stem in stems]
    intrinsics = given_intrinsics(intrinsics, depth_paths[0])
    if intrinsics is None:
        intrinsics = _scannet_intrinsics(path / "intrinsic", depth_paths[0], next(iter(colors.values())))
    pose_paths = [path / "pose" / f"{stem}.txt" for stem in stems]
    return files_per_frame(path.name, colors, depth_paths, pose_paths, intrinsics, DEPTH_SCALE, resize_color=True)


def _scannet_intrinsics(directory: Path, first_depth: Path, first_color: Path) -> Intrinsics:
    height, width = image_size(first_depth)
    depth_k = directory / "intrinsic_depth.txt"
    if depth_k.exists():
        return intrinsics_from_matrix(read_matrix(depth_k, 4), height, width, where=depth_k)
    color_k = directory / "intrinsic_color.txt"
    if not color_k.exists():
        raise DatasetError(f"{directory}: neither intrinsic_depth.txt nor intrinsic_color.txt is present")
    k = read_matrix(color_k, 4)
    color_h, color_w = image_size(first_color)
    # Resample the colour camera to the depth size; pixel centres at integers: u' = (u + 0.5) s - 0.5.
    sx, sy = width / color_w, height / color_h
    k[0, :3] = (k[0, 0] * sx, 0.0, (k[0, 2] + 0.5) * sx - 0.5)
    k[1, :3] = (0.0, k[1, 1] * sy, (k[1, 2] + 0.5) * sy - 0.5)
    return intrinsics_from_matrix(k, height, width, where=color_k)
