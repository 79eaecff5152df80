"""Analytic checks of the float64 reference renderer itself (tests/support/reference_render.py).

The reference is the yardstick for the rasterizer, so each rule of the contract is pinned here on a scene
whose answer is known in closed form.
"""

from __future__ import annotations

import numpy as np
import pytest

from gsjax.camera import make_intrinsics
from gsjax.gaussians import Gaussians
from tests.support import reference_render as rr
from tests.support import scenes

H, W = 32, 40
FX, FY, CX, CY = 40.0, 30.0, 20.0, 16.0  # integer principal point: a centred Gaussian sits on pixel (16, 20)
INTR = make_intrinsics(FX, FY, CX, CY, H, W)
IDENTITY = np.eye(4)


def logit(p):
    return np.log(p) - np.log1p(-p)


def make(means, scales, opacities, rgb=None, active=None):
    """float64 numpy Gaussians (the reference accepts any array type)."""
    means = np.atleast_2d(np.asarray(means, np.float64))
    n = len(means)
    rgb = np.full((n, 3), 0.5) if rgb is None else np.asarray(rgb, np.float64).reshape(n, 3)
    return Gaussians(
        means=means,
        log_scales=np.log(np.broadcast_to(np.asarray(scales, np.float64), (n,))),
        logit_opacities=logit(np.broadcast_to(np.asarray(opacities, np.float64), (n,))),
        rgb=rgb,
        active=np.ones(n, bool) if active is None else np.asarray(active, bool),
    )


def test_single_gaussian_at_its_centre_renders_opacity_times_its_attributes():
    rgb = np.array([0.2, 0.5, 0.9])
    ref = rr.render_reference(make([0.0, 0.0, 2.0], 0.05, 0.7, rgb), IDENTITY, INTR)
    np.testing.assert_allclose(ref.silhouette[16, 20], 0.7, rtol=1e-14)
    np.testing.assert_allclose(ref.color[16, 20], 0.7 * rgb, rtol=1e-14)
    np.testing.assert_allclose(ref.depth[16, 20], 0.7 * 2.0, rtol=1e-14)
    np.testing.assert_allclose(ref.depth_sq[16, 20], 0.7 * 4.0, rtol=1e-14)
    assert ref.count[16, 20] == 1 and ref.contributors[16, 20, 0]


def test_single_gaussian_falls_off_with_the_dilated_ewa_covariance():
    # On the optical axis J = diag(fx/z, fy/z) (x/z = y/z = 0), so Sigma2D = diag(s^2 fx^2/z^2, s^2 fy^2/z^2) + 0.3.
    s, z, o = 0.1, 2.0, 0.7
    ref = rr.render_reference(make([0.0, 0.0, z], s, o), IDENTITY, INTR)
    sxx, syy = (s * FX / z) ** 2 + 0.3, (s * FY / z) ** 2 + 0.3
    dx, dy = 3.0, -2.0  # column +3, row -2
    expected = o * np.exp(-0.5 * (dx * dx / sxx + dy * dy / syy))
    assert expected > 0.1
    np.testing.assert_allclose(ref.silhouette[16 - 2, 20 + 3], expected, rtol=1e-13)
    # the pixel grid convention: pixel (row i, column j) is sampled at (u, v) = (j, i), no half-pixel offset
    np.testing.assert_allclose(ref.silhouette[16, 20], o, rtol=1e-14)
    assert ref.silhouette[16, 20] == ref.silhouette.max()


def test_covariance_is_the_projection_jacobian_pushed_through_the_pose():
    # Independent of the hand-written J: differentiate world point -> pixel numerically (central differences).
    rng = np.random.default_rng(3)
    w2c = scenes.rigid(scenes.random_rotation(rng), rng.normal(size=3))
    cam = np.array([0.3, -0.2, 1.7])  # x/z, y/z inside the clamp
    world = np.linalg.solve(w2c[:3, :3], cam - w2c[:3, 3])
    s = 0.04
    p = rr.project(make(world, s, 0.5), w2c, INTR)

    def pixel(x):
        c = w2c[:3, :3] @ x + w2c[:3, 3]
        return np.array([FX * c[0] / c[2] + CX, FY * c[1] / c[2] + CY])

    eps = 1e-6
    jac = np.stack([(pixel(world + eps * e) - pixel(world - eps * e)) / (2 * eps) for e in np.eye(3)], -1)
    np.testing.assert_allclose(p.uv[0], pixel(world), rtol=1e-12)
    np.testing.assert_allclose(p.cov2d[0], s * s * jac @ jac.T + 0.3 * np.eye(2), rtol=1e-7)
    assert not p.jacobian_clamped.any()


