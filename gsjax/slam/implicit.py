"""The implicit derivative of a tracked pose with respect to the config: the pose is the fixed point of its loss.

At the tracker's result xi* (``exp(delta) @ w2c``, delta = 0), the loss's gradient in delta vanishes for every
config theta near the one it was tracked with, so ``d xi* / d theta = -H^-1 d2L / (d delta d theta)`` with ``H`` the
6 x 6 Hessian in delta. :func:`implicit_pose` returns the tracked pose unchanged in value and carrying that derivative
(one Newton step from it that is zero at theta: ``delta(theta) = -H^-1 (g(theta) - stop_gradient(g(theta)))``), so
``jax.grad`` and ``jax.jvp`` of anything computed from it differentiate the fixed point, not the iterations that
found it (:mod:`gsjax.slam.hypergrad`).

The tracking loss is a sum of absolute values, whose second derivative autodiff sees as zero (its curvature lies in
the kinks): the derivative is that of the loss with each |r| smoothed to the pseudo-Huber ``sqrt(r^2 + b^2) - b``
(|r| - b far from 0, r^2 / (2 b) near it), ``b`` the term's median absolute residual at the pose over the loss's
pixels, and ``H`` its Gauss-Newton Hessian ``J^T diag(lambda rho''(r)) J`` (positive semi-definite), damped by 1e-6 of
its mean eigenvalue. The Jacobian J [R, 6] is forward mode through the renderer (six JVPs; the XLA path).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gsjax.camera import perturb_left
from gsjax.slam.config import SlamConfig
from gsjax.slam.losses import TrackingTerms, masked_residuals
from gsjax.slam.tracking import TrackingProblem, tracking_objective

_DAMPING = 1e-6  # of H's mean eigenvalue: H is singular only in a degenerate view (a plane seen head on)


def _pseudo_huber(r: jax.Array, b: jax.Array) -> jax.Array:
    return jnp.sqrt(r * r + b * b) - b


def _scale(r: jax.Array) -> jax.Array:
    """b: the median |r| over the residuals the loss counts (nonzero), 1e-6 at least (no gradient)."""
    r = jax.lax.stop_gradient(jnp.abs(r.reshape(-1)))
    return jnp.maximum(jnp.nan_to_num(jnp.nanmedian(jnp.where(r > 0, r, jnp.nan)), nan=1.0), 1e-6)


def implicit_pose(problem: TrackingProblem, config: SlamConfig, w2c: jax.Array) -> jax.Array:
    """``w2c`` with the implicit derivative of the fixed point of ``problem``'s tracking loss.

    Args:
      problem: the frame's tracking problem (its map, frame and CB-KNN inputs; ``w2c_init`` is not read: a fixed
        point does not depend on where the tracker started).
      config: the SLAM config whose traced fields the derivative is taken with respect to (its raster on the XLA
        path: :meth:`gsjax.raster.RasterSettings.for_forward_mode`).
      w2c: [4, 4] the tracked world-to-camera pose (m), taken as the fixed point (no derivative of its own).

    Returns:
      [4, 4] ``w2c``'s value, whose derivative with respect to ``config`` and ``problem`` is
        ``-H^-1 d2L / (d delta d theta)`` through the left perturbation at ``w2c``.
    """
    w2c = jax.lax.stop_gradient(w2c)
    objective = tracking_objective(problem._replace(w2c_init=w2c), config)
    terms = TrackingTerms.of(config.tracking, objective.lambda_color)
    weights = (terms.lambda_depth, terms.lambda_color)

    def residuals(delta):
        depth, color = masked_residuals(objective.view_at(delta), problem.color, problem.depth, terms)
        return depth.reshape(-1), color.reshape(-1)

    zero = jnp.zeros(6, jnp.float32)
    at_zero = residuals(zero)
    scales = tuple(_scale(r) for r in at_zero)

    def surrogate(delta):
        return sum(w * jnp.sum(_pseudo_huber(r, b)) for w, r, b in zip(weights, residuals(delta), scales))

    jacobians = jax.lax.stop_gradient(jax.jacfwd(residuals)(zero))  # ([H W, 6], [H W 3, 6])
    curvature = [jax.lax.stop_gradient(w * b * b / (r * r + b * b) ** 1.5)
                 for w, r, b in zip(weights, at_zero, scales)]
    hessian = sum((j * c[:, None]).T @ j for j, c in zip(jacobians, curvature))
    hessian = hessian + (_DAMPING * jnp.trace(hessian) / 6.0 + 1e-12) * jnp.eye(6, dtype=hessian.dtype)
    gradient = jax.grad(surrogate)(zero)
    delta = -jnp.linalg.solve(jax.lax.stop_gradient(hessian), gradient - jax.lax.stop_gradient(gradient))
    return perturb_left(delta, w2c)
