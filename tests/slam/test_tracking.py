"""Camera tracking: recovery of a known SE(3) perturbation (Adam and LM), non-finite iterations, and CB-KNN's
keyframe tracking (smoothed render, lambda_c = 0.6) in ``paper`` mode."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import se3_exp, se3_log
from gsjax.raster import render
from gsjax.raster.render import empty_selection
from gsjax.slam.config import EarlyStop
from gsjax.slam.losses import TrackingTerms, exposure_gain, rendered_depth, tracking_loss, tracking_mask
from gsjax.slam.presets import with_cbknn_mode
from gsjax.slam.tracking import Stage, TrackingProblem, _track_adam, track
from gsjax.slam.views import render_view
from tests.support.tiny_slam import first_frame_map, map_config, relative_gt_w2c, replaced, tiny_sequence

track_jit = jax.jit(track)
TRUE_FRAME = 2  # the true pose: frame 2's GT pose relative to frame 0 (not the identity)
PERTURBATIONS = {
    # (rho m, phi rad): 3-4 cm and about 1.5 degrees, i.e. about a pixel at 40x30.
    "a": (0.03, -0.02, 0.02, 0.02, -0.015, 0.01),
    "b": (-0.02, 0.03, -0.03, -0.01, 0.02, 0.015),
}


def tracking_config(optimizer: str, iters: int, mode: str = "off", **overrides: object):
    """``map_config()`` tracking with ``optimizer`` for ``iters`` iterations (and ``overrides``, dotted names with
    dots as double underscores): the caps of ``map_config()``, so one program per optimizer serves every count."""
    return replaced(with_cbknn_mode(map_config(), mode), {
        "tracking.optimizer": optimizer, "tracking.iters": iters,
        **{name.replace("__", "."): value for name, value in overrides.items()}})


@pytest.fixture(scope="module")
def rendered_scene():
    """(map from frame 0, observed colour, observed depth, true w2c): the observation is the map's own render at
    the true pose (depth D / S where S > 0.5, else invalid), so the tracking loss is zero exactly there."""
    gaussians = first_frame_map()
    w2c_true = jnp.asarray(relative_gt_w2c()[TRUE_FRAME], jnp.float32)
    config = map_config()
    view = render_view(gaussians, w2c_true, tiny_sequence().intrinsics, config.raster, config.cbknn, False, 0.0)
    depth = jnp.where(view.silhouette > 0.5, rendered_depth(view, config.tracking.normalized_depth), 0.0)
    return gaussians, view.color, depth, w2c_true


def pose_error(w2c, w2c_true):
    """(translation norm m, rotation norm rad) of the left error exp(e) = w2c w2c_true^-1."""
    e = np.asarray(se3_log(w2c @ jnp.linalg.inv(w2c_true)))
    return np.linalg.norm(e[:3]), np.linalg.norm(e[3:])


# The second perturbation and the strided Adam without reselection (the cpu preset's variant keeps reselection) are in
# the slow suite: the default one keeps SplaTAM's Adam, the cpu preset's, LM, and LM after strided steps.
@pytest.mark.parametrize("perturbation", ["a", pytest.param("b", marks=pytest.mark.slow)])
@pytest.mark.parametrize("optimizer, iters, strided, reselect", [("adam", 60, 0, 1), ("lm", 10, 0, 1),
                                                                 pytest.param("adam", 20, 40, 1,
                                                                              marks=pytest.mark.slow),
                                                                 ("lm", 5, 5, 1), ("adam", 20, 40, 10)])
def test_tracking_recovers_a_known_perturbation_of_a_rendered_map(rendered_scene, optimizer, iters, strided,
                                                                  reselect, perturbation):
    """On every pixel, and after ``strided`` iterations on a quarter of the pixels; with ``reselect`` 10 each
    pixel's contributors are chosen every 10th iteration (the strided grids take the full image's)."""
    gaussians, color, depth, w2c_true = rendered_scene
    delta = jnp.asarray(PERTURBATIONS[perturbation], jnp.float32)
    w2c_init = se3_exp(delta) @ w2c_true
    config = tracking_config(optimizer, iters, tracking__strided_iters=strided,
                             tracking__reselect_every=reselect)
    problem = TrackingProblem(gaussians, color, depth, w2c_init, tiny_sequence().intrinsics, False, 0.0)
    result = track_jit(problem, config)
    trans, rot = pose_error(result.w2c, w2c_true)
    # Measured: at most 5.3% (Adam, 60 iterations), 5.1% (Adam, 40 strided + 20) and 4e-6 (LM, 10 iterations) of
    # the perturbation.
    assert trans < 0.1 * np.linalg.norm(delta[:3])
    assert rot < 0.1 * np.linalg.norm(delta[3:])
    assert int(result.nonfinite) == 0
    if optimizer == "adam":
        assert int(result.iterations) == strided + iters
    start = pose_error(w2c_init, w2c_true)
    assert np.allclose(start, (np.linalg.norm(delta[:3]), np.linalg.norm(delta[3:])), rtol=1e-3)


@pytest.mark.parametrize("row, col", [(0, 0), (0, 1), (1, 0), (1, 1)])
def test_a_strided_render_is_the_full_render_at_every_other_pixel(rendered_scene, row, col):
    """What the strided tracking iterations see: the render at ``Intrinsics.strided`` with a quarter of the
    dilation equals the full render's pixels (2 i + row, 2 j + col), and so does the observation."""
    from gsjax.slam.views import strided_observation, strided_setup

    gaussians, color, depth, w2c_true = rendered_scene
    intrinsics = tiny_sequence().intrinsics
    full = render(gaussians, w2c_true, intrinsics, map_config().raster)
    strided = render(gaussians, w2c_true, intrinsics.strided(row, col), strided_setup(map_config(), intrinsics).raster)
    for name in ("color", "depth", "silhouette"):
        np.testing.assert_allclose(np.asarray(getattr(strided, name)),
                                   np.asarray(getattr(full, name))[row::2, col::2], atol=2e-6)
    np.testing.assert_array_equal(np.asarray(strided_observation(color, row, col)), np.asarray(color)[row::2, col::2])
    assert int(strided.stats.tiles_overflowed) == 0


