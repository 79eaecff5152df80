"""Hypergradients: the derivative of an objective of a SLAM window with respect to traced config fields.

    window = hypergrad.record(frames, config, intrinsics)          # the run, with each frame's state before it
    result = hypergrad.hypergradient(window, config, intrinsics, ["tracking.lr_trans", "cbknn.params.alpha"])
    result.value, result.gradient["tracking.lr_trans"]               # d objective / d field, in the field's unit

The objective (:mod:`gsjax.slam.objectives`) is ``residual`` (no ground truth needed) or ``ate``. A tracked pose's
derivative is taken one of two ways (``adjoint``):

* ``unrolled``: reverse mode through the tracker's iterations (loops as scans over their caps, each iteration
  checkpointed; :class:`gsjax.slam.loops.LoopCaps` ``differentiable``): what a finite number of iterations ends at,
  so it has the derivative of the fields that move that end and not the fixed point (learning rates, their decay);
* ``implicit``: the pose as the fixed point of its loss, ``-H^-1 d2L / (d xi d theta)``, at the recorded pose
  (:func:`gsjax.slam.implicit.implicit_pose`: no iteration replayed; the loss the tracker minimised, ``adam``'s or
  ``lm``'s). Fields that do not move the fixed point (learning rates) have no implicit derivative.

The map's dependence on the fields is cut (``truncation``):

* ``frame``: each frame's pose is differentiated with the state before it held fixed (its map, its prediction, its
  keyframes): the objective's derivative sums each frame's own. Only tracking is replayed;
* ``window``: nothing is held: the derivative passes every step (densification's poses, the mapping iterations, the
  constant-velocity predictions, CB-KNN's motion) from the first frame on: a window's whole SLAM differentiated, the
  mapping iterations unrolled. With ``implicit`` each frame's pose is its fixed point on the replayed map (whose
  derivative the earlier frames' mapping carries), the tracker's iterations not replayed.

Either mode gives the same derivative (``mode``): reverse mode (one backward pass, every field at once) or forward
mode (a tangent per field pushed with the iterations, through the run's own while loops; no iteration's carries
kept). For a few fields forward is the cheaper (10 kitchen frames at 80x60, ``unrolled`` ``frame``, best of 3 calls:
2.17x the frames' tracking for one field, 3.60x for two, 5.15x for three, 6.81x for four, against 5.50x in
reverse), so ``mode="auto"`` takes it for up to :data:`FORWARD_FIELDS` fields there.

Renders run on the XLA path (Pallas' backward has no derivative of its own), and CB-KNN's adaptive K passes its
unrounded value's derivative (``CBKNN.straight_through_k``), so that ``k0`` and ``beta`` have one; values unchanged.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics, orthonormalize
from gsjax.config.paths import differentiable_entry, replace_paths
from gsjax.frame import Frame, stack_frames, to_device
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import (
    capacity_of,
    concat_outputs,
    doubled,
    dropped_in,
    host_frames,
    pad_chunk,
    stack_trees,
    start_capacity,
)
from gsjax.slam.implicit import implicit_pose
from gsjax.slam.loops import LoopCaps, loop_caps
from gsjax.slam.objectives import OBJECTIVES, AteTarget, ate, ate_target, centre_error, frame_residual, mean_over
from gsjax.slam.state import SlamState, grow_capacity, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs, frame_input, run_chunk, sanitize_frame, step, unknown_poses
from gsjax.slam.tracking import GuardedTrack, track_guarded

ADJOINTS = ("unrolled", "implicit")
TRUNCATIONS = ("frame", "window")


class Window(NamedTuple):
    """A recorded SLAM run over a window of frames (:func:`record`), what a hypergradient replays.

    Attributes:
      frames: the frames, every leaf with a leading axis of T (their ground truth is read by ``ate`` only).
      states: the :class:`gsjax.slam.state.SlamState` before each frame, stacked [T] (one capacity: the run's last).
      outputs: the per-frame :class:`gsjax.slam.system.StepOutputs`, stacked [T].
    """

    frames: Frame
    states: SlamState
    outputs: StepOutputs


class Hypergradient(NamedTuple):
    """What :func:`hypergradient` returns.

    Attributes:
      value: the objective (m for ``ate``; m + colour units for ``residual``) at the replayed poses.
      gradient: ``{field: d objective / d field}``, each in the objective's unit per the field's unit.
      w2c: [T, 4, 4] the replayed world-to-camera poses (m); the recorded ones for ``implicit``.
    """

    value: float
    gradient: dict[str, float]
    w2c: np.ndarray


def record(frames: Frame | Sequence[Frame], config: SlamConfig, intrinsics: Intrinsics, *, seed: int = 0,
           capacity: int | None = None, call: Callable | None = None) -> Window:
    """SLAM over ``frames`` one at a time (the run :func:`gsjax.slam.run` makes), keeping the state before each.

    Args:
      frames: a stacked :class:`Frame` ([T, ...] leaves) or a sequence of frames.
      config: the SLAM config.
      intrinsics: the camera at the frames' resolution.
      seed: PRNG seed.
      capacity: the map's starting capacity (default 2 H W); doubled whenever a frame drops a Gaussian.
      call: ``call(run_chunk, *args)`` runs each frame (the shell's exported program); None: directly.

    Returns:
      The recorded :class:`Window`.
    """
    items = host_frames(frames)
    if not items:
        raise ValueError("a hypergradient window needs at least one frame")
    height, width = intrinsics.height, intrinsics.width
    state = initial_state(capacity or start_capacity(height, width), height, width,
                          keyframe_capacity_for(len(items), config.keyframe_every), len(items), seed)
    states, outputs = [], []
    for frame in items:
        stacked, valid = pad_chunk([frame], 1)
        while True:
            args = (state, stacked, valid, config, intrinsics, unknown_poses(1))
            new_state, out = call(run_chunk, *args) if call is not None else run_chunk(*args)
            out = jax.device_get(out)
            if dropped_in(out, 1) == 0:
                break
            state = doubled(state)
        states.append(state)
        outputs.append(out)
        state = new_state
    size = capacity_of(state)
    states = [grow_capacity(s, size) if capacity_of(s) < size else s for s in states]
    return Window(to_device(stack_frames(items)), stack_trees(states),
                  jax.tree_util.tree_map(jnp.asarray, concat_outputs(outputs)))


def _held_out_residual(state: SlamState, frame: Frame, w2c: jax.Array, intrinsics: Intrinsics, raster: Any):
    """[] the ``residual`` of a sanitized ``frame`` at ``w2c``, rendered from the map of the state before it: the
    state's, without Gaussians with a non-finite parameter (as the step cleans it) and without injected noise."""
    gaussians = state.gaussians.without_nonfinite()[0]
    return frame_residual(gaussians, w2c, frame.color, frame.depth, intrinsics, raster)


def hypergradient_config(config: SlamConfig, adjoint: str = "unrolled", truncation: str = "frame",
                         mode: str = "reverse") -> SlamConfig:
    """``config`` as a hypergradient's program runs it: its loops differentiable for ``unrolled`` in reverse mode
    (:class:`gsjax.slam.loops.LoopCaps` ``differentiable``), renders on the XLA path, CB-KNN's K straight-through.

    Args:
      config: the SLAM config.
      adjoint: ``"unrolled"`` or ``"implicit"``.
      truncation: ``"frame"`` or ``"window"`` (``window`` runs mapping's loops differentiable in reverse mode).
      mode: ``"reverse"`` or ``"forward"`` (forward mode passes the run's while loops).

    Returns:
      The config (the same values).

    Raises:
      ValueError: an unknown adjoint, truncation or mode.
    """
    if adjoint not in ADJOINTS:
        raise ValueError(f"adjoint must be one of {', '.join(ADJOINTS)}, got {adjoint!r}")
    if truncation not in TRUNCATIONS:
        raise ValueError(f"truncation must be one of {', '.join(TRUNCATIONS)}, got {truncation!r}")
    if mode not in ("forward", "reverse"):
        raise ValueError(f"mode must be 'forward' or 'reverse', got {mode!r}")
    # Caps at the counts themselves: a scan runs its whole cap (cond-skipped iterations cost in reverse mode).
    caps = LoopCaps.of(config, exact=True) or loop_caps(config)
    caps = dataclasses.replace(caps, differentiable=(adjoint == "unrolled" or truncation == "window")
                               and mode == "reverse")
    params = dataclasses.replace(config.cbknn.params, straight_through_k=True)
    return dataclasses.replace(config, raster=config.raster.for_forward_mode(),
                               cbknn=dataclasses.replace(config.cbknn, params=params)).with_caps(caps)


def _tracked(state: SlamState, recorded: StepOutputs) -> jax.Array:
    """[] bool: the frame was tracked (the map existed, its depth was usable, it did not fall back)."""
    return (state.keyframes.count > 0) & ~recorded.skipped & ~recorded.diverged


def _replayed_frame(state: SlamState, frame: Frame, recorded: StepOutputs, config: SlamConfig,
                    intrinsics: Intrinsics, adjoint: str):
    """(w2c [4, 4], residual [], tracked [] bool) of one frame tracked again from the recorded state before it."""
    frame = sanitize_frame(frame)
    given = frame_input(state, frame, config, intrinsics)
    tracked = _tracked(state, recorded)

    def pose():
        if adjoint == "implicit":
            return implicit_pose(given.problem, config, recorded.w2c)
        return orthonormalize(track_guarded(given.problem, config, state.previous_tracking_loss).w2c)

    w2c = jax.lax.cond(tracked, pose, lambda: recorded.w2c)
    return w2c, _held_out_residual(state, frame, w2c, intrinsics, config.raster), tracked


def _frame_truncated(values: dict[str, jax.Array], window: Window, config: SlamConfig, intrinsics: Intrinsics,
                     target: AteTarget | None, adjoint: str, mode: str = "reverse"):
    """((objective, w2c [T, 4, 4]), {field: derivative}) with each frame's state held fixed (``ate`` with a
    ``target``, else ``residual``).

    Both objectives are ``g(sum_t term_t / n)`` over per-frame terms (``ate``: the squared centre error, ``g`` the
    square root; ``residual``: the frame's residual), and a frame's term depends on the fields through that frame's
    tracking alone: each frame's derivative is taken inside its step of a forward scan, so reverse mode holds one
    frame's carries at a time (peak 1.6 GB for 10 frames at 80x60, 3.6 GB as one reverse pass over the window).
    ``mode`` ``forward``: one tangent per field, pushed through the frame's tracking with the primal shared (the
    config's loops then the run's while loops)."""
    held = jax.lax.stop_gradient(window)
    counted = target.valid if target is not None else jax.vmap(_tracked)(held.states, held.outputs)
    centres = target.centres if target is not None else jnp.zeros((counted.shape[0], 3), jnp.float32)

    def one(total, inputs):
        state, frame, recorded, count, centre = inputs

        def term(values):
            w2c, residual, _ = _replayed_frame(state, frame, recorded, replace_paths(config, values), intrinsics,
                                               adjoint)
            value = centre_error(w2c, centre, target) if target is not None else residual
            return jnp.where(count, value, 0.0), w2c

        (value, w2c), grad = _value_and_derivative(term, values, mode)
        return jax.tree.map(jnp.add, total, grad), (value, w2c)

    zero = jax.tree.map(jnp.zeros_like, values)
    total, (terms, w2c) = jax.lax.scan(one, zero, (held.states, held.frames, held.outputs, counted, centres))
    n = jnp.maximum(jnp.sum(counted), 1)
    mean = mean_over(terms, counted)
    value = jnp.sqrt(mean) if target is not None else mean
    scale = 0.5 / (jnp.maximum(value, 1e-30) * n) if target is not None else 1.0 / n  # g'(mean) / n
    return (value, w2c), jax.tree.map(lambda g: g * scale, total)


def _value_and_derivative(fn: Callable, values: dict[str, jax.Array], mode: str):
    """(``fn(values)``, {field: d fn(values)[0] / d field}) for ``fn`` returning (scalar, aux): reverse mode, or
    forward mode with one tangent per field, vmapped (the primal computed once)."""
    if not values:  # nothing to differentiate: the value alone
        return fn(values), {}
    if mode != "forward":
        return jax.value_and_grad(fn, has_aux=True)(values)
    names = list(values)
    basis = {k: jnp.asarray([float(k == n) for n in names], jnp.float32) for k in values}
    push = jax.vmap(lambda t: jax.jvp(fn, (values,), (t,)), out_axes=((None, None), (0, 0)))
    primal, (tangent, _) = push(basis)
    return primal, {name: tangent[i] for i, name in enumerate(names)}


def _fixed_point_tracker(config: SlamConfig, recorded: StepOutputs) -> Callable:
    """:func:`step`'s tracker for ``implicit`` ``window``: the recorded pose carrying its fixed point's derivative on
    the map it is given (a frame that fell back keeps its prediction, no derivative)."""

    def track(problem, _previous):
        w2c = jax.lax.cond(recorded.diverged, lambda: recorded.w2c,
                           lambda: implicit_pose(problem, config, recorded.w2c))
        return GuardedTrack(w2c, recorded.tracking_loss, recorded.nonfinite, recorded.retried, recorded.diverged,
                            recorded.tracking_iters)

    return track


def _window_objective(values: dict[str, jax.Array], window: Window, config: SlamConfig, intrinsics: Intrinsics,
                      target: AteTarget | None, objective: str, adjoint: str):
    """(objective, w2c [T, 4, 4]) of the whole window run again from its first state (the ``window`` truncation)."""
    config = replace_paths(config, values)
    held = jax.lax.stop_gradient(window)

    def run(state, inputs):
        frame, recorded = inputs
        tracked = _tracked(state, recorded)
        track = _fixed_point_tracker(config, recorded) if adjoint == "implicit" else None
        new_state, out = step(state, frame, config, intrinsics, track=track)
        residual = _held_out_residual(state, sanitize_frame(frame), out.w2c, intrinsics, config.raster)
        return new_state, (out.w2c, residual, tracked)

    first = jax.tree_util.tree_map(lambda x: x[0], held.states)
    _, (w2c, residual, tracked) = jax.lax.scan(jax.checkpoint(run), first, (held.frames, held.outputs))
    value = ate(w2c, target) if objective == "ate" and target is not None else mean_over(residual, tracked)
    return value, w2c


@functools.partial(jax.jit, static_argnames=("objective", "adjoint", "mode"))
def _window_value_and_grad(values, window, config, intrinsics, target, objective, adjoint="unrolled", mode="reverse"):
    fn = functools.partial(_window_objective, window=window, config=config, intrinsics=intrinsics, target=target,
                           objective=objective, adjoint=adjoint)
    return _value_and_derivative(fn, values, mode)


_frame_value_and_grad = jax.jit(_frame_truncated, static_argnames=("adjoint", "mode"))
FORWARD_FIELDS = 3  # ``mode="auto"`` pushes tangents for up to this many fields (the module docstring's timings)
MODES = ("auto", "forward", "reverse")


def hypergradient(window: Window, config: SlamConfig, intrinsics: Intrinsics, fields: Sequence[str], *,
                  objective: str = "residual", adjoint: str = "unrolled", truncation: str = "frame",
                  mode: str = "auto") -> Hypergradient:
    """The derivative of ``objective`` over ``window`` with respect to ``fields`` of ``config``.

    Args:
      window: the recorded run (:func:`record`) with ``config``.
      config: the SLAM config the window was recorded with.
      intrinsics: the camera.
      fields: dotted names of traced float fields (:func:`gsjax.config.paths.differentiable_fields`).
      objective: ``"residual"`` or ``"ate"`` (:mod:`gsjax.slam.objectives`; ``ate`` reads the frames' ground truth).
      adjoint: ``"unrolled"`` or ``"implicit"`` (module docstring).
      truncation: ``"frame"`` or ``"window"`` (module docstring).
      mode: ``"forward"`` (a tangent per field, through the run's while loops), ``"reverse"`` (one backward pass,
        the loops as checkpointed scans), or ``"auto"``: forward for ``unrolled`` ``frame`` with at most
        :data:`FORWARD_FIELDS` fields and the ``adam`` tracker (the cheaper there), else reverse. The same
        derivative either way (``lm`` ``unrolled``: reverse only).

    Returns:
      The objective, its derivative per field and the poses.

    Raises:
      ValueError: an unknown objective, adjoint, truncation or mode, a field without a derivative, ``forward`` with
        ``lm`` ``unrolled``, or ``ate`` with ground truth on fewer than 3 frames.
    """
    _check_objective(objective)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    values = {name: jnp.float32(differentiable_entry(config, name).value) for name in fields}
    target = _ate_target(window) if objective == "ate" else None
    lm = config.tracking.optimizer == "lm"
    if mode == "auto":
        forward = adjoint == "unrolled" and truncation == "frame" and len(values) <= FORWARD_FIELDS and not lm
        mode = "forward" if forward else "reverse"
    if mode == "forward" and adjoint == "unrolled" and lm and values:  # optimistix: its while loop implicitly
        raise ValueError("the LM tracker's unrolled derivative is reverse mode only (mode 'reverse' or 'auto')")
    mode = mode if values else "forward"  # no field: the value alone, through the run's own loops
    hyper = hypergradient_config(config, adjoint, truncation, mode)
    if truncation == "frame":
        (value, w2c), grads = _frame_value_and_grad(values, window, hyper, intrinsics, target, adjoint=adjoint,
                                                    mode=mode)
    else:
        (value, w2c), grads = _window_value_and_grad(values, window, hyper, intrinsics, target, objective=objective,
                                                     adjoint=adjoint, mode=mode)
    return Hypergradient(float(value), {k: float(v) for k, v in grads.items()}, np.asarray(w2c))


def replayed_objective(window: Window, config: SlamConfig, intrinsics: Intrinsics,
                       objective: str = "residual") -> float:
    """``objective`` with every frame tracked again (``config``'s tracking) from its recorded state: the function whose
    derivative the ``frame`` truncation takes, what its central differences compare with (no derivative taken).

    Args:
      window: the recorded run.
      config: the SLAM config to track with (the recorded one's, or another value of its traced fields).
      intrinsics: the camera.
      objective: ``"residual"`` or ``"ate"``.

    Returns:
      The objective's value at the replayed poses.
    """
    return hypergradient(window, config, intrinsics, (), objective=objective, adjoint="unrolled").value


def objective_value(window: Window, config: SlamConfig, intrinsics: Intrinsics, objective: str = "residual") -> float:
    """``objective`` of the recorded run as it ran (no derivative; what a finite difference of runs compares).

    Args:
      window: the recorded run.
      config: its SLAM config (the raster settings are read).
      intrinsics: the camera.
      objective: ``"residual"`` or ``"ate"``.

    Returns:
      The objective's value.
    """
    _check_objective(objective)
    if objective == "ate":
        return float(ate(window.outputs.w2c, _ate_target(window)))
    return float(_recorded_residual(window, config.raster, intrinsics))


def _check_objective(objective: str) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")


def _ate_target(window: Window) -> AteTarget:
    """The ``ate`` objective's ground truth and alignment, from the window's frames and recorded poses."""
    frames = jax.device_get(window.frames)
    return ate_target(frames.c2w, frames.pose_valid, np.asarray(window.outputs.w2c))


@jax.jit
def _recorded_residual(window: Window, raster: Any, intrinsics: Intrinsics) -> jax.Array:
    def one(_, inputs):
        state, frame, recorded = inputs
        residual = _held_out_residual(state, sanitize_frame(frame), recorded.w2c, intrinsics, raster)
        return None, (residual, _tracked(state, recorded))

    _, (residual, tracked) = jax.lax.scan(one, None, (window.states, window.frames, window.outputs))
    return mean_over(residual, tracked)
