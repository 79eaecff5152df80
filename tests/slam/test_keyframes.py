"""Keyframe rule, CB-KNN mode switches, and the released code's 3D KNN smoothing of the overlap samples
(``code_parity``, method_spec C.1): identity where the subset is one point, exact neighbour means without dropout,
deterministic given the key, and a smoothing effect on noisy samples."""

from __future__ import annotations

import dataclasses

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.slam.config import CBKNNConfig
from gsjax.slam.keyframes import smooth_points
from gsjax.slam.presets import preset, with_cbknn_mode
from gsjax.slam.views import is_keyframe


def test_keyframes_are_frame_zero_every_fifth_and_the_second_to_last():
    frames = jnp.arange(13)
    keyframes = np.flatnonzero(np.asarray(is_keyframe(frames, 13, 5)))
    np.testing.assert_array_equal(keyframes, [0, 4, 9, 11])


def test_cbknn_modes_switch_render_and_overlap_smoothing():
    config = preset("cpu")
    off, parity, paper = (with_cbknn_mode(config, m).cbknn for m in ("off", "code_parity", "paper"))
    assert (off.smooth_renders, off.smooth_overlap) == (False, False)
    assert (parity.smooth_renders, parity.smooth_overlap) == (False, True)
    assert (paper.smooth_renders, paper.smooth_overlap) == (True, False)
    assert dataclasses.replace(paper, kf_overlap_smoothing=True).smooth_overlap  # optional in paper mode


def noisy_plane(count=200, noise=0.01, seed=0):
    """Points on the plane z = 0 over a unit square, with Gaussian noise along z (m)."""
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(0, 1, (count, 2)), rng.normal(0, noise, (count, 1))], axis=1).astype(
        np.float32
    )


def smoothing(**changes) -> CBKNNConfig:
    return dataclasses.replace(with_cbknn_mode(preset("cpu"), "code_parity").cbknn, **changes)


def test_smoothing_with_subsets_of_one_point_returns_the_points_unchanged():
    # K = 2 or 3 with 40 % dropout gives a subset of max(1, floor(0.6 K)) = 1: the value is kept (method_spec C.1).
    points = jnp.asarray(noisy_plane())
    out = smooth_points(jax.random.PRNGKey(0), points, smoothing(smoothing_min_k=2, smoothing_max_k=3))
    np.testing.assert_array_equal(np.asarray(out), np.asarray(points))


@pytest.mark.parametrize("k", [2, 5, 9])
def test_smoothing_without_dropout_is_the_mean_of_the_k_nearest_neighbours(k):
    points = noisy_plane(count=60, seed=k)
    config = smoothing(smoothing_min_k=k, smoothing_max_k=k, smoothing_base_k=min(6, k), smoothing_dropout=0.0)
    out = np.asarray(smooth_points(jax.random.PRNGKey(3), jnp.asarray(points), config))
    d2 = np.sum((points[:, None, :].astype(np.float64) - points[None, :, :]) ** 2, axis=-1)
    nearest = np.argsort(d2, axis=1)[:, :k]  # self included
    np.testing.assert_allclose(out, points[nearest].mean(axis=1), atol=1e-6)


def test_smoothing_is_deterministic_given_the_key_and_random_across_keys():
    points = jnp.asarray(noisy_plane())
    config = smoothing()
    first = np.asarray(smooth_points(jax.random.PRNGKey(7), points, config))
    again = np.asarray(smooth_points(jax.random.PRNGKey(7), points, config))
    other = np.asarray(smooth_points(jax.random.PRNGKey(8), points, config))
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)


