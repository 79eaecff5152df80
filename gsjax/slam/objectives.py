"""What a hypergradient measures a SLAM window by (:mod:`gsjax.slam.hypergrad`), as differentiable functions of the
tracked poses: fixed measures that no config field weighs, so that tuning a field cannot win by changing the measure.

* ``residual``: needs no ground truth. Each tracked frame rendered at its tracked pose from the map built before
  it (the frame is held out of that map) against the observation: the unweighted L1 of depth (m) plus the L1 of
  colour (mean over the channels), each a mean over the pixels with valid depth whose canonical silhouette exceeds
  0.99, averaged over the frames. The render is canonical (no CB-KNN correction, whatever the mode).
* ``ate``: the RMSE (m) of the camera centres after the rigid alignment onto the ground truth (as ``gsjax eval``
  reports it). The alignment is the minimiser of the same squared error, so its own derivative does not enter
  (envelope theorem): it is computed once, on the host, and held fixed.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics, camera_center, invert_transform
from gsjax.eval.trajectory import umeyama_alignment
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings
from gsjax.slam.config import CBKNNConfig
from gsjax.slam.losses import tracking_mask
from gsjax.slam.views import render_view

OBJECTIVES = ("residual", "ate")
RESIDUAL_SILHOUETTE = 0.99  # SplaTAM's tracking threshold, fixed: the measure must not follow a tuned field


def frame_residual(gaussians: Gaussians, w2c: jax.Array, color: jax.Array, depth: jax.Array,
                   intrinsics: Intrinsics, raster: RasterSettings) -> jax.Array:
    """The ``residual`` of one frame: how well ``gaussians`` rendered at ``w2c`` explain the observation.

    Args:
      gaussians: the map built before the frame.
      w2c: [4, 4] the frame's tracked world-to-camera pose (m).
      color: [H, W, 3] the observed colour in [0, 1].
      depth: [H, W] the observed depth (m; 0 marks an invalid pixel).
      intrinsics: the camera.
      raster: the rasterizer settings.

    Returns:
      [] mean |depth error| (m) + mean |colour error| over the counted pixels (0 when none counts).
    """
    view = render_view(gaussians, w2c, intrinsics, raster, CBKNNConfig(), False, 0.0, can_smooth=False)
    mask = jax.lax.stop_gradient(tracking_mask(view, depth, RESIDUAL_SILHOUETTE))
    count = jnp.maximum(jnp.sum(mask), 1)
    depth_l1 = jnp.sum(jnp.where(mask, jnp.abs(view.depth - depth), 0.0)) / count
    color_l1 = jnp.sum(jnp.where(mask[..., None], jnp.abs(view.color - color), 0.0)) / (3 * count)
    return depth_l1 + color_l1


def mean_over(values: jax.Array, counted: jax.Array) -> jax.Array:
    """The mean of ``values`` over the frames ``counted``.

    Args:
      values: [T] a value per frame.
      counted: [T] bool, the frames that count.

    Returns:
      [] the mean over the counted frames (0 when none is).
    """
    return jnp.sum(jnp.where(counted, values, 0.0)) / jnp.maximum(jnp.sum(counted), 1)


class AteTarget(NamedTuple):
    """The ground truth of the ``ate`` objective and the alignment held fixed (:func:`ate_target`).

    Attributes:
      centres: [T, 3] float32 ground-truth camera centres (m).
      valid: [T] bool, the frames whose ground truth is real.
      rotation: [3, 3] float32 the alignment's rotation (estimate onto ground truth).
      translation: [3] float32 its translation (m).
    """

    centres: jax.Array
    valid: jax.Array
    rotation: jax.Array
    translation: jax.Array


def ate_target(gt_c2w: np.ndarray, gt_valid: np.ndarray, w2c: np.ndarray) -> AteTarget:
    """The ``ate`` objective's target: the ground truth and the rigid alignment of ``w2c`` onto it (float64).

    Args:
      gt_c2w: [T, 4, 4] ground-truth camera-to-world poses (m).
      gt_valid: [T] bool, the frames whose ground truth is real.
      w2c: [T, 4, 4] the estimated world-to-camera poses to align (m; the recorded run's).

    Returns:
      The target, an :class:`AteTarget`.

    Raises:
      ValueError: fewer than 3 frames have ground truth.
    """
    gt_c2w = np.asarray(gt_c2w, np.float64)
    valid = np.asarray(gt_valid, bool) & np.isfinite(gt_c2w).all(axis=(1, 2))
    if valid.sum() < 3:
        raise ValueError(f"the ate objective needs ground truth on at least 3 frames, got {int(valid.sum())}")
    est_c2w = invert_transform(np.asarray(w2c, np.float64))
    alignment = umeyama_alignment(est_c2w[valid, :3, 3], gt_c2w[valid, :3, 3])
    return AteTarget(jnp.asarray(np.nan_to_num(gt_c2w[:, :3, 3]), jnp.float32), jnp.asarray(valid),
                     jnp.asarray(alignment.rotation, jnp.float32), jnp.asarray(alignment.translation, jnp.float32))


def centre_error(w2c: jax.Array, centre: jax.Array, target: AteTarget) -> jax.Array:
    """The squared distance (m^2) of one pose's camera centre, aligned by ``target``, from its ground truth.

    Args:
      w2c: [4, 4] a world-to-camera pose (m).
      centre: [3] its ground-truth camera centre (m).
      target: the alignment (:func:`ate_target`; its ``centres`` and ``valid`` are not read).

    Returns:
      [] the squared error (m^2).
    """
    error = target.rotation @ camera_center(w2c) + target.translation - centre
    return jnp.sum(error * error)


def ate(w2c: jax.Array, target: AteTarget) -> jax.Array:
    """The ``ate`` objective: the RMSE (m) of the camera centres of ``w2c`` [T, 4, 4] under ``target``'s alignment.

    Args:
      w2c: [T, 4, 4] world-to-camera poses (m).
      target: the ground truth and alignment (:func:`ate_target`).

    Returns:
      [] the RMSE (m) over the frames with ground truth.
    """
    squared = jax.vmap(centre_error, in_axes=(0, 0, None))(w2c, target.centres, target)
    return jnp.sqrt(mean_over(squared, target.valid))