def test_strided_iterations_descend_the_full_loss_and_only_full_ones_pick_the_pose(rendered_scene):
    """The strided loss is 4x the tracking loss on the strided grid; 40 strided iterations and one full one bring
    the full loss far below the start's, and the result is the pose of that one full iteration (pre_step), its
    loss the full loss."""
    from gsjax.slam.tracking import strided_problem, tracking_objective

    gaussians, color, depth, w2c_true = rendered_scene
    w2c_init = se3_exp(jnp.asarray(PERTURBATIONS["a"], jnp.float32)) @ w2c_true
    intrinsics = tiny_sequence().intrinsics
    config = tracking_config("adam", 1, tracking__strided_iters=40)
    problem = TrackingProblem(gaussians, color, depth, w2c_init, intrinsics, False, 0.0)
    objective, color_s, depth_s = strided_problem(problem, config)(3)
    full = tracking_objective(problem, config)
    zero = jnp.zeros(6, jnp.float32)
    view = full.view_at(zero)
    on_grid = view._replace(color=view.color[1::2, 1::2], depth=view.depth[1::2, 1::2],
                            silhouette=view.silhouette[1::2, 1::2], depth_sq=view.depth_sq[1::2, 1::2])
    terms = TrackingTerms(full.lambda_color, config.tracking.lambda_depth, config.tracking.sil_threshold,
                          config.tracking.normalized_depth)
    expected = 4.0 * tracking_loss(on_grid, color_s, depth_s, terms)
    np.testing.assert_allclose(float(objective.loss(zero)), float(expected), rtol=1e-5)
    result = track_jit(TrackingProblem(gaussians, color, depth, w2c_init, intrinsics, False, 0.0), config)
    assert int(result.iterations) == 41
    delta = se3_log(result.w2c @ jnp.linalg.inv(w2c_init))
    assert float(full.loss(delta)) < 0.2 * float(full.loss(zero))
    np.testing.assert_allclose(float(result.loss), float(full.loss(delta)), rtol=1e-4)


