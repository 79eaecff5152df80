"""The Pallas path (``RasterSettings(backend="pallas")``, interpret mode on CPU) against the XLA path and the
float64 references: the two kernels on their own, then whole renders, truncation statistics, CB-KNN, gradients,
the memory-bounded compositing, and the transformations users rely on (vmap sweeps, forward mode via XLA).

The XLA path is the reference: the Pallas path must give the same values (<= 1e-5), the same statistics, and the
same gradients (<= 1e-4 relative).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import se3_exp
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster import pallas as kernels
from gsjax.raster.cbknn import CBKNN
from gsjax.raster.project import ALPHA_MIN
from tests.support import reference_render as rr
from tests.support import scenes
from tests.support.raster_checks import FIELDS, OUTPUTS, assert_within_tolerance, errors, format_errors

VALUE_TOL = 1e-5
GRAD_TOL = 1e-4
CBKNN_CASES = {
    "adaptive": dict(alpha=0.25, k0=4.3, beta=0.37),
    "top_weight": dict(alpha=0.2, k0=5.0, beta=0.0, select="top_weight"),
    "truncate_fraction": dict(alpha=0.3, k0=6.0, beta=0.2, truncate=True, shift_mode="fraction"),
    "colour_only": dict(alpha=0.2, k0=5.0, beta=0.0, position=False),
}
MOTION = 0.6

_renders: dict[tuple, object] = {}


def both(scene_name: str, cbknn_case: str | None = None, **overrides):
    """(xla render, pallas render) of a scene, cached per arguments."""
    key = (scene_name, cbknn_case, tuple(sorted(overrides.items())))
    if key not in _renders:
        gaussians, w2c, intr = scenes.SCENES[scene_name](0)
        cb = None if cbknn_case is None else CBKNN(**CBKNN_CASES[cbknn_case])
        _renders[key] = tuple(
            render(gaussians, w2c, intr, RasterSettings(backend=backend, **overrides), cbknn=cb, motion=MOTION)
            for backend in ("xla", "pallas")
        )
    return _renders[key]


def assert_same_render(a, b, label: str) -> None:
    for field in OUTPUTS:
        x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
        scale = max(1.0, float(np.abs(x).max()))
        assert np.abs(x - y).max() <= VALUE_TOL * scale, f"{label}: {field} differs by {np.abs(x - y).max():.3e}"
    flat_a, tree_a = jax.tree_util.tree_flatten(a.stats)
    flat_b, tree_b = jax.tree_util.tree_flatten(b.stats)
    assert tree_a == tree_b, label
    for index, (x, y) in enumerate(zip(flat_a, flat_b)):
        x, y = np.asarray(x), np.asarray(y)
        if np.issubdtype(x.dtype, np.floating):
            np.testing.assert_allclose(y, x, atol=1e-6, rtol=1e-5, err_msg=f"{label}: stats leaf {index}")
        else:
            np.testing.assert_array_equal(y, x, err_msg=f"{label}: stats leaf {index}")


# ----------------------------------------------------------------------------------------------- the kernels


def composite_reference(alpha, r, g, b, z):
    """Dense float64 front-to-back compositing: (color r, g, b, depth, silhouette, depth_sq, final T) per pixel."""
    alpha, r, g, b, z = (np.asarray(x, np.float64) for x in (alpha, r, g, b, z))
    before = np.concatenate([np.ones_like(alpha[:1]), np.cumprod(1.0 - alpha, axis=0)[:-1]])
    w = alpha * before
    return (np.sum(w * r, 0), np.sum(w * g, 0), np.sum(w * b, 0), np.sum(w * z, 0), np.sum(w, 0),
            np.sum(w * z * z, 0), np.prod(1.0 - alpha, axis=0))


def random_slots(seed: int, num_slots: int = 7, num_pixels: int = 192):
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(0.0, 0.99, (num_slots, num_pixels)) * (rng.uniform(size=(num_slots, num_pixels)) < 0.8)
    colours = rng.uniform(0.0, 1.0, (3, num_slots, num_pixels))
    depth = rng.uniform(0.5, 4.0, (num_slots, num_pixels))
    return (alpha, *colours, depth)


def test_composite_kernel_matches_the_float64_reference():
    inputs = random_slots(0)  # 7 slots (not a power of two), 192 pixels (three programs of 64)
    got = kernels.composite_slots(*(jnp.asarray(x, jnp.float32) for x in inputs))
    for name, g, want in zip(("r", "g", "b", "depth", "silhouette", "depth_sq", "final T"), got,
                             composite_reference(*inputs)):
        np.testing.assert_allclose(np.asarray(g), want, rtol=1e-5, atol=1e-6, err_msg=name)


def test_composite_kernel_gradient_matches_finite_differences_of_the_reference():
    inputs = random_slots(1, num_slots=5, num_pixels=64)
    rng = np.random.default_rng(2)
    cotangents = [rng.normal(size=64) for _ in range(7)]

    def reference_loss(*xs):
        return sum(np.sum(c * o) for c, o in zip(cotangents, composite_reference(*xs)))

    _, vjp = jax.vjp(kernels.composite_slots, *(jnp.asarray(x, jnp.float32) for x in inputs))
    grads = vjp(tuple(jnp.asarray(c, jnp.float32) for c in cotangents))
    h = 1e-6
    for index, name in enumerate(("alpha", "r", "g", "b", "depth")):
        direction = rng.normal(size=inputs[index].shape)
        plus = [x + h * direction if i == index else x for i, x in enumerate(inputs)]
        minus = [x - h * direction if i == index else x for i, x in enumerate(inputs)]
        finite_difference = (reference_loss(*plus) - reference_loss(*minus)) / (2 * h)
        by_vjp = float(np.sum(np.asarray(grads[index], np.float64) * direction))
        assert abs(by_vjp - finite_difference) <= GRAD_TOL * abs(finite_difference) + 1e-5, (
            f"{name}: vjp {by_vjp} vs finite difference {finite_difference}"
        )


def walk_reference(features, count, pixels):
    """The selection walk, pixel by pixel (numpy float32, the kernel's arithmetic): kept bits [B, T^2, M]."""
    u, v, a, b, c, o = (np.asarray(f, np.float32) for f in features)
    num_tiles, num_entries = u.shape
    kept = np.zeros((num_tiles, pixels.shape[1], num_entries), bool)
    for tile in range(num_tiles):
        for p, (px, py) in enumerate(np.asarray(pixels[tile], np.float32)):
            transmittance = np.float32(1.0)
            for m in range(min(int(count[tile]), num_entries)):
                dx, dy = px - u[tile, m], py - v[tile, m]
                power = np.float32(-0.5) * (a[tile, m] * dx * dx + c[tile, m] * dy * dy) - b[tile, m] * dx * dy
                alpha = min(np.float32(0.99), o[tile, m] * np.exp(power, dtype=np.float32))
                if alpha < np.float32(ALPHA_MIN):
                    continue
                transmittance = transmittance * (np.float32(1.0) - alpha)
                if transmittance < np.float32(kernels.T_MIN):
                    break
                kept[tile, p, m] = True
    return kept


def test_walk_kernel_selects_the_first_k_contributors_the_stop_rule_allows():
    rng = np.random.default_rng(3)
    num_tiles, num_entries, side = 3, 64, 8
    uv = rng.uniform(-2.0, 10.0, (2, num_tiles, num_entries))
    sigma = rng.uniform(0.7, 4.0, (num_tiles, num_entries))
    opacity = rng.uniform(0.05, 0.99, (num_tiles, num_entries))
    count = np.array([64, 20, 0], np.int32)  # a full list, a short one, an empty one
    opacity[np.arange(num_entries)[None, :] >= count[:, None]] = 0.0
    features = (uv[0], uv[1], 1 / sigma**2, np.zeros_like(sigma), 1 / sigma**2, opacity)
    local_v, local_u = np.divmod(np.arange(side * side), side)
    pixels = np.broadcast_to(np.stack([local_u, local_v], -1), (num_tiles, side * side, 2)).astype(np.float32)
    k = 32
    local, num_kept, transmittance = kernels.walk_select(
        tuple(jnp.asarray(f, jnp.float32) for f in features), jnp.asarray(count), jnp.asarray(pixels), k
    )
    want = walk_reference(features, count, pixels)
    assert want[0].any(axis=-1).all() and want[0].sum(-1).min() < k < want[0].sum(-1).max()  # not vacuous
    np.testing.assert_array_equal(np.asarray(num_kept), want.sum(-1))
    for tile in range(num_tiles):
        for p in range(side * side):
            first = np.flatnonzero(want[tile, p])[:k]
            expected = np.concatenate([first, np.full(k - first.size, -1)])
            np.testing.assert_array_equal(np.asarray(local)[tile, :, p], expected, err_msg=f"tile {tile} px {p}")
    np.testing.assert_array_equal(np.asarray(transmittance)[2], 1.0)  # the empty tile's pixels see nothing


# ----------------------------------------------------------------------------------------------- whole renders


# One interpreted render per kernel in the default suite (both kernels run in a render); the other scenes, and every
# other interpreted render below (truncation, CB-KNN, batches, vmap, forward mode, LM), run in the slow suite: they
# take 10-30 s each to compile in interpret mode, and the XLA path's own tests cover what they compare against.
SLOW = pytest.mark.slow


@pytest.mark.parametrize("name", [n if n == "dense_surface" else pytest.param(n, marks=SLOW)
                                  for n in sorted(scenes.SCENES)])
def test_pallas_render_equals_the_xla_render_and_the_float64_reference(name):
    xla, pallas = both(name)
    assert_same_render(xla, pallas, name)
    gaussians, w2c, intr = scenes.SCENES[name](0)
    ref = rr.render_reference(gaussians, w2c, intr)
    errs = errors(pallas, ref, ~ref.ambiguous)
    print("\n" + format_errors(f"{name} pallas", errs))
    assert_within_tolerance(f"{name} pallas", errs)


@SLOW
@pytest.mark.parametrize(
    "name, overrides",
    [("heavy_overlap", dict(max_contributors=8)), ("dense_surface", dict(max_contributors=16)),
     ("heavy_overlap", dict(tile_size=16, tile_capacity=16)), ("dense_surface", dict(tile_capacity=64))],
)
def test_truncation_is_reported_the_same_way(name, overrides):
    xla, pallas = both(name, **overrides)
    assert bool(xla.stats.truncated)  # the case does truncate
    assert_same_render(xla, pallas, f"{name} {overrides}")


@SLOW
@pytest.mark.parametrize(
    "name, case", [("dense_surface", c) for c in sorted(CBKNN_CASES)] + [("heavy_overlap", "adaptive")]
)
def test_cbknn_render_and_statistics_are_the_same_on_both_backends(name, case):
    xla, pallas = both(name, case)
    canonical, _ = both(name)
    assert np.abs(np.asarray(xla.color) - np.asarray(canonical.color)).max() > 1e-3  # CB-KNN acts here
    assert_same_render(xla, pallas, f"{name} {case}")


def test_the_lowering_platform_picks_triton_kernels_for_a_gpu_and_the_interpreter_elsewhere():
    """Not the default backend: a GPU program compiled ahead of time on this CPU machine gets the Triton kernels."""
    from jax import export

    x = jnp.full((8, 256), 0.1, jnp.float32)
    f = jax.jit(lambda a: kernels.composite_slots(a, a, a, a, a))
    triton = export.DisabledSafetyCheck.custom_call("__gpu$xla.gpu.triton")
    cuda = export.export(f, platforms=["cuda"], disabled_checks=[triton])(x).mlir_module()
    cpu = export.export(f, platforms=["cpu"])(x).mlir_module()
    assert cuda.count("@__gpu$xla.gpu.triton") == 1 and 'name = "_composite_kernel"' in cuda
    assert "__gpu$xla.gpu.triton" not in cpu and "custom_call" not in cpu
    np.testing.assert_allclose(f(x)[6], 0.9**8, rtol=1e-6)  # interpreted here: the transmittance after 8 slots


def test_auto_backend_is_xla_without_a_gpu_and_a_bad_backend_is_named():
    assert not kernels.on_gpu()
    assert not RasterSettings().uses_pallas and RasterSettings(backend="pallas").uses_pallas
    assert RasterSettings(backend="pallas").for_forward_mode().backend == "xla"
    assert RasterSettings(backend="xla").for_forward_mode() == RasterSettings(backend="xla")
    with pytest.raises(ValueError, match="RasterSettings.backend must be one of auto, xla, pallas, got 'cuda'"):
        RasterSettings(backend="cuda")
    with pytest.raises(ValueError, match="slots_per_batch"):
        RasterSettings(slots_per_batch=0)


# ----------------------------------------------------------------------------------------------- gradients


def _loss(primals, active, w2c0, intr, weights, render_settings, cbknn):
    *fields, delta = primals
    out = render(Gaussians(*fields, active), se3_exp(delta) @ w2c0, intr, render_settings, cbknn=cbknn,
                          motion=MOTION)
    return sum(jnp.sum(getattr(out, k) * w) for k, w in weights.items())


_grad = jax.jit(jax.grad(_loss), static_argnames=("render_settings",))


def gradients(name: str, render_settings, cbknn):
    gaussians, w2c, intr = scenes.SCENES[name](0)
    rng = np.random.default_rng(5)
    weights = {k: jnp.asarray(rng.normal(size=shape), jnp.float32)
               for k, shape in (("color", (intr.height, intr.width, 3)), ("depth", (intr.height, intr.width)),
                            ("silhouette", (intr.height, intr.width)), ("depth_sq", (intr.height, intr.width)))}
    primals = tuple(getattr(gaussians, f) for f in FIELDS) + (jnp.zeros(6, jnp.float32),)
    return _grad(primals, gaussians.active, w2c, intr, weights, render_settings, cbknn)


def assert_same_gradients(a, b, label):
    for field, x, y in zip(FIELDS + ("pose",), a, b):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        scale = np.abs(x).max()
        assert scale > 0, f"{label}: {field} has no gradient"
        assert np.abs(x - y).max() <= GRAD_TOL * scale, f"{label}: {field} rel {np.abs(x - y).max() / scale:.2e}"


# 9-11 s each: the canonical render's backward pass in the default suite, the others in the slow one.
@pytest.mark.parametrize("name, case", [("dense_surface", None), pytest.param("dense_surface", "adaptive", marks=SLOW),
                                        pytest.param("dense_surface", "truncate_fraction", marks=SLOW),
                                        pytest.param("sparse_random", None, marks=SLOW)])
def test_gradients_are_the_same_on_both_backends(name, case):
    cb = None if case is None else CBKNN(**CBKNN_CASES[case])
    xla = gradients(name, RasterSettings(backend="xla"), cb)
    pallas = gradients(name, RasterSettings(backend="pallas"), cb)
    assert_same_gradients(xla, pallas, f"{name} {case}")


# ----------------------------------------------------------------------------------------------- bounded memory


@pytest.mark.parametrize("backend, case", [("xla", "adaptive"), pytest.param("pallas", None, marks=SLOW),
                                           pytest.param("pallas", "adaptive", marks=SLOW)])
def test_compositing_in_batches_of_tiles_gives_the_same_render_and_gradients(backend, case):
    # dense_surface: 20 tiles of 64 px, K = 64; 20000 slots per batch -> 5 batches of 4 tiles.
    name, small = "dense_surface", 20000
    cb = None if case is None else CBKNN(**CBKNN_CASES[case])
    gaussians, w2c, intr = scenes.SCENES[name](0)
    whole = render(gaussians, w2c, intr, RasterSettings(backend=backend), cbknn=cb, motion=MOTION)
    batched = render(gaussians, w2c, intr, RasterSettings(backend=backend, slots_per_batch=small), cbknn=cb,
                              motion=MOTION)
    assert_same_render(whole, batched, f"{backend} {case} batched")
    assert_same_gradients(
        gradients(name, RasterSettings(backend=backend), cb),
        gradients(name, RasterSettings(backend=backend, slots_per_batch=small), cb),
        f"{backend} {case} batched",
    )


# ----------------------------------------------------------------------------------------------- transformations


@SLOW
def test_vmap_over_cbknn_parameters_on_the_pallas_path_equals_each_render():
    gaussians, w2c, intr = scenes.SCENES["dense_surface"](0)
    s = RasterSettings(backend="pallas")
    alphas = jnp.asarray([0.05, 0.3], jnp.float32)
    batched = jax.jit(jax.vmap(lambda a: render(gaussians, w2c, intr, s, cbknn=CBKNN(alpha=a), motion=MOTION)))
    out = batched(alphas)
    for i, a in enumerate((0.05, 0.3)):
        single = render(gaussians, w2c, intr, RasterSettings(backend="xla"), cbknn=CBKNN(alpha=a), motion=MOTION)
        assert_same_render(single, jax.tree_util.tree_map(lambda x: x[i], out), f"alpha {a}")
    assert np.abs(np.asarray(out.color[0]) - np.asarray(out.color[1])).max() > 1e-3


@SLOW
def test_vmap_of_the_pose_gradient_over_cbknn_parameters_on_the_pallas_path():
    # What a sweep's tracking does: jax.grad w.r.t. the pose inside jax.vmap over CB-KNN parameters.
    gaussians, w2c, intr = scenes.SCENES["dense_surface"](0)

    def pose_grad(alpha, render_settings):
        def loss(delta):
            out = render(gaussians, se3_exp(delta) @ w2c, intr, render_settings, cbknn=CBKNN(alpha=alpha),
                                  motion=MOTION)
            return jnp.sum(out.color) + jnp.sum(out.depth)

        return jax.grad(loss)(jnp.zeros(6, jnp.float32))

    alphas = jnp.asarray([0.05, 0.3], jnp.float32)
    batched = jax.jit(jax.vmap(lambda a: pose_grad(a, RasterSettings(backend="pallas"))))(alphas)
    for i in range(2):
        single = pose_grad(alphas[i], RasterSettings(backend="xla"))
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(single), rtol=GRAD_TOL,
                                   atol=GRAD_TOL * float(jnp.abs(single).max()))
    assert np.abs(np.asarray(batched[0] - batched[1])).max() > 1e-3


