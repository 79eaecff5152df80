"""Intel RealSense recordings (``realsense-viewer``, the SDK's recorder) as RGB-D sequences.

The SDK (2.5x) records a ROS 2 sqlite3 file (``.db3``, without ``metadata.yaml``), older SDKs a ROS 1 ``.bag``, in
one topic layout: ``/device_0/sensor_N/Depth_0/image/data[/compressedDepth]``,
``/device_0/sensor_M/Color_0/image/data[/compressed]``, each stream's ``image/camera_info``, the depth units in
``/device_0/sensor_N/option/Depth_Units/value`` and each stream's extrinsics in ``.../tf/...``.

gsjax reads them with the same reader as ROS bags (:mod:`gsjax.data.rosbag`), not through the SDK's playback: the
frames are stored losslessly (PNG, or raw in the old format), so they decode bit for bit, at any speed and without
dropping a frame, on any machine (no SDK needed). Where the two streams differ (size, intrinsics or pose), depth is
aligned to colour by the SDK's own rule (``rs2::align`` to colour, :func:`align_depth_to_color`); the frames are then
in the colour camera.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from gsjax.camera import Intrinsics, invert_transform, make_intrinsics, quaternion_to_rotation_np
from gsjax.data.bag_images import camera_from_info
from gsjax.data.errors import DatasetError
from gsjax.data.listing import GivenIntrinsics
from gsjax.data.rosbag import BagFile, BagOptions, paired_sequence
from gsjax.data.sequence import Sequence

_STREAM = r"/device_\d+/sensor_(\d+)/{kind}_0"


def open_realsense(path: str | Path, options: BagOptions = BagOptions(), *, intrinsics: GivenIntrinsics = None,
                   depth_scale: float | None = None, start: int = 0, stride: int = 1, max_frames: int | None = None,
                   downscale: int = 1) -> Sequence:
    """A RealSense recording (``.db3`` or ``.bag``) as a lazily read :class:`Sequence` in the colour camera (see the
    module docstring); ``depth_scale`` overrides the recorded depth units (units per metre), ``intrinsics`` the
    colour camera. DatasetError naming the file for a recording without a depth or colour stream."""
    path = Path(path)
    if path.is_file() and path.suffix not in (".db3", ".bag"):
        raise DatasetError(f"{path}: not a RealSense recording (expected the .db3 or .bag file the SDK writes)")
    bag = BagFile(path)
    depth, color = (_stream_topic(bag, kind) for kind in ("Depth", "Color"))
    if depth_scale is None:
        depth_scale = _depth_units_per_metre(bag, depth)
    depth_camera, color_camera = (_stream_camera(bag, topic) for topic in (depth, color))
    depth_to_color = _extrinsics(bag, depth, color)

    def camera(size: tuple[int, int]):
        target = color_camera if intrinsics is None else _given(intrinsics, color_camera)
        if _same_geometry(depth_camera, target, depth_to_color):
            return target, None
        return target, lambda c, d: (c, align_depth_to_color(d, depth_camera, target, depth_to_color, depth_scale))

    return paired_sequence(bag, color, depth, camera, options, depth_scale=depth_scale, start=start, stride=stride,
                           max_frames=max_frames, downscale=downscale, same_size=False)


def recorded_color_stamps(path: str | Path) -> np.ndarray:
    """The stamps (s, sorted) of a recording's colour frames: the frame times ``open_realsense`` gives them."""
    bag = BagFile(Path(path))
    return bag.scan(_stream_topic(bag, "Color"))[1] / 1e9


