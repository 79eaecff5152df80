"""SLAM configuration: frozen dataclass pytrees, validated when built.

Hyperparameters that users sweep (learning rates, loss weights, thresholds, CB-KNN alpha/K0/beta) are *traced*
leaves, so ``jax.vmap`` over a batch of configs runs one compiled program; iteration counts, window sizes, modes
and flags are *static* (they set shapes or control flow). The named presets are in :mod:`gsjax.slam.presets`;
overrides by dotted field name and the JSON round trip in :mod:`gsjax.config_text`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TypeVar

import jax
import numpy as np

from gsjax.checks import is_checkable
from gsjax.names import CBKNN_MODES
from gsjax.raster import RasterSettings
from gsjax.raster.cbknn import CBKNN

SLAM_MAX_CONTRIBUTORS = 96
TRACKING_OPTIMIZERS = ("adam", "lm")
BEST_POSE = ("pre_step", "post_step")

_T = TypeVar("_T")


def static(default: _T) -> _T:
    """A static (treedef, compile-time) dataclass field."""
    return dataclasses.field(default=default, metadata=dict(static=True))


def _check_positive_int(owner: str, name: str, value, minimum: int = 1) -> None:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{owner}.{name} must be an int >= {minimum}, got {value!r}")


def _check_number(owner: str, name: str, value, low: float, high: float = math.inf, strict_low=False) -> None:
    if not is_checkable(value):
        return  # traced, or a placeholder JAX puts in a pytree (e.g. vmap's in_axes): checked when built
    v = np.asarray(value, np.float64)
    ok = np.isfinite(v).all() and np.all(v > low if strict_low else v >= low) and np.all(v <= high)
    if not ok:
        bound = f"{'>' if strict_low else '>='} {low}" + (f" and <= {high}" if high < math.inf else "")
        raise ValueError(f"{owner}.{name} must be a finite number {bound}, got {value!r}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """Camera tracking (method_spec A.6): a fixed number of iterations on the pose tangent (left perturbation).

    Attributes:
      iters: optimisation iterations per frame.
      optimizer: ``"adam"`` (SplaTAM parity: a fresh Adam per frame) or ``"lm"`` (Levenberg-Marquardt with
        optimistix on the masked residuals, Jacobian by forward mode).
      lr_trans: Adam step size of the translation part rho (m).
      lr_rot: Adam step size of the rotation part phi (rad). SplaTAM's quaternion learning rate q corresponds to
        about 2 q here (a unit quaternion's vector part moves by half the angle).
      lambda_color, lambda_depth: weights of the summed L1 colour and depth terms.
      sil_threshold: pixels enter the loss where the rendered silhouette exceeds this (and depth is valid).
      best_pose: ``"pre_step"`` keeps the pose whose loss was lowest; ``"post_step"`` reproduces SplaTAM's
        off-by-one (stores the pose after the step taken from the best loss).
      lr_final_ratio: the Adam step sizes decay exponentially over the iterations to this fraction (1 = constant,
        SplaTAM). Adam's steps do not shrink near the optimum, so a constant step leaves the pose jittering within
        about one step; decaying it lets the last iterations settle.
      normalized_depth: compare the observed depth with the rendered depth divided by the silhouette, D / S,
        instead of SplaTAM's D = sum w z. With S < 1 (young maps, low resolution) D underestimates depth by
        (1 - S) z, which biases the camera along its axis by about that much; D / S removes the bias.
      max_step_m, max_step_deg: a physical bound on how far tracking may move the camera from its
        constant-velocity prediction in one frame (camera centre, m; rotation, degrees). A tracked pose beyond it
        has diverged.
      loss_jump: tracking has also diverged when its loss exceeds this many times the previous tracked frame's.
      retry_lr_scale: a diverged frame is tracked once more from the constant-velocity prediction with the step
        sizes scaled by this; the result within the bound with the lower loss is kept, and when neither attempt is
        within it the frame keeps the prediction (``StepOutputs.retried``, ``diverged``). (``adam`` only: the LM
        solver has no step size to change, so a diverged LM frame keeps the prediction.)
      converge_window: 0 (SplaTAM) runs all ``iters`` iterations; W > 0 stops a frame's ``adam`` tracking once W
        iterations in a row have not brought the loss ``converge_rtol`` (relative) below the loss of the last
        iteration that did, ``iters`` staying the cap (``StepOutputs.tracking_iters`` counts the iterations run).
      converge_rtol: the relative loss drop that counts as progress for ``converge_window``.
      match_exposure: (traced bool) scale the render's colour per channel to the frame's brightness before the
        colour term (:func:`gsjax.slam.losses.exposure_gain`), so that a camera's auto exposure changing after the
        map was made is not mistaken for motion. False: SplaTAM.
      strided_iters: 0 (SplaTAM) tracks on every pixel only; S > 0 first runs S iterations on a quarter of the
        pixels, every other one of each row and column (the four such grids in turn), rendered exactly as the full
        render renders them (:meth:`gsjax.camera.Intrinsics.strided`) at a fraction of its cost, then the ``iters``
        iterations on every pixel from there; only those compete for the best pose. ``adam`` keeps one state over
        all S + ``iters`` (the strided loss is scaled by 4, the pixel ratio, and the step sizes decay over all);
        ``lm`` solves on one grid with at most S steps, then on every pixel from its solution.
      blur_radius_px: 0 (SplaTAM) compares render and frame pixel by pixel; R > 0 compiles image-space smoothing:
        the masked residuals (render - frame, colour and depth) pass through a Gaussian filter of ``blur_px`` std
        (px, traced) truncated at R px before the L1 sum, which is blurring render and frame together, the
        textbook way to widen a photometric basin. ``blur_px`` 0 with R > 0 is the unblurred loss.
      coarse_iters, coarse_levels, coarse_sigma_px: coarse-to-fine tracking (``adam`` only; needs
        ``blur_radius_px``): ``coarse_iters`` iterations run first, split over ``coarse_levels`` levels from the
        coarsest, each on every pixel with the residuals blurred at ``coarse_sigma_px`` x 2^(levels - 1 - level) px
        (a Gaussian pyramid's smoothing without its subsampling), then the strided and full iterations; only the
        full ones compete for the best pose. The step sizes decay over all iterations.
      reselect_every: 1 (SplaTAM) chooses every pixel's contributors (binning and the selection walk) at each
        iteration's own pose; R > 1 chooses them at iterations 0, R, 2R, ... (counted over coarse, strided and full
        iterations; the strided grids take the full image's slots at their pixels) and composites those slots at
        the poses in between, with the render and its gradient exact for those slots (``adam`` only; see
        :func:`gsjax.raster.select_slots`). The map is fixed while a frame is tracked and the pose moves by
        millimetres, so few slots that matter change. Each iteration's loss (and so the best pose's, the frame's
        ``tracking_loss``) is the composite of the slots it was given.
    """

    iters: int = static(40)
    optimizer: str = static("adam")
    lr_trans: float = 2e-3
    lr_rot: float = 8e-4
    lambda_color: float = 0.5
    lambda_depth: float = 1.0
    sil_threshold: float = 0.99
    lr_final_ratio: float = 1.0
    best_pose: str = static("pre_step")
    normalized_depth: bool = static(False)
    max_step_m: float = 0.5
    max_step_deg: float = 30.0
    loss_jump: float = 10.0
    retry_lr_scale: float = 0.5
    converge_window: int = static(0)
    converge_rtol: float = 1e-3
    strided_iters: int = static(0)
    match_exposure: bool = False
    blur_radius_px: int = static(0)
    blur_px: float = 0.0
    coarse_iters: int = static(0)
    coarse_levels: int = static(2)
    coarse_sigma_px: float = 1.0
    reselect_every: int = static(1)

    def __post_init__(self):
        _check_positive_int("tracking", "iters", self.iters)
        _check_positive_int("tracking", "reselect_every", self.reselect_every)
        _check_positive_int("tracking", "converge_window", self.converge_window, 0)
        _check_positive_int("tracking", "strided_iters", self.strided_iters, 0)
        _check_positive_int("tracking", "blur_radius_px", self.blur_radius_px, 0)
        _check_positive_int("tracking", "coarse_iters", self.coarse_iters, 0)
        _check_positive_int("tracking", "coarse_levels", self.coarse_levels)
        _check_number("tracking", "blur_px", self.blur_px, 0.0)
        _check_number("tracking", "coarse_sigma_px", self.coarse_sigma_px, 0.0)
        if self.coarse_iters and not self.blur_radius_px:
            raise ValueError("tracking.coarse_iters needs tracking.blur_radius_px > 0 (the coarse levels' filter)")
        if self.coarse_iters and self.optimizer != "adam":
            raise ValueError("tracking.coarse_iters runs with tracking.optimizer adam only")
        _check_number("tracking", "converge_rtol", self.converge_rtol, 0.0, 1.0)
        if self.optimizer not in TRACKING_OPTIMIZERS:
            raise ValueError(f"tracking.optimizer must be one of {TRACKING_OPTIMIZERS}, got {self.optimizer!r}")
        if self.best_pose not in BEST_POSE:
            raise ValueError(f"tracking.best_pose must be one of {BEST_POSE}, got {self.best_pose!r}")
        for name in ("lr_trans", "lr_rot", "lambda_color", "lambda_depth"):
            _check_number("tracking", name, getattr(self, name), 0.0)
        _check_number("tracking", "lr_final_ratio", self.lr_final_ratio, 0.0, 1.0, strict_low=True)
        _check_number("tracking", "sil_threshold", self.sil_threshold, 0.0, 1.0)
        for name in ("max_step_m", "max_step_deg", "loss_jump", "retry_lr_scale"):
            _check_number("tracking", name, getattr(self, name), 0.0, strict_low=True)


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
      lr_means, lr_rgb, lr_opacity, lr_scale: Adam step sizes of means (m), colours, logit opacities, log scales.
      lr_means_first: the means' step size when mapping frame 0 (SplaTAM: the same as ``lr_means``). Fresh
        Gaussians render a depth biased towards the camera on slanted surfaces (nearer neighbours come first in
        the blend) by up to a fraction of a pixel footprint; at low resolution that is centimetres, and the first
        map needs a larger step to remove it before the second frame tracks against it.
      lambda_color, lambda_depth: loss weights; ``ssim_weight`` mixes 1 - SSIM into the colour term.
      prune_opacity: prune Gaussians with opacity below this; ``prune_scale_ratio``: or with scale above this
        fraction of the scene radius.
      prune_iters: the mapping iterations at which pruning runs (counted from the first, strided or not).
      clamp_rgb: (traced bool) project the colours back into [0, 1] after every mapping step. SplaTAM leaves them
        unbounded (False: its behaviour): with Adam's eps 1e-15 a Gaussian with a near-zero colour gradient takes
        full-size steps and can leave [0, 1] far, and renders then depend on whether it is in view.
      skip_step_at_prune: reproduce SplaTAM's quirk of skipping the Adam step at pruning iterations.
      overlap_samples: depth pixels sampled to measure keyframe overlap; ``overlap_margin``: border (px) a
        projected sample must clear to count as inside a keyframe.
      every: 1 (SplaTAM) maps every frame; E > 1 maps only frames t with t % E == 0, keyframes and the first frame
        with depth (the others are tracked and densified, their new Gaussians optimised by the next mapping).
      reselect_every: 1 (SplaTAM) chooses every pixel's contributors at each iteration, on the map as it is then;
        R > 1 chooses them for every view of the window at iterations 0, R, 2R, ... (counted over strided and full
        iterations) and composites those slots in between, as the map changes (render and gradient exact for those
        slots; a Gaussian that would newly enter a pixel's first K in between does not).
    """

    iters: int = static(30)
    strided_iters: int = static(0)
    window_size: int = static(24)
    lr_means: float = 1e-4
    lr_means_first: float = 1e-4
    lr_rgb: float = 2.5e-3
    lr_opacity: float = 5e-2
    lr_scale: float = 1e-3
    lambda_color: float = 0.5
    lambda_depth: float = 1.0
    ssim_weight: float = 0.2
    prune_opacity: float = 0.005
    prune_scale_ratio: float = 0.1
    prune_iters: tuple = static((0, 20))
    skip_step_at_prune: bool = static(False)
    clamp_rgb: bool = False
    overlap_samples: int = static(1600)
    overlap_margin: float = 20.0
    reselect_every: int = static(1)
    every: int = static(1)

    def __post_init__(self):
        _check_positive_int("mapping", "iters", self.iters)
        _check_positive_int("mapping", "every", self.every)
        _check_positive_int("mapping", "reselect_every", self.reselect_every)
        _check_positive_int("mapping", "strided_iters", self.strided_iters, 0)
        _check_positive_int("mapping", "window_size", self.window_size, 2)
        _check_positive_int("mapping", "overlap_samples", self.overlap_samples)
        for name in ("lr_means", "lr_means_first", "lr_rgb", "lr_opacity", "lr_scale", "lambda_color", "lambda_depth",
                     "prune_opacity", "prune_scale_ratio", "overlap_margin"):
            _check_number("mapping", name, getattr(self, name), 0.0)
        _check_number("mapping", "ssim_weight", self.ssim_weight, 0.0, 1.0)
        if not isinstance(self.prune_iters, tuple) or not all(isinstance(i, int) and i >= 0 for i in self.prune_iters):
            raise ValueError(f"mapping.prune_iters must be a tuple of ints >= 0, got {self.prune_iters!r}")


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

    sil_threshold: float = 0.5
    depth_error_factor: float = 50.0
    init_opacity: float = 0.5

    def __post_init__(self):
        _check_number("densify", "sil_threshold", self.sil_threshold, 0.0, 1.0)
        _check_number("densify", "depth_error_factor", self.depth_error_factor, 0.0)
        _check_number("densify", "init_opacity", self.init_opacity, 0.0, 1.0, strict_low=True)
        if is_checkable(self.init_opacity) and float(np.max(self.init_opacity)) >= 1.0:
            raise ValueError(f"densify.init_opacity must be < 1, got {self.init_opacity!r}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CBKNNConfig:
    """Where CB-KNN acts (method_spec D.6) and its parameters.

    Attributes:
      mode: ``"off"`` (SplaTAM), ``"code_parity"`` (only the released code's 3D KNN smoothing of the overlap
        samples) or ``"paper"`` (per-pixel smoothing of keyframe renders).
      params: the per-pixel smoothing (:class:`gsjax.raster.cbknn.CBKNN`: alpha, k0, beta, ... ).
      track_keyframes, map_keyframes, densify: in ``paper`` mode, smooth keyframe tracking renders, mapping
        renders of keyframes, and the densification render of keyframes.
      lambda_color_keyframe: tracking colour weight on smoothed keyframes (paper: 0.6).
      kf_overlap_smoothing: smooth the overlap samples (on in ``code_parity``).
      smoothing_base_k, smoothing_min_k, smoothing_max_k, smoothing_dropout: that smoothing's parameters.
    """

    mode: str = static("off")
    params: CBKNN = CBKNN()
    track_keyframes: bool = static(True)
    map_keyframes: bool = static(True)
    densify: bool = static(True)
    lambda_color_keyframe: float = 0.6
    kf_overlap_smoothing: bool = static(False)
    smoothing_base_k: int = static(6)
    smoothing_min_k: int = static(2)
    smoothing_max_k: int = static(16)
    smoothing_dropout: float = static(0.4)

    def __post_init__(self):
        if self.mode not in CBKNN_MODES:
            raise ValueError(f"cbknn.mode must be one of {CBKNN_MODES}, got {self.mode!r}")
        _check_number("cbknn", "lambda_color_keyframe", self.lambda_color_keyframe, 0.0)
        for name in ("smoothing_base_k", "smoothing_min_k", "smoothing_max_k"):
            _check_positive_int("cbknn", name, getattr(self, name))
        if self.smoothing_min_k > self.smoothing_max_k:
            raise ValueError("cbknn.smoothing_min_k must not exceed cbknn.smoothing_max_k")
        if not 0.0 <= self.smoothing_dropout < 1.0:
            raise ValueError(f"cbknn.smoothing_dropout must lie in [0, 1), got {self.smoothing_dropout!r}")

    @property
    def smooth_renders(self) -> bool:
        return self.mode == "paper"

    @property
    def smooth_overlap(self) -> bool:
        return self.mode == "code_parity" or (self.mode == "paper" and self.kf_overlap_smoothing)


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
      persistent_means_cm, persistent_rgb: std (cm; colour units) of noise added once to every active mean and
        colour of the stored map itself, at the start of frame ``persistent_frame`` (before it is tracked), and left
        there: tracking from then on sees the noisy map, and only mapping's own updates repair it (the paper's
        "noisy Gaussian parameters"). ``persistent_frame`` >= 1 (frame 0 builds the first map).
    """

    map_means_cm: float = 0.0
    map_rgb: float = 0.0
    depth_cm: float = 0.0
    persistent_means_cm: float = 0.0
    persistent_rgb: float = 0.0
    persistent_frame: int = 1

    def __post_init__(self):
        for name in ("map_means_cm", "map_rgb", "depth_cm", "persistent_means_cm", "persistent_rgb"):
            _check_number("noise", name, getattr(self, name), 0.0)
        _check_number("noise", "persistent_frame", self.persistent_frame, 1.0)
        if is_checkable(self.persistent_frame) and np.any(np.asarray(self.persistent_frame) % 1):
            raise ValueError(f"noise.persistent_frame must be an int >= 1, got {self.persistent_frame!r}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SlamConfig:
    """Everything the SLAM core needs (a pytree: traced hyperparameters, static shapes and modes).

    Attributes:
      tracking, mapping, densify, cbknn: the stage configs; noise: injected noise (off by default).
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
    """

    tracking: TrackingConfig = TrackingConfig()
    mapping: MappingConfig = MappingConfig()
    densify: DensifyConfig = DensifyConfig()
    cbknn: CBKNNConfig = CBKNNConfig()
    raster: RasterSettings = RasterSettings(max_contributors=SLAM_MAX_CONTRIBUTORS)
    keyframe_every: int = static(5)
    scene_radius_depth_ratio: float = 3.0
    min_valid_depth: float = static(0.01)
    noise: NoiseConfig = NoiseConfig()

    def __post_init__(self):
        _check_positive_int("config", "keyframe_every", self.keyframe_every)
        _check_number("config", "scene_radius_depth_ratio", self.scene_radius_depth_ratio, 0.0, strict_low=True)
        _check_number("config", "min_valid_depth", self.min_valid_depth, 0.0, 1.0)
        if self.cbknn.smooth_renders and self.cbknn.params.k_max > self.raster.max_contributors:
            raise ValueError(
                f"cbknn.params.k_max ({self.cbknn.params.k_max}) exceeds raster.max_contributors "
                f"({self.raster.max_contributors})"
            )
