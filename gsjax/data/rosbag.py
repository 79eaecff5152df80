"""ROS bags as RGB-D sequences: ROS 1 ``.bag`` files and ROS 2 bag folders (sqlite3 or mcap storage), read with
``rosbags`` (pure Python: no ROS install).

* Topics: the colour, depth and ``CameraInfo`` topics are chosen by message type where that is unambiguous (an
  image topic is depth when its first message's encoding is; several ``CameraInfo`` topics: the one beside the depth
  topic, then the colour topic); otherwise :class:`BagOptions` names them, and a DatasetError lists the candidates.
* Encodings: see :mod:`gsjax.data.bag_images`. ``16UC1`` depth is millimetres unless ``depth_scale`` says otherwise.
* Pairing: colour and depth by their header stamps, one to one, greedily by the smallest difference (TUM's
  ``associate.py``) within ``max_time_diff`` (20 ms); how many of each stream were paired and dropped is reported
  as a DatasetWarning. Frame timestamps are the colour stamps.
* Camera: from ``CameraInfo`` (K; ``plumb_bob`` / ``rational_polynomial`` distortion is undone with OpenCV, any
  other refused), or ``intrinsics`` (which reads the images as stored). Colour and depth of different sizes are
  refused, naming both (record depth aligned to colour, e.g. RealSense's ``aligned_depth_to_color``).
* Ground truth (optional): a TUM trajectory file (nearest pose within ``max_time_diff``), or the bag's ``/tf``
  between two named frames (the transform ``parent -> child`` is the camera-to-world pose).
* Frames are read when asked for: the bag is scanned once for the message stamps, then each frame's two messages
  are fetched by time, so memory does not grow with the bag's length.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gsjax.camera import Intrinsics, invert_transform, make_intrinsics, quaternion_to_rotation_np
from gsjax.data.bag_db3 import Db3Reader
from gsjax.data.bag_images import (
    BagCamera,
    Undistorter,
    camera_from_info,
    decode_color,
    decode_depth,
    is_depth_image,
    stamp_ns,
)
from gsjax.data.errors import DatasetError, DatasetWarning
from gsjax.data.images import downscale_color, downscale_depth
from gsjax.data.listing import GivenIntrinsics, select_indices
from gsjax.data.sequence import Sequence
from gsjax.data.tum import associate, read_groundtruth_at

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class BagOptions:
    """How to read a bag (``gsjax run --dataset rosbag`` flags in brackets).

    Attributes:
      rgb_topic: the colour topic (``--rgb-topic``); None: chosen by message type.
      depth_topic: the depth topic (``--depth-topic``); None: chosen by message type.
      camera_info_topic: the ``CameraInfo`` topic (``--camera-info-topic``); None: chosen by message type.
      max_time_diff: the largest colour-depth stamp difference of a pair, and of a frame and its ground-truth pose
        (s; ``--max-time-diff``).
      groundtruth: a TUM trajectory file of camera-to-world poses (``--groundtruth``).
      gt_frames: (parent, child) frames of ``/tf`` whose transform is the camera-to-world pose (``--gt-frames``).
    """

    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    max_time_diff: float = 0.02
    groundtruth: Path | None = None
    gt_frames: tuple[str, str] | None = None


def open_rosbag(path: str | Path, options: BagOptions = BagOptions(), *, intrinsics: GivenIntrinsics = None,
                depth_scale: float | None = None, start: int = 0, stride: int = 1, max_frames: int | None = None,
                downscale: int = 1) -> Sequence:
    """A ROS 1 bag file or ROS 2 bag folder as a lazily read :class:`Sequence` (see the module docstring).

    Raises DatasetError naming the bag (and the topic) for anything it cannot use: not a bag, a truncated or empty
    one, no depth topic, an ambiguous topic, an unknown encoding, mismatched sizes, no camera, stamps that never pair.
    """
    if options.groundtruth is not None and options.gt_frames is not None:
        raise ValueError("give the ground truth as a TUM file or as /tf frames, not both")
    bag = BagFile(Path(path))
    rgb, depth, info = bag.choose_topics(options)

    def camera(size: tuple[int, int]) -> tuple[Intrinsics, Callable | None]:
        found, undistort = _camera(bag, info, intrinsics, size)
        return found, None if undistort is None else (lambda c, d: (undistort.color(c), undistort.depth(d)))

    return paired_sequence(bag, rgb, depth, camera, options, depth_scale=depth_scale, start=start, stride=stride,
                           max_frames=max_frames, downscale=downscale)


def paired_sequence(bag: BagFile, rgb: str, depth: str,
                    camera: Callable[[tuple[int, int]], tuple[Intrinsics, Callable | None]], options: BagOptions, *,
                    depth_scale: float | None, start: int, stride: int, max_frames: int | None, downscale: int,
                    same_size: bool = True) -> Sequence:
    """The colour and depth messages of ``rgb`` and ``depth`` paired by stamp, as a lazily read :class:`Sequence`.

    ``camera(depth size)`` -> (the frames' intrinsics at the stored size, and a function that maps a decoded
    (colour, depth metres) pair into that camera, or None); ``depth_scale``: depth units per metre (None: 16-bit
    depth in millimetres, float depth in metres);
    ``same_size``: refuse colour and depth of different sizes (False when ``camera``'s function aligns them)."""
    color_log, color_stamps, color_size = bag.scan(rgb)
    depth_log, depth_stamps, depth_size = bag.scan(depth)
    if same_size and color_size != depth_size:
        raise DatasetError(f"{bag.path}: colour ({rgb}) is {color_size[1]}x{color_size[0]} but depth ({depth}) is "
                           f"{depth_size[1]}x{depth_size[0]} (WxH); record depth aligned to colour (e.g. RealSense's "
                           "aligned_depth_to_color topic) or resize one of them")
    i, j = associate(color_stamps / 1e9, depth_stamps / 1e9, options.max_time_diff)
    if i.size == 0:
        raise DatasetError(
            f"{bag.path}: no colour frame ({rgb}, stamps {_span(color_stamps)}) has a depth image ({depth}, stamps "
            f"{_span(depth_stamps)}) within {options.max_time_diff} s (--max-time-diff)")
    if i.size < color_stamps.size or j.size < depth_stamps.size:
        warnings.warn(f"{bag.path}: paired {i.size} frames: {color_stamps.size - i.size} of {color_stamps.size} "
                      f"colour images ({rgb}) and {depth_stamps.size - j.size} of {depth_stamps.size} depth images "
                      f"({depth}) have no partner within {options.max_time_diff} s and are dropped", DatasetWarning,
                      stacklevel=3)
    times = color_stamps[i] / 1e9
    intrinsics, transform = camera(depth_size)
    c2w, valid = _ground_truth(bag, options, times)
    keep = select_indices(len(times), start=start, stride=stride, max_frames=max_frames)
    if keep.size == 0:
        raise DatasetError(f"{bag.path}: empty sequence ({len(times)} frames paired, none left from start={start})")
    pairs = [(int(color_log[i[k]]), int(depth_log[j[k]])) for k in keep]
    where = [f"{bag.path} at {times[k]:.6f} s" for k in keep]
    lock = threading.Lock()

    def read_rgbd(n: int) -> tuple[np.ndarray, np.ndarray]:
        with lock:  # one reader, shared by the chunk prefetch and the outputs
            color_msg = bag.message_at(rgb, pairs[n][0])
            depth_msg = bag.message_at(depth, pairs[n][1])
        color = decode_color(color_msg, f"{where[n]} ({rgb})")
        metres = decode_depth(depth_msg, depth_scale, f"{where[n]} ({depth})")
        if transform is not None:
            color, metres = transform(color, metres)
        if color.shape[:2] != intrinsics.shape or metres.shape != intrinsics.shape:
            raise DatasetError(f"{where[n]}: images {color.shape[1]}x{color.shape[0]} / {metres.shape[1]}x"
                               f"{metres.shape[0]}, the camera expects {intrinsics.width}x{intrinsics.height}")
        return downscale_color(color, downscale), downscale_depth(metres, downscale)

    return Sequence(name=bag.path.stem if bag.path.is_file() else bag.path.name,
                    intrinsics=intrinsics if downscale == 1 else intrinsics.downscaled(downscale),
                    timestamps=times[keep], c2w=c2w[keep], pose_valid=valid[keep], read_rgbd=read_rgbd,
                    depth_scale=1000.0 if depth_scale is None else float(depth_scale))


def _span(stamps: np.ndarray) -> str:
    return f"{stamps.min() / 1e9:.3f}-{stamps.max() / 1e9:.3f} s" if stamps.size else "none"


class BagFile:
    """An open bag: its connections by topic, the first message of each, and messages fetched by time."""

    def __init__(self, path: Path):
        from rosbags.highlevel import AnyReader

        self.path = path
        if not path.exists():
            raise DatasetError(f"{path}: bag is missing")
        bag_path = path.parent if path.is_file() and path.suffix in (".db3", ".mcap") else path
        if path.is_file() and path.suffix not in (".bag", ".db3", ".mcap"):
            raise DatasetError(f"{path}: not a ROS bag (expected a ROS 1 .bag file or a ROS 2 bag folder)")
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            raise DatasetError(f"{path}: not a ROS 2 bag folder (no metadata.yaml); a ROS 1 bag is a .bag file")
        bare_db3 = path.suffix == ".db3" and not (path.parent / "metadata.yaml").is_file()  # RealSense's .db3
        try:
            if bare_db3:
                self.reader: Any = Db3Reader(path)
            else:
                self.reader = AnyReader([bag_path])
                self.reader.open()
        except Exception as error:  # rosbags raises its own errors, or a decoder's, for a damaged file
            raise DatasetError(f"{path}: cannot be read as a ROS bag (truncated or damaged? {error})") from None
        self.topics: dict[str, list] = {}
        for connection in self.reader.connections:
            self.topics.setdefault(connection.topic, []).append(connection)
        if not self.topics or self.reader.message_count == 0:
            raise DatasetError(f"{path}: the bag holds no messages")
        self._first: dict[str, Any] = {}

    def msgtype(self, topic: str) -> str:
        return self.topics[topic][0].msgtype

    def first(self, topic: str) -> Any:
        """The first message of ``topic``, deserialized."""
        if topic not in self._first:
            for connection, _, raw in self.reader.messages(connections=self.topics[topic]):
                self._first[topic] = self.reader.deserialize(raw, connection.msgtype)
                break
            else:
                raise DatasetError(f"{self.path}: topic {topic} holds no message")
        return self._first[topic]

    def choose_topics(self, options: BagOptions) -> tuple[str, str, str | None]:
        images = sorted(t for t in self.topics if self.msgtype(t) in IMAGE_TYPES)
        depths = [t for t in images if is_depth_image(self.first(t))]
        colors = [t for t in images if t not in depths]
        rgb = self._pick("colour", options.rgb_topic, colors, "--rgb-topic", IMAGE_TYPES)
        depth = self._pick("depth", options.depth_topic, depths, "--depth-topic", IMAGE_TYPES)
        infos = sorted(t for t in self.topics if self.msgtype(t) == INFO_TYPE)
        if options.camera_info_topic is None and len(infos) > 1:
            for image in (depth, rgb):
                beside = [t for t in infos if t.rsplit("/", 1)[0] == image.rsplit("/", 1)[0]]
                if len(beside) == 1:
                    return rgb, depth, beside[0]
        info = None if not infos and options.camera_info_topic is None else self._pick(
            "camera_info", options.camera_info_topic, infos, "--camera-info-topic", (INFO_TYPE,))
        return rgb, depth, info

    def _pick(self, what: str, given: str | None, candidates: list[str], flag: str, types: tuple) -> str:
        if given is not None:
            if given not in self.topics:
                raise DatasetError(f"{self.path}: no topic {given} ({flag}); its topics: {self._listing()}")
            if self.msgtype(given) not in types:
                raise DatasetError(f"{self.path}: {given} ({flag}) holds {self.msgtype(given)}, not "
                                   f"{' or '.join(types)}")
            return given
        if len(candidates) == 1:
            return candidates[0]
        if not candidates:
            kind = " of depth" if what == "depth" else ""
            raise DatasetError(f"{self.path}: no {what} topic ({' or '.join(types)}{kind}); its topics: "
                               f"{self._listing()}")
        raise DatasetError(f"{self.path}: {len(candidates)} {what} topics ({', '.join(candidates)}); choose one with "
                           f"{flag}")

    def _listing(self) -> str:
        return ", ".join(f"{t} ({self.msgtype(t)})" for t in sorted(self.topics)) or "none"

    def scan(self, topic: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
        """(log times [N] int64 ns, header stamps [N] int64 ns sorted by stamp, image size (H, W)) of ``topic``'s
        messages; reads each message once, keeps none."""
        log, stamps = [], []
        for connection, timestamp, raw in self.reader.messages(connections=self.topics[topic]):
            log.append(timestamp)
            stamps.append(stamp_ns(self.reader.deserialize(raw, connection.msgtype)))
        order = np.argsort(np.asarray(stamps, np.int64), kind="stable")
        first = self.first(topic)
        size = (int(first.height), int(first.width)) if hasattr(first, "height") else _decoded_size(first, topic)
        return np.asarray(log, np.int64)[order], np.asarray(stamps, np.int64)[order], size

    def message_at(self, topic: str, log_ns: int) -> Any:
        for connection, _, raw in self.reader.messages(connections=self.topics[topic], start=log_ns, stop=log_ns + 1):
            return self.reader.deserialize(raw, connection.msgtype)
        raise DatasetError(f"{self.path}: the {topic} message at {log_ns} ns cannot be read again")


def _decoded_size(msg: Any, topic: str) -> tuple[int, int]:
    image = decode_depth(msg, None, topic) if is_depth_image(msg) else decode_color(msg, topic)[..., 0]
    return int(image.shape[0]), int(image.shape[1])


def _camera(bag: BagFile, info: str | None, given: GivenIntrinsics,
            size: tuple[int, int]) -> tuple[Intrinsics, Undistorter | None]:
    """The camera at the stored size, and the undistortion its CameraInfo asks for (none with ``given``)."""
    height, width = size
    if isinstance(given, Intrinsics):
        if given.shape != size:
            raise DatasetError(f"{bag.path}: the given intrinsics are {given.width}x{given.height}, the images "
                               f"{width}x{height}")
        return given, None
    if given is not None:
        return make_intrinsics(*given, height=height, width=width), None
    if info is None:
        raise DatasetError(f"{bag.path}: no sensor_msgs/CameraInfo topic and no --intrinsics: give the camera with "
                           "--intrinsics FX,FY,CX,CY (pixels at the stored image size)")
    camera: BagCamera = camera_from_info(bag.first(info), f"{bag.path} ({info})")
    if (camera.height, camera.width) != size:
        raise DatasetError(f"{bag.path}: {info} describes {camera.width}x{camera.height} images, the images are "
                           f"{width}x{height}")
    k = camera.k
    return make_intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], height, width), (
        Undistorter(camera) if camera.distorted else None)


