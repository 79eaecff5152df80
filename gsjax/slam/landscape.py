"""Tracking-loss landscapes: one frame's tracking loss (exactly the tracker's, :func:`tracking_objective`) and its
``jax.grad`` under left perturbations of a reference pose along the six pose axes, and the tracker's basin of
convergence on the same grid, along single axes (1-D) and over the plane of two axes (2-D). Pure; vmapped over the
grid's points (in batches, :func:`map_batched`), one compiled program for the axes and their plane.

A perturbation of ``offset`` along an axis is ``w2c = exp(offset * unit * e_axis) @ w2c_ref`` with the tangent
ordered (rho, phi): ``tx ty tz`` translate the camera by ``offset`` cm along its own axes, ``rx ry rz`` rotate it by
``offset`` degrees about them; a 2-D grid point (a, b) is ``exp(a * unit_a * e_a + b * unit_b * e_b) @ w2c_ref``.
Gradients are d loss / d offset in the axis's unit (per cm, per degree).

Where the tracker started at a grid point ends is measured twice: from the reference pose, and from the tracker's
own fixed point p* (where it ends when started at the reference itself). With a map that is not exact, p* is off the
reference (its bias); the basin against p* is the one the optimiser has, the basin against the reference adds the
bias to it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import perturb_left, rotation_angle, se3_inverse
from gsjax.slam.config import SlamConfig
from gsjax.slam.tracking import TrackingProblem, track, tracking_objective

if TYPE_CHECKING:
    import numpy.typing as npt

# name -> (tangent component, unit, metres or radians per unit)
AXES = {
    "tx": (0, "cm", 0.01), "ty": (1, "cm", 0.01), "tz": (2, "cm", 0.01),
    "rx": (3, "deg", math.pi / 180), "ry": (4, "deg", math.pi / 180), "rz": (5, "deg", math.pi / 180),
}
CONVERGED_CM = 0.5
CONVERGED_DEG = 0.5


def directions(axes: tuple[str, ...]) -> jax.Array:
    """The tangent per unit offset along each named axis.

    Args:
      axes: the A axis names, each one of ``tx ty tz rx ry rz``.

    Returns:
      [A, 6] float32 tangents (rho m, phi rad): 0.01 m per cm in the translation component of a ``t`` axis,
        pi / 180 rad per degree in the rotation component of an ``r`` axis, 0 elsewhere.
    """
    rows = []
    for name in axes:
        component, _, scale = AXES[name]
        rows.append(jnp.zeros(6, jnp.float32).at[component].set(scale))
    return jnp.stack(rows)


class Landscape2d(NamedTuple):
    """The landscape over the plane of two axes, at grid point [i, j] = (``offsets[0][i]``, ``offsets[1][j]``).

    Attributes:
      loss: [S, S] the tracking loss.
      grad: [S, S, 2] d loss / d offset along each of the two axes, per unit of that axis (per cm, per degree).
      final_w2c: [S, S, 4, 4] the tracker's final world-to-camera pose when started at the grid point.
      error_cm: [S, S] translation (cm) of that final pose from the reference pose.
      error_deg: [S, S] rotation (deg) of that final pose from the reference pose.
      fixed_error_cm: [S, S] translation (cm) of that final pose from the fixed point.
      fixed_error_deg: [S, S] rotation (deg) of that final pose from the fixed point.
    """

    loss: jax.Array
    grad: jax.Array
    final_w2c: jax.Array
    error_cm: jax.Array
    error_deg: jax.Array
    fixed_error_cm: jax.Array
    fixed_error_deg: jax.Array


class Landscape(NamedTuple):
    """The landscape along each axis [A] at each offset [S], and where the tracker started there ends.

    Attributes:
      loss: [A, S] the tracking loss.
      grad: [A, S] d loss / d offset, per unit of the axis (per cm, per degree).
      error_cm: [A, S] translation (cm) of the tracker's final pose from the reference pose.
      error_deg: [A, S] rotation (deg) of the tracker's final pose from the reference pose.
      fixed_error_cm: [A, S] translation (cm) of the tracker's final pose from the fixed point.
      fixed_error_deg: [A, S] rotation (deg) of the tracker's final pose from the fixed point.
      final_w2c: [A, S, 4, 4] the tracker's final world-to-camera pose.
      fixed_w2c: [4, 4] the fixed point: where the tracker started at the reference pose ends.
      plane: the 2-D landscape of the two axes (:class:`Landscape2d`) when asked for, else None.
    """

    loss: jax.Array
    grad: jax.Array
    error_cm: jax.Array
    error_deg: jax.Array
    fixed_error_cm: jax.Array
    fixed_error_deg: jax.Array
    final_w2c: jax.Array
    fixed_w2c: jax.Array
    plane: Landscape2d | None = None


def loss_and_grad(problem: TrackingProblem, config: SlamConfig, direction: jax.Array,
                  offsets: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The tracking loss of ``problem`` at ``offsets`` from its reference pose ``problem.w2c_init`` along
    ``direction``, and its derivative with respect to the offset.

    Args:
      problem: the frame's tracking problem; its ``w2c_init`` is the reference pose.
      config: the SLAM config (the tracking loss's settings).
      direction: [6] tangent per unit offset (a row of :func:`directions`).
      offsets: [S] offsets along ``direction``, in the axis's unit (cm, deg).

    Returns:
      loss: [S] the tracking loss at each offset.
      grad: [S] d loss / d offset, per unit offset.
    """
    objective = tracking_objective(problem, config)
    along = jax.value_and_grad(lambda offset: objective.loss(direction * offset))
    return jax.vmap(along)(offsets)


