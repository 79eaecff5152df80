"""The SLAM scan: chunking does not change the result (bit for bit), padding frames are no-ops, one vmapped program
over a batch of configs and states equals the separate runs, every CB-KNN mode runs, frame 0 initialises the map,
ground truth is never read, and frames without usable depth are skipped (numerical faults:
``test_slam_faults.py``)."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import constant_velocity, orthonormalize
from gsjax.frame import without_ground_truth
from gsjax.slam import system
from tests.support.tiny_slam import (
    CHUNK,
    FRAMES,
    HEIGHT,
    WIDTH,
    all_finite,
    assert_trees_close,
    assert_trees_equal,
    frames,
    initial,
    replaced,
    scan,
    tiny_config,
    tiny_sequence,
    trees_differ,
)


def run_chunk(state, chunk, valid, config, intrinsics):
    """The SLAM scan over the stacked frames ``chunk`` from ``state``, in chunks of CHUNK through the suite's one
    program (:func:`tests.support.tiny_slam.scan`)."""
    return scan(chunk, config, state, valid)


def concat(*outputs):
    return jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *outputs)


def valid(*flags):
    return jnp.asarray(flags, bool)


@functools.lru_cache(maxsize=None)
def run_first_chunk(mode: str = "off", seed: int = 0, overrides: tuple = ()):
    """run_chunk over frames [0, CHUNK) from the initial state (cached: several tests compare with it)."""
    config = replaced(tiny_config(mode), dict(overrides))
    return run_chunk(initial(seed), frames(0, CHUNK), jnp.ones(CHUNK, bool), config, tiny_sequence().intrinsics)


# ------------------------------------------------------------------------------------------------- chunking


@pytest.fixture(scope="module")
def whole_run():
    """All FRAMES frames, in chunks of CHUNK."""
    return run_chunk(initial(), frames(0, FRAMES), jnp.ones(FRAMES, bool), tiny_config(), tiny_sequence().intrinsics)


def test_chunks_cut_anywhere_give_bit_for_bit_the_state_and_outputs_of_the_whole_run(whole_run):
    """Chunks of 1, 3 and 2 frames (the short ones padded as the runner pads the last chunk) against chunks of 3."""
    state, out = scan(frames(0, FRAMES), cuts=(1, 4))
    assert_trees_equal(state, whole_run[0])
    assert_trees_equal(out, whole_run[1])


def test_padding_frames_leave_the_state_untouched_and_output_zeros(whole_run):
    intrinsics, config = tiny_sequence().intrinsics, tiny_config()
    first_state, _ = run_first_chunk()
    # Frames 3 and 4 followed by a frame marked invalid ...
    state, out = run_chunk(first_state, frames(CHUNK, FRAMES), valid(True, True, False), config, intrinsics)
    # ... are frames 3 and 4 of the whole run, and the padding frame's outputs are zeros.
    assert int(state.frame) == 5
    assert_trees_equal(jax.tree_util.tree_map(lambda x: x[:2], out),
                       jax.tree_util.tree_map(lambda x: x[CHUNK:5], whole_run[1]))
    for leaf in jax.tree_util.tree_leaves(out):
        assert not np.any(np.asarray(leaf[2]))
    # An all-padding chunk is a no-op.
    same_state, _ = run_chunk(first_state, frames(CHUNK, FRAMES), valid(False, False, False), config, intrinsics)
    assert_trees_equal(same_state, first_state)


def test_frame_zero_initialises_the_map_from_every_valid_pixel_and_becomes_keyframe_zero(whole_run):
    state, out = whole_run
    np.testing.assert_array_equal(np.asarray(out.w2c[0]), np.eye(4))  # the first camera is the world frame
    assert float(out.tracking_loss[0]) == 0.0 and int(out.nonfinite[0]) == 0
    assert int(out.added[0]) == WIDTH * HEIGHT  # the synthetic room has valid depth everywhere
    assert int(out.dropped.sum()) == 0 == int(state.dropped_gaussians)
    np.testing.assert_array_equal(np.asarray(out.keyframe), [True, False, False, False, True, False])
    assert int(state.keyframes.count) == 2
    np.testing.assert_array_equal(np.asarray(state.keyframes.frame[:2]), [0, 4])
    np.testing.assert_array_equal(np.asarray(state.keyframes.w2c[1]), np.asarray(out.w2c[4]))
    assert int(state.frame) == FRAMES and all_finite(state) and all_finite(out)
    assert np.all(np.asarray(out.tracking_loss[1:]) > 0)


# ------------------------------------------------------------------------------------------------------ vmap

SWEPT = (("tracking.lr_trans", 0.004), ("cbknn.params.alpha", 0.5), ("mapping.lr_rgb", 0.01))


def stack(a, b):
    return jax.tree_util.tree_map(lambda x, y: jnp.stack([jnp.asarray(x), jnp.asarray(y)]), a, b)


# Slow (a vmapped program of its own): the default suite's vmapped sweep (tests/app/test_sweep.py) checks the same.
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["off", "paper"])
def test_vmap_over_configs_and_states_equals_the_separate_runs(mode):
    """One program over a batch of two configs (traced fields differ) and two initial states (seeds differ); in
    ``paper`` mode CB-KNN acts on keyframe 0's densification and mapping and on the alpha that differs."""
    config_a = tiny_config(mode)
    config_b = replaced(config_a, dict(SWEPT))
    configs, states = stack(config_a, config_b), stack(initial(0), initial(1))
    batched = jax.vmap(system.run_chunk, in_axes=(0, None, None, 0, None, None))(
        states, frames(0, CHUNK), jnp.ones(CHUNK, bool), configs, tiny_sequence().intrinsics, None
    )
    separate = [run_first_chunk(mode, 0), run_first_chunk(mode, 1, SWEPT)]
    for i, expected in enumerate(separate):
        # Measured: up to 1e-4 absolute on tracking losses of ~200 (float32 sums reduced in another order), 5e-6 on
        # logit opacities and 7e-5 to 1.2e-4 on 1-3 of 7200 colours (the SSIM's matrix products reduce in another
        # order under vmap, and Adam with eps 1e-15 turns a near-zero gradient's rounding into a step of up to its
        # rate: a few entries may differ by up to one colour step, mapping.lr_rgb); integers and masks equal.
        assert_trees_close(jax.tree_util.tree_map(lambda x: x[i], batched), expected, rtol=1e-5, atol=1e-4, few=4,
                           few_atol=dict(SWEPT)["mapping.lr_rgb"])
    # The comparison is not vacuous: the swept fields change the run (with the same seed).
    assert trees_differ(run_first_chunk(mode, 0, SWEPT), run_first_chunk(mode, 0))


