"""Write a sequence as a ROS bag (``gsjax synth --format rosbag``): ROS 1 ``.bag`` or a ROS 2 bag folder (sqlite3
or mcap), colour and depth raw or compressed, the camera on a ``CameraInfo`` topic, and the ground truth as ``/tf``
(``world`` -> ``camera``) beside a TUM trajectory file. What the tests and users write, :mod:`gsjax.data.rosbag`
reads back; with lossless images (raw, or PNG) the frames are those of the folder layout, bit for bit, when the
depth scales agree.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsjax.camera import rotation_to_quaternion_np
from gsjax.data.bag_images import camera_info_message, color_message, depth_message
from gsjax.data.sequence import Sequence

ROS_VERSIONS = (1, 2)
STORAGES = ("sqlite3", "mcap")
# ROS 1's tf2 message, which rosbags' ROS 1 type store does not carry.
_TF_MSG = "geometry_msgs/TransformStamped[] transforms"


@dataclass(frozen=True)
class BagTopics:
    """The topics written: RealSense's ROS driver's names by default (colour, depth aligned to it, its camera)."""

    rgb: str = "/camera/color/image_raw"
    depth: str = "/camera/aligned_depth_to_color/image_raw"
    camera_info: str = "/camera/color/camera_info"
    world_frame: str = "world"
    camera_frame: str = "camera"


def write_rosbag(sequence: Sequence, path: str | Path, *, ros: int = 1, storage: str = "sqlite3",
                 compressed: bool = False, depth_scale: float = 1000.0, topics: BagTopics = BagTopics()) -> Path:
    """Write a sequence as a ROS bag, its valid ground-truth poses on ``/tf`` (``world`` -> ``camera``).

    One ``CameraInfo`` per frame; every message stamped (and logged) at the frame's timestamp. Written under a
    temporary name and renamed, so a killed writer leaves no half bag under ``path``.

    Args:
      sequence: the frames (read one at a time) and their ground truth.
      path: where to write: a ``.bag`` file (ROS 1) or a bag folder (ROS 2); must not exist.
      ros: 1 or 2.
      storage: ROS 2's storage, "sqlite3" or "mcap" (ignored for ROS 1).
      compressed: colour as PNG ``CompressedImage`` and depth as ``compressedDepth`` instead of raw ``rgb8`` /
        ``16UC1``.
      depth_scale: raw depth units per metre of the 16-bit depth.
      topics: the topic and frame names.

    Returns:
      ``path``.

    Raises:
      ValueError: ``ros`` or ``storage`` is unknown.
      FileExistsError: ``path`` exists.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if ros not in ROS_VERSIONS or storage not in STORAGES:
        raise ValueError(f"ros must be one of {ROS_VERSIONS} and storage one of {STORAGES}, got {ros}, {storage!r}")
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; not overwriting it")
    typestore = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    if ros == 1:
        typestore.register(get_types_from_msg(_TF_MSG, "tf2_msgs/msg/TFMessage"))
    msgtypes = typestore.types
    staging = path.with_name(f".{path.name}.partial")  # the bag is written inside, under its own name
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    temporary = staging / path.name
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    serialize = typestore.serialize_ros1 if ros == 1 else typestore.serialize_cdr
    times, c2w, valid = sequence.gt_trajectory()
    k = np.asarray(sequence.intrinsics.matrix(), np.float64)
    with _writer(temporary, ros, storage) as writer:
        streams = {name: writer.add_connection(topic, msgtype, typestore=typestore) for name, topic, msgtype in (
            ("rgb", topics.rgb, image_type), ("depth", topics.depth, image_type),
            ("info", topics.camera_info, "sensor_msgs/msg/CameraInfo"), ("tf", "/tf", "tf2_msgs/msg/TFMessage"))}
        for i, stamp in enumerate(times):
            frame = sequence.read_host(i)
            ns = int(round(float(stamp) * 1e9))
            frame_id = topics.camera_frame
            messages = [("info", camera_info_message(k, sequence.intrinsics.width, sequence.intrinsics.height, ns,
                                                     frame_id, msgtypes)),
                        ("rgb", color_message(frame.color, ns, frame_id, msgtypes, compressed)),
                        ("depth", depth_message(frame.depth, ns, frame_id, msgtypes, depth_scale, compressed))]
            if valid[i]:
                messages.append(("tf", _tf_message(c2w[i], ns, topics, msgtypes)))
            for name, msg in messages:
                writer.write(streams[name], ns, serialize(msg, msg.__msgtype__))
    temporary.rename(path)
    staging.rmdir()
    return path


def _writer(path: Path, ros: int, storage: str):
    if ros == 1:
        from rosbags.rosbag1 import Writer as Writer1

        return Writer1(path)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer2(path, version=9, storage_plugin=plugin)


def _tf_message(c2w: np.ndarray, stamp_ns: int, topics: BagTopics, msgtypes) -> object:
    """``/tf``: the camera frame's pose in the world frame (camera-to-world)."""
    from gsjax.data.bag_images import header_message, make_message

    w, x, y, z = rotation_to_quaternion_np(np.asarray(c2w[:3, :3], np.float64))
    translation = make_message(msgtypes, "geometry_msgs/msg/Vector3", x=c2w[0, 3], y=c2w[1, 3], z=c2w[2, 3])
    rotation = make_message(msgtypes, "geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w)
    transform = make_message(msgtypes, "geometry_msgs/msg/Transform", translation=translation, rotation=rotation)
    stamped = make_message(msgtypes, "geometry_msgs/msg/TransformStamped",
                           header=header_message(msgtypes, stamp_ns, topics.world_frame),
                           child_frame_id=topics.camera_frame, transform=transform)
    return make_message(msgtypes, "tf2_msgs/msg/TFMessage", transforms=[stamped])