# ------------------------------------------------------------------------------------------ non-finite handling


def nan_pixel(color):
    return color.at[12, 20, 1].set(jnp.nan)


@pytest.mark.parametrize("optimizer, iters, counted", [("adam", 60, 60), ("lm", 10, 1)])
def test_a_frame_with_a_nan_pixel_keeps_the_initial_pose_and_counts_nonfinite(rendered_scene, optimizer, iters,
                                                                              counted):
    """A NaN colour makes every loss (Adam) or the solve (LM) non-finite: no step is taken, the pose handed in is
    returned unchanged, and the skipped iterations (Adam) or the unusable solve (LM) are counted."""
    gaussians, color, depth, w2c_true = rendered_scene
    w2c_init = se3_exp(jnp.asarray(PERTURBATIONS["a"], jnp.float32)) @ w2c_true
    config = tracking_config(optimizer, iters)
    problem = TrackingProblem(gaussians, nan_pixel(color), depth, w2c_init, tiny_sequence().intrinsics, False, 0.0)
    result = track_jit(problem, config)
    np.testing.assert_array_equal(np.asarray(result.w2c), np.asarray(w2c_init))
    assert int(result.nonfinite) == counted


def test_reselect_every_chooses_contributors_at_every_rth_iteration_across_stages():
    """With ``reselect_every`` 5, 3 strided + 9 full iterations choose the contributors at iterations 0, 5 and 10
    (counted over both stages, at the pose of that iteration) and hand each iteration the latest choice; with 1
    every iteration chooses its own, at its pose. The count is traced: both run one program."""
    config = map_config()
    intrinsics = tiny_sequence().intrinsics
    chosen, handed = [], []

    def select(delta):
        jax.debug.callback(lambda d: chosen.append(np.asarray(d).copy()), delta)
        return empty_selection(intrinsics, config.raster)._replace(tiles_overflowed=jnp.int32(marker(delta)))

    def marker(delta):  # which selection: the first pose component in tenths of a millimetre
        return jnp.round(delta[0] * 1e4).astype(jnp.int32)

    def loss(delta, selection=None):
        if selection is not None:
            jax.debug.callback(lambda m: handed.append(int(m)), selection.tiles_overflowed)
        return jnp.sum((delta - jnp.asarray([0.01, 0, 0, 0, 0, 0])) ** 2)

    @jax.jit
    def run(w2c, tracking):
        stages = [Stage(lambda d, it, sel: loss(d, sel), None, tracking.strided_iters, caps.tracking_strided, False),
                  Stage(lambda d, it, sel: loss(d, sel), None, tracking.iters, caps.tracking, True)]
        return _track_adam(stages, w2c, tracking, select=select)

    base = dataclasses.replace(config.tracking, iters=9, strided_iters=3)
    caps = dataclasses.replace(config, tracking=base).caps
    for every, expected_selects in ((5, 3), (1, 12)):
        chosen.clear(), handed.clear()
        jax.block_until_ready(run(jnp.eye(4), dataclasses.replace(base, reselect_every=every)))
        assert len(chosen) == expected_selects
        markers = [int(np.round(d[0] * 1e4)) for d in chosen]
        assert markers[0] == 0 and len(set(markers)) > 1  # at the start pose, then at later poses
        assert handed == [markers[i // every] for i in range(12)]
    assert run._cache_size() == 1


def test_adam_skips_non_finite_iterations_and_keeps_the_best_finite_pose():
    """Loss |delta - target|^2 that turns NaN once rho_x exceeds 0.011: Adam walks towards the target (about
    lr_trans per step) until a step lands past 0.011; from there no step is taken (the pose stays put) and every
    later iteration is non-finite. The result is the lowest-loss finite pose (pre_step: the pose whose loss was
    measured), and the count is exact."""
    config = map_config()
    config = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, iters=20, lr_trans=2e-3))
    target = jnp.asarray([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])

    def loss_fn(delta):
        return jnp.where(delta[0] > 0.011, jnp.nan, jnp.sum((delta - target) ** 2))

    w2c_init = jnp.asarray(relative_gt_w2c()[TRUE_FRAME], jnp.float32)
    stages = [Stage(lambda d, it, sel: loss_fn(d), None, config.tracking.iters, config.caps.tracking, True)]
    result = jax.jit(lambda w: _track_adam(stages, w, config.tracking))(w2c_init)
    best = np.asarray(se3_log(result.w2c @ jnp.linalg.inv(w2c_init)))
    # Adam's first steps have size lr: rho_x = 0.002 k after k steps, so the losses at k = 0..5 are finite and the
    # loss after the 6th step (rho_x = 0.012) is not: 6 finite iterations, 14 skipped, best at k = 5.
    np.testing.assert_allclose(best, [0.01, 0, 0, 0, 0, 0], atol=2e-5)
    assert int(result.nonfinite) == 20 - 6
    np.testing.assert_allclose(float(result.loss), float(loss_fn(jnp.asarray(best, jnp.float32))), rtol=1e-4)