# ---------------------------------------------------------------------------------------------- CB-KNN modes


@pytest.mark.parametrize("mode", ["off", "code_parity", "paper"])
def test_every_cbknn_mode_runs_without_nan(mode):
    state, out = run_first_chunk(mode)
    assert all_finite(state) and all_finite(out)
    assert int(state.nonfinite_tracking) == 0 and int(state.dropped_gaussians) == 0
    assert int(out.num_gaussians[-1]) >= WIDTH * HEIGHT


def _frame_zero(config):
    """The state after frame 0 alone (the chunk's other frames marked padding: the chunk program of every test)."""
    state, _ = run_chunk(initial(), frames(0, CHUNK), jnp.arange(CHUNK) < 1, config, tiny_sequence().intrinsics)
    return state


def test_paper_mode_changes_the_run_through_keyframe_zero():
    """Frame 0 is keyframe 0 and is not tracked; paper mode smooths its mapping renders (and its densification
    render, of the still empty map: nothing to smooth). So after frame 0 alone paper's map differs from off's, and
    with keyframe mapping unsmoothed it is off's bit for bit: the difference comes through keyframe 0's mapping."""
    off, paper = tiny_config("off"), tiny_config("paper")
    assert trees_differ(_frame_zero(paper).gaussians, _frame_zero(off).gaussians)
    unsmoothed = dataclasses.replace(paper, cbknn=dataclasses.replace(paper.cbknn, map_keyframes=False))
    assert unsmoothed.cbknn.densify and unsmoothed.cbknn.mode == "paper"
    assert_trees_equal(_frame_zero(unsmoothed).gaussians, _frame_zero(off).gaussians)


# ------------------------------------------------------------------------------------------------ non-finite


# ----------------------------------------------------------------------------- ground truth, frames without depth


