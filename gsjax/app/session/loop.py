"""The shell's one SLAM loop: frames from a source (a recording, a live camera) through the SLAM chunk program a chunk
at a time, for one config or a batch of configs over the same frames, with capacity growth.

``gsjax run`` and its ``--resume`` (:mod:`gsjax.app.session.runner`), the live camera
(:mod:`gsjax.app.session.live`) and ``gsjax sweep`` (:mod:`gsjax.app.sweep.grid`) all run :func:`chunk_loop`; each
chunk goes to a :class:`gsjax.app.session.recorder.Recorder` per config, which writes the run's folder. The core's
in-memory :func:`gsjax.slam.run` runs the same chunks with the same growth rule, without the timing, read-ahead and
hooks kept here.

Capacity: the map has a fixed number of slots. When a chunk could not insert every new Gaussian (in any config of
a group), the group's capacity doubles (:func:`gsjax.slam.driver.doubled`) and the chunk is re-run from its saved
starting state, so no Gaussian is dropped.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterable, Iterator
from typing import NamedTuple

import jax
import numpy as np

from gsjax.camera import Intrinsics
from gsjax.frame import Frame
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import capacity_of, chunk_poses, doubled, dropped_in, pad_chunk, run_batch_chunk
from gsjax.slam.state import SlamState
from gsjax.slam.system import StepOutputs, run_chunk


class Group(NamedTuple):
    """One program call's worth of a batch: a state and its config, or V of each stacked and run as one program.

    Attributes:
      state: the :class:`SlamState` to continue from, or, when ``stacked``, V states stacked on a leading axis
        (:func:`gsjax.slam.driver.stack_trees`).
      config: its :class:`SlamConfig`, or, when ``stacked``, V configs with the same static fields stacked on a
        leading axis.
      stacked: whether ``state`` and ``config`` are stacked and run vmapped
        (:func:`gsjax.slam.driver.run_batch_chunk`); False by default.
    """

    state: SlamState
    config: SlamConfig
    stacked: bool = False


class Runtime(NamedTuple):
    """How the loop reaches the devices.

    Attributes:
      call: ``call(run_chunk, *args)`` runs a one-config group's chunk (the shell passes
        :meth:`gsjax.app.runtime.programs.ExportedPrograms.call`, which skips tracing in a warm process); None: a
        plain call.
      place: ``place(group_index, state)`` puts a grown state back where the group lives; None: JAX's default
        placement.
      fetch: brings a chunk's outputs to the host (a multi-process sweep gathers a group sharded over processes).
    """

    call: Callable | None = None
    place: Callable | None = None
    fetch: Callable = jax.device_get


class Chunk(NamedTuple):
    """One chunk of :func:`chunk_loop`, once every group has run it.

    Attributes:
      start: the index of its first frame.
      count: its number of real frames (at most the chunk size; the last chunk may be shorter).
      frames: the ``count`` host frames read (with their ground truth, for the shell's warnings), shared by every
        group.
      states: per group, the :class:`SlamState` after the chunk (V stacked states for a stacked group), on the device.
      outputs: per group, the :class:`StepOutputs` of the real frames as numpy, [count, ...], or [V, count, ...] for a
        stacked group.
      seconds: wall time (s) from stacking the chunk's frames and launching every group's chunk until all their
        outputs are on the host (the next chunk's frames are read meanwhile), the scans redone for capacity aside.
      regrow_seconds: wall time (s) of the scans redone for capacity, summed over the groups.
      read_seconds: wall time (s) of reading its frames (behind the previous chunk's scans, except for the first).
    """

    start: int
    count: int  # type: ignore[assignment]  # shadows tuple.count: the name is public
    frames: list
    states: list
    outputs: list
    seconds: float
    regrow_seconds: float
    read_seconds: float


def sequence_frames(sequence, start: int = 0) -> Iterator[Frame]:
    """The host frames of a :class:`gsjax.data.Sequence` from frame ``start`` to its end."""
    return (sequence.read_host(i) for i in range(start, len(sequence)))


def _call(group: Group, frames, valid, intrinsics, poses, call: Callable | None):
    if group.stacked:
        return run_batch_chunk(group.state, frames, valid, group.config, intrinsics, poses)
    if call is not None:
        return call(run_chunk, group.state, frames, valid, group.config, intrinsics, poses)
    return run_chunk(group.state, frames, valid, group.config, intrinsics, poses)


def chunk_loop(
    groups: list[Group],
    frames: Iterable[Frame],
    intrinsics: Intrinsics,
    *,
    chunk: int = 8,
    start: int = 0,
    poses: np.ndarray | None = None,
    on_grow: Callable[[int, int, int, int, int], None] | None = None,
    runtime: Runtime = Runtime(),
) -> Iterator[Chunk]:
    """Run ``frames`` through SLAM for every group, ``chunk`` frames per program call, each chunk's frames read once.

    Every group's chunk is dispatched before any result is awaited, so groups placed on different devices run at
    the same time, and the next chunk's frames are read (from a file, or waited for from a camera) while the current
    one runs. A group whose chunk dropped Gaussians is grown (capacity doubled, every entry of a stacked group) and
    re-run on its own, as often as needed.

    Args:
      groups: the groups to run, each a state and its config (:class:`Group`).
      frames: the host frames from frame ``start`` on (:func:`sequence_frames`, or a camera's); the loop ends when
        they do. Their ground-truth poses are blanked before they reach the core.
      intrinsics: the camera at the frames' resolution.
      chunk: frames per program call (C); a short last chunk is padded to it.
      start: the index of the first frame (the groups' states are those after frames ``0 .. start - 1``).
      poses: [T, 4, 4] known world-to-camera poses (m), indexed by frame, to map at instead of tracking (NaN where
        not known: tracked); None tracks.
      on_grow: ``on_grow(group, dropped, first, last, new_capacity)`` is told before a group's chunk is re-run with a
        doubled capacity: the group's index, the Gaussians dropped over the chunk (all its entries), the chunk's
        first and last frame, the new capacity; None: nothing.
      runtime: how the chunks are called, placed and fetched (:class:`Runtime`).

    Yields:
      Each chunk's :class:`Chunk` once every group has run it, in frame order.
    """
    place = runtime.place or (lambda index, state: state)
    states = [g.state for g in groups]
    source = iter(frames)

    def read() -> tuple[list, float]:
        """The host frames of the next chunk (fewer at the end, none past it), and the seconds spent reading them."""
        t0 = time.perf_counter()
        host = list(itertools.islice(source, chunk))
        return host, time.perf_counter() - t0

    done = start
    host, read_s = read()
    while host:
        count = len(host)
        t0 = time.perf_counter()
        stacked, valid = pad_chunk(host, chunk)
        known = chunk_poses(poses, done, count, chunk)
        launched = [_call(g._replace(state=s), stacked, valid, intrinsics, known, runtime.call)
                    for g, s in zip(groups, states)]
        # Read on the host (no device transfer, which would wait for this chunk) while the chunk runs (dispatch is
        # asynchronous), so reading overlaps the SLAM work.
        upcoming, upcoming_read_s = read()
        new_states, outputs, regrow_s = [], [], 0.0
        for index, (group, (new_state, out)) in enumerate(zip(groups, launched)):
            out = runtime.fetch(out)
            state = states[index]
            while (dropped := dropped_in(out, count)) > 0:
                t1 = time.perf_counter()
                state = doubled(state, group.stacked)
                if on_grow is not None:
                    on_grow(index, dropped, done, done + count - 1, capacity_of(state, group.stacked))
                state = place(index, state)
                new_state, out = _call(group._replace(state=state), stacked, valid, intrinsics, known, runtime.call)
                out = runtime.fetch(out)
                regrow_s += time.perf_counter() - t1
            new_states.append(new_state)
            # Per-frame fields are [C, ...], or [V, C, ...] after vmap over the scan.
            outputs.append(jax.tree_util.tree_map(
                lambda x, s=group.stacked: np.asarray(x)[:, :count] if s else np.asarray(x)[:count], out))
        seconds = time.perf_counter() - t0 - regrow_s
        states = new_states
        yield Chunk(done, count, host, states, outputs, seconds, regrow_s, read_s)
        done += count
        host, read_s = upcoming, upcoming_read_s


def one_config(chunk: Chunk) -> tuple[SlamState, StepOutputs]:
    """The state and outputs of a one-group, unstacked :func:`chunk_loop`'s chunk."""
    return chunk.states[0], chunk.outputs[0]