def test_early_stop_window_stops_once_the_loss_stops_falling_and_zero_runs_every_iteration():
    """Loss |delta - target|^2 with the target 1 cm away: Adam (lr 2 mm) reaches it within ~6 steps, then jitters
    around it. With stop.window 3 the loop stops 3 iterations after the last drop of 1e-3 (relative), well
    before the cap, at the same best pose; with 0 (SplaTAM) all iterations run."""
    config = map_config()
    target = jnp.asarray([0.01, 0.0, 0.0, 0.0, 0.0, 0.0])

    def loss_fn(delta):
        return jnp.sum((delta - target) ** 2) + 1e-6

    base = dataclasses.replace(config.tracking, iters=60, lr_trans=2e-3)
    caps = dataclasses.replace(config, tracking=base).caps
    run = jax.jit(lambda w, tracking: _track_adam(
        [Stage(lambda d, it, sel: loss_fn(d), None, tracking.iters, caps.tracking, True)], w, tracking))

    def tracked(window):
        return run(jnp.eye(4, dtype=jnp.float32), dataclasses.replace(base, stop=EarlyStop(window=window, rtol=1e-3)))

    full, stopped = tracked(0), tracked(3)
    assert run._cache_size() == 1  # the window is traced
    assert int(full.iterations) == 60
    assert 6 <= int(stopped.iterations) < 30
    losses = [float(r.loss) for r in (full, stopped)]
    assert losses[1] <= 2 * losses[0] + 1e-6, losses  # both at the target within Adam's jitter
    # The stopped run ends at the target too (within Adam's step of 2 mm).
    assert np.linalg.norm(np.asarray(se3_log(stopped.w2c))[:3] - np.asarray(target[:3])) < 2e-3


# ------------------------------------------------------------------------ CB-KNN keyframe tracking (paper mode)


def test_paper_mode_renders_keyframes_smoothed_and_everything_else_canonically(rendered_scene):
    gaussians, _, _, w2c_true = rendered_scene
    intrinsics = tiny_sequence().intrinsics
    paper, off = with_cbknn_mode(map_config(), "paper"), map_config()
    canonical = render(gaussians, w2c_true, intrinsics, off.raster)
    smoothed = render_view(gaussians, w2c_true, intrinsics, paper.raster, paper.cbknn, True, 0.3)
    unsmoothed = render_view(gaussians, w2c_true, intrinsics, paper.raster, paper.cbknn, False, 0.3)
    ignored = render_view(gaussians, w2c_true, intrinsics, off.raster, off.cbknn, True, 0.3)  # off mode never smooths
    for view in (unsmoothed, ignored):
        np.testing.assert_array_equal(np.asarray(view.color), np.asarray(canonical.color))
        np.testing.assert_array_equal(np.asarray(view.depth), np.asarray(canonical.depth))
    assert float(jnp.max(jnp.abs(smoothed.color - canonical.color))) > 1e-3
    assert float(jnp.max(jnp.abs(smoothed.depth - canonical.depth))) > 1e-4


