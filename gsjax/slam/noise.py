"""Noise injection for robustness studies (:class:`gsjax.slam.config.NoiseConfig`): pure functions of a key.

The keys are folded from the step's key with fixed stream numbers, so the step's other random choices (window
and pixel sampling) are the same with or without noise, and zero noise leaves every value unchanged. Each function
draws its noise inside a ``lax.cond`` on its levels being nonzero, so the default step (no noise) draws nothing.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gsjax.frame import Frame
from gsjax.gaussians import Gaussians
from gsjax.slam.config import NoiseConfig

NOISE_STREAM = 1_000_003  # fold_in stream of the depth noise; the map noise uses the next one, the stored map's
# persistent noise the one after

MIN_NOISY_DEPTH_M = 1e-3  # noisy depth stays valid (> 0) where the input was valid


def add_depth_noise(frame: Frame, noise: NoiseConfig, key: jax.Array) -> Frame:
    """``frame`` with N(0, (depth_cm / 100)^2) m added to each valid depth pixel.

    A valid pixel stays valid: at least 1 mm, or the input where that is less; invalid pixels stay 0. With
    ``noise.depth_cm`` 0 the depth is returned unchanged.

    Args:
      frame: the frame; its depth [H, W] (m; 0 marks an invalid pixel) is read.
      noise: the noise levels (``noise.depth_cm``, the std in cm, is read; traced).
      key: PRNG key for the noise.

    Returns:
      The frame with its depth replaced (same shape and dtype); the other fields unchanged.
    """
    depth = frame.depth

    def noisy():
        sample = jax.random.normal(key, depth.shape, depth.dtype) * (noise.depth_cm / 100.0)
        floor = jnp.minimum(depth, MIN_NOISY_DEPTH_M)  # so zero noise returns the input exactly
        return jnp.where(depth > 0, jnp.maximum(depth + sample, floor), 0.0)

    return dataclasses.replace(frame, depth=jax.lax.cond(noise.depth_cm > 0, noisy, lambda: depth))


def perturb_map(gaussians: Gaussians, noise: NoiseConfig, key: jax.Array) -> Gaussians:
    """``gaussians`` with N(0, (map_means_cm / 100)^2) m on each mean and N(0, map_rgb^2) on each colour channel.

    Every slot is perturbed (inactive slots are not rendered). With ``noise.map_means_cm`` and ``noise.map_rgb``
    both 0 the map is returned unchanged.

    Args:
      gaussians: the map (N slots).
      noise: the noise levels (``map_means_cm``, the means' std in cm, and ``map_rgb``, the colours' std; traced).
      key: PRNG key for the noise.

    Returns:
      The map with its means [N, 3] and colours [N, 3] perturbed (colours not clamped); the other fields
        unchanged.
    """
    return jax.lax.cond((noise.map_means_cm > 0) | (noise.map_rgb > 0),
                        lambda: _perturbed(gaussians, noise.map_means_cm, noise.map_rgb, key), lambda: gaussians)


def perturb_stored_map(gaussians: Gaussians, noise: NoiseConfig, frame: jax.Array, key: jax.Array) -> Gaussians:
    """The stored map as frame ``frame`` starts: perturbed once, at ``noise.persistent_frame``, else unchanged.

    At that frame, N(0, (persistent_means_cm / 100)^2) m is added to each mean and N(0, persistent_rgb^2) to each
    colour channel (every slot); at any other frame, or with both levels 0, ``gaussians`` itself is returned.

    Args:
      gaussians: the stored map (N slots).
      noise: the noise levels (``persistent_means_cm``, ``persistent_rgb`` and ``persistent_frame`` are read).
      frame: [] int32 index of the frame that starts.
      key: PRNG key for the noise.

    Returns:
      The map, with its means [N, 3] and colours [N, 3] perturbed at ``noise.persistent_frame``.
    """
    now = (frame == noise.persistent_frame) & ((noise.persistent_means_cm > 0) | (noise.persistent_rgb > 0))
    return jax.lax.cond(now, lambda: _perturbed(gaussians, noise.persistent_means_cm, noise.persistent_rgb, key),
                        lambda: gaussians)


def _perturbed(gaussians: Gaussians, means_cm, rgb_std, key: jax.Array) -> Gaussians:
    key_means, key_rgb = jax.random.split(key)
    means = gaussians.means + jax.random.normal(key_means, gaussians.means.shape) * (means_cm / 100.0)
    rgb = gaussians.rgb + jax.random.normal(key_rgb, gaussians.rgb.shape) * rgb_std
    return dataclasses.replace(gaussians, means=means, rgb=rgb)
