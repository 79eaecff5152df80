"""Camera tracking (method_spec A.6): a fixed number of iterations on the pose tangent, map held fixed.

The pose is ``w2c = exp(delta) @ w2c_init`` (left perturbation, delta = (rho, phi)), so the optimisation is
unconstrained and exact on SE(3). Two optimisers:

* ``adam`` (SplaTAM parity): a fresh Adam per frame (:func:`pose_optimizer`, optax) with per-component step
  sizes (rho: ``lr_trans``, phi: ``lr_rot``) on the summed L1 loss; the lowest-loss pose seen is kept. An
  iteration whose gradient is not finite takes no step and is counted.
* ``lm``: Levenberg-Marquardt (optimistix) on the same masked residuals in least squares, with a forward-mode
  Jacobian through the renderer (6 columns); the result is kept only if its L1 tracking loss beats the start's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
import optimistix as optx

from gsjax.camera import Intrinsics, se3_exp
from gsjax.gaussians import Gaussians
from gsjax.slam.config import SlamConfig
from gsjax.slam.losses import tracking_loss, tracking_residuals
from gsjax.slam.optimizers import finite_only_if_loss_is, nonfinite_steps, pose_optimizer
from gsjax.slam.views import render_view


class TrackResult(NamedTuple):
    """w2c [4, 4] tracked pose; loss [] at that pose; nonfinite [] int32 skipped iterations."""

    w2c: jax.Array
    loss: jax.Array
    nonfinite: jax.Array


class TrackingObjective(NamedTuple):
    """The tracker's objective around ``w2c_init``: ``view_at(delta)`` renders at ``exp(delta) @ w2c_init``,
    ``loss(delta)`` is the tracking loss there (delta [6] = (rho m, phi rad)), ``lambda_color`` its colour weight."""

    view_at: Callable
    loss: Callable
    lambda_color: jax.Array


def tracking_objective(
    gaussians: Gaussians,
    color: jax.Array,
    depth: jax.Array,
    w2c_init: jax.Array,
    intrinsics: Intrinsics,
    config: SlamConfig,
    smooth,
    gamma,
) -> TrackingObjective:
    """What the tracker minimises for one frame (colour [H, W, 3], depth [H, W]) with the map held fixed;
    ``smooth`` selects CB-KNN renders (keyframes in ``paper`` mode, with the keyframe colour weight)."""
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

    return TrackingObjective(view_at, loss_fn, lambda_color)


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
    """Track one frame (colour [H, W, 3], depth [H, W]) from ``w2c_init``, minimising :func:`tracking_objective`."""
    objective = tracking_objective(gaussians, color, depth, w2c_init, intrinsics, config, smooth, gamma)
    if config.tracking.optimizer == "lm":
        return _track_lm(objective.view_at, objective.loss, w2c_init, config, objective.lambda_color, color, depth)
    return _track_adam(objective.loss, w2c_init, config)


def _track_adam(loss_fn, w2c_init, config: SlamConfig) -> TrackResult:
    cfg = config.tracking
    optimizer = pose_optimizer(config)
    tangent = lambda delta: jnp.concatenate([delta["rho"], delta["phi"]])  # noqa: E731
    delta0 = {"rho": jnp.zeros(3, jnp.float32), "phi": jnp.zeros(3, jnp.float32)}

    def iteration(carry, _):
        delta, opt_state, best_delta, best_loss = carry
        loss, grad = jax.value_and_grad(lambda d: loss_fn(tangent(d)))(delta)
        updates, opt_state = optimizer.update(finite_only_if_loss_is(loss, grad), opt_state)
        new_delta = optax.apply_updates(delta, updates)
        better = jnp.isfinite(loss) & (loss < best_loss)
        candidate = delta if cfg.best_pose == "pre_step" else new_delta
        best_delta = jax.tree.map(lambda c, b: jnp.where(better, c, b), candidate, best_delta)
        return (new_delta, opt_state, best_delta, jnp.where(better, loss, best_loss)), None

    init = (delta0, optimizer.init(delta0), delta0, jnp.float32(jnp.inf))
    (_, opt_state, best_delta, best_loss), _ = jax.lax.scan(iteration, init, None, length=cfg.iters)
    return TrackResult(se3_exp(tangent(best_delta)) @ w2c_init, best_loss, nonfinite_steps(opt_state))


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
