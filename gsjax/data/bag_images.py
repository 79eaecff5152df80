"""ROS image messages as arrays and back: ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` (colour and
depth, including ``compressedDepth``) and the camera of ``sensor_msgs/CameraInfo``. Works on the deserialized
message objects of ROS 1 and ROS 2 alike (field names differ only in ``CameraInfo``'s case); no ROS install needed.

Encodings read: colour ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8`` and JPEG/PNG ``CompressedImage``; depth
``16UC1`` (raw units, millimetres unless the caller's depth scale says otherwise) and ``32FC1`` (metres), raw or as
``compressedDepth`` (PNG after a 12-byte header).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from gsjax.data.errors import DatasetError

COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
_COMPRESSED_DEPTH_HEADER = 12  # int32 format, float32 depthQuantA, float32 depthQuantB (image_transport's)


def is_depth_image(msg: Any) -> bool:
    """Whether an Image or CompressedImage message holds depth (by its encoding or format string)."""
    if hasattr(msg, "encoding"):
        return msg.encoding in DEPTH_ENCODINGS
    return "compresseddepth" in msg.format.lower()


def decode_color(msg: Any, where: str) -> np.ndarray:
    """An Image or CompressedImage -> [H, W, 3] float32 RGB in [0, 1]; DatasetError naming ``where`` otherwise."""
    if hasattr(msg, "encoding"):
        channels = _CHANNELS.get(msg.encoding)
        if channels is None:
            raise DatasetError(f"{where}: colour encoding {msg.encoding!r} is not read (expected one of "
                               f"{', '.join(COLOR_ENCODINGS)} or a JPEG/PNG CompressedImage)")
        pixels = _raw_pixels(msg, np.uint8, channels, where)
        if msg.encoding.startswith("bgr"):
            pixels = pixels[..., [2, 1, 0]]
        rgb = np.repeat(pixels, 3, axis=-1) if channels == 1 else pixels[..., :3]
    else:
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DatasetError(f"{where}: compressed colour image ({msg.format!r}) cannot be decoded")
        rgb = bgr[:, :, ::-1]
    return rgb.astype(np.float32) / np.float32(255.0)


def decode_depth(msg: Any, depth_scale: float | None, where: str) -> np.ndarray:
    """An Image or CompressedImage of depth -> [H, W] float32 metres, 0 where invalid. ``16UC1`` is divided by
    ``depth_scale`` (raw units per metre; None: 1000, millimetres), ``32FC1`` is metres (divided by ``depth_scale``
    when given); non-finite float depth counts as invalid (ROS marks missing depth with NaN)."""
    if hasattr(msg, "encoding"):
        if msg.encoding not in DEPTH_ENCODINGS:
            raise DatasetError(f"{where}: depth encoding {msg.encoding!r} is not read (expected one of "
                               f"{', '.join(DEPTH_ENCODINGS)})")
        dtype = np.float32 if msg.encoding == "32FC1" else np.uint16
        raw = _raw_pixels(msg, dtype, 1, where)[..., 0]
    else:
        raw = _compressed_depth(msg, where)
    if raw.dtype == np.uint16:
        scale = np.float32(1000.0 if depth_scale is None else depth_scale)
        return np.where(raw == 0, np.float32(0.0), raw.astype(np.float32) / scale)
    depth = raw.astype(np.float32) / np.float32(1.0 if depth_scale is None else depth_scale)
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0.0))


def _raw_pixels(msg: Any, dtype, channels: int, where: str) -> np.ndarray:
    """The pixels of a raw Image as [H, W, channels] ``dtype``, honouring its row step and byte order."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    item = np.dtype(dtype).itemsize
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data.tobytes(), np.uint8)
    if step < width * channels * item or data.size < step * height:
        raise DatasetError(f"{where}: image data holds {data.size} bytes, {height} rows of {step} bytes expected for "
                           f"{width}x{height} {msg.encoding}")
    rows = data[: step * height].reshape(height, step)[:, : width * channels * item]
    order = ">" if getattr(msg, "is_bigendian", 0) else "<"
    return rows.copy().view(np.dtype(dtype).newbyteorder(order) if item > 1 else dtype).reshape(
        height, width, channels).astype(dtype)