def pose_error(w2c: jax.Array, w2c_ref: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Distance of poses ``w2c`` from ``w2c_ref``, as the residual left perturbation ``w2c @ inverse(w2c_ref)``.

    Args:
      w2c: [..., 4, 4] world-to-camera poses.
      w2c_ref: [4, 4] the reference world-to-camera pose.

    Returns:
      error_cm: [...] the residual's translation (cm).
      error_deg: [...] the residual's rotation angle (deg).
    """
    relative = w2c @ se3_inverse(w2c_ref)
    angle = jnp.vectorize(rotation_angle, signature="(3,3)->()")(relative[..., :3, :3])
    return 100.0 * jnp.linalg.norm(relative[..., :3, 3], axis=-1), jnp.degrees(angle)


def tracked_from(problem: TrackingProblem, config: SlamConfig, direction: jax.Array,
                 offsets: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Run the tracker (its optimiser and iterations) from each perturbed pose; its final distance from the reference
    pose ``problem.w2c_init``.

    Args:
      problem: the frame's tracking problem; its ``w2c_init`` is the reference pose.
      config: the SLAM config (the tracking loss, optimiser and iterations).
      direction: [6] tangent per unit offset (a row of :func:`directions`).
      offsets: [S] offsets along ``direction`` to start from, in the axis's unit (cm, deg).

    Returns:
      error_cm: [S] translation (cm) of each final pose from the reference pose (:func:`pose_error`).
      error_deg: [S] rotation (deg) of each final pose from the reference pose.
    """
    w2c_ref = problem.w2c_init
    start = lambda offset: perturb_left(direction * offset, w2c_ref)  # noqa: E731
    final = jax.vmap(lambda offset: track(problem._replace(w2c_init=start(offset)), config).w2c)(offsets)
    return pose_error(final, w2c_ref)


def map_batched(fn, xs: jax.Array, batch: int | None):
    """``fn`` over the leading axis of ``xs``, ``batch`` at a time (``jax.vmap`` within a batch, batches in
    sequence; all at once when None). The batches are as even as their count allows, the last one padded with
    copies of ``xs[-1]`` (under one per batch), so the program holds ``fn`` once. The result is ``fn``'s outputs,
    each leaf with a leading axis of N.

    Args:
      fn (Callable): the function of one element ``xs[i]``.
      xs: [N, ...] the inputs.
      batch: elements evaluated at a time (values below 1 count as 1); None: all N at once.
    """
    n = xs.shape[0]
    batches = 1 if batch is None else -(-n // max(1, batch))
    batch = -(-n // batches)
    padded = jnp.concatenate([xs, jnp.repeat(xs[-1:], batches * batch - n, axis=0)])
    return jax.tree.map(lambda v: v[:n], jax.lax.map(fn, padded, batch_size=batch))


def _evaluate(problem: TrackingProblem, config: SlamConfig, tangents: jax.Array, batch: int | None):
    """At every tangent [N, 6] around ``problem.w2c_init``: the loss [N], its gradient [N, 6] (per m and rad) and the
    tracker's final pose from there [N, 4, 4]; and the fixed point [4, 4], the tracker's from the reference itself
    (one run more in the same batches, :func:`map_batched`)."""
    objective = tracking_objective(problem, config)

    def one(tangent):
        loss, grad = jax.value_and_grad(objective.loss)(tangent)
        start = perturb_left(tangent, problem.w2c_init)
        return loss, grad, track(problem._replace(w2c_init=start), config).w2c

    loss, grad, final = map_batched(one, jnp.concatenate([tangents, jnp.zeros((1, 6), tangents.dtype)]), batch)
    return loss[:-1], grad[:-1], final[:-1], final[-1]


@functools.partial(jax.jit, static_argnames=("plane", "batch"))
def landscape(problem: TrackingProblem, config: SlamConfig, directions: jax.Array, offsets: jax.Array,
              plane: bool = False, batch: int | None = None) -> Landscape:
    """:func:`loss_and_grad` and :func:`tracked_from` along every direction at every offset, around the reference
    pose ``problem.w2c_init``, and the fixed point. With ``plane`` (A = 2): also the 2-D landscape over the grid
    offsets[0] x offsets[1] (S^2 tracker runs more), in the same batches so one program compiles (jitted).

    Args:
      problem: the frame's tracking problem; its ``w2c_init`` is the reference pose.
      config: the SLAM config (the tracking loss, optimiser and iterations).
      directions: [A, 6] tangent per unit offset along each axis (:func:`directions`).
      offsets: [A, S] offsets along each axis, in its unit (cm, deg).
      plane: also compute the 2-D landscape of the two axes (static).
      batch: tracker runs vmapped at a time (memory; static); None: all A S + 1 (+ S^2) at once.

    Returns:
      The landscape (a ``Landscape``), its ``plane`` set when ``plane`` is True.

    Raises:
      ValueError: ``plane`` is True and A is not 2.
    """
    num_axes, steps = offsets.shape
    tangents = [(directions[:, None, :] * offsets[..., None]).reshape(-1, 6)]  # [A S, 6]
    if plane:
        if num_axes != 2:
            raise ValueError(f"a 2-D landscape needs exactly two axes, got {num_axes}")
        grid = offsets[0][:, None, None] * directions[0] + offsets[1][None, :, None] * directions[1]  # [S, S, 6]
        tangents.append(grid.reshape(-1, 6))
    loss, grad, final, fixed = _evaluate(problem, config, jnp.concatenate(tangents), batch)
    error_cm, error_deg = pose_error(final, problem.w2c_init)
    fixed_cm, fixed_deg = pose_error(final, fixed)
    count = num_axes * steps
    line = lambda values: values[:count].reshape(num_axes, steps, *values.shape[1:])  # noqa: E731
    result = Landscape(line(loss), jnp.einsum("asj,aj->as", line(grad), directions), line(error_cm),
                       line(error_deg), line(fixed_cm), line(fixed_deg), line(final), fixed)
    if not plane:
        return result
    square = lambda values: values[count:].reshape(steps, steps, *values.shape[1:])  # noqa: E731
    return result._replace(plane=Landscape2d(
        square(loss), square(grad) @ directions.T, square(final), square(error_cm), square(error_deg),
        square(fixed_cm), square(fixed_deg)))


def converged(error_cm: npt.ArrayLike, error_deg: npt.ArrayLike) -> np.ndarray:
    """Whether a final pose is within :data:`CONVERGED_CM` and :data:`CONVERGED_DEG` of its target (any shape).

    Args:
      error_cm: the final poses' translation errors (cm).
      error_deg: the final poses' rotation errors (deg), of a shape that broadcasts with ``error_cm``.

    Returns:
      bool, of the two errors' broadcast shape: True where both errors are within their threshold (inclusive).
    """
    return (np.asarray(error_cm) <= CONVERGED_CM) & (np.asarray(error_deg) <= CONVERGED_DEG)


def basin_radius(radii: npt.ArrayLike, converged: npt.ArrayLike) -> float:
    """The largest grid radius r such that the tracker converged from every grid point with radius <= r: the
    radius of the farthest point nearer than the nearest failure (0 when it fails from the point nearest the
    reference; the largest radius when it never fails). ``radii`` >= 0 and ``converged`` of one shape; radii within
    1e-6 (relative) of each other count as equal.

    Args:
      radii: the grid points' radii (their absolute values are used).
      converged: bool, whether the tracker converged from each grid point, of the shape of ``radii``.

    Returns:
      The basin's radius, in the unit of ``radii``.
    """
    radii = np.abs(np.asarray(radii, np.float64)).ravel()
    converged = np.asarray(converged, bool).ravel()
    failed = radii[~converged]
    nearest_failure = failed.min() if failed.size else np.inf
    inside = radii[radii < nearest_failure * (1.0 - 1e-6)]
    return float(inside.max()) if inside.size else 0.0


def basin_width(offsets: Iterable[float], converged: Iterable[bool]) -> float:
    """The largest |offset| r such that the tracker converged from every grid offset with |offset| <= r (0 when
    it fails from the grid point nearest the reference).

    Args:
      offsets: the grid's offsets along one axis, in its unit (cm, deg).
      converged: whether the tracker converged from each offset, one per offset.

    Returns:
      The basin's half-width r, in the unit of ``offsets`` (:func:`basin_radius`).
    """
    return basin_radius(np.abs(np.asarray(list(offsets), np.float64)), list(converged))


def normalised_radii(offsets_a: npt.ArrayLike, offsets_b: npt.ArrayLike) -> np.ndarray:
    """sqrt((a / e_a)^2 + (b / e_b)^2) at grid point (a, b), e_a and e_b the grid's half-widths (the largest |a|,
    |b|): 1 on the ellipse inscribed in the grid.

    Args:
      offsets_a: [S_a] the grid's offsets along the first axis.
      offsets_b: [S_b] the grid's offsets along the second axis.

    Returns:
      [S_a, S_b] float64 normalised radii.
    """
    a, b = np.asarray(offsets_a, np.float64), np.asarray(offsets_b, np.float64)
    return np.hypot(a[:, None] / np.abs(a).max(), b[None, :] / np.abs(b).max())


def basin_2d(offsets_a: npt.ArrayLike, offsets_b: npt.ArrayLike, converged: npt.ArrayLike) -> tuple[float, float]:
    """The 2-D basin of a grid ``offsets_a`` x ``offsets_b``: its normalised radius and the fraction of the grid's
    points the tracker converged from.

    Args:
      offsets_a: [S_a] the grid's offsets along the first axis.
      offsets_b: [S_b] the grid's offsets along the second axis.
      converged: [S_a, S_b] bool, whether the tracker converged from each grid point.

    Returns:
      radius: the largest normalised radius r in [0, 1] (:func:`normalised_radii`) such that the tracker converged
        from every grid point with radius <= r, a fraction of the grid's half-widths (only the points on or inside
        the inscribed ellipse count).
      fraction: the fraction of all S_a S_b grid points it converged from.
    """
    radii = normalised_radii(offsets_a, offsets_b)
    converged = np.asarray(converged, bool)
    within = radii <= 1.0 + 1e-6  # the corners beyond the inscribed ellipse would make it a partial ring
    return basin_radius(radii[within], converged[within]), float(converged.mean())
