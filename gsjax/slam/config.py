"""SLAM configuration: frozen dataclass pytrees, validated when built.

Hyperparameters that users sweep (learning rates, loss weights, thresholds, CB-KNN alpha/K0/beta, the iteration
counts, CB-KNN's mode and where it acts) are *traced* leaves, so ``jax.vmap`` over a batch of configs runs one
compiled program; an iteration count runs within a static cap (``SlamConfig.caps``, :mod:`gsjax.slam.loops`). Shapes
(window size, contributor slots, tiles, a filter's radius), the optimizer and a few flags are *static*. The named
presets are in :mod:`gsjax.slam.presets`; overrides by dotted field name and the JSON round trip in
:mod:`gsjax.config.text`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.config.fields import check_fields, choice_is, derived, is_checkable, param, register_config
from gsjax.config.names import CBKNN_MODES
from gsjax.raster import RasterSettings
from gsjax.raster.cbknn import CBKNN
from gsjax.slam.loops import LoopCaps
from gsjax.slam.tracking_config import (
    BEST_POSE,
    TRACKING_OPTIMIZERS,
    CoarseToFine,
    DivergenceGuard,
    EarlyStop,
    Exposure,
    ImageBlur,
    TrackingConfig,
)

SLAM_MAX_CONTRIBUTORS = 96


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class MappingConfig:
    """Map optimisation over a keyframe window (method_spec A.8, A.9).

    Attributes:
      iters: iterations per frame (a fresh Adam each frame, eps 1e-15).
      strided_iters: 0 (SplaTAM) maps on every pixel only; S > 0 first runs S iterations on a quarter of the
        pixels (every other one of each row and column, the four such grids in turn; the render there is the full
        render's, see ``tracking.strided_iters``), then the ``iters`` on every pixel, one Adam over all.
      window_size: views per window: overlapping keyframes + the last keyframe + the current frame.
      lr_means: Adam step size of the means (m).
      lr_rgb: Adam step size of the colours.
      lr_opacity: Adam step size of the logit opacities.
      lr_scale: Adam step size of the log scales.
      lr_means_first: the means' step size when mapping frame 0 (SplaTAM: the same as ``lr_means``). Fresh
        Gaussians render a depth biased towards the camera on slanted surfaces (nearer neighbours come first in
        the blend) by up to a fraction of a pixel footprint; at low resolution that is centimetres, and the first
        map needs a larger step to remove it before the second frame tracks against it.
      lambda_color: loss weight of the colour term.
      lambda_depth: loss weight of the depth term.
      ssim_weight: mixes 1 - SSIM into the colour term.
      prune_opacity: prune Gaussians with opacity below this.
      prune_scale_ratio: prune Gaussians with a scale above this fraction of the scene radius (given at the
        preset's width: it follows the pixel footprint, see :mod:`gsjax.slam.presets`).
      prune_iters: the mapping iterations at which pruning runs (counted from the first, strided or not).
      clamp_rgb: (traced bool) project the colours back into [0, 1] after every mapping step. SplaTAM leaves them
        unbounded (False: its behaviour): with Adam's eps 1e-15 a Gaussian with a near-zero colour gradient takes
        full-size steps and can leave [0, 1] far, and renders then depend on whether it is in view.
      skip_step_at_prune: reproduce SplaTAM's quirk of skipping the Adam step at pruning iterations.
      overlap_samples: depth pixels sampled to measure keyframe overlap.
      overlap_margin: the border a projected sample must clear to count as inside a keyframe.
      every: 1 (SplaTAM) maps every frame; E > 1 maps only frames t with t % E == 0, keyframes and the first frame
        with depth (the others are tracked and densified, their new Gaussians optimised by the next mapping).
      reselect_every: 1 (SplaTAM) chooses every pixel's contributors at each iteration, on the map as it is then;
        R > 1 chooses them for every view of the window at iterations 0, R, 2R, ... (counted over strided and full
        iterations) and composites those slots in between, as the map changes (render and gradient exact for those
        slots; a Gaussian that would newly enter a pixel's first K in between does not).
    """

    iters: int = param(30, "iterations", low=1)
    strided_iters: int = param(0, "iterations", low=0)
    window_size: int = param(24, "views", static=True, low=2)
    lr_means: float = param(1e-4, "m", low=0.0)
    lr_means_first: float = param(1e-4, "m", low=0.0)
    lr_rgb: float = param(2.5e-3, "colour", low=0.0)
    lr_opacity: float = param(5e-2, "logit", low=0.0)
    lr_scale: float = param(1e-3, "log m", low=0.0)
    lambda_color: float = param(0.5, "weight", low=0.0)
    lambda_depth: float = param(1.0, "weight", low=0.0)
    ssim_weight: float = param(0.2, "weight", low=0.0, high=1.0)
    prune_opacity: float = param(0.005, "opacity", low=0.0)
    prune_scale_ratio: float = param(0.1, "ratio", low=0.0, scaling="footprint")
    prune_iters: tuple = param((0, 20), "iterations", static=True, low=0)
    skip_step_at_prune: bool = param(False, "flag", static=True)
    clamp_rgb: bool = param(False, "flag")
    overlap_samples: int = param(1600, "count", static=True, low=1)
    overlap_margin: float = param(20.0, "px", low=0.0)
    reselect_every: int = param(1, "iterations", low=1)
    every: int = param(1, "frames", low=1)

    def __post_init__(self):
        check_fields(self, "mapping")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DensifyConfig:
    """Densification (method_spec A.7): new Gaussians where the silhouette is low or the map lies behind.

    Attributes:
      sil_threshold: add where the rendered silhouette is below this.
      depth_error_factor: or where rendered depth lies behind the observation by more than this times the median
        depth error.
      init_opacity: opacity of new Gaussians (SplaTAM: 0.5).
    """

    sil_threshold: float = param(0.5, "ratio", low=0.0, high=1.0)
    depth_error_factor: float = param(50.0, "ratio", low=0.0)
    init_opacity: float = param(0.5, "opacity", low=0.0, low_open=True, high=1.0, high_open=True)

    def __post_init__(self):
        check_fields(self, "densify")


@register_config
@dataclasses.dataclass(frozen=True)
class CBKNNConfig:
    """Where CB-KNN acts (method_spec D.6) and its parameters.

    Attributes:
      mode: ``"off"`` (SplaTAM), ``"code_parity"`` (only the released code's 3D KNN smoothing of the overlap
        samples) or ``"paper"`` (per-pixel smoothing of keyframe renders).
      params: the per-pixel smoothing (:class:`gsjax.raster.cbknn.CBKNN`: alpha, k0, beta, ... ).
      track_keyframes: in ``paper`` mode, smooth the tracking renders of keyframes.
      map_keyframes: in ``paper`` mode, smooth the mapping renders of keyframes.
      densify: in ``paper`` mode, smooth the densification render of keyframes.
      lambda_color_keyframe: tracking colour weight on smoothed keyframes (paper: 0.6).
      kf_overlap_smoothing: smooth the overlap samples (on in ``code_parity``).
      smoothing_base_k: the overlap smoothing's density is measured over this many nearest neighbours (self included).
      smoothing_min_k: the fewest neighbours K a point is smoothed over (at the lowest density).
      smoothing_max_k: the most neighbours K a point is smoothed over (at the highest density).
      smoothing_dropout: the fraction of the K neighbours left out at random (a point becomes the mean of
        ``max(1, floor(K (1 - dropout)))`` of them).
    """

    mode: str = param("off", "choice", choices=CBKNN_MODES)
    params: CBKNN = CBKNN()
    track_keyframes: bool = param(True, "flag")
    map_keyframes: bool = param(True, "flag")
    densify: bool = param(True, "flag")
    lambda_color_keyframe: float = param(0.6, "weight", low=0.0)
    kf_overlap_smoothing: bool = param(False, "flag")
    smoothing_base_k: int = param(6, "count", static=True, low=1)
    smoothing_min_k: int = param(2, "count", static=True, low=1)
    smoothing_max_k: int = param(16, "count", static=True, low=1)
    smoothing_dropout: float = param(0.4, "ratio", static=True, low=0.0, high=1.0, high_open=True)

    def __post_init__(self):
        check_fields(self, "cbknn")
        if self.smoothing_min_k > self.smoothing_max_k:
            raise ValueError("cbknn.smoothing_min_k must not exceed cbknn.smoothing_max_k")

    @property
    def smooth_renders(self) -> bool | jax.Array:
        """Whether keyframe renders are smoothed per pixel (``paper`` mode): a bool, or a [] bool array when the mode is
        traced."""
        return choice_is(self.mode, "paper", CBKNN_MODES)

    @property
    def smooth_overlap(self) -> bool | jax.Array:
        """Whether the overlap samples are smoothed (``code_parity``, or ``paper`` with ``kf_overlap_smoothing``): a
        bool, or a [] bool array when the mode or the flag is traced."""
        parity, paper = choice_is(self.mode, "code_parity", CBKNN_MODES), choice_is(self.mode, "paper", CBKNN_MODES)
        if isinstance(parity, bool) and isinstance(self.kf_overlap_smoothing, bool):
            return parity or (paper and self.kf_overlap_smoothing)
        return jnp.logical_or(parity, jnp.logical_and(paper, self.kf_overlap_smoothing))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    """Noise injected for robustness studies (:mod:`gsjax.slam.noise`); all zero (off) by default, all traced, so
    noise levels sweep in one program.

    Attributes:
      map_means_cm: std (cm) of Gaussian noise added to every active mean of the map that a frame's tracking
        renders, drawn afresh per frame (the stored map is not changed: noisy Gaussian parameters at tracking time).
      map_rgb: std of the noise added to those Gaussians' colours (colour units, images in [0, 1]).
      depth_cm: std (cm) of noise added to each valid pixel of the input depth, before everything (tracking,
        densification, mapping, the stored keyframe).
      persistent_means_cm: std (cm) of noise added once to every active mean of the stored map itself, at the
        start of frame ``persistent_frame`` (before it is tracked), and left there: tracking from then on sees the
        noisy map, and only mapping's own updates repair it (the paper's "noisy Gaussian parameters").
      persistent_rgb: std (colour units) of noise added once to every active colour of the stored map, at the start
        of frame ``persistent_frame``, as ``persistent_means_cm``.
      persistent_frame: the frame at whose start the persistent noise is added (>= 1: frame 0 builds the first
        map).
    """

    map_means_cm: float = param(0.0, "cm", low=0.0)
    map_rgb: float = param(0.0, "colour", low=0.0)
    depth_cm: float = param(0.0, "cm", low=0.0)
    persistent_means_cm: float = param(0.0, "cm", low=0.0)
    persistent_rgb: float = param(0.0, "colour", low=0.0)
    persistent_frame: int = param(1, "frame", low=1)

    def __post_init__(self):
        check_fields(self, "noise")

    def levels(self) -> tuple:
        """The noise levels: every field but ``persistent_frame`` (all 0: no noise is drawn).

        Returns:
          ``(map_means_cm, map_rgb, depth_cm, persistent_means_cm, persistent_rgb)``.
        """
        return (self.map_means_cm, self.map_rgb, self.depth_cm, self.persistent_means_cm, self.persistent_rgb)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SlamConfig:
    """Everything the SLAM core needs (a pytree: traced hyperparameters, static shapes and modes).

    Attributes:
      tracking: camera tracking.
      mapping: map optimisation.
      densify: densification.
      cbknn: where CB-KNN acts and its parameters.
      noise: injected noise (off by default).
      raster: rasterizer settings. SLAM maps carry many young, semi-transparent Gaussians (opacity 0.5 at
        birth), so the SLAM default keeps 96 slots per pixel (the rasterizer's own default, 64, fits converged
        SplaTAM-density maps). Close-up views still exceed it at a few pixels (7-Scenes kitchen: up to ~150
        contributors); that is reported per frame (``truncation_residual``: at most 0.41 over the 150-frame run,
        so a cut pixel's silhouette stays above the densification threshold); 128 slots moved the 150-frame ATE by
        0.13 cm. The ``cpu`` preset keeps 64 (:mod:`gsjax.slam.presets`).
      keyframe_every: a keyframe every this many frames (plus frame 0 and the second-to-last frame).
      scene_radius_depth_ratio: scene radius = max depth of frame 0 / this (used by pruning).
      min_valid_depth: the fraction of pixels with valid depth a frame needs to be tracked and mapped; a frame
        with less keeps its constant-velocity prediction and leaves the map alone (:mod:`gsjax.slam.system`).
        Real RGB-D frames have 60-99 % valid depth; 1 % keeps far too few pixels to constrain a pose. Static (a
        property of the data, not a hyperparameter to sweep): the decision then depends on the frame alone, so in a
        batch of configs vmapped over shared frames it stays a branch instead of computing both sides.
      caps: (derived, static) the loops' caps and mapping's selection buffer (:class:`gsjax.slam.loops.LoopCaps`):
        the program runs any counts within them. Derived from the counts whenever the config is built; a sweep pins
        common caps on its configs (:meth:`with_caps`, raised only where a count outgrows them), so that they share
        one program. Not written to ``config.json`` and not set on the command line.
    """

    tracking: TrackingConfig = TrackingConfig()
    mapping: MappingConfig = MappingConfig()
    densify: DensifyConfig = DensifyConfig()
    cbknn: CBKNNConfig = CBKNNConfig()
    raster: RasterSettings = RasterSettings(max_contributors=SLAM_MAX_CONTRIBUTORS)
    keyframe_every: int = param(5, "frames", static=True, low=1)
    scene_radius_depth_ratio: float = param(3.0, "ratio", low=0.0, low_open=True)
    min_valid_depth: float = param(0.01, "ratio", static=True, low=0.0, high=1.0)
    noise: NoiseConfig = NoiseConfig()
    caps: LoopCaps | None = derived()

    def __post_init__(self):
        check_fields(self, "config")
        concrete = isinstance(self.cbknn.mode, str) or is_checkable(self.cbknn.mode)  # (not traced, not a placeholder)
        if concrete and np.any(self.cbknn.smooth_renders) and self.cbknn.params.k_max > self.raster.max_contributors:
            raise ValueError(
                f"cbknn.params.k_max ({self.cbknn.params.k_max}) exceeds raster.max_contributors "
                f"({self.raster.max_contributors})"
            )
        derived = LoopCaps.of(self)
        if derived is not None:  # (None: traced counts, under jit: the caps come with the tree structure)
            caps = self.caps
            if caps is None or not caps.pinned:
                caps = derived
            elif not caps.covers(LoopCaps.of(self, exact=True)):
                caps = caps.union(derived)
            object.__setattr__(self, "caps", caps)

    def with_caps(self, caps: LoopCaps) -> SlamConfig:
        """This config compiled for ``caps`` (configs given the same caps share one program; a sweep does that).

        Args:
          caps: the caps; a cap below this config's count is raised to hold it.

        Returns:
          The config with those caps.
        """
        return dataclasses.replace(self, caps=dataclasses.replace(caps, pinned=True))


# Every config class (a pytree): the config reference and the checks cover them all (tests/test_config_fields.py).
CONFIG_CLASSES = (SlamConfig, TrackingConfig, DivergenceGuard, EarlyStop, ImageBlur, CoarseToFine, Exposure,
                  MappingConfig, DensifyConfig, CBKNNConfig, NoiseConfig, RasterSettings, CBKNN)
__all__ = ["BEST_POSE", "CONFIG_CLASSES", "SLAM_MAX_CONTRIBUTORS", "TRACKING_OPTIMIZERS", "CBKNNConfig",
           "CoarseToFine", "DensifyConfig", "DivergenceGuard", "EarlyStop", "Exposure", "ImageBlur", "MappingConfig",
           "NoiseConfig", "SlamConfig", "TrackingConfig"]
