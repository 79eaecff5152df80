"""The implicit derivative of a tracked pose with respect to the config: the pose is the fixed point of its loss.

At the tracker's result xi* (``exp(delta) @ w2c``, delta = 0) the loss's gradient in delta vanishes for every config
theta near the one it was tracked with, so ``d xi* / d theta = -H^-1 d g / d theta`` with ``g`` the loss's gradient
and ``H`` its 6 x 6 Hessian in delta. A tracker stops near the fixed point, not on it (a tolerance, an iteration
count; in a flat valley of the loss, a plane seen head on, far from it), so :func:`implicit_pose` takes the
derivative of the Newton step's end, ``delta(theta) = -H(theta)^-1 g(theta)``: ``-H^-1 (dg - dH H^-1 g)``, the fixed
point's where ``g`` = 0, and unchanged, as the fixed point is, when every loss weight is scaled alike (without the
``dH`` term a common scale would move it by the whole Newton step). The pose keeps its value (``delta - stop_gradient(
delta)``), so ``jax.grad`` and ``jax.jvp`` of anything computed from it differentiate the fixed point, not the
iterations that found it (:mod:`gsjax.slam.hypergrad`).

The loss is the tracker's: ``lm`` minimises the weighted squares of the masked residuals (``H`` Gauss-Newton's
``J^T diag(2 lambda) J``); ``adam`` their weighted absolute values, whose second derivative autodiff sees as zero (its
curvature lies in the kinks), so there each |r| is smoothed to the pseudo-Huber ``sqrt(r^2 + b^2) - b`` (|r| - b far
from 0, r^2 / (2 b) near it), ``b`` the term's median absolute residual at the pose over the loss's pixels, ``H``
``J^T diag(lambda rho''(r)) J``. Both are positive semi-definite, damped by 1e-6 of their mean eigenvalue. The
Jacobian J [R, 6] is forward mode through the renderer (six tangents, the primal once; the XLA path).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gsjax.camera import perturb_left
from gsjax.slam.config import SlamConfig
from gsjax.slam.losses import TrackingTerms, masked_residuals
from gsjax.slam.tracking import TrackingProblem, tracking_objective

_DAMPING = 1e-6  # of H's mean eigenvalue: H is singular only in a degenerate view (a plane seen head on)


def _scale(r: jax.Array) -> jax.Array:
    """b: the median |r| over the residuals the loss counts (nonzero), 1e-6 at least (no gradient)."""
    r = jax.lax.stop_gradient(jnp.abs(r.reshape(-1)))
    return jnp.maximum(jnp.nan_to_num(jnp.nanmedian(jnp.where(r > 0, r, jnp.nan)), nan=1.0), 1e-6)


def _slope_and_curvature(r: jax.Array, squares: bool) -> tuple[jax.Array, jax.Array]:
    """(rho'(r), rho''(r)) per residual: of r^2 (``squares``), else of the pseudo-Huber at the median |r|."""
    if squares:
        return 2.0 * r, jnp.full_like(r, 2.0)
    b = _scale(r)
    root = jnp.sqrt(r * r + b * b)
    return r / root, b * b / root**3


def implicit_pose(problem: TrackingProblem, config: SlamConfig, w2c: jax.Array) -> jax.Array:
    """``w2c`` with the implicit derivative of the fixed point of ``problem``'s tracking loss.

    Args:
      problem: the frame's tracking problem (its map, frame and CB-KNN inputs; ``w2c_init`` is not read: a fixed
        point does not depend on where the tracker started).
      config: the SLAM config whose traced fields the derivative is taken with respect to (its raster on the XLA
        path: :meth:`gsjax.raster.RasterSettings.for_forward_mode`; ``tracking.optimizer`` picks the loss).
      w2c: [4, 4] the tracked world-to-camera pose (m), taken as the fixed point (no derivative of its own).

    Returns:
      [4, 4] ``w2c``'s value, whose derivative with respect to ``config`` and ``problem`` is the Newton step's end's,
        ``-H^-1 (dg - dH H^-1 g)``, through the left perturbation at ``w2c``.
    """
    w2c = jax.lax.stop_gradient(w2c)
    objective = tracking_objective(problem._replace(w2c_init=w2c), config)
    terms = TrackingTerms.of(config.tracking, objective.lambda_color)
    squares = config.tracking.optimizer == "lm"

    def residuals(delta):
        depth, color = masked_residuals(objective.view_at(delta), problem.color, problem.depth, terms)
        return depth.reshape(-1), color.reshape(-1)

    zero = jnp.zeros(6, jnp.float32)
    tangents = jax.vmap(lambda t: jax.jvp(residuals, (zero,), (t,)), out_axes=((None, None), (-1, -1)))
    at_zero, jacobians = tangents(jnp.eye(6, dtype=jnp.float32))  # ([H W], [H W 3]), ([H W, 6], [H W 3, 6])
    gradient, hessian = jnp.zeros(6, jnp.float32), jnp.zeros((6, 6), jnp.float32)
    for weight, r, j in zip((terms.lambda_depth, terms.lambda_color), at_zero, jacobians):
        slope, curvature = _slope_and_curvature(r, squares)
        gradient = gradient + weight * (j.T @ slope)
        hessian = hessian + weight * ((j * curvature[:, None]).T @ j)
    hessian = hessian + (_DAMPING * jnp.trace(hessian) / 6.0 + 1e-12) * jnp.eye(6, dtype=hessian.dtype)
    delta = -jnp.linalg.solve(hessian, gradient)
    return perturb_left(delta - jax.lax.stop_gradient(delta), w2c)
