"""Where the viewer's keyframe images come from: the map rendered at a keyframe's pose (:class:`MapRenderer`), and
the keyframe's input colour image, read from a finished run's checkpoints (:class:`RunImages`) or kept from the
live state (:class:`LiveImages`)."""

from __future__ import annotations

import threading
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics, invert_transform
from gsjax.gaussians import Gaussians
from gsjax.io.images import to_uint8
from gsjax.raster import RasterSettings, render


class MapRenderer:
    """The canonical render of a map at camera-to-world poses, as uint8 images; thread-safe, one compiled program
    per map capacity."""

    def __init__(self, intrinsics: Intrinsics, settings: RasterSettings = RasterSettings()):
        self._render = jax.jit(lambda g, w2c: render(g, w2c, intrinsics, settings).color)
        self._gaussians: Gaussians | None = None
        self._lock = threading.Lock()

    def set_map(self, gaussians: Gaussians) -> None:
        with self._lock:
            self._gaussians = gaussians

    def render(self, c2w: np.ndarray) -> np.ndarray | None:
        """[H, W, 3] uint8 of the map seen from ``c2w`` [4, 4] (map frame), or None before a map is set."""
        with self._lock:
            gaussians = self._gaussians
        if gaussians is None:
            return None
        w2c = jnp.asarray(invert_transform(c2w), jnp.float32)
        return to_uint8(np.asarray(self._render(gaussians, w2c)))


class RunImages:
    """A finished run's keyframe images: inputs from ``checkpoints/keyframes/SLOT.npz`` (slot k = the k-th
    keyframe; None when the run kept no checkpoints, e.g. a sweep's rows), renders of its ``map.ply``."""

    def __init__(self, run_dir: Path, c2w: np.ndarray, keyframes: np.ndarray, renderer: MapRenderer):
        self._directory = Path(run_dir) / "checkpoints" / "keyframes"
        self._c2w, self._renderer = c2w, renderer
        self._slot = {int(frame): slot for slot, frame in enumerate(keyframes)}

    def input_image(self, frame: int) -> np.ndarray | None:
        if frame not in self._slot or not (path := self._directory / f"{self._slot[frame]:05d}.npz").is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                return to_uint8(data["color"])
        except (OSError, ValueError, KeyError):  # a damaged file: the viewer shows that the input is missing
            return None

    def render_image(self, frame: int) -> np.ndarray | None:
        return self._renderer.render(self._c2w[frame]) if frame < len(self._c2w) else None


class LiveImages:
    """A running SLAM's keyframe images: inputs copied from the state as keyframes are stored, renders of the
    newest map at the newest poses."""

    def __init__(self, renderer: MapRenderer):
        self._renderer = renderer
        self._inputs: dict[int, np.ndarray] = {}
        self._c2w = np.zeros((0, 4, 4))
        self._lock = threading.Lock()

    def update(self, c2w: np.ndarray, inputs: dict[int, np.ndarray]) -> None:
        """The poses so far [T, 4, 4] (map frame) and the keyframe input images new since the last update."""
        with self._lock:
            self._c2w = c2w
            self._inputs.update(inputs)

    def known(self) -> set[int]:
        with self._lock:
            return set(self._inputs)

    def input_image(self, frame: int) -> np.ndarray | None:
        with self._lock:
            return self._inputs.get(frame)

    def render_image(self, frame: int) -> np.ndarray | None:
        with self._lock:
            c2w = self._c2w
        return self._renderer.render(c2w[frame]) if frame < len(c2w) else None
