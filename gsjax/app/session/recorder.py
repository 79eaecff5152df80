"""What one run writes, from its first chunk to its metrics: ``config.json``, the per-frame outputs in one typed
form (:class:`gsjax.slam.system.StepOutputs` of numpy arrays, from the chunk to the checkpoints and the files), the
evaluation frames it keeps, its stage timings, its checkpoints, and at the end every output file
(:func:`gsjax.app.run_folder.outputs.finish_run`).

``gsjax run`` and its ``--resume`` and the live camera keep one :class:`Recorder` with checkpoints, fed chunk by
chunk (:meth:`Recorder.add`); ``gsjax sweep`` one per config, without checkpoints, given its outputs once the batch
is done.
"""

from __future__ import annotations

import time

from gsjax.app.run_folder.checkpoints import Checkpoints, RunLedger
from gsjax.app.run_folder.outputs import OutputOptions, finish_run
from gsjax.data.sequence import Sequence
from gsjax.eval.renders import is_evaluation_frame
from gsjax.eval.run_input import RunInput
from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.run_folder import write_config
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import capacity_of, concat_outputs
from gsjax.slam.state import SlamState
from gsjax.slam.system import StepOutputs

STAGES = ("read_frames_s", "slam_s", "checkpoint_s", "regrow_s")  # the loop's stage timings (s)


class Recorder:
    """One run's outputs as they grow.

    Args:
      record: what ``config.json`` holds (written now, into ``options.out``).
      options: where the outputs go and what is rendered for them.
      ledger: what the run has done beyond its state (a resumed run's, or a fresh one); its ``timings`` cover the
        whole run.
      checkpoints: where checkpoints go; None writes none (a sweep's configs).
      checkpoint_every: a checkpoint after the first chunk that completes this many frames since the previous one,
        and after the last chunk.
      outputs: the per-frame outputs of the frames before the first chunk added (a resumed run's), or all of them (a
        sweep's config).
      kept: host frames the run still holds, by index (evaluation frames: the outputs need not read them again).
    """

    def __init__(self, record: RunInput, options: OutputOptions, ledger: RunLedger, *,
                 checkpoints: Checkpoints | None = None, checkpoint_every: int = 0,
                 outputs: StepOutputs | None = None, kept: dict | None = None):
        self.record, self.options, self.ledger = record, options, ledger
        self.checkpoints, self.checkpoint_every = checkpoints, checkpoint_every
        if checkpoints is not None:
            ledger.checkpoints.every = checkpoint_every  # (a resumed run's may have had another)
        self.kept = dict(kept or {})
        self._parts = [outputs] if outputs is not None and len(outputs.w2c) else []
        self._pending: list[StepOutputs] = []  # the chunks' outputs since the last checkpoint
        self.write_config(record)

    @property
    def frames_done(self) -> int:
        return self.ledger.frames_done

    def write_config(self, record: RunInput) -> None:
        """(Re)write ``config.json`` (a live run adds its dropped frames at the end)."""
        self.record = record
        write_config(self.options.out, record)

    @property
    def outputs(self) -> StepOutputs:
        """The per-frame outputs so far, [T, ...] numpy arrays."""
        if len(self._parts) > 1:
            self._parts = [concat_outputs(self._parts)]
        return self._parts[0]

    def add(self, start: int, frames: list, state: SlamState, outputs: StepOutputs, *, seconds: float,
            regrow_seconds: float = 0.0, read_seconds: float = 0.0, last: bool = False) -> None:
        """Record a chunk: frames ``start ..`` (``frames``, the host frames read), the state after it, its outputs
        ([count, ...] numpy) and its timings (s); a checkpoint when one is due, or ``last``."""
        ledger, timings = self.ledger, self.ledger.timings
        for stage in STAGES:  # (a sweep's config, given its outputs whole, keeps the sweep's own timings)
            timings.setdefault(stage, 0.0)
        count = len(outputs.w2c)
        timings["read_frames_s"] += read_seconds
        timings["slam_s"] += seconds
        timings["regrow_s"] += regrow_seconds
        if ledger.first_chunk_s is None:
            ledger.first_chunk_s = seconds
        self.kept.update((start + i, frame) for i, frame in enumerate(frames)
                         if is_evaluation_frame(start + i, self.options.eval_every))
        self._parts.append(outputs)
        self._pending.append(outputs)
        ledger.frames_done = start + count
        ledger.capacity = capacity_of(state)
        since = ledger.segments[-1][1] if ledger.segments else 0
        if self.checkpoints is not None and (ledger.frames_done - since >= self.checkpoint_every or last):
            self._checkpoint(state, since)

    def _checkpoint(self, state: SlamState, since: int) -> None:
        assert self.checkpoints is not None
        t0 = time.perf_counter()
        self.ledger.segments.append([since, self.ledger.frames_done])
        written = self.checkpoints.save(state, self.ledger, concat_outputs(self._pending))
        self._pending = []
        seconds = time.perf_counter() - t0
        self.ledger.timings["checkpoint_s"] += seconds
        self.ledger.checkpoints.add(seconds, written)

    def close(self) -> None:
        if self.checkpoints is not None:
            self.checkpoints.close()

    def finish(self, sequence: Sequence, config: SlamConfig, state: SlamState, *, input_warnings=(),
               resume_warnings=()) -> RunMetrics:
        """Evaluate the run and write every output file (:func:`gsjax.app.run_folder.outputs.finish_run`)."""
        ledger = self.ledger
        if ledger.first_chunk_s is not None:
            ledger.timings["compile_s_estimate"] = compile_estimate(
                ledger.first_chunk_s, ledger.timings["slam_s"], ledger.frames_done, self.record.chunk)
        return finish_run(sequence, config, self.options, state, self.outputs, ledger.timings, self.record,
                          input_warnings=input_warnings, resume_warnings=resume_warnings,
                          checkpoints=ledger.checkpoints if self.checkpoints is not None else None, frames=self.kept)


def compile_estimate(first_chunk_s: float | None, slam_s: float, total: int, chunk: int) -> float | None:
    """Seconds of the first chunk beyond its frames' steady cost: the first chunk's time less ``chunk`` frames at
    the later chunks' rate per real frame (a short last chunk is padded, and padding frames cost next to nothing);
    None with a single chunk."""
    later_frames = total - chunk
    if first_chunk_s is None or later_frames <= 0:
        return None
    per_frame = (slam_s - first_chunk_s) / later_frames
    return max(0.0, first_chunk_s - per_frame * chunk)
