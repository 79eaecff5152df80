"""Image and depth metrics as small pure JAX functions (jitted; images [H, W, 3] with data range 1).

* :func:`psnr`: PSNR (dB) of the whole image (dm-pix); :func:`psnr_splatam`: SplaTAM's per-channel PSNR, averaged
  over channels (method_spec B.3).
* :func:`ssim`: SSIM over the 'valid' region (dm-pix: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2);
  :func:`ssim_splatam`: SplaTAM's training SSIM (same window, zero padding of 5 px, no clipping), differentiable,
  used by the mapping loss (method_spec A.9).
* :func:`ms_ssim`: MS-SSIM with pytorch_msssim's defaults, the number SplaTAM reports as "SSIM".
* :func:`depth_l1`: SplaTAM's depth L1 (m) over pixels with valid GT depth.
* :func:`render_metrics_splatam`: the three numbers SplaTAM's evaluation reports for one frame, with its masking.

LPIPS is not implemented: it needs pretrained AlexNet weights, which no installed package ships and which
cannot be downloaded at run time here.
"""

from __future__ import annotations

import functools

import dm_pix
import jax
import jax.numpy as jnp
import numpy as np

WINDOW_SIZE = 11
WINDOW_SIGMA = 1.5
K1, K2 = 0.01, 0.03
MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def gaussian_window(size: int = WINDOW_SIZE, sigma: float = WINDOW_SIGMA) -> np.ndarray:
    """Normalised 1D Gaussian window [size] centred on ``size // 2`` (float64)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


# Up to this side (px), blurs are products with banded [H', H] and [W', W] matrices: XLA:CPU runs a small matrix
# product far faster than an 11-tap convolution (80x60 SSIM with its gradient: 0.9 ms against 13 ms); beyond it the
# band's zeros would cost more than the convolution.
MATMUL_BLUR_MAX_SIDE = 256


def _band(size: int, pad: int) -> np.ndarray:
    """[size + 2 pad - 10, size] float64: row i holds the window centred on input pixel i - pad + 5, taps beyond the
    image dropped (zero padding)."""
    window = gaussian_window()
    rows = size + 2 * pad - (WINDOW_SIZE - 1)
    band = np.zeros((rows, size))
    for tap, weight in enumerate(window):
        i = np.arange(rows)
        j = i + tap - pad
        inside = (j >= 0) & (j < size)
        band[i[inside], j[inside]] = weight
    return band


def _blur(image: jax.Array, pad: int) -> jax.Array:
    """Separable 11x11 Gaussian blur of [..., H, W, C] per channel; ``pad`` zero pixels on each side (0 = 'valid')."""
    hp = jax.lax.Precision.HIGHEST
    height, width = image.shape[-3:-1]
    if max(height, width) <= MATMUL_BLUR_MAX_SIDE:
        rows, cols = (jnp.asarray(_band(n, pad), image.dtype) for n in (height, width))
        x = jnp.einsum("ih,...hwc->...iwc", rows, image, precision=hp)
        return jnp.einsum("jw,...iwc->...ijc", cols, x, precision=hp)
    window = jnp.asarray(gaussian_window(), image.dtype)
    batch = image.shape[:-3]
    x = jnp.moveaxis(image.reshape((-1,) + image.shape[-3:]), -1, 1).reshape(-1, 1, height, width)  # depthwise
    conv = jax.lax.conv_general_dilated
    x = conv(x, window.reshape(1, 1, -1, 1), (1, 1), [(pad, pad), (0, 0)], precision=hp)
    x = conv(x, window.reshape(1, 1, 1, -1), (1, 1), [(0, 0), (pad, pad)], precision=hp)
    x = jnp.moveaxis(x.reshape(-1, image.shape[-1], *x.shape[-2:]), 1, -1)
    return x.reshape(batch + x.shape[1:])


def _ssim_maps(a: jax.Array, b: jax.Array, pad: int) -> tuple[jax.Array, jax.Array]:
    """(SSIM map, contrast-structure map) [H', W', C], Wang et al. 2004 with alpha = beta = gamma = 1, unclipped."""
    c1, c2 = K1**2, K2**2
    mu_a, mu_b, aa, bb, ab = _blur(jnp.stack([a, b, a * a, b * b, a * b]), pad)  # one blur of all five
    var_a = aa - mu_a * mu_a
    var_b = bb - mu_b * mu_b
    cov = ab - mu_a * mu_b
    cs = (2.0 * cov + c2) / (var_a + var_b + c2)
    luminance = (2.0 * mu_a * mu_b + c1) / (mu_a * mu_a + mu_b * mu_b + c1)
    return luminance * cs, cs


def _check_images(a: jax.Array, b: jax.Array) -> None:
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"images must both have shape [H, W, C], got {a.shape} and {b.shape}")


@jax.jit
def psnr(image: jax.Array, reference: jax.Array) -> jax.Array:
    """PSNR from the MSE over all pixels and channels (dm-pix), data range 1.

    Args:
      image: [H, W, C] float image, data range 1.
      reference: [H, W, C] reference image, same shape.

    Returns:
      [] PSNR (dB).

    Raises:
      ValueError: the shapes differ or are not [H, W, C].
    """
    _check_images(image, reference)
    return dm_pix.psnr(image, reference)


@jax.jit
def psnr_splatam(image: jax.Array, reference: jax.Array) -> jax.Array:
    """SplaTAM's PSNR: ``20 log10(1 / sqrt(MSE_c))`` per channel c, then the mean over channels.

    Args:
      image: [H, W, C] float image, data range 1.
      reference: [H, W, C] reference image, same shape.

    Returns:
      [] mean per-channel PSNR (dB).
    """
    _check_images(image, reference)
    mse = jnp.mean(jnp.square(image - reference), axis=(0, 1))
    return jnp.mean(-10.0 * jnp.log10(mse))


@jax.jit
def ssim(image: jax.Array, reference: jax.Array) -> jax.Array:
    """Mean SSIM over the 'valid' region (no padding) and channels (dm-pix; window 11, sigma 1.5).

    Args:
      image: [H, W, C] float image, data range 1.
      reference: [H, W, C] reference image, same shape.

    Returns:
      [] mean SSIM, at most 1.
    """
    _check_images(image, reference)
    return dm_pix.ssim(
        image, reference, max_val=1.0, filter_size=WINDOW_SIZE, filter_sigma=WINDOW_SIGMA, k1=K1, k2=K2
    )


@jax.jit
def ssim_splatam(image: jax.Array, reference: jax.Array) -> jax.Array:
    """SplaTAM's training SSIM ([S] ``calc_ssim``): 11x11 Gaussian window (sigma 1.5), zero padding of 5 px so the
    map covers every pixel, C1 = 0.01^2, C2 = 0.03^2, mean over pixels and channels. Differentiable in both
    arguments (no clipping of the local variances).

    Args:
      image: [H, W, C] float image, data range 1.
      reference: [H, W, C] reference image, same shape.

    Returns:
      [] mean SSIM, at most 1.
    """
    _check_images(image, reference)
    return jnp.mean(_ssim_maps(image, reference, WINDOW_SIZE // 2)[0])


def _avg_pool2(image: jax.Array) -> jax.Array:
    """``F.avg_pool2d(kernel_size=2, padding=size % 2)`` on [H, W, C]: zero padding counts in the average."""
    h, w, c = image.shape
    x = jnp.pad(image, ((h % 2, h % 2), (w % 2, w % 2), (0, 0)))
    ho, wo = (h + 1) // 2, (w + 1) // 2
    return x[: 2 * ho, : 2 * wo].reshape(ho, 2, wo, 2, c).mean(axis=(1, 3))


@functools.partial(jax.jit, static_argnames="weights")
def ms_ssim(image: jax.Array, reference: jax.Array, weights: tuple[float, ...] = MS_SSIM_WEIGHTS) -> jax.Array:
    """Multi-scale SSIM as ``pytorch_msssim.ms_ssim(data_range=1)`` with its defaults: 'valid' 11-px Gaussian
    windows (sigma 1.5), 2x average pooling between scales, per channel
    ``prod_{s<last} relu(cs_s)^w_s * relu(ssim_last)^w_last``, then the mean over channels.

    Args:
      image: [H, W, C] float image, data range 1, with ``min(H, W) > 10 * 2^(len(weights) - 1)`` (161 px for 5
        scales).
      reference: [H, W, C] reference image, same shape.
      weights: one weight per scale, finest first; a static tuple (one compile per distinct value).

    Returns:
      [] MS-SSIM, in [0, 1].

    Raises:
      ValueError: the images are too small for ``len(weights)`` scales, or their shapes differ.
    """
    _check_images(image, reference)
    levels = len(weights)
    min_side = (WINDOW_SIZE - 1) * 2 ** (levels - 1)
    if min(image.shape[:2]) <= min_side:
        raise ValueError(f"ms_ssim needs images larger than {min_side} px on each side, got {image.shape[:2]}")
    factors = []
    a, b = image, reference
    for level in range(levels):
        ssim_map, cs_map = _ssim_maps(a, b, pad=0)
        if level < levels - 1:
            factors.append(jax.nn.relu(jnp.mean(cs_map, axis=(0, 1))))
            a, b = _avg_pool2(a), _avg_pool2(b)
    factors.append(jax.nn.relu(jnp.mean(ssim_map, axis=(0, 1))))
    per_channel = jnp.prod(jnp.stack(factors) ** jnp.asarray(weights, image.dtype)[:, None], axis=0)
    return jnp.mean(per_channel)


def valid_depth_mask(depth_gt: jax.Array) -> jax.Array:
    """Pixels [H, W] whose GT depth is a positive finite number (SplaTAM: ``depth > 0``)."""
    return jnp.isfinite(depth_gt) & (depth_gt > 0)


@jax.jit
def depth_l1(depth: jax.Array, depth_gt: jax.Array) -> jax.Array:
    """SplaTAM's depth L1 (m): ``sum |D - D_gt| valid / sum valid`` over pixels with valid GT depth. [H, W].

    Invalid pixels contribute nothing even where ``depth`` is not finite (SplaTAM multiplies by the mask, which
    gives NaN there).

    Args:
      depth: [H, W] rendered or estimated depth (m).
      depth_gt: [H, W] ground-truth depth (m); valid where positive and finite.

    Returns:
      [] mean absolute depth error (m) over valid pixels; NaN with no valid pixel.
    """
    valid = valid_depth_mask(depth_gt)
    err = jnp.where(valid, jnp.abs(depth - depth_gt), 0.0)
    return jnp.sum(err) / jnp.sum(valid)


def ms_ssim_scales(height: int, width: int) -> int:
    """How many of MS-SSIM's 5 scales an image of this size supports (at least 1)."""
    levels = len(MS_SSIM_WEIGHTS)
    while levels > 1 and min(height, width) <= (WINDOW_SIZE - 1) * 2 ** (levels - 1):
        levels -= 1
    return levels


