"""SLAM on a live frame source (:class:`gsjax.app.live_camera.LiveCamera`), one frame at a time as frames come:
``gsjax run --dataset realsense --path live`` (or ``--path REC --realtime``, a recording played as if live).

The loop takes the oldest frame the camera still holds (it holds the newest few and drops the rest, counted), steps
the SLAM core on it, and stops at ``max_frames``, when the source ends, on Ctrl-C or SIGTERM (``stop``): then every
output is written by :func:`gsjax.app.run_outputs.finish_run`, as for a recording, the dropped frames counted in
``metrics.json``'s warnings. There is no resume: a live camera cannot be re-read."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from gsjax.app.live_camera import LiveCamera, LiveFrame
from gsjax.app.run_dir import check_run_dir, clear_previous_run, locked_run_dir
from gsjax.app.run_outputs import finish_run, host_outputs, is_evaluation_frame, run_record
from gsjax.app.runner import RunOptions
from gsjax.data.frame import DatasetError, host_frame, to_device
from gsjax.data.images import downscale_color, downscale_depth
from gsjax.data.sequence import Sequence
from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.atomic import atomic_write_json
from gsjax.slam.config import SlamConfig
from gsjax.slam.state import initial_state, keyframe_capacity_for
from gsjax.slam.system import step

_step = jax.jit(step)


def run_live(camera: LiveCamera, config: SlamConfig, options: RunOptions, *, downscale: int, max_frames: int,
             describe: dict | None = None, stop: threading.Event | None = None,
             observe: Callable | None = None, say: Callable[[str], None] = print) -> RunMetrics:
    """SLAM on ``camera``'s frames (reduced by ``downscale``) until ``max_frames`` are processed, the source ends or
    ``stop`` is set (or Ctrl-C); writes every output under ``options.out`` and returns the metrics. ``observe(state,
    outputs)`` as for :func:`gsjax.app.runner.run_slam` (the live viewer), after every frame."""
    out = Path(options.out)
    check_run_dir(out, overwrite=options.overwrite)
    stop = stop or threading.Event()
    intrinsics = camera.intrinsics if downscale == 1 else camera.intrinsics.downscaled(downscale)
    height, width = intrinsics.height, intrinsics.width
    with locked_run_dir(out):
        if options.overwrite:
            clear_previous_run(out)
        state = initial_state(options.capacity or 8 * height * width, height, width,
                              keyframe_capacity_for(max_frames, config.keyframe_every), max_frames, options.seed)
        outputs: dict[str, list] = {}
        times: list[float] = []
        kept: dict = {}
        timings = dict(read_frames_s=0.0, slam_s=0.0, checkpoint_s=0.0, regrow_s=0.0)
        started = time.perf_counter()
        try:
            while len(times) < max_frames and not stop.is_set():
                t0 = time.perf_counter()
                captured = camera.next(timeout=0.5)
                if captured is None:
                    if camera.ended:
                        break
                    continue
                frame = _reduce(captured, downscale, len(times))
                timings["read_frames_s"] += time.perf_counter() - t0
                t0 = time.perf_counter()
                state, frame_outputs = _step(state, to_device(frame), config, intrinsics)
                frame_outputs = jax.device_get(frame_outputs)
                timings["slam_s"] += time.perf_counter() - t0
                if is_evaluation_frame(len(times), options.eval_every) or len(times) < 2:
                    kept[len(times)] = frame
                times.append(captured.timestamp)
                for name, value in frame_outputs._asdict().items():
                    outputs.setdefault(name, []).append(np.asarray(value).tolist())
                if observe is not None:
                    observe(state, outputs)
        except KeyboardInterrupt:
            say("gsjax run: stopped; writing the outputs of the frames processed")
        finally:
            camera.stop()
        if not times:
            raise DatasetError(f"{camera.source}: no frame was processed (the camera gave none)")
        timings["wall_s"] = time.perf_counter() - started
        sequence = _processed(camera, intrinsics, np.asarray(times), kept)
        dropped = f"live: {camera.dropped} of {camera.captured} captured frames were dropped (SLAM slower than " \
                  f"the camera: {len(times)} processed)"
        record = run_record(sequence, config, chunk=1, seed=options.seed,
                            describe=dict(describe or {}, live=dict(captured=camera.captured, dropped=camera.dropped)))
        atomic_write_json(out / "config.json", record.to_json())
        return finish_run(sequence, config, options.outputs, jax.device_get(state), host_outputs(outputs), timings,
                          record, input_warnings=(dropped,) if camera.dropped else (), frames=kept)


def _reduce(captured: LiveFrame, factor: int, index: int):
    return host_frame(downscale_color(captured.color, factor), downscale_depth(captured.depth, factor), np.eye(4),
                      False, index)


def _processed(camera: LiveCamera, intrinsics, times: np.ndarray, kept: dict) -> Sequence:
    """The frames processed, as the :class:`Sequence` the outputs are written from (no ground truth; only the kept
    evaluation frames can be read again)."""
    def read(i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in kept:
            raise DatasetError(f"{camera.source}: live frame {i} was not kept")
        return kept[i].color, kept[i].depth

    name = "realsense-live" if camera.source == "live" else Path(camera.source).stem
    return Sequence(name=name, intrinsics=intrinsics, timestamps=times, c2w=np.tile(np.eye(4), (len(times), 1, 1)),
                    pose_valid=np.zeros(len(times), bool), read_rgbd=read, depth_scale=camera.depth_units_per_metre)