def align_depth_to_color(depth: np.ndarray, depth_camera: Intrinsics, color_camera: Intrinsics,
                         depth_to_color: np.ndarray, units_per_metre: float) -> np.ndarray:
    """Depth [H_d, W_d] (m, ``units_per_metre`` raw units each) seen from the colour camera [H_c, W_c], by the rule
    of the SDK's ``rs2::align`` to colour: each depth pixel's top-left corner is deprojected at its depth, moved by
    ``depth_to_color`` [4, 4] and projected into the colour image (pixel = int(p + 0.5), truncated as C++ casts);
    when depth has fewer pixels per degree than colour its bottom-right corner too, and the rectangle between them
    takes the depth; the nearest depth wins where pixels meet, cells outside the image are skipped. Pinhole cameras
    (the D400 series' streams); float32 arithmetic in the SDK's order. Matches pyrealsense2 2.59's ``rs.align``
    pixel for pixel (``tests/data/test_realsense.py``, depth coarser and finer than colour)."""
    f32 = np.float32
    raw = np.round(np.asarray(depth, np.float64) * units_per_metre)
    rows, cols = np.nonzero(raw > 0)
    z = raw[rows, cols].astype(f32) * f32(1.0 / units_per_metre)
    r = depth_to_color[:3, :3].astype(f32)
    t = depth_to_color[:3, 3].astype(f32)
    fx, fy, cx, cy = (f32(getattr(color_camera, name)) for name in ("fx", "fy", "cx", "cy"))

    def corner(offset: float) -> tuple[np.ndarray, np.ndarray]:
        x = (cols.astype(f32) + f32(offset) - f32(depth_camera.cx)) / f32(depth_camera.fx)
        y = (rows.astype(f32) + f32(offset) - f32(depth_camera.cy)) / f32(depth_camera.fy)
        px, py = z * x, z * y
        mx = ((r[0, 0] * px + r[0, 1] * py) + r[0, 2] * z) + t[0]
        my = ((r[1, 0] * px + r[1, 1] * py) + r[1, 2] * z) + t[1]
        mz = ((r[2, 0] * px + r[2, 1] * py) + r[2, 2] * z) + t[2]
        u, v = (mx / mz) * fx + cx, (my / mz) * fy + cy
        return np.trunc(u + f32(0.5)).astype(np.int64), np.trunc(v + f32(0.5)).astype(np.int64)

    u0, v0 = corner(-0.5)
    u1, v1 = corner(0.5) if _coarser(depth_camera, color_camera) else (u0, v0)
    height, width = color_camera.height, color_camera.width
    out = np.full(height * width, np.inf, f32)
    values = (raw[rows, cols] / units_per_metre).astype(f32)
    for dv in range(int(np.max(v1 - v0, initial=-1)) + 1):
        for du in range(int(np.max(u1 - u0, initial=-1)) + 1):
            u, v = u0 + du, v0 + dv
            hit = (du <= u1 - u0) & (dv <= v1 - v0) & (u >= 0) & (v >= 0) & (u < width) & (v < height)
            np.minimum.at(out, v[hit] * width + u[hit], values[hit])
    return np.where(np.isinf(out), f32(0.0), out).reshape(height, width)


def _coarser(depth: Intrinsics, color: Intrinsics) -> bool:
    """Whether depth has fewer pixels per degree of field of view than colour (along either axis)."""
    def per_degree(k: Intrinsics) -> tuple[float, float]:
        fov_x = np.arctan2(float(k.cx) + 0.5, float(k.fx)) + np.arctan2(k.width - (float(k.cx) + 0.5), float(k.fx))
        fov_y = np.arctan2(float(k.cy) + 0.5, float(k.fy)) + np.arctan2(k.height - (float(k.cy) + 0.5), float(k.fy))
        return k.width / np.degrees(fov_x), k.height / np.degrees(fov_y)

    (dx, dy), (cx, cy) = per_degree(depth), per_degree(color)
    special = ((depth.width, depth.height), (color.width, color.height)) in (((640, 240), (320, 180)),
                                                                             ((640, 480), (640, 360)))
    return dx < cx or dy < cy or special


def _stream_topic(bag: BagFile, kind: str) -> str:
    pattern = re.compile(_STREAM.format(kind=kind) + r"/image/data(/compressed|/compressedDepth)?$")
    found = sorted(t for t in bag.topics if pattern.fullmatch(t))
    if not found:
        raise DatasetError(f"{bag.path}: no {kind.lower()} stream (a RealSense recording has "
                           f"/device_0/sensor_N/{kind}_0/image/data...); record both depth and colour")
    return found[0]