def test_jacobian_is_evaluated_at_the_clamped_direction_but_the_centre_is_not_clamped():
    lim_x = 1.3 * W / (2 * FX)  # 0.65
    z, s = 1.5, 0.1
    ref_point = make([[1.0 * z, 0.1 * z, z], [lim_x * z, 0.1 * z, z]], s, 0.5)
    p = rr.project(ref_point, IDENTITY, INTR)
    assert p.jacobian_clamped[0].tolist() == [True, False] and not p.jacobian_clamped[1].any()
    np.testing.assert_allclose(p.uv[0, 0], FX * 1.0 + CX, rtol=1e-14)  # centre uses the true x/z
    np.testing.assert_allclose(p.cov2d[0], p.cov2d[1], rtol=1e-14)  # covariance as if at the clamp
    unclamped = rr.project(ref_point, IDENTITY, INTR, jacobian_clamp=False)
    assert not np.allclose(unclamped.cov2d[0], p.cov2d[0], rtol=1e-3)
    np.testing.assert_allclose(unclamped.cov2d[1], p.cov2d[1], rtol=1e-14)


def test_front_gaussian_is_composited_first_whatever_its_slot():
    o_front, o_back = 0.6, 0.8
    c_front, c_back = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    means = [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]
    for perm in ([0, 1], [1, 0]):
        g = make(np.array(means)[perm], 0.05, np.array([o_front, o_back])[perm], np.stack([c_front, c_back])[perm])
        ref = rr.render_reference(g, IDENTITY, INTR)
        np.testing.assert_allclose(ref.color[16, 20], o_front * c_front + (1 - o_front) * o_back * c_back, rtol=1e-14)
        np.testing.assert_allclose(ref.depth[16, 20], o_front * 1.0 + (1 - o_front) * o_back * 2.0, rtol=1e-14)
        np.testing.assert_allclose(ref.depth_sq[16, 20], o_front * 1.0 + (1 - o_front) * o_back * 4.0, rtol=1e-14)
        np.testing.assert_array_equal(ref.order, np.argsort(np.array(means)[perm][:, 2]))
    # swapping the depths swaps the roles
    g = make([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]], 0.05, [o_front, o_back], np.stack([c_front, c_back]))
    ref = rr.render_reference(g, IDENTITY, INTR)
    np.testing.assert_allclose(ref.color[16, 20], o_back * c_back + (1 - o_back) * o_front * c_front, rtol=1e-14)


def test_walk_stops_at_the_first_gaussian_that_would_drop_t_below_1e_4():
    # alphas at the shared centre pixel, front to back: 0.9, 0.99 (0.995 clamped), 0.95, 0.5.
    # T: 1 -> 0.1 -> 1e-3; the third would give 5e-5 < 1e-4, so the walk stops there. The fourth would leave
    # 5e-4 >= 1e-4 and would be added if the rule were "skip" instead of "stop"; it must not be.
    opac = [0.9, 0.995, 0.95, 0.5]
    g = make([[0.0, 0.0, 1.0 + k] for k in range(4)], 0.02, opac, np.eye(4)[:, :3])
    ref = rr.render_reference(g, IDENTITY, INTR)
    np.testing.assert_allclose(ref.silhouette[16, 20], 0.9 + 0.1 * 0.99, rtol=1e-14)
    np.testing.assert_allclose(ref.color[16, 20], [0.9, 0.1 * 0.99, 0.0], rtol=1e-14)
    np.testing.assert_allclose(ref.depth[16, 20], 0.9 * 1.0 + 0.1 * 0.99 * 2.0, rtol=1e-14)
    np.testing.assert_allclose(ref.transmittance[16, 20], 1e-3, rtol=1e-12)
    assert ref.contributors[16, 20].tolist() == [True, True, False, False]
    assert ref.stopped[16, 20] and ref.count[16, 20] == 2
    assert ref.clamped[16, 20].tolist() == [False, True, False, False]


def test_alpha_is_clamped_at_0_99():
    ref = rr.render_reference(make([0.0, 0.0, 1.0], 0.05, 0.999), IDENTITY, INTR)
    np.testing.assert_allclose(ref.silhouette[16, 20], 0.99, rtol=1e-14)
    assert ref.clamped[16, 20, 0] and not ref.clamped[16, 22, 0]


