"""One SLAM step per frame (track -> densify -> map -> keyframe) and ``lax.scan`` over a chunk of frames.

``step(state, frame)`` is pure and jit-able; :func:`run_chunk` scans it over a stacked chunk of frames. The shell
(:mod:`gsjax.slam.runner`) streams chunks from disk, checkpoints and grows capacity between them. Frame 0 goes
through the same step: on the empty map every valid pixel is densified (SplaTAM's initialisation), tracking is
skipped (the first camera defines the world frame), and the frame is mapped and becomes keyframe 0.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from gsjax.camera import Intrinsics, constant_velocity, orthonormalize
from gsjax.data.frame import Frame
from gsjax.raster.cbknn import motion_from_poses
from gsjax.slam.config import SlamConfig
from gsjax.slam.densify import densify
from gsjax.slam.keyframes import select_window
from gsjax.slam.mapping import map_window, window_views
from gsjax.slam.state import SlamState
from gsjax.slam.tracking import track
from gsjax.slam.views import is_keyframe, render_view


class StepOutputs(NamedTuple):
    """Per-frame outputs of :func:`step` (stacked along the frames by the scan).

    Attributes:
      w2c: [4, 4] estimated world-to-camera pose; tracking_loss: [] loss at that pose (0 at frame 0);
      mapping_loss: [] last mapping iteration's loss; num_gaussians: [] active after the step;
      added, dropped: [] Gaussians densified / not inserted for lack of capacity; keyframe: [] bool;
      gamma: [] motion used by CB-KNN; nonfinite: [] skipped tracking iterations; truncated: [] bool, the
      densification render was truncated by the rasterizer's capacities; residual: [] the largest
      transmittance that truncation left in that render.
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
    residual: jax.Array


def step(state: SlamState, frame: Frame, config: SlamConfig, intrinsics: Intrinsics) -> tuple[SlamState, StepOutputs]:
    """Process one frame (colour, depth, GT validity); returns the new state and the frame's outputs."""
    t = state.frame
    keyframe = is_keyframe(t, state.num_frames, config.keyframe_every)
    smooth = jnp.asarray(config.cbknn.smooth_renders) & keyframe
    gamma = jnp.where(
        t >= 2,
        motion_from_poses(state.w2c_prev2, state.w2c_prev1, config.cbknn.params.tau_t, config.cbknn.params.tau_r),
        0.0,
    )
    key_window, key_map, key_next = jax.random.split(state.key, 3)

    with jax.named_scope("track"):
        w2c_init = jnp.where(t >= 2, constant_velocity(state.w2c_prev2, state.w2c_prev1), state.w2c_prev1)

        def do_track():
            result = track(state.gaussians, frame.color, frame.depth, w2c_init, intrinsics, config, smooth, gamma)
            return result.w2c, result.loss, result.nonfinite

        def skip_track():
            return w2c_init, jnp.float32(0.0), jnp.int32(0)

        w2c, tracking_loss, nonfinite = jax.lax.cond(t > 0, do_track, skip_track)
        w2c = orthonormalize(w2c)

    with jax.named_scope("densify"):
        smooth_densify = smooth & config.cbknn.densify
        view = render_view(state.gaussians, w2c, intrinsics, config, smooth_densify, gamma)
        inserted = densify(state.gaussians, jax.lax.stop_gradient(view), frame.color, frame.depth, w2c, intrinsics,
                           config.densify)
        gaussians = inserted.gaussians
        scene_radius = jnp.where(t == 0, jnp.max(frame.depth) / config.scene_radius_depth_ratio, state.scene_radius)

    with jax.named_scope("map"):
        window = select_window(key_window, state.keyframes, frame.depth, w2c, intrinsics, config.mapping,
                               config.cbknn)
        views = window_views(window, state.keyframes, frame.color, frame.depth, w2c, gamma, keyframe)
        mapped = map_window(key_map, gaussians, views, intrinsics, config, scene_radius, first=t == 0)

    keyframes = state.keyframes.push(frame.color, frame.depth, w2c, t, gamma, keyframe & frame.pose_valid)
    new_state = dataclasses.replace(
        state,
        gaussians=mapped.gaussians,
        w2c_prev1=w2c,
        w2c_prev2=state.w2c_prev1,
        keyframes=keyframes,
        key=key_next,
        frame=t + 1,
        scene_radius=scene_radius,
        nonfinite_tracking=state.nonfinite_tracking + nonfinite,
        nonfinite_mapping=state.nonfinite_mapping + mapped.nonfinite,
        dropped_gaussians=state.dropped_gaussians + inserted.dropped,
    )
    outputs = StepOutputs(
        w2c=w2c,
        tracking_loss=tracking_loss,
        mapping_loss=mapped.loss,
        num_gaussians=mapped.gaussians.num_active(),
        added=inserted.added,
        dropped=inserted.dropped,
        keyframe=keyframe,
        gamma=gamma,
        nonfinite=nonfinite,
        truncated=view.truncated,
        residual=view.residual,
    )
    return new_state, outputs


@jax.jit
def run_chunk(state: SlamState, frames: Frame, valid: jax.Array, config: SlamConfig, intrinsics: Intrinsics):
    """``lax.scan`` of :func:`step` over a chunk of frames stacked along a leading axis -> (state, outputs).

    ``valid`` [C] bool marks real frames; padding frames (a short last chunk padded to the chunk size, so it
    reuses the compiled program) leave the state untouched and give zero outputs.
    """

    def body(state, inputs):
        frame, is_real = inputs

        def skip(state, frame):
            _, zeros = jax.eval_shape(lambda s, f: step(s, f, config, intrinsics), state, frame)
            return state, jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), zeros)

        return jax.lax.cond(is_real, lambda s, f: step(s, f, config, intrinsics), skip, state, frame)

    return jax.lax.scan(body, state, (frames, valid))
