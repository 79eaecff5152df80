"""Named SLAM configurations: ``replica``, ``tum`` and ``scannet`` hold SplaTAM's per-dataset values
(method_spec A.11) and the paper's CB-KNN K0 (D.6); ``cpu`` is sized for 2 CPU cores.

A preset owns its resolution. Its pixel-sized settings (``mapping.overlap_margin``, and ``cbknn.params.alpha`` in
the "unit" shift mode, where it is px) are given for the image width in :data:`PRESET_WIDTH`;
``preset(name, width=w)`` scales them to ``w`` px, so the same preset means the same physical margins and shifts at
any resolution. The pruning bound on a Gaussian's size (``mapping.prune_scale_ratio``, a fraction of the scene
radius) follows the pixel footprint instead: a fresh Gaussian is one pixel wide (scale = depth / focal length), so
at half the width it is twice as large, and the bound doubles with it; otherwise a low-resolution map prunes its
own new Gaussians and thins out. The other thresholds are unitless (opacity, silhouette, depth error over its
median) or physical on purpose (step bounds in metres and degrees). The ``cpu`` preset also works at about
that width (``gsjax run`` reduces its input to ~80 px across, :func:`working_downscale`); the paper presets work
at the input's own resolution.
"""

from __future__ import annotations

import dataclasses

from gsjax.config.fields import rescale
from gsjax.config.names import PRESETS
from gsjax.raster import RasterSettings
from gsjax.raster.cbknn import CBKNN
from gsjax.slam.config import CBKNNConfig, CoarseToFine, ImageBlur, MappingConfig, SlamConfig, TrackingConfig

# The width (px) each preset's pixel-sized settings are given for: the cpu preset's working width, and the native
# width of the dataset each paper preset is for (Replica 1200x680, TUM and ScanNet 640x480).
PRESET_WIDTH = {"cpu": 80, "replica": 1200, "tum": 640, "scannet": 640}
REDUCES_INPUT = ("cpu",)  # presets that reduce the input to about their width


def working_downscale(name: str, width: int) -> int:
    """The integer reduction ``gsjax run`` applies to input ``width`` px wide under preset ``name`` (1 = native).

    Args:
      name: the preset's name (:data:`gsjax.config.names.PRESETS`).
      width: the input images' width (px).

    Returns:
      ``max(1, round(width / PRESET_WIDTH[name]))`` for a preset that reduces its input (``cpu``), else 1.

    Raises:
      ValueError: ``name`` is not a preset.
    """
    _check_name(name)
    return max(1, round(width / PRESET_WIDTH[name])) if name in REDUCES_INPUT else 1


def _check_name(name: str) -> None:
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r} ({', '.join(PRESETS)})")


def at_width(config: SlamConfig, width: int, preset_width: int) -> SlamConfig:
    """``config`` with the fields that follow the width scaled from ``preset_width`` to ``width`` px.

    Every traced field in px (``mapping.overlap_margin``, ``tracking.blur.sigma_px``, ``tracking.coarse.sigma_px``,
    ``cbknn.params.alpha`` when its shift mode makes it px) is scaled by ``width / preset_width``, and
    ``mapping.prune_scale_ratio`` by the pixel footprint (``preset_width / width``). Which fields those are is
    declared with each field (:class:`gsjax.config.fields.FieldSpec`); static ones in px (``tracking.blur.radius_px``,
    tile and cell sizes) are shapes and stay.

    Args:
      config: the config, its pixel-sized values given for ``preset_width``.
      width: the images' width (px) to scale to.
      preset_width: the width (px) the values of ``config`` are given for (:data:`PRESET_WIDTH`).

    Returns:
      The scaled config; the very same object when the two widths agree.
    """
    return rescale(config, width / preset_width)


def _cbknn_values(k0: float) -> CBKNNConfig:
    """The paper's CB-KNN values for a dataset (alpha 0.2 px, beta 0.3, its K0); the mode stays ``off`` until
    chosen (``gsjax run --cbknn``, :func:`with_cbknn_mode`)."""
    return CBKNNConfig(mode="off", params=CBKNN(alpha=0.2, k0=k0, beta=0.3))


