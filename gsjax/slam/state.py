"""The SLAM state carried through ``lax.scan`` over frames: the map, recent poses, keyframes, RNG, counters."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gsjax.gaussians import Gaussians

DEPTH_UNIT_M = 1e-3  # stored keyframe depth unit: millimetres (the raw unit of 7-Scenes, ScanNet, most sensors)
_DEPTH_MAX = 65535


def encode_color(color: jax.Array) -> jax.Array:
    """Colour in [0, 1] (float) -> uint8 (clipped, rounded; exact for images read from 8-bit files).

    Args:
      color: float colour in [0, 1], any shape (NaN reads as 0).

    Returns:
      uint8 ``round(255 color)`` of the same shape, clipped to [0, 255].
    """
    return jnp.round(jnp.clip(jnp.nan_to_num(color), 0.0, 1.0) * 255.0).astype(jnp.uint8)


def decode_color(color: jax.Array) -> jax.Array:
    """uint8 colour (:func:`encode_color`) -> float32 in [0, 1].

    Args:
      color: uint8 colour, any shape.

    Returns:
      float32 ``color / 255`` of the same shape.
    """
    return color.astype(jnp.float32) / 255.0


def encode_depth(depth: jax.Array) -> jax.Array:
    """Depth (m, float; 0 or non-finite = invalid) -> uint16 millimetres (0 = invalid; clipped at 65.535 m).

    Args:
      depth: float depth (m), any shape; 0, NaN and +inf mark invalid pixels.

    Returns:
      uint16 depth in mm (rounded) of the same shape; 0 where invalid, negative or below 0.5 mm, 65535 at
        65.535 m or more.
    """
    return jnp.round(jnp.clip(jnp.nan_to_num(depth / DEPTH_UNIT_M, posinf=0.0), 0, _DEPTH_MAX)).astype(jnp.uint16)


def decode_depth(depth: jax.Array) -> jax.Array:
    """uint16 millimetres (:func:`encode_depth`) -> float32 metres.

    Args:
      depth: uint16 depth in mm, any shape (0 = invalid).

    Returns:
      float32 depth (m) of the same shape; 0 stays 0 (invalid).
    """
    return depth.astype(jnp.float32) * DEPTH_UNIT_M


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class KeyframeBuffer:
    """Fixed-capacity keyframe store (method_spec A.10), filled in order.

    The images are stored compactly (5 bytes per pixel instead of 16, so a long full-resolution run's keyframes
    fit on a GPU): read them with :meth:`color_at` / :meth:`depth_at`.

    Attributes:
      color: [F, H, W, 3] uint8 colours (:func:`encode_color`).
      depth: [F, H, W] uint16 depths in mm (:func:`encode_depth`, 0 = invalid).
      w2c: [F, 4, 4] float32 estimated world-to-camera pose at insertion (fixed after tracking, so mapping
        re-renders it).
      frame: [F] int32 frame index (-1 in an empty slot).
      gamma: [F] float32 motion gamma used at that frame's tracking (CB-KNN).
      count: [] int32 keyframes stored (slots >= count are empty).
    """

    color: jax.Array
    depth: jax.Array
    w2c: jax.Array
    frame: jax.Array
    gamma: jax.Array
    count: jax.Array

    @property
    def capacity(self) -> int:
        """F, the number of keyframe slots (static)."""
        return self.frame.shape[-1]

    @staticmethod
    def empty(capacity: int, height: int, width: int) -> "KeyframeBuffer":
        """A buffer with every slot empty.

        Args:
          capacity: F, the number of keyframe slots.
          height: image height H (px).
          width: image width W (px).

        Returns:
          The buffer: zero images, identity poses, frame -1, count 0.
        """
        return KeyframeBuffer(
            color=jnp.zeros((capacity, height, width, 3), jnp.uint8),
            depth=jnp.zeros((capacity, height, width), jnp.uint16),
            w2c=jnp.broadcast_to(jnp.eye(4, dtype=jnp.float32), (capacity, 4, 4)),
            frame=jnp.full((capacity,), -1, jnp.int32),
            gamma=jnp.zeros((capacity,), jnp.float32),
            count=jnp.int32(0),
        )

    def color_at(self, slot: int | jax.Array) -> jax.Array:
        """The colour of keyframes, decoded.

        Args:
          slot: a slot index, or an int array [...] of them.

        Returns:
          [..., H, W, 3] float32 colour in [0, 1].
        """
        return decode_color(self.color[slot])

    def depth_at(self, slot: int | jax.Array) -> jax.Array:
        """The depth of keyframes, decoded.

        Args:
          slot: a slot index, or an int array [...] of them.

        Returns:
          [..., H, W] float32 depth (m, to the mm; 0 = invalid).
        """
        return decode_depth(self.depth[slot])

    def push(self, color: jax.Array, depth: jax.Array, w2c: jax.Array, frame: int | jax.Array,
             gamma: float | jax.Array, enabled: jax.Array) -> "KeyframeBuffer":
        """Append a keyframe when ``enabled``; a full buffer keeps its content (the shell sizes it for the whole
        sequence, so this does not happen in a run). One slot is written (an in-place update of the scan's carry),
        never the whole buffer.

        Args:
          color: [H, W, 3] float colour in [0, 1] (stored as uint8).
          depth: [H, W] float depth (m; 0 or non-finite = invalid), stored as uint16 mm, clipped at 65.535 m.
          w2c: [4, 4] estimated world-to-camera pose.
          frame: the frame index.
          gamma: the motion gamma used at that frame's tracking.
          enabled: [] bool (traced), whether to append.

        Returns:
          The buffer with the keyframe in slot ``count`` and ``count`` raised by one, or unchanged.
        """
        enabled = enabled & (self.count < self.capacity)
        slot = jnp.minimum(self.count, self.capacity - 1)

        def put(buffer, value):
            value = jnp.where(enabled, jnp.asarray(value).astype(buffer.dtype), buffer[slot])
            return jax.lax.dynamic_update_index_in_dim(buffer, value, slot, axis=0)

        return KeyframeBuffer(
            color=put(self.color, encode_color(color)),
            depth=put(self.depth, encode_depth(depth)),
            w2c=put(self.w2c, w2c),
            frame=put(self.frame, frame),
            gamma=put(self.gamma, gamma),
            count=self.count + enabled.astype(jnp.int32),
        )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SlamState:
    """Everything one SLAM step needs from the previous ones.

    Attributes:
      gaussians: the map (fixed capacity, ``active`` mask).
      w2c_prev1: [4, 4] float32 estimated world-to-camera pose of frame t-1 (identity before frame 1).
      w2c_prev2: [4, 4] float32 estimated world-to-camera pose of frame t-2 (identity before frame 2).
      keyframes: the keyframe buffer.
      key: PRNG key for mapping-window and pixel sampling.
      frame: [] int32 index t of the next frame to process.
      num_frames: [] int32 length of the sequence (decides the second-to-last keyframe).
      scene_radius: [] float32 (m), set at frame 0 from its depth.
      nonfinite_tracking: [] int32 tracking iterations whose loss or gradient was not finite (skipped).
      nonfinite_mapping: [] int32 mapping iterations whose loss or gradient was not finite (skipped).
      dropped_gaussians: [] int32 new Gaussians that found no free slot (the shell grows capacity to avoid it).
      nonfinite_gaussians: [] int32 Gaussians freed because a parameter was not finite.
      previous_tracking_loss: [] float32 the last tracked frame's tracking loss (0 before; the divergence test's
        reference).
      retried_frames: [] int32 frames whose tracking diverged and was retried.
      diverged_frames: [] int32 frames whose tracking diverged and fell back to the constant-velocity prediction.
    """

    gaussians: Gaussians
    w2c_prev1: jax.Array
    w2c_prev2: jax.Array
    keyframes: KeyframeBuffer
    key: jax.Array
    frame: jax.Array
    num_frames: jax.Array
    scene_radius: jax.Array
    nonfinite_tracking: jax.Array
    nonfinite_mapping: jax.Array
    dropped_gaussians: jax.Array
    nonfinite_gaussians: jax.Array
    previous_tracking_loss: jax.Array
    retried_frames: jax.Array
    diverged_frames: jax.Array


def initial_state(
    capacity: int, height: int, width: int, keyframe_capacity: int, num_frames: int, seed: int
) -> SlamState:
    """An empty map and no history, ready for frame 0.

    Args:
      capacity: N, the map's slots (Gaussians).
      height: image height H (px).
      width: image width W (px).
      keyframe_capacity: F, keyframe slots (:func:`keyframe_capacity_for`).
      num_frames: the sequence's length (decides the second-to-last keyframe).
      seed: PRNG seed (mapping-window and pixel sampling).

    Returns:
      The state: poses the identity, counters 0, scene radius 1 m until frame 0 sets it.
    """
    eye = jnp.eye(4, dtype=jnp.float32)
    return SlamState(
        gaussians=Gaussians.empty(capacity),
        w2c_prev1=eye,
        w2c_prev2=eye,
        keyframes=KeyframeBuffer.empty(keyframe_capacity, height, width),
        key=jax.random.PRNGKey(seed),
        frame=jnp.int32(0),
        num_frames=jnp.int32(num_frames),
        scene_radius=jnp.float32(1.0),
        nonfinite_tracking=jnp.int32(0),
        nonfinite_mapping=jnp.int32(0),
        dropped_gaussians=jnp.int32(0),
        nonfinite_gaussians=jnp.int32(0),
        previous_tracking_loss=jnp.float32(0.0),
        retried_frames=jnp.int32(0),
        diverged_frames=jnp.int32(0),
    )


def grow_capacity(state: SlamState, capacity: int) -> SlamState:
    """The same state with the map's capacity raised to ``capacity`` (new slots free).

    Args:
      state: the state.
      capacity: the new number of Gaussian slots N, at least the current one.

    Returns:
      The state with a map of ``capacity`` slots, the existing ones first and unchanged; the rest of the state
        unchanged.

    Raises:
      ValueError: ``capacity`` is smaller than the current capacity.
    """
    return dataclasses.replace(state, gaussians=state.gaussians.grow(capacity))


def keyframe_capacity_for(num_frames: int, every: int) -> int:
    """The keyframe slots of a sequence: at least the keyframes it can produce (frame 0, every ``every``-th and the
    second-to-last: ``num_frames // every + 2``), rounded up to a power of two (at least 8).

    The slots are a shape of the compiled SLAM program; rounded, sequences of similar lengths (a run and the
    landscape of one of its frames, ``--max-frames`` 20 and 30) share one program. Empty slots are never chosen for a
    window, and the window's random order is drawn per slot, so the slots beyond the keyframes change nothing.

    Args:
      num_frames: the sequence's length.
      every: ``SlamConfig.keyframe_every``.

    Returns:
      The capacity, a power of two >= 8 and >= ``num_frames // every + 2``.
    """
    needed = num_frames // every + 2
    return max(8, 1 << (needed - 1).bit_length())
