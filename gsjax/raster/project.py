"""Projection of isotropic 3D Gaussians to screen-space 2D Gaussians (EWA splatting), differentiable.

Semantics are SplaTAM's rasterizer (method_spec A.3) with DESIGN 2.2.1's pixel convention (centres at integers):

* camera point ``x = R mu + t``; culled when ``z <= near``;
* centre ``u = fx X/Z + cx``, ``v = fy Y/Z + cy`` (px);
* ``Sigma2D = s^2 J J^T + 0.3 I`` (px^2; the dilation is ``RasterSettings.dilation``), with the perspective
  Jacobian J evaluated at X/Z, Y/Z clamped to ``+-1.3 tan(fov/2)`` (3DGS); isotropic 3D covariance so the
  rotation drops out;
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
DILATION = 0.3  # px^2 added to the 2D covariance (low-pass filter), the default of RasterSettings.dilation
JACOBIAN_CLAMP = 1.3  # x/z, y/z clamp in units of tan(fov/2)
# Relative + absolute slack (px) on the screen extent: binning must never miss a pixel that float32 rounding in
# the per-pixel alpha test would still accept; extra candidates are harmless (the alpha test is exact).
_EXTENT_SLACK_REL = 1e-3
_EXTENT_SLACK_ABS = 1e-2


class Splat(NamedTuple):
    """Screen-space Gaussians, elementwise over any batch shape [...] (one array per quantity: on XLA:CPU separate
    arrays vectorise far better than a packed minor axis).

    Attributes:
      u, v: centre (px); conic_a, conic_b, conic_c: inverse 2D covariance [[a, b], [b, c]] (1/px^2);
      depth: camera z (m); opacity: sigmoid(logit); cov_xx, cov_yy: diagonal of the 2D covariance (px^2);
      in_front: bool, z > near.
    """

    u: jax.Array
    v: jax.Array
    conic_a: jax.Array
    conic_b: jax.Array
    conic_c: jax.Array
    depth: jax.Array
    opacity: jax.Array
    cov_xx: jax.Array
    cov_yy: jax.Array
    in_front: jax.Array


def splat(x: jax.Array, y: jax.Array, z: jax.Array, log_scale: jax.Array, logit_opacity: jax.Array,
          intrinsics: Intrinsics, near: float | jax.Array, dilation: float | jax.Array = DILATION) -> Splat:
    """EWA projection of isotropic Gaussians at camera-frame centres (x, y, z) (m), elementwise; ``dilation``
    (px^2) is added to the 2D covariance.

    Entries behind the near plane get harmless values (and zero gradient through z); ``in_front`` marks them.
    """
    in_front = z > near
    z_safe = jnp.where(in_front, z, 1.0)
    fx, fy = intrinsics.fx, intrinsics.fy
    x_over_z, y_over_z = x / z_safe, y / z_safe
    tan_x, tan_y = intrinsics.tan_half_fov()
    tx = jnp.clip(x_over_z, -JACOBIAN_CLAMP * tan_x, JACOBIAN_CLAMP * tan_x)
    ty = jnp.clip(y_over_z, -JACOBIAN_CLAMP * tan_y, JACOBIAN_CLAMP * tan_y)
    # J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]] with tx, ty the clamped X/Z, Y/Z; Sigma3D = s^2 I.
    var_over_z2 = jnp.exp(2.0 * log_scale) / (z_safe * z_safe)
    cov_xx = var_over_z2 * fx * fx * (1.0 + tx * tx) + dilation
    cov_xy = var_over_z2 * fx * fy * (tx * ty)
    cov_yy = var_over_z2 * fy * fy * (1.0 + ty * ty) + dilation
    inv_det = 1.0 / (cov_xx * cov_yy - cov_xy * cov_xy)
    return Splat(
        u=fx * x_over_z + intrinsics.cx,
        v=fy * y_over_z + intrinsics.cy,
        conic_a=cov_yy * inv_det,
        conic_b=-cov_xy * inv_det,
        conic_c=cov_xx * inv_det,
        depth=z,
        opacity=jax.nn.sigmoid(logit_opacity),
        cov_xx=cov_xx,
        cov_yy=cov_yy,
        in_front=in_front,
    )


def to_camera(x: jax.Array, y: jax.Array, z: jax.Array, w2c: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """World points given as coordinate arrays (m), elementwise -> camera-frame coordinate arrays."""
    r, t = w2c[:3, :3], w2c[:3, 3]
    x_c, y_c, z_c = (r[i, 0] * x + r[i, 1] * y + r[i, 2] * z + t[i] for i in range(3))
    return x_c, y_c, z_c


def sanitized(gaussians: Gaussians) -> Gaussians:
    """Free slots replaced by harmless constants, so whatever they hold they get exactly zero gradient."""
    active = gaussians.active
    return Gaussians(
        means=jnp.where(active[:, None], gaussians.means, 0.0),
        log_scales=jnp.where(active, gaussians.log_scales, 0.0),
        logit_opacities=jnp.where(active, gaussians.logit_opacities, -20.0),
        rgb=jnp.where(active[:, None], gaussians.rgb, 0.0),
        active=active,
    )


class Projected(NamedTuple):
    """Screen-space Gaussians for binning and selection, N entries (no gradient is needed through them).

    Attributes:
      uv: [N, 2] centre (u, v) in px.
      conic: [N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]] (1/px^2).
      depth: [N] camera z (m).
      opacity: [N] sigmoid(logit_opacity).
      extent: [N, 2] half-width/height (px) of the box holding every pixel with alpha >= 1/255.
      visible: [N] bool: active, in front of the near plane, able to reach alpha >= 1/255, box overlaps the image.
    """

    uv: jax.Array
    conic: jax.Array
    depth: jax.Array
    opacity: jax.Array
    extent: jax.Array
    visible: jax.Array


def project(gaussians: Gaussians, w2c: jax.Array, intrinsics: Intrinsics, near: float | jax.Array,
            dilation: float | jax.Array = DILATION) -> Projected:
    """Project Gaussians [N] with world-to-camera ``w2c`` [4, 4] into the image of ``intrinsics`` (values only:
    the differentiable path recomputes :func:`splat` per contributor slot)."""
    g = sanitized(jax.lax.stop_gradient(gaussians))
    x, y, z = to_camera(g.means[:, 0], g.means[:, 1], g.means[:, 2], jax.lax.stop_gradient(w2c))
    s = splat(x, y, z, g.log_scales, g.logit_opacities, intrinsics, near, dilation)
    uv = jnp.stack([s.u, s.v], axis=-1)
    # Contribution region: d^T Sigma^-1 d <= r2 = 2 ln(255 o); its bounding box has half sizes r sqrt(Sigma_ii).
    r2 = 2.0 * jnp.log(jnp.maximum(s.opacity / ALPHA_MIN, 1.0))
    cov_diag = jnp.stack([s.cov_xx, s.cov_yy], axis=-1)
    extent = jnp.sqrt(r2[:, None] * cov_diag) * (1.0 + _EXTENT_SLACK_REL) + _EXTENT_SLACK_ABS
    size = jnp.array([intrinsics.width - 1.0, intrinsics.height - 1.0])
    on_screen = jnp.all((uv + extent >= 0.0) & (uv - extent <= size), axis=-1)
    visible = g.active & s.in_front & (s.opacity >= ALPHA_MIN) & on_screen & jnp.all(jnp.isfinite(uv), -1)
    conic = jnp.stack([s.conic_a, s.conic_b, s.conic_c], axis=-1)
    return Projected(uv, conic, s.depth, s.opacity, extent, visible)


def straight_through_min(x: jax.Array, upper: float) -> jax.Array:
    """``min(x, upper)`` in the forward pass with the gradient of ``x`` (SplaTAM's alpha clamp, A.3)."""
    return x - jax.lax.stop_gradient(x - jnp.minimum(x, upper))


def gaussian_alpha(dx: jax.Array, dy: jax.Array, a: jax.Array, b: jax.Array, c: jax.Array,
                   opacity: jax.Array) -> jax.Array:
    """Per-pixel alpha = min(0.99, o exp(-(a dx^2 + 2 b dx dy + c dy^2) / 2)), straight-through at the clamp.

    ``dx, dy`` are pixel minus centre (px); (a, b, c) the conic; all arguments broadcast elementwise.
    """
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    return straight_through_min(opacity * jnp.exp(power), ALPHA_MAX)
