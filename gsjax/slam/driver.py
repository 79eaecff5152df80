"""SLAM over whole sequences in memory (:func:`run`), and the parts every chunked run shares: a chunk's frames
padded to the program's size (:func:`pad_chunk`), the vmapped chunk program of a batch of configs
(:func:`run_batch_chunk`), the capacity growth rule (:func:`dropped_in`, :func:`doubled`) and stacking configs and
states (:func:`stack_trees`). No I/O, no timing: the shell's loop (:mod:`gsjax.app.session.loop`) runs the same chunks
with read-ahead, timing and its hooks.

    from gsjax import slam
    result = slam.run(frames, slam.preset("cpu", 80), intrinsics, seed=0)   # frames: a stacked Frame [T, ...]
    result.w2c  # [T, 4, 4] estimated world-to-camera poses (the SLAM world frame is the first camera)

Capacity: the map has a fixed number of slots. When a chunk could not insert every new Gaussian, the capacity
doubles and the chunk is re-run from its saved starting state, so no Gaussian is dropped; the result equals a run
started with the larger capacity up to float32 rounding.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple, TypeVar, cast

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics
from gsjax.frame import Frame, stack_frames, to_device, without_ground_truth
from gsjax.slam.config import SlamConfig
from gsjax.slam.state import SlamState, grow_capacity, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs, run_chunk, unknown_poses

if TYPE_CHECKING:
    from gsjax.data.sequence import Sequence as FrameSequence

_Tree = TypeVar("_Tree")


def pad_chunk(frames: list[Frame], size: int) -> tuple[Frame, jax.Array]:
    """Stack ``frames`` without their ground truth and pad them to ``size`` frames, on the device.

    The padding repeats the last frame, so a short last chunk reuses the compiled program of a full one.

    Args:
      frames: 1 to ``size`` host frames (numpy leaves) of equal shapes.
      size: the chunk size C.

    Returns:
      frames (Frame): the stacked frames as jax arrays with a leading axis of ``size`` on every leaf (ground-truth
        poses blanked: identity, ``pose_valid`` False).
      valid (jax.Array): [size] bool, the real frames (True for the first ``len(frames)``).
    """
    valid = np.arange(size) < len(frames)
    padded = list(frames) + [frames[-1]] * (size - len(frames))
    return to_device(without_ground_truth(stack_frames(padded))), jnp.asarray(valid)


def chunk_poses(poses: np.ndarray | None, start: int, count: int, size: int) -> jax.Array:
    """The known poses of a chunk's frames, padded as :func:`pad_chunk` pads the frames.

    Args:
      poses: [T, 4, 4] known world-to-camera poses (m) indexed by frame (NaN where not known), or None.
      start: the chunk's first frame.
      count: its real frames.
      size: the chunk size C.

    Returns:
      [C, 4, 4] float32: the poses of frames ``start .. start + count - 1``, the last repeated; all NaN (tracked)
        when ``poses`` is None. Always an array, so tracking and mapping at known poses run one program.
    """
    if poses is None:
        return unknown_poses(size)
    known = np.asarray(poses[start:start + count], np.float32)
    return jnp.asarray(np.concatenate([known, np.repeat(known[-1:], size - count, 0)]))


@jax.jit
def run_batch_chunk(states, frames, valid, configs, intrinsics, poses):
    """:func:`gsjax.slam.system.run_chunk` vmapped over V stacked states and configs, the same frames for all (jitted).

    The program a sweep calls for a group of stacked configs (:class:`Group` with ``stacked``).

    Args:
      states (SlamState): V states stacked on a leading axis (:func:`stack_trees`).
      frames (Frame): the chunk, a leading axis of C on every leaf (:func:`pad_chunk`), shared by all V.
      valid (jax.Array): [C] bool, the real frames (False: padding).
      configs (SlamConfig): V configs with the same static fields, stacked on a leading axis (:func:`stack_trees`).
      intrinsics (Intrinsics): the camera at the frames' resolution, shared by all V.
      poses (jax.Array | None): [C, 4, 4] known world-to-camera poses (m) to map at instead of tracking, shared by
        all V; None tracks.

    Returns:
      states (SlamState): the V states after the chunk, stacked on a leading axis.
      outputs (StepOutputs): their outputs, every leaf [V, C, ...].
    """
    return jax.vmap(run_chunk, in_axes=(0, None, None, 0, None, None))(states, frames, valid, configs, intrinsics,
                                                                        poses)


@jax.jit
def _grow_batch(states, like):
    return jax.vmap(lambda s: grow_capacity(s, like.shape[0]))(states)


# A live camera's run starts with more slots than a recording's 2 H W: growing re-runs the frame with a new program
# shape (a compilation, seconds) while the camera keeps capturing, and those frames are dropped.
LIVE_CAPACITY_PER_PIXEL = 8


def start_capacity(height: int, width: int, live: bool = False) -> int:
    """The map's capacity a run starts from.

    Args:
      height: the image height (px).
      width: the image width (px).
      live: the run is a live camera's.

    Returns:
      The number of Gaussian slots: 2 H W, or 8 H W for a live camera.
    """
    return (LIVE_CAPACITY_PER_PIXEL if live else 2) * height * width


def dropped_in(outputs: StepOutputs, count: int) -> int:
    """The Gaussians a chunk could not insert for lack of free slots: a chunk that dropped any is re-run at
    :func:`doubled` capacity.

    Args:
      outputs: the chunk's outputs ([C, ...], or [V, C, ...] for a stacked group).
      count: its real frames (the first ``count`` of C).

    Returns:
      The Gaussians dropped over the real frames (every entry of a stacked group), on the host.
    """
    return int(np.sum(np.asarray(outputs.dropped)[..., :count]))


def capacity_of(state: SlamState, stacked: bool = False) -> int:
    """The map's capacity of a state.

    Args:
      state: a state, or (``stacked``) V states stacked on a leading axis.
      stacked: whether ``state`` is V stacked states.

    Returns:
      The number of Gaussian slots (of each of the V states).
    """
    return int(state.gaussians.means.shape[1 if stacked else 0])


def doubled(state: SlamState, stacked: bool = False) -> SlamState:
    """The growth rule of every run: the map's capacity doubled, the new slots free.

    Args:
      state: a state, or (``stacked``) V states stacked on a leading axis.
      stacked: whether ``state`` is V stacked states.

    Returns:
      The state (every entry of V stacked states) at twice the capacity.
    """
    capacity = 2 * capacity_of(state, stacked)
    return _grow_batch(state, jnp.zeros(capacity)) if stacked else grow_capacity(state, capacity)


def concat_outputs(chunks: list[StepOutputs], batched: bool = False) -> StepOutputs:
    """Per-chunk outputs joined along the frame axis.

    Args:
      chunks: the chunks' :class:`StepOutputs` (numpy leaves), in frame order.
      batched: the outputs are a stacked group's, [V, count, ...], joined along axis 1; False: [count, ...],
        joined along axis 0.

    Returns:
      The joined :class:`StepOutputs` of numpy arrays, [T, ...] or (``batched``) [V, T, ...], T the chunks' frames
        together.
    """
    axis = 1 if batched else 0
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=axis), *chunks)


# ------------------------------------------------------------------------------------------- in memory


class RunResult(NamedTuple):
    """What :func:`run` returns.

    Attributes:
      w2c: [T, 4, 4] float32 estimated world-to-camera poses (m), the outputs' ``w2c``.
      outputs: the per-frame :class:`StepOutputs`, numpy arrays with a leading axis of T.
      state: the final :class:`SlamState` (the map, the keyframes, the counters).
    """

    w2c: np.ndarray
    outputs: StepOutputs
    state: SlamState


def host_frames(frames: Frame | Sequence[Frame]) -> list[Frame]:
    """Frames as a list of host (numpy) frames.

    Args:
      frames: a stacked :class:`Frame` ([T, ...] leaves), a single frame, or a sequence of frames.

    Returns:
      One numpy :class:`Frame` per frame.
    """
    if isinstance(frames, Frame):
        n = np.shape(frames.index)[0] if np.ndim(frames.index) else None
        if n is None:
            return [jax.tree_util.tree_map(np.asarray, frames)]
        host = jax.tree_util.tree_map(np.asarray, frames)
        return [jax.tree_util.tree_map(lambda x, i=i: x[i], host) for i in range(n)]
    return [jax.tree_util.tree_map(np.asarray, f) for f in frames]


def run(
    frames: Frame | Sequence[Frame] | FrameSequence,
    config: SlamConfig,
    intrinsics: Intrinsics,
    *,
    seed: int = 0,
    poses: np.ndarray | None = None,
    chunk: int = 8,
    capacity: int | None = None,
    call: Callable | None = None,
) -> RunResult:
    """SLAM over ``frames`` in memory, no I/O: the same chunk loop (and so the same result) as ``gsjax run``.

    Args:
      frames: a stacked :class:`Frame` ([T, ...] leaves), a sequence of frames, or a :class:`gsjax.data.Sequence`.
        Their ground-truth poses are ignored.
      config: the SLAM config.
      intrinsics: the camera at the frames' resolution.
      seed: PRNG seed (mapping-window and pixel sampling).
      poses: optional [T, 4, 4] world-to-camera poses (m) to map with instead of tracking.
      chunk: frames per jitted scan.
      capacity: initial map capacity in Gaussians (default 2 H W, grown as needed).
      call: ``call(run_chunk, *args)`` runs each chunk (the shell's exported program); None: directly.

    Returns:
      The T estimated poses, the per-frame outputs and the final state.

    Raises:
      ValueError: there is no frame, or ``poses`` is not [T, 4, 4].
    """
    read: Callable[[int], Frame]
    if hasattr(frames, "read_host"):
        sequence = cast("FrameSequence", frames)
        read, total = sequence.read_host, len(sequence)
    else:
        items = host_frames(frames)
        read, total = items.__getitem__, len(items)
    if total < 1:
        raise ValueError("gsjax.slam.run needs at least one frame")
    if poses is not None and np.shape(poses) != (total, 4, 4):
        raise ValueError(f"poses must be [T, 4, 4] = [{total}, 4, 4], got {np.shape(poses)}")
    height, width = intrinsics.height, intrinsics.width
    state = initial_state(capacity or start_capacity(height, width), height, width,
                          keyframe_capacity_for(total, config.keyframe_every), total, seed)
    parts = []
    for start in range(0, total, chunk):
        host = [read(i) for i in range(start, min(start + chunk, total))]
        count = len(host)
        stacked, valid = pad_chunk(host, chunk)
        while True:
            args = (state, stacked, valid, config, intrinsics, chunk_poses(poses, start, count, chunk))
            new_state, out = call(run_chunk, *args) if call is not None else run_chunk(*args)
            out = jax.device_get(out)
            if dropped_in(out, count) == 0:
                break
            state = doubled(state)
        state = new_state
        parts.append(jax.tree_util.tree_map(lambda x, n=count: np.asarray(x)[:n], out))
    outputs = concat_outputs(parts)
    return RunResult(np.asarray(outputs.w2c), outputs, state)


# ------------------------------------------------------------------------------------------- batches


def stack_trees(trees: list[_Tree]) -> _Tree:
    """Trees of one structure stacked on a new leading axis (configs with the same static fields, states of one shape).

    Args:
      trees: V >= 1 pytrees of one structure (static fields included) and leaf shapes.

    Returns:
      A tree of that structure whose every leaf is the V leaves stacked, a jax array [V, ...].

    Raises:
      ValueError: the trees differ in structure or static fields.
    """
    structure = jax.tree_util.tree_structure(trees[0])
    for tree in trees[1:]:
        if jax.tree_util.tree_structure(tree) != structure:  # type: ignore[operator]  # PyTreeDef defines !=
            raise ValueError("stack_trees: the trees differ in structure or static fields")
    return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def unstack_tree(tree: _Tree, index: int) -> _Tree:
    """Entry ``index`` of a batched tree.

    Args:
      tree: a pytree whose every leaf has a leading axis (V, as :func:`stack_trees` makes).
      index: the entry to take, in [0, V).

    Returns:
      A tree of the same structure with every leaf ``leaf[index]``.
    """
    return jax.tree_util.tree_map(lambda x: x[index], tree)


def static_key(config: SlamConfig) -> jax.tree_util.PyTreeDef:
    """What decides a config's compiled program: its tree structure, which holds every static field.

    Args:
      config: the SLAM config.

    Returns:
      The config's pytree structure; two configs with equal keys can be stacked (:func:`stack_trees`) and run by
        one program.
    """
    return jax.tree_util.tree_structure(config)