def test_the_core_never_reads_ground_truth():
    """The same frames with their GT poses, without any, and with wrong ones give bit for bit the same run."""
    chunk = frames(0, FRAMES)
    config, intrinsics = tiny_config(), tiny_sequence().intrinsics
    with_gt = run_chunk(initial(), chunk, jnp.ones(FRAMES, bool), config, intrinsics)
    assert bool(np.all(np.asarray(chunk.pose_valid)))
    blank = without_ground_truth(chunk)
    assert not np.any(np.asarray(blank.pose_valid)) and np.array_equal(np.asarray(blank.c2w[3]), np.eye(4))
    wrong = dataclasses.replace(chunk, c2w=jnp.flip(chunk.c2w, axis=0))
    for other in (blank, wrong):
        assert_trees_equal(run_chunk(initial(), other, jnp.ones(FRAMES, bool), config, intrinsics), with_gt)
    assert int(with_gt[0].keyframes.count) == 2  # keyframes 0 and 4, whatever the GT says


def _with_depth(chunk, index, depth):
    return dataclasses.replace(chunk, depth=chunk.depth.at[index].set(depth))


def test_a_frame_without_usable_depth_keeps_its_predicted_pose_and_leaves_the_map_alone():
    """Frame 4 (a keyframe by the frame rule) keeps 10 valid depth pixels of 1200, under the 1 % threshold: it is
    skipped (predicted pose, no map change, no keyframe), and frame 5 is tracked from there."""
    config, intrinsics = tiny_config(), tiny_sequence().intrinsics
    first_state, first_out = run_first_chunk()
    rest = frames(CHUNK, FRAMES)
    sparse = jnp.zeros((HEIGHT, WIDTH)).at[5, :10].set(rest.depth[1, 5, :10])
    rest = _with_depth(rest, 1, sparse)
    state_3, _ = run_chunk(first_state, rest, valid(True, False, False), config, intrinsics)  # after frame 3
    state_4, _ = run_chunk(first_state, rest, valid(True, True, False), config, intrinsics)  # after frame 4
    state, out = run_chunk(first_state, rest, valid(True, True, True), config, intrinsics)
    np.testing.assert_array_equal(np.asarray(out.skipped), [False, True, False])
    w2c = np.concatenate([np.asarray(first_out.w2c), np.asarray(out.w2c)])
    predicted = orthonormalize(constant_velocity(jnp.asarray(w2c[2]), jnp.asarray(w2c[3])))
    np.testing.assert_allclose(w2c[4], np.asarray(predicted), atol=1e-6)
    assert_trees_equal(state_4.gaussians, state_3.gaussians)
    assert_trees_equal(state_4.keyframes, state_3.keyframes)
    assert not bool(out.keyframe[1]) and int(state.keyframes.count) == 1
    assert int(out.added[1]) == 0 and float(out.tracking_loss[1]) == 0.0
    assert float(out.tracking_loss[2]) > 0 and all_finite(state) and all_finite(out)
    assert int(state.frame) == FRAMES


def test_the_first_frame_with_depth_starts_the_map():
    """Frame 0 has no depth at all: frame 1 initialises the map (not tracked, keyframe 0, world frame), frame 2 on
    are tracked."""
    config, intrinsics = tiny_config(), tiny_sequence().intrinsics
    chunk = _with_depth(frames(0, FRAMES), 0, jnp.zeros((HEIGHT, WIDTH)))
    state, out = run_chunk(initial(), chunk, jnp.ones(FRAMES, bool), config, intrinsics)
    np.testing.assert_array_equal(np.asarray(out.skipped), [True] + [False] * (FRAMES - 1))
    np.testing.assert_array_equal(np.asarray(out.num_gaussians[:2]), [0, WIDTH * HEIGHT])
    np.testing.assert_array_equal(np.asarray(out.w2c[:2]), np.stack([np.eye(4)] * 2))
    np.testing.assert_array_equal(np.asarray(out.tracking_loss[:2]), [0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(out.keyframe), [False, True, False, False, True, False])
    np.testing.assert_array_equal(np.asarray(state.keyframes.frame[:2]), [1, 4])
    assert np.all(np.asarray(out.tracking_loss[2:]) > 0) and all_finite(state) and all_finite(out)
