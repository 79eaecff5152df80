"""``Sequence``: an RGB-D sequence whose frames are read (or rendered) only when asked for.

The interface every dataset shares: ``len``, ``seq[i] -> Frame``, iteration, ``chunks(size)`` (stacked Frames for
``lax.scan``), ``intrinsics``, ``timestamps``, ``name`` and ``gt_trajectory()`` (which reads no image).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from gsjax.camera import Intrinsics
from gsjax.data.errors import DatasetError
from gsjax.frame import Frame, host_frame, stack_frames, to_device

# (i) -> (colour [H, W, 3] float32 in [0, 1], depth [H, W] float32 m) for position i of the sequence.
ReadRGBD = Callable[[int], tuple[np.ndarray, np.ndarray]]


class Sequence:
    """An RGB-D sequence that reads (or renders) frames on demand; nothing is cached.

    Built by the readers (:func:`gsjax.data.open_sequence`); the arguments are keyword-only.

    Args:
      name: a short name (usually the directory's).
      intrinsics: the camera of the frames as ``read_rgbd`` returns them.
      timestamps: [T] timestamps (s).
      c2w: [T, 4, 4] ground-truth camera-to-world poses (m); entries where ``pose_valid`` is False are ignored.
      pose_valid: [T] bool, which frames have a ground-truth pose.
      read_rgbd: ``i -> (colour [H, W, 3] float32 in [0, 1], depth [H, W] float32 m)`` for position i.
      files: (colour path, depth path) per frame, or None where frames are not read from files.
      depth_scale: raw depth units per metre of the files read, or None.

    Raises:
      ValueError: the shapes of ``c2w`` or ``pose_valid`` do not match ``timestamps``.

    Attributes:
      name: a short name (usually the directory's).
      intrinsics: :class:`gsjax.camera.Intrinsics` of the frames as returned (after downscaling).
      timestamps: [T] float64 seconds (the frame number where the dataset has no timestamps).
      depth_scale: raw depth units per metre of the files read (None where frames are not read from files).
    """

    def __init__(
        self,
        *,
        name: str,
        intrinsics: Intrinsics,
        timestamps: np.ndarray,
        c2w: np.ndarray,
        pose_valid: np.ndarray,
        read_rgbd: ReadRGBD,
        files: list[tuple[Path, Path]] | None = None,
        depth_scale: float | None = None,
    ):
        count = len(timestamps)
        if c2w.shape != (count, 4, 4) or pose_valid.shape != (count,):
            raise ValueError(f"poses {c2w.shape} / flags {pose_valid.shape} do not match {count} timestamps")
        self.name = name
        self.intrinsics = intrinsics
        self.timestamps = np.array(timestamps, np.float64)
        self.timestamps.flags.writeable = False
        self._c2w = np.where(pose_valid[:, None, None], c2w, np.eye(4)).astype(np.float64)
        self._pose_valid = np.asarray(pose_valid, bool)
        self._read_rgbd = read_rgbd
        self._files = files
        self.depth_scale = depth_scale

    def __len__(self) -> int:
        return len(self.timestamps)

    def __repr__(self) -> str:
        i = self.intrinsics
        return f"Sequence({self.name!r}, {len(self)} frames, {i.width}x{i.height})"

    def __getitem__(self, index: int) -> Frame:
        """Frame ``index`` (negative counts from the end), read now, as jax arrays."""
        return to_device(self.read_host(index))

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def chunks(self, size: int) -> Iterator[Frame]:
        """The sequence as consecutive stacked Frames, for ``lax.scan``; each chunk is read when reached.

        Args:
          size: frames per chunk, a positive int.

        Yields:
          Frames of jax arrays with a leading axis of ``size`` (the last chunk may be shorter).
        """
        if not isinstance(size, int) or size < 1:
            raise ValueError(f"chunk size must be a positive int, got {size!r}")
        for begin in range(0, len(self), size):
            end = min(begin + size, len(self))
            yield to_device(stack_frames([self.read_host(i) for i in range(begin, end)]))

    def gt_trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ground truth, without reading any image (copies).

        Returns:
          timestamps: [T] float64 (s).
          c2w: [T, 4, 4] float64 camera-to-world poses (m), as the dataset gives them; the identity where invalid.
          valid: [T] bool, which frames have a ground-truth pose.
        """
        return self.timestamps.copy(), self._c2w.copy(), self._pose_valid.copy()

    def frame_files(self, index: int) -> tuple[Path, Path] | None:
        """The files a frame is read from.

        Args:
          index: the frame's position in the sequence.

        Returns:
          (colour path, depth path), or None where frames are not read from files.
        """
        return None if self._files is None else self._files[index]

    def describe_frame(self, index: int) -> str:
        """A frame's name for messages.

        Args:
          index: the frame's position in the sequence.

        Returns:
          ``frame i`` and, where frames come from files, its depth image's path in brackets.
        """
        files = self.frame_files(index)
        return f"frame {index}" if files is None else f"frame {index} ({files[1]})"

    def read_host(self, index: int) -> Frame:
        """Read one frame as numpy arrays (now, no device transfer): for writers and host-side tools.

        Args:
          index: the frame's position; negative counts from the end.

        Returns:
          The Frame, numpy leaves of the canonical dtypes (float32 images, [4, 4] float32 c2w, int32 index).

        Raises:
          TypeError: ``index`` is not an int.
          IndexError: ``index`` is out of range.
          DatasetError: the images read do not have the size of ``intrinsics``.
        """
        if not isinstance(index, (int, np.integer)):
            raise TypeError(f"frame index must be an int, got {type(index).__name__}")
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for a sequence of {len(self)} frames")
        index = int(index) % len(self)
        color, depth = self._read_rgbd(index)
        expected = self.intrinsics.shape
        if depth.shape != expected or color.shape != (*expected, 3):
            raise DatasetError(f"{self.name} frame {index}: images {color.shape}/{depth.shape}, expected {expected}")
        return host_frame(color, depth, self._c2w[index], self._pose_valid[index], index)

