"""`gsjax.slam.run` (in memory, the runner's chunk loop), mapping at known poses, and noise injection."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax import slam
from gsjax.app.runtime.cache import exported_call
from gsjax.config.text import apply_overrides
from gsjax.frame import Frame, stack_frames
from gsjax.gaussians import Gaussians
from gsjax.slam.config import NoiseConfig
from gsjax.slam.noise import add_depth_noise, perturb_map, perturb_stored_map
from gsjax.slam.presets import preset, with_cbknn_mode
from tests.support.tiny_slam import (
    CHUNK,
    FRAMES,
    TINY_OVERRIDES,
    WIDTH,
    all_finite,
    assert_trees_equal,
    frames,
    relative_gt_w2c,
    replaced,
    scan,
    tiny_config,
    tiny_sequence,
    trees_differ,
)


def run_tiny(config=None, seed=0, poses=None, source=None):
    """``gsjax.slam.run`` of the tiny sequence through the suite's exported program (one compilation for all; the
    direct call gives the same bits, test_programs)."""
    return slam.run(tiny_sequence() if source is None else source, config or tiny_config(),
                    tiny_sequence().intrinsics, seed=seed, poses=poses, chunk=CHUNK, call=exported_call())


@pytest.mark.parametrize("mode", ["off", "paper"])
def test_tiny_config_is_the_config_the_command_line_builds(mode):
    """The tests build configs from typed values (:func:`replaced`); the tiny config is the one ``gsjax run --preset
    cpu --cbknn MODE`` builds from :data:`TINY_OVERRIDES` (the command line's text), leaf types and tree structure
    included, so the CLI tests run the same compiled program."""
    typed = tiny_config(mode)
    parsed = apply_overrides(with_cbknn_mode(preset("cpu", WIDTH), mode), TINY_OVERRIDES)
    assert typed == parsed
    assert jax.tree_util.tree_structure(typed) == jax.tree_util.tree_structure(parsed)
    assert [type(x) for x in jax.tree_util.tree_leaves(typed)] == [type(x) for x in jax.tree_util.tree_leaves(parsed)]


def test_replaced_names_the_path_of_an_unknown_field_or_a_value_of_another_type():
    config = tiny_config()
    with pytest.raises(AttributeError, match="tracking.itres"):
        replaced(config, {"tracking.itres": 3})
    with pytest.raises(AttributeError, match="caps"):
        replaced(config, {"caps": config.caps})  # derived, not a setting
    with pytest.raises(TypeError, match="tracking.iters"):
        replaced(config, {"tracking.iters": "3"})
    with pytest.raises(TypeError, match="tracking.lr_trans"):
        replaced(config, {"tracking.lr_trans": 1})  # an int for a float field: another program
    with pytest.raises(TypeError, match="tracking.stop"):
        replaced(config, {"tracking.stop": config.tracking.stop})  # a section: set its fields


def test_slam_run_equals_the_chunked_scan_bit_for_bit():
    result = run_tiny()
    state, expected = scan(frames(0, FRAMES))
    assert_trees_equal(result.outputs, expected)
    assert_trees_equal(result.state, state)
    np.testing.assert_array_equal(result.w2c, np.asarray(expected.w2c))
    assert result.w2c.shape == (FRAMES, 4, 4)


def test_slam_run_takes_a_stacked_frame_or_a_list_and_ignores_ground_truth():
    host = [tiny_sequence().read_host(i) for i in range(FRAMES)]
    stacked = stack_frames(host)
    wrong_gt = dataclasses.replace(stacked, c2w=stacked.c2w + 1.0)
    reference = run_tiny()
    for source in (stacked, host, wrong_gt):
        assert_trees_equal(run_tiny(source=source).outputs, reference.outputs)


def test_slam_run_rejects_empty_input_and_misshaped_poses():
    with pytest.raises(ValueError, match="at least one frame"):
        slam.run([], tiny_config(), tiny_sequence().intrinsics)
    with pytest.raises(ValueError, match=r"\[6, 4, 4\]"):
        run_tiny(poses=np.zeros((5, 4, 4)))


def test_mapping_at_known_poses_keeps_them_and_builds_the_map():
    gt = relative_gt_w2c().astype(np.float32)
    result = run_tiny(poses=gt)
    np.testing.assert_allclose(result.w2c, gt, atol=2e-6)  # orthonormalised in float32
    np.testing.assert_array_equal(result.outputs.tracking_loss, 0.0)
    assert int(result.state.gaussians.num_active()) > 0 and all_finite(result.state)
    # Not the tracked run: the map follows the given poses.
    assert trees_differ(run_tiny().state.gaussians, result.state.gaussians)


# ------------------------------------------------------------------------------------------------ noise


def _frame(depth):
    return Frame(color=jnp.zeros(depth.shape + (3,)), depth=jnp.asarray(depth, jnp.float32), c2w=jnp.eye(4),
                 pose_valid=jnp.bool_(False), index=jnp.int32(0))


def test_depth_noise_has_the_configured_std_on_valid_pixels_and_leaves_holes():
    depth = np.full((200, 300), 2.0, np.float32)
    depth[:, :50] = 0.0
    noisy = np.asarray(add_depth_noise(_frame(depth), NoiseConfig(depth_cm=1.0), jax.random.PRNGKey(3)).depth)
    assert np.all(noisy[:, :50] == 0.0) and np.all(noisy[:, 50:] > 0)
    error = noisy[:, 50:] - 2.0
    assert abs(error.std() - 0.01) < 0.0005 and abs(error.mean()) < 0.0005  # 50 000 samples
    # Zero noise returns the input exactly (also below the 1 mm floor).
    depth[0, 60] = 1e-4
    same = add_depth_noise(_frame(depth), NoiseConfig(), jax.random.PRNGKey(3)).depth
    np.testing.assert_array_equal(np.asarray(same), depth)


def test_map_noise_perturbs_means_in_cm_and_colours_with_the_configured_std():
    n = 20000
    gaussians = Gaussians(means=jnp.ones((n, 3)), log_scales=jnp.zeros(n), logit_opacities=jnp.zeros(n),
                          rgb=jnp.full((n, 3), 0.5), active=jnp.ones(n, bool))
    noisy = perturb_map(gaussians, NoiseConfig(map_means_cm=2.0, map_rgb=0.1), jax.random.PRNGKey(0))
    assert abs(float(jnp.std(noisy.means - 1.0)) - 0.02) < 0.001
    assert abs(float(jnp.std(noisy.rgb - 0.5)) - 0.1) < 0.005
    np.testing.assert_array_equal(np.asarray(noisy.log_scales), 0.0)
    unchanged = perturb_map(gaussians, NoiseConfig(), jax.random.PRNGKey(0))
    assert_trees_equal(unchanged, gaussians)


def test_noise_changes_the_run_reproducibly_and_zero_noise_is_the_plain_run():
    noisy_config = replaced(tiny_config(), {"noise.depth_cm": 1.0, "noise.map_means_cm": 0.5})
    noisy = run_tiny(noisy_config)
    assert trees_differ(noisy.outputs, run_tiny().outputs)
    assert_trees_equal(run_tiny(noisy_config).outputs, noisy.outputs)  # same seed, same noise
    zero = replaced(tiny_config(), {"noise.depth_cm": 0.0, "noise.map_rgb": 0.0})
    assert not zero.caps.noise and noisy_config.caps.noise  # zero levels: a program without the draws
    assert_trees_equal(run_tiny(zero).outputs, run_tiny().outputs)
    # Zero levels in the program that draws (a sweep's row beside noisy ones): the plain run still.
    assert_trees_equal(run_tiny(zero.with_caps(noisy_config.caps)).outputs, run_tiny().outputs)
    assert all_finite(noisy.outputs)


def test_persistent_noise_perturbs_the_stored_map_at_its_frame_only():
    n = 20000
    gaussians = Gaussians(means=jnp.ones((n, 3)), log_scales=jnp.zeros(n), logit_opacities=jnp.zeros(n),
                          rgb=jnp.full((n, 3), 0.5), active=jnp.ones(n, bool))
    noise = NoiseConfig(persistent_means_cm=3.0, persistent_rgb=0.05, persistent_frame=4,
                        map_means_cm=9.0, map_rgb=0.9)  # the fresh per-frame levels play no part here
    noisy = perturb_stored_map(gaussians, noise, jnp.int32(4), jax.random.PRNGKey(1))
    assert abs(float(jnp.std(noisy.means - 1.0)) - 0.03) < 0.0015
    assert abs(float(jnp.std(noisy.rgb - 0.5)) - 0.05) < 0.0025
    for frame in (3, 5):
        assert_trees_equal(perturb_stored_map(gaussians, noise, jnp.int32(frame), jax.random.PRNGKey(1)), gaussians)


def test_persistent_noise_stays_in_the_map_from_its_frame_on():
    plain = run_tiny()
    config = replaced(tiny_config(), {"noise.persistent_means_cm": 1.0, "noise.persistent_frame": 3})
    noisy = run_tiny(config)
    before = jax.tree_util.tree_map(lambda x: x[:3], noisy.outputs)
    assert_trees_equal(before, jax.tree_util.tree_map(lambda x: x[:3], plain.outputs))
    assert not np.allclose(noisy.w2c[3], plain.w2c[3], atol=1e-7)  # frame 3 is tracked against the noisy map
    assert trees_differ(noisy.state.gaussians, plain.state.gaussians)
    # Once, not afresh per frame: the fresh per-frame noise of the same level is another run.
    fresh = run_tiny(replaced(tiny_config(), {"noise.map_means_cm": 1.0}))
    assert trees_differ(noisy.outputs, fresh.outputs)
    zero = replaced(tiny_config(), {"noise.persistent_means_cm": 0.0, "noise.persistent_frame": 2})
    assert_trees_equal(run_tiny(zero).outputs, plain.outputs)
    assert all_finite(noisy.outputs)


def test_noise_levels_are_validated():
    with pytest.raises(ValueError, match="noise.depth_cm"):
        NoiseConfig(depth_cm=-1.0)
    with pytest.raises(ValueError, match="noise.persistent_means_cm"):
        NoiseConfig(persistent_means_cm=-0.5)
    for frame in (0, 1.5):
        with pytest.raises(ValueError, match="noise.persistent_frame"):
            NoiseConfig(persistent_frame=frame)


def test_mapping_every_other_frame_skips_mapping_on_the_others_only():
    """``mapping.every`` 2: frames 1, 3 and 5 (neither even nor keyframes) are tracked and densified but not
    mapped (mapping loss 0); frames 0, 2 and 4 are mapped as in the plain run up to then."""
    plain = run_tiny()
    sparse = run_tiny(replaced(tiny_config(), {"mapping.every": 2}))
    loss = np.asarray(sparse.outputs.mapping_loss)
    assert np.all(loss[[1, 3, 5]] == 0.0) and np.all(loss[[0, 2, 4]] > 0.0)
    assert np.asarray(plain.outputs.mapping_loss)[1] > 0.0
    assert_trees_equal(jax.tree_util.tree_map(lambda x: x[:1], sparse.outputs),
                       jax.tree_util.tree_map(lambda x: x[:1], plain.outputs))
    assert all_finite(sparse.outputs)
