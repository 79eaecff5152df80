"""Write a sequence as a RealSense recording with the SDK's own recorder (``gsjax synth --format realsense``): a
software device with a depth and a colour sensor (the sequence's camera for both, no extrinsic offset) is recorded
by ``rs.recorder`` while the frames are pushed at their frame rate, so the file is what ``realsense-viewer`` writes
(pyrealsense2 2.59: a ROS 2 sqlite3 ``.db3``, PNG colour, ``compressedDepth`` depth). Needs the optional
``pyrealsense2`` (``pip install -e '.[realsense]'``)."""

from __future__ import annotations

import gc
import time
from pathlib import Path

import numpy as np

from gsjax.data.sequence import Sequence


def require_pyrealsense2():
    """The pyrealsense2 module; ImportError saying how to install it otherwise."""
    try:
        import pyrealsense2
    except ImportError:
        raise ImportError("RealSense recording and live capture need pyrealsense2: pip install -e '.[realsense]'") \
            from None
    return pyrealsense2


def write_realsense(sequence: Sequence, path: str | Path, *, depth_units: float = 0.001) -> np.ndarray:
    """Record ``sequence`` to ``path`` (``.db3``) through the SDK's recorder, one frame per frame interval (the
    recorder stamps messages by their arrival); depth in units of ``depth_units`` m. Returns the stamps (s) the
    colour frames got, for a ground-truth file in the recording's time."""
    rs = require_pyrealsense2()
    from gsjax.io.images import to_uint8

    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; not overwriting it")
    k = sequence.intrinsics
    identity = rs.extrinsics()
    identity.rotation, identity.translation = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [0.0, 0.0, 0.0]
    recording = SoftwareRecording(rs, path, k, k, identity, depth_units)
    times = sequence.timestamps
    start = time.perf_counter()
    try:
        for i in range(len(sequence)):
            frame = sequence.read_host(i)
            raw = np.round(np.where(frame.depth > 0, frame.depth, 0.0) / depth_units).astype(np.uint16)
            delay = float(times[i] - times[0]) - (time.perf_counter() - start)
            if delay > 0:
                time.sleep(delay)  # at the frame rate: the recorder stamps by arrival
            recording.push(i, 1e3 * float(times[i]), raw, to_uint8(frame.color))
    finally:
        recording.close()
        del recording
    return _written_stamps(path, len(sequence))


def _written_stamps(path: Path, frames: int, timeout_s: float = 30.0) -> np.ndarray:
    """The colour stamps of the recording at ``path`` once all ``frames`` are in the file: the SDK's writer may still
    be flushing the last ones when the recorder is released (seen on a loaded machine: 5 of 6 frames read back at
    once, 6 a moment later)."""
    from gsjax.data.realsense import recorded_color_stamps

    deadline = time.monotonic() + timeout_s
    found = 0
    while True:
        try:
            stamps = recorded_color_stamps(path)
            found = len(stamps)
            if found == frames:
                return stamps
        except Exception:  # a file still being written may not read yet
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"{path}: the RealSense SDK's recorder wrote {found} of {frames} colour frames")
        gc.collect()  # the SDK closes the file when its last handle is collected
        time.sleep(0.05)


class SoftwareRecording:
    """The SDK's recorder over a software device with a depth and a colour sensor: frames pushed to it are written
    to ``path`` as a RealSense recording (what ``realsense-viewer`` writes).

    Args:
      rs: the pyrealsense2 module.
      path: the recording to write (``.db3``).
      depth_camera: the depth sensor's :class:`gsjax.camera.Intrinsics` (its size is the depth images').
      color_camera: the colour sensor's.
      depth_to_color (rs.extrinsics): the depth camera's pose in the colour camera's frame.
      depth_units: metres per raw depth unit, recorded as the depth sensor's option.
    """

    def __init__(self, rs, path: str | Path, depth_camera, color_camera, depth_to_color, depth_units: float):
        self._rs = rs
        device = rs.software_device()
        self._sensors = (device.add_sensor("Depth"), device.add_sensor("Color"))
        self._profiles = (self._sensors[0].add_video_stream(video_stream(rs, depth_camera, rs.stream.depth,
                                                                         rs.format.z16, 2, 0)),
                          self._sensors[1].add_video_stream(video_stream(rs, color_camera, rs.stream.color,
                                                                         rs.format.rgb8, 3, 1)))
        self._sensors[0].add_read_only_option(rs.option.depth_units, depth_units)
        self._profiles[0].register_extrinsics_to(self._profiles[1], depth_to_color)
        device.create_matcher(rs.matchers.default)
        self._recorder = rs.recorder(str(path), device)
        self._recorded = self._recorder.query_sensors()
        for sensor, profile in zip(self._recorded, self._profiles):
            sensor.open(profile)
            sensor.start(lambda frame: None)

    def push(self, number: int, stamp_ms: float, depth: np.ndarray, color: np.ndarray) -> None:
        """Hand one frame to both sensors.

        Args:
          number: the frame number.
          stamp_ms: its hardware-clock timestamp (ms).
          depth: [H, W] uint16 raw depth of the depth camera's size.
          color: [H, W, 3] uint8 RGB of the colour camera's size.
        """
        rs = self._rs
        for sensor, profile, pixels, bpp in zip(self._sensors, self._profiles, (depth, color), (2, 3)):
            video = rs.software_video_frame()
            video.pixels, video.stride, video.bpp = np.ascontiguousarray(pixels), pixels.shape[1] * bpp, bpp
            video.timestamp, video.frame_number = stamp_ms, number
            video.domain, video.profile = rs.timestamp_domain.hardware_clock, profile.as_video_stream_profile()
            sensor.on_video_frame(video)

    def close(self) -> None:
        """Stop the sensors and let go of the recorder (the SDK writes out and closes the file once its last handle
        is gone)."""
        for sensor in self._recorded:
            sensor.stop()
            sensor.close()
        self._recorded = self._sensors = self._profiles = ()
        del self._recorder
        gc.collect()


def video_stream(rs, k, kind, fmt, bpp: int, uid: int):
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = k.width, k.height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = float(k.fx), float(k.fy), float(k.cx), float(k.cy)
    intrinsics.model, intrinsics.coeffs = rs.distortion.none, [0.0] * 5
    stream = rs.video_stream()
    stream.type, stream.fmt, stream.index, stream.uid = kind, fmt, 0, uid
    stream.width, stream.height, stream.fps, stream.bpp, stream.intrinsics = k.width, k.height, 30, bpp, intrinsics
    return stream
