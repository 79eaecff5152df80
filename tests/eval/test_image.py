"""Image metrics against an independent numpy float64 reference (explicit 2D Gaussian window), plus gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.eval.image import (
    depth_l1,
    ms_ssim,
    psnr,
    psnr_splatam,
    render_metrics_splatam,
    ssim,
    ssim_splatam,
)

# ------------------------------------------------------------------------------- numpy float64 reference


def window_2d(size=11, sigma=1.5):
    ax = np.arange(size) - (size - 1) / 2.0
    w = np.exp(-(ax[:, None] ** 2 + ax[None, :] ** 2) / (2 * sigma**2))
    return w / w.sum()


def filter_valid(x, w):
    """'valid' 2D correlation of [H, W, C] with w [k, k]."""
    win = np.lib.stride_tricks.sliding_window_view(x, w.shape, axis=(0, 1))  # [H', W', C, k, k]
    return np.einsum("hwcij,ij->hwc", win, w)


def ssim_maps_ref(a, b, pad=0):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if pad:
        a = np.pad(a, ((pad, pad), (pad, pad), (0, 0)))
        b = np.pad(b, ((pad, pad), (pad, pad), (0, 0)))
    w = window_2d()
    mu_a, mu_b = filter_valid(a, w), filter_valid(b, w)
    saa = filter_valid(a * a, w) - mu_a**2
    sbb = filter_valid(b * b, w) - mu_b**2
    sab = filter_valid(a * b, w) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    cs = (2 * sab + c2) / (saa + sbb + c2)
    return (2 * mu_a * mu_b + c1) / (mu_a**2 + mu_b**2 + c1) * cs, cs


def avg_pool_ref(x):
    """torch avg_pool2d(kernel 2, stride 2, padding=size % 2, count_include_pad=True), written with loops."""
    h, w, _ = x.shape
    ph, pw = h % 2, w % 2
    xp = np.pad(x, ((ph, ph), (pw, pw), (0, 0)))
    out = np.zeros(((h + 2 * ph - 2) // 2 + 1, (w + 2 * pw - 2) // 2 + 1, x.shape[2]))
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = xp[2 * i : 2 * i + 2, 2 * j : 2 * j + 2].mean(axis=(0, 1))
    return out


def ms_ssim_ref(a, b, weights=(0.0448, 0.2856, 0.3001, 0.2363, 0.1333)):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    values = []
    for level in range(len(weights)):
        s, cs = ssim_maps_ref(a, b)
        if level < len(weights) - 1:
            values.append(np.maximum(cs.mean(axis=(0, 1)), 0))
            a, b = avg_pool_ref(a), avg_pool_ref(b)
    values.append(np.maximum(s.mean(axis=(0, 1)), 0))
    return np.mean(np.prod(np.stack(values) ** np.asarray(weights)[:, None], axis=0))


def image_pair(shape, noise, seed=0):
    """A smooth textured image and a noisy copy, float32 in [0, 1]."""
    rng = np.random.default_rng(seed)
    h, w, _ = shape
    yy, xx = np.mgrid[0:h, 0:w] / 7.0
    base = 0.5 + 0.25 * np.stack([np.sin(xx + yy), np.cos(0.7 * xx - yy), np.sin(0.3 * xx * yy / 5)], -1)
    base = np.clip(base + 0.1 * rng.random(shape), 0, 1)
    other = np.clip(base + noise * rng.standard_normal(shape), 0, 1)
    return jnp.asarray(base, jnp.float32), jnp.asarray(other, jnp.float32)


# ----------------------------------------------------------------------------------------------- tests


def test_psnr_matches_reference():
    a, b = image_pair((30, 41, 3), 0.05)
    mse = np.mean((np.float64(a) - np.float64(b)) ** 2)
    assert float(psnr(a, b)) == pytest.approx(-10 * np.log10(mse), abs=1e-4)


def test_psnr_splatam_is_the_mean_of_per_channel_psnrs():
    a, b = image_pair((30, 41, 3), 0.05)
    b = b.at[..., 0].set(a[..., 0] + 0.2)  # one channel much worse: the two definitions differ
    err = (np.float64(a) - np.float64(b)) ** 2
    per_channel = 20 * np.log10(1.0 / np.sqrt(err.mean(axis=(0, 1))))
    assert float(psnr_splatam(a, b)) == pytest.approx(per_channel.mean(), abs=1e-4)
    assert abs(float(psnr_splatam(a, b)) - float(psnr(a, b))) > 1.0


def test_ssim_valid_matches_reference():
    a, b = image_pair((48, 40, 3), 0.08)
    expected = ssim_maps_ref(a, b)[0].mean()
    assert 0.3 < expected < 0.95
    assert float(ssim(a, b)) == pytest.approx(expected, abs=1e-5)  # float32: E[x^2] - mu^2 cancels digits
    with jax.enable_x64(True):
        assert float(ssim(jnp.float64(a), jnp.float64(b))) == pytest.approx(expected, abs=1e-12)


def test_ssim_splatam_matches_zero_padded_reference():
    a, b = image_pair((48, 40, 3), 0.08)
    expected = ssim_maps_ref(a, b, pad=5)[0].mean()
    assert float(ssim_splatam(a, b)) == pytest.approx(expected, abs=1e-5)
    with jax.enable_x64(True):
        assert float(ssim_splatam(jnp.float64(a), jnp.float64(b))) == pytest.approx(expected, abs=1e-12)
    assert abs(expected - ssim_maps_ref(a, b)[0].mean()) > 1e-3  # the padding matters at this size


def test_ssim_splatam_matches_the_reference_beyond_the_matrix_blur_size():
    """Past MATMUL_BLUR_MAX_SIDE the blurs are convolutions; the same SSIM either way."""
    from gsjax.eval.image import MATMUL_BLUR_MAX_SIDE

    a, b = image_pair((20, MATMUL_BLUR_MAX_SIDE + 4, 3), 0.08)
    assert float(ssim_splatam(a, b)) == pytest.approx(ssim_maps_ref(a, b, pad=5)[0].mean(), abs=1e-5)
    assert float(ssim(a, b)) == pytest.approx(ssim_maps_ref(a, b)[0].mean(), abs=1e-5)


def test_ssim_splatam_gradient_matches_finite_differences():
    with jax.enable_x64(True):
        a, b = image_pair((14, 12, 3), 0.1, seed=3)
        a, b = jnp.asarray(a, jnp.float64), jnp.asarray(b, jnp.float64)
        grad_a, grad_b = jax.jit(jax.grad(ssim_splatam, argnums=(0, 1)))(a, b)
        rng = np.random.default_rng(4)
        eps = 1e-6
        for _ in range(3):
            da = jnp.asarray(rng.standard_normal(a.shape))
            db = jnp.asarray(rng.standard_normal(b.shape))
            fd = (ssim_splatam(a + eps * da, b + eps * db) - ssim_splatam(a - eps * da, b - eps * db)) / (2 * eps)
            analytic = jnp.sum(grad_a * da) + jnp.sum(grad_b * db)
            assert float(analytic) == pytest.approx(float(fd), rel=1e-6, abs=1e-9)


def test_ssim_splatam_gradient_is_finite_on_flat_images():
    flat = jnp.full((16, 16, 3), 0.5, jnp.float32)
    grad = jax.grad(ssim_splatam)(flat, flat)
    assert bool(jnp.all(jnp.isfinite(grad)))


def test_ms_ssim_matches_reference_on_odd_sizes():
    a, b = image_pair((175, 190, 3), 0.05)  # 175 is odd: exercises the padded pooling
    assert float(ms_ssim(a, b)) == pytest.approx(ms_ssim_ref(a, b), abs=2e-5)


def test_ms_ssim_is_one_for_identical_images_and_decreases_with_noise():
    values = []
    for noise in (0.0, 0.02, 0.05, 0.1, 0.2):
        a, b = image_pair((176, 176, 3), noise, seed=1)
        values.append(float(ms_ssim(a, b)))
    assert values[0] == pytest.approx(1.0, abs=1e-6)
    assert all(x > y for x, y in zip(values, values[1:])), values


def test_ms_ssim_rejects_images_too_small_for_five_scales():
    a, b = image_pair((160, 200, 3), 0.0)
    with pytest.raises(ValueError, match="larger than 160 px"):
        ms_ssim(a, b)


def test_depth_l1_averages_over_valid_gt_pixels_only():
    depth_gt = jnp.array([[1.0, 2.0], [0.0, jnp.nan]])
    depth = jnp.array([[1.5, 1.0], [jnp.inf, 7.0]])
    assert float(depth_l1(depth, depth_gt)) == pytest.approx((0.5 + 1.0) / 2)


def test_render_metrics_splatam_masks_colour_by_valid_depth():
    a, b = image_pair((176, 180, 3), 0.05)
    depth_gt = jnp.ones(a.shape[:2]).at[:40].set(0.0)  # top rows have no depth
    b_garbage_on_top = b.at[:40].set(1.0 - b[:40])
    metrics = render_metrics_splatam(a, depth_gt + 0.1, b_garbage_on_top, depth_gt)
    mask = np.asarray(depth_gt > 0)[..., None]
    assert float(metrics["psnr_db"]) == pytest.approx(float(psnr_splatam(a * mask, b * mask)), abs=1e-4)
    assert float(metrics["ms_ssim"]) == pytest.approx(ms_ssim_ref(a * mask, b * mask), abs=2e-5)
    assert float(metrics["depth_l1_m"]) == pytest.approx(0.1, abs=1e-6)
