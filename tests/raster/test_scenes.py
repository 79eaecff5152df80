"""The test scenes exercise what they claim to, so that the rasterizer tests built on them can actually fail."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.support import reference_render as rr
from tests.support import scenes


@pytest.mark.parametrize("name", sorted({**scenes.SCENES, **scenes.GRADIENT_SCENES}))
def test_scene_is_finite_nonempty_and_free_of_float32_ambiguities(name):
    gaussians, w2c, intr = {**scenes.SCENES, **scenes.GRADIENT_SCENES}[name](0)
    for field in ("means", "log_scales", "logit_opacities", "rgb"):
        value = np.asarray(getattr(gaussians, field))
        assert value.dtype == np.float32 and np.isfinite(value).all(), field
    assert np.asarray(w2c).shape == (4, 4) and np.asarray(w2c).dtype == np.float32
    ref = rr.render_reference(gaussians, w2c, intr)
    assert ref.silhouette.max() > 0.5
    assert ref.ambiguous.mean() < 0.01, f"{ref.ambiguous.sum()} pixels at a float32-ambiguous decision"
    # seed 1 is what the gradient tests use; it must have no ambiguity at all
    if name in scenes.GRADIENT_SCENES:
        assert not rr.render_reference(*scenes.GRADIENT_SCENES[name](1)).ambiguous.any()


def test_dense_surface_is_one_opaque_gaussian_per_pixel():
    gaussians, w2c, intr = scenes.dense_surface(0)
    assert gaussians.capacity == intr.height * intr.width
    ref = rr.render_reference(gaussians, w2c, intr)
    assert ref.silhouette.min() > 0.99 and ref.stopped.mean() > 0.5
    # scale = z / f: one pixel's footprint at the Gaussian's depth
    z = ref.projected.z
    scales = np.exp(np.asarray(gaussians.log_scales, np.float64))
    np.testing.assert_allclose(scales * float(intr.fx) / z, 1.0, rtol=1e-4)


def test_heavy_overlap_has_50_to_60_contributors_before_the_stop():
    ref = rr.render_reference(*scenes.heavy_overlap(0))
    assert 50 <= ref.count.max() <= 64 and np.median(ref.count) >= 30
    assert ref.stopped.mean() > 0.9
    opacities = rr.sigmoid(np.asarray(scenes.heavy_overlap(0)[0].logit_opacities))[: ref.order.size]
    assert opacities.min() >= 0.3 - 1e-6 and opacities.max() <= 0.6 + 1e-6


def test_near_plane_scene_would_differ_without_the_cull():
    gaussians, w2c, intr = scenes.near_plane(0)
    ref = rr.render_reference(gaussians, w2c, intr)
    z = ref.projected.z
    active = np.asarray(gaussians.active)
    assert ((z > 0.2) & (z < 0.25) & active).sum() >= 2 and ((z <= 0.2) & (z > 0) & active).sum() >= 3
    assert ((z < 0) & active).sum() >= 5
    assert ref.projected.visible.sum() < active.sum()
    # culling only the Gaussians behind the camera (near ~ 0) visibly changes the image
    barely = rr.render_reference(gaussians, w2c, intr, near=0.1)
    assert np.abs(barely.color - ref.color).max() > 0.1


def test_off_screen_scene_needs_the_jacobian_clamp_and_reaches_into_the_image():
    gaussians, w2c, intr = scenes.off_screen(0)
    ref = rr.render_reference(gaussians, w2c, intr)
    uv = ref.projected.uv
    outside = (uv[:, 0] < -0.5) | (uv[:, 0] > intr.width - 0.5) | (uv[:, 1] < -0.5) | (uv[:, 1] > intr.height - 0.5)
    outside &= np.asarray(gaussians.active)
    assert outside.sum() >= 10
    assert ref.contributors[..., outside].any(axis=(0, 1)).sum() >= 10  # their footprints reach in
    assert ref.projected.jacobian_clamped.any(-1).sum() >= 5
    unclamped = rr.render_reference(gaussians, w2c, intr, jacobian_clamp=False)
    assert np.abs(unclamped.color - ref.color).max() > 0.02


def test_tiny_and_huge_scene_spans_sub_pixel_to_whole_image_footprints():
    gaussians, w2c, intr = scenes.tiny_and_huge(0)
    p = rr.project(gaussians, w2c, intr)
    sigma_px = np.sqrt(p.cov2d[:, 0, 0] - 0.3)[p.visible]
    assert sigma_px.min() < 0.05 and sigma_px.max() > 100
    ref = rr.render_reference(gaussians, w2c, intr)
    assert ref.silhouette.min() > 0.3  # the huge ones cover every pixel


def test_rotated_camera_is_far_from_the_identity():
    from gsjax.camera import rotation_angle

    _, w2c, intr = scenes.rotated_camera(0)
    assert float(rotation_angle(w2c[:3, :3])) > 0.5 and np.linalg.norm(np.asarray(w2c)[:3, 3]) > 0.5
    assert intr.height % 8 and intr.width % 8 and float(intr.fx) != float(intr.fy)


def test_inactive_garbage_would_show_if_rendered():
    gaussians, w2c, intr = scenes.inactive_garbage(0)
    active = np.asarray(gaussians.active)
    assert active.sum() == 20 and not np.all(active[:20])  # scattered, not a prefix
    ref = rr.render_reference(gaussians, w2c, intr)
    everything = rr.render_reference(dataclasses.replace(gaussians, active=np.ones_like(active)), w2c, intr)
    assert np.abs(everything.color - ref.color).max() > 10
