"""Microsoft 7-Scenes / 3DMatch frame layout.

``frame-NNNNNN.color.{jpg,png}``, ``frame-NNNNNN.depth.png`` (16-bit millimetres; 0 and 65535 invalid),
``frame-NNNNNN.pose.txt`` (4x4 camera-to-world, m; a missing file flags the frame's pose invalid) and
``camera-intrinsics.txt`` (3x3 K, as 3DMatch ships it; without it, the nominal 7-Scenes values fx = fy = 585,
cx = 320, cy = 240 from the dataset's page). The image size is the first depth image's. The timestamp of a frame
is its number. In 7-Scenes colour and depth are not registered; the single K is used for both, as everyone does.
"""

from __future__ import annotations

from pathlib import Path

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.data.images import image_size
from gsjax.data.listing import FrameFiles, files_per_frame, intrinsics_from_matrix, numbered_files
from gsjax.data.poses import read_matrix

DEPTH_SCALE = 1000.0  # raw units per metre
INVALID_RAW = (0, 65535)
NOMINAL_K = (585.0, 585.0, 320.0, 240.0)  # fx, fy, cx, cy


def list_sevenscenes(path: Path, intrinsics: Intrinsics | None = None) -> FrameFiles:
    """List a directory of 7-Scenes frames (one ``seq-XX`` folder, or a 3DMatch ``data/`` folder)."""
    path = Path(path)
    colors = numbered_files(path, r"frame-(\d+)\.color\.(?:jpg|png)", "frame-NNNNNN.color.jpg/png")
    stems = [p.name.split(".")[0] for p in colors.values()]
    depth_paths = [path / f"{stem}.depth.png" for stem in stems]
    if intrinsics is None:
        size = image_size(depth_paths[0])
        k_path = path / "camera-intrinsics.txt"
        if k_path.exists():
            intrinsics = intrinsics_from_matrix(read_matrix(k_path, 3), *size, where=k_path)
        else:
            intrinsics = make_intrinsics(*NOMINAL_K, *size)
    pose_paths = [path / f"{stem}.pose.txt" for stem in stems]
    return files_per_frame(path.name, colors, depth_paths, pose_paths, intrinsics, DEPTH_SCALE, invalid_raw=INVALID_RAW)