def _stream_camera(bag: BagFile, image_topic: str) -> Intrinsics:
    """The camera of a stream, from its ``camera_info`` beside the image topic."""
    base = image_topic[: image_topic.index("/image/data")]
    candidates = [t for t in bag.topics if t.startswith(base) and t.endswith("camera_info")
                  and bag.msgtype(t) == "sensor_msgs/msg/CameraInfo"]
    if not candidates:
        raise DatasetError(f"{bag.path}: no camera_info of the stream {base}")
    camera = camera_from_info(bag.first(candidates[0]), f"{bag.path} ({candidates[0]})")
    if camera.distorted:
        raise DatasetError(f"{bag.path}: {base} records a distorted camera ({camera.model}); gsjax aligns pinhole "
                           "RealSense streams (the D400 series' are): give --intrinsics to read the images as they are")
    k = camera.k
    return make_intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], camera.height, camera.width)


def _depth_units_per_metre(bag: BagFile, depth_topic: str) -> float:
    """1 / the recorded ``Depth_Units`` option (metres per unit) of the depth sensor; 1000 (mm) when absent."""
    sensor = re.match(r"(/device_\d+/sensor_\d+)/", depth_topic).group(1)  # type: ignore[union-attr]
    names = [f"{sensor}/option/{name}/value" for name in ("Depth_Units", "Depth Units")]  # newer, older SDKs
    topic = next((name for name in names if name in bag.topics), None)
    if topic is None:
        return 1000.0
    value = _number(bag.first(topic))
    if not value > 0:
        raise DatasetError(f"{bag.path}: {topic} is {value!r}, not a depth unit")
    return 1.0 / value


def _number(msg: Any) -> float:
    data = msg.data
    return float(data.strip()) if isinstance(data, str) else float(data)


def _extrinsics(bag: BagFile, depth_topic: str, color_topic: str) -> np.ndarray:
    """depth -> colour [4, 4]: each stream records the transform from the reference stream to itself
    (``.../tf/ref_N``: ``rotation=r0..r8;translation=t0,t1,t2``, the SDK's column-major rotation, or a geometry_msgs
    Transform; identity for the reference itself or where none is recorded)."""
    def pose(image_topic: str) -> np.ndarray:
        base = image_topic[: image_topic.index("/image/data")]
        found = sorted(t for t in bag.topics if t.startswith(base + "/tf/"))
        transform = np.eye(4)
        if not found:
            return transform
        msg = bag.first(found[0])
        if isinstance(getattr(msg, "data", None), str):
            fields = dict(part.split("=", 1) for part in msg.data.split(";") if "=" in part)
            rotation = np.array([float(x) for x in fields["rotation"].split(",")]).reshape(3, 3).T
            transform[:3, :3], transform[:3, 3] = rotation, [float(x) for x in fields["translation"].split(",")]
        else:
            q, t = msg.rotation, msg.translation
            transform[:3, :3] = quaternion_to_rotation_np(np.array([q.w, q.x, q.y, q.z]))
            transform[:3, 3] = (t.x, t.y, t.z)
        return transform

    return pose(color_topic) @ invert_transform(pose(depth_topic))


def _same_geometry(depth: Intrinsics, color: Intrinsics, depth_to_color: np.ndarray) -> bool:
    same_camera = depth.shape == color.shape and all(
        float(getattr(depth, name)) == float(getattr(color, name)) for name in ("fx", "fy", "cx", "cy"))
    return same_camera and bool(np.allclose(depth_to_color, np.eye(4), atol=1e-9))


def _given(given: GivenIntrinsics, color: Intrinsics) -> Intrinsics:
    if isinstance(given, Intrinsics):
        return given
    return make_intrinsics(*given, height=color.height, width=color.width)  # type: ignore[misc]
