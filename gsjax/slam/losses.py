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
    """[H, W] bool: valid observed depth, finite rendered depth and variance, silhouette above the threshold."""
    variance = view.depth_sq - view.depth * view.depth
    return (depth_gt > 0) & jnp.isfinite(view.depth) & jnp.isfinite(variance) & (view.silhouette > sil_threshold)


def rendered_depth(view: RenderedView, normalized: bool) -> jax.Array:
    """SplaTAM's depth D = sum w z, or D / S (``normalized``; 0 where S = 0)."""
    if not normalized:
        return view.depth
    covered = view.silhouette > 0
    return jnp.where(covered, view.depth / jnp.where(covered, view.silhouette, 1.0), 0.0)


def exposure_gain(color: jax.Array, color_gt: jax.Array, mask: jax.Array) -> jax.Array:
    """[3] the per-channel gain that matches the render's brightness to the observation's over ``mask``: the ratio
    of their sums, within [0.5, 2] (no gradient: a nuisance fitted afresh for every render)."""
    weight = mask[..., None].astype(color.dtype)
    gain = jnp.sum(weight * color_gt, axis=(0, 1)) / jnp.maximum(jnp.sum(weight * color, axis=(0, 1)), 1e-6)
    return jax.lax.stop_gradient(jnp.clip(gain, 0.5, 2.0))


def _compared_color(view: RenderedView, color_gt: jax.Array, mask: jax.Array,
                    match_exposure: bool | jax.Array) -> jax.Array:
    gain = exposure_gain(view.color, color_gt, mask)
    return view.color * jnp.where(match_exposure, gain, 1.0)


def gaussian_blur(image: jax.Array, sigma_px: float | jax.Array, radius: int) -> jax.Array:
    """``image`` [H, W, C] filtered by a separable Gaussian of std ``sigma_px`` (px, may be traced) truncated at
    ``radius`` px (static) and normalised over its taps, zero outside the image; ``sigma_px`` 0 returns the image."""
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
      lambda_color, lambda_depth: the weights of the colour and depth terms (traced).
      sil_threshold: the silhouette above which a pixel with valid depth counts (:func:`tracking_mask`, traced).
      normalized_depth: compare depth / silhouette (:func:`rendered_depth`; a Python bool).
      match_exposure: scale the render's colour by :func:`exposure_gain` first (bool, may be traced).
      blur_px: std (px) of the Gaussian that filters the masked residuals (traced); blur_radius: its truncation (px,
        a Python int; 0: no filter).
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
        """The terms ``tracking`` sets; ``lambda_color`` (a keyframe's) and ``blur_px`` (a coarse level's) replace
        its own when given."""
        return cls(tracking.lambda_color if lambda_color is None else lambda_color, tracking.lambda_depth,
                   tracking.sil_threshold, tracking.normalized_depth, tracking.exposure.match,
                   tracking.blur.sigma_px if blur_px is None else blur_px, tracking.blur.radius_px)


def tracking_loss(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array, terms: TrackingTerms) -> jax.Array:
    """SplaTAM's tracking loss: lambda_depth sum_M |D - D_gt| + lambda_color sum_M |C - C_gt| (sums, not means);
    with ``match_exposure`` the render's colour is first scaled by :func:`exposure_gain`. With ``blur_radius`` > 0
    the masked residuals are first filtered by :func:`gaussian_blur` (``blur_px``): render and frame blurred
    together."""
    if terms.blur_radius:
        depth, color = _masked_residuals(view, color_gt, depth_gt, terms)
        return terms.lambda_depth * jnp.sum(jnp.abs(depth)) + terms.lambda_color * jnp.sum(jnp.abs(color))
    mask = jax.lax.stop_gradient(tracking_mask(view, depth_gt, terms.sil_threshold))
    depth = rendered_depth(view, terms.normalized_depth)
    color = _compared_color(view, color_gt, mask, terms.match_exposure)
    depth_term = jnp.sum(jnp.where(mask, jnp.abs(depth - depth_gt), 0.0))
    color_term = jnp.sum(jnp.where(mask[..., None], jnp.abs(color - color_gt), 0.0))
    return terms.lambda_depth * depth_term + terms.lambda_color * color_term


def tracking_residuals(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array,
                       terms: TrackingTerms) -> jax.Array:
    """The same masked terms as a residual vector [H*W*4] for least squares (Gauss-Newton / LM), blurred as
    :func:`tracking_loss` blurs them."""
    depth, color = _masked_residuals(view, color_gt, depth_gt, terms)
    depth, color = depth * jnp.sqrt(terms.lambda_depth), color * jnp.sqrt(terms.lambda_color)
    return jnp.concatenate([depth.reshape(-1), color.reshape(-1)])


def _masked_residuals(view, color_gt, depth_gt, terms: TrackingTerms) -> tuple[jax.Array, jax.Array]:
    """(depth [H, W], colour [H, W, 3]) render - frame, zero outside :func:`tracking_mask`, then filtered by
    :func:`gaussian_blur` when ``blur_radius`` > 0."""
    mask = jax.lax.stop_gradient(tracking_mask(view, depth_gt, terms.sil_threshold))
    depth = jnp.where(mask, rendered_depth(view, terms.normalized_depth) - depth_gt, 0.0)
    color = jnp.where(mask[..., None], _compared_color(view, color_gt, mask, terms.match_exposure) - color_gt, 0.0)
    if terms.blur_radius:
        depth = gaussian_blur(depth[..., None], terms.blur_px, terms.blur_radius)[..., 0]
        color = gaussian_blur(color, terms.blur_px, terms.blur_radius)
    return depth, color


def mapping_loss(view: RenderedView, color_gt: jax.Array, depth_gt: jax.Array, lambda_color: float | jax.Array,
                 lambda_depth: float | jax.Array, ssim_weight: float | jax.Array) -> jax.Array:
    """SplaTAM's mapping loss: lambda_depth mean_{D_gt>0} |D - D_gt| + lambda_color ((1 - w) mean |C - C_gt| +
    w (1 - SSIM(C, C_gt))), colour over all pixels, SSIM zero-padded as in SplaTAM's training code."""
    valid = depth_gt > 0
    depth_term = jnp.sum(jnp.where(valid, jnp.abs(view.depth - depth_gt), 0.0)) / jnp.maximum(jnp.sum(valid), 1)
    l1 = jnp.mean(jnp.abs(view.color - color_gt))
    color_term = (1.0 - ssim_weight) * l1 + ssim_weight * (1.0 - ssim_splatam(view.color, color_gt))
    return lambda_depth * depth_term + lambda_color * color_term
