"""The ``Frame`` pytree: one RGB-D observation, the unit that ``lax.scan`` steps over.

Frames of one sequence all have the same shapes and dtypes, so they stack along a leading axis (see
:func:`stack_frames`). The ground-truth pose is therefore always present: frames without one carry the identity
and ``pose_valid = False``. Timestamps need float64, which jax lacks without x64, so they stay on the host
(``Sequence.timestamps``) and the frame carries its position ``index`` in the sequence instead.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Frame:
    """One RGB-D frame (or, stacked, a chunk of T frames with a leading axis on every field).

    Numpy arrays on the host (as the readers build it, :func:`host_frame`), jax arrays on the device
    (:func:`to_device`).

    Attributes:
      color: [H, W, 3] float32 RGB in [0, 1].
      depth: [H, W] float32 metres along the optical axis; 0 marks an invalid pixel.
      c2w: [4, 4] float32 ground-truth camera-to-world pose (m); the identity when ``pose_valid`` is False.
      pose_valid: [] bool, whether ``c2w`` is a real ground-truth pose.
      index: [] int32, position of the frame in its ``Sequence`` (its timestamp is ``sequence.timestamps[index]``).
    """

    color: jax.Array
    depth: jax.Array
    c2w: jax.Array
    pose_valid: jax.Array
    index: jax.Array

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the images."""
        height, width = self.depth.shape[-2:]
        return height, width


def host_frame(color: np.ndarray, depth: np.ndarray, c2w: np.ndarray, pose_valid: bool, index: int) -> Frame:
    """A Frame of numpy arrays with the canonical dtypes (the host-side form readers build before stacking)."""
    return Frame(
        color=np.asarray(color, np.float32),
        depth=np.asarray(depth, np.float32),
        c2w=np.asarray(c2w, np.float32) if pose_valid else np.eye(4, dtype=np.float32),
        pose_valid=np.asarray(bool(pose_valid)),
        index=np.asarray(index, np.int32),
    )


def stack_frames(frames: list[Frame]) -> Frame:
    """Stack frames of equal shapes into one Frame with a leading axis (numpy in, numpy out).

    Args:
      frames: T >= 1 host frames (numpy leaves) of equal shapes.

    Returns:
      A Frame whose every leaf has a leading axis of T (color [T, H, W, 3], ..., index [T]), numpy arrays.

    Raises:
      ValueError: ``frames`` is empty.
    """
    if not frames:
        raise ValueError("stack_frames needs at least one frame")
    return jax.tree.map(lambda *leaves: np.stack(leaves), *frames)


def without_ground_truth(frame: Frame) -> Frame:
    """The same Frame with the ground-truth pose blanked (identity, ``pose_valid`` False): what the SLAM core gets,
    so its result cannot depend on whether a dataset has ground truth."""
    eye = np.broadcast_to(np.eye(4, dtype=np.float32), np.shape(frame.c2w))
    return dataclasses.replace(frame, c2w=eye, pose_valid=np.zeros(np.shape(frame.pose_valid), bool))


def to_device(frame: Frame) -> Frame:
    """The same Frame with every leaf a jax array (one transfer per leaf)."""
    return jax.tree.map(jnp.asarray, frame)
