"""Synthetic generator: exact analytic depth, determinism, configured motion, sensor effects, TUM round trip."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import backproject, make_intrinsics
from gsjax.data import SyntheticConfig, open_sequence, scene, synthetic_sequence, write_tum
from gsjax.data.synthetic import camera_trajectory, depth_edges, render_frame, render_view

SMALL = SyntheticConfig(width=64, height=48, num_frames=6)


def _look(position, forward, down):
    """Camera-to-world pose at ``position`` with the given optical axis and image-down direction (world frame)."""
    forward, down = np.asarray(forward, float), np.asarray(down, float)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = np.cross(down, forward), down, forward, position
    return c2w


def test_depth_of_a_facing_wall_is_its_distance_along_the_axis_not_the_ray_length():
    # From y = -0.5 looking at the back wall (y = -2): nothing between, the wall fills the view.
    intrinsics = make_intrinsics(50.0, 50.0, 31.5, 23.5, 48, 64)
    _, depth = render_view(_look([0.2, -0.5, 1.3], [0, -1, 0], [0, 0, -1]), intrinsics)
    np.testing.assert_allclose(depth, 1.5, rtol=0, atol=1e-6)  # corners included: ray length there is 1.9 m


def test_depth_at_the_pixel_aimed_at_a_sphere_centre_is_distance_minus_radius():
    centre, radius = scene.SPHERES[0]
    position = np.array([0.3, -0.8, 1.0])
    axis = (centre - position) / np.linalg.norm(centre - position)
    down = np.cross(axis, np.cross([0, 0, -1.0], axis))
    intrinsics = make_intrinsics(60.0, 60.0, 20.0, 15.0, 31, 41)  # pixel (15, 20) sits on the optical axis
    _, depth = render_view(_look(position, axis, down / np.linalg.norm(down)), intrinsics)
    assert depth[15, 20] == pytest.approx(np.linalg.norm(centre - position) - radius, abs=1e-6)
    # Off-axis pixels on the sphere: back-projected points satisfy |p - c| = r.
    points = _world_points(depth, intrinsics, _look(position, axis, down / np.linalg.norm(down)))
    on_sphere = np.abs(np.linalg.norm(points[12:19, 17:24] - centre, axis=-1) - radius)
    assert on_sphere.max() < 1e-5


def _world_points(depth, intrinsics, c2w):
    camera = np.asarray(backproject(jnp.asarray(depth), intrinsics), np.float64)
    return camera @ c2w[:3, :3].T + c2w[:3, 3]


def test_every_rendered_pixel_lies_on_a_scene_surface():
    config = SyntheticConfig(width=80, height=60)
    intrinsics = config.intrinsics()
    for c2w in camera_trajectory(np.array([0.0, 7.0, 13.0])):
        _, depth = render_view(c2w, intrinsics)
        points = _world_points(depth, intrinsics, c2w).reshape(-1, 3)
        assert np.abs(scene.clearance(points)).max() < 2e-5


def test_same_seed_gives_identical_frames_whatever_the_reading_order():
    config = dataclasses.replace(SMALL, seed=3).with_sensor_noise()
    first, second = synthetic_sequence(config), synthetic_sequence(config)
    later = second[4]
    for a, b in ((first[4], later), (first[1], second[1])):
        np.testing.assert_array_equal(np.asarray(a.color), np.asarray(b.color))
        np.testing.assert_array_equal(np.asarray(a.depth), np.asarray(b.depth))


def test_different_seed_changes_the_noise_but_not_the_scene_or_poses():
    noisy = SMALL.with_sensor_noise()
    a = synthetic_sequence(dataclasses.replace(noisy, seed=1))[2]
    b = synthetic_sequence(dataclasses.replace(noisy, seed=2))[2]
    assert not np.array_equal(np.asarray(a.color), np.asarray(b.color))
    assert not np.array_equal(np.asarray(a.depth), np.asarray(b.depth))
    np.testing.assert_array_equal(np.asarray(a.c2w), np.asarray(b.c2w))
    clean_a = synthetic_sequence(dataclasses.replace(SMALL, seed=1))[2]
    clean_b = synthetic_sequence(dataclasses.replace(SMALL, seed=2))[2]
    np.testing.assert_array_equal(np.asarray(clean_a.color), np.asarray(clean_b.color))


def test_speed_scales_the_motion_along_the_same_path():
    _, slow, _ = synthetic_sequence(dataclasses.replace(SMALL, num_frames=40)).gt_trajectory()
    _, fast, _ = synthetic_sequence(dataclasses.replace(SMALL, num_frames=20, speed=2.0)).gt_trajectory()
    np.testing.assert_allclose(fast, slow[::2], atol=1e-12)
    step = lambda c2w: np.mean(np.linalg.norm(np.diff(c2w[:, :3, 3], axis=0), axis=1))  # noqa: E731
    assert step(fast) == pytest.approx(2 * step(slow), rel=0.05)


def test_default_motion_is_about_a_centimetre_per_frame():
    _, c2w, valid = synthetic_sequence(SyntheticConfig()).gt_trajectory()
    steps = np.linalg.norm(np.diff(c2w[:, :3, 3], axis=0), axis=1)
    assert valid.all() and 0.005 < steps.mean() < 0.015


def test_trajectory_is_rigid_faces_into_the_room_and_keeps_clear_of_surfaces():
    c2w = camera_trajectory(np.linspace(0.0, 600.0, 20001))
    rot = c2w[:, :3, :3]
    np.testing.assert_allclose(np.swapaxes(rot, 1, 2) @ rot, np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    assert np.all(c2w[:, 1, 2] > 0.5)  # optical axis points towards the far (+y) half of the room
    assert scene.clearance(c2w[:, :3, 3]).min() > 0.5


def test_depth_noise_std_grows_with_depth_squared():
    config = dataclasses.replace(SMALL, width=160, height=120, depth_noise=0.01, supersample=1)
    clean = dataclasses.replace(config, depth_noise=0.0)
    noisy_depth = render_frame(config, 0)[1].astype(np.float64)
    clean_depth = render_frame(clean, 0)[1].astype(np.float64)
    normalised = (noisy_depth - clean_depth) / clean_depth**2
    assert np.std(normalised) == pytest.approx(0.01, rel=0.05)
    near, far = clean_depth < np.median(clean_depth), clean_depth >= np.median(clean_depth)
    assert np.std(noisy_depth - clean_depth, where=far) > 1.3 * np.std(noisy_depth - clean_depth, where=near)


def test_depth_holes_are_exactly_the_depth_discontinuities():
    config = dataclasses.replace(SMALL, depth_holes=True)
    depth = render_frame(config, 0)[1]
    clean = render_frame(SMALL, 0)[1]
    edges = depth_edges(clean, config.hole_threshold)
    assert 0 < edges.sum() < 0.2 * edges.size
    np.testing.assert_array_equal(depth == 0, edges)


def test_colour_noise_has_the_configured_std():
    config = dataclasses.replace(SMALL, color_noise=0.02)
    difference = render_frame(config, 1)[0] - render_frame(SMALL, 1)[0]
    assert np.std(difference) == pytest.approx(0.02, rel=0.1)


def test_motion_blur_averages_sub_frame_renders():
    no_exposure = dataclasses.replace(SMALL, motion_blur=3, shutter=0.0)
    np.testing.assert_allclose(render_frame(no_exposure, 3)[0], render_frame(SMALL, 3)[0], atol=1e-6)
    fast = dataclasses.replace(SMALL, speed=8.0)
    blurred = render_frame(dataclasses.replace(fast, motion_blur=4, shutter=1.0), 3)[0]
    sharp = render_frame(fast, 3)[0]
    gradient = lambda image: np.mean(np.abs(np.diff(image, axis=1)))  # noqa: E731
    assert gradient(blurred) < 0.9 * gradient(sharp)
    blurred_depth = render_frame(dataclasses.replace(fast, motion_blur=4), 3)[1]
    np.testing.assert_array_equal(blurred_depth, render_frame(fast, 3)[1])  # depth: the centre time's


def test_tum_round_trip_preserves_frames_within_quantisation(tmp_path):
    config = dataclasses.replace(SMALL, num_frames=4).with_sensor_noise()
    original = synthetic_sequence(config)
    read = open_sequence("tum", write_tum(original, tmp_path / "synthetic"))
    assert len(read) == 4
    k, k0 = read.intrinsics, original.intrinsics
    assert k.shape == k0.shape
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [k0.fx, k0.fy, k0.cx, k0.cy])
    times, c2w, valid = read.gt_trajectory()
    times0, c2w0, _ = original.gt_trajectory()
    np.testing.assert_allclose(times, times0, atol=1e-6)
    np.testing.assert_allclose(c2w, c2w0, atol=1e-6)
    assert valid.all()
    for a, b in zip(original, read):
        np.testing.assert_allclose(np.asarray(b.color), np.asarray(a.color), atol=0.5 / 255 + 1e-6)
        np.testing.assert_allclose(np.asarray(b.depth), np.asarray(a.depth), atol=0.5 / 5000 + 1e-6)
        np.testing.assert_array_equal(np.asarray(b.depth) == 0, np.asarray(a.depth) == 0)



def test_open_sequence_opens_the_synthetic_room_like_a_dataset(tmp_path):
    """``open_sequence("synthetic", ...)``: the generator's sequence with the size reduced by ``downscale``, the
    motion sped up by ``stride``, 30 frames by default, sensor noise on request; what only files have is refused."""
    opened = open_sequence("synthetic", max_frames=3, stride=2, downscale=4, sensor_noise=True, seed=5)
    direct = synthetic_sequence(SyntheticConfig(width=40, height=30, num_frames=3, speed=2.0, seed=5)
                                .with_sensor_noise())
    assert len(opened) == 3 and opened.intrinsics == direct.intrinsics
    for i in range(3):
        np.testing.assert_array_equal(opened.read_host(i).color, direct.read_host(i).color)
        np.testing.assert_array_equal(opened.read_host(i).depth, direct.read_host(i).depth)
    assert len(open_sequence("synthetic")) == 30
    with pytest.raises(ValueError, match="downscale 7 must divide"):
        open_sequence("synthetic", downscale=7)
    with pytest.raises(ValueError, match="generated"):
        open_sequence("synthetic", tmp_path)
    with pytest.raises(ValueError, match="synthetic sequence only"):
        open_sequence("tum", tmp_path, sensor_noise=True)
    with pytest.raises(ValueError, match="needs its directory"):
        open_sequence("tum")
