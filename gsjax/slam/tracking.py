"""Camera tracking (method_spec A.6): a fixed number of iterations on the pose tangent, map held fixed.

The pose is ``w2c = exp(delta) @ w2c_init`` (left perturbation, delta = (rho, phi)), so the optimisation is
unconstrained and exact on SE(3). Two optimisers:

* ``adam`` (SplaTAM parity): a fresh Adam per frame (:func:`pose_optimizer`, optax) with per-component step
  sizes (rho: ``lr_trans``, phi: ``lr_rot``) on the summed L1 loss; the lowest-loss pose seen is kept. An
  iteration whose gradient is not finite takes no step and is counted.
* ``lm``: Levenberg-Marquardt (optimistix) on the same masked residuals in least squares, with a forward-mode
  Jacobian through the renderer (6 columns; always on the XLA path, see ``RasterSettings.for_forward_mode``); the
  result is kept only if its L1 tracking loss beats the start's.

Both can start on a quarter of the pixels (``tracking.strided_iters``): every other pixel of each row and column,
rendered exactly as the full render renders them (:meth:`gsjax.camera.Intrinsics.strided`) at a fraction of the
cost, then finish on every pixel.

:func:`track_guarded` (what SLAM calls) detects divergence: a pose beyond a physical bound from the
constant-velocity prediction, or a loss jump over the previous frame's; the frame is retried once (``adam``) and
falls back to the prediction when no attempt stays within the bound.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from gsjax.camera import Intrinsics, camera_center, perturb_left, rotation_angle
from gsjax.config.fields import choice_is
from gsjax.gaussians import Gaussians
from gsjax.raster import select_slots
from gsjax.slam.config import BEST_POSE, CoarseToFine, SlamConfig, TrackingConfig
from gsjax.slam.loops import LoopCaps, compiles_smoothing, counted_scan, is_differentiable, loop_caps
from gsjax.slam.losses import TrackingTerms, tracking_loss, tracking_residuals
from gsjax.slam.optimizers import finite_only_if_loss_is, nonfinite_steps, pose_optimizer
from gsjax.slam.views import render_view, strided_frame, strided_setup, strided_slots


class TrackResult(NamedTuple):
    """One frame's tracking result (:func:`track`).

    Attributes:
      w2c: [4, 4] the tracked world-to-camera pose (m): ``adam``'s lowest-loss pose among the iterations on every
        pixel (see ``tracking.best_pose``; the pose they started from when no loss was finite), or ``lm``'s
        solution where its loss beats the start's (else ``w2c_init``).
      loss: [] float32 the tracking loss there: ``adam``'s lowest (with ``best_pose`` ``post_step``, that of the
        pose before ``w2c``'s step; inf when no iteration on every pixel had a finite loss), ``lm``'s at ``w2c``.
      nonfinite: [] int32 ``adam``'s iterations skipped for a non-finite loss or gradient (all stages counted);
        ``lm``: 1 when its solution or its loss was not finite (the start kept), else 0.
      iterations: [] int32 iterations run: ``adam``'s over the coarse, strided and full stages (fewer when
        ``tracking.stop.window`` stops early), ``lm``'s steps on the strided grid and on every pixel.
    """

    w2c: jax.Array
    loss: jax.Array
    nonfinite: jax.Array
    iterations: jax.Array


class TrackingProblem(NamedTuple):
    """One frame's tracking problem, the map held fixed.

    SLAM's step builds it with :func:`gsjax.slam.system.tracking_problem`.

    Attributes:
      gaussians: the map (no gradient reaches it).
      color: [H, W, 3] the observed colour in [0, 1].
      depth: [H, W] the observed depth (m; 0 marks an invalid pixel).
      w2c_init: [4, 4] the start pose, world-to-camera (m); in SLAM the constant-velocity prediction.
      intrinsics: the camera at the frame's resolution.
      smooth: [] bool, render with CB-KNN (a keyframe in ``paper`` mode).
      gamma: [] CB-KNN's inter-frame motion in [0, 1] (its adaptive K).
    """

    gaussians: Gaussians
    color: jax.Array
    depth: jax.Array
    w2c_init: jax.Array
    intrinsics: Intrinsics
    smooth: jax.Array
    gamma: jax.Array


class TrackingObjective(NamedTuple):
    """The tracker's objective around ``w2c_init`` (:func:`tracking_objective`), as functions of the pose update.

    delta [6] = (rho m, phi rad) is the left perturbation: the pose is ``exp(delta) @ w2c_init``.

    Attributes:
      view_at: ``view_at(delta, selection=None)`` renders (:class:`gsjax.slam.views.RenderedView`) at that pose.
      loss: ``loss(delta, selection=None)``, the tracking loss [] there (:func:`gsjax.slam.losses.tracking_loss`).
      lambda_color: the loss's colour weight (a float or a [] array).
      select: ``select(delta)`` chooses every pixel's contributor slots at that pose
        (:func:`gsjax.raster.select_slots`, the full image's): given to ``view_at``/``loss``, those slots are
        composited instead of being chosen at the rendered pose (``tracking.reselect_every``).
    """

    view_at: Callable
    loss: Callable
    lambda_color: float | jax.Array
    select: Callable


class Stage(NamedTuple):
    """One stage of tracking (coarse levels, strided grids, every pixel): what it minimises, for how many iterations,
    and whether those compete for the returned pose. Both trackers run a list of stages in order, each from the
    previous one's pose (:func:`tracking_stages`).

    Attributes:
      loss: ``loss(delta, it, selection)`` -> [] at iteration ``it`` (counted over all stages; may be traced), for
        delta [6] and the selection in use (None: every render chooses its contributors): the Adam tracker's.
      residuals: ``residuals(delta)`` -> [R], the masked residuals in least squares (the LM tracker's), or None.
      iters: the stage's iteration count (may be traced).
      cap: the static cap of its loop (:class:`gsjax.slam.loops.LoopCaps`).
      competes_for_best: whether its iterations compete for the returned pose (only those on every pixel at the
        loss's own blur: the strided and blurred losses do not compare with them); the early stop
        (``tracking.stop``) watches that stage alone.
    """

    loss: Callable
    residuals: Callable | None
    iters: Any
    cap: int
    competes_for_best: bool


def tracking_objective(problem: TrackingProblem, config: SlamConfig) -> TrackingObjective:
    """What the tracker minimises for ``problem``: its renders and loss around ``problem.w2c_init``.

    The map is held fixed (no gradient, ``raster.pose_only``; in a program whose loops are differentiable,
    :attr:`gsjax.slam.loops.LoopCaps.differentiable`, the pose's derivative with respect to the map passes). In
    ``paper`` mode with ``cbknn.track_keyframes``,
    where ``problem.smooth`` is true (a keyframe), the renders are CB-KNN's and the colour weight is
    ``cbknn.lambda_color_keyframe``; elsewhere the canonical render and ``tracking.lambda_color``.

    Args:
      problem: the frame's tracking problem.
      config: the SLAM config (its ``tracking``, ``raster`` and ``cbknn`` are read).

    Returns:
      the objective: renders, loss, colour weight and slot selection as functions of the pose update.
    """
    cfg = config.tracking
    gaussians, color, depth, w2c_init, intrinsics, smooth, gamma = problem
    if not is_differentiable(config):
        # (A hypergradient through the whole window lets the map's derivative through: the pose depends on it.)
        gaussians = jax.lax.stop_gradient(gaussians)
    config = dataclasses.replace(config, raster=dataclasses.replace(config.raster, pose_only=True))
    smooth = jnp.logical_and(smooth, config.cbknn.track_keyframes)
    lambda_color = jnp.where(jnp.logical_and(smooth, config.cbknn.smooth_renders), config.cbknn.lambda_color_keyframe,
                             cfg.lambda_color)

    def view_at(delta, selection=None):
        return render_view(gaussians, perturb_left(delta, w2c_init), intrinsics, config.raster, config.cbknn, smooth,
                           gamma, selection, compiles_smoothing(config))

    def loss_fn(delta, selection=None):
        return tracking_loss(view_at(delta, selection), color, depth, TrackingTerms.of(cfg, lambda_color))

    def select(delta):
        return select_slots(gaussians, perturb_left(delta, w2c_init), intrinsics, config.raster)

    return TrackingObjective(view_at, loss_fn, lambda_color, select)


def track(problem: TrackingProblem, config: SlamConfig) -> TrackResult:
    """Track one frame from ``problem.w2c_init``, minimising :func:`tracking_objective`.

    ``tracking.optimizer`` picks Adam (after the coarse levels and the strided grids when configured) or
    Levenberg-Marquardt (after the strided grids when configured; rendered on the XLA path for its forward mode).
    The iteration counts are traced: each stage is a loop over its cap (``config.caps``) that skips the iterations
    past its count.

    Args:
      problem: the frame's tracking problem.
      config: the SLAM config (its ``tracking``, ``raster``, ``cbknn`` and ``caps`` are read).

    Returns:
      the tracked pose, its loss, the skipped iterations and the iterations run.
    """
    caps = loop_caps(config)
    if config.tracking.optimizer == "lm":
        # LM's Jacobian is forward mode, which the Pallas compositing (a custom_vjp) does not have.
        config = dataclasses.replace(config, raster=config.raster.for_forward_mode())
        return _track_lm(tracking_stages(problem, config, caps), problem.w2c_init, caps.differentiable)
    return _track_adam(tracking_stages(problem, config, caps), problem.w2c_init, config.tracking,
                       caps.differentiable, tracking_objective(problem, config).select)


def tracking_stages(problem: TrackingProblem, config: SlamConfig, caps: LoopCaps) -> list[Stage]:
    """The stages of tracking ``problem``, in order: the coarse levels (``tracking.coarse.iters``, :func:`coarse_loss`),
    the strided grids (``tracking.strided_iters``, :func:`strided_problem`; the grid of phase ``it`` % 4 at
    iteration ``it``, phase 0 for LM, whose residuals are blurred at half the std: its pixels are twice as far
    apart), each where its cap in ``caps`` is not 0, then every pixel (``tracking.iters``), the stage that competes
    for the pose.

    Args:
      problem: the frame's tracking problem.
      config: the SLAM config.
      caps: the loops' static caps (:func:`gsjax.slam.loops.loop_caps` of ``config``).

    Returns:
      the stages (:class:`Stage`), in the order they run.
    """
    cfg = config.tracking
    full = tracking_objective(problem, config)

    def residuals(objective: TrackingObjective, color, depth, blur_px):
        return lambda delta: tracking_residuals(objective.view_at(delta), color, depth,
                                                TrackingTerms.of(cfg, full.lambda_color, blur_px))

    stages = []
    if caps.tracking_coarse:
        stages.append(Stage(coarse_loss(problem, config), None, cfg.coarse.iters, caps.tracking_coarse, False))
    if caps.tracking_strided:
        on_grid = strided_problem(problem, config)
        lm = cfg.optimizer == "lm"  # (static) LM solves on grid 0 only: built here, outside its loop
        stages.append(Stage(lambda delta, it, selection: on_grid(it % 4)[0].loss(delta, selection),
                            residuals(*on_grid(0), cfg.blur.sigma_px / 2) if lm else None,
                            cfg.strided_iters, caps.tracking_strided, False))
    stages.append(Stage(lambda delta, it, selection: full.loss(delta, selection),
                        residuals(full, problem.color, problem.depth, cfg.blur.sigma_px), cfg.iters, caps.tracking,
                        True))
    return stages


def coarse_level(it: jax.Array, coarse: CoarseToFine) -> jax.Array:
    """The coarse-to-fine level of coarse iteration ``it``: ``coarse.iters`` split over ``coarse.levels`` levels from
    the coarsest (0), the remainder to the first.

    Args:
      it: [] int32 the iteration, counted from the first coarse one (may be traced).
      coarse: the coarse-to-fine config (its ``iters`` and ``levels`` may be traced).

    Returns:
      [] int32 the level, 0 (coarsest) to ``levels`` - 1.
    """
    per = coarse.iters // coarse.levels
    first = per + coarse.iters % coarse.levels
    return jnp.where(it < first, 0, 1 + (it - first) // jnp.maximum(per, 1)).astype(jnp.int32)


def coarse_loss(problem: TrackingProblem, config: SlamConfig) -> Callable:
    """The loss of coarse-to-fine tracking at each coarse iteration.

    At level ``l`` (:func:`coarse_level`) it is the tracking objective's loss with the residuals blurred at
    ``coarse.sigma_px`` x 2^(levels - 1 - l) px (``tracking.blur.radius_px`` truncates the filter).

    Args:
      problem: the frame's tracking problem.
      config: the SLAM config (its ``tracking.coarse`` sets the levels).

    Returns:
      ``loss(delta, it, selection=None)`` -> [] for delta [6] (as :class:`TrackingObjective`) at coarse iteration
        ``it`` (counted from the first coarse one).
    """
    cfg = config.tracking

    def loss(delta, it, selection=None):
        level = coarse_level(it, cfg.coarse)
        sigma = jnp.ldexp(jnp.asarray(cfg.coarse.sigma_px, jnp.float32), cfg.coarse.levels - 1 - level)
        blurred = dataclasses.replace(config, tracking=dataclasses.replace(
            cfg, blur=dataclasses.replace(cfg.blur, sigma_px=sigma)))
        return tracking_objective(problem, blurred).loss(delta, selection)

    return loss


def strided_problem(
    problem: TrackingProblem, config: SlamConfig
) -> Callable[[int | jax.Array], tuple[TrackingObjective, jax.Array, jax.Array]]:
    """The tracking problem on each strided grid: every other pixel from (row, col) = (phase // 2, phase % 2).

    The render there is the full render's pixels (:func:`gsjax.slam.views.strided_setup`); the objective's loss is
    scaled by the pixel ratio, (H W) / ((H // 2) (W // 2)), so its gradient has the full loss's scale. Its
    ``view_at``/``loss`` take the full image's selection (``select`` is the full image's) and composite its slots
    at the grid's pixels.

    Args:
      problem: the frame's tracking problem on every pixel.
      config: the SLAM config for the full image.

    Returns:
      ``on_grid(phase)`` for the grid ``phase`` 0-3 (may be traced), which gives the grid's
        :class:`TrackingObjective`, its colour [H // 2, W // 2, 3] and its depth [H // 2, W // 2].
    """
    intrinsics = problem.intrinsics
    full = tracking_objective(problem, config)
    strided_config = strided_setup(config, intrinsics)
    ratio = (intrinsics.height * intrinsics.width) / ((intrinsics.height // 2) * (intrinsics.width // 2))

    def on_grid(phase):
        color_s, depth_s, intrinsics_s = strided_frame(problem.color, problem.depth, intrinsics, phase)
        objective = tracking_objective(problem._replace(color=color_s, depth=depth_s, intrinsics=intrinsics_s),
                                       strided_config)

        def on_grid_slots(selection):
            return None if selection is None else strided_slots(selection, config.raster, intrinsics, phase)

        return TrackingObjective(
            view_at=lambda delta, selection=None: objective.view_at(delta, on_grid_slots(selection)),
            loss=lambda delta, selection=None: ratio * objective.loss(delta, on_grid_slots(selection)),
            lambda_color=objective.lambda_color, select=full.select), color_s, depth_s

    return on_grid


class AdamCarry(NamedTuple):
    """The Adam tracker's loop state, carried through the coarse, strided and full stages.

    The best update and the progress are reset at each stage: only the stage on every pixel competes for the
    returned pose.

    Attributes:
      it: [] int32 the iteration, counted over all stages.
      delta: the pose update ``{"rho": [3], "phi": [3]}`` float32 (m, rad), the left perturbation of ``w2c_init``.
      opt_state: the optimiser's state (:func:`gsjax.slam.optimizers.pose_optimizer`; it counts the skipped steps).
      best_delta: the update with the stage's lowest finite loss (as ``delta``).
      best_loss: [] float32 that loss (inf until a finite one).
      progress_at: [] int32 the iteration of the last progress (for ``tracking.stop.window``).
      progress_loss: [] float32 the loss at the last progress (inf before the first).
      selection: the :class:`gsjax.raster.SlotSelection` in use, chosen every ``tracking.reselect_every``
        iterations (every iteration when it is 1), or None when every render chooses its own.
    """

    it: jax.Array
    delta: dict
    opt_state: Any
    best_delta: dict
    best_loss: jax.Array
    progress_at: jax.Array
    progress_loss: jax.Array
    selection: Any


def _track_adam(stages: list[Stage], w2c_init, cfg: TrackingConfig, differentiable: bool = False,
                select=None) -> TrackResult:
    """Adam through ``stages`` in order, one optimiser state carried through them (:class:`Stage`: each a
    :func:`gsjax.slam.loops.counted_scan` within its cap; after a stage that does not compete for the pose, the
    best pose and the progress start again). ``select(delta)`` chooses the contributor slots at iterations 0, R, 2R,
    ... (R = ``tracking.reselect_every``) and the iterations in between composite those (None: every render chooses
    its own). ``differentiable``: the loops take the form reverse mode passes through."""
    optimizer = pose_optimizer(cfg, differentiable)
    post_step = choice_is(cfg.best_pose, "post_step", BEST_POSE)
    tangent = lambda delta: jnp.concatenate([delta["rho"], delta["phi"]])  # noqa: E731
    delta0 = {"rho": jnp.zeros(3, jnp.float32), "phi": jnp.zeros(3, jnp.float32)}

    def iteration(loss, carry: AdamCarry) -> AdamCarry:
        it, delta, selection = carry.it, carry.delta, carry.selection
        if select is not None:
            selection = jax.lax.cond(it % cfg.reselect_every == 0, lambda: select(tangent(delta)), lambda: selection)
        value, grad = jax.value_and_grad(lambda d: loss(tangent(d), it, selection))(delta)
        updates, opt_state = optimizer.update(finite_only_if_loss_is(value, grad), carry.opt_state)
        new_delta = optax.apply_updates(delta, updates)
        better = jnp.isfinite(value) & (value < carry.best_loss)
        # pre_step keeps the pose whose loss this is; post_step (SplaTAM's off-by-one) the pose after its step.
        candidate = jax.tree.map(lambda old, new: jnp.where(post_step, new, old), delta, new_delta)
        best_delta = jax.tree.map(lambda c, b: jnp.where(better, c, b), candidate, carry.best_delta)
        # Progress: the loss fell by stop.rtol below the loss of the last progress (the first finite loss is).
        progress = jnp.isfinite(value) & (value < carry.progress_loss * (1.0 - cfg.stop.rtol))
        return AdamCarry(it + 1, new_delta, opt_state, best_delta, jnp.where(better, value, carry.best_loss),
                         jnp.where(progress, it, carry.progress_at), jnp.where(progress, value, carry.progress_loss),
                         selection)

    def restart(final: AdamCarry) -> AdamCarry:  # the next stage goes on from this one's pose, state, selection
        return final._replace(best_delta=final.delta, best_loss=inf, progress_at=final.it, progress_loss=inf)

    inf = jnp.float32(jnp.inf)
    selection0 = None
    if select is not None:  # (its trace is the selection's first, which the loop's calls then reuse)
        selection0 = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(select, tangent(delta0)))
    carry = AdamCarry(jnp.int32(0), delta0, optimizer.init(delta0), delta0, inf, jnp.int32(0), inf, selection0)

    def run(stage: Stage, carry: AdamCarry) -> AdamCarry:
        end = carry.it + stage.iters

        def running(c: AdamCarry):  # the early stop (the competing stage's): no progress for stop.window iterations
            return (c.it < end) & ((cfg.stop.window == 0) | (c.it - c.progress_at <= cfg.stop.window))

        final = counted_scan(lambda _, c: iteration(stage.loss, c), carry, stage.iters, stage.cap,
                             running if stage.competes_for_best else None, differentiable)
        return final if stage.competes_for_best else restart(final)

    for stage in stages:
        carry = run(stage, carry)
    final = carry
    return TrackResult(perturb_left(tangent(final.best_delta), w2c_init), final.best_loss,
                       nonfinite_steps(final.opt_state), final.it)


@functools.cache
def _step_limited() -> type:
    """A least-squares solver stopped after ``limit`` steps (traced), within its loop's static ``max_steps`` (the
    class is made on first use: optimistix takes 0.3 s to import, and only the LM tracker needs it)."""
    import optimistix as optx

    class StepLimited(optx.AbstractLeastSquaresSolver):
        inner: optx.AbstractLeastSquaresSolver
        limit: jax.Array
        rtol: float
        atol: float
        norm: Callable

        def init(self, fn, y, args, options, f_struct, aux_struct, tags):
            return self.inner.init(fn, y, args, options, f_struct, aux_struct, tags), jnp.int32(0)

        def step(self, fn, y, args, options, state, tags):
            y, inner_state, aux = self.inner.step(fn, y, args, options, state[0], tags)
            return y, (inner_state, state[1] + 1), aux

        def terminate(self, fn, y, args, options, state, tags):
            done, result = self.inner.terminate(fn, y, args, options, state[0], tags)
            return done | (state[1] >= self.limit), result

        def postprocess(self, fn, y, aux, args, options, state, tags, result):
            return self.inner.postprocess(fn, y, aux, args, options, state[0], tags, result)

    return StepLimited


def _track_lm(stages: list[Stage], w2c_init, unrolled: bool = False) -> TrackResult:
    """Levenberg-Marquardt on each stage's residuals in order (at most its ``iters`` steps, within its cap), each
    from the previous one's solution where that is finite (else from the start); the last stage's solution is kept
    where its loss beats the start's. Reverse mode passes optimistix's implicit adjoint (the solution's derivative
    at its fixed point), or with ``unrolled`` its steps (checkpointed)."""
    import optimistix as optx

    inner: Any = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)  # generic over types optimistix leaves open
    adjoint = optx.RecursiveCheckpointAdjoint() if unrolled else optx.ImplicitAdjoint()

    def solve(stage: Stage, start):
        assert stage.residuals is not None
        solver: Any = _step_limited()(inner, jnp.asarray(stage.iters, jnp.int32), inner.rtol, inner.atol, inner.norm)
        return optx.least_squares(lambda delta, _: stage.residuals(delta), solver, start, max_steps=stage.cap,
                                  throw=False, adjoint=adjoint)

    delta0 = jnp.zeros(6, jnp.float32)
    start, steps = delta0, jnp.int32(0)
    *before, final = stages
    for stage in before:
        first = solve(stage, start)
        start = jnp.where(jnp.all(jnp.isfinite(first.value)), first.value, start)
        steps = steps + jnp.asarray(first.stats["num_steps"], jnp.int32)
    solution = solve(final, start)
    delta = solution.value
    start_loss, end_loss = final.loss(delta0, 0, None), final.loss(delta, 0, None)
    usable = jnp.all(jnp.isfinite(delta)) & jnp.isfinite(end_loss)
    better = usable & (end_loss < start_loss)
    best = jnp.where(better, delta, delta0)
    return TrackResult(perturb_left(best, w2c_init), jnp.where(better, end_loss, start_loss),
                       (~usable).astype(jnp.int32), steps + jnp.asarray(solution.stats["num_steps"], jnp.int32))


class GuardedTrack(NamedTuple):
    """A frame tracked with the divergence guard (:func:`track_guarded`): :class:`TrackResult`'s fields and two flags.

    Attributes:
      w2c: [4, 4] the kept attempt's pose (m), or ``w2c_init`` (the prediction) when ``diverged``.
      loss: [] float32 the kept attempt's loss (the first attempt's when ``diverged``).
      nonfinite: [] int32 skipped iterations, over both attempts when the frame was tracked again.
      retried: [] bool, the first attempt diverged (``adam`` then tracks the frame again; ``lm`` does not).
      diverged: [] bool, the first attempt diverged and no attempt stayed within the bound.
      iterations: [] int32 iterations run, over both attempts when the frame was tracked again.
    """

    w2c: jax.Array
    loss: jax.Array
    nonfinite: jax.Array
    retried: jax.Array
    diverged: jax.Array
    iterations: jax.Array


def within_step_bound(w2c: jax.Array, w2c_init: jax.Array, tracking: TrackingConfig) -> jax.Array:
    """Whether ``w2c`` lies within the physical bound of one frame's motion from ``w2c_init``.

    Args:
      w2c: [4, 4] the tracked world-to-camera pose (m).
      w2c_init: [4, 4] the pose it started from (m), the constant-velocity prediction.
      tracking: the tracking config (its ``guard.max_step_m`` and ``guard.max_step_deg`` are read).

    Returns:
      [] bool, ``w2c`` is finite, its camera centre at most ``guard.max_step_m`` (m) from ``w2c_init``'s and its
        rotation at most ``guard.max_step_deg`` (deg) from ``w2c_init``'s.
    """
    cfg = tracking
    shift = jnp.linalg.norm(camera_center(w2c) - camera_center(w2c_init))
    turn = rotation_angle(w2c[:3, :3] @ w2c_init[:3, :3].T)
    return jnp.all(jnp.isfinite(w2c)) & (shift <= cfg.guard.max_step_m) & (turn <= jnp.deg2rad(cfg.guard.max_step_deg))


def _diverged(result: TrackResult, w2c_init, previous_loss, tracking: TrackingConfig) -> jax.Array:
    # A non-finite loss (every iteration skipped) already keeps the start pose; a retry cannot mend the map.
    jump = (previous_loss > 0) & (result.loss > tracking.guard.loss_jump * previous_loss)
    return jnp.isfinite(result.loss) & (jump | ~within_step_bound(result.w2c, w2c_init, tracking))


def track_guarded(problem: TrackingProblem, config: SlamConfig, previous_loss: jax.Array) -> GuardedTrack:
    """:func:`track` from the constant-velocity prediction ``problem.w2c_init``, guarded against divergence.

    An attempt with a finite loss has diverged when its pose is beyond :func:`within_step_bound` or its loss exceeds
    ``guard.loss_jump`` times ``previous_loss``. With ``adam`` a diverged frame is tracked once more with the step
    sizes times ``guard.retry_lr_scale``; the second attempt is kept when it is within the bound and the first is
    not, or both are and its loss is lower. When neither is within the bound the pose is the prediction.

    Both attempts are passes of one ``while_loop`` (a ``scan`` of two in a differentiable program, for reverse mode)
    over a single traced tracker, so the compiled program holds the
    tracker once and the retry costs nothing when no frame diverges (also under ``vmap``, where a ``cond`` would
    run both sides).

    Args:
      problem: the frame's tracking problem (``w2c_init``: the constant-velocity prediction).
      config: the SLAM config (its ``tracking.guard`` sets the guard).
      previous_loss: [] the previous tracked frame's loss (0: none, no loss-jump test).

    Returns:
      the kept pose, its loss, the skipped and run iterations of both attempts, and whether the frame was retried
        and diverged.
    """
    cfg = config.tracking
    w2c_init = problem.w2c_init
    if cfg.optimizer == "adam":
        def attempt(carry):
            number, first, _ = carry
            scale = jnp.where(number == 0, 1.0, cfg.guard.retry_lr_scale)
            scaled = dataclasses.replace(config, tracking=dataclasses.replace(
                cfg, lr_trans=cfg.lr_trans * scale, lr_rot=cfg.lr_rot * scale))
            result = track(problem, scaled)
            first = jax.tree.map(lambda new, old: jnp.where(number == 0, new, old), result, first)
            return number + 1, first, result

        def another(carry):
            number, first, _ = carry
            return (number == 0) | ((number == 1) & _diverged(first, w2c_init, previous_loss, cfg))

        zeros = TrackResult(jnp.zeros((4, 4), jnp.float32), jnp.float32(0.0), jnp.int32(0), jnp.int32(0))
        init = (jnp.int32(0), zeros, zeros)
        if is_differentiable(config):  # (reverse mode passes a scan, not a while loop)
            def attempt_if(carry, _):
                return jax.lax.cond(another(carry), attempt, lambda c: c, carry), None

            _, first, second = jax.lax.scan(attempt_if, init, None, length=2)[0]
        else:
            _, first, second = jax.lax.while_loop(another, attempt, init)
    else:
        first = second = track(problem, config)
    retry = _diverged(first, w2c_init, previous_loss, cfg)
    ok_first = within_step_bound(first.w2c, w2c_init, config.tracking)
    ok_second = within_step_bound(second.w2c, w2c_init, config.tracking)
    use_second = retry & ok_second & (~ok_first | (second.loss < first.loss))
    diverged = retry & ~ok_first & ~ok_second
    w2c = jnp.where(diverged, w2c_init, jnp.where(use_second, second.w2c, first.w2c))
    loss = jnp.where(use_second, second.loss, first.loss)
    again = retry & (cfg.optimizer == "adam")
    nonfinite = first.nonfinite + jnp.where(again, second.nonfinite, 0)
    iterations = first.iterations + jnp.where(again, second.iterations, 0)
    return GuardedTrack(w2c, loss, nonfinite, retry, diverged, iterations)
