"""Named SLAM configurations: ``replica``, ``tum`` and ``scannet`` hold SplaTAM's per-dataset values
(method_spec A.11) and the paper's CB-KNN K0 (D.6); ``cpu`` is sized for 2 CPU cores."""

from __future__ import annotations

import dataclasses

from gsjax.names import PRESETS
from gsjax.raster.cbknn import CBKNN
from gsjax.slam.config import CBKNNConfig, MappingConfig, SlamConfig, TrackingConfig


def _cbknn_values(k0: float) -> CBKNNConfig:
    """The paper's CB-KNN values for a dataset (alpha 0.2 px, beta 0.3, its K0); the mode stays ``off`` until
    chosen (``gsjax run --cbknn``, :func:`with_cbknn_mode`)."""
    return CBKNNConfig(mode="off", params=CBKNN(alpha=0.2, k0=k0, beta=0.3))


def preset(name: str) -> SlamConfig:
    """A named preset: ``replica``, ``tum``, ``scannet`` (SplaTAM / paper values) or ``cpu`` (2 CPU cores)."""
    # SplaTAM's rotation learning rates act on quaternions; phi moves about twice as fast (see TrackingConfig).
    if name == "replica":
        return SlamConfig(
            tracking=TrackingConfig(iters=40, lr_trans=2e-3, lr_rot=8e-4),
            mapping=MappingConfig(iters=60, window_size=24),
            cbknn=_cbknn_values(5.0),
            scene_radius_depth_ratio=3.0,
        )
    if name == "tum":
        return SlamConfig(
            tracking=TrackingConfig(iters=200, lr_trans=2e-3, lr_rot=4e-3),
            mapping=MappingConfig(iters=30, window_size=20),
            cbknn=_cbknn_values(8.0),
            scene_radius_depth_ratio=2.0,
        )
    if name == "scannet":
        return SlamConfig(
            tracking=TrackingConfig(iters=100, lr_trans=5e-4, lr_rot=1e-3),
            mapping=MappingConfig(iters=30, window_size=10),
            cbknn=_cbknn_values(8.0),
            scene_radius_depth_ratio=3.0,
        )
    if name == "cpu":
        # About 80x60 input (see the runner's downscale). Tracking compares D / S (young maps have S < 1, and
        # D = sum w z would pull the camera along its axis). The means keep SplaTAM's step (1e-4) after frame 0: a
        # larger one lets each frame's map update absorb that frame's tracking error, which then accumulates
        # (7-Scenes kitchen, 150 frames: 1e-3 -> 2.9 cm ATE, 3e-4 -> 2.5 cm, 1e-4 -> 2.0 cm; noisy synthetic,
        # 60 frames: 0.42 -> 0.34 cm). Frame 0's map takes 1e-3 to remove the blending depth bias of fresh
        # Gaussians, which at ~8x a full-resolution pixel is centimetres (Replica sample, 80x45: 2.2 cm ATE with
        # 1e-4 on frame 0 too, no better than a constant pose).
        return SlamConfig(
            tracking=TrackingConfig(iters=40, lr_trans=2e-3, lr_rot=2e-3, normalized_depth=True),
            mapping=MappingConfig(iters=30, window_size=10, lr_means_first=1e-3, overlap_samples=800,
                                  overlap_margin=2.5),
            cbknn=_cbknn_values(8.0),
            scene_radius_depth_ratio=2.0,
        )
    raise ValueError(f"unknown preset {name!r} ({', '.join(PRESETS)})")



def with_cbknn_mode(config: SlamConfig, mode: str) -> SlamConfig:
    """The config with CB-KNN switched to ``mode`` (``off``, ``code_parity``, ``paper``)."""
    return dataclasses.replace(config, cbknn=dataclasses.replace(config.cbknn, mode=mode))
