"""Image reading shared by every reader: loading with validation and integer downscaling (writing: gsjax.io.images).

Conventions: colour is returned as float32 RGB in [0, 1] (OpenCV reads BGR; converted here); depth as float32
metres, raw value / ``depth_scale``, with 0 for invalid pixels. Every error is a :class:`DatasetError` naming
the file.

Downscaling by an integer factor f (sizes floored, trailing rows/columns dropped, matching
:meth:`gsjax.camera.Intrinsics.downscaled`): each output pixel is one f x f block of input pixels.
* colour: the block mean (what ``cv2.INTER_AREA`` computes for an integer factor).
* depth: the median of the block's valid samples; the output pixel is invalid (0) when fewer than half of the
  block's f^2 samples are valid. A mean would blend foreground and background at depth edges into depths where
  there is no surface; the median of the valid samples picks one of the surfaces, and the majority rule stops a
  few stray valid samples from filling a hole.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gsjax.camera import Intrinsics
from gsjax.data.errors import DatasetError
from gsjax.data.registration import ColorCamera, register_color


def image_size(path: Path) -> tuple[int, int]:
    """(height, width) of an image file (decodes it once)."""
    image = _imread(path, cv2.IMREAD_UNCHANGED, "image")
    return int(image.shape[0]), int(image.shape[1])


def read_color(path: Path) -> np.ndarray:
    """An 8-bit colour image -> [H, W, 3] float32 RGB in [0, 1] (grey images are replicated to 3 channels)."""
    bgr = _imread(path, cv2.IMREAD_COLOR, "colour image")
    return bgr[:, :, ::-1].astype(np.float32) / np.float32(255.0)


def read_depth(path: Path, depth_scale: float, invalid_raw: tuple[int, ...] = (0,)) -> np.ndarray:
    """A depth image -> [H, W] float32 metres (raw / depth_scale), 0 where invalid.

    Accepts 16-bit unsigned images (raw values listed in ``invalid_raw`` mark invalid pixels; 0 always does) and
    single-channel float images (non-finite or negative values are an error, 0 is invalid).
    """
    raw = _imread(path, cv2.IMREAD_UNCHANGED, "depth image")
    if raw.ndim != 2:
        raise DatasetError(f"{path}: depth image must have one channel, got shape {raw.shape}")
    if raw.dtype == np.uint16:
        invalid = np.isin(raw, np.asarray((0,) + tuple(invalid_raw), np.uint16))
        depth = raw.astype(np.float32) / np.float32(depth_scale)
        return np.where(invalid, np.float32(0.0), depth)
    if raw.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(raw)):
            raise DatasetError(f"{path}: depth image has {int(np.sum(~np.isfinite(raw)))} non-finite values")
        if np.any(raw < 0):
            raise DatasetError(f"{path}: depth image has {int(np.sum(raw < 0))} negative values")
        return (raw / depth_scale).astype(np.float32)
    raise DatasetError(f"{path}: depth image must be 16-bit unsigned or float, got {raw.dtype}")


def load_rgbd(
    color_path: Path,
    depth_path: Path,
    *,
    depth_scale: float,
    native_shape: tuple[int, int],
    downscale: int = 1,
    invalid_raw: tuple[int, ...] = (0,),
    resize_color: bool = False,
    color_camera: ColorCamera | None = None,
    intrinsics: Intrinsics | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Read, check and downscale one colour/depth pair -> (colour [h, w, 3], depth [h, w]) at native_shape // f.

    ``native_shape`` (H, W) is the size the intrinsics describe; the depth image must have it. The colour image
    must too, unless ``resize_color`` (ScanNet: colour is resampled to the depth size with INTER_AREA) or
    ``color_camera`` is given: then colour is registered to the depth camera (``intrinsics``, native size) with
    :func:`gsjax.data.registration.register_color` before downscaling.
    """
    color = read_color(color_path)
    depth = read_depth(depth_path, depth_scale, invalid_raw)
    if depth.shape != tuple(native_shape):
        raise DatasetError(
            f"{depth_path}: depth image is {depth.shape[1]}x{depth.shape[0]} (WxH), "
            f"the intrinsics expect {native_shape[1]}x{native_shape[0]}"
        )
    if color_camera is not None:
        color = register_color(color, depth, intrinsics, color_camera)
    if color.shape[:2] != depth.shape:
        if not resize_color:
            raise DatasetError(
                f"{color_path}: colour image is {color.shape[1]}x{color.shape[0]} (WxH) but its depth image "
                f"{depth_path.name} is {depth.shape[1]}x{depth.shape[0]}"
            )
        color = cv2.resize(color, (depth.shape[1], depth.shape[0]), interpolation=cv2.INTER_AREA)
    return downscale_color(color, downscale), downscale_depth(depth, downscale)


def downscale_color(color: np.ndarray, factor: int) -> np.ndarray:
    """[H, W, C] -> [H // f, W // f, C]: mean over each f x f block."""
    if factor == 1:
        return color
    h, w = color.shape[0] // factor, color.shape[1] // factor
    blocks = color[: h * factor, : w * factor].reshape(h, factor, w, factor, -1)
    return blocks.mean(axis=(1, 3), dtype=np.float32).astype(color.dtype)


def downscale_depth(depth: np.ndarray, factor: int) -> np.ndarray:
    """[H, W] metres (0 invalid) -> [H // f, W // f]: median of each block's valid samples, 0 when fewer than half
    of the block is valid (for an even count of valid samples, the mean of the two middle ones)."""
    if factor == 1:
        return depth
    h, w = depth.shape[0] // factor, depth.shape[1] // factor
    blocks = depth[: h * factor, : w * factor].reshape(h, factor, w, factor).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(h, w, factor * factor)
    valid = blocks > 0
    count = valid.sum(axis=-1)
    ordered = np.sort(np.where(valid, blocks, np.inf), axis=-1)  # valid samples first, ascending
    lo = np.take_along_axis(ordered, np.maximum(count - 1, 0)[..., None] // 2, axis=-1)[..., 0]
    hi = np.take_along_axis(ordered, (count // 2)[..., None], axis=-1)[..., 0]
    enough = 2 * count >= factor * factor
    return np.where(enough, 0.5 * (lo + hi), 0.0).astype(depth.dtype)


def _imread(path: Path, flags: int, what: str) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: {what} is missing")
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DatasetError(f"{path}: {what} cannot be read (not an image OpenCV can decode)")
    return image