def _compressed_depth(msg: Any, where: str) -> np.ndarray:
    """``compressedDepth``: a 12-byte header, then a PNG of the raw 16-bit depth (``16UC1``) or of the quantized
    inverse depth (``32FC1``: depth = A / (q - B), 0 where q is 0)."""
    data = bytes(msg.data)
    kind = msg.format.split(";")[0].strip()
    if len(data) <= _COMPRESSED_DEPTH_HEADER:
        raise DatasetError(f"{where}: compressedDepth message of {len(data)} bytes holds no image")
    png = cv2.imdecode(np.frombuffer(data[_COMPRESSED_DEPTH_HEADER:], np.uint8), cv2.IMREAD_UNCHANGED)
    if png is None or png.dtype != np.uint16 or png.ndim != 2:
        raise DatasetError(f"{where}: compressedDepth image ({msg.format!r}) is not a 16-bit PNG")
    if kind in ("16UC1", "mono16"):
        return png
    if kind == "32FC1":
        _, quant_a, quant_b = struct.unpack("<iff", data[:_COMPRESSED_DEPTH_HEADER])
        q = png.astype(np.float32)
        return np.where(png > 0, quant_a / np.where(png > 0, q - quant_b, 1.0), 0.0).astype(np.float32)
    raise DatasetError(f"{where}: compressedDepth of {kind!r} is not read (expected 16UC1 or 32FC1)")


@dataclass(frozen=True)
class BagCamera:
    """A camera from ``sensor_msgs/CameraInfo``: ``k`` [3, 3] (px), image ``width`` x ``height``, and the
    distortion (``model``, coefficients ``d``; all zero or empty: none)."""

    k: np.ndarray
    width: int
    height: int
    model: str
    d: np.ndarray

    @property
    def distorted(self) -> bool:
        return bool(np.any(self.d != 0))


def camera_from_info(msg: Any, where: str) -> BagCamera:
    """The camera of a CameraInfo message (ROS 1 ``K``/``D`` or ROS 2 ``k``/``d``); DatasetError naming ``where``
    for a calibration that is not one (zero focal length) or a distortion model gsjax cannot undo."""
    k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, np.float64).reshape(3, 3)
    d = np.asarray(msg.d if hasattr(msg, "d") else msg.D, np.float64).reshape(-1)
    camera = BagCamera(k, int(msg.width), int(msg.height), str(msg.distortion_model), d)
    if not (k[0, 0] > 0 and k[1, 1] > 0 and np.isfinite(k).all()):
        raise DatasetError(f"{where}: camera_info has no calibration (K = {k.reshape(-1).tolist()}); give the camera "
                           "with --intrinsics FX,FY,CX,CY")
    if camera.distorted and camera.model not in DISTORTION_MODELS:
        raise DatasetError(f"{where}: distortion model {camera.model!r} with non-zero coefficients cannot be undone "
                           f"(gsjax undistorts {', '.join(DISTORTION_MODELS)}); rectify the images first, or give "
                           "--intrinsics to read them as they are")
    return camera