def test_default_smoothing_moves_noisy_samples_towards_their_neighbourhood():
    """With the released code's parameters (K 2..16 by density, 40 % dropout) each point becomes the mean of a
    subset of its nearest neighbours: it stays within its K_max-neighbourhood, the sparsest point (K = 2, subset
    of one) is unchanged, and the noise across the plane shrinks."""
    points = noisy_plane()
    config = smoothing()
    assert (config.smoothing_base_k, config.smoothing_min_k, config.smoothing_max_k) == (6, 2, 16)
    assert config.smoothing_dropout == 0.4
    out = np.asarray(smooth_points(jax.random.PRNGKey(0), jnp.asarray(points), config))
    d2 = np.sum((points[:, None, :].astype(np.float64) - points[None, :, :]) ** 2, axis=-1)
    ordered = np.sort(d2, axis=1)
    reach = np.sqrt(ordered[:, 15])  # distance to the 16th nearest (self included)
    assert np.all(np.linalg.norm(out - points, axis=1) <= reach + 1e-6)
    sparsest = np.argmax(np.mean(ordered[:, :6], axis=1))  # lowest density 1 / mean d^2 over 6 nearest
    np.testing.assert_array_equal(out[sparsest], points[sparsest])
    assert np.std(out[:, 2]) < 0.8 * np.std(points[:, 2])
    assert np.mean(np.linalg.norm(out - points, axis=1) > 0) > 0.5  # most points moved


# ----------------------------------------------------------------------------------------------- compact storage


def test_keyframe_buffer_stores_uint8_colour_and_millimetre_depth():
    from gsjax.slam.state import KeyframeBuffer

    rng = np.random.default_rng(0)
    buffer = KeyframeBuffer.empty(3, 6, 5)
    assert buffer.color.dtype == np.uint8 and buffer.depth.dtype == np.uint16
    assert (buffer.color.nbytes + buffer.depth.nbytes) == 3 * 6 * 5 * 5  # 5 bytes per pixel, not 16
    color8 = rng.integers(0, 256, (6, 5, 3))
    depth = rng.uniform(0.3, 9.0, (6, 5))
    depth[0, :4] = [0.0, np.nan, np.inf, 70.0]  # invalid, invalid, invalid, beyond the uint16 range
    w2c = jnp.eye(4).at[0, 3].set(0.5)
    buffer = buffer.push(jnp.asarray(color8 / 255.0, jnp.float32), jnp.asarray(depth, jnp.float32), w2c, 7, 0.25,
                         jnp.bool_(True))
    assert int(buffer.count) == 1 and int(buffer.frame[0]) == 7
    np.testing.assert_array_equal(np.round(np.asarray(buffer.color_at(0)) * 255), color8)  # 8-bit input: exact
    decoded = np.asarray(buffer.depth_at(0))
    np.testing.assert_array_equal(decoded[0, :4], [0.0, 0.0, 0.0, np.float32(65.535)])
    assert np.abs(decoded - depth).ravel()[4:].max() <= 0.5e-3 + 1e-6  # rounded to the millimetre
    # a disabled push and a push into a full buffer leave everything as it was
    same = buffer.push(jnp.zeros((6, 5, 3)), jnp.ones((6, 5)), jnp.eye(4), 8, 0.0, jnp.bool_(False))
    jax.tree_util.tree_map(np.testing.assert_array_equal, same, buffer)
    full = KeyframeBuffer.empty(1, 6, 5).push(jnp.ones((6, 5, 3)), jnp.ones((6, 5)), jnp.eye(4), 0, 0.0, True)
    again = full.push(jnp.zeros((6, 5, 3)), jnp.zeros((6, 5)), jnp.eye(4), 1, 0.0, jnp.bool_(True))
    jax.tree_util.tree_map(np.testing.assert_array_equal, again, full)


def test_keyframe_push_writes_one_slot_and_never_selects_over_the_buffer():
    from gsjax.slam.state import KeyframeBuffer

    buffer = KeyframeBuffer.empty(4, 6, 5)
    jaxpr = jax.make_jaxpr(lambda b, c, d, on: b.push(c, d, jnp.eye(4), 1, 0.0, on))(
        buffer, jnp.zeros((6, 5, 3)), jnp.zeros((6, 5)), jnp.bool_(True))

    def flatten(jaxpr):
        for e in jaxpr.eqns:
            yield e
            for sub in jax.extend.core.jaxprs_in_params(e.params):
                yield from flatten(sub)

    equations = list(flatten(jaxpr.jaxpr))
    assert sum(e.primitive.name == "dynamic_update_slice" for e in equations) == 5  # one per field
    for e in equations:  # no where/select over a whole image buffer (that would copy it every frame)
        if e.primitive.name == "select_n":
            assert all(np.prod(v.aval.shape) < 4 * 6 * 5 for v in e.outvars), e
