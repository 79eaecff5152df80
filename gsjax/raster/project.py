"""Projection of isotropic 3D Gaussians to screen-space 2D Gaussians (EWA splatting), differentiable.

Semantics are SplaTAM's rasterizer (method_spec A.3) with DESIGN 2.2.1's pixel convention (centres at integers):

* camera point ``x = R mu + t``; culled when ``z <= near``;
* centre ``u = fx X/Z + cx``, ``v = fy Y/Z + cy`` (px);
* ``Sigma2D = s^2 J J^T + 0.3 I`` (px^2), with the perspective Jacobian J evaluated at X/Z, Y/Z clamped to
  ``+-1.3 tan(fov/2)`` (3DGS); isotropic 3D covariance so the rotation drops out;
* per-pixel alpha ``min(0.99, o exp(-d^T Sigma2D^-1 d / 2))``, contributing where ``alpha >= 1/255``. The screen
  extent is the bounding box of that ellipse, ``d^T Sigma2D^-1 d <= 2 ln(255 o)``, so it depends on the opacity
  and no contributing pixel is missed.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics
from gsjax.gaussians import Gaussians

ALPHA_MIN = 1.0 / 255.0  # smallest alpha that contributes to a pixel
ALPHA_MAX = 0.99  # alpha clamp (straight-through gradient)
DILATION = 0.3  # px^2 added to the 2D covariance (low-pass filter)
JACOBIAN_CLAMP = 1.3  # x/z, y/z clamp in units of tan(fov/2)
# Relative + absolute slack (px) on the screen extent: binning must never miss a pixel that float32 rounding in
# the per-pixel alpha test would still accept; extra candidates are harmless (the alpha test is exact).
_EXTENT_SLACK_REL = 1e-3
_EXTENT_SLACK_ABS = 1e-2


class Projected(NamedTuple):
    """Screen-space Gaussians, N entries (all differentiable except ``extent`` and ``visible``).

    Attributes:
      uv: [N, 2] centre (u, v) in px.
      conic: [N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]] (1/px^2).
      depth: [N] camera z (m).
      opacity: [N] sigmoid(logit_opacity).
      rgb: [N, 3] colour.
      extent: [N, 2] half-width/height (px) of the box holding every pixel with alpha >= 1/255 (no gradient).
      visible: [N] bool: active, in front of the near plane, able to reach alpha >= 1/255, box overlaps the image.
    """

    uv: jax.Array
    conic: jax.Array
    depth: jax.Array
    opacity: jax.Array
    rgb: jax.Array
    extent: jax.Array
    visible: jax.Array


def project(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, near: jax.Array) -> Projected:
    """Project Gaussians [N] with world-to-camera ``w2c`` [4, 4] into the image of ``intrinsics``.

    Free slots are replaced by harmless constants first, so whatever they hold, they get exactly zero gradient.
    """
    active = gaussians.active
    means = jnp.where(active[:, None], gaussians.means, 0.0)
    log_scales = jnp.where(active, gaussians.log_scales, 0.0)
    logit_opacities = jnp.where(active, gaussians.logit_opacities, -20.0)
    rgb = jnp.where(active[:, None], gaussians.rgb, 0.0)
    points = means @ w2c[:3, :3].T + w2c[:3, 3]
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    in_front = z > near
    z_safe = jnp.where(in_front, z, 1.0)  # culled entries get harmless values (and zero gradient)
    fx, fy = intrinsics.fx, intrinsics.fy
    uv = jnp.stack([fx * x / z_safe + intrinsics.cx, fy * y / z_safe + intrinsics.cy], axis=-1)

    tan_x, tan_y = intrinsics.tan_half_fov()
    tx = jnp.clip(x / z_safe, -JACOBIAN_CLAMP * tan_x, JACOBIAN_CLAMP * tan_x)
    ty = jnp.clip(y / z_safe, -JACOBIAN_CLAMP * tan_y, JACOBIAN_CLAMP * tan_y)
    # J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]] with tx, ty the clamped X/Z, Y/Z.
    var = jnp.exp(2.0 * log_scales)
    inv_z2 = 1.0 / (z_safe * z_safe)
    cov_xx = var * fx * fx * inv_z2 * (1.0 + tx * tx) + DILATION
    cov_xy = var * fx * fy * inv_z2 * (tx * ty)
    cov_yy = var * fy * fy * inv_z2 * (1.0 + ty * ty) + DILATION
    det = cov_xx * cov_yy - cov_xy * cov_xy
    conic = jnp.stack([cov_yy / det, -cov_xy / det, cov_xx / det], axis=-1)
    opacity = jax.nn.sigmoid(logit_opacities)

    # Contribution region: d^T Sigma^-1 d <= r2 = 2 ln(255 o); its bounding box has half sizes r sqrt(Sigma_ii).
    r2 = jax.lax.stop_gradient(2.0 * jnp.log(jnp.maximum(opacity / ALPHA_MIN, 1.0)))
    cov_diag = jax.lax.stop_gradient(jnp.stack([cov_xx, cov_yy], axis=-1))
    extent = jnp.sqrt(r2[:, None] * cov_diag) * (1.0 + _EXTENT_SLACK_REL) + _EXTENT_SLACK_ABS
    centre = jax.lax.stop_gradient(uv)
    size = jnp.array([intrinsics.width - 1.0, intrinsics.height - 1.0])
    on_screen = jnp.all((centre + extent >= 0.0) & (centre - extent <= size), axis=-1)
    visible = active & in_front & (opacity >= ALPHA_MIN) & on_screen & jnp.all(jnp.isfinite(centre), -1)
    return Projected(uv, conic, z, opacity, rgb, extent, visible)


def straight_through_min(x: jax.Array, upper: float) -> jax.Array:
    """``min(x, upper)`` in the forward pass with the gradient of ``x`` (SplaTAM's alpha clamp, A.3)."""
    return x - jax.lax.stop_gradient(x - jnp.minimum(x, upper))


def gaussian_alpha(dx: jax.Array, dy: jax.Array, conic: jax.Array, opacity: jax.Array) -> jax.Array:
    """Per-pixel alpha = min(0.99, o exp(-(a dx^2 + 2 b dx dy + c dy^2) / 2)), straight-through at the clamp.

    ``dx, dy`` are pixel minus centre (px); ``conic`` is [..., 3]; shapes broadcast.
    """
    a, b, c = conic[..., 0], conic[..., 1], conic[..., 2]
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    return straight_through_min(opacity * jnp.exp(power), ALPHA_MAX)
