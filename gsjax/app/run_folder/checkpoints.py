"""Checkpoints of a SLAM run: what a checkpoint writes does not grow with the run, and the newest readable one
is restored.

Layout under ``<out>/checkpoints``:

* ``<step>/`` (orbax, one per checkpoint, the newest ``keep`` kept): the state without the keyframe images
  (the map, recent poses, keyframe poses and counters, RNG) and the run's :class:`RunLedger` as JSON (the run
  folder's format, frames done, capacity, the run's record, timings, the checkpoints so far). ``step`` is the number
  of frames done. Orbax writes into a temporary directory and renames it when complete, so a step directory is
  either whole or absent. Checkpoints of another run folder format are refused (:class:`OlderRunError`).
* ``frames/<a>-<b>.npz``: the per-frame outputs of frames a..b-1, written once by the checkpoint that reached b.
* ``keyframes/<slot>.npz``: keyframe ``slot``'s colour and depth, written once by the checkpoint after it was
  stored.

So a checkpoint writes the map plus the outputs and keyframes new since the previous one. Segment files are
written atomically (:mod:`gsjax.io.atomic`) before the step that refers to them, and the step is the commit:
files a killed checkpoint left without a step are rewritten, identically, when the run gets there again. The npz
members carry CRC32s, so a damaged file fails to load. :meth:`Checkpoints.restore` tries the steps newest first
and falls back, with a warning, past one it cannot read.
"""

from __future__ import annotations

import dataclasses
import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from gsjax.app.run_folder.layout import RunDirError
from gsjax.eval.run_input import RUN_FORMAT, older_run_message
from gsjax.eval.run_metrics import CheckpointSummary
from gsjax.io.atomic import atomic_write_bytes, remove_stale_temporaries
from gsjax.slam.state import KeyframeBuffer, SlamState
from gsjax.slam.system import StepOutputs

_IMAGES = ("color", "depth")  # the keyframe fields stored as files, one per slot


class OlderRunError(RunDirError):
    """Checkpoints of another run folder format (:data:`gsjax.eval.run_input.RUN_FORMAT`): not resumed, not
    fallen back past."""


@dataclasses.dataclass
class CheckpointLedger:
    """The checkpoints a run has written: how often (frames), how many, their total and largest time (s), the last
    and the largest size (bytes)."""

    every: int = 0
    count: int = 0
    seconds_total: float = 0.0
    seconds_max: float = 0.0
    bytes_last: int = 0
    bytes_max: int = 0

    def add(self, seconds: float, written: int) -> None:
        """Count a checkpoint that took ``seconds`` and wrote ``written`` bytes."""
        self.count += 1
        self.seconds_total += seconds
        self.seconds_max = max(self.seconds_max, seconds)
        self.bytes_last, self.bytes_max = written, max(self.bytes_max, written)

    def summary(self) -> CheckpointSummary | None:
        """What ``metrics.json`` reports, or None when the run wrote no checkpoint."""
        if not self.count:
            return None
        return CheckpointSummary(count=self.count, every_frames=self.every, mean_s=self.seconds_total / self.count,
                                 max_s=self.seconds_max, last_bytes=self.bytes_last, max_bytes=self.bytes_max)


@dataclasses.dataclass
class RunLedger:
    """What a run has done beyond its state, kept in every checkpoint (as JSON, the field names as keys) so that a
    resumed run continues it exactly.

    Attributes:
      capacity: the map's capacity; record: what a resume must match (:meth:`gsjax.eval.run_input.RunInput.resume_key`).
      frames_done: frames processed; timings: seconds per stage so far; first_chunk_s: the first chunk's seconds.
      depth_units_checked: whether the depth unit check ran.
      checkpoints: the checkpoints so far; segments: [a, b) frame ranges of the per-frame output files;
      keyframes_saved: keyframe slots whose images are on disk.
      format: the run folder's format (:data:`gsjax.eval.run_input.RUN_FORMAT`).
    """

    capacity: int
    record: dict
    frames_done: int = 0
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    first_chunk_s: float | None = None
    depth_units_checked: bool = False
    checkpoints: CheckpointLedger = dataclasses.field(default_factory=CheckpointLedger)
    segments: list[list[int]] = dataclasses.field(default_factory=list)
    keyframes_saved: int = 0
    format: int = RUN_FORMAT

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, value: dict) -> RunLedger:
        """The ledger a checkpoint holds; ValueError when it is of another run folder format."""
        if value.get("format") != RUN_FORMAT:
            raise ValueError(f"format {value.get('format')}")
        return cls(**dict(value, checkpoints=CheckpointLedger(**value["checkpoints"])))


