"""Synthetic RGB-D sequences: the analytic room of :mod:`gsjax.data.scene`, ray cast along a handheld-like path.

Everything is exact and deterministic: depth is z along the optical axis (not ray length) of the nearest analytic
surface at each pixel centre, colour is the procedural texture (optionally anti-aliased), and the ground-truth
trajectory is a closed-form function of time. Optional sensor effects, all drawn from ``seed`` and the frame
number (so frames can be rendered in any order and still agree):

* depth noise: Gaussian with std ``depth_noise * z^2`` (Kinect-like growth with distance);
* depth holes: pixels at depth discontinuities (a 4-neighbour whose depth differs by more than
  ``hole_threshold * z``) are invalid, as structured-light sensors lose them;
* colour noise: additive Gaussian with std ``color_noise``, clipped to [0, 1];
* motion blur: the colour is the mean of ``motion_blur`` renders spread over ``shutter`` of the frame interval,
  centred on the frame time (depth and the GT pose are those of the centre time).

Defaults: 160x120 at 30 fps, 60 frames, a Kinect-like 62 degree horizontal field of view. On two CPU cores the
splatting renderer costs about 50 ns per pixel-candidate, so one tracking or mapping iteration at 160x120 takes
tens of milliseconds and a 60-frame SLAM demo runs in minutes; 320x240 would be four times slower. At
``speed=1`` the camera moves about 1 cm and 0.3-0.4 degrees per frame (TUM fr1/desk: 1.4 cm, 0.8 degrees).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.config.fields import check_fields, param
from gsjax.data import scene
from gsjax.data.sequence import Sequence

# Kinect: fx = 525 px at 640 px width, a 62 degree horizontal field of view.
_FOCAL_PER_WIDTH = 525.0 / 640.0


@dataclasses.dataclass(frozen=True)
class SyntheticConfig:
    """Settings of a synthetic sequence (see the module docstring for the defaults' rationale).

    Attributes:
      width: image width (px).
      height: image height (px).
      fx: focal length along x (px); None gives 525/640 * width (Kinect-like). Principal point at the image centre.
      fy: focal length along y (px); None gives 525/640 * width, like ``fx``.
      num_frames: number of frames.
      fps: frame rate (Hz); timestamps are frame / fps (s).
      speed: time-scale of the motion; frame i at speed s shows the pose of frame s * i at speed 1.
      seed: seeds the sensor noise (the scene and the trajectory do not depend on it).
      depth_noise: std of the depth noise at 1 m (m); it grows with z^2. 0 disables.
      depth_holes: invalidate pixels at depth discontinuities.
      hole_threshold: relative depth jump (fraction of z) that counts as a discontinuity.
      color_noise: std of additive colour noise (colour in [0, 1]). 0 disables.
      motion_blur: number of sub-frame renders averaged for the colour (1: no blur).
      shutter: exposure time as a fraction of the frame interval (for motion blur).
      supersample: colour samples per pixel along each axis (anti-aliasing); depth is always the pixel centre's.
    """

    width: int = param(160, "px", static=True, low=1)
    height: int = param(120, "px", static=True, low=1)
    fx: float | None = param(None, "px", low=0.0, low_open=True, scaling=None)
    fy: float | None = param(None, "px", low=0.0, low_open=True, scaling=None)
    num_frames: int = param(60, "frames", static=True, low=1)
    fps: float = param(30.0, "Hz", low=0.0, low_open=True)
    speed: float = param(1.0, "ratio", low=0.0)
    seed: int = param(0, "count", static=True)
    depth_noise: float = param(0.0, "m", low=0.0)
    depth_holes: bool = param(False, "flag", static=True)
    hole_threshold: float = param(0.05, "ratio", low=0.0)
    color_noise: float = param(0.0, "colour", low=0.0)
    motion_blur: int = param(1, "count", static=True, low=1)
    shutter: float = param(0.5, "ratio", low=0.0, high=1.0)
    supersample: int = param(2, "count", static=True, low=1)

    def __post_init__(self):
        check_fields(self, "synthetic")

    def with_sensor_noise(self) -> "SyntheticConfig":
        """This config with Kinect-like sensor effects.

        Returns:
          A copy with 1.5 mm depth noise at 1 m (6 mm at 2 m), holes at depth edges, colour noise of 1/100 and
            3-sample motion blur over the shutter (half the frame interval by default).
        """
        return dataclasses.replace(self, depth_noise=0.0015, depth_holes=True, color_noise=0.01, motion_blur=3)

    def intrinsics(self) -> Intrinsics:
        """The pinhole camera of the rendered frames.

        Returns:
          float32 intrinsics of ``width`` x ``height``, principal point at the image centre ((W - 1) / 2,
            (H - 1) / 2).
        """
        fx = self.fx if self.fx is not None else _FOCAL_PER_WIDTH * self.width
        fy = self.fy if self.fy is not None else _FOCAL_PER_WIDTH * self.width
        return make_intrinsics(fx, fy, (self.width - 1) / 2.0, (self.height - 1) / 2.0, self.height, self.width)


def camera_trajectory(times: np.ndarray) -> np.ndarray:
    """Camera-to-world poses [N, 4, 4] float64 at times [N] (s, at speed 1): a smooth handheld-like path.

    Position: a sum of sinusoids around (0, -0.7, 1.3) m (slow sweeps of 0.1-0.45 m plus 1-2 cm of faster
    shake), bounded for all t so the camera stays more than 0.5 m from every surface. Orientation: looking at a
    point that wanders over the far half of the room (so the view always faces into it), z up, with a slow
    roll of up to 3 degrees and a small fast shake.
    """
    t = np.asarray(times, np.float64)[:, None]

    def wave(amplitudes, frequencies, phases):  # sum of sinusoids (m or deg; Hz; rad) -> [N]
        return np.sum(np.asarray(amplitudes) * np.sin(2 * np.pi * np.asarray(frequencies) * t + phases), axis=-1)

    position = np.stack(
        [
            wave([0.45, 0.02], [0.14, 0.9], [0.3, 1.1]),
            -0.7 + wave([0.25, 0.015], [0.09, 1.3], [2.0, 0.4]),
            1.3 + wave([0.12, 0.01], [0.15, 1.7], [1.0, 2.2]),
        ],
        axis=-1,
    )
    target = np.stack(
        [
            wave([1.4, 0.03], [0.08, 1.1], [0.5, 0.2]),
            np.full(t.shape[0], 2.0),
            0.9 + wave([0.3, 0.03], [0.11, 1.4], [0.0, 1.7]),
        ],
        axis=-1,
    )
    roll = np.deg2rad(wave([3.0, 0.3], [0.2, 1.9], [0.7, 0.1]))
    forward = target - position
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(forward, right)
    cos, sin = np.cos(roll)[:, None], np.sin(roll)[:, None]
    right, down = cos * right + sin * down, cos * down - sin * right  # roll about the optical axis
    c2w = np.tile(np.eye(4), (t.shape[0], 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = right, down, forward, position
    return c2w


def render_view(c2w: np.ndarray, intrinsics: Intrinsics, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ray cast the scene from a camera-to-world pose [4, 4] -> (colour [H, W, 3] float32 in [0, 1], depth [H, W]
    float32 m along the optical axis, exact at pixel centres; the room is closed, so every pixel is valid)."""
    c2w = np.asarray(c2w, np.float64)
    fx, fy, cx, cy = (float(v) for v in (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy))
    height, width = intrinsics.shape

    def cast(offsets: np.ndarray):
        v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
        u = u[..., None] + offsets[:, 0]
        v = v[..., None] + offsets[:, 1]
        # Camera ray (x/z, y/z, 1): its parameter t is the depth z of the point it reaches.
        rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3) @ c2w[:3, :3].T
        t, material = scene.raycast(c2w[:3, 3], rays)
        return t, scene.shade(c2w[:3, 3] + t[:, None] * rays, material)

    depth, color = cast(np.zeros((1, 2)))
    if supersample > 1:
        grid = (np.arange(supersample) + 0.5) / supersample - 0.5
        offsets = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2)
        _, samples = cast(offsets)
        color = samples.reshape(height * width, len(offsets), 3).mean(axis=1)
    return color.reshape(height, width, 3).astype(np.float32), depth.reshape(height, width).astype(np.float32)