def _ground_truth(bag: BagFile, options: BagOptions, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if options.groundtruth is not None:
        path = Path(options.groundtruth)
        if not path.is_file():
            raise DatasetError(f"{path}: ground-truth file is missing (--groundtruth)")
        return read_groundtruth_at(path, times, options.max_time_diff)
    c2w, valid = np.tile(np.eye(4), (times.size, 1, 1)), np.zeros(times.size, bool)
    if options.gt_frames is None:
        return c2w, valid
    parent, child = options.gt_frames
    stamps, poses = _tf_poses(bag, parent, child)
    if not stamps.size:
        raise DatasetError(f"{bag.path}: no /tf transform between {parent} and {child} (--gt-frames)")
    from gsjax.eval.association import associate_timestamps

    frame_idx, pose_idx = associate_timestamps(times, stamps, options.max_time_diff)
    c2w[frame_idx], valid[frame_idx] = poses[pose_idx], True
    return c2w, valid


def read_bag_trajectory(path: str | Path, parent: str, child: str) -> tuple[np.ndarray, np.ndarray]:
    """The bag's ground truth: (stamps [N] s, camera-to-world [N, 4, 4]) of the ``/tf`` transform ``parent ->
    child``, sorted by stamp; DatasetError naming the bag when there is none."""
    bag = BagFile(Path(path))
    stamps, poses = _tf_poses(bag, parent, child)
    if not stamps.size:
        raise DatasetError(f"{bag.path}: no /tf transform between {parent} and {child}")
    order = np.argsort(stamps, kind="stable")
    return stamps[order], poses[order]


def _tf_poses(bag: BagFile, parent: str, child: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps [N] s, transforms parent <- child [N, 4, 4]) of the bag's /tf and /tf_static (either direction)."""
    connections = [c for topic in ("/tf", "/tf_static") for c in bag.topics.get(topic, []) if c.msgtype == TF_TYPE]
    stamps, poses = [], []
    for connection, _, raw in bag.reader.messages(connections=connections) if connections else ():
        for tf in bag.reader.deserialize(raw, connection.msgtype).transforms:
            ends = (tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/"))
            if ends not in ((parent, child), (child, parent)):
                continue
            q, t = tf.transform.rotation, tf.transform.translation
            pose = np.eye(4)
            pose[:3, :3] = quaternion_to_rotation_np(np.array([q.w, q.x, q.y, q.z]) / np.linalg.norm(
                [q.w, q.x, q.y, q.z]))
            pose[:3, 3] = (t.x, t.y, t.z)
            stamps.append(stamp_ns(tf) / 1e9)
            poses.append(pose if ends == (parent, child) else invert_transform(pose))
    return np.asarray(stamps, np.float64), np.asarray(poses, np.float64).reshape(-1, 4, 4)