@pytest.fixture(scope="module")
def one_iteration_tracking(rendered_scene):
    """Tracking with a single Adam iteration and SplaTAM's ``post_step`` candidate: the returned loss is the loss
    at the initial pose, the returned pose is one gradient step from it."""
    gaussians, color, depth, w2c_true = rendered_scene
    w2c_init = se3_exp(jnp.asarray(PERTURBATIONS["a"], jnp.float32)) @ w2c_true

    def run(mode, smooth, **cbknn):
        config = replaced(tracking_config("adam", 1, mode), {"tracking.best_pose": "post_step"})
        config = dataclasses.replace(config, cbknn=dataclasses.replace(config.cbknn, **cbknn))
        problem = TrackingProblem(gaussians, color, depth, w2c_init, tiny_sequence().intrinsics, smooth, 0.3)
        return track_jit(problem, config)

    return run, w2c_init


def test_paper_mode_tracks_non_keyframes_exactly_as_off_mode(one_iteration_tracking):
    run, w2c_init = one_iteration_tracking
    off, paper = run("off", False), run("paper", False)
    assert not np.array_equal(np.asarray(off.w2c), np.asarray(w2c_init))  # a step was taken
    np.testing.assert_array_equal(np.asarray(paper.w2c), np.asarray(off.w2c))
    assert float(paper.loss) == float(off.loss)
    keyframe = run("paper", True)
    assert not np.array_equal(np.asarray(keyframe.w2c), np.asarray(off.w2c))
    assert float(keyframe.loss) != float(off.loss)


def test_paper_mode_keyframe_tracking_uses_the_smoothed_render_and_the_keyframe_colour_weight(
    rendered_scene, one_iteration_tracking
):
    gaussians, color, depth, _ = rendered_scene
    run, w2c_init = one_iteration_tracking
    config = with_cbknn_mode(map_config(), "paper")
    tc = config.tracking
    smoothed = render_view(gaussians, w2c_init, tiny_sequence().intrinsics, config.raster, config.cbknn, True, 0.3)

    def expected(lambda_color):
        return float(tracking_loss(smoothed, color, depth, TrackingTerms(lambda_color, tc.lambda_depth,
                                                                         tc.sil_threshold, tc.normalized_depth)))

    assert config.cbknn.lambda_color_keyframe == 0.6 and tc.lambda_color == 0.5
    np.testing.assert_allclose(float(run("paper", True).loss), expected(0.6), rtol=1e-5)
    np.testing.assert_allclose(float(run("paper", True, lambda_color_keyframe=0.2).loss), expected(0.2), rtol=1e-5)
    assert abs(expected(0.6) - expected(0.5)) > 1e-3 * expected(0.5)  # the weight is visible in the loss


def test_exposure_match_takes_a_change_of_brightness_for_what_it_is(rendered_scene):
    """The observation 1.3x brighter in red, 1.2x in green and blue (auto exposure after the map was made): with
    ``exposure.match`` the colour term at the true pose is the unchanged observation's (zero), and tracking from a
    perturbation recovers the pose as it does without the change; without it the colour term is not zero."""
    gaussians, color, depth, w2c_true = rendered_scene
    gain = jnp.asarray([1.3, 1.2, 1.2], jnp.float32)
    brighter = color * gain
    config = map_config()
    view = render_view(gaussians, w2c_true, tiny_sequence().intrinsics, config.raster, config.cbknn, False, 0.0)
    mask = tracking_mask(view, depth, 0.99)
    np.testing.assert_allclose(np.asarray(exposure_gain(view.color, brighter, mask)), np.asarray(gain), rtol=1e-5)
    assert float(exposure_gain(view.color, 9 * color, mask)[0]) == 2.0  # bounded: never a free brightness
    loss = lambda gt, match: float(tracking_loss(view, gt, depth, TrackingTerms(0.5, 1.0, 0.99, False, match)))  # noqa: E731
    assert loss(brighter, True) == pytest.approx(loss(color, False), rel=1e-4)  # the depth term only
    assert loss(brighter, False) > loss(color, False) + 100
    config = replaced(tracking_config("lm", 10), {"tracking.exposure.match": True})
    delta = jnp.asarray(PERTURBATIONS["a"], jnp.float32)
    problem = TrackingProblem(gaussians, brighter, depth, se3_exp(delta) @ w2c_true, tiny_sequence().intrinsics,
                              False, 0.0)
    trans, rot = pose_error(track_jit(problem, config).w2c, w2c_true)
    assert trans < 0.1 * np.linalg.norm(delta[:3]) and rot < 0.1 * np.linalg.norm(delta[3:])


