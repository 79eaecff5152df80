"""Numerical faults in the SLAM step: non-finite input pixels are made invalid, a map Gaussian with a non-finite
parameter is freed and counted, and tracking divergence (a pose beyond the physical bound, a loss jump) is retried
once and falls back to the constant-velocity prediction when the retry diverges too."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import constant_velocity, orthonormalize, se3_exp
from gsjax.slam.tracking import TrackingProblem, track, track_guarded, within_step_bound
from tests.support.tiny_slam import (
    CHUNK,
    FRAMES,
    all_finite,
    assert_trees_equal,
    frames,
    replaced,
    scan,
    tiny_config,
    tiny_sequence,
)


def test_non_finite_pixels_are_invalid_pixels():
    """NaN colour, NaN depth and inf depth in frames 0 and 2 give bit for bit the run where those pixels have no
    depth (and zero colour): nothing non-finite reaches a loss, a Gaussian or a keyframe."""
    chunk = frames(0, FRAMES)
    bad = dataclasses.replace(chunk, color=chunk.color.at[2, 12, 20, 0].set(jnp.nan).at[0, 3, 4, 2].set(jnp.inf),
                              depth=chunk.depth.at[2, 5, 6].set(jnp.nan).at[0, 7, 8].set(jnp.inf))
    invalid = dataclasses.replace(
        chunk, color=chunk.color.at[2, 12, 20].set(0.0).at[0, 3, 4].set(0.0).at[2, 5, 6].set(0.0).at[0, 7, 8].set(0.0),
        depth=chunk.depth.at[2, 12, 20].set(0.0).at[0, 3, 4].set(0.0).at[2, 5, 6].set(0.0).at[0, 7, 8].set(0.0))
    got = scan(bad)
    assert_trees_equal(got, scan(invalid))
    assert all_finite(got)
    assert int(got[0].nonfinite_tracking) == 0 and int(got[0].nonfinite_mapping) == 0


def test_a_frame_of_nan_is_a_frame_without_depth():
    """Frame 3 all NaN (a dropped sensor read as NaN): skipped like a frame without depth, the map stays finite."""
    chunk = frames(0, FRAMES)
    bad = dataclasses.replace(chunk, color=chunk.color.at[3].set(jnp.nan), depth=chunk.depth.at[3].set(jnp.nan))
    state, out = scan(bad)
    np.testing.assert_array_equal(np.asarray(out.skipped), np.arange(FRAMES) == 3)
    assert all_finite(state) and all_finite(out)


def test_a_gaussian_with_a_non_finite_parameter_is_freed_before_tracking_and_counted():
    """A NaN colour put into the map after frame 2: frame 3 frees that slot first (counted in the state and the
    frame's outputs), then runs exactly as from the map with the slot empty."""
    state, _ = scan(frames(0, CHUNK))
    slot = int(np.flatnonzero(np.asarray(state.gaussians.active))[7])
    g = state.gaussians
    poisoned = dataclasses.replace(state, gaussians=dataclasses.replace(g, rgb=g.rgb.at[slot, 1].set(jnp.nan)))
    emptied = dataclasses.replace(state, gaussians=dataclasses.replace(
        g, means=g.means.at[slot].set(0.0), log_scales=g.log_scales.at[slot].set(0.0),
        logit_opacities=g.logit_opacities.at[slot].set(0.0), rgb=g.rgb.at[slot].set(0.0),
        active=g.active.at[slot].set(False)))
    rest, one = frames(CHUNK, FRAMES), jnp.asarray([True, False, False])
    got_state, got = scan(rest, state=poisoned, valid=one)
    want_state, want = scan(rest, state=emptied, valid=one)
    assert int(got.nonfinite_gaussians[0]) == 1 and int(want.nonfinite_gaussians[0]) == 0
    assert int(got_state.nonfinite_gaussians) == 1
    assert_trees_equal(got._replace(nonfinite_gaussians=want.nonfinite_gaussians), want)
    assert_trees_equal(dataclasses.replace(got_state, nonfinite_gaussians=want_state.nonfinite_gaussians), want_state)
    assert int(got.nonfinite[0]) == 0  # tracking never saw the NaN


def test_the_step_bound_measures_camera_centre_and_rotation():
    config = replaced(tiny_config(), {"tracking.guard.max_step_m": 0.1, "tracking.guard.max_step_deg": 10.0})
    start = orthonormalize(se3_exp(jnp.asarray([0.3, -0.2, 1.0, 0.1, 0.2, -0.1])))
    moved = lambda delta: se3_exp(jnp.asarray(delta, jnp.float32)) @ start  # noqa: E731
    assert bool(within_step_bound(start, start, config.tracking))
    assert bool(within_step_bound(moved([0.09, 0, 0, 0, 0, 0]), start, config.tracking))
    assert not bool(within_step_bound(moved([0.11, 0, 0, 0, 0, 0]), start, config.tracking))
    # A left rotation turns the camera about its own centre: the centre stays, the angle decides.
    assert bool(within_step_bound(moved([0, 0, 0, 0, np.deg2rad(9.5), 0]), start, config.tracking))
    assert not bool(within_step_bound(moved([0, 0, 0, 0, np.deg2rad(10.5), 0]), start, config.tracking))
    assert not bool(within_step_bound(start.at[0, 3].set(jnp.nan), start, config.tracking))


def test_a_pose_beyond_the_bound_is_retried_then_falls_back_to_the_prediction():
    """With a bound no tracked pose can meet (1 micrometre), every tracked frame is retried, the retry fails the
    bound too, and the frame keeps its constant-velocity prediction; the counts land in the state."""
    config = replaced(tiny_config(), {"tracking.guard.max_step_m": 1e-6})
    state, out = scan(frames(0, FRAMES), config)
    tracked = np.arange(FRAMES) >= 1
    np.testing.assert_array_equal(np.asarray(out.retried), tracked)
    np.testing.assert_array_equal(np.asarray(out.diverged), tracked)
    assert int(state.retried_frames) == int(state.diverged_frames) == FRAMES - 1
    w2c = np.asarray(out.w2c)
    np.testing.assert_allclose(w2c[1], w2c[0], atol=1e-6)  # frame 1's prediction is frame 0's pose
    for t in range(2, FRAMES):
        predicted = orthonormalize(constant_velocity(jnp.asarray(w2c[t - 2]), jnp.asarray(w2c[t - 1])))
        np.testing.assert_allclose(w2c[t], np.asarray(predicted), atol=1e-6)
    plain_state, plain = scan(frames(0, FRAMES))
    assert not np.any(np.asarray(plain.retried)) and int(plain_state.retried_frames) == 0
    assert not np.allclose(np.asarray(plain.w2c[2]), w2c[2], atol=1e-5)


def test_a_loss_jump_is_retried_and_keeps_the_lower_loss():
    """A loss-jump factor below 1 flags every frame with a previous tracked frame (2 on): each is tracked again
    with smaller steps and keeps the attempt with the lower loss, so frame 2's loss is at most the plain run's;
    frame 1 has no reference and is not retried; nothing falls back to the prediction."""
    config = replaced(tiny_config(), {"tracking.guard.loss_jump": 1e-3})
    state, out = scan(frames(0, FRAMES), config)
    np.testing.assert_array_equal(np.asarray(out.retried), np.arange(FRAMES) >= 2)
    assert not np.any(np.asarray(out.diverged))
    _, plain = scan(frames(0, FRAMES))
    assert_trees_equal(out.w2c[:2], plain.w2c[:2])
    assert float(out.tracking_loss[2]) <= float(plain.tracking_loss[2])
    assert int(state.retried_frames) == FRAMES - 2



def test_the_retry_is_the_tracker_again_with_its_steps_scaled_and_the_lower_loss_wins():
    """``track_guarded`` with a forced retry (a tiny previous loss) equals two plain ``track`` calls, the second
    with both step sizes times ``retry_lr_scale``: the pose of the lower loss, both attempts' iterations. (A scale
    above 1 here, so that the second attempt wins at 3 iterations.)"""
    config = replaced(tiny_config(), {"tracking.guard.retry_lr_scale": 2.0})
    state, _ = scan(frames(0, CHUNK), config)
    frame = frames(CHUNK, CHUNK + 1)
    cfg = config.tracking
    slower = dataclasses.replace(config, tracking=dataclasses.replace(cfg, lr_trans=cfg.lr_trans * 2,
                                                                      lr_rot=cfg.lr_rot * 2))
    problem = TrackingProblem(state.gaussians, frame.color[0], frame.depth[0], state.w2c_prev1,
                              tiny_sequence().intrinsics, False, 0.0)

    @jax.jit
    def attempts(config, slower):
        return track_guarded(problem, config, jnp.float32(1e-9)), track(problem, config), track(problem, slower)

    guarded, first, second = attempts(config, slower)
    assert bool(guarded.retried) and not bool(guarded.diverged)
    assert float(second.loss) < float(first.loss)
    np.testing.assert_array_equal(np.asarray(guarded.w2c), np.asarray(second.w2c))
    assert float(guarded.loss) == float(second.loss)
    assert int(guarded.iterations) == int(first.iterations) + int(second.iterations)
