"""Gradients of the rasterizer against central finite differences of the float64 reference, and its behaviour
under jax transformations (jit, vmap over poses, vmap over maps).

The loss is a fixed random weighting of all four outputs. Directional derivatives along a random direction
(fixed seed) are taken for each Gaussian field separately and for the pose tangent ``delta`` with the left
perturbation ``w2c = se3_exp(delta) @ w2c0`` at ``delta = 0``. The reference's discrete state (contributor
sets, clamps, depth order, stops) is checked to be the same at theta - h, theta and theta + h, so that the
finite difference cannot straddle a discontinuity. Scene opacities stay below 0.99, so the alpha clamp (whose
straight-through gradient finite differences cannot see) never acts; it has its own test.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import make_intrinsics, se3_exp
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster.binning import TileGrid
from tests.support import reference_render as rr
from tests.support import scenes
from tests.support.raster_checks import FIELDS, GRAD_SEED, REL_TOL, STEP, loss_weights, stats_dict


def weighted_sum(images, weights) -> float:
    return sum(np.sum(np.asarray(getattr(images, k), np.float64) * w) for k, w in weights.items())


def _loss(means, log_scales, logit_opacities, rgb, delta, active, w2c0, intr, weights, render_settings):
    gaussians = Gaussians(means, log_scales, logit_opacities, rgb, active)
    out = render(gaussians, se3_exp(delta) @ w2c0, intr, render_settings)
    return sum(jnp.sum(getattr(out, k) * w) for k, w in weights.items())


_loss_and_grad = jax.jit(jax.value_and_grad(_loss, argnums=(0, 1, 2, 3, 4)))


@jax.jit
def _loss_jvp(primals, tangents, active, w2c0, intr, weights, render_settings):
    return jax.jvp(lambda *p: _loss(*p, active, w2c0, intr, weights, render_settings), primals, tangents)


def float64_copy(gaussians: Gaussians, **updates) -> Gaussians:
    fields = {f: np.asarray(getattr(gaussians, f), np.float64) for f in FIELDS}
    fields.update(updates)
    return Gaussians(active=np.asarray(gaussians.active), **fields)


def reference_loss(gaussians64, w2c64, intr, weights):
    ref = rr.render_reference(gaussians64, w2c64, intr)
    return weighted_sum(ref, weights), ref


def assert_same_discrete_state(a, b, label):
    for i, (x, y) in enumerate(zip(a.discrete_state(), b.discrete_state())):
        assert x.shape == y.shape and np.array_equal(x, y), f"{label}: discrete state {i} differs: h too large"


# pallas: its jvp runs on the XLA path (for_forward_mode); interpreted, in the slow suite (the default one compares its
# gradient with XLA's in test_pallas.py and differences the composite kernel on its own).
@pytest.mark.parametrize("backend", ["xla", pytest.param("pallas", marks=pytest.mark.slow)])
@pytest.mark.parametrize("name", sorted(scenes.GRADIENT_SCENES))
def test_gradients_match_finite_differences_of_the_reference(name, backend):
    render_settings = RasterSettings(backend=backend)
    gaussians, w2c, intr = scenes.GRADIENT_SCENES[name](GRAD_SEED)
    weights = loss_weights(intr.height, intr.width)
    weights32 = {k: jnp.asarray(v, jnp.float32) for k, v in weights.items()}
    active = np.asarray(gaussians.active)
    primals = tuple(getattr(gaussians, f) for f in FIELDS) + (jnp.zeros(6, jnp.float32),)
    value, grads = _loss_and_grad(*primals, gaussians.active, w2c, intr, weights32, render_settings)

    base = float64_copy(gaussians)
    w2c64 = np.asarray(w2c, np.float64)
    ref_value, ref_base = reference_loss(base, w2c64, intr, weights)
    assert not ref_base.ambiguous.any()
    np.testing.assert_allclose(float(value), ref_value, rtol=1e-4, atol=1e-3)

    rng = np.random.default_rng(7)
    lines = []
    for index, field in enumerate(FIELDS + ("pose",)):
        shape = (6,) if field == "pose" else np.shape(getattr(gaussians, field))
        direction = rng.normal(size=shape)
        if field != "pose":
            direction[~active] = 0.0  # free slots: not part of the map
        h = STEP[field]
        if field == "pose":
            plus_args = (base, scenes.se3_exp_np(h * direction) @ w2c64)
            minus_args = (base, scenes.se3_exp_np(-h * direction) @ w2c64)
        else:
            theta = np.asarray(getattr(gaussians, field), np.float64)
            plus_args = (float64_copy(gaussians, **{field: theta + h * direction}), w2c64)
            minus_args = (float64_copy(gaussians, **{field: theta - h * direction}), w2c64)
        loss_plus, ref_plus = reference_loss(*plus_args, intr, weights)
        loss_minus, ref_minus = reference_loss(*minus_args, intr, weights)
        assert_same_discrete_state(ref_plus, ref_base, f"{name}/{field} +h")
        assert_same_discrete_state(ref_minus, ref_base, f"{name}/{field} -h")
        finite_difference = (loss_plus - loss_minus) / (2 * h)

        by_grad = float(np.sum(np.asarray(grads[index], np.float64) * direction))
        tangents = tuple(
            jnp.asarray(direction if i == index else np.zeros(np.shape(p)), jnp.float32) for i, p in enumerate(primals)
        )
        _, by_jvp = _loss_jvp(primals, tangents, gaussians.active, w2c, intr, weights32,
                              render_settings.for_forward_mode())
        by_jvp = float(by_jvp)
        err_grad = abs(by_grad - finite_difference) / abs(finite_difference)
        err_jvp = abs(by_jvp - finite_difference) / abs(finite_difference)
        lines.append(
            f"  {field:16s} fd {finite_difference:+.6e}  grad {by_grad:+.6e} (rel {err_grad:.1e})  "
            f"jvp {by_jvp:+.6e} (rel {err_jvp:.1e})"
        )
        assert abs(finite_difference) > 1e-3, f"{name}/{field}: derivative too small to test ({finite_difference})"
        assert err_grad <= REL_TOL, f"{name}/{field}: grad {by_grad} vs finite difference {finite_difference}"
        assert err_jvp <= REL_TOL, f"{name}/{field}: jvp {by_jvp} vs finite difference {finite_difference}"
    print(f"\n{name} ({backend}): loss {float(value):.6f} (reference {ref_value:.6f})\n" + "\n".join(lines))

    # free slots hold garbage (finite, would be visible) and get exactly zero gradient
    for field, grad in zip(FIELDS, grads[:4]):
        grad = np.asarray(grad)
        assert np.isfinite(grad).all(), field
        assert np.all(grad[~active] == 0.0), f"{name}: nonzero gradient of {field} in a free slot"


def test_alpha_clamp_passes_the_unclamped_gradient_straight_through():
    # One Gaussian on pixel (10, 14) with opacity 0.995: alpha = min(0.99, o g) is clamped at its centre. The
    # backward pass ignores the clamp (as SplaTAM's CUDA rasterizer), so d alpha / d logit = g o (1 - o) there.
    intr = make_intrinsics(30.0, 28.0, 14.0, 10.0, scenes.GRAD_HEIGHT, scenes.GRAD_WIDTH)
    opacity, z = 0.995, 1.5
    rgb = np.array([0.2, 0.6, 0.9])
    gaussians = Gaussians.create(
        [[0.0, 0.0, z]], [rgb], 0.04, opacity, capacity=scenes.GRAD_CAPACITY
    )  # same shapes as the gradient scenes: no new compilation
    w2c = jnp.eye(4, dtype=jnp.float32)
    primals = tuple(getattr(gaussians, f) for f in FIELDS) + (jnp.zeros(6, jnp.float32),)
    slope = opacity * (1 - opacity)  # d o / d logit
    p = rr.project(gaussians, np.eye(4), intr)
    g_side = float(np.exp(-0.5 * p.conic[0, 0, 0] * 2.0**2))  # 2 px right of the centre, o g < 0.99 there
    assert opacity * g_side < 0.99

    def one_pixel_loss(output, row, col):
        weights = {k: jnp.zeros(v.shape, jnp.float32) for k, v in loss_weights(intr.height, intr.width).items()}
        weights[output] = weights[output].at[row, col].set(1.0)
        return _loss_and_grad(*primals, gaussians.active, w2c, intr, weights, RasterSettings())

    cases = (((10, 14), 1.0, "silhouette"), ((10, 14), 1.0, "depth"), ((10, 16), g_side, "silhouette"))
    for (row, col), g, out_weight in cases:
        value, grads = one_pixel_loss(out_weight, row, col)
        factor = z if out_weight == "depth" else 1.0
        np.testing.assert_allclose(float(value), factor * min(0.99, opacity * g), rtol=1e-5)
        np.testing.assert_allclose(float(grads[2][0]), factor * g * slope, rtol=1e-3)
    # and the colour channel's gradient at the clamped centre is rgb * o (1 - o), nonzero
    _, grads = one_pixel_loss("color", 10, 14)
    np.testing.assert_allclose(float(grads[2][0]), rgb.sum() * slope, rtol=1e-3)


def _assert_renders_equal(a, b, label, atol=1e-5):
    for field in ("color", "depth", "silhouette", "depth_sq"):
        np.testing.assert_allclose(
            np.asarray(getattr(a, field)), np.asarray(getattr(b, field)), atol=atol, err_msg=f"{label}: {field}"
        )
    assert stats_dict(a) == pytest.approx(stats_dict(b), abs=1e-6), label


def test_jit_gives_the_same_render_as_eager_execution():
    gaussians, w2c, intr = scenes.sparse_random(0)
    s = RasterSettings()
    eager = render(gaussians, w2c, intr, s)
    jitted = jax.jit(lambda g, w, k: render(g, w, k, s))(gaussians, w2c, intr)
    _assert_renders_equal(jitted, eager, "jit vs eager")


# 20 tiles: 20 x 1, 7 x 3 (+1 padding), 3 x 7 (+1); a program each: 3 (uneven, padded) in the default suite.
@pytest.mark.parametrize("tiles_per_batch", [pytest.param(1, marks=pytest.mark.slow), 3,
                                             pytest.param(7, marks=pytest.mark.slow)])
def test_selection_in_batches_of_tiles_gives_the_same_render(tiles_per_batch):
    gaussians, w2c, intr = scenes.sparse_random(0)
    whole = render(gaussians, w2c, intr, RasterSettings())
    batched = render(gaussians, w2c, intr, RasterSettings(tiles_per_batch=tiles_per_batch))
    grid = TileGrid.for_image(intr.height, intr.width, RasterSettings().tile_size)
    assert grid.num_tiles > tiles_per_batch
    _assert_renders_equal(batched, whole, f"{tiles_per_batch} tiles per batch", atol=0.0)


def test_vmap_over_poses_equals_rendering_each_pose():
    gaussians, w2c, intr = scenes.sparse_random(0)
    s = RasterSettings()
    deltas = jnp.asarray(np.random.default_rng(8).normal(scale=0.05, size=(3, 6)), jnp.float32)
    poses = jax.vmap(lambda d: se3_exp(d) @ w2c)(deltas)
    batched = jax.jit(jax.vmap(lambda g, w: render(g, w, intr, s), in_axes=(None, 0)))(gaussians, poses)
    single = jax.jit(lambda g, w: render(g, w, intr, s))
    for b in range(3):
        _assert_renders_equal(jax.tree_util.tree_map(lambda x: x[b], batched), single(gaussians, poses[b]), f"pose {b}")
    assert not np.allclose(np.asarray(batched.color[0]), np.asarray(batched.color[1]), atol=1e-3)


def test_vmap_over_stacked_maps_equals_rendering_each_map():
    maps = [scenes.sparse_random(seed)[0] for seed in (0, 1, 2)]
    _, w2c, intr = scenes.sparse_random(0)
    s = RasterSettings()
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *maps)
    assert stacked.means.shape == (3, scenes.SMALL_CAPACITY, 3)
    batched = jax.jit(jax.vmap(lambda g, w: render(g, w, intr, s), in_axes=(0, None)))(stacked, w2c)
    single = jax.jit(lambda g, w: render(g, w, intr, s))
    for b, g in enumerate(maps):
        _assert_renders_equal(jax.tree_util.tree_map(lambda x: x[b], batched), single(g, w2c), f"map {b}")
        ref = rr.render_reference(g, w2c, intr)
        np.testing.assert_allclose(np.asarray(batched.color[b]), ref.color, atol=5e-3)


@pytest.mark.parametrize("name", sorted(scenes.GRADIENT_SCENES))
def test_pose_only_path_gives_the_same_render_and_pose_gradient_and_no_map_gradient(name):
    # pose_only projects every slot from the raw parameters (no scatter into the Gaussians in the backward pass):
    # the render and the pose gradient must equal the per-Gaussian path's, the pose gradient must match finite
    # differences of the float64 reference, and the map gets no gradient at all.
    gaussians, w2c, intr = scenes.GRADIENT_SCENES[name](GRAD_SEED)
    weights = loss_weights(intr.height, intr.width)
    weights32 = {k: jnp.asarray(v, jnp.float32) for k, v in weights.items()}
    primals = tuple(getattr(gaussians, f) for f in FIELDS) + (jnp.zeros(6, jnp.float32),)
    full_value, full = _loss_and_grad(*primals, gaussians.active, w2c, intr, weights32, RasterSettings())
    value, grads = _loss_and_grad(*primals, gaussians.active, w2c, intr, weights32, RasterSettings(pose_only=True))
    np.testing.assert_allclose(float(value), float(full_value), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(grads[4]), np.asarray(full[4]), rtol=1e-4, atol=1e-5 * np.abs(full[4]).max())
    for field, grad in zip(FIELDS, grads[:4]):
        assert np.all(np.asarray(grad) == 0.0), f"{name}: pose_only let a gradient reach {field}"
    base, w2c64 = float64_copy(gaussians), np.asarray(w2c, np.float64)
    direction, h = np.random.default_rng(11).normal(size=6), STEP["pose"]
    plus = reference_loss(base, scenes.se3_exp_np(h * direction) @ w2c64, intr, weights)[0]
    minus = reference_loss(base, scenes.se3_exp_np(-h * direction) @ w2c64, intr, weights)[0]
    finite_difference = (plus - minus) / (2 * h)
    by_grad = float(np.sum(np.asarray(grads[4], np.float64) * direction))
    assert abs(by_grad - finite_difference) <= REL_TOL * abs(finite_difference), (by_grad, finite_difference)
