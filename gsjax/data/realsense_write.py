"""Write a sequence as a RealSense recording with the SDK's own recorder (``gsjax synth --format realsense``): a
software device with a depth and a colour sensor (the sequence's camera for both, no extrinsic offset) is recorded
by ``rs.recorder`` while the frames are pushed at their frame rate, so the file is what ``realsense-viewer`` writes
(pyrealsense2 2.59: a ROS 2 sqlite3 ``.db3``, PNG colour, ``compressedDepth`` depth). Needs the optional
``pyrealsense2`` (``pip install -e '.[realsense]'``)."""

from __future__ import annotations

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
    device = rs.software_device()
    depth_sensor, color_sensor = device.add_sensor("Depth"), device.add_sensor("Color")
    depth_profile = depth_sensor.add_video_stream(video_stream(rs, k, rs.stream.depth, rs.format.z16, 2, 0))
    color_profile = color_sensor.add_video_stream(video_stream(rs, k, rs.stream.color, rs.format.rgb8, 3, 1))
    depth_sensor.add_read_only_option(rs.option.depth_units, depth_units)
    identity = rs.extrinsics()
    identity.rotation, identity.translation = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [0.0, 0.0, 0.0]
    depth_profile.register_extrinsics_to(color_profile, identity)
    device.create_matcher(rs.matchers.default)
    recorder = rs.recorder(str(path), device)
    recorded = recorder.query_sensors()
    for sensor, profile in zip(recorded, (depth_profile, color_profile)):
        sensor.open(profile)
        sensor.start(lambda frame: None)
    times = sequence.timestamps
    start = time.perf_counter()
    try:
        for i in range(len(sequence)):
            frame = sequence.read_host(i)
            raw = np.round(np.where(frame.depth > 0, frame.depth, 0.0) / depth_units).astype(np.uint16)
            delay = float(times[i] - times[0]) - (time.perf_counter() - start)
            if delay > 0:
                time.sleep(delay)  # at the frame rate: the recorder stamps by arrival
            for sensor, profile, pixels, bpp in ((depth_sensor, depth_profile, raw, 2),
                                                 (color_sensor, color_profile, to_uint8(frame.color), 3)):
                video = rs.software_video_frame()
                video.pixels, video.stride, video.bpp = np.ascontiguousarray(pixels), k.width * bpp, bpp
                video.timestamp, video.frame_number = 1e3 * float(times[i]), i
                video.domain, video.profile = rs.timestamp_domain.hardware_clock, profile.as_video_stream_profile()
                sensor.on_video_frame(video)
    finally:
        for sensor in recorded:
            sensor.stop()
            sensor.close()
        del recorder  # closes the file
    from gsjax.data.realsense import recorded_color_stamps

    return recorded_color_stamps(path)


def video_stream(rs, k, kind, fmt, bpp: int, uid: int):
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = k.width, k.height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = float(k.fx), float(k.fy), float(k.cx), float(k.cy)
    intrinsics.model, intrinsics.coeffs = rs.distortion.none, [0.0] * 5
    stream = rs.video_stream()
    stream.type, stream.fmt, stream.index, stream.uid = kind, fmt, 0, uid
    stream.width, stream.height, stream.fps, stream.bpp, stream.intrinsics = k.width, k.height, 30, bpp, intrinsics
    return stream