@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_gaussian_contributes_exactly_where_alpha_reaches_1_over_255(side):
    # Choose the scale so that alpha at 4 px right of the centre is (1 + side * 1e-6) / 255.
    o, z, dx = 0.5, 1.0, 4.0
    target = (1.0 + side * 1e-6) / 255.0
    sxx = dx * dx / (2.0 * np.log(o / target))
    s = np.sqrt(sxx - 0.3) * z / FX
    ref = rr.render_reference(make([0.0, 0.0, z], s, o), IDENTITY, INTR)
    if side > 0:
        np.testing.assert_allclose(ref.silhouette[16, 24], target, rtol=1e-9)
        assert ref.candidates[16, 24, 0] and ref.contributors[16, 24, 0]
    else:
        assert ref.silhouette[16, 24] == 0.0 and not ref.candidates[16, 24, 0]
    assert ref.ambiguous[16, 24]  # this close to the threshold float32 may decide either way
    assert not ref.ambiguous[16, 20]


def test_near_plane_and_inactive_slots_render_nothing():
    means = [[0.0, 0.0, 0.2], [0.0, 0.0, 0.2 + 1e-6], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]
    g = make(means, 0.001, 0.5, active=[True, True, False, True])
    ref = rr.render_reference(g, IDENTITY, INTR)
    assert ref.projected.visible.tolist() == [False, True, False, False]
    np.testing.assert_allclose(ref.depth[16, 20], 0.5 * (0.2 + 1e-6), rtol=1e-14)
    ref_far = rr.render_reference(g, IDENTITY, INTR, near=0.5)
    assert not ref_far.projected.visible.any() and ref_far.silhouette.max() == 0.0


def test_background_is_zero_away_from_every_gaussian():
    ref = rr.render_reference(make([0.0, 0.0, 1.0], 0.01, 0.9), IDENTITY, INTR)
    assert ref.silhouette[0, 0] == 0 and ref.depth[0, 0] == 0 and np.all(ref.color[0, 0] == 0)
    assert ref.count[0, 0] == 0


def test_silhouette_is_one_minus_the_transmittance():
    ref = rr.render_reference(*scenes.heavy_overlap(0))
    np.testing.assert_allclose(ref.silhouette, 1.0 - ref.transmittance, atol=1e-12)
    np.testing.assert_array_equal(ref.count, ref.contributors.sum(-1))


def test_moving_world_and_camera_together_leaves_the_image_unchanged():
    g, w2c, intr = scenes.sparse_random(4)
    rng = np.random.default_rng(5)
    motion = scenes.rigid(scenes.random_rotation(rng), rng.normal(size=3))
    w2c64 = np.asarray(w2c, np.float64)
    means = np.asarray(g.means, np.float64)
    moved = Gaussians(means @ motion[:3, :3].T + motion[:3, 3], g.log_scales, g.logit_opacities, g.rgb, g.active)
    a = rr.render_reference(g, w2c64, intr)
    b = rr.render_reference(moved, w2c64 @ np.linalg.inv(motion), intr)
    for name, value in a.outputs().items():
        np.testing.assert_allclose(getattr(b, name), value, atol=1e-11, err_msg=name)


def test_truncated_reference_keeps_the_first_k_contributors_in_depth_order():
    g, w2c, intr = scenes.heavy_overlap(0)
    k = 5
    full = rr.render_reference(g, w2c, intr)
    cut = rr.render_reference(g, w2c, intr, max_contributors=k)
    assert cut.count.max() == k and (cut.cut == (full.count > k)).all()
    rank = np.zeros_like(full.contributors, np.int64)
    for pos, slot in enumerate(full.order):  # rank of each contributor along the walk
        rank[..., slot] = full.contributors[..., full.order[: pos + 1]].sum(-1)
    np.testing.assert_array_equal(cut.contributors, full.contributors & (rank <= k))
    expectation = rr.expected_truncation(g, w2c, intr, k)
    assert 0 < expectation["must"] <= expectation["may"] == H * W
    assert 0 < expectation["residual_must"] <= expectation["residual_may"] < 1


def test_tile_candidate_counts_bound_the_per_pixel_candidates():
    ref = rr.render_reference(*scenes.sparse_random(0))
    whole = rr.tile_candidate_counts(ref, 64)
    assert whole.shape == (1, 1) and whole[0, 0] == ref.candidates.any(axis=(0, 1)).sum()
    tiles = rr.tile_candidate_counts(ref, 8)
    assert tiles.shape == (4, 5) and tiles.max() >= ref.num_candidates.max()
