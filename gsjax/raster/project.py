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
      u: centre's column ``fx X/Z + cx`` (px).
      v: centre's row ``fy Y/Z + cy`` (px).
      conic_a: entry a of the inverse 2D covariance [[a, b], [b, c]] (1/px^2).
      conic_b: entry b of the inverse 2D covariance (1/px^2).
      conic_c: entry c of the inverse 2D covariance (1/px^2).
      depth: camera z (m), as given (not replaced behind the near plane).
      opacity: sigmoid(logit_opacity), in (0, 1).
      cov_xx: 2D covariance's xx entry (px^2), dilation included.
      cov_yy: 2D covariance's yy entry (px^2), dilation included.
      in_front: bool, z > near; where False the other fields hold harmless values.
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
    """EWA projection of isotropic Gaussians at camera-frame centres (x, y, z) (m), elementwise.

    Entries behind the near plane get harmless values (and zero gradient through z); ``in_front`` marks them.
    Differentiable w.r.t. every array argument.

    Args:
      x: camera-frame X of the centres (m), any shape (the arguments broadcast elementwise).
      y: camera-frame Y of the centres (m).
      z: camera-frame Z (depth) of the centres (m).
      log_scale: log of the standard deviation (m) of each isotropic Gaussian.
      logit_opacity: logit of each opacity.
      intrinsics: :class:`~gsjax.camera.Intrinsics` of the image (px).
      near: near plane (m); entries with ``z <= near`` are culled (``in_front`` False).
      dilation: added to the diagonal of the 2D covariance (px^2), 0.3 by default (``RasterSettings.dilation``).

    Returns:
      Screen-space Gaussians as a :class:`Splat`, every field of the arguments' broadcast shape.
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
    """World points given as coordinate arrays (m), elementwise -> camera-frame coordinate arrays.

    Args:
      x: world X (m), any shape (x, y and z broadcast elementwise).
      y: world Y (m).
      z: world Z (m).
      w2c: [4, 4] world-to-camera rigid transform (m); only its top 3 rows are read.

    Returns:
      The camera-frame coordinates ``R p + t`` as three arrays (x, y, z) (m) of the arguments' broadcast shape.
    """
    r, t = w2c[:3, :3], w2c[:3, 3]
    x_c, y_c, z_c = (r[i, 0] * x + r[i, 1] * y + r[i, 2] * z + t[i] for i in range(3))
    return x_c, y_c, z_c


def sanitized(gaussians: Gaussians) -> Gaussians:
    """Free slots replaced by harmless constants, so whatever they hold they get exactly zero gradient.

    Args:
      gaussians: :class:`~gsjax.gaussians.Gaussians` with N slots.

    Returns:
      Gaussians with the same N slots: active ones unchanged; free ones with means, log_scales and rgb 0 and
        logit_opacities -20 (opacity about 2e-9, below the 1/255 that contributes); ``active`` unchanged.
    """
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
    the differentiable path recomputes :func:`splat` per contributor slot).

    Args:
      gaussians: :class:`~gsjax.gaussians.Gaussians` with N slots (free slots are never visible).
      w2c: [4, 4] world-to-camera rigid transform (m).
      intrinsics: :class:`~gsjax.camera.Intrinsics` of the image (px).
      near: near plane (m); Gaussians with camera z <= near are not visible.
      dilation: added to the diagonal of the 2D covariance (px^2), 0.3 by default (``RasterSettings.dilation``).

    Returns:
      Screen-space Gaussians as a :class:`Projected` with N entries, under ``stop_gradient`` (no gradient flows
        through it).
    """
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
    """``min(x, upper)`` in the forward pass with the gradient of ``x`` (SplaTAM's alpha clamp, A.3).

    Args:
      x: the values, any shape.
      upper: the clamp.

    Returns:
      ``min(x, upper)``, of ``x``'s shape, whose gradient w.r.t. ``x`` is the identity (also above the clamp).
    """
    return x - jax.lax.stop_gradient(x - jnp.minimum(x, upper))


def gaussian_alpha(dx: jax.Array, dy: jax.Array, a: jax.Array, b: jax.Array, c: jax.Array,
                   opacity: jax.Array) -> jax.Array:
    """Per-pixel alpha = min(0.99, o exp(-(a dx^2 + 2 b dx dy + c dy^2) / 2)), straight-through at the clamp.

    No 1/255 threshold is applied here (callers test ``alpha >= ALPHA_MIN`` where they need it).

    Args:
      dx: pixel u minus centre u (px); all arguments broadcast elementwise.
      dy: pixel v minus centre v (px).
      a: conic entry a, the inverse 2D covariance [[a, b], [b, c]] (1/px^2).
      b: conic entry b (1/px^2).
      c: conic entry c (1/px^2).
      opacity: opacity o in (0, 1).

    Returns:
      alpha in [0, 0.99] of the arguments' broadcast shape.
    """
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    return straight_through_min(opacity * jnp.exp(power), ALPHA_MAX)
