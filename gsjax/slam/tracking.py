"""Camera tracking (method_spec A.6): a fixed number of iterations on the pose tangent, map held fixed.

The pose is ``w2c = exp(delta) @ w2c_init`` (left perturbation, delta = (rho, phi)), so the optimisation is
unconstrained and exact on SE(3). Two optimisers:

* ``adam`` (SplaTAM parity): a fresh Adam per frame with per-component step sizes (rho: ``lr_trans``, phi:
  ``lr_rot``) on the summed L1 loss; the lowest-loss pose seen is kept. An iteration whose loss or gradient is
  not finite takes no step and is counted.
* ``lm``: Levenberg-Marquardt (optimistix) on the same masked residuals in least squares, with a forward-mode
  Jacobian through the renderer (6 columns); the result is kept only if its L1 tracking loss beats the start's.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
import optimistix as optx

from gsjax.camera import Intrinsics, se3_exp
from gsjax.gaussians import Gaussians
from gsjax.slam.config import SlamConfig
from gsjax.slam.losses import tracking_loss, tracking_residuals
from gsjax.slam.views import render_view


class TrackResult(NamedTuple):
    """w2c [4, 4] tracked pose; loss [] at that pose; nonfinite [] int32 skipped iterations."""

    w2c: jax.Array
    loss: jax.Array
    nonfinite: jax.Array


def track(
    gaussians: Gaussians,
    color: jax.Array,
    depth: jax.Array,
    w2c_init: jax.Array,
    intrinsics: Intrinsics,
    config: SlamConfig,
    smooth,
    gamma,
) -> TrackResult:
    """Track one frame (colour [H, W, 3], depth [H, W]) from ``w2c_init``; ``smooth`` selects CB-KNN renders
    (keyframes in ``paper`` mode, with the keyframe colour weight)."""
    cfg = config.tracking
    gaussians = jax.lax.stop_gradient(gaussians)
    lambda_color = jnp.where(smooth, config.cbknn.lambda_color_keyframe, cfg.lambda_color) if (
        config.cbknn.smooth_renders and config.cbknn.track_keyframes
    ) else cfg.lambda_color
    smooth = jnp.asarray(smooth) & config.cbknn.track_keyframes

    def view_at(delta):
        return render_view(gaussians, se3_exp(delta) @ w2c_init, intrinsics, config, smooth, gamma)

    def loss_fn(delta):
        return tracking_loss(view_at(delta), color, depth, lambda_color, cfg.lambda_depth, cfg.sil_threshold,
                             cfg.normalized_depth)

    if cfg.optimizer == "lm":
        return _track_lm(view_at, loss_fn, w2c_init, config, lambda_color, color, depth)
    return _track_adam(loss_fn, w2c_init, config)


def _track_adam(loss_fn, w2c_init, config: SlamConfig) -> TrackResult:
    cfg = config.tracking
    step_size = jnp.concatenate([jnp.full(3, cfg.lr_trans), jnp.full(3, cfg.lr_rot)])
    adam = optax.scale_by_adam(b1=0.9, b2=0.999, eps=1e-8)
    delta0 = jnp.zeros(6, jnp.float32)

    # Exponential decay from 1 to lr_final_ratio over the iterations (constant when the ratio is 1).
    decay = jnp.power(cfg.lr_final_ratio, jnp.arange(cfg.iters, dtype=jnp.float32) / max(cfg.iters - 1, 1))

    def iteration(carry, factor):
        delta, opt_state, best_delta, best_loss, nonfinite = carry
        loss, grad = jax.value_and_grad(loss_fn)(delta)
        finite = jnp.isfinite(loss) & jnp.all(jnp.isfinite(grad))
        updates, new_opt_state = adam.update(grad, opt_state)
        new_delta = delta - factor * step_size * updates
        better = finite & (loss < best_loss)
        candidate = delta if cfg.best_pose == "pre_step" else new_delta
        best_delta = jnp.where(better, candidate, best_delta)
        best_loss = jnp.where(better, loss, best_loss)
        delta = jnp.where(finite, new_delta, delta)
        opt_state = jax.tree_util.tree_map(lambda new, old: jnp.where(finite, new, old), new_opt_state, opt_state)
        return (delta, opt_state, best_delta, best_loss, nonfinite + (~finite).astype(jnp.int32)), None

    init = (delta0, adam.init(delta0), delta0, jnp.float32(jnp.inf), jnp.int32(0))
    (_, _, best_delta, best_loss, nonfinite), _ = jax.lax.scan(iteration, init, decay)
    return TrackResult(se3_exp(best_delta) @ w2c_init, best_loss, nonfinite)


def _track_lm(view_at, loss_fn, w2c_init, config: SlamConfig, lambda_color, color, depth) -> TrackResult:
    cfg = config.tracking

    def residuals(delta, _):
        return tracking_residuals(view_at(delta), color, depth, lambda_color, cfg.lambda_depth, cfg.sil_threshold,
                                  cfg.normalized_depth)

    solver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)
    delta0 = jnp.zeros(6, jnp.float32)
    solution = optx.least_squares(residuals, solver, delta0, max_steps=cfg.iters, throw=False)
    delta = solution.value
    start_loss, end_loss = loss_fn(delta0), loss_fn(delta)
    usable = jnp.all(jnp.isfinite(delta)) & jnp.isfinite(end_loss)
    better = usable & (end_loss < start_loss)
    best = jnp.where(better, delta, delta0)
    return TrackResult(se3_exp(best) @ w2c_init, jnp.where(better, end_loss, start_loss), (~usable).astype(jnp.int32))
