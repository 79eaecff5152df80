"""What readers share: the :class:`FrameFiles` listing, turning a listing into a :class:`Sequence`, numbered-file
discovery and intrinsics files.

Every reader only *lists* a dataset (paths, timestamps, poses, native intrinsics), checking listing and poses at
open time; :func:`sequence_from_files` applies the common options (start, stride, max_frames, downscale), checks
that the selected images exist, and returns a Sequence that reads and checks each image pair when it is asked for.
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.data.errors import DatasetError
from gsjax.data.images import image_size, load_rgbd
from gsjax.data.poses import read_pose_files
from gsjax.data.registration import ColorCamera
from gsjax.data.sequence import Sequence

# What a caller may give a reader instead of the dataset's own intrinsics: Intrinsics (native size), or the pinhole
# values (fx, fy, cx, cy) in pixels at the size of the stored depth images (``gsjax run --intrinsics``).
GivenIntrinsics = Intrinsics | tuple[float, float, float, float] | None


def given_intrinsics(given: GivenIntrinsics, first_depth: Path) -> Intrinsics | None:
    """The caller's intrinsics as :class:`Intrinsics`: as they are, or (fx, fy, cx, cy) at the size of
    ``first_depth`` (read from that image); None when none were given (the reader then uses the dataset's own)."""
    if given is None or isinstance(given, Intrinsics):
        return given
    values = tuple(given)
    if len(values) != 4:
        raise ValueError(f"intrinsics must be (fx, fy, cx, cy), got {len(values)} numbers")
    return make_intrinsics(*values, *image_size(first_depth))


@dataclasses.dataclass(frozen=True)
class FrameFiles:
    """What a reader lists on disk, before the common options are applied (N frames).

    Attributes:
      name: sequence name.
      color_paths, depth_paths: N image paths each.
      timestamps: [N] float64 s.
      c2w: [N, 4, 4] float64 GT camera-to-world poses (anything where invalid); pose_valid: [N] bool.
      intrinsics: intrinsics of the images on disk (native size, before downscaling).
      depth_scale: raw depth units per metre.
      invalid_raw: raw 16-bit depth values that mark invalid pixels besides 0.
      resize_color: resample colour to the depth size (ScanNet), instead of rejecting a size mismatch.
      color_camera: for recordings whose colour is not registered to depth (7-Scenes), the colour camera; colour
        is then resampled into the depth camera when read (:mod:`gsjax.data.registration`).
    """

    name: str
    color_paths: list[Path]
    depth_paths: list[Path]
    timestamps: np.ndarray
    c2w: np.ndarray
    pose_valid: np.ndarray
    intrinsics: Intrinsics
    depth_scale: float
    invalid_raw: tuple[int, ...] = (0,)
    resize_color: bool = False
    color_camera: ColorCamera | None = None


def select_indices(count: int, *, start: int = 0, stride: int = 1, max_frames: int | None = None) -> np.ndarray:
    """Indices ``start, start + stride, ...`` below ``count``, at most ``max_frames`` of them."""
    for label, value, low in (("start", start, 0), ("stride", stride, 1)):
        if not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{label} must be an int >= {low}, got {value!r}")
    if max_frames is not None and (not isinstance(max_frames, (int, np.integer)) or max_frames < 1):
        raise ValueError(f"max_frames must be a positive int or None, got {max_frames!r}")
    return np.arange(start, count, stride)[:max_frames]


def sequence_from_files(
    files: FrameFiles,
    source: Path,
    *,
    start: int = 0,
    stride: int = 1,
    max_frames: int | None = None,
    downscale: int = 1,
) -> Sequence:
    """Apply the common options to a listing and wrap it in a lazily read :class:`Sequence`.

    Raises DatasetError naming ``source`` when no frame is left, or naming the file when a selected image is missing.
    """
    total = len(files.timestamps)
    keep = select_indices(total, start=start, stride=stride, max_frames=max_frames)
    if keep.size == 0:
        raise DatasetError(f"{source}: empty sequence ({total} frames listed, none left from start={start})")
    color_paths = [files.color_paths[i] for i in keep]
    depth_paths = [files.depth_paths[i] for i in keep]
    for path in (*color_paths, *depth_paths):
        if not path.is_file():
            raise DatasetError(f"{path}: image is missing")
    # downscaled() validates the factor; 1 keeps the given values bit for bit.
    intrinsics = files.intrinsics if downscale == 1 else files.intrinsics.downscaled(downscale)
    native_shape = files.intrinsics.shape

    def read_rgbd(i: int) -> tuple[np.ndarray, np.ndarray]:
        return load_rgbd(
            color_paths[i],
            depth_paths[i],
            depth_scale=files.depth_scale,
            native_shape=native_shape,
            downscale=downscale,
            invalid_raw=files.invalid_raw,
            resize_color=files.resize_color,
            color_camera=files.color_camera,
            intrinsics=files.intrinsics,
        )

    return Sequence(
        name=files.name,
        intrinsics=intrinsics,
        timestamps=files.timestamps[keep],
        c2w=files.c2w[keep],
        pose_valid=files.pose_valid[keep],
        read_rgbd=read_rgbd,
        files=list(zip(color_paths, depth_paths)),
        depth_scale=files.depth_scale,
    )


def numbered_files(directory: Path, pattern: str, expected: str | None) -> dict[int, Path]:
    """Files in ``directory`` whose name fully matches ``pattern`` (one group: the frame number) -> {number: path},
    sorted by number. DatasetError when there is none (the message names ``expected``, e.g. "frameNNNNNN.jpg"),
    unless ``expected`` is None."""
    regex = re.compile(pattern)
    if not directory.is_dir():
        raise DatasetError(f"{directory}: directory is missing")
    found: dict[int, Path] = {}
    for path in directory.iterdir():
        match = regex.fullmatch(path.name)
        if match:
            number = int(match.group(1))
            if number in found:
                raise DatasetError(f"{directory}: two files for frame {number}: {found[number].name}, {path.name}")
            found[number] = path
    if not found and expected is not None:
        raise DatasetError(f"{directory}: empty sequence (no {expected})")
    return dict(sorted(found.items()))


def require_color_for_depth(colors: dict[int, Path], depth_dir: Path, depth_pattern: str,
                            color_stem: Callable[[int], Path]) -> None:
    """DatasetError naming the colour image a frame lacks when a depth image in ``depth_dir`` (``depth_pattern``, as
    for :func:`numbered_files`) is numbered as no colour image is: the frames of a numbered layout are its colour
    images, so such a frame would be dropped without a word. ``color_stem(number)`` is the expected colour path
    without its suffix (the suffix of the colour images found). A missing ``depth_dir`` is left to the per-frame
    checks."""
    if not depth_dir.is_dir():
        return
    depths = numbered_files(depth_dir, depth_pattern, None)
    orphans = sorted(set(depths) - set(colors))
    if orphans:
        number = orphans[0]
        expected = color_stem(number).with_name(color_stem(number).name + next(iter(colors.values())).suffix)
        raise DatasetError(f"{expected}: colour image is missing (its depth image {depths[number].name} is "
                           f"present; {len(orphans)} frame(s) without colour in all)")


def files_per_frame(
    name: str,
    colors: dict[int, Path],
    depth_paths: list[Path],
    pose_paths: list[Path],
    intrinsics: Intrinsics,
    depth_scale: float,
    **options: Any,
) -> FrameFiles:
    """The listing of a layout with one colour, depth and pose file per frame, found by frame number (ScanNet,
    7-Scenes): ``colors`` from :func:`numbered_files`; the timestamp of a frame is its number; a missing pose file
    flags its frame's pose invalid. ``options``: the other :class:`FrameFiles` fields."""
    c2w, valid = read_pose_files(pose_paths)
    return FrameFiles(
        name=name,
        color_paths=list(colors.values()),
        depth_paths=depth_paths,
        timestamps=np.array(list(colors), np.float64),
        c2w=c2w,
        pose_valid=valid,
        intrinsics=intrinsics,
        depth_scale=depth_scale,
        **options,
    )


def intrinsics_from_matrix(k: np.ndarray, height: int, width: int, where: Path) -> Intrinsics:
    """A 3x3 (or the top-left of a 4x4) calibration matrix -> Intrinsics; DatasetError naming ``where`` if invalid."""
    k = np.asarray(k, np.float64)
    if abs(k[0, 1]) > 1e-9 or np.any(np.abs(k[2, :3] - (0.0, 0.0, 1.0)) > 1e-9) or abs(k[1, 0]) > 1e-9:
        raise DatasetError(f"{where}: not a pinhole calibration matrix (fx 0 cx; 0 fy cy; 0 0 1): {k[:3, :3].tolist()}")
    try:
        return make_intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], height, width)
    except ValueError as err:
        raise DatasetError(f"{where}: {err}") from None


def read_json_numbers(path: Path, required: tuple[str, ...], optional: tuple[str, ...] = (), within: str = "") -> dict:
    """Numbers from a JSON object (or from its member ``within``): all ``required`` names, and the ``optional`` ones
    that are present -> {name: float}. DatasetError naming the file when one is missing or not a number."""
    try:
        data = json.loads(path.read_text())
        if within:
            data = data[within]
        names = list(required) + [name for name in optional if name in data]
        return {name: float(data[name]) for name in names}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DatasetError(f"{path}: cannot read {', '.join(required)} ({type(err).__name__}: {err})") from None
