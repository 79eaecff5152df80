"""``gsjax run --viewer``: the viewer fed from the running SLAM, updated between scan chunks."""

from __future__ import annotations

import time

import jax
import numpy as np

from gsjax.camera import invert_transform
from gsjax.data.sequence import Sequence
from gsjax.eval.run_metrics import RunMetrics
from gsjax.eval.trajectory import ate_so_far, ground_truth_on_estimate
from gsjax.io.images import to_uint8
from gsjax.slam.config import SlamConfig
from gsjax.slam.state import SlamState
from gsjax.viewer.scene import Camera, MapSnapshot, MapViewer, TrajectorySnapshot
from gsjax.viewer.sources import LiveImages, MapRenderer


class LiveViewer:
    """A :class:`MapViewer` of a run in progress; :meth:`update` after each chunk (it copies what it shows to the
    host, so the SLAM loop may go on at once). ``seconds`` is the time the updates took (the run's cost).

    While the run goes on the map is shown as points: viser's splats keep a depth sort running in the browser (more
    than a core of a 2-core machine): a browser sharing the run's two cores slowed it by 12-13 % with splats, 3-7 %
    with points (``experiments/bench_viewer.py``). :meth:`finished` shows the splats, unless a user chose in the
    GUI.
    """

    def __init__(self, sequence: Sequence, config: SlamConfig, host: str = "127.0.0.1", port: int = 8080,
                 title: str | None = None):
        k = sequence.intrinsics
        self._renderer = MapRenderer(k, config.raster)
        self._images = LiveImages(self._renderer)
        self.viewer = MapViewer(Camera(float(k.fx), float(k.fy), float(k.cx), float(k.cy), k.width, k.height),
                                self._images, title=title or f"gsjax run: {sequence.name}", host=host, port=port,
                                map_as="points")
        _, self._gt_c2w, self._gt_valid = sequence.gt_trajectory()
        self._title = title or sequence.name
        self.seconds = 0.0

    @property
    def url(self) -> str:
        return self.viewer.url

    def update(self, state: SlamState, outputs: dict) -> None:
        """Show the map, the poses and the keyframes of ``state`` and the per-frame ``outputs`` so far."""
        t0 = time.perf_counter()
        gaussians = jax.tree_util.tree_map(np.array, jax.device_get(state.gaussians))  # host copies
        self._renderer.set_map(gaussians)
        c2w = invert_transform(outputs.w2c)
        count = int(state.keyframes.count)
        keyframes = np.asarray(state.keyframes.frame)[:count].astype(int)
        known = self._images.known()
        inputs = {int(frame): to_uint8(np.asarray(state.keyframes.color[slot]))
                  for slot, frame in enumerate(keyframes) if int(frame) not in known}
        self._images.update(c2w, inputs)
        n = len(c2w)
        aligned = ground_truth_on_estimate(c2w, self._gt_c2w[:n], self._gt_valid[:n])
        gt_frames, gt_c2w = aligned if aligned is not None else (None, None)
        ate_m = ate_so_far(c2w, self._gt_c2w, self._gt_valid)
        snapshot = MapSnapshot.of(gaussians)
        self.viewer.set_map(snapshot)
        self.viewer.set_trajectory(TrajectorySnapshot(c2w, gt_frames, gt_c2w, keyframes))
        ate = f", ATE so far {100 * ate_m:.2f} cm" if ate_m is not None else ""
        self.viewer.set_summary(f"**{self._title}** (running)  \nframe {len(c2w)} of {len(self._gt_valid)}: "
                                f"{len(snapshot.centers)} Gaussians, {count} keyframes{ate}")
        self.seconds += time.perf_counter() - t0

    def finished(self, metrics: RunMetrics) -> None:
        """Say that the run is over, with its final figures."""
        from gsjax.viewer import summary_markdown

        self.viewer.set_summary(summary_markdown(self._title, metrics))
        self.viewer.suggest_map_as("splats")

    def stop(self) -> None:
        self.viewer.stop()