def preset(name: str, width: int | None = None) -> SlamConfig:
    """A named preset's config for images of a given width.

    Args:
      name: ``replica``, ``tum``, ``scannet`` (SplaTAM / paper values) or ``cpu`` (2 CPU cores).
      width: the images' width (px); the fields that follow the width are scaled to it (:func:`at_width`).
        None: the preset's own width, :data:`PRESET_WIDTH`.

    Returns:
      The preset's config.

    Raises:
      ValueError: ``name`` is not a preset.
    """
    _check_name(name)
    config = _preset_values(name)
    return config if width is None else at_width(config, width, PRESET_WIDTH[name])


# SplaTAM's per-dataset values (method_spec A.11) and the paper's K0 (D.6). SplaTAM's rotation learning rates act on
# quaternions; phi moves about twice as fast (see TrackingConfig).
_PAPER = {
    "replica": dict(tracking_iters=40, lr_trans=2e-3, lr_rot=8e-4, mapping_iters=60, window_size=24, k0=5.0,
                    scene_radius_depth_ratio=3.0),
    "tum": dict(tracking_iters=200, lr_trans=2e-3, lr_rot=4e-3, mapping_iters=30, window_size=20, k0=8.0,
                scene_radius_depth_ratio=2.0),
    "scannet": dict(tracking_iters=100, lr_trans=5e-4, lr_rot=1e-3, mapping_iters=30, window_size=10, k0=8.0,
                    scene_radius_depth_ratio=3.0),
}


def _paper_preset(tracking_iters, lr_trans, lr_rot, mapping_iters, window_size, k0, scene_radius_depth_ratio):
    return SlamConfig(
        tracking=TrackingConfig(iters=tracking_iters, lr_trans=lr_trans, lr_rot=lr_rot),
        mapping=MappingConfig(iters=mapping_iters, window_size=window_size),
        cbknn=_cbknn_values(k0),
        scene_radius_depth_ratio=scene_radius_depth_ratio,
    )


def _preset_values(name: str) -> SlamConfig:
    if name in _PAPER:
        return _paper_preset(**_PAPER[name])
    # cpu: about 80x60 input (PRESET_WIDTH, working_downscale). Tracking compares D / S (young maps have S < 1, and
    # D = sum w z would pull the camera along its axis). The means keep SplaTAM's step (1e-4) after frame 0: a
    # larger one lets each frame's map update absorb that frame's tracking error, which then accumulates
    # (7-Scenes kitchen, 150 frames: 1e-3 -> 2.9 cm ATE, 3e-4 -> 2.5 cm, 1e-4 -> 2.0 cm; noisy synthetic,
    # 60 frames: 0.42 -> 0.34 cm). Frame 0's map takes 1e-3 to remove the blending depth bias of fresh
    # Gaussians, which at ~8x a full-resolution pixel is centimetres (Replica sample, 80x45: 2.2 cm ATE with
    # 1e-4 on frame 0 too, no better than a constant pose).
    # 64 contributor slots: at 80 px the contributors per pixel measured 30 mean, 48 p99, 56 max (noisy synthetic,
    # frame 16); 12 of the first 40 7-Scenes frames have pixels with more (largest residual transmittance 0.065,
    # reported per frame), while every slot costs compositing time whether used or not (profile_frame.py).
    # Strided tracking: 30 of tracking's 40 iterations run on every other pixel (an exact render of a quarter of
    # the pixels, about half the cost of a full iteration): step 1309 -> 951 ms at frame 16 of the noisy synthetic
    # room (experiments/README.md). Strided mapping (20 of 30) would take it to 751 ms and holds on the noisy room
    # and 7-Scenes, but moved the 4-frame Replica sample's ATE from 0.85 to 1.00 cm: mapping stays full.
    # (Tile lists of 256 and 2 pairs per Gaussian slot made binning 10 % cheaper, but cut the lists of 22 of 40
    # 7-Scenes frames, residual transmittance up to 0.69: the raster defaults stay.)
    # Contributor slots are chosen every 10th tracking iteration (tracking.reselect_every) and once per frame for each
    # mapping view (mapping.reselect_every 30 = the mapping iterations), and composited in between: step 936 -> 669
    # ms at frame 16 of the noisy synthetic room; over 3 seeds of 7-Scenes 40 / 150, the noisy room 60 and the
    # synthetic room 200 ATE moved by -0.07 to +0.008 cm and PSNR by -0.14 to -0.45 dB (issue 37's accuracy gate,
    # experiments/README.md). Fewer mapping pixels (strided mapping, 20 of 30 iterations) or mapping every other
    # frame cost 7-Scenes 1.2-1.3 dB of PSNR and were not adopted.
    # Colours are kept in [0, 1] (mapping.clamp_rgb): unbounded, a few Gaussians' colours ran far outside within
    # 40 frames and PSNR depended on whether they were in view (7-Scenes 40 frames, seeds 0 / 1: 31.3 / 32.9 dB
    # unbounded, 33.7 / 33.7 dB clamped; ATE 0.239 / 0.249 -> 0.249 / 0.257 cm, within the seeds' spread).
    return SlamConfig(
        tracking=TrackingConfig(iters=10, strided_iters=30, lr_trans=2e-3, lr_rot=2e-3, normalized_depth=True,
                                reselect_every=10),
        mapping=MappingConfig(iters=30, window_size=10, lr_means_first=1e-3, overlap_samples=800,
                              overlap_margin=2.5, clamp_rgb=True, reselect_every=30),
        cbknn=_cbknn_values(8.0),
        scene_radius_depth_ratio=2.0,
        raster=RasterSettings(max_contributors=64),
    )


