"""A RealSense camera (or a recording played in real time) as a live frame source: colour and depth aligned to
colour by the SDK, captured on a thread into a bounded queue that keeps the newest frames; when SLAM is slower than
the camera the oldest waiting frame is dropped and counted, so memory never grows and SLAM always works on a recent
frame. Needs pyrealsense2 (``pip install -e '.[realsense]'``)."""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.data.realsense_write import require_pyrealsense2

LIVE = "live"  # --path live: the first connected camera


@dataclass(frozen=True)
class LiveFrame:
    """One captured frame: ``number`` (0, 1, ... in capture order, dropped ones included), ``timestamp`` (s, the
    camera's), ``color`` [H, W, 3] float32 in [0, 1], ``depth`` [H, W] float32 m (0: none), in the colour camera."""

    number: int
    timestamp: float
    color: np.ndarray
    depth: np.ndarray


class LiveCamera:
    """Frames from ``source`` (:data:`LIVE`, or a recording played back in real time through the same pipeline, as
    if it were a camera): ``next()`` blocks for the newest waiting frame (None once the source has ended or
    :meth:`stop` was called); at most ``waiting`` frames wait, older ones are dropped (``dropped``)."""

    def __init__(self, source: str | Path, *, waiting: int = 2, width: int = 640, height: int = 480, fps: int = 30):
        rs = require_pyrealsense2()
        self.source = str(source)
        config = rs.config()
        if self.source == LIVE:
            config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
            config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        else:
            if not Path(source).is_file():
                raise ValueError(f"{source}: no such RealSense recording")
            config.enable_device_from_file(str(source), repeat_playback=False)
        if self.source == LIVE and not len(rs.context().query_devices()):
            # pipeline.start waits about 15 s for a camera before it gives up: say so at once instead.
            raise ValueError(f"--path {source}: no RealSense camera is connected (No device connected)")
        self._pipeline = rs.pipeline()
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as error:
            what = "no RealSense camera is connected" if self.source == LIVE else f"{source} cannot be played"
            raise ValueError(f"--path {source}: {what} ({error})") from None
        device = profile.get_device()
        if self.source != LIVE:
            device.as_playback().set_real_time(True)  # frames come at the recorded rate, as from a camera
        self._units = float(device.first_depth_sensor().get_depth_scale())  # metres per raw unit
        k = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics: Intrinsics = make_intrinsics(k.fx, k.fy, k.ppx, k.ppy, k.height, k.width)
        self._align = rs.align(rs.stream.color)
        self._queue: collections.deque[LiveFrame] = collections.deque()
        self._waiting = waiting
        self._ready = threading.Condition()
        self._ended = False
        self.captured = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._capture, name="gsjax-live-camera", daemon=True)
        self._thread.start()

    @property
    def ended(self) -> bool:
        """The source has ended (or :meth:`stop` was called) and no frame waits."""
        with self._ready:
            return self._ended and not self._queue

    @property
    def depth_units_per_metre(self) -> float:
        return 1.0 / self._units

    def _capture(self) -> None:
        try:
            while not self._ended:
                try:
                    frames = self._pipeline.wait_for_frames(2000 if self.source == LIVE else 1000)
                except RuntimeError:  # no frame: the recording has ended (or the camera went away)
                    break
                aligned = self._align.process(frames)
                color, depth = aligned.get_color_frame(), aligned.get_depth_frame()
                if not color or not depth:
                    continue
                raw = np.asanyarray(depth.get_data())
                frame = LiveFrame(self.captured, 1e-3 * color.get_timestamp(),
                                  np.asanyarray(color.get_data()).astype(np.float32) / np.float32(255.0),
                                  np.where(raw > 0, raw.astype(np.float32) * np.float32(self._units), np.float32(0)))
                with self._ready:
                    self.captured += 1
                    if len(self._queue) >= self._waiting:
                        self._queue.popleft()
                        self.dropped += 1
                    self._queue.append(frame)
                    self._ready.notify()
        finally:
            with self._ready:
                self._ended = True
                self._ready.notify_all()

    def next(self, timeout: float | None = None) -> LiveFrame | None:
        """The oldest waiting frame (the queue holds only the newest ``waiting``), blocking until one comes; None
        when the source has ended and nothing waits."""
        with self._ready:
            self._ready.wait_for(lambda: self._queue or self._ended, timeout)
            return self._queue.popleft() if self._queue else None

    def stop(self) -> None:
        """Stop capturing (frames still waiting are left unprocessed and counted as dropped)."""
        with self._ready:
            self._ended = True
            self.dropped += len(self._queue)
            self._queue.clear()
            self._ready.notify_all()
        self._thread.join(timeout=5)
        try:
            self._pipeline.stop()
        except RuntimeError:
            pass