class Restored(NamedTuple):
    """A restored checkpoint: ``step`` (frames done), ``state``, ``ledger`` and ``outputs`` (the per-frame outputs
    of frames 0..step-1, [step, ...] numpy arrays)."""

    step: int
    state: SlamState
    ledger: RunLedger
    outputs: StepOutputs


def _without_images(state: SlamState) -> dict:
    """The state as a plain dict tree for orbax, the keyframe images left out."""
    tree = {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}
    tree["keyframes"] = {f.name: getattr(state.keyframes, f.name) for f in dataclasses.fields(KeyframeBuffer)
                         if f.name not in _IMAGES}
    return tree


def _npz_bytes(arrays: dict) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _load_npz(path: Path) -> dict:
    """Every member of ``path`` (reading each checks its CRC32)."""
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


class Checkpoints:
    """The checkpoints of one run directory: :meth:`save` after a chunk, :meth:`restore` on ``--resume``."""

    def __init__(self, directory: str | os.PathLike, keep: int = 2):
        self.directory = Path(directory).resolve()
        self.directory.mkdir(parents=True, exist_ok=True)
        for sub in ("frames", "keyframes"):
            (self.directory / sub).mkdir(exist_ok=True)
            remove_stale_temporaries(self.directory / sub)
        self._manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
        )

    # ---------------------------------------------------------------------------------------------- writing

    def save(self, state: SlamState, ledger: RunLedger, outputs: StepOutputs) -> int:
        """Write the checkpoint after ``ledger.frames_done`` frames; returns the bytes written.

        ``outputs``: the per-frame outputs ([b - a, ...] numpy) of the frames since the previous checkpoint,
        ``ledger.segments[-1] == [a, b]``; keyframe slots from ``ledger.keyframes_saved`` to the state's count are
        written now, and ``ledger.keyframes_saved`` is advanced to it.
        """
        step = int(ledger.frames_done)
        start, end = ledger.segments[-1]
        written = 0
        path = self.directory / "frames" / f"{start:06d}-{end:06d}.npz"
        written += len(data := _npz_bytes({k: np.asarray(v) for k, v in outputs._asdict().items()}))
        atomic_write_bytes(path, data)
        count = int(state.keyframes.count)
        for slot in range(ledger.keyframes_saved, count):
            images = {name: np.asarray(getattr(state.keyframes, name)[slot]) for name in _IMAGES}
            written += len(data := _npz_bytes(images))
            atomic_write_bytes(self.directory / "keyframes" / f"{slot:05d}.npz", data)
        ledger.keyframes_saved = count
        self._manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(_without_images(state)),
                                                         meta=ocp.args.JsonSave(ledger.to_json())), force=True)
        self._manager.wait_until_finished()
        return written + _tree_size(self.directory / str(step))

    # ---------------------------------------------------------------------------------------------- reading

    def steps(self) -> list[int]:
        """Complete checkpoints' steps, newest first."""
        return sorted(self._manager.all_steps(), reverse=True)

    def latest(self) -> int | None:
        steps = self.steps()
        return steps[0] if steps else None

    def read_ledger(self, step: int) -> RunLedger:
        """Checkpoint ``step``'s ledger; :class:`OlderRunError` when it is of another run folder format."""
        meta = self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta
        if meta.get("format") != RUN_FORMAT:
            raise OlderRunError(f"--resume: {older_run_message(self.directory.parent, meta.get('format'))}")
        return RunLedger.from_json(meta)

    def outputs(self, step: int) -> StepOutputs:
        """The per-frame outputs of frames 0..step-1 recorded by checkpoint ``step``, [step, ...] numpy arrays."""
        return self._outputs(self.read_ledger(step))

    def _outputs(self, ledger: RunLedger) -> StepOutputs:
        segments = ledger.segments
        parts = [_load_npz(self.directory / "frames" / f"{a:06d}-{b:06d}.npz") for a, b in segments]
        if [a for a, _ in segments] != [0, *[b for _, b in segments[:-1]]]:
            raise ValueError("the frame segments do not cover the run contiguously")
        if not parts:
            raise ValueError("the checkpoint lists no frame segment")
        missing = [name for name in StepOutputs._fields if name not in parts[0]]
        if missing:
            raise ValueError(f"the frame segments lack {', '.join(missing)}")
        outputs = StepOutputs(*(np.concatenate([p[name] for p in parts]) for name in StepOutputs._fields))
        lengths = {len(v) for v in outputs}
        if lengths != {ledger.frames_done}:
            raise ValueError(f"the frame segments hold {sorted(lengths)} frames, not {ledger.frames_done}")
        return outputs

    def restore(self, like: Callable[[int], SlamState], warn: Callable[[str], None]) -> Restored | None:
        """The newest checkpoint that reads back whole, or None when there is none.

        ``like(capacity)``: a state of the run's shapes for that map capacity (the structure to restore into). A
        checkpoint that fails to read (damaged, partial, missing a segment) is reported through ``warn``, moved to
        ``unreadable/`` and the previous one is tried.
        """
        unreadable, restored = [], None
        for step in self.steps():
            try:
                restored = self._restore(step, like)
                break
            except OlderRunError:
                raise
            except Exception as error:  # any other failure to read a checkpoint means: use an older one
                detail = (str(error).splitlines() or ["no detail"])[0][:160]
                warn(f"checkpoint {self.directory / str(step)} cannot be read ({type(error).__name__}: {detail}); "
                     f"falling back to an older one (it is kept in {self.directory / 'unreadable'})")
                unreadable.append(step)
        if unreadable:  # out of the way of the steps the run will write again, kept for a look
            aside = self.directory / "unreadable"
            aside.mkdir(exist_ok=True)
            for step in unreadable:
                target = aside / str(step)
                n = 1
                while target.exists():
                    target, n = aside / f"{step}.{n}", n + 1
                os.replace(self.directory / str(step), target)
            self._manager.reload()
        return restored

    def _restore(self, step: int, like: Callable[[int], SlamState]) -> Restored:
        ledger = self.read_ledger(step)
        template = like(int(ledger.capacity))
        abstract = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), _without_images(template))
        tree = self._manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract))).state
        # Plain host arrays, as a fresh start has (restored ones carry a placement that would force a recompile).
        tree = jax.tree_util.tree_map(np.asarray, tree)
        count = int(tree["keyframes"]["count"])
        if count != ledger.keyframes_saved:
            raise ValueError(f"the state holds {count} keyframes, the record {ledger.keyframes_saved}")
        images = {name: np.zeros_like(getattr(template.keyframes, name)) for name in _IMAGES}
        for slot in range(count):
            stored = _load_npz(self.directory / "keyframes" / f"{slot:05d}.npz")
            for name in _IMAGES:
                images[name][slot] = stored[name]
        keyframes = KeyframeBuffer(**tree.pop("keyframes"), **images)
        state = SlamState(**tree, keyframes=keyframes)
        state = jax.tree_util.tree_map(jnp.asarray, state)
        return Restored(step, state, ledger, self._outputs(ledger))

    def close(self) -> None:
        self._manager.close()


def _tree_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def checkpoint_bytes(directory: str | os.PathLike) -> int:
    """Bytes on disk under a checkpoint directory (every step and segment)."""
    return _tree_size(Path(directory))
