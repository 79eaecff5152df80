"""The chunk loop: frames streamed through the jitted SLAM scan a chunk at a time, with capacity growth, for one
config (:func:`chunk_loop`) or a batch of configs over the same frames (:func:`batch_chunk_loop`: each group of
the batch is one config, or several stacked and vmapped into one program). ``gsjax run``, ``gsjax sweep``,
``gsjax landscape`` and the in-memory :func:`run` all drive SLAM through :func:`batch_chunk_loop`.

    from gsjax import slam
    result = slam.run(frames, slam.preset("cpu", 80), intrinsics, seed=0)   # frames: a stacked Frame [T, ...]
    result.w2c  # [T, 4, 4] estimated world-to-camera poses (the SLAM world frame is the first camera)

Capacity: the map has a fixed number of slots. When a chunk could not insert every new Gaussian (in any config
of a batch), the capacity doubles and the chunk is re-run from its saved starting state, so no Gaussian is
dropped; the result equals a run started with the larger capacity up to float32 rounding.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, NamedTuple, TypeVar, cast

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics
from gsjax.data.frame import Frame, stack_frames, to_device, without_ground_truth
from gsjax.slam.config import SlamConfig
from gsjax.slam.state import SlamState, grow_capacity, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs, run_chunk, unknown_poses

if TYPE_CHECKING:
    from gsjax.data.sequence import Sequence as FrameSequence

_Tree = TypeVar("_Tree")


class Chunk(NamedTuple):
    """One processed chunk, as :func:`chunk_loop` yields it.

    Attributes:
      start: the index of its first frame in the sequence.
      count: its number of real frames (at most the chunk size; the last chunk may be shorter).
      frames: the ``count`` host frames read (with their ground truth, for the shell's warnings).
      state: the state after the chunk.
      outputs: :class:`StepOutputs` of the real frames as numpy, [count, ...].
      capacity: the map capacity (Gaussian slots) after the chunk.
      seconds: wall time of the chunk's final scan (s), from its launch until its outputs are on the host (the next
        chunk's frames are read meanwhile).
      regrow_seconds: wall time (s) of the scans redone for capacity (growing the map and re-running the chunk).
      read_seconds: wall time (s) of reading its frames (behind the previous chunk's scan, except for the first
        chunk).
    """

    start: int
    count: int  # type: ignore[assignment]  # shadows tuple.count: the name is public
    frames: list
    state: SlamState
    outputs: StepOutputs
    capacity: int
    seconds: float
    regrow_seconds: float
    read_seconds: float


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


def chunk_loop(
    state: SlamState,
    read_frame: Callable[[int], Frame],
    total: int,
    config: SlamConfig,
    intrinsics: Intrinsics,
    *,
    chunk: int = 8,
    start: int = 0,
    poses: np.ndarray | None = None,
    on_grow: Callable[[int, int, int, int], None] | None = None,
    call: Callable | None = None,
) -> Iterator[Chunk]:
    """Run frames ``start`` to ``total - 1`` through SLAM for one config, ``chunk`` frames per scan.

    :func:`batch_chunk_loop` with a single unstacked :class:`Group`. When a chunk dropped Gaussians, the map's
    capacity doubles (as often as needed) and the chunk is re-run from its starting state.

    Args:
      state: the state after frames ``0 .. start - 1`` (:func:`gsjax.slam.state.initial_state` when ``start`` is 0).
      read_frame: ``read_frame(i)`` gives host frame ``i``; its ground-truth pose is blanked before it reaches the
        core.
      total: the sequence's length; the last frame processed is ``total - 1``.
      config: the SLAM config.
      intrinsics: the camera at the frames' resolution.
      chunk: frames per jitted scan (C); a short last chunk is padded to it.
      start: the first frame to process.
      poses: [total, 4, 4] known world-to-camera poses (m), indexed by frame, to map at instead of tracking
        (mapping-only studies); None tracks.
      on_grow: ``on_grow(dropped, first, last, new_capacity)`` is told before a chunk is re-run with a doubled
        capacity: the Gaussians dropped over the chunk, its first and last frame, the new capacity; None: nothing.
      call: how a chunk's ``run_chunk`` is called (``call(run_chunk, *args)``, as :func:`batch_chunk_loop`);
        None calls it directly.

    Yields:
      Each chunk's :class:`Chunk` once it has run, in frame order.
    """
    for batch in batch_chunk_loop([Group(state, config)], read_frame, total, intrinsics, chunk=chunk, start=start,
                                  poses=poses, on_grow=lambda group, *info: on_grow and on_grow(*info), call=call):
        yield Chunk(batch.start, batch.count, batch.frames, batch.states[0], batch.outputs[0],
                    _capacity(batch.states[0], False), batch.seconds, batch.regrow_seconds, batch.read_seconds)


class Group(NamedTuple):
    """One program call's worth of a batch: a state and its config, or V of each stacked and run as one program.

    Attributes:
      state: the :class:`SlamState` to continue from, or, when ``stacked``, V states stacked on a leading axis
        (:func:`stack_trees`).
      config: its :class:`SlamConfig`, or, when ``stacked``, V configs with the same static fields stacked on a
        leading axis.
      stacked: whether ``state`` and ``config`` are stacked and run vmapped (:func:`run_batch_chunk`); False by
        default.
    """

    state: SlamState
    config: SlamConfig
    stacked: bool = False


class BatchChunk(NamedTuple):
    """One chunk of :func:`batch_chunk_loop`: as :class:`Chunk`, with a new state and outputs per group.

    Attributes:
      start: the index of its first frame in the sequence.
      count: its number of real frames (at most the chunk size; the last chunk may be shorter).
      frames: the ``count`` host frames read (with their ground truth), shared by every group.
      states: per group, the :class:`SlamState` after the chunk (V stacked states for a stacked group), on the
        device.
      outputs: per group, the :class:`StepOutputs` of the real frames as numpy, [count, ...], or [V, count, ...]
        for a stacked group.
      seconds: wall time (s) from stacking the chunk's frames and launching every group's chunk until all their
        outputs are on the host (the next chunk's frames are read meanwhile), the scans redone for capacity aside.
      regrow_seconds: wall time (s) of the scans redone for capacity, summed over the groups.
      read_seconds: wall time (s) of reading its frames (behind the previous chunk's scans, except for the first
        chunk).
    """

    start: int
    count: int  # type: ignore[assignment]  # shadows tuple.count: the name is public
    frames: list
    states: list
    outputs: list
    seconds: float
    regrow_seconds: float
    read_seconds: float


def _call(group: Group, frames, valid, intrinsics, poses, call: Callable | None):
    if group.stacked:
        return run_batch_chunk(group.state, frames, valid, group.config, intrinsics, poses)
    if call is not None:
        return call(run_chunk, group.state, frames, valid, group.config, intrinsics, poses)
    return run_chunk(group.state, frames, valid, group.config, intrinsics, poses)


def batch_chunk_loop(
    groups: list[Group],
    read_frame: Callable[[int], Frame],
    total: int,
    intrinsics: Intrinsics,
    *,
    chunk: int = 8,
    start: int = 0,
    poses: np.ndarray | None = None,
    on_grow: Callable[[int, int, int, int, int], None] | None = None,
    place: Callable | None = None,
    fetch: Callable = jax.device_get,
    call: Callable | None = None,
) -> Iterator[BatchChunk]:
    """:func:`chunk_loop` for several groups over the same frames, each chunk's frames read once.

    Every group's chunk is dispatched before any result is awaited, so groups placed on different devices run at
    the same time. The next chunk's frames are read on the host while the current one runs. A group whose chunk
    dropped Gaussians is grown (capacity doubled, every entry of a stacked group) and re-run on its own, as often
    as needed.

    Args:
      groups: the groups to run, each a state and its config (:class:`Group`).
      read_frame: ``read_frame(i)`` gives host frame ``i``; its ground-truth pose is blanked before it reaches the
        core.
      total: the sequence's length; the last frame processed is ``total - 1``.
      intrinsics: the camera at the frames' resolution.
      chunk: frames per jitted scan (C); a short last chunk is padded to it.
      start: the first frame to process (the groups' states are those after frames ``0 .. start - 1``).
      poses: [total, 4, 4] known world-to-camera poses (m), indexed by frame, to map at instead of tracking (NaN
        where not known: tracked); None tracks.
      on_grow: ``on_grow(group, dropped, first, last, new_capacity)`` is told before a group's chunk is re-run with a
        doubled capacity: the group's index, the Gaussians dropped over the chunk (all its entries), the chunk's
        first and last frame, the new capacity; None: nothing.
      place: ``place(group_index, state)`` puts a grown state back where the group lives; None: JAX's default
        placement.
      fetch: brings a chunk's outputs to the host (a multi-process sweep gathers a group sharded over processes);
        ``jax.device_get`` by default.
      call: ``call(run_chunk, *args)`` runs a one-config group's chunk; None: ``run_chunk(*args)``. The shell passes
        :meth:`gsjax.app.programs.ExportedPrograms.call`, which skips tracing in a warm process.

    Yields:
      Each chunk's :class:`BatchChunk` once every group has run it, in frame order.
    """
    place = place or (lambda index, state: state)
    states = [g.state for g in groups]

    def read(first: int) -> tuple[list, float]:
        """The host frames of the chunk from frame ``first``, and the seconds spent reading them."""
        t0 = time.perf_counter()
        host = [read_frame(i) for i in range(first, min(first + chunk, total))]
        return host, time.perf_counter() - t0

    done = start
    upcoming = read(done) if done < total else None
    while done < total:
        assert upcoming is not None  # read while done < total
        host, read_s = upcoming
        count = len(host)
        t0 = time.perf_counter()
        frames, valid = pad_chunk(host, chunk)
        # Always an array (NaN where not known): tracking and mapping at known poses run one program.
        chunk_poses = unknown_poses(chunk)
        if poses is not None:
            host_poses = np.asarray(poses[done:done + count], np.float32)
            chunk_poses = jnp.asarray(np.concatenate([host_poses, np.repeat(host_poses[-1:], chunk - count, 0)]))
        launched = [_call(g._replace(state=s), frames, valid, intrinsics, chunk_poses, call)
                    for g, s in zip(groups, states)]
        # The next chunk is read (on the host: no device transfer, which would wait for this chunk) while this one
        # runs (dispatch is asynchronous), so reading overlaps the SLAM work.
        upcoming = read(done + count) if done + count < total else None
        new_states, outputs, regrow_s = [], [], 0.0
        for index, (group, (new_state, out)) in enumerate(zip(groups, launched)):
            out = fetch(out)
            state = states[index]
            while (dropped := int(np.sum(np.asarray(out.dropped)[..., :count]))) > 0:
                t1 = time.perf_counter()
                capacity = 2 * _capacity(state, group.stacked)
                if on_grow is not None:
                    on_grow(index, dropped, done, done + count - 1, capacity)
                state = place(index, _grow_batch(state, jnp.zeros(capacity)) if group.stacked
                              else grow_capacity(state, capacity))
                new_state, out = _call(group._replace(state=state), frames, valid, intrinsics, chunk_poses, call)
                out = fetch(out)
                regrow_s += time.perf_counter() - t1
            new_states.append(new_state)
            # Per-frame fields are [C, ...], or [V, C, ...] after vmap over the scan.
            outputs.append(jax.tree_util.tree_map(
                lambda x: np.asarray(x)[:, :count] if group.stacked else np.asarray(x)[:count], out))
        seconds = time.perf_counter() - t0 - regrow_s
        states = new_states
        yield BatchChunk(done, count, host, states, outputs, seconds, regrow_s, read_s)
        done += count


def _capacity(state: SlamState, batched: bool) -> int:
    return int(state.gaussians.means.shape[1 if batched else 0])


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


def _frame_list(frames) -> list[Frame]:
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
      call: how each chunk's ``run_chunk`` is called (:func:`batch_chunk_loop`; None: directly).

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
        items = _frame_list(frames)
        read, total = items.__getitem__, len(items)
    if total < 1:
        raise ValueError("gsjax.slam.run needs at least one frame")
    if poses is not None and np.shape(poses) != (total, 4, 4):
        raise ValueError(f"poses must be [T, 4, 4] = [{total}, 4, 4], got {np.shape(poses)}")
    height, width = intrinsics.height, intrinsics.width
    state = initial_state(capacity or 2 * height * width, height, width,
                          keyframe_capacity_for(total, config.keyframe_every), total, seed)
    parts, chunk_state = [], state
    for done in chunk_loop(state, read, total, config, intrinsics, chunk=chunk, poses=poses, call=call):
        parts.append(done.outputs)
        chunk_state = done.state
    outputs = concat_outputs(parts)
    return RunResult(np.asarray(outputs.w2c), outputs, chunk_state)


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
