"""Loops with a traced count under a static cap (gsjax.slam.loops): both forms run the same iterations, the scan form
is differentiable in reverse mode, one program serves every count, and configs derive and pin their caps."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.config.text import config_from_dict, config_to_dict
from gsjax.slam.loops import LoopCaps, cap_for, common_caps, counted_scan
from gsjax.slam.presets import preset, with_cbknn_mode
from tests.support.tiny_slam import replaced


def _descend(lr, count, cap, differentiable, running=None):
    """Gradient descent on (x - 3)^2 from 0 with step ``lr``, ``count`` iterations; the iterations are recorded."""
    def body(i, carry):
        x, seen = carry
        return x - lr * 2.0 * (x - 3.0), seen.at[i].set(1)

    return counted_scan(body, (jnp.float32(0.0), jnp.zeros(cap, jnp.int32)), count, cap, running, differentiable)


@pytest.mark.parametrize("differentiable", [False, True])
def test_a_counted_loop_runs_count_iterations_within_its_cap_and_stops_early_when_told(differentiable):
    run = jax.jit(lambda lr, count: _descend(lr, count, 8, differentiable))
    for count in (0, 3, 8, 11):
        x, seen = run(jnp.float32(0.1), count)
        ran = min(count, 8)
        np.testing.assert_allclose(float(x), 3.0 * (1 - 0.8 ** ran), rtol=1e-6)  # x_k = 3 (1 - 0.8^k)
        assert np.asarray(seen).tolist() == [1] * ran + [0] * (8 - ran)
    assert run._cache_size() == 1  # the count is traced: one program
    x, seen = jax.jit(lambda: _descend(0.1, 8, 8, differentiable, running=lambda c: c[0] < 1.5))()
    assert np.asarray(seen).tolist() == [1, 1, 1, 1, 0, 0, 0, 0]  # x passes 1.5 after the 4th iteration
    assert counted_scan(lambda i, c: c + 1, jnp.int32(5), 3, 0) == 5  # cap 0: no loop


def test_the_differentiable_form_has_the_gradient_of_the_iterations_run():
    """d x_count / d lr by reverse mode through the scan form against a central finite difference of the loop, and
    against the closed form x_k = 3 (1 - (1 - 2 lr)^k)."""
    def final(lr):
        return _descend(lr, jnp.int32(5), 16, True)[0]

    lr = 0.05
    grad = float(jax.grad(final)(jnp.float32(lr)))
    h = 1e-3
    finite = (float(final(jnp.float32(lr + h))) - float(final(jnp.float32(lr - h)))) / (2 * h)
    exact = 3.0 * 5 * 2 * (1 - 2 * lr) ** 4
    np.testing.assert_allclose(grad, exact, rtol=1e-4)
    np.testing.assert_allclose(finite, exact, rtol=1e-3)
    with pytest.raises(ValueError, match="Reverse-mode differentiation does not work for lax.while_loop"):
        jax.grad(lambda lr: _descend(lr, jnp.int32(5), 16, False)[0])(jnp.float32(lr))


def test_caps_are_powers_of_two_from_32_and_zero_compiles_no_loop():
    assert [cap_for(c) for c in (0, 1, 10, 32, 33, 40, 200)] == [0, 32, 32, 32, 64, 64, 256]


def test_a_config_derives_its_caps_from_its_counts_and_a_pinned_cap_is_kept():
    cpu = preset("cpu")
    assert cpu.caps == LoopCaps(tracking=32, tracking_strided=32, mapping=32, mapping_reselect=True)
    # Derived anew from the counts, whatever the config was built from (no history).
    assert replaced(preset("tum"), {"tracking.iters": 10}).caps.tracking == 32
    assert config_from_dict(config_to_dict(cpu)) == cpu
    # A sweep pins common caps: kept while they hold the counts, raised where a count outgrows them.
    pinned = cpu.with_caps(dataclasses.replace(cpu.caps, tracking=128))
    assert pinned.caps.tracking == 128 and pinned.caps.pinned
    assert replaced(pinned, {"tracking.iters": 100}).caps.tracking == 128
    assert replaced(pinned, {"tracking.iters": 300}).caps.tracking == 512
    # Stacked configs (a batch) derive the caps of their largest counts.
    from gsjax.slam.driver import stack_trees

    a, b = (replaced(cpu, {"mapping.iters": n}) for n in (20, 40))
    common = b.caps
    stacked = stack_trees([a.with_caps(common), b.with_caps(common)])
    assert stacked.caps.mapping == 64


def test_a_config_draws_noise_only_where_a_level_is_above_zero():
    cpu = preset("cpu")
    assert not cpu.caps.noise
    for field in ("map_means_cm", "map_rgb", "depth_cm", "persistent_means_cm", "persistent_rgb"):
        assert replaced(cpu, {f"noise.{field}": 0.5}).caps.noise, field
    assert not replaced(cpu, {"noise.persistent_frame": 3}).caps.noise  # a frame is no level
    # A sweep's common caps hold the noisy configs' draws; the zero-level config runs them (drawing nothing).
    zero, noisy = (replaced(cpu, {"noise.depth_cm": v}) for v in (0.0, 1.0))
    assert common_caps([zero, noisy]).noise and zero.with_caps(common_caps([zero, noisy])).caps.noise


def test_cbknn_correction_is_compiled_in_for_paper_only_and_a_common_cap_holds_it():
    off = preset("cpu")
    parity, paper = with_cbknn_mode(off, "code_parity"), with_cbknn_mode(off, "paper")
    assert not off.caps.smoothing and not parity.caps.smoothing and paper.caps.smoothing
    assert common_caps([off, paper]).smoothing and not common_caps([off, parity]).smoothing
    # caps pinned without the correction are raised when the mode becomes paper
    pinned = off.with_caps(off.caps)
    assert replaced(pinned, {"cbknn.mode": "paper"}).caps.smoothing
    assert not replaced(pinned, {"cbknn.mode": "code_parity"}).caps.smoothing