@SLOW  # the default suite checks that for_forward_mode() gives the XLA path (test_auto_backend_is_xla_...)
def test_forward_mode_needs_the_xla_path_and_for_forward_mode_gives_it():
    gaussians, w2c, intr = scenes.SCENES["sparse_random"](0)

    def depth_sum(delta, render_settings):
        return jnp.sum(render(gaussians, se3_exp(delta) @ w2c, intr, render_settings).depth)

    delta, tangent = jnp.zeros(6, jnp.float32), jnp.asarray([0.01, -0.02, 0.03, 0.1, 0.0, -0.1], jnp.float32)
    pallas = RasterSettings(backend="pallas")
    with pytest.raises(TypeError, match="custom_vjp"):
        jax.jvp(lambda d: depth_sum(d, pallas), (delta,), (tangent,))
    _, by_jvp = jax.jvp(lambda d: depth_sum(d, pallas.for_forward_mode()), (delta,), (tangent,))
    by_grad = jnp.dot(jax.grad(depth_sum)(delta, pallas), tangent)
    assert abs(float(by_jvp)) > 1e-3
    np.testing.assert_allclose(float(by_jvp), float(by_grad), rtol=GRAD_TOL)


@SLOW
def test_the_lm_tracker_runs_with_pallas_settings_and_tracks_as_with_xla():
    from gsjax.camera import camera_center
    from gsjax.slam.config import SlamConfig, TrackingConfig
    from gsjax.slam.tracking import TrackingProblem, track

    gaussians, w2c, intr = scenes.SCENES["dense_surface"](0)
    target = render(gaussians, w2c, intr, RasterSettings())
    start = se3_exp(jnp.asarray([0.01, -0.005, 0.0, 0.0, 0.01, 0.0], jnp.float32)) @ w2c
    results, problem = {}, TrackingProblem(gaussians, target.color, target.depth, start, intr, False, 0.0)
    for backend in ("xla", "pallas"):
        config = SlamConfig(tracking=TrackingConfig(optimizer="lm", iters=4))
        config = dataclasses.replace(config, raster=dataclasses.replace(config.raster, backend=backend))
        results[backend] = track(problem, config)
    np.testing.assert_allclose(np.asarray(results["pallas"].w2c), np.asarray(results["xla"].w2c), atol=1e-6)
    error = lambda pose: float(jnp.linalg.norm(camera_center(pose) - camera_center(w2c)))  # noqa: E731
    assert error(results["pallas"].w2c) < 0.5 * error(start)  # it did track
