"""Registration of colour to depth for RGB-D recordings whose two cameras were not registered (7-Scenes).

Depth is the reference: poses, intrinsics and maps are the depth camera's. Each depth pixel takes the colour seen
where its 3D point lands in the colour camera (bilinear), so colour and depth describe the same rays. Pixels
without valid depth use the frame's median depth, which is right for distant and flat content and off by at most
the parallax of the baseline elsewhere.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from gsjax.camera import Intrinsics, backproject


@dataclasses.dataclass(frozen=True)
class ColorCamera:
    """The colour camera of an unregistered RGB-D pair.

    Attributes:
      fx, fy, cx, cy: its pinhole intrinsics (px, for the colour image as stored on disk).
      depth_to_color: [4, 4] rigid transform taking depth-camera points to colour-camera points (m).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    depth_to_color: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))


def register_color(color: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, camera: ColorCamera) -> np.ndarray:
    """Resample ``color`` [Hc, Wc, 3] (the colour camera's image) into the depth camera -> [H, W, 3], same dtype.

    ``depth`` [H, W] (m, 0 invalid) and ``intrinsics`` are the depth camera's. Points that land outside the colour
    image take the nearest border colour.
    """
    valid = depth > 0
    fallback = float(np.median(depth[valid])) if valid.any() else 1.0
    z = np.where(valid, depth, fallback).astype(np.float32)
    points = np.asarray(backproject(z, intrinsics), np.float64)  # [H, W, 3] in the depth camera
    rotation, translation = camera.depth_to_color[:3, :3], camera.depth_to_color[:3, 3]
    seen = points @ rotation.T + translation
    z_color = np.maximum(seen[..., 2], 1e-6)
    map_u = (camera.fx * seen[..., 0] / z_color + camera.cx).astype(np.float32)
    map_v = (camera.fy * seen[..., 1] / z_color + camera.cy).astype(np.float32)
    return cv2.remap(color, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