# ------------------------------------------------------------------------------- image-space smoothing, coarse-to-fine


def _dense_blur_reference(image, sigma, radius):
    """float64: the same truncated, tap-normalised separable Gaussian as a dense [H*W, H*W] matrix product."""
    h, w = image.shape[:2]
    taps = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 * (taps / sigma) ** 2)
    weights /= weights.sum()

    def matrix(n):
        m = np.zeros((n, n))
        for i in range(n):
            for t, wt in zip(taps, weights):
                if 0 <= i + t < n:
                    m[i, i + t] = wt
        return m

    flat = np.kron(matrix(h), matrix(w))
    return (flat @ np.asarray(image, np.float64).reshape(h * w, -1)).reshape(image.shape)


def test_gaussian_blur_is_the_dense_filter_and_zero_sigma_is_the_image():
    from gsjax.slam.losses import gaussian_blur

    image = np.random.default_rng(0).normal(size=(9, 13, 3)).astype(np.float32)
    for sigma in (0.7, 1.5, 3.0):
        found = jax.jit(gaussian_blur, static_argnums=2)(jnp.asarray(image), jnp.float32(sigma), 4)
        np.testing.assert_allclose(np.asarray(found), _dense_blur_reference(image, sigma, 4), atol=2e-6)
    np.testing.assert_array_equal(np.asarray(gaussian_blur(jnp.asarray(image), 0.0, 4)), image)


def test_gaussian_blur_gradient_matches_finite_differences():
    from gsjax.slam.losses import gaussian_blur

    image = jnp.asarray(np.random.default_rng(1).normal(size=(6, 7, 2)), jnp.float32)
    probe = jnp.asarray(np.random.default_rng(2).normal(size=(6, 7, 2)), jnp.float32)
    f = lambda sigma: jnp.sum(probe * gaussian_blur(image, sigma, 3))  # noqa: E731
    h = 1e-2
    numeric = (f(1.2 + h) - f(1.2 - h)) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(f)(jnp.float32(1.2))), float(numeric), rtol=2e-2, atol=1e-4)
    g = jax.grad(lambda x: jnp.sum(probe * gaussian_blur(x, 1.2, 3)))(image)  # the filter is its own adjoint here
    np.testing.assert_allclose(np.asarray(g), _dense_blur_reference(np.asarray(probe), 1.2, 3), atol=2e-6)


def test_the_blurred_tracking_loss_is_the_l1_of_the_blurred_masked_residuals(rendered_scene):
    gaussians, color, depth, w2c_true = rendered_scene
    config = map_config()
    cfg = config.tracking
    w2c = se3_exp(jnp.asarray(PERTURBATIONS["a"], jnp.float32)) @ w2c_true
    view = render_view(gaussians, w2c, tiny_sequence().intrinsics, config.raster, config.cbknn, False, 0.0)
    args = (0.5, 1.0, cfg.sil_threshold, cfg.normalized_depth)
    plain = float(tracking_loss(view, color, depth, TrackingTerms(*args)))
    np.testing.assert_allclose(float(tracking_loss(view, color, depth, TrackingTerms(*args, False, 0.0, 4))), plain,
                               rtol=1e-6)
    mask = np.asarray(tracking_mask(view, depth, cfg.sil_threshold))
    depth_residual = np.where(mask, np.asarray(rendered_depth(view, cfg.normalized_depth)) - depth, 0)
    residual = np.concatenate([depth_residual[..., None],
                               np.where(mask[..., None], np.asarray(view.color) - np.asarray(color), 0)], axis=-1)
    smoothed = np.abs(_dense_blur_reference(residual, 1.5, 4))
    expected = smoothed[..., 0].sum() + 0.5 * smoothed[..., 1:].sum()
    blurred = float(tracking_loss(view, color, depth, TrackingTerms(*args, False, 1.5, 4)))
    np.testing.assert_allclose(blurred, expected, rtol=1e-5)
    assert blurred < plain  # opposite residuals cancel once blurred


