"""The optax optimisers of tracking and mapping against a hand-written float64 Adam: per-group step sizes, the
exponential decay, skipped and counted non-finite steps, and SplaTAM's skip-at-prune."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from gsjax.slam.optimizers import finite_only_if_loss_is, map_optimizer, nonfinite_steps, pose_optimizer
from gsjax.slam.presets import preset
from tests.support.tiny_slam import replaced


def reference_adam(grads: list[dict], rates: dict, eps: float, skip=lambda i: False, decay=lambda i: 1.0):
    """Adam (b1 0.9, b2 0.999) in float64, one step per gradient; a step is skipped (no state change) when any
    gradient entry is not finite or ``skip(i)``; the step size of update i is ``rate * decay(k)`` with k the count
    of steps taken before it. Returns the parameter trajectory (params start at 0) and the skipped count."""
    b1, b2 = 0.9, 0.999
    params = {k: np.zeros_like(np.asarray(g, np.float64)) for k, g in grads[0].items()}
    m = {k: np.zeros_like(v) for k, v in params.items()}
    v = {k: np.zeros_like(p) for k, p in params.items()}
    taken, skipped, path = 0, 0, []
    for i, grad in enumerate(grads):
        finite = all(np.all(np.isfinite(np.asarray(g))) for g in grad.values())
        if not finite:
            skipped += 1
        if finite and not skip(i):
            taken += 1
            for k, g in grad.items():
                g = np.asarray(g, np.float64)
                m[k] = b1 * m[k] + (1 - b1) * g
                v[k] = b2 * v[k] + (1 - b2) * g * g
                m_hat, v_hat = m[k] / (1 - b1**taken), v[k] / (1 - b2**taken)
                params[k] = params[k] - rates[k] * decay(taken - 1) * m_hat / (np.sqrt(v_hat) + eps)
        path.append({k: p.copy() for k, p in params.items()})
    return path, skipped


def run(optimizer, grads: list[dict]):
    params = {k: jnp.zeros_like(jnp.asarray(g, jnp.float32)) for k, g in grads[0].items()}
    state = optimizer.init(params)
    path = []
    for grad in grads:
        updates, state = optimizer.update({k: jnp.asarray(g, jnp.float32) for k, g in grad.items()}, state)
        params = optax.apply_updates(params, updates)
        path.append(params)
    return path, int(nonfinite_steps(state))


def _pose_grads(rng, count, nan_at=()):
    grads = [{"rho": rng.normal(size=3), "phi": rng.normal(size=3) * 0.1} for _ in range(count)]
    for i in nan_at:
        grads[i]["phi"][1] = np.nan
    return grads


@pytest.mark.parametrize("iters, strided", [(8, 0), (3, 5)])
@pytest.mark.parametrize("ratio", [1.0, 0.1])
def test_pose_optimizer_is_adam_with_a_step_per_component_and_exponential_decay(ratio, iters, strided):
    """The step sizes decay over all 8 iterations, strided (tracking.strided_iters) or not."""
    config = replaced(preset("cpu"), {"tracking.iters": iters, "tracking.strided_iters": strided,
                                      "tracking.lr_final_ratio": ratio, "tracking.lr_trans": 0.002,
                                      "tracking.lr_rot": 0.0005})
    grads = _pose_grads(np.random.default_rng(0), 8, nan_at=(3,))
    got, skipped = run(pose_optimizer(config.tracking), grads)
    want, want_skipped = reference_adam(grads, {"rho": 2e-3, "phi": 5e-4}, eps=1e-8,
                                        decay=lambda k: ratio ** (k / 7))
    assert skipped == want_skipped == 1
    for g, w in zip(got, want):
        for k in ("rho", "phi"):
            np.testing.assert_allclose(np.asarray(g[k]), w[k], rtol=1e-5, atol=1e-8)  # float32 steps of ~1e-3
    np.testing.assert_array_equal(np.asarray(got[3]["phi"]), np.asarray(got[2]["phi"]))  # the NaN step: no move


@pytest.mark.parametrize("skip_at_prune", [False, True])
def test_map_optimizer_steps_each_group_and_skips_prune_iterations_when_asked(skip_at_prune):
    config = replaced(preset("cpu"), {"mapping.iters": 6, "mapping.strided_iters": 0, "mapping.prune_iters": (0, 4),
                                      "mapping.skip_step_at_prune": skip_at_prune})
    cfg = config.mapping
    rng = np.random.default_rng(1)
    grads = [dict(means=rng.normal(size=(4, 3)), rgb=rng.normal(size=(4, 3)), logit_opacities=rng.normal(size=4),
                  log_scales=rng.normal(size=4)) for _ in range(6)]
    grads[2]["rgb"][0, 0] = np.inf
    got, skipped = run(map_optimizer(config.mapping, jnp.float32(1e-3)), grads)
    rates = dict(means=1e-3, rgb=cfg.lr_rgb, logit_opacities=cfg.lr_opacity, log_scales=cfg.lr_scale)
    want, want_skipped = reference_adam(grads, rates, eps=1e-15, skip=lambda i: skip_at_prune and i in (0, 4))
    assert skipped == want_skipped == 1
    for g, w in zip(got, want):
        for k in rates:
            np.testing.assert_allclose(np.asarray(g[k]), w[k], rtol=1e-4, atol=1e-8)
    if skip_at_prune:
        np.testing.assert_array_equal(np.asarray(got[0]["means"]), np.zeros((4, 3)))


def test_a_non_finite_loss_skips_the_step_even_with_a_finite_gradient():
    grads = {"rho": jnp.ones(3), "phi": jnp.ones(3)}
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree.leaves(finite_only_if_loss_is(1.0, grads)))
    assert not any(bool(jnp.any(jnp.isfinite(g))) for g in jax.tree.leaves(finite_only_if_loss_is(jnp.nan, grads)))


def test_the_learning_rates_are_traced_so_a_batch_of_configs_is_one_program():
    config = preset("cpu")
    doubled = replaced(config, {"tracking.lr_trans": 2 * config.tracking.lr_trans})
    batch = jax.tree.map(lambda a, b: jnp.stack([jnp.asarray(a), jnp.asarray(b)]), config, doubled)

    def first_update(cfg):
        optimizer = pose_optimizer(cfg.tracking)
        delta = {"rho": jnp.zeros(3), "phi": jnp.zeros(3)}
        updates, _ = optimizer.update({"rho": jnp.ones(3), "phi": jnp.ones(3)}, optimizer.init(delta))
        return updates["rho"]

    rho = jax.vmap(first_update)(batch)
    np.testing.assert_allclose(np.asarray(rho[1]), 2 * np.asarray(rho[0]), rtol=1e-6)
