"""The optimisers of tracking and mapping, from optax combinators: SplaTAM's fresh-per-frame Adam, a step size per
parameter group (``optax.multi_transform``), skipped and counted non-finite steps (``optax.apply_if_finite``)."""

from __future__ import annotations

from typing import TypeVar

import jax
import jax.numpy as jnp
import optax

from gsjax.slam.config import MappingConfig, TrackingConfig

_Grads = TypeVar("_Grads")

MAP_PARAMS = ("means", "rgb", "logit_opacities", "log_scales")  # the Gaussians' fields mapping optimises
_NEVER_GIVE_UP = 2**30  # apply_if_finite's limit of consecutive skipped steps: above any frame's iterations
# Adam's eps_root in a program differentiated through its steps (hypergradients): sqrt(v) has an infinite derivative
# at v = 0 (a parameter whose gradient is exactly 0, e.g. a Gaussian no view sees), which made 0 * inf = NaN; below
# any float32 v that is not 0, so the steps' values are the run's.
DIFFERENTIABLE_EPS_ROOT = 1e-30


def finite_only_if_loss_is(loss: jax.Array, grads: _Grads) -> _Grads:
    """``grads`` unchanged where ``loss`` is finite, else NaN everywhere.

    A step whose loss is not finite is then skipped like one whose gradient is not (``apply_if_finite`` looks at
    the gradient only).

    Args:
      loss: [] the loss the gradients are of.
      grads: the gradients, a pytree of arrays.

    Returns:
      ``grads``' structure and shapes, every leaf NaN when ``loss`` is not finite.
    """
    return jax.tree.map(lambda g: jnp.where(jnp.isfinite(loss), g, jnp.nan), grads)


def nonfinite_steps(opt_state: optax.OptState) -> jax.Array:
    """The steps that ``apply_if_finite`` skipped so far.

    Args:
      opt_state: the state of an optimizer made by :func:`pose_optimizer` or :func:`map_optimizer`.

    Returns:
      [] int32 the number of skipped steps (``total_notfinite``).
    """
    return optax.tree_utils.tree_get(opt_state, "total_notfinite")


def pose_optimizer(tracking: TrackingConfig, differentiable: bool = False) -> optax.GradientTransformation:
    """SplaTAM's per-frame Adam on the pose tangent ``{"rho": [3], "phi": [3]}``.

    Step ``lr_trans`` on rho and ``lr_rot`` on phi, each decaying exponentially to ``lr_final_ratio`` of itself
    over the frame's iterations (coarse, strided and full); an update whose gradient is not finite is skipped and
    counted (``total_notfinite`` in the state, :func:`nonfinite_steps`).

    Args:
      tracking: the tracking config (its iteration counts, ``lr_trans``, ``lr_rot`` and ``lr_final_ratio``).
      differentiable: reverse mode will pass its steps (:data:`DIFFERENTIABLE_EPS_ROOT`).

    Returns:
      The optax optimizer over ``{"rho", "phi"}``.
    """
    cfg = tracking
    total = cfg.coarse.iters + cfg.strided_iters + cfg.iters  # one Adam over every iteration of the frame (traced)

    def adam(lr):
        decay = lambda count: lr * cfg.lr_final_ratio ** (count / jnp.maximum(total - 1, 1))  # noqa: E731
        return optax.chain(optax.scale_by_adam(b1=0.9, b2=0.999, eps=1e-8,
                                               eps_root=DIFFERENTIABLE_EPS_ROOT if differentiable else 0.0),
                           optax.scale_by_learning_rate(decay))

    groups = optax.multi_transform({"rho": adam(cfg.lr_trans), "phi": adam(cfg.lr_rot)}, {"rho": "rho", "phi": "phi"})
    return optax.apply_if_finite(groups, max_consecutive_errors=_NEVER_GIVE_UP)  # never gives up within a frame


def map_optimizer(mapping: MappingConfig, lr_means: float | jax.Array,
                  differentiable: bool = False) -> optax.GradientTransformation:
    """SplaTAM's per-frame Adam (eps 1e-15) on the map parameters, a step size per parameter group.

    The parameters are ``{name: array}`` for the names of :data:`MAP_PARAMS`. An update whose gradient is not finite
    is skipped and counted (``total_notfinite``, :func:`nonfinite_steps`); with ``mapping.skip_step_at_prune`` the
    iterations in ``mapping.prune_iters`` take no step (SplaTAM's quirk).

    Args:
      mapping: the mapping config (its iteration counts, ``lr_rgb``, ``lr_opacity``, ``lr_scale``,
        ``prune_iters`` and ``skip_step_at_prune``).
      lr_means: the step size of the means (m; may be traced).
      differentiable: reverse mode will pass its steps (:data:`DIFFERENTIABLE_EPS_ROOT`).

    Returns:
      The optax optimizer over ``{"means", "rgb", "logit_opacities", "log_scales"}``.
    """
    cfg = mapping
    rates = dict(means=lr_means, rgb=cfg.lr_rgb, logit_opacities=cfg.lr_opacity, log_scales=cfg.lr_scale)
    eps_root = DIFFERENTIABLE_EPS_ROOT if differentiable else 0.0
    groups = {name: optax.chain(optax.scale_by_adam(b1=0.9, b2=0.999, eps=1e-15, eps_root=eps_root),
                                optax.scale_by_learning_rate(lr))
              for name, lr in rates.items()}
    optimizer = optax.apply_if_finite(optax.multi_transform(groups, {name: name for name in MAP_PARAMS}),
                                      max_consecutive_errors=_NEVER_GIVE_UP)
    if cfg.skip_step_at_prune and cfg.prune_iters:
        prune_iters = jnp.asarray(cfg.prune_iters, jnp.int32)
        optimizer = optax.transforms.conditionally_mask(optimizer, lambda step: ~jnp.isin(step, prune_iters))
    return optimizer
