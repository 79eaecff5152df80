"""Datasets: the :class:`Frame` pytree, lazily read :class:`Sequence` s, readers, and synthetic scenes.

``open_sequence`` is the one entry point for data on disk and for the synthetic room::

    seq = open_sequence("tum", "data/rgbd_dataset_freiburg1_desk", max_frames=100, downscale=2)
    for chunk in seq.chunks(16):   # Frame with a leading axis of 16, for lax.scan
        ...
    times, c2w, valid = seq.gt_trajectory()   # camera-to-world, as the dataset gives it (not re-based)

The readers and their formats: :mod:`gsjax.data.tum`, :mod:`gsjax.data.replica`, :mod:`gsjax.data.scannet`,
:mod:`gsjax.data.sevenscenes`, ROS bags :mod:`gsjax.data.rosbag`; the downscaling rules: :mod:`gsjax.data.images`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from gsjax.config.names import BAGS, SYNTHETIC
from gsjax.data.bag_write import write_rosbag
from gsjax.data.errors import DatasetError, DatasetWarning
from gsjax.data.listing import GivenIntrinsics, sequence_from_files
from gsjax.data.replica import list_replica
from gsjax.data.rosbag import BagOptions, open_rosbag
from gsjax.data.scannet import list_scannet
from gsjax.data.sequence import Sequence
from gsjax.data.sevenscenes import list_sevenscenes
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.data.tum import list_tum, write_tum
from gsjax.frame import Frame, stack_frames

# One reader per name of gsjax.config.names.DATASETS (tests check the two agree).
READERS = {"tum": list_tum, "replica": list_replica, "scannet": list_scannet, "7scenes": list_sevenscenes}
SYNTHETIC_FRAMES = 30  # frames of the synthetic sequence unless max_frames says otherwise


def open_sequence(
    dataset: str,
    path: str | Path | None = None,
    *,
    max_frames: int | None = None,
    stride: int = 1,
    downscale: int = 1,
    start: int = 0,
    intrinsics: GivenIntrinsics = None,
    depth_scale: float | None = None,
    register_color: bool = True,
    sensor_noise: bool = False,
    seed: int = 0,
    bag: BagOptions | None = None,
) -> Sequence:
    """Open an RGB-D sequence stored in a dataset's own layout; frames are read only when accessed.

    Args:
      dataset: "tum", "replica", "scannet", "7scenes", "rosbag" (a ROS 1 ``.bag`` file or a ROS 2 bag folder,
        :mod:`gsjax.data.rosbag`), "realsense" (a RealSense SDK recording, ``.db3`` or ``.bag``,
        :mod:`gsjax.data.realsense`), or "synthetic": the ray-cast room
        (:mod:`gsjax.data.synthetic`, 160x120 before ``downscale``, :data:`SYNTHETIC_FRAMES` frames unless
        ``max_frames`` says otherwise; ``stride`` speeds its motion up; no path, camera or depth-scale overrides).
      path: the sequence directory (TUM: the one holding rgb.txt; Replica: the scene folder holding results/).
      max_frames: keep at most this many frames (after start and stride).
      stride: keep every stride-th frame.
      downscale: integer factor; images are reduced by f x f blocks (colour: mean; depth: median of the valid
        samples, invalid when fewer than half are valid) and the intrinsics by ``Intrinsics.downscaled(f)``.
      start: index of the first frame kept (in the dataset's listing).
      intrinsics: the camera, overriding the dataset's: an Intrinsics at the native resolution (its size must
        match the images), or (fx, fy, cx, cy) in pixels at the stored depth images' size.
      depth_scale: raw depth units per metre, overriding the dataset's (TUM 5000, 7-Scenes and ScanNet 1000,
        Replica 6553.5).
      register_color: resample colour into the depth camera where the reader knows the two are not registered
        (7-Scenes; see :mod:`gsjax.data.sevenscenes`); False reads colour as stored.
      sensor_noise: synthetic only: Kinect-like sensor effects (:meth:`SyntheticConfig.with_sensor_noise`).
      seed: synthetic only: the sensor effects' seed.
      bag: rosbag and realsense: the topics (rosbag), the pairing tolerance and the ground truth
        (:class:`gsjax.data.rosbag.BagOptions`).

    Returns:
      A lazily read :class:`Sequence` whose ``intrinsics`` are the downscaled ones.

    Raises:
      DatasetError: (a ValueError) naming the file, for anything missing, unreadable or inconsistent; checks of
        listings and poses happen here, checks of image contents when a frame is read.

    Warns:
      DatasetWarning: naming the file, for what is handled in a defined way: list files out of order (sorted) or
        with repeated timestamps (repeats dropped), unpaired TUM images (skipped), ground-truth poses that are not
        finite or not rigid (left out of the evaluation).
    """
    if dataset == SYNTHETIC:
        if path is not None or intrinsics is not None or depth_scale is not None or start:
            raise ValueError("the synthetic sequence is generated: no path, intrinsics, depth_scale or start")
        return _synthetic(max_frames, stride, downscale, sensor_noise, seed)
    if dataset not in READERS and dataset not in BAGS:
        raise ValueError(f"unknown dataset {dataset!r}; expected one of {', '.join((*READERS, *BAGS))}, {SYNTHETIC}")
    if sensor_noise:
        raise ValueError("sensor_noise applies to the synthetic sequence only")
    if path is None:
        raise ValueError(f"the {dataset} sequence needs its {'bag' if dataset in BAGS else 'directory'} (path)")
    if depth_scale is not None and not (isinstance(depth_scale, (int, float)) and math.isfinite(depth_scale)
                                        and depth_scale > 0):
        raise ValueError(f"depth_scale must be a finite number > 0 (raw units per metre), got {depth_scale!r}")
    if bag is not None and dataset not in BAGS:
        raise ValueError(f"bag options apply to {', '.join(BAGS)} only")
    path = Path(path)
    if dataset == "realsense":
        from gsjax.data.realsense import open_realsense

        return open_realsense(path, bag or BagOptions(), intrinsics=intrinsics, depth_scale=depth_scale, start=start,
                              stride=stride, max_frames=max_frames, downscale=downscale)
    if dataset in BAGS:
        return open_rosbag(path, bag or BagOptions(), intrinsics=intrinsics, depth_scale=depth_scale, start=start,
                           stride=stride, max_frames=max_frames, downscale=downscale)
    if not path.is_dir():
        raise DatasetError(f"{path}: {dataset} sequence directory is missing")
    files = READERS[dataset](path, intrinsics)
    if depth_scale is not None:
        files = dataclasses.replace(files, depth_scale=float(depth_scale))
    if not register_color:
        files = dataclasses.replace(files, color_camera=None)
    return sequence_from_files(files, path, start=start, stride=stride, max_frames=max_frames, downscale=downscale)


def _synthetic(max_frames: int | None, stride: int, downscale: int, sensor_noise: bool, seed: int) -> Sequence:
    base = SyntheticConfig()
    if downscale < 1 or base.width % downscale or base.height % downscale:
        raise ValueError(f"downscale {downscale} must divide the synthetic {base.width}x{base.height} image")
    config = SyntheticConfig(width=base.width // downscale, height=base.height // downscale,
                             num_frames=max_frames or SYNTHETIC_FRAMES, speed=float(stride), seed=seed)
    return synthetic_sequence(config.with_sensor_noise() if sensor_noise else config)


__all__ = [
    "BagOptions",
    "DatasetError",
    "DatasetWarning",
    "Frame",
    "Sequence",
    "SyntheticConfig",
    "open_sequence",
    "stack_frames",
    "synthetic_sequence",
    "write_rosbag",
    "write_tum",
]
