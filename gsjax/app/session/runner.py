"""``gsjax run`` on a recording and its ``--resume``: the run folder checked and locked, the newest readable
checkpoint restored, the frames through the shell's one loop (:func:`gsjax.app.session.loop.chunk_loop`, which grows the
map's capacity, said here, when a chunk could not insert every new Gaussian) into one
:class:`gsjax.app.session.recorder.Recorder` (checkpoints every ``checkpoint_every`` frames, so ``--resume`` continues
exactly where the run stopped; the outputs at the end), with a progress bar (frame, tracking loss, Gaussians, ATE
so far when ground truth exists, frames/s).

Ground truth is for evaluation only: the frames reach the SLAM core with their GT pose blanked
(:func:`gsjax.frame.without_ground_truth`). What the run handles in a defined way but a user should know
(frames without usable depth, depth in an implausible unit, and what the reader reported) is printed as a warning
and listed in ``metrics.json`` under ``warnings``.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gsjax.app.run_folder.checkpoints import Checkpoints, RunLedger
from gsjax.app.run_folder.layout import check_run_dir, clear_previous_run, locked_run_dir
from gsjax.app.run_folder.outputs import OutputOptions, run_record
from gsjax.app.run_folder.run_warnings import run_warnings
from gsjax.app.runtime.cache import exported_call
from gsjax.app.runtime.memory import limit_malloc_arenas
from gsjax.app.runtime.progress import Progress
from gsjax.app.session.loop import Group, Runtime, chunk_loop, one_config, sequence_frames
from gsjax.app.session.recorder import Recorder
from gsjax.camera import invert_transform
from gsjax.data.sequence import Sequence
from gsjax.eval.run_metrics import RunMetrics
from gsjax.eval.trajectory import ate_so_far
from gsjax.io.atomic import remove_stale_temporaries
from gsjax.io.run_folder import RENDERS
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import start_capacity
from gsjax.slam.state import SlamState, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs

log = logging.getLogger("gsjax")

@dataclasses.dataclass(frozen=True)
class RunOptions:
    """Shell options of a run (not part of the traced config).

    Attributes:
      out: output directory.
      chunk: frames per jitted scan chunk.
      checkpoint_every: a checkpoint after the first chunk that completes this many frames since the previous one,
        and after the last frame.
      seed: PRNG seed of the run.
      resume: continue from the newest checkpoint in ``out/checkpoints``.
      eval_every: render-metric frames are t = 0 and (t + 1) % eval_every == 0 (SplaTAM's rule).
      capacity: initial map capacity (default: 2 H W).
      progress: show the progress bar.
      samples: number of render-vs-input panels written to ``renders/``.
    """

    out: Path
    chunk: int = 8
    checkpoint_every: int = 8
    seed: int = 0
    resume: bool = False
    eval_every: int = 5
    capacity: int | None = None
    progress: bool = True
    samples: int = 3
    overwrite: bool = False

    def __post_init__(self):
        for name in ("chunk", "checkpoint_every", "eval_every", "samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.capacity is not None and self.capacity < 1:
            raise ValueError(f"--capacity must be >= 1, got {self.capacity}")

    @property
    def outputs(self) -> OutputOptions:
        return OutputOptions(Path(self.out), self.eval_every, self.samples)


# ------------------------------------------------------------------------------------------------ the run


def run_slam(
    sequence: Sequence,
    config: SlamConfig,
    options: RunOptions,
    *,
    describe: dict | None = None,
    on_chunk: Callable[[int], None] | None = None,
    observe: Callable[[SlamState, StepOutputs], None] | None = None,
    input_warnings: tuple[str, ...] = (),
) -> RunMetrics:
    """Run SLAM on ``sequence`` with ``config``; write every output under ``options.out``; return the metrics.

    ``describe`` (dataset name, path, preset, ...) is recorded in ``config.json`` and ``metrics.json``.
    ``on_chunk(frames_done)`` is called after each chunk and its checkpoint, if any (tests use it to interrupt a
    run); ``observe(state, outputs)`` too, with the state and the per-frame outputs so far (:class:`StepOutputs`; the
    live viewer); the time it takes is ``stage_timings_s["observe_s"]``.
    ``input_warnings``: what opening the sequence warned about, listed first in ``metrics.json``'s ``warnings``.

    Raises :class:`gsjax.app.run_folder.layout.RunDirError` before writing anything when ``options.out`` holds a
    previous run and neither ``resume`` nor ``overwrite`` is set, cannot be used at all (:func:`check_run_dir`), or is
    held by another live run (:func:`gsjax.app.run_folder.layout.locked_run_dir`).
    """
    out = Path(options.out)
    check_run_dir(out, resume=options.resume, overwrite=options.overwrite)
    if len(sequence) < 1:
        raise ValueError(f"sequence {sequence.name!r} has no frames")
    sequence.read_host(0)  # an unreadable first frame fails before anything in ``out`` changes
    limit_malloc_arenas()  # before the checkpoints' threads allocate (see gsjax.app.runtime.memory)
    with locked_run_dir(out):
        return _run_locked(sequence, config, options, describe, on_chunk, observe, input_warnings)


def _run_locked(sequence: Sequence, config: SlamConfig, options: RunOptions, describe: dict | None,
                on_chunk: Callable[[int], None] | None, observe: Callable[[SlamState, StepOutputs], None] | None,
                input_warnings: tuple[str, ...]) -> RunMetrics:
    """:func:`run_slam` once ``options.out`` is checked and this process holds its lock."""
    out = Path(options.out)
    intrinsics = sequence.intrinsics
    height, width = intrinsics.height, intrinsics.width
    total = len(sequence)
    if options.overwrite:
        removed = clear_previous_run(out)
        if removed:
            log.info("--overwrite: removed the previous run's %s from %s", ", ".join(removed), out)
    out.mkdir(parents=True, exist_ok=True)
    for directory in (out, out / RENDERS):  # what writers killed mid-write left (never a finished output)
        remove_stale_temporaries(directory)
    record = run_record(sequence, config, chunk=options.chunk, seed=options.seed, describe=describe)
    kf_capacity = keyframe_capacity_for(total, config.keyframe_every)

    def like(capacity: int):
        return initial_state(capacity, height, width, kf_capacity, total, options.seed)

    capacity = options.capacity or start_capacity(height, width)
    state, restored_outputs = like(capacity), None
    ledger = RunLedger(capacity=capacity, record=record.resume_key())
    resume_warnings: list[str] = []  # about this resume (a checkpoint that could not be read)
    checkpoints = Checkpoints(out / "checkpoints")
    if options.resume:
        def fell_back(message: str) -> None:
            resume_warnings.append(message)
            print(f"warning: {message}", file=sys.stderr, flush=True)

        try:
            restored = checkpoints.restore(like, fell_back)  # OlderRunError: a run folder of another format
            if restored is not None:
                _check_resumable(restored.ledger.record, ledger.record, out)
        except ValueError:
            checkpoints.close()
            raise
        if restored is not None:
            state, restored_outputs, ledger = restored.state, restored.outputs, restored.ledger
            log.info("resumed from checkpoint at frame %d (capacity %d)", ledger.frames_done, ledger.capacity)
        elif resume_warnings:
            fell_back("no checkpoint could be read: the run starts from frame 0")
    recorder = Recorder(record, options.outputs, ledger, checkpoints=checkpoints,
                        checkpoint_every=options.checkpoint_every, outputs=restored_outputs)
    timings = ledger.timings  # cover the whole run, resumed or not

    _, gt_c2w, gt_valid = sequence.gt_trajectory()
    progress = Progress(total, ledger.frames_done, options.progress)

    def on_grow(group, dropped, first, last, new_capacity):
        progress.write(f"capacity: {dropped} new Gaussians found no free slot at frames {first}-{last}; growing the "
                       f"map to {new_capacity} slots and re-running the chunk")

    start = ledger.frames_done
    try:
        for chunk in chunk_loop([Group(state, config)], sequence_frames(sequence, start), intrinsics,
                                chunk=options.chunk, start=start, on_grow=on_grow, runtime=Runtime(exported_call())):
            state, outputs = one_config(chunk)
            # Printed as they happen; metrics.json lists them again from all the outputs (finish_run).
            for message in run_warnings(sequence, config, outputs, lambda t: chunk.frames[t - chunk.start],
                                        start=chunk.start, depth_units=not ledger.depth_units_checked):
                progress.write(f"warning: {message}", file=sys.stderr)
            ledger.depth_units_checked |= bool(np.any(~outputs.skipped))
            done = chunk.start + chunk.count
            recorder.add(chunk.start, chunk.frames, state, outputs, seconds=chunk.seconds,
                         regrow_seconds=chunk.regrow_seconds, read_seconds=chunk.read_seconds, last=done == total)
            so_far = recorder.outputs
            ate = ate_so_far(invert_transform(np.asarray(so_far.w2c, np.float64)), gt_c2w, gt_valid)
            fields = dict(loss=f"{so_far.tracking_loss[-1]:.1f}", gaussians=int(so_far.num_gaussians[-1]),
                          fps=f"{done / max(timings['slam_s'], 1e-9):.2f}")
            if ate is not None:
                fields["ate_cm"] = f"{100 * ate:.2f}"
            progress.update(chunk.count, **fields)
            if observe is not None:
                t0 = time.perf_counter()
                observe(state, so_far)
                timings["observe_s"] = timings.get("observe_s", 0.0) + time.perf_counter() - t0
            if on_chunk is not None:
                on_chunk(done)
    finally:
        progress.close()
        recorder.close()
    return recorder.finish(sequence, config, state, input_warnings=input_warnings, resume_warnings=resume_warnings)


def _check_resumable(saved: dict, key_now: dict, out: Path) -> None:
    from gsjax.config.text import canonical_config_dict

    saved = {**saved, "config": canonical_config_dict(saved.get("config"))}  # JSON's lists as the fields' tuples
    for key, value in key_now.items():
        if saved.get(key) != value:
            raise ValueError(
                f"--resume: the checkpoint in {out / 'checkpoints'} was made with a different {key} "
                f"({saved.get(key)!r} vs {value!r}); resume with the same options, or use a new --out"
            )
