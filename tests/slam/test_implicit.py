"""The implicit derivative of a tracked pose (gsjax.slam.implicit) against central differences of an independent
Gauss-Newton step, on a frame of the tiny room."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import perturb_left
from gsjax.config.paths import replace_path
from gsjax.slam import hypergrad as hg
from gsjax.slam.implicit import implicit_pose
from gsjax.slam.losses import TrackingTerms, tracking_residuals
from gsjax.slam.system import frame_input, sanitize_frame
from gsjax.slam.tracking import tracking_objective
from tests.support import tiny_slam as ts

FRAME = 4  # a keyframe (CB-KNN smooths its renders), tracked on a map of four frames


@pytest.fixture(scope="module")
def tracked():
    """(state before FRAME, FRAME, its recorded pose, the LM config as a hypergradient runs it)."""
    sequence = ts.tiny_sequence(ts.FRAMES)
    frames = [sequence.read_host(i) for i in range(FRAME + 1)]
    config = ts.replaced(ts.tiny_config("paper"), {"tracking.optimizer": "lm", "tracking.iters": 10,
                                                     "tracking.strided_iters": 0, "tracking.reselect_every": 1})
    window = hg.record(frames, config, sequence.intrinsics)
    at = lambda x: x[FRAME]  # noqa: E731
    state, frame = jax.tree.map(at, window.states), jax.tree.map(at, window.frames)
    hyper = hg.hypergradient_config(config, adjoint="implicit")
    return state, sanitize_frame(frame), window.outputs.w2c[FRAME], hyper, sequence.intrinsics


def _problem(state, frame, config, intrinsics):
    return frame_input(state, frame, config, intrinsics).problem


def test_the_implicit_pose_moves_as_the_gauss_newton_step_from_it_ends(tracked):
    """LM's loss is the weighted sum of squares: its Newton step is Gauss-Newton's, ``-(J^T J)^-1 J^T r`` on the
    square-root-weighted residuals, written here from the tracker's own residual vector; its end's central
    difference in a loss weight and in CB-KNN's alpha against the implicit pose's tangent. Measured: cosines 0.9998
    and 0.998, norm ratios 0.99 and 1.00; with H held (``-H^-1 dg`` alone) lambda_depth's cosine was 0.03."""
    state, frame, w2c, config, intrinsics = tracked

    def newton_end(name, value):
        cfg = replace_path(config, name, value)
        problem = _problem(state, frame, cfg, intrinsics)
        objective = tracking_objective(problem._replace(w2c_init=w2c), cfg)
        terms = TrackingTerms.of(cfg.tracking, objective.lambda_color)
        residuals = lambda d: tracking_residuals(objective.view_at(d), problem.color, problem.depth, terms)  # noqa: E731
        zero = jnp.zeros(6, jnp.float32)
        jacobian, r = jax.jacfwd(residuals)(zero), residuals(zero)
        return perturb_left(-jnp.linalg.solve(jacobian.T @ jacobian, jacobian.T @ r), w2c)

    def implicit(name, value):
        cfg = replace_path(config, name, value)
        return implicit_pose(_problem(state, frame, cfg, intrinsics), cfg, w2c)

    for name, value, step in (("tracking.lambda_depth", 1.0, 0.05), ("cbknn.params.alpha", 0.1, 0.01)):
        value = jnp.float32(value)
        pose, tangent = jax.jvp(lambda v, n=name: implicit(n, v), (value,), (jnp.float32(1.0),))
        np.testing.assert_array_equal(np.asarray(pose), np.asarray(w2c))  # the value is the recorded pose
        ends = [jax.jit(newton_end, static_argnums=0)(name, value + s * step) for s in (1, -1)]
        difference = np.asarray(ends[0] - ends[1])[:3] / (2 * step)
        tangent = np.asarray(tangent)[:3]
        assert np.abs(difference).max() > 1e-5, name  # the weight moves the pose
        cosine = np.sum(difference * tangent) / (np.linalg.norm(difference) * np.linalg.norm(tangent))
        assert cosine > 0.99, (name, difference, tangent)
        assert 0.9 < np.linalg.norm(tangent) / np.linalg.norm(difference) < 1.1, (name, difference, tangent)
