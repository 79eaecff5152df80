"""One SLAM step per frame (track -> densify -> map -> keyframe) and ``lax.scan`` over a chunk of frames.

``step(state, frame)`` is pure and jit-able; :func:`run_chunk` scans it over a stacked chunk of frames. The shell
(:mod:`gsjax.app.session`) streams chunks from disk, checkpoints and grows capacity between them. The first frame goes
through the same step: on the empty map every valid pixel is densified (SplaTAM's initialisation), tracking is
skipped (the first camera defines the world frame), and the frame is mapped and becomes keyframe 0.

The core reads a frame's colour and depth only, never its ground-truth pose (``Frame.c2w``, ``pose_valid``): a
sequence gives the same result with or without ground truth. (SplaTAM stores a keyframe only where the GT pose is
finite, a guard for ScanNet's invalid poses; here keyframes follow the frame rule alone.)

A frame with too little valid depth (a fraction below ``SlamConfig.min_valid_depth``: a covered or saturated
sensor, a dropped depth image) is not tracked, densified, mapped or stored as a keyframe; its pose is the
constant-velocity prediction and ``StepOutputs.skipped`` is set. Until a frame with depth arrives the map is
empty, and that frame initialises it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics, constant_velocity, orthonormalize
from gsjax.frame import Frame
from gsjax.raster.cbknn import CBKNN, motion_from_poses
from gsjax.slam.config import SlamConfig
from gsjax.slam.densify import densify
from gsjax.slam.keyframes import select_window
from gsjax.slam.loops import compiles_noise, compiles_smoothing
from gsjax.slam.mapping import MapResult, gather_window_frames, map_window
from gsjax.slam.noise import NOISE_STREAM, add_depth_noise, perturb_map, perturb_stored_map
from gsjax.slam.state import SlamState
from gsjax.slam.tracking import GuardedTrack, TrackingProblem, track_guarded
from gsjax.slam.views import is_keyframe, render_view


class StepOutputs(NamedTuple):
    """Per-frame outputs of :func:`step` (stacked along the frames by the scan).

    Attributes:
      w2c: [4, 4] float32 estimated world-to-camera pose.
      tracking_loss: [] float32 the tracking loss at that pose (0 at frame 0).
      mapping_loss: [] float32 the last mapping iteration's loss (0 on a frame not mapped, ``mapping.every``).
      num_gaussians: [] int32 active Gaussians after the step.
      added: [] int32 Gaussians densified this frame.
      dropped: [] int32 Gaussians not inserted for lack of capacity.
      keyframe: [] bool, the frame was stored as a keyframe.
      gamma: [] float32 the camera motion CB-KNN's adaptive K used.
      nonfinite: [] int32 tracking iterations skipped because the loss or gradient was not finite.
      truncated: [] bool, the densification render was truncated by the rasterizer's capacities.
      truncation_residual: [] float32 the largest transmittance that truncation left in that render.
      skipped: [] bool, the frame had too little valid depth and kept its predicted pose.
      retried: [] bool, tracking diverged and the frame was tracked again
        (:func:`gsjax.slam.tracking.track_guarded`).
      diverged: [] bool, the frame fell back to the constant-velocity prediction.
      nonfinite_gaussians: [] int32 Gaussians freed this frame because a parameter was not finite.
      tracking_iters: [] int32 tracking iterations run (both attempts of a retried frame; 0 when not tracked).
      depth_valid: [] float32 the fraction of the frame's pixels with valid depth.
    """

    w2c: jax.Array
    tracking_loss: jax.Array
    mapping_loss: jax.Array
    num_gaussians: jax.Array
    added: jax.Array
    dropped: jax.Array
    keyframe: jax.Array
    gamma: jax.Array
    nonfinite: jax.Array
    truncated: jax.Array
    truncation_residual: jax.Array
    skipped: jax.Array
    retried: jax.Array
    diverged: jax.Array
    nonfinite_gaussians: jax.Array
    tracking_iters: jax.Array
    depth_valid: jax.Array


def sanitize_frame(frame: Frame) -> Frame:
    """The frame with every pixel whose colour or depth is not finite made invalid (depth 0, colour 0).

    A NaN or inf from a broken sensor or file then never reaches a loss, a new Gaussian or a keyframe.

    Args:
      frame: the frame; its colour [H, W, 3] and depth [H, W] are read.

    Returns:
      The frame with depth and all three colour channels set to 0 at every pixel where the depth or a colour
        channel is not finite; the other fields unchanged.
    """
    finite = jnp.isfinite(frame.depth) & jnp.all(jnp.isfinite(frame.color), axis=-1)
    return dataclasses.replace(frame, depth=jnp.where(finite, frame.depth, 0.0),
                               color=jnp.where(finite[..., None], frame.color, 0.0))


def _motion(state: SlamState, params: CBKNN) -> jax.Array:
    """CB-KNN's inter-frame motion gamma from the last two poses (0 before frame 2; ``params``' tau_t, tau_r)."""
    return jnp.where(state.frame >= 2, motion_from_poses(state.w2c_prev2, state.w2c_prev1, params.tau_t, params.tau_r),
                     0.0)


def predicted_pose(state: SlamState) -> jax.Array:
    """The constant-velocity prediction of the next pose (the last pose before frame 2).

    Args:
      state: the state after the previous frames (its last two poses and frame index are read).

    Returns:
      [4, 4] float32 predicted world-to-camera pose of frame ``state.frame``
        (:func:`gsjax.camera.constant_velocity`); ``state.w2c_prev1`` before frame 2.
    """
    return jnp.where(state.frame >= 2, constant_velocity(state.w2c_prev2, state.w2c_prev1), state.w2c_prev1)


def tracking_problem(state: SlamState, color: jax.Array, depth: jax.Array, config: SlamConfig,
                     intrinsics: Intrinsics) -> TrackingProblem:
    """The tracking problem of the frame after ``state``, as :func:`step` poses it: the map, the constant-velocity
    prediction, CB-KNN's motion from the last two poses, and the smooth flag (``paper`` mode and a keyframe; the
    first frame with depth always is one).

    Args:
      state: the state after the previous frames (its map, last two poses, frame index and keyframes are read).
      color: [H, W, 3] the frame's colour in [0, 1].
      depth: [H, W] the frame's depth (m; 0 marks an invalid pixel).
      config: the SLAM config (its ``cbknn`` and ``keyframe_every`` are read).
      intrinsics: the camera at the frame's resolution.

    Returns:
      The frame's ``TrackingProblem`` (:mod:`gsjax.slam.tracking`) with ``state``'s Gaussians, ``color`` and
        ``depth``, the start pose ``w2c_init`` [4, 4] (the constant-velocity prediction; the last pose before frame
        2), ``intrinsics``, ``smooth`` [] bool and CB-KNN's motion ``gamma`` [] in [0, 1] (0 before frame 2).
    """
    return TrackingProblem(state.gaussians, color, depth, predicted_pose(state), intrinsics,
                           jnp.asarray(config.cbknn.smooth_renders) & _is_keyframe(state, config.keyframe_every),
                           _motion(state, config.cbknn.params))


def _is_keyframe(state: SlamState, every: int) -> jax.Array:
    """The frame after ``state`` is a keyframe: by SplaTAM's rule (one ``every`` frames), or the first frame with
    depth (the map's first)."""
    return is_keyframe(state.frame, state.num_frames, every) | (state.keyframes.count == 0)


def step(state: SlamState, frame: Frame, config: SlamConfig, intrinsics: Intrinsics,
         pose: jax.Array | None = None, *,
         track: Callable[[TrackingProblem, jax.Array], GuardedTrack] | None = None) -> tuple[SlamState, StepOutputs]:
    """Process one frame: track, densify, map, store a keyframe (pure, jit-able).

    Args:
      state: the state after the previous frames.
      frame: the frame (its colour and depth are read; its ground-truth pose never is).
      config: the SLAM config.
      intrinsics: the camera at the frame's resolution.
      pose: [4, 4] world-to-camera pose (m) to map the frame at instead of tracking it (mapping-only studies,
        e.g. a map built from ground truth); a pose with a non-finite entry (NaN: not known) or None tracks. A known
        pose is a traced choice: one program maps at known poses and tracks.
      track: ``track(problem, previous_tracking_loss)`` tracks a frame once the map exists; None:
        :func:`gsjax.slam.tracking.track_guarded` with ``config`` (hypergradients pass the implicit fixed point).

    Returns:
      state: the state after the frame.
      outputs: the frame's outputs.
    """
    frame = sanitize_frame(frame)
    usable = jnp.mean(frame.depth > 0) >= config.min_valid_depth
    return jax.lax.cond(usable, lambda s: _process(s, frame, config, intrinsics, pose, track),
                        lambda s: _coast(s, frame, config, pose), state)


def _no_outputs() -> StepOutputs:
    """The zeros a padding frame gives (the dtypes of every step's outputs: ``lax.cond`` checks they match)."""
    zero, no = jnp.float32(0.0), jnp.bool_(False)
    return StepOutputs(w2c=jnp.zeros((4, 4), jnp.float32), tracking_loss=zero, mapping_loss=zero,
                       num_gaussians=jnp.int32(0), added=jnp.int32(0), dropped=jnp.int32(0), keyframe=no, gamma=zero,
                       nonfinite=jnp.int32(0), truncated=no, truncation_residual=zero, skipped=no, retried=no,
                       diverged=no, nonfinite_gaussians=jnp.int32(0), tracking_iters=jnp.int32(0), depth_valid=zero)


def _known(pose) -> jax.Array:
    """[] bool: ``pose`` (a [4, 4] array or None) is a known pose to map at (every entry finite)."""
    return jnp.bool_(False) if pose is None else jnp.all(jnp.isfinite(pose))


def _coast(state: SlamState, frame: Frame, config: SlamConfig, pose) -> tuple[SlamState, StepOutputs]:
    """A frame without usable depth: the predicted (or known) pose, the map and keyframes untouched."""
    predicted = predicted_pose(state)
    w2c = orthonormalize(predicted if pose is None else jnp.where(_known(pose), pose, predicted))
    zero = jnp.float32(0.0)
    outputs = StepOutputs(w2c=w2c, tracking_loss=zero, mapping_loss=zero, num_gaussians=state.gaussians.num_active(),
                          added=jnp.int32(0), dropped=jnp.int32(0), keyframe=jnp.bool_(False),
                          gamma=jnp.asarray(_motion(state, config.cbknn.params), jnp.float32), nonfinite=jnp.int32(0),
                          truncated=jnp.bool_(False), truncation_residual=zero, skipped=jnp.bool_(True),
                          retried=jnp.bool_(False), diverged=jnp.bool_(False), nonfinite_gaussians=jnp.int32(0),
                          tracking_iters=jnp.int32(0), depth_valid=jnp.mean(frame.depth > 0))
    new_state = dataclasses.replace(state, w2c_prev1=w2c, w2c_prev2=state.w2c_prev1,
                                    key=jax.random.split(state.key, 3)[2], frame=state.frame + 1)
    return new_state, outputs


class FrameInput(NamedTuple):
    """A frame with usable depth as :func:`step` tracks it (:func:`frame_input`).

    Attributes:
      state: the state before the frame, its map cleaned of Gaussians with a non-finite parameter and given the
        persistent noise of ``config.noise`` (when its frame has come).
      frame: the frame with the depth noise of ``config.noise``.
      problem: its tracking problem (:func:`tracking_problem`) on the map as tracking sees it (the per-frame noise).
      freed: [] int32 the Gaussians freed for a non-finite parameter.
    """

    state: SlamState
    frame: Frame
    problem: TrackingProblem
    freed: jax.Array


def frame_input(state: SlamState, frame: Frame, config: SlamConfig, intrinsics: Intrinsics) -> FrameInput:
    """What :func:`step` tracks for a frame with usable depth: the cleaned map, the injected noise and the problem.

    Args:
      state: the state after the previous frames.
      frame: the frame (after :func:`sanitize_frame`).
      config: the SLAM config (its ``noise``, ``cbknn`` and ``keyframe_every`` are read).
      intrinsics: the camera at the frame's resolution.

    Returns:
      The frame's :class:`FrameInput`.
    """
    # A map handed in with non-finite parameters (a restored or edited state) is cleaned before tracking sees it.
    stored, freed = state.gaussians.without_nonfinite()
    noisy = compiles_noise(config)  # (static: a program whose levels are all 0 compiles no draw)
    if noisy:
        stored = perturb_stored_map(stored, config.noise, state.frame,
                                    jax.random.fold_in(state.key, NOISE_STREAM + 2))
        frame = add_depth_noise(frame, config.noise, jax.random.fold_in(state.key, NOISE_STREAM))
    state = dataclasses.replace(state, gaussians=stored)
    problem = tracking_problem(state, frame.color, frame.depth, config, intrinsics)
    if noisy:
        problem = problem._replace(gaussians=perturb_map(state.gaussians, config.noise,
                                                         jax.random.fold_in(state.key, NOISE_STREAM + 1)))
    return FrameInput(state, frame, problem, freed)


def _process(state: SlamState, frame: Frame, config: SlamConfig, intrinsics: Intrinsics, pose, track):
    state, frame, problem, freed_before = frame_input(state, frame, config, intrinsics)
    t = state.frame
    started = state.keyframes.count > 0  # the map exists: a frame with depth has been processed
    keyframe = _is_keyframe(state, config.keyframe_every)
    smooth, gamma, w2c_init = problem.smooth, problem.gamma, problem.w2c_init
    key_window, key_map, key_next = jax.random.split(state.key, 3)

    with jax.named_scope("track"):
        known = _known(pose)

        def do_track():
            if track is not None:
                return track(problem, state.previous_tracking_loss)
            return track_guarded(problem, config, state.previous_tracking_loss)

        def at(w2c):
            return lambda: GuardedTrack(w2c, jnp.float32(0.0), jnp.int32(0), jnp.bool_(False), jnp.bool_(False),
                                        jnp.int32(0))

        def unknown():  # tracked once the map exists; the first frame with depth keeps its prediction
            return jax.lax.cond(started, do_track, at(w2c_init))

        # A known pose is taken as it is (and nothing is tracked).
        tracked = unknown() if pose is None else jax.lax.cond(known, at(jnp.where(known, pose, w2c_init)), unknown)
        w2c, tracking_loss, nonfinite = orthonormalize(tracked.w2c), tracked.loss, tracked.nonfinite
        tracked_now = started & ~known & ~tracked.diverged

    with jax.named_scope("densify"):
        smooth_densify = smooth & config.cbknn.densify
        view = render_view(state.gaussians, w2c, intrinsics, config.raster, config.cbknn, smooth_densify, gamma,
                           can_smooth=compiles_smoothing(config))
        inserted = densify(state.gaussians, jax.lax.stop_gradient(view), frame.color, frame.depth, w2c, intrinsics,
                           config.densify)
        gaussians = inserted.gaussians
        scene_radius = jnp.where(started, state.scene_radius, jnp.max(frame.depth) / config.scene_radius_depth_ratio)

    with jax.named_scope("map"):
        window = select_window(key_window, state.keyframes, frame.depth, w2c, intrinsics, config.mapping,
                               config.cbknn)
        views = gather_window_frames(window, state.keyframes, frame.color, frame.depth, w2c, gamma, keyframe)
        def map_now():
            return map_window(key_map, gaussians, views, intrinsics, config, scene_radius, first_map=~started)

        mapped = jax.lax.cond(~started | keyframe | (t % config.mapping.every == 0), map_now,
                              lambda: MapResult(gaussians, jnp.float32(0.0), jnp.int32(0)))
        final_map, freed_after = mapped.gaussians.without_nonfinite()
        freed = freed_before + freed_after

    keyframes = state.keyframes.push(frame.color, frame.depth, w2c, t, gamma, keyframe)
    new_state = dataclasses.replace(
        state,
        gaussians=final_map,
        w2c_prev1=w2c,
        w2c_prev2=state.w2c_prev1,
        keyframes=keyframes,
        key=key_next,
        frame=t + 1,
        scene_radius=scene_radius,
        nonfinite_tracking=state.nonfinite_tracking + nonfinite,
        nonfinite_mapping=state.nonfinite_mapping + mapped.nonfinite,
        dropped_gaussians=state.dropped_gaussians + inserted.dropped,
        nonfinite_gaussians=state.nonfinite_gaussians + freed,
        previous_tracking_loss=jnp.where(tracked_now, tracking_loss, state.previous_tracking_loss),
        retried_frames=state.retried_frames + tracked.retried.astype(jnp.int32),
        diverged_frames=state.diverged_frames + tracked.diverged.astype(jnp.int32),
    )
    outputs = StepOutputs(
        w2c=w2c,
        tracking_loss=tracking_loss,
        mapping_loss=mapped.loss,
        num_gaussians=final_map.num_active(),
        added=inserted.added,
        dropped=inserted.dropped,
        keyframe=keyframe,
        gamma=gamma,
        nonfinite=nonfinite,
        truncated=view.truncated,
        truncation_residual=view.truncation_residual,
        skipped=jnp.bool_(False),
        retried=tracked.retried,
        diverged=tracked.diverged,
        nonfinite_gaussians=freed,
        tracking_iters=tracked.iterations,
        depth_valid=jnp.mean(frame.depth > 0),
    )
    return new_state, outputs


@jax.jit
def run_chunk(state: SlamState, frames: Frame, valid: jax.Array, config: SlamConfig, intrinsics: Intrinsics,
              poses: jax.Array | None = None) -> tuple[SlamState, StepOutputs]:
    """``lax.scan`` of :func:`step` over a chunk of frames stacked along a leading axis (jitted).

    Padding frames (a short last chunk padded to the chunk size, so it reuses the compiled program) leave the
    state untouched and give zero outputs.

    Args:
      state: the state after the previous chunks.
      frames: a Frame with a leading axis of C on every leaf.
      valid: [C] bool, the real frames (False: padding).
      config: the SLAM config.
      intrinsics: the camera at the frames' resolution.
      poses: [C, 4, 4] known world-to-camera poses (m) to map at instead of tracking, NaN where a frame's pose is not
        known (tracked; see :func:`step`); None tracks every frame. The shell always passes an array
        (:func:`unknown_poses`), so that tracking and mapping at known poses are one program.

    Returns:
      state: the state after the chunk.
      outputs: the frames' outputs, each leaf with a leading axis of C.
    """

    def body(state, inputs):
        frame, is_real, pose = inputs
        one = lambda s, f: step(s, f, config, intrinsics, pose)  # noqa: E731

        def skip(state, frame):
            return state, _no_outputs()

        return jax.lax.cond(is_real, one, skip, state, frame)

    return jax.lax.scan(body, state, (frames, valid, poses))


def unknown_poses(count: int) -> jax.Array:
    """[count, 4, 4] float32 NaN: no frame's pose known (:func:`run_chunk` tracks them all).

    Args:
      count: the frames.

    Returns:
      The poses, every entry NaN.
    """
    return jnp.full((count, 4, 4), jnp.nan, jnp.float32)