def depth_edges(depth: np.ndarray, threshold: float) -> np.ndarray:
    """[H, W] bool: pixels with a 4-neighbour whose depth differs by more than ``threshold * depth``."""
    jump = np.zeros(depth.shape, bool)
    dy = np.abs(np.diff(depth, axis=0)) > threshold * np.minimum(depth[1:], depth[:-1])
    dx = np.abs(np.diff(depth, axis=1)) > threshold * np.minimum(depth[:, 1:], depth[:, :-1])
    jump[1:] |= dy
    jump[:-1] |= dy
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    return jump


def render_frame(config: SyntheticConfig, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``frame`` of the sequence ``config`` describes, sensor effects included -> (colour, depth)."""
    intrinsics = config.intrinsics()
    time = config.speed * frame / config.fps
    color, depth = render_view(camera_trajectory(np.array([time]))[0], intrinsics, config.supersample)
    if config.motion_blur > 1:
        spread = config.speed * config.shutter / config.fps
        sub_times = time + spread * ((np.arange(config.motion_blur) + 0.5) / config.motion_blur - 0.5)
        color = np.mean(
            [render_view(pose, intrinsics, config.supersample)[0] for pose in camera_trajectory(sub_times)], axis=0
        )
    rng = np.random.default_rng([config.seed, frame])
    holes = depth_edges(depth, config.hole_threshold) if config.depth_holes else np.zeros(depth.shape, bool)
    if config.depth_noise > 0:
        depth = depth + rng.normal(size=depth.shape) * config.depth_noise * depth**2
    if config.color_noise > 0:
        color = np.clip(color + rng.normal(size=color.shape) * config.color_noise, 0.0, 1.0)
    depth = np.where(holes, 0.0, np.maximum(depth, 0.0))
    return color.astype(np.float32), depth.astype(np.float32)


def synthetic_sequence(config: SyntheticConfig = SyntheticConfig()) -> Sequence:
    """The synthetic room as a sequence whose frames are rendered on demand.

    Args:
      config: size, length, motion and sensor effects.

    Returns:
      A Sequence of ``config.num_frames`` frames at ``config.fps``, with exact ground-truth poses (all valid).
    """
    frames = np.arange(config.num_frames)
    return Sequence(
        name=f"synthetic-seed{config.seed}",
        intrinsics=config.intrinsics(),
        timestamps=frames / config.fps,
        c2w=camera_trajectory(config.speed * frames / config.fps),
        pose_valid=np.ones(config.num_frames, bool),
        read_rgbd=lambda i: render_frame(config, i),
    )
