"""Hypergradients (gsjax.slam.hypergrad) against central finite differences of whole SLAM runs, on the tiny room.

A SLAM run is a function of its config with jumps (densification, the best pose among the iterations, the loss's
pixel mask): its finite differences agree with a derivative only where the run responds smoothly. That is the regime
of a tracker that has not converged (the learning rates at a tenth of the preset's, 10 iterations): there the
differences of whole runs taken with 5 % and 20 % steps agree with each other, and the tests compare there. At a
converged tracker the differences of whole runs change sign between step sizes (docs/guide/hypergradients.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.config.paths import differentiable_entry, differentiable_fields, replace_path, replace_paths
from gsjax.slam import hypergrad as hg
from tests.support import tiny_slam as ts

FRAMES = 4
# Under-converged tracking (a tenth of the cpu preset's 2e-3 at this width, 10 iterations): whole runs respond
# smoothly to the fields, so finite differences of runs are a derivative to compare with.
SMOOTH = {"tracking.iters": 10, "tracking.lr_trans": 2e-4, "tracking.lr_rot": 2e-4}
FIELDS = ("tracking.lr_trans", "tracking.lr_rot", "tracking.lambda_color", "tracking.lambda_depth",
          "cbknn.lambda_color_keyframe")


@pytest.fixture(scope="module")
def setup():
    sequence = ts.tiny_sequence(ts.FRAMES)
    frames = [sequence.read_host(i) for i in range(FRAMES)]
    config = ts.replaced(ts.tiny_config("paper"), SMOOTH)
    window = hg.record(frames, config, sequence.intrinsics)
    return frames, config, sequence.intrinsics, window


_differences: dict[str, dict[str, float]] = {}


def _run_differences(frames, config, intrinsics, objective):
    """:func:`_differences_of` at 5 % steps, once per objective for the tiny room."""
    if objective not in _differences:
        _differences[objective] = _differences_of(frames, config, intrinsics, objective)
    return _differences[objective]


def _differences_of(frames, config, intrinsics, objective, step=0.05, fields=FIELDS):
    """{field: v * (J(v + h) - J(v - h)) / (2 h)} over whole runs, h = step * v (relative sensitivities)."""
    out = {}
    for name in fields:
        value = float(differentiable_entry(config, name).value)
        ends = [hg.objective_value(hg.record(frames, replace_path(config, name, value * (1 + s * step)), intrinsics),
                                   config, intrinsics, objective) for s in (1, -1)]
        out[name] = (ends[0] - ends[1]) / (2 * step)
    return out


def _relative(result: hg.Hypergradient, config, fields=FIELDS) -> dict[str, float]:
    return {name: float(differentiable_entry(config, name).value) * result.gradient[name] for name in fields}


# Text overrides of the cpu preset: LM with 20 steps on every pixel (poses are fixed points), and CB-KNN's case of a
# noisy map (1 cm of fresh map noise and 1 cm of depth noise).
LM = {"tracking.optimizer": "lm", "tracking.iters": "20", "tracking.strided_iters": "0", "tracking.reselect_every": "1"}
MAP_NOISE = {"noise.map_means_cm": "1.0", "noise.depth_cm": "1.0"}


def _noisy_room(frames: int, downscale: int, overrides: dict[str, str]):
    """(frames, intrinsics, config): the noisy synthetic room's first ``frames`` at 160x120 / ``downscale``, and the
    cpu preset at that width with CB-KNN ``paper`` and ``overrides``."""
    from gsjax.config.text import apply_overrides
    from gsjax.data import open_sequence
    from gsjax.slam.presets import preset, with_cbknn_mode

    sequence = open_sequence("synthetic", max_frames=frames, downscale=downscale, sensor_noise=True)
    config = apply_overrides(with_cbknn_mode(preset("cpu", sequence.intrinsics.width), "paper"), overrides)
    return [sequence.read_host(i) for i in range(len(sequence))], sequence.intrinsics, config


def test_the_unrolled_hypergradient_through_the_whole_window_has_the_sign_and_size_of_whole_runs(setup):
    frames, config, intrinsics, window = setup
    result = hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual", truncation="window")
    assert result.value == pytest.approx(hg.objective_value(window, config, intrinsics, "residual"), rel=1e-6)
    exact = _relative(result, config)
    runs = _run_differences(frames, config, intrinsics, "residual")
    for name in FIELDS:
        assert np.sign(exact[name]) == np.sign(runs[name]), (name, exact[name], runs[name])
    a, b = np.array([exact[n] for n in FIELDS]), np.array([runs[n] for n in FIELDS])
    assert np.corrcoef(a, b)[0, 1] > 0.9, (exact, runs)
    # The learning rates dominate here; each is within a factor 2 of its difference of runs.
    for name in FIELDS[:2]:
        assert 0.5 < exact[name] / runs[name] < 2.0, (name, exact[name], runs[name])


def test_the_frame_truncated_hypergradient_points_as_whole_runs_do_for_the_learning_rates(setup):
    frames, config, intrinsics, window = setup
    result = hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual")
    truncated = _relative(result, config)
    runs = _run_differences(frames, config, intrinsics, "residual")
    for name in FIELDS[:2]:  # each frame's own share: the same sign, a smaller size (the map's share is cut)
        assert np.sign(truncated[name]) == np.sign(runs[name]), (name, truncated[name], runs[name])
        assert abs(truncated[name]) < abs(runs[name])
    # Each frame's derivative is taken inside its own step (one frame's iterations held at a time): the same as one
    # reverse pass over the whole objective, written here independently.
    hyper = hg.hypergradient_config(config)
    values = {name: jnp.float32(differentiable_entry(config, name).value) for name in FIELDS}

    def whole(values):
        held = jax.lax.stop_gradient(window)
        replay = lambda _, x: (None, hg._replayed_frame(*x, replace_paths(hyper, values), intrinsics,  # noqa: E731
                                                        "unrolled"))
        _, (_, residual, tracked) = jax.lax.scan(replay, None, (held.states, held.frames, held.outputs))
        return jnp.sum(jnp.where(tracked, residual, 0.0)) / jnp.maximum(jnp.sum(tracked), 1)

    value, grads = jax.jit(jax.value_and_grad(whole))(values)
    assert result.value == pytest.approx(float(value), rel=1e-6)
    for name in FIELDS:
        assert result.gradient[name] == pytest.approx(float(grads[name]), rel=1e-4, abs=1e-9), name


def test_forward_mode_gives_the_derivative_reverse_mode_gives(setup):
    """A tangent per field pushed through the run's while loops against one backward pass through the checkpointed
    scans (measured on this room: relative differences below 1e-5, for ``window`` too)."""
    _, config, intrinsics, window = setup
    reverse = hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual", mode="reverse")
    forward = hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual", mode="forward")
    assert forward.value == pytest.approx(reverse.value, rel=1e-6)
    np.testing.assert_allclose(forward.w2c, reverse.w2c, atol=1e-6)
    # The function both differentiate, its value alone: the frames tracked again reproduce the recorded run.
    assert hg.replayed_objective(window, config, intrinsics) == pytest.approx(reverse.value, rel=1e-6)
    assert reverse.value == pytest.approx(hg.objective_value(window, config, intrinsics), rel=1e-4)
    for name in FIELDS:
        assert forward.gradient[name] == pytest.approx(reverse.gradient[name], rel=1e-4, abs=1e-10), name


@pytest.mark.slow
def test_the_window_hypergradient_of_ate_matches_whole_runs(setup):
    frames, config, intrinsics, window = setup
    exact = _relative(hg.hypergradient(window, config, intrinsics, FIELDS, objective="ate", truncation="window"),
                      config)
    runs = _run_differences(frames, config, intrinsics, "ate")
    for name in ("tracking.lr_trans", "tracking.lambda_color", "tracking.lambda_depth"):
        assert np.sign(exact[name]) == np.sign(runs[name]), (name, exact[name], runs[name])
        assert 0.5 < exact[name] / runs[name] < 2.0, (name, exact[name], runs[name])


def test_the_implicit_hypergradient_keeps_the_recorded_poses_and_gives_learning_rates_no_derivative(setup):
    _, config, intrinsics, window = setup
    result = hg.hypergradient(window, config, intrinsics, ("tracking.lr_trans", "tracking.lambda_depth",
                                                            "cbknn.params.alpha"), adjoint="implicit")
    np.testing.assert_array_equal(result.w2c, np.asarray(window.outputs.w2c))
    assert result.gradient["tracking.lr_trans"] == 0.0  # a step size does not move a fixed point
    assert result.gradient["tracking.lambda_depth"] != 0.0 and np.isfinite(result.gradient["cbknn.params.alpha"])


@pytest.mark.parametrize("truncation", ["frame", "window"])
def test_the_implicit_fixed_point_does_not_move_when_every_loss_weight_is_scaled_alike(setup, truncation):
    """Scaling the tracking loss scales its gradient and Hessian alike: its fixed point stays, so the weights'
    relative derivatives sum to 0. (The Newton step's end's derivative; -H^-1 dg alone moved it by a whole Newton
    step, as large as each weight's own on this room.) The window's mapping carries the map's share."""
    _, config, intrinsics, window = setup
    weights = FIELDS[2:]  # lambda_color, lambda_depth, lambda_color_keyframe: every weight of the tracking loss
    for objective in ("residual", "ate"):
        result = hg.hypergradient(window, config, intrinsics, (*weights, "cbknn.params.alpha"), objective=objective,
                                  adjoint="implicit", truncation=truncation)
        relative = np.array([float(differentiable_entry(config, n).value) * result.gradient[n] for n in weights])
        assert np.abs(relative).max() > 0
        assert abs(relative.sum()) < 1e-3 * np.abs(relative).max(), (objective, relative)


def test_a_field_without_a_derivative_or_a_bad_choice_is_refused_by_name(setup):
    _, config, intrinsics, window = setup
    for name, words in (("tracking.iters", "integer"), ("tracking.optimizer", "static"), ("nope.x", "unknown"),
                        ("tracking.exposure.match", "switch")):
        with pytest.raises(ValueError, match=words):
            hg.hypergradient(window, config, intrinsics, (name,))
    with pytest.raises(ValueError, match="truncation"):
        hg.hypergradient(window, config, intrinsics, FIELDS[:1], truncation="map")
    with pytest.raises(ValueError, match="objective"):
        hg.hypergradient(window, config, intrinsics, FIELDS[:1], objective="psnr")
    with pytest.raises(ValueError, match="mode"):
        hg.hypergradient(window, config, intrinsics, FIELDS[:1], mode="sideways")
    lm = ts.replaced(config, {"tracking.optimizer": "lm", "tracking.strided_iters": 0, "tracking.reselect_every": 1})
    with pytest.raises(ValueError, match="reverse mode only"):  # optimistix's while loop: implicit in forward mode
        hg.hypergradient(window, lm, intrinsics, FIELDS[:1], mode="forward")
    assert set(FIELDS) <= set(differentiable_fields(config))
    assert "tracking.iters" not in differentiable_fields(config)


def test_the_straight_through_kernel_size_keeps_renders_and_follows_the_next_slot():
    from gsjax.raster import RasterSettings, render
    from gsjax.raster.cbknn import CBKNN
    from tests.support import scenes

    gaussians, w2c, intrinsics = scenes.SCENES["heavy_overlap"](0)

    def image(k0, beta=0.0, straight=True):
        cbknn = CBKNN(alpha=0.3, k0=k0, beta=beta, straight_through_k=straight)
        out = render(gaussians, w2c, intrinsics, RasterSettings(), cbknn=cbknn, motion=0.8)
        return jnp.concatenate([out.color.reshape(-1), out.depth.reshape(-1)])

    plain = np.asarray(image(5.0, 0.4, straight=False))
    np.testing.assert_array_equal(np.asarray(image(5.0, 0.4)), plain)  # the values are the rounded K's
    # d/dk0 against the change one more unit of k0 makes (the staircase's secant): the same pixels move alike.
    _, tangent = jax.jvp(lambda k: image(k, 0.4), (jnp.float32(5.0),), (jnp.float32(1.0),))
    secant = np.asarray(image(6.0, 0.4, straight=False)) - plain
    moved = (np.abs(secant) > 1e-6) | (np.abs(np.asarray(tangent)) > 1e-6)
    assert moved.sum() > 100
    assert np.corrcoef(np.asarray(tangent)[moved], secant[moved])[0, 1] > 0.75
    _, by_beta = jax.jvp(lambda b: image(5.0, b), (jnp.float32(0.4),), (jnp.float32(1.0),))
    assert np.abs(np.asarray(by_beta)).max() > 0  # beta moves K through the motion term
    _, none = jax.jvp(lambda k: image(k, 0.4, straight=False), (jnp.float32(5.0),), (jnp.float32(1.0),))
    assert np.abs(np.asarray(none)).max() == 0.0  # without it K is a step function


@pytest.fixture(scope="module")
def room80():
    """The noisy synthetic room at the cpu preset's 80x60 (its strided iterations too), in the same regime: the
    window, and the runs' differences of the residual at 5 % and 20 % steps."""
    frames, intrinsics, config = _noisy_room(FRAMES, 2, {name: str(value) for name, value in SMOOTH.items()})
    window = hg.record(frames, config, intrinsics)
    runs = {step: _differences_of(frames, config, intrinsics, "residual", step) for step in (0.05, 0.2)}
    return config, intrinsics, window, runs


@pytest.mark.slow
def test_at_80x60_the_frame_hypergradient_the_tuner_uses_points_as_whole_runs_do(room80):
    """Measured: learning rates -0.00020 / -0.00058 against the runs' -0.00053 / -0.00087 (5 %) and -0.00080 /
    -0.00059 (20 %); correlation over the five fields 0.87 and 0.62 (lambda_depth's sign differs: +0.00013 against
    -0.00017 / -0.00015)."""
    config, intrinsics, window, runs = room80
    exact = _relative(hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual"), config)
    for differences in runs.values():
        for name in FIELDS[:2]:
            assert np.sign(exact[name]) == np.sign(differences[name]), (name, exact[name], differences[name])
        a, b = np.array([exact[n] for n in FIELDS]), np.array([differences[n] for n in FIELDS])
        assert np.corrcoef(a, b)[0, 1] > 0.5, (exact, differences)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="a limit of the window derivative (issue 49, experiments/hypergrad_scan.py): "
                   "at 80x60 with sensor noise only, d residual / d lr_trans is +0.00117 (forward mode through the "
                   "run's while loops: +0.00114) and stays positive along lr_trans +-20 % (+0.0005 to +0.0016 at nine "
                   "points) while 41 whole runs there fall (slope -0.00075; they move by 1e-5 at any step, 1e-6 "
                   "included; densification, keyframes and iteration counts the same throughout). With 10 mapping "
                   "iterations instead of 30 it has the runs' sign (-0.00098); through 30 one step's map responds to "
                   "its pose by a sixth of the runs' slope or less, of the other sign on three of six axes: what "
                   "whole runs follow through many mapping iterations is not the derivative of what is computed. "
                   "With 1 cm of map noise it has their sign (-0.00052; the map-noise test below)")
def test_at_80x60_the_window_hypergradient_has_the_sign_of_whole_runs(room80):
    config, intrinsics, window, runs = room80
    exact = _relative(hg.hypergradient(window, config, intrinsics, FIELDS, objective="residual",
                                       truncation="window"), config)
    for name in FIELDS[:2]:
        assert np.sign(exact[name]) == np.sign(runs[0.05][name]), (name, exact[name], runs[0.05][name])
    a, b = np.array([exact[n] for n in FIELDS]), np.array([runs[0.05][n] for n in FIELDS])
    assert np.corrcoef(a, b)[0, 1] > 0.9, (exact, runs)


@pytest.mark.slow
def test_at_80x60_the_implicit_hypergradient_of_ate_has_the_sign_of_whole_runs_for_the_loss_weights():
    """The tutorial's setting (the noisy room, 8 frames, LM: poses are fixed points). Measured (relative, x 1e3):
    lambda_color -0.41, lambda_depth +0.25, lambda_color_keyframe +0.16 (window: the same within 0.01) against whole
    runs' -1.87 / +0.54 / +0.18 at 5 % steps and -0.38 / +0.16 / +0.17 at 20 %; the runs' differences for CB-KNN's
    alpha and K0 change sign between the steps (experiments/README.md), so they are not compared."""
    _assert_implicit_ate_has_the_runs_sign(_noisy_room(8, 2, LM), ("tracking.lambda_color", "tracking.lambda_depth",
                                                                   "cbknn.lambda_color_keyframe"))


@pytest.mark.slow
@pytest.mark.parametrize("downscale", [4, 2], ids=["40x30", "80x60"])
def test_with_map_noise_the_window_hypergradient_has_the_sign_of_whole_runs_for_cbknn_rates_and_weights(downscale):
    """The noisy room (4 frames, the cpu preset's mapping), the under-converged regime with 1 cm of fresh map noise and
    1 cm of depth noise, where CB-KNN's parameters move whole runs (`experiments/hypergrad_check.py --downscale D
    --frames 4 --regime adam-smooth+noise`). Measured, residual (relative, x 1e3), derivative against the runs' at 5 %
    / 20 % steps: 40x30 lr_trans -2.18 (-2.90 / -2.32), lr_rot -8.10 (-9.09 / -8.50), lambda_depth +0.068 (+0.76 /
    +0.29), lambda_color_keyframe -0.055 (-0.82 / -0.31), alpha -0.049 (-0.37 / -0.15), K0 +7.81 (+0.96 / +5.07),
    correlation over the eight fields 0.84 / 0.98; 80x60 lr_trans -3.90 (-3.91 / -4.25), lr_rot -11.6 (-11.9 /
    -11.6), K0 +2.79 (+0.65 / +0.22), lambda_color -0.21 against +0.07 / +0.02 (the one steady field whose sign
    differs), correlation 0.98 / 0.98. Fields whose runs change sign between the steps (or do not move) are not
    compared: lambda_color and beta at 40x30, alpha and beta at 80x60."""
    frames, intrinsics, config = _noisy_room(FRAMES, downscale, {
        "tracking.iters": "10", "tracking.strided_iters": "0", "tracking.lr_trans": "2e-4", "tracking.lr_rot": "2e-4",
        **MAP_NOISE})
    fields = FIELDS + ("cbknn.params.alpha", "cbknn.params.k0", "cbknn.params.beta")
    window = hg.record(frames, config, intrinsics)
    result = hg.hypergradient(window, config, intrinsics, fields, objective="residual", truncation="window")
    exact = np.array(list(_relative(result, config, fields).values()))
    runs = {step: np.array(list(_differences_of(frames, config, intrinsics, "residual", step, fields).values()))
            for step in (0.05, 0.2)}
    # Where the runs' differences are a derivative: the same sign at both steps, and not zero.
    steady = (np.sign(runs[0.05]) == np.sign(runs[0.2])) & (np.minimum(abs(runs[0.05]), abs(runs[0.2])) > 1e-6)
    agree = np.sign(exact) == np.sign(runs[0.2])
    assert steady.sum() >= 6, runs
    assert np.sum(steady & ~agree) <= 1, [(n, e, r5, r2) for n, e, r5, r2 in zip(fields, exact, runs[0.05], runs[0.2])]
    k0 = fields.index("cbknn.params.k0")
    assert steady[k0] and agree[k0], (exact[k0], runs[0.05][k0], runs[0.2][k0])
    for differences in runs.values():
        assert np.corrcoef(exact, differences)[0, 1] > 0.8, (exact, differences)


@pytest.mark.slow
def test_at_80x60_with_map_noise_the_implicit_hypergradient_of_ate_has_the_sign_of_whole_runs_for_cbknn():
    """LM's fixed points with 1 cm of fresh map noise and 1 cm of depth noise (the noisy room at 80x60, 8 frames;
    `experiments/hypergrad_check.py --regime lm+noise`), where whole runs' ATE responds to CB-KNN. Measured (relative,
    x 1e3): alpha +0.138 against the runs' +1.34 / +0.110 at 5 % / 20 % steps, K0 +0.172 against +1.09 / +1.81,
    lambda_color_keyframe +0.319 against +0.268 / +0.342 (beta's sign differs: +0.067 against -2.6 / -0.16)."""
    _assert_implicit_ate_has_the_runs_sign(_noisy_room(8, 2, {**LM, **MAP_NOISE}),
                                           ("cbknn.params.alpha", "cbknn.params.k0", "cbknn.lambda_color_keyframe"))


def _assert_implicit_ate_has_the_runs_sign(room, fields):
    """The implicit hypergradient of ATE against whole runs' central differences at 5 % and 20 % steps: each field's
    sign at both."""
    frames, intrinsics, config = room
    window = hg.record(frames, config, intrinsics)
    exact = _relative(hg.hypergradient(window, config, intrinsics, fields, objective="ate", adjoint="implicit"),
                      config, fields)
    for step in (0.05, 0.2):
        runs = _differences_of(frames, config, intrinsics, "ate", step, fields)
        for name in fields:
            assert np.sign(exact[name]) == np.sign(runs[name]), (name, step, exact[name], runs[name])
