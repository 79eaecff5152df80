"""Microsoft 7-Scenes / 3DMatch frame layout.

``frame-NNNNNN.color.{jpg,png}``, ``frame-NNNNNN.depth.png`` (16-bit millimetres; 0 and 65535 invalid),
``frame-NNNNNN.pose.txt`` (4x4 camera-to-world, m; a missing file flags the frame's pose invalid) and
``camera-intrinsics.txt`` (3x3 K, as 3DMatch ships it; without it, the nominal 7-Scenes values fx = fy = 585,
cx = 320, cy = 240 from the dataset's page). The image size is the first depth image's. The timestamp of a frame
is its number.

In 7-Scenes colour and depth come from the Kinect's two cameras and are not registered; 585 px is the depth
camera's focal length (the dataset's page), the colour camera's is about 525 px, and the two sit about 2.5 cm apart
(the values the visual-relocalisation literature registers 7-Scenes with, e.g. DSAC*/ACE's setup scripts). Using
one K for both makes colour disagree with geometry by ~11% in scale: measured on the kitchen sequence, depth edges
lie a median 3.5 px from colour edges unregistered and 1.9 px registered, and tracking underestimated the camera's
pan by ~13%. So when the listed intrinsics are 7-Scenes' nominal depth ones (640x480), colour is registered to the
depth camera (:data:`COLOR_CAMERA`, :mod:`gsjax.data.registration`); 3DMatch's other scenes (already registered,
other intrinsics) are read as they are. ``open_sequence(..., register_color=False)`` turns it off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gsjax.camera import Intrinsics, make_intrinsics
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
from gsjax.data.registration import ColorCamera

DEPTH_SCALE = 1000.0  # raw units per metre
INVALID_RAW = (0, 65535)
NOMINAL_K = (585.0, 585.0, 320.0, 240.0)  # fx, fy, cx, cy of the depth camera
NOMINAL_SIZE = (480, 640)
_DEPTH_TO_COLOR = np.eye(4)
_DEPTH_TO_COLOR[0, 3] = -0.025  # the colour camera sits 2.5 cm along the depth camera's +x
COLOR_CAMERA = ColorCamera(fx=525.0, fy=525.0, cx=320.0, cy=240.0, depth_to_color=_DEPTH_TO_COLOR)


def _is_nominal(intrinsics: Intrinsics) -> bool:
    values = (float(intrinsics.fx), float(intrinsics.fy), float(intrinsics.cx), float(intrinsics.cy))
    return intrinsics.shape == NOMINAL_SIZE and np.allclose(values, NOMINAL_K)


def list_sevenscenes(path: Path, intrinsics: GivenIntrinsics = None) -> FrameFiles:
    """List a directory of 7-Scenes frames (one ``seq-XX`` folder, or a 3DMatch ``data/`` folder)."""
    path = Path(path)
    colors = numbered_files(path, r"frame-(\d+)\.color\.(?:jpg|png)", "frame-NNNNNN.color.jpg/png")
    require_color_for_depth(colors, path, r"frame-(\d+)\.depth\.png", lambda n: path / f"frame-{n:06d}.color")
    stems = [p.name.split(".")[0] for p in colors.values()]
    depth_paths = [path / f"{stem}.depth.png" for stem in stems]
    intrinsics = given_intrinsics(intrinsics, depth_paths[0])
    if intrinsics is None:
        size = image_size(depth_paths[0])
        k_path = path / "camera-intrinsics.txt"
        if k_path.exists():
            intrinsics = intrinsics_from_matrix(read_matrix(k_path, 3), *size, where=k_path)
        else:
            intrinsics = make_intrinsics(*NOMINAL_K, *size)
    pose_paths = [path / f"{stem}.pose.txt" for stem in stems]
    color_camera = COLOR_CAMERA if _is_nominal(intrinsics) else None
    return files_per_frame(path.name, colors, depth_paths, pose_paths, intrinsics, DEPTH_SCALE, invalid_raw=INVALID_RAW,
                           color_camera=color_camera)
