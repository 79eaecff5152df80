"""Colour-to-depth registration (gsjax.data.registration) and its use by the 7-Scenes reader.

The reference scene is analytic: a textured plane z = 2 m in the depth camera, seen by a colour camera with another
focal length, a baseline and a small rotation. The colour image is made by intersecting each colour ray with the
plane; registered colour must equal the texture at each depth pixel's own point.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsjax.camera import make_intrinsics
from gsjax.data import open_sequence
from gsjax.data.registration import ColorCamera, register_color
from gsjax.data.sevenscenes import COLOR_CAMERA
from tests.support.recordings import imwrite_depth, imwrite_rgb, matrix_text

PLANE_Z = 2.0


def texture(x, y):
    """Smooth RGB texture on the plane (x, y in m) -> [..., 3] in [0.1, 0.9]."""
    return np.stack([0.5 + 0.4 * np.sin(7 * x) * np.cos(5 * y), 0.5 + 0.4 * np.cos(6 * x + 1),
                     0.5 + 0.4 * np.sin(9 * y)],
                    axis=-1)


def depth_to_color(angle_deg: float, baseline: float) -> np.ndarray:
    a = np.radians(angle_deg)
    transform = np.eye(4)
    transform[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    transform[0, 3] = baseline
    return transform


def colour_camera_image(camera: ColorCamera, height: int, width: int) -> np.ndarray:
    """What the colour camera sees of the plane z_depth = PLANE_Z, by ray casting (float64)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    rotation, translation = camera.depth_to_color[:3, :3], camera.depth_to_color[:3, 3]
    # depth-frame point of colour-frame point s * ray: R^T (s ray - t); solve its z = PLANE_Z for s
    dirs, origin = rays @ rotation, -(rotation.T @ translation)
    s = (PLANE_Z - origin[2]) / dirs[..., 2]
    points = origin + s[..., None] * dirs
    return texture(points[..., 0], points[..., 1]).astype(np.float32)


def expected_registered(intrinsics) -> np.ndarray:
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width].astype(np.float64)
    x = (u - float(intrinsics.cx)) / float(intrinsics.fx) * PLANE_Z
    y = (v - float(intrinsics.cy)) / float(intrinsics.fy) * PLANE_Z
    return texture(x, y)


@pytest.mark.parametrize("angle_deg, baseline", [(0.0, -0.025), (1.5, 0.04)])
def test_registered_colour_is_the_texture_at_each_depth_pixels_point(angle_deg, baseline):
    intrinsics = make_intrinsics(70.0, 70.0, 40.0, 30.0, 60, 80)
    camera = ColorCamera(fx=62.0, fy=63.0, cx=41.0, cy=29.5, depth_to_color=depth_to_color(angle_deg, baseline))
    color = colour_camera_image(camera, 66, 90)  # colour image of another size: the output takes the depth's
    depth = np.full((60, 80), PLANE_Z, np.float32)
    depth[10:14, 20:30] = 0.0  # holes take the median depth, which is the plane's here
    want = expected_registered(intrinsics)
    got = register_color(color, depth, intrinsics, camera)
    assert got.shape == (60, 80, 3) and got.dtype == np.float32
    inner = np.s_[2:-2, 2:-2]
    assert np.max(np.abs(got[inner] - want[inner])) < 0.02  # bilinear interpolation of a smooth texture
    unregistered = cv2.resize(color, (80, 60), interpolation=cv2.INTER_LINEAR)
    assert np.mean(np.abs(unregistered - want)) > 0.05  # the check can tell registered from not


def _write_nominal_7scenes(folder, color_rgb_u8, depth_m):
    folder.mkdir(parents=True, exist_ok=True)
    imwrite_rgb(folder / "frame-000000.color.png", color_rgb_u8)
    imwrite_depth(folder / "frame-000000.depth.png", depth_m, 1000.0)
    (folder / "frame-000000.pose.txt").write_text(matrix_text(np.eye(4)))
    (folder / "camera-intrinsics.txt").write_text("585 0 320\n0 585 240\n0 0 1\n")
    return folder


def test_sevenscenes_reader_registers_colour_only_for_the_nominal_7scenes_camera(tmp_path):
    intrinsics = make_intrinsics(585.0, 585.0, 320.0, 240.0, 480, 640)
    color = colour_camera_image(COLOR_CAMERA, 480, 640)
    color_u8 = np.round(color * 255).astype(np.uint8)
    folder = _write_nominal_7scenes(tmp_path / "seq-01", color_u8, np.full((480, 640), PLANE_Z, np.float32))
    want = expected_registered(intrinsics)
    got = np.asarray(open_sequence("7scenes", folder)[0].color)
    stored = np.asarray(open_sequence("7scenes", folder, register_color=False)[0].color)
    np.testing.assert_allclose(stored, color_u8 / 255.0, atol=1e-6)
    inner = np.s_[4:-4, 4:-4]
    assert np.max(np.abs(got[inner] - want[inner])) < 0.02
    assert np.mean(np.abs(stored - want)) > 0.05
    # other intrinsics (a 3DMatch scene that is registered already): colour as stored
    (folder / "camera-intrinsics.txt").write_text("580 0 320\n0 580 240\n0 0 1\n")
    np.testing.assert_allclose(np.asarray(open_sequence("7scenes", folder)[0].color), color_u8 / 255.0, atol=1e-6)
