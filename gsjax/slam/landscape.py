"""Tracking-loss landscapes: one frame's tracking loss (exactly the tracker's, :func:`tracking_objective`) and its
``jax.grad`` under left perturbations of a reference pose along the six pose axes, and the tracker's basin of
convergence on the same grid. Pure and vmapped over every grid point.

A perturbation of ``offset`` along an axis is ``w2c = exp(offset * unit * e_axis) @ w2c_ref`` with the tangent
ordered (rho, phi): ``tx ty tz`` translate the camera by ``offset`` cm along its own axes, ``rx ry rz`` rotate it by
``offset`` degrees about them. Gradients are d loss / d offset in the axis's unit (per cm, per degree).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import rotation_angle, se3_exp
from gsjax.slam.config import SlamConfig
from gsjax.slam.tracking import TrackingProblem, track, tracking_objective

# name -> (tangent component, unit, metres or radians per unit)
AXES = {
    "tx": (0, "cm", 0.01), "ty": (1, "cm", 0.01), "tz": (2, "cm", 0.01),
    "rx": (3, "deg", math.pi / 180), "ry": (4, "deg", math.pi / 180), "rz": (5, "deg", math.pi / 180),
}
CONVERGED_CM = 0.5
CONVERGED_DEG = 0.5


def directions(axes: tuple[str, ...]) -> jax.Array:
    """[A, 6] tangent per unit offset along each named axis."""
    rows = []
    for name in axes:
        component, _, scale = AXES[name]
        rows.append(jnp.zeros(6, jnp.float32).at[component].set(scale))
    return jnp.stack(rows)


class Landscape(NamedTuple):
    """Along each axis [A] at each offset [S]: loss [A, S], grad [A, S] (per unit offset), and where the tracker
    started there ends: error_cm [A, S] (translation of its pose from the reference), error_deg [A, S] (rotation)."""

    loss: jax.Array
    grad: jax.Array
    error_cm: jax.Array
    error_deg: jax.Array


def loss_and_grad(problem: TrackingProblem, config: SlamConfig, direction: jax.Array,
                  offsets: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The tracking loss [S] of ``problem`` at ``offsets`` [S] from its reference pose ``problem.w2c_init`` along
    ``direction`` [6] (tangent per unit offset), and its derivative with respect to the offset [S]."""
    objective = tracking_objective(problem, config)
    along = jax.value_and_grad(lambda offset: objective.loss(direction * offset))
    return jax.vmap(along)(offsets)


def tracked_from(problem: TrackingProblem, config: SlamConfig, direction: jax.Array,
                 offsets: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Run the tracker (its optimiser and iterations) from each perturbed pose; its final distance from the reference
    pose ``problem.w2c_init`` as (translation cm [S], rotation deg [S])."""
    w2c_ref = problem.w2c_init

    def one(offset):
        result = track(problem._replace(w2c_init=se3_exp(direction * offset) @ w2c_ref), config)
        relative = result.w2c @ jnp.linalg.inv(w2c_ref)  # the residual left perturbation
        return 100.0 * jnp.linalg.norm(relative[:3, 3]), jnp.degrees(rotation_angle(relative[:3, :3]))

    return jax.vmap(one)(offsets)


@jax.jit
def landscape(problem: TrackingProblem, config: SlamConfig, directions: jax.Array, offsets: jax.Array) -> Landscape:
    """:func:`loss_and_grad` and :func:`tracked_from` along every direction [A, 6] at every offset [A, S], around
    the reference pose ``problem.w2c_init``."""

    def axis(direction, grid):
        loss, grad = loss_and_grad(problem, config, direction, grid)
        error_cm, error_deg = tracked_from(problem, config, direction, grid)
        return Landscape(loss, grad, error_cm, error_deg)

    return jax.vmap(axis)(directions, offsets)


def basin_width(offsets: Iterable[float], converged: Iterable[bool]) -> float:
    """The largest |offset| r such that the tracker converged from every grid offset with |offset| <= r (0 when
    it fails from the grid point nearest the reference)."""
    width = 0.0
    points = sorted(zip((abs(float(o)) for o in offsets), (bool(c) for c in converged)))
    i = 0
    while i < len(points):
        radius = points[i][0]
        same = [c for r, c in points if r == radius]
        if not all(same):
            break
        width = radius
        i += len(same)
    return width
