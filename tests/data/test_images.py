"""Image reading: channel order, depth units and invalid values, the downscaling rules."""

from __future__ import annotations

import cv2
import numpy as np

from gsjax.camera import make_intrinsics, project_points
from gsjax.data import open_sequence
from gsjax.data.images import downscale_color, downscale_depth, read_color, read_depth
from gsjax.data.synthetic import render_view
from tests.support.recordings import tiny_scene, write_sevenscenes


def test_read_color_converts_opencv_bgr_to_rgb(tmp_path):
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 0] = 255  # OpenCV's first channel is blue
    cv2.imwrite(str(tmp_path / "blue.png"), bgr)
    rgb = read_color(tmp_path / "blue.png")
    assert rgb.dtype == np.float32
    np.testing.assert_array_equal(rgb[0, 0], [0.0, 0.0, 1.0])


def test_read_depth_divides_by_scale_and_zeroes_invalid_values(tmp_path):
    raw = np.array([[0, 1000, 65535, 5000]], np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), raw)
    np.testing.assert_allclose(read_depth(tmp_path / "d.png", 1000.0, (0, 65535)), [[0.0, 1.0, 0.0, 5.0]])
    np.testing.assert_allclose(read_depth(tmp_path / "d.png", 5000.0), [[0.0, 0.2, 13.107, 1.0]])


def test_downscale_color_is_the_block_mean_and_floors_sizes():
    color = np.arange(5 * 7 * 3, dtype=np.float32).reshape(5, 7, 3)
    small = downscale_color(color, 2)
    assert small.shape == (2, 3, 3)
    np.testing.assert_allclose(small[1, 2], color[2:4, 4:6].mean(axis=(0, 1)))
    # INTER_AREA is the same block mean for integer factors (on the part the floor keeps).
    np.testing.assert_allclose(small, cv2.resize(color[:4, :6], (3, 2), interpolation=cv2.INTER_AREA), rtol=1e-6)


def test_downscale_depth_takes_the_median_of_valid_samples():
    depth = np.array(
        [
            [1.0, 2.0, 0.0, 5.0, 0.0, 0.0],
            [9.0, 4.0, 0.0, 7.0, 0.0, 3.0],
        ],
        np.float32,
    )
    # Blocks: {1, 2, 9, 4} -> median of 4 valid = (2 + 4) / 2; {0, 5, 0, 7}: half valid -> (5 + 7) / 2;
    # {0, 0, 0, 3}: one of four valid (fewer than half) -> invalid.
    np.testing.assert_allclose(downscale_depth(depth, 2), [[3.0, 6.0, 0.0]])


def test_downscale_depth_with_odd_factor_uses_the_middle_valid_sample():
    block = np.array([[0.0, 1.0, 8.0], [2.0, 0.0, 3.0], [0.0, 0.0, 9.0]], np.float32)  # 5 of 9 valid
    np.testing.assert_allclose(downscale_depth(block, 3), [[3.0]])
    block[0, 1] = 0.0  # 4 of 9 valid: fewer than half
    np.testing.assert_allclose(downscale_depth(block, 3), [[0.0]])


def test_downscale_depth_does_not_blend_across_a_depth_edge():
    depth = np.array([[1.0, 1.0], [1.0, 4.0]], np.float32)
    assert float(downscale_depth(depth, 2)[0, 0]) == 1.0  # a mean would invent a surface at 1.75 m


def test_downscaled_frames_keep_sizes_intrinsics_and_geometry_consistent(tmp_path):
    scene = tiny_scene(count=1, height=48, width=66)
    intrinsics, _, depths, c2w = scene
    seq = open_sequence("7scenes", write_sevenscenes(tmp_path, scene), downscale=2)
    k = seq.intrinsics
    assert (k.height, k.width) == (24, 33) and seq[0].depth.shape == (24, 33)
    # A camera point projects to the same physical place: full-res pixel u <-> downscaled (u + 0.5) / 2 - 0.5.
    point = np.array([0.3, -0.2, 1.7], np.float32)
    full, small = np.asarray(project_points(point, intrinsics)), np.asarray(project_points(point, k))
    np.testing.assert_allclose(small, (full + 0.5) / 2 - 0.5, atol=1e-4)
    # The downscaled depth agrees with a render at the downscaled intrinsics, and better than with naive ones.
    _, exact = render_view(c2w[0], k)
    naive = make_intrinsics(float(k.fx), float(k.fy), float(intrinsics.cx) / 2, float(intrinsics.cy) / 2, 24, 33)
    _, shifted = render_view(c2w[0], naive)
    got = np.asarray(seq[0].depth)
    error, naive_error = np.median(np.abs(got - exact)), np.median(np.abs(got - shifted))
    assert error < 1e-3 and naive_error > 10 * error

