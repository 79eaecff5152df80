"""SLAM on a live frame source (:class:`gsjax.app.session.camera.LiveCamera`), one frame at a time as frames come:
``gsjax run --dataset realsense --path live`` (or ``--path REC --realtime``, a recording played as if live).

The frames go through the shell's one loop (:func:`gsjax.app.session.loop.chunk_loop`, chunks of one frame: the
camera is waited for while the previous frame's SLAM runs) into one :class:`gsjax.app.session.recorder.Recorder`, as a
recording's do: the map grows when it is full (said, and counted in ``stage_timings_s.regrow_s``), checkpoints are
written every ``checkpoint_every`` frames (a crash keeps what was mapped; there is no resume: a live camera cannot be
re-read), and every output is written at the end. The loop takes the oldest frame the camera still holds (it holds the
newest few and drops the rest, counted), and stops at ``max_frames``, when the source ends, on Ctrl-C or SIGTERM
(``stop``); the dropped frames are counted in ``metrics.json``'s warnings."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from gsjax.app.run_folder.checkpoints import Checkpoints, RunLedger
from gsjax.app.run_folder.layout import check_run_dir, clear_previous_run, locked_run_dir
from gsjax.app.run_folder.outputs import run_record
from gsjax.app.runtime.cache import exported_call
from gsjax.app.session.camera import LiveCamera, LiveFrame
from gsjax.app.session.loop import Group, Runtime, chunk_loop, one_config
from gsjax.app.session.recorder import Recorder
from gsjax.app.session.runner import RunOptions
from gsjax.data.errors import DatasetError
from gsjax.data.images import downscale_color, downscale_depth
from gsjax.data.sequence import Sequence
from gsjax.eval.run_metrics import RunMetrics
from gsjax.frame import Frame, host_frame
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import start_capacity
from gsjax.slam.state import initial_state, keyframe_capacity_for


def run_live(camera: LiveCamera, config: SlamConfig, options: RunOptions, *, downscale: int, max_frames: int,
             describe: dict | None = None, stop: threading.Event | None = None,
             observe: Callable | None = None, say: Callable[[str], None] = print) -> RunMetrics:
    """SLAM on ``camera``'s frames (reduced by ``downscale``) until ``max_frames`` are processed, the source ends or
    ``stop`` is set (or Ctrl-C); writes every output under ``options.out`` and returns the metrics. ``observe(state,
    outputs)`` as for :func:`gsjax.app.session.runner.run_slam` (the live viewer), after every frame."""
    out = Path(options.out)
    check_run_dir(out, overwrite=options.overwrite)
    stop = stop or threading.Event()
    intrinsics = camera.intrinsics if downscale == 1 else camera.intrinsics.downscaled(downscale)
    height, width = intrinsics.height, intrinsics.width
    with locked_run_dir(out):
        if options.overwrite:
            clear_previous_run(out)
        out.mkdir(parents=True, exist_ok=True)
        capacity = options.capacity or start_capacity(height, width, live=True)
        state = initial_state(capacity, height, width, keyframe_capacity_for(max_frames, config.keyframe_every),
                              max_frames, options.seed)
        times: list[float] = []
        frames = _frames(camera, downscale, max_frames, stop, times)

        def record(sequence: Sequence):
            return run_record(sequence, config, chunk=1, seed=options.seed, describe=dict(
                describe or {}, live=dict(captured=camera.captured, dropped=camera.dropped)))

        ledger = RunLedger(capacity=capacity, record={})
        recorder = Recorder(record(_processed(camera, intrinsics, [], {})), options.outputs, ledger,
                            checkpoints=Checkpoints(out / "checkpoints"), checkpoint_every=options.checkpoint_every)

        def on_grow(group, dropped, first, last, new_capacity):
            say(f"capacity: {dropped} new Gaussians found no free slot at frame {last}; growing the map to "
                f"{new_capacity} slots and re-running the frame (a compilation: the camera's frames meanwhile are "
                "dropped)")

        try:
            for chunk in chunk_loop([Group(state, config)], frames, intrinsics, chunk=1, on_grow=on_grow,
                                    runtime=Runtime(exported_call())):
                state, outputs = one_config(chunk)
                recorder.add(chunk.start, chunk.frames, state, outputs, seconds=chunk.seconds,
                             regrow_seconds=chunk.regrow_seconds, read_seconds=chunk.read_seconds)
                if observe is not None:
                    observe(state, recorder.outputs)
        except KeyboardInterrupt:
            say("gsjax run: stopped; writing the outputs of the frames processed")
        finally:
            camera.stop()
            recorder.close()
        if not recorder.frames_done:
            raise DatasetError(f"{camera.source}: no frame was processed (the camera gave none)")
        sequence = _processed(camera, intrinsics, times[:recorder.frames_done], recorder.kept)  # not one read ahead
        recorder.write_config(record(sequence))
        dropped = f"live: {camera.dropped} of {camera.captured} captured frames were dropped (SLAM slower than " \
                  f"the camera: {recorder.frames_done} processed)"
        return recorder.finish(sequence, config, state, input_warnings=(dropped,) if camera.dropped else ())


def _frames(camera: LiveCamera, downscale: int, max_frames: int, stop: threading.Event,
            times: list[float]) -> Iterator[Frame]:
    """The camera's frames as they come (the oldest it holds first), until ``max_frames``, the end of the source or
    ``stop``; each frame's timestamp (s) appended to ``times``."""
    while len(times) < max_frames and not stop.is_set():
        captured = camera.next(timeout=0.5)
        if captured is None:
            if camera.ended:
                return
            continue
        times.append(captured.timestamp)
        yield _reduce(captured, downscale, len(times) - 1)


def _reduce(captured: LiveFrame, factor: int, index: int):
    return host_frame(downscale_color(captured.color, factor), downscale_depth(captured.depth, factor), np.eye(4),
                      False, index)


def _processed(camera: LiveCamera, intrinsics, times: list[float], kept: dict) -> Sequence:
    """The frames processed, as the :class:`Sequence` the outputs are written from (no ground truth; only the kept
    evaluation frames can be read again)."""
    def read(i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in kept:
            raise DatasetError(f"{camera.source}: live frame {i} was not kept")
        return kept[i].color, kept[i].depth

    name = "realsense-live" if camera.source == "live" else Path(camera.source).stem
    return Sequence(name=name, intrinsics=intrinsics, timestamps=np.asarray(times, np.float64),
                    c2w=np.tile(np.eye(4), (len(times), 1, 1)), pose_valid=np.zeros(len(times), bool), read_rgbd=read,
                    depth_scale=camera.depth_units_per_metre)
