"""The imperative shell of ``gsjax run``: stream chunks of frames through the jitted SLAM scan, checkpoint,
grow capacity, report progress; then :mod:`gsjax.run_outputs` evaluates and writes the outputs.

The chunk loop is :func:`gsjax.slam.driver.chunk_loop` (the same one :func:`gsjax.slam.run` and the sweep use;
it grows the map capacity, logged here, when a chunk could not insert every new Gaussian). Between chunks this
module:

* checkpoints the state (orbax) so ``--resume`` continues exactly where the run stopped;
* shows a progress bar (frame, tracking loss, Gaussians, ATE so far when ground truth exists, frames/s).

Ground truth is for evaluation only: the frames reach the SLAM core with their GT pose blanked
(:func:`gsjax.data.frame.without_ground_truth`). What the run handles in a defined way but a user should know
(frames without usable depth, depth in an implausible unit, and what the reader reported) is printed as a warning
and listed in ``metrics.json`` under ``warnings``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.config_text import config_to_dict
from gsjax.data.frame import Frame
from gsjax.data.sequence import Sequence
from gsjax.io.atomic import atomic_write_json
from gsjax.io.run_dir import check_run_dir, clear_previous_run
from gsjax.progress import Progress
from gsjax.run_outputs import write_outputs
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import chunk_loop
from gsjax.slam.state import initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs

log = logging.getLogger("gsjax")

# Median depth (m) of a frame outside this range means the depth scale is almost surely wrong for an indoor scene.
PLAUSIBLE_MEDIAN_DEPTH_M = (0.1, 20.0)


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """Shell options of a run (not part of the traced config).

    Attributes:
      out: output directory.
      chunk: frames per jitted scan chunk (and per checkpoint).
      seed: PRNG seed of the run.
      resume: continue from the newest checkpoint in ``out/checkpoints``.
      eval_every: render-metric frames are t = 0 and (t + 1) % eval_every == 0 (SplaTAM's rule).
      capacity: initial map capacity (default: 2 H W).
      progress: show the progress bar.
      samples: number of render-vs-input panels written to ``renders/``.
    """

    out: Path
    chunk: int = 8
    seed: int = 0
    resume: bool = False
    eval_every: int = 5
    capacity: int | None = None
    progress: bool = True
    samples: int = 3
    overwrite: bool = False

    def __post_init__(self):
        for name in ("chunk", "eval_every", "samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.capacity is not None and self.capacity < 1:
            raise ValueError(f"--capacity must be >= 1, got {self.capacity}")


# ------------------------------------------------------------------------------------------------ the run


def _outputs_to_lists(outputs: StepOutputs, count: int) -> dict:
    return {name: np.asarray(value)[:count].tolist() for name, value in outputs._asdict().items()}


def _ate_so_far(w2c: np.ndarray, gt_c2w: np.ndarray, gt_valid: np.ndarray) -> float | None:
    """ATE (m) of the frames so far that have ground truth (the rigid alignment absorbs the world frames)."""
    from gsjax.eval.trajectory import ate_rmse_c2w

    n = len(w2c)
    if gt_valid[:n].sum() < 3:
        return None
    try:
        return ate_rmse_c2w(np.linalg.inv(w2c), gt_c2w[:n], gt_valid[:n]).value_m
    except ValueError:
        return None


def _camera_record(sequence: Sequence) -> dict:
    """The camera the run uses (intrinsics at the working resolution, the depth files' units per metre)."""
    k = sequence.intrinsics
    return dict(fx=float(k.fx), fy=float(k.fy), cx=float(k.cx), cy=float(k.cy), width=k.width, height=k.height,
                depth_scale=sequence.depth_scale)


def _depth_unit_warning(sequence: Sequence, index: int, frame: Frame) -> str | None:
    """A warning when frame ``index``'s median valid depth is implausible for an indoor RGB-D camera."""
    depth = np.asarray(frame.depth)
    median = float(np.median(depth[depth > 0]))
    low, high = PLAUSIBLE_MEDIAN_DEPTH_M
    if low <= median <= high:
        return None
    scale = f"{sequence.depth_scale:g} raw units per metre" if sequence.depth_scale else "the dataset's scale"
    return (f"{sequence.describe_frame(index)}: median depth {median:.3g} m is outside {low:g}-{high:g} m; the depth "
            f"scale ({scale}) looks wrong for this recording: give the right one with --depth-scale S")


def _skipped_warning(sequence: Sequence, index: int, frame: Frame, config: SlamConfig, started: bool) -> str:
    fraction = float(np.mean(np.asarray(frame.depth) > 0))
    then = "" if started else "; the map starts at the first frame with depth"
    return (f"{sequence.describe_frame(index)}: only {100 * fraction:.1f}% of the pixels have valid depth (below "
            f"min_valid_depth {100 * float(config.min_valid_depth):g}%); the frame is not tracked or mapped, its pose "
            f"is the constant-velocity prediction{then}")


def run_slam(
    sequence: Sequence,
    config: SlamConfig,
    options: RunOptions,
    *,
    describe: dict | None = None,
    on_chunk: Callable[[int], None] | None = None,
    input_warnings: tuple[str, ...] = (),
) -> dict:
    """Run SLAM on ``sequence`` with ``config``; write every output under ``options.out``; return the metrics.

    ``describe`` (dataset name, path, preset, ...) is recorded in ``config.json`` and ``metrics.json``.
    ``on_chunk(frames_done)`` is called after each checkpoint (tests use it to interrupt a run).
    ``input_warnings``: what opening the sequence warned about, listed first in ``metrics.json``'s ``warnings``.

    Raises :class:`gsjax.io.run_dir.RunDirError` before writing anything when ``options.out`` holds a previous run
    and neither ``resume`` nor ``overwrite`` is set, or cannot be used at all (:func:`check_run_dir`).
    """
    from gsjax.io.checkpoint import Checkpoints

    out = Path(options.out)
    check_run_dir(out, resume=options.resume, overwrite=options.overwrite)
    intrinsics = sequence.intrinsics
    height, width = intrinsics.height, intrinsics.width
    total = len(sequence)
    if total < 1:
        raise ValueError(f"sequence {sequence.name!r} has no frames")
    sequence.read_host(0)  # an unreadable first frame fails before anything in ``out`` changes
    if options.overwrite:
        removed = clear_previous_run(out)
        if removed:
            log.info("--overwrite: removed the previous run's %s from %s", ", ".join(removed), out)
    out.mkdir(parents=True, exist_ok=True)
    record = dict(describe or {}, frames=total, width=width, height=height, chunk=options.chunk, seed=options.seed,
                  camera=_camera_record(sequence), config=config_to_dict(config))
    checkpoints = Checkpoints(out / "checkpoints")
    timings = dict(read_frames_s=0.0, slam_s=0.0, checkpoint_s=0.0, regrow_s=0.0)
    capacity = options.capacity or 2 * height * width
    kf_capacity = keyframe_capacity_for(total, config.keyframe_every)
    state = initial_state(capacity, height, width, kf_capacity, total, options.seed)
    outputs: dict[str, list] = {}
    frame_warnings: list[str] = []  # found while running (kept in checkpoints, so a resumed run reports them too)
    units_checked = False
    done = 0
    first_chunk_s = None
    if options.resume and checkpoints.latest() is not None:
        step = checkpoints.latest()
        meta = checkpoints.read_meta(step)
        try:
            _check_resumable(meta, record, out)
        except ValueError:
            checkpoints.close()
            raise
        like = initial_state(meta["capacity"], height, width, kf_capacity, total, options.seed)
        state, meta = checkpoints.restore(step, like)
        # Plain device arrays, as a fresh start has (restored ones carry a placement that would force a recompile).
        state = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)), state)
        outputs, done, capacity = meta["outputs"], meta["frames_done"], meta["capacity"]
        timings, first_chunk_s = meta["timings"], meta["first_chunk_s"]  # timings cover the whole run
        frame_warnings, units_checked = meta["warnings"], meta["depth_units_checked"]
        log.info("resumed from checkpoint at frame %d (capacity %d)", done, capacity)
    atomic_write_json(out / "config.json", record)

    _, gt_c2w, gt_valid = sequence.gt_trajectory()
    progress = Progress(total, done, options.progress)

    def warn(message: str) -> None:
        frame_warnings.append(message)
        progress.write(f"warning: {message}", file=sys.stderr)

    def on_grow(dropped, first, last, new_capacity):
        progress.write(f"capacity: {dropped} new Gaussians found no free slot at frames {first}-{last}; growing the "
                       f"map to {new_capacity} slots and re-running the chunk")

    try:
        for chunk in chunk_loop(state, sequence.read_host, total, config, intrinsics, chunk=options.chunk,
                                start=done, on_grow=on_grow):
            state, chunk_out, count, capacity = chunk.state, chunk.outputs, chunk.count, chunk.capacity
            timings["read_frames_s"] += chunk.read_seconds
            timings["slam_s"] += chunk.seconds
            timings["regrow_s"] += chunk.regrow_seconds
            if first_chunk_s is None:
                first_chunk_s = chunk.seconds
            # The core decided which frames had usable depth; the host only words the warnings.
            processed = np.flatnonzero(~chunk_out.skipped)
            if not units_checked and processed.size:
                units_checked = True
                message = _depth_unit_warning(sequence, done + int(processed[0]), chunk.frames[processed[0]])
                if message:
                    warn(message)
            for i in np.flatnonzero(chunk_out.skipped):
                warn(_skipped_warning(sequence, done + int(i), chunk.frames[i], config,
                                      started=int(chunk_out.num_gaussians[i]) > 0))
            for name, values in _outputs_to_lists(chunk_out, count).items():
                outputs.setdefault(name, []).extend(values)
            done += count
            t0 = time.perf_counter()
            checkpoints.save(done, state, dict(frames_done=done, capacity=capacity, outputs=outputs,
                                               record=_resume_key(record), timings=timings,
                                               first_chunk_s=first_chunk_s, warnings=frame_warnings,
                                               depth_units_checked=units_checked))
            timings["checkpoint_s"] += time.perf_counter() - t0
            w2c = np.asarray(outputs["w2c"], np.float64)
            ate = _ate_so_far(w2c, gt_c2w, gt_valid)
            fields = dict(loss=f"{outputs['tracking_loss'][-1]:.1f}", gaussians=outputs["num_gaussians"][-1],
                          fps=f"{done / max(timings['slam_s'], 1e-9):.2f}")
            if ate is not None:
                fields["ate_cm"] = f"{100 * ate:.2f}"
            progress.update(count, **fields)
            if on_chunk is not None:
                on_chunk(done)
    finally:
        progress.close()
        checkpoints.close()

    timings["compile_s_estimate"] = _compile_estimate(first_chunk_s, timings["slam_s"], total, options.chunk)
    return write_outputs(sequence, config, options, state, outputs, timings, record, [*input_warnings, *frame_warnings])


def _resume_key(record: dict) -> dict:
    return {k: record[k] for k in ("frames", "width", "height", "chunk", "seed", "camera", "config")}


def _check_resumable(meta: dict, record: dict, out: Path) -> None:
    saved = meta.get("record", {})
    for key, value in _resume_key(record).items():
        if saved.get(key) != value:
            raise ValueError(
                f"--resume: the checkpoint in {out / 'checkpoints'} was made with a different {key} "
                f"({saved.get(key)!r} vs {value!r}); resume with the same options, or use a new --out"
            )


def _compile_estimate(first_chunk_s, slam_s, total, chunk) -> float | None:
    chunks = math.ceil(total / chunk)
    if first_chunk_s is None or chunks < 2:
        return None
    steady = (slam_s - first_chunk_s) / (chunks - 1)
    return max(0.0, first_chunk_s - steady)