def test_coarse_to_fine_runs_its_levels_first_at_halving_blur_and_keeps_a_full_iteration_s_pose(rendered_scene):
    from gsjax.slam.tracking import coarse_loss, tracking_objective

    gaussians, color, depth, w2c_true = rendered_scene
    w2c_init = se3_exp(jnp.asarray(PERTURBATIONS["b"], jnp.float32)) @ w2c_true
    intrinsics = tiny_sequence().intrinsics
    config = replaced(tracking_config("adam", 20), {  # each iteration chooses its contributors: exact losses
        "tracking.blur.radius_px": 4, "tracking.coarse.iters": 31, "tracking.coarse.levels": 3,
        "tracking.coarse.sigma_px": 0.5, "tracking.reselect_every": 1})
    problem = TrackingProblem(gaussians, color, depth, w2c_init, intrinsics, False, 0.0)
    coarse = coarse_loss(problem, config)
    zero = jnp.zeros(6, jnp.float32)
    view = tracking_objective(problem, config).view_at(zero)
    cfg = config.tracking
    # 31 iterations over 3 levels: 11 (the remainder to the first), 10, 10
    for its, sigma in (((0, 10), 2.0), ((11, 20), 1.0), ((21, 30), 0.5)):
        terms = TrackingTerms(cfg.lambda_color, cfg.lambda_depth, cfg.sil_threshold, cfg.normalized_depth, False,
                              sigma, 4)
        expected = tracking_loss(view, color, depth, terms)
        for it in its:
            np.testing.assert_allclose(float(coarse(zero, jnp.int32(it))), float(expected), rtol=1e-6)
    result = track_jit(problem, config)
    assert int(result.iterations) == 31 + 20
    trans, rot = pose_error(result.w2c, w2c_true)
    assert trans < 0.1 * np.linalg.norm(PERTURBATIONS["b"][:3]) and rot < 0.1 * np.linalg.norm(PERTURBATIONS["b"][3:])
    full = tracking_objective(problem, config)  # blur.sigma_px 0: the reported loss is the unblurred one
    np.testing.assert_allclose(float(result.loss), float(full.loss(se3_log(result.w2c @ jnp.linalg.inv(w2c_init)))),
                               rtol=1e-4)


def test_smoothing_settings_are_checked_and_scale_with_the_pixel():
    from gsjax.slam.config import CoarseToFine, ImageBlur, TrackingConfig
    from gsjax.slam.presets import at_width

    with pytest.raises(ValueError, match="blur.radius_px"):
        TrackingConfig(coarse=CoarseToFine(iters=10))
    with pytest.raises(ValueError, match="adam only"):
        TrackingConfig(coarse=CoarseToFine(iters=10), blur=ImageBlur(radius_px=4), optimizer="lm")
    with pytest.raises(ValueError, match="tracking.blur.sigma_px"):
        ImageBlur(sigma_px=-1.0)
    config = replaced(map_config(), {"tracking.blur.sigma_px": 2.0, "tracking.coarse.sigma_px": 1.0,
                                     "tracking.blur.radius_px": 6})
    half = at_width(config, 40, 80).tracking
    assert (float(half.blur.sigma_px), float(half.coarse.sigma_px), half.blur.radius_px) == (1.0, 0.5, 6)