def with_image_smoothing(config: SlamConfig, blur_px: float = 1.5, radius_px: int = 6) -> SlamConfig:
    """``config`` tracking on residuals blurred by a Gaussian filter (``tracking.blur``).

    Image-space smoothing, the textbook alternative to CB-KNN for a wider basin.

    Args:
      config: the config to change.
      blur_px: the filter's std (px at the config's working width), ``tracking.blur.sigma_px``.
      radius_px: where the filter is truncated (px), ``tracking.blur.radius_px`` (static: a shape).

    Returns:
      A copy of ``config`` with ``tracking.blur`` set to those values.

    Raises:
      ValueError: a value is out of its field's range, or the tracking config would run coarse to fine
        (``tracking.coarse.iters`` > 0) with ``radius_px`` 0.
    """
    tracking = dataclasses.replace(config.tracking, blur=ImageBlur(radius_px=radius_px, sigma_px=blur_px))
    return dataclasses.replace(config, tracking=tracking)


def with_coarse_to_fine(config: SlamConfig, iters: int = 20, levels: int = 2, sigma_px: float = 1.0,
                        radius_px: int = 6) -> SlamConfig:
    """``config`` tracking coarse to fine (``tracking.coarse``), the coarse iterations taken from the strided ones.

    The ``iters`` coarse iterations run first, each on every pixel; they replace as many strided iterations where
    there are that many, so a frame runs as many iterations as before (``tracking.strided_iters`` is lowered by
    ``iters``, not below 0).

    Args:
      config: the config to change (its tracking optimizer must be ``adam``).
      iters: the coarse iterations, ``tracking.coarse.iters``.
      levels: the blur levels they are split over, ``tracking.coarse.levels``.
      sigma_px: the finest level's blur std (px at the working width; doubling per coarser level),
        ``tracking.coarse.sigma_px``.
      radius_px: the least truncation radius (px) of the levels' filter: ``tracking.blur.radius_px`` becomes the
        larger of it and its current value.

    Returns:
      A copy of ``config`` with ``tracking.coarse``, ``tracking.blur.radius_px`` and ``tracking.strided_iters``
        changed.

    Raises:
      ValueError: a value is out of its field's range, or ``iters`` > 0 while the tracking optimizer is not ``adam``
        or the blur radius stays 0.
    """
    cfg = config.tracking
    tracking = dataclasses.replace(cfg, coarse=CoarseToFine(iters=iters, levels=levels, sigma_px=sigma_px),
                                   blur=dataclasses.replace(cfg.blur, radius_px=max(cfg.blur.radius_px, radius_px)),
                                   strided_iters=max(cfg.strided_iters - iters, 0))
    return dataclasses.replace(config, tracking=tracking)


def with_cbknn_mode(config: SlamConfig, mode: str) -> SlamConfig:
    """Switch CB-KNN's mode.

    Args:
      config: the config to change.
      mode: ``off``, ``code_parity`` or ``paper`` (:class:`CBKNNConfig`).

    Returns:
      A copy of ``config`` with ``cbknn.mode`` set.

    Raises:
      ValueError: ``mode`` is not a CB-KNN mode.
    """
    return dataclasses.replace(config, cbknn=dataclasses.replace(config.cbknn, mode=mode))