class Undistorter:
    """Undistorts images of a :class:`BagCamera` to the pinhole of the same K (colour bilinear; depth nearest, so
    no depth is blended across an edge)."""

    def __init__(self, camera: BagCamera):
        self.maps = cv2.initUndistortRectifyMap(camera.k, camera.d, None, camera.k, (camera.width, camera.height),
                                                cv2.CV_32FC1)

    def color(self, image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, *self.maps, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def depth(self, image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, *self.maps, interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)


def color_message(color: np.ndarray, stamp_ns: int, frame_id: str, msgtypes: Any, compressed: bool = False) -> Any:
    """A colour frame [H, W, 3] in [0, 1] as an ``rgb8`` Image (rounded, as :func:`gsjax.io.images.save_color_png`)
    or a PNG CompressedImage, made with the typestore's classes ``msgtypes`` (a dict by message type)."""
    from gsjax.io.images import to_uint8  # imported here: it pulls in matplotlib

    rgb = to_uint8(color)
    header = header_message(msgtypes, stamp_ns, frame_id)
    if compressed:
        ok, png = cv2.imencode(".png", rgb[:, :, ::-1])
        return make_message(msgtypes, "sensor_msgs/msg/CompressedImage", header=header,
                            format="rgb8; png compressed bgr8", data=np.frombuffer(png.tobytes(), np.uint8))
    height, width = rgb.shape[:2]
    return make_message(msgtypes, "sensor_msgs/msg/Image", header=header, height=height, width=width,
                        encoding="rgb8", is_bigendian=0, step=3 * width, data=rgb.reshape(-1))


def depth_message(depth: np.ndarray, stamp_ns: int, frame_id: str, msgtypes: Any, depth_scale: float,
                  compressed: bool = False) -> Any:
    """A depth frame [H, W] metres as a ``16UC1`` Image of ``depth_scale`` units per metre (rounded), or as the
    ``compressedDepth`` PNG form."""
    depth = np.asarray(depth, np.float64)
    raw = np.round(np.where(np.isfinite(depth) & (depth > 0), depth, 0.0) * depth_scale)
    if np.any(raw > np.iinfo(np.uint16).max):
        raise ValueError(f"depth beyond {np.iinfo(np.uint16).max / depth_scale:.1f} m does not fit 16UC1 at "
                         f"{depth_scale:g} units per metre")
    raw = raw.astype(np.uint16)
    header = header_message(msgtypes, stamp_ns, frame_id)
    if compressed:
        ok, png = cv2.imencode(".png", raw)
        data = struct.pack("<iff", 0, 0.0, 0.0) + png.tobytes()
        return make_message(msgtypes, "sensor_msgs/msg/CompressedImage", header=header,
                            format="16UC1; compressedDepth png", data=np.frombuffer(data, np.uint8))
    height, width = raw.shape
    return make_message(msgtypes, "sensor_msgs/msg/Image", header=header, height=height, width=width,
                        encoding="16UC1", is_bigendian=0, step=2 * width,
                        data=np.frombuffer(raw.astype("<u2").tobytes(), np.uint8))


def camera_info_message(k: np.ndarray, width: int, height: int, stamp_ns: int, frame_id: str, msgtypes: Any) -> Any:
    """A distortion-free ``sensor_msgs/CameraInfo`` of calibration ``k`` [3, 3] (ROS 1 or ROS 2 field names, as
    ``msgtypes``' class has them)."""
    k = np.asarray(k, np.float64)
    p = np.concatenate([k, np.zeros((3, 1))], axis=1)
    values = dict(header=header_message(msgtypes, stamp_ns, frame_id), height=height, width=width,
                  distortion_model="plumb_bob", d=np.zeros(5), k=k.reshape(-1), r=np.eye(3).reshape(-1),
                  p=p.reshape(-1), binning_x=0, binning_y=0,
                  roi=make_message(msgtypes, "sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0,
                                   width=0, do_rectify=False))
    return make_message(msgtypes, "sensor_msgs/msg/CameraInfo", **values)


def header_message(msgtypes: Any, stamp_ns: int, frame_id: str) -> Any:
    stamp = make_message(msgtypes, "builtin_interfaces/msg/Time", sec=int(stamp_ns // 1_000_000_000),
                  nanosec=int(stamp_ns % 1_000_000_000))
    return make_message(msgtypes, "std_msgs/msg/Header", seq=0, stamp=stamp, frame_id=frame_id)


def make_message(msgtypes: Any, msgtype: str, **values: Any) -> Any:
    """A message of ``msgtype`` from ``values`` matched to its fields by name, case aside (ROS 1's ``K`` is ROS 2's
    ``k``); values for fields the type lacks (ROS 2 headers have no ``seq``) are left out."""
    cls = msgtypes[msgtype]
    fields = {name.lower(): name for name in cls.__dataclass_fields__ if name != "__msgtype__"}
    return cls(**{fields[name.lower()]: value for name, value in values.items() if name.lower() in fields})


def stamp_ns(msg: Any) -> int:
    """A message's header stamp in nanoseconds (ROS 1 ``secs``/``nsecs`` are read into ROS 2 names by rosbags)."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
