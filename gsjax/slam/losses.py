"""Tracking and mapping losses (method_spec A.6.3, A.9), on :class:`gsjax.slam.views.RenderedView` renders."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp

from gsjax.eval.image import ssim_splatam
from gsjax.slam.views import RenderedView

if TYPE_CHECKING:
    from gsjax.slam.config import TrackingConfig


def tracking_mask(view: RenderedView, depth_gt: jax.Array, sil_threshold: float | jax.Array) -> jax.Array:
    """The pixels the tracking loss counts: valid observed depth, finite render, silhouette above the threshold.

    A finite render is a finite rendered depth and depth variance (depth_sq - depth^2).

    Args:
      view: the render (its depth, depth_sq and silhouette are read).
      depth_gt: [H, W] the observed depth (m; 0 marks an invalid pixel).
      sil_threshold: a pixel counts where the rendered silhouette exceeds this (may be traced).

    Returns:
      [H, W] bool, the pixels that count.
    """
    variance = view.depth_sq - view.depth * view.depth
    return (depth_gt > 0) & jnp.isfinite(view.depth) & jnp.isfinite(variance) & (view.silhouette > sil_threshold)


def rendered_depth(view: RenderedView, normalized: bool) -> jax.Array:
    """SplaTAM's depth D = sum w z, or D / S (``normalized``; 0 where S = 0).

    Args:
      view: the render.
      normalized: divide the depth by the silhouette S (a Python bool).

    Returns:
      [H, W] the depth to compare with the observed depth (m).
    """
    if not normalized:
        return view.depth
    covered = view.silhouette > 0
    return jnp.where(covered, view.depth / jnp.where(covered, view.silhouette, 1.0), 0.0)


def exposure_gain(color: jax.Array, color_gt: jax.Array, mask: jax.Array) -> jax.Array:
    """The per-channel gain that matches the render's brightness to the observation's over ``mask``.

    The ratio of their sums, within [0.5, 2] (no gradient: a nuisance fitted afresh for every render).

    Args:
      color: [H, W, 3] the rendered colour.
      color_gt: [H, W, 3] the observed colour.
      mask: [H, W] bool, the pixels summed (:func:`tracking_mask`).

    Returns:
      [3] the gain of each channel, of ``color``'s dtype (1e-6 bounds the render's sum from below).
    """
    weight = mask[..., None].astype(color.dtype)
    gain = jnp.sum(weight * color_gt, axis=(0, 1)) / jnp.maximum(jnp.sum(weight * color, axis=(0, 1)), 1e-6)
    return jax.lax.stop_gradient(jnp.clip(gain, 0.5, 2.0))


def _compared_color(view: RenderedView, color_gt: jax.Array, mask: jax.Array,
                    match_exposure: bool | jax.Array) -> jax.Array:
    gain = exposure_gain(view.color, color_gt, mask)
    return view.color * jnp.where(match_exposure, gain, 1.0)


def gaussian_blur(image: jax.Array, sigma_px: float | jax.Array, radius: int) -> jax.Array:
    """``image`` filtered by a separable Gaussian, truncated and normalised over its taps, zero outside the image.

    Args:
      image: [H, W, C] the image (filtered along H and W).
      sigma_px: the Gaussian's std (px, may be traced); 0 returns the image.
      radius: the truncation (px, a Python int): 2 ``radius`` + 1 taps per axis.

    Returns:
      [H, W, C] the filtered image, of ``image``'s dtype.
    """
    taps = jnp.arange(-radius, radius + 1, dtype=image.dtype)
    sigma = jnp.asarray(sigma_px, image.dtype)
    bell = jnp.exp(-0.5 * jnp.square(taps / jnp.where(sigma > 0, sigma, 1.0)))
    weights = jnp.where(sigma > 0, bell / jnp.sum(bell), (taps == 0).astype(image.dtype))

    def along(x, axis):
        padded = jnp.pad(x, [(radius, radius) if a == axis else (0, 0) for a in range(x.ndim)])
        size = x.shape[axis]
        return sum(weights[i] * jax.lax.slice_in_dim(padded, i, i + size, axis=axis) for i in range(2 * radius + 1))

    return along(along(image, 0), 1)


class TrackingTerms(NamedTuple):
    """How the tracking loss weighs and filters its terms (:func:`tracking_loss`, :func:`tracking_residuals`).

    Attributes:
      lambda_color: the weight of the colour term (traced).
      lambda_depth: the weight of the depth term (traced).
      sil_threshold: the silhouette above which a pixel with valid depth counts (:func:`tracking_mask`, traced).
      normalized_depth: compare depth / silhouette (:func:`rendered_depth`; a Python bool).
      match_exposure: scale the render's colour by :func:`exposure_gain` first (bool, may be traced).
      blur_px: std (px) of the Gaussian that filters the masked residuals (traced).
      blur_radius: the truncation of that Gaussian (px, a Python int; 0: no filter).
    """

    lambda_color: float | jax.Array
    lambda_depth: float | jax.Array
    sil_threshold: float | jax.Array
    normalized_depth: bool = False
    match_exposure: bool | jax.Array = False
    blur_px: float | jax.Array = 0.0
    blur_radius: int = 0

    @classmethod
    def of(cls, tracking: TrackingConfig, lambda_color: float | jax.Array | None = None,
           blur_px: float | jax.Array | None = None) -> TrackingTerms:
        """The terms ``tracking`` sets; ``lambda_color`` and ``blur_px`` replace its own when given.

        Args:
          tracking: the tracking config (its ``lambda_color``, ``lambda_depth``, ``sil_threshold``,
            ``normalized_depth``, ``exposure.match``, ``blur.sigma_px`` and ``blur.radius_px`` are read).
          lambda_color: the colour weight to use instead of ``tracking.lambda_color`` (a smoothed keyframe's), or
            None.
          blur_px: the blur std (px) to use instead of ``tracking.blur.sigma_px`` (the LM tracker's, halved on a
            strided grid), or None.

        Returns:
          the terms.
        """
        return cls(tracking.lambda_color if lambda_color is None else lambda_color, tracking.lambda_depth,
                   tracking.sil_threshold, tracking.normalized_depth, tracking.exposure.match,
                   tracking.blur.sigma_px if blur_px is None else blur_px, tracking.blur.radius_px)


def tracking_loss(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array, terms: TrackingTerms) -> jax.Array:
    """SplaTAM's tracking loss: lambda_depth sum_M |D - D_gt| + lambda_color sum_M |C - C_gt| (sums, not means).

    M is :func:`tracking_mask` (no gradient flows through it) and D :func:`rendered_depth`. With
    ``match_exposure`` the render's colour is first scaled by :func:`exposure_gain`. With ``blur_radius`` > 0 the
    masked residuals are first filtered by :func:`gaussian_blur` (``blur_px``): render and frame blurred together.

    Args:
      view: the render.
      color_gt: [H, W, 3] the observed colour.
      depth_gt: [H, W] the observed depth (m; 0 marks an invalid pixel).
      terms: the weights, threshold and filters.

    Returns:
      [] the loss.
    """
    if terms.blur_radius:
        depth, color = masked_residuals(view, color_gt, depth_gt, terms)
        return terms.lambda_depth * jnp.sum(jnp.abs(depth)) + terms.lambda_color * jnp.sum(jnp.abs(color))
    mask = jax.lax.stop_gradient(tracking_mask(view, depth_gt, terms.sil_threshold))
    depth = rendered_depth(view, terms.normalized_depth)
    color = _compared_color(view, color_gt, mask, terms.match_exposure)
    depth_term = jnp.sum(jnp.where(mask, jnp.abs(depth - depth_gt), 0.0))
    color_term = jnp.sum(jnp.where(mask[..., None], jnp.abs(color - color_gt), 0.0))
    return terms.lambda_depth * depth_term + terms.lambda_color * color_term


def tracking_residuals(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array,
                       terms: TrackingTerms) -> jax.Array:
    """The masked terms of :func:`tracking_loss` as a residual vector for least squares (Gauss-Newton / LM).

    Blurred as :func:`tracking_loss` blurs them; each is scaled by the square root of its weight, so the sum of
    squares weighs them as the loss does (squares, not absolute values).

    Args:
      view: the render.
      color_gt: [H, W, 3] the observed colour.
      depth_gt: [H, W] the observed depth (m; 0 marks an invalid pixel).
      terms: the weights, threshold and filters.

    Returns:
      [H*W*4] the depth residuals (H*W) and then the colour residuals (H*W*3), render - frame, zero outside
        :func:`tracking_mask` (before the blur).
    """
    depth, color = masked_residuals(view, color_gt, depth_gt, terms)
    depth, color = depth * jnp.sqrt(terms.lambda_depth), color * jnp.sqrt(terms.lambda_color)
    return jnp.concatenate([depth.reshape(-1), color.reshape(-1)])


def masked_residuals(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array,
                     terms: TrackingTerms) -> tuple[jax.Array, jax.Array]:
    """The terms of :func:`tracking_loss` before their absolute values and weights.

    Args:
      view: the render.
      color_gt: [H, W, 3] the observed colour.
      depth_gt: [H, W] the observed depth (m; 0 marks an invalid pixel).
      terms: the threshold and filters (the weights are not applied).

    Returns:
      (depth [H, W] m, colour [H, W, 3]) render - frame, zero outside :func:`tracking_mask` (no gradient through
        the mask), then filtered by :func:`gaussian_blur` when ``blur_radius`` > 0.
    """
    mask = jax.lax.stop_gradient(tracking_mask(view, depth_gt, terms.sil_threshold))
    depth = jnp.where(mask, rendered_depth(view, terms.normalized_depth) - depth_gt, 0.0)
    color = jnp.where(mask[..., None], _compared_color(view, color_gt, mask, terms.match_exposure) - color_gt, 0.0)
    if terms.blur_radius:
        depth = gaussian_blur(depth[..., None], terms.blur_px, terms.blur_radius)[..., 0]
        color = gaussian_blur(color, terms.blur_px, terms.blur_radius)
    return depth, color


def mapping_loss(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array, lambda_color: float | jax.Array,
                 lambda_depth: float | jax.Array, ssim_weight: float | jax.Array) -> jax.Array:
    """SplaTAM's mapping loss: L1 depth over the valid pixels plus L1 and SSIM colour over all pixels.

    lambda_depth mean_{D_gt>0} |D - D_gt| + lambda_color ((1 - w) mean |C - C_gt| + w (1 - SSIM(C, C_gt))), D the
    rendered ``sum w z`` (not normalised), SSIM zero-padded as in SplaTAM's training code
    (:func:`gsjax.eval.image.ssim_splatam`).

    Args:
      view: the render.
      color_gt: [H, W, 3] the observed colour in [0, 1].
      depth_gt: [H, W] the observed depth (m; 0 marks an invalid pixel).
      lambda_color: the weight of the colour term (may be traced).
      lambda_depth: the weight of the depth term (may be traced).
      ssim_weight: w, the share of 1 - SSIM in the colour term (may be traced).

    Returns:
      [] the loss (0 depth term when no pixel has valid depth).
    """
    valid = depth_gt > 0
    depth_term = jnp.sum(jnp.where(valid, jnp.abs(view.depth - depth_gt), 0.0)) / jnp.maximum(jnp.sum(valid), 1)
    l1 = jnp.mean(jnp.abs(view.color - color_gt))
    color_term = (1.0 - ssim_weight) * l1 + ssim_weight * (1.0 - ssim_splatam(view.color, color_gt))
    return lambda_depth * depth_term + lambda_color * color_term
