"""The browser viewer (``gsjax view RUN_DIR``, ``gsjax run --viewer``), built on viser: the Gaussian map as
splats, the estimated and ground-truth trajectories with camera frustums, the input and rendered images of the
selected keyframe, and a frame slider.

* :mod:`gsjax.viewer.scene`: the viser scene and GUI (:class:`MapViewer`).
* :mod:`gsjax.viewer.sources`: the keyframe images (renders of the map, stored inputs).
* :mod:`gsjax.viewer.live`: the viewer fed from a running SLAM (:class:`LiveViewer`).
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import numpy as np

from gsjax.eval.run_metrics import RunMetrics
from gsjax.viewer.scene import Camera, MapSnapshot, MapViewer, TrajectorySnapshot

__all__ = ["MapViewer", "open_run", "summary_markdown", "wait_for_stop"]


def summary_markdown(title: str, metrics: RunMetrics) -> str:
    """The viewer's summary of a finished run (from its ``metrics.json``)."""
    lines = [f"**{title}**"]
    if metrics.ate_cm is not None:
        lines.append(f"ATE RMSE {metrics.ate_cm:.2f} cm")
    render = metrics.render.mean
    if render:
        lines.append(f"PSNR {render['psnr_db']:.2f} dB, depth L1 {render['depth_l1_cm']:.2f} cm")
    lines.append(f"{metrics.frames} frames, {metrics.num_gaussians} Gaussians, {metrics.keyframes} keyframes")
    return "  \n".join(lines)


def open_run(run_dir: str | Path, host: str = "127.0.0.1", port: int = 8080) -> MapViewer:
    """Serve the finished run in ``run_dir`` (its ``map.ply``, trajectories, keyframes) and return the viewer.

    Raises :class:`gsjax.report.RunRecordError` (a ValueError) naming the directory or file that cannot be used.
    """
    from gsjax.camera import make_intrinsics
    from gsjax.config.text import config_from_dict
    from gsjax.io.ply import read_ply
    from gsjax.io.run_folder import RunRecordError, read_run
    from gsjax.raster import RasterSettings
    from gsjax.viewer.sources import MapRenderer, RunImages

    run = read_run(run_dir)
    ply = run.path / "map.ply"
    if not ply.is_file():
        raise RunRecordError(f"{run.path} has no map.ply: not a finished gsjax run")
    try:
        gaussians = read_ply(ply)
    except ValueError as error:
        raise RunRecordError(str(error)) from None
    camera = run.metrics.camera or (run.record.camera if run.record else None)
    if not camera:
        raise RunRecordError(f"{run.path / 'metrics.json'}: no 'camera' (the run predates the viewer)")
    intrinsics = make_intrinsics(camera["fx"], camera["fy"], camera["cx"], camera["cy"], camera["height"],
                                 camera["width"])
    try:
        settings = config_from_dict(run.record.config if run.record else None).raster
    except (KeyError, TypeError, ValueError, AttributeError):  # an older or edited config: the default rasterizer
        settings = RasterSettings()
    renderer = MapRenderer(intrinsics, settings)
    renderer.set_map(gaussians)
    c2w = run.map_c2w()
    keyframes = np.asarray(run.metrics.keyframe_frames, int)
    viewer = MapViewer(Camera(camera["fx"], camera["fy"], camera["cx"], camera["cy"], camera["width"],
                              camera["height"]), RunImages(run.path, c2w, keyframes, renderer),
                       title=f"gsjax: {run.name}", host=host, port=port)
    viewer.set_summary(summary_markdown(f"gsjax run {run.name}", run.metrics))
    viewer.set_map(MapSnapshot.of(gaussians))
    aligned = run.ground_truth_in_map()
    gt_frames, gt_c2w = aligned if aligned is not None else (None, None)
    viewer.set_trajectory(TrajectorySnapshot(c2w, gt_frames, gt_c2w, keyframes))
    return viewer


def wait_for_stop(poll_s: float = 0.2) -> str:
    """Block until SIGINT or SIGTERM arrives and return its name (call from the main thread). The previous handlers
    are restored, so a second Ctrl-C while the caller cleans up behaves as usual."""
    received: list[str] = []
    stop = threading.Event()

    def handler(signum, _frame):
        received.append(signal.Signals(signum).name)
        stop.set()

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not stop.wait(poll_s):
            pass
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    return received[0]