@jax.jit
def render_metrics_splatam(color: jax.Array, depth: jax.Array, color_gt: jax.Array,
                           depth_gt: jax.Array) -> dict[str, jax.Array]:
    """One frame's metrics as SplaTAM's final evaluation computes them (method_spec B.3).

    Both colour images are multiplied by the valid-GT-depth mask (invalid pixels count as zero error but stay in
    the denominators); the render is not clamped. Colour [H, W, 3] in [0, 1], depth [H, W] (m). Images smaller than
    MS-SSIM's 161 px use its first scales only (weights renormalised; ``ms_ssim_scales`` says how many), and SSIM is
    reported as well.

    Args:
      color: [H, W, 3] rendered colour in [0, 1].
      depth: [H, W] rendered depth (m).
      color_gt: [H, W, 3] ground-truth colour in [0, 1].
      depth_gt: [H, W] ground-truth depth (m); valid where positive and finite.

    Returns:
      {"psnr_db": psnr_splatam, "ms_ssim": ms_ssim, "ms_ssim_scales": n, "ssim": ssim, "depth_l1_m": depth_l1}.
    """
    valid = valid_depth_mask(depth_gt)[..., None]
    masked = jnp.where(valid, color, 0.0)
    masked_gt = jnp.where(valid, color_gt, 0.0)
    levels = ms_ssim_scales(*color.shape[:2])
    weights = MS_SSIM_WEIGHTS[:levels]
    weights = tuple(w / sum(weights) for w in weights)
    return {
        "psnr_db": psnr_splatam(masked, masked_gt),
        "ms_ssim": ms_ssim(masked, masked_gt, weights),
        "ms_ssim_scales": levels,
        "ssim": ssim(masked, masked_gt),
        "depth_l1_m": depth_l1(depth, depth_gt),
    }
