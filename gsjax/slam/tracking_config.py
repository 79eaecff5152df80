"""Tracking's configuration: SplaTAM's core (:class:`TrackingConfig`) and its nested parts, one per concern: the
divergence guard (``tracking.guard``), stopping early (``tracking.stop``), and the research alternatives to the
plain per-pixel loss (``tracking.blur``, ``tracking.coarse``, ``tracking.exposure``). Units, static/traced and
bounds are declared per field (:func:`gsjax.config.fields.param`)."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from gsjax.config.fields import check_fields, is_checkable, param, register_config

TRACKING_OPTIMIZERS = ("adam", "lm")
BEST_POSE = ("pre_step", "post_step")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DivergenceGuard:
    """When a tracked pose has diverged, and what happens then (:func:`gsjax.slam.tracking.track_guarded`).

    Attributes:
      max_step_m: how far tracking may move the camera centre from its constant-velocity prediction in one frame;
        a tracked pose beyond it (or beyond ``max_step_deg``) has diverged.
      max_step_deg: how far tracking may turn the camera from its prediction in one frame.
      loss_jump: tracking has also diverged when its loss exceeds this many times the previous tracked frame's.
      retry_lr_scale: a diverged frame is tracked once more from the constant-velocity prediction with the step
        sizes scaled by this; the result within the bound with the lower loss is kept, and when neither attempt is
        within it the frame keeps the prediction (``StepOutputs.retried``, ``diverged``). (``adam`` only: the LM
        solver has no step size to change, so a diverged LM frame keeps the prediction.)
    """

    max_step_m: float = param(0.5, "m", low=0.0, low_open=True)
    max_step_deg: float = param(30.0, "deg", low=0.0, low_open=True)
    loss_jump: float = param(10.0, "ratio", low=0.0, low_open=True)
    retry_lr_scale: float = param(0.5, "ratio", low=0.0, low_open=True)

    def __post_init__(self):
        check_fields(self, "tracking.guard")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EarlyStop:
    """Stopping a frame's ``adam`` tracking once its loss stops falling.

    Attributes:
      window: 0 (SplaTAM) runs all ``tracking.iters`` iterations; W > 0 stops once W iterations in a row have not
        brought the loss ``rtol`` (relative) below the loss of the last iteration that did, ``tracking.iters``
        staying the cap (``StepOutputs.tracking_iters`` counts the iterations run).
      rtol: the relative loss drop that counts as progress for ``window``.
    """

    window: int = param(0, "iterations", low=0)
    rtol: float = param(1e-3, "ratio", low=0.0, high=1.0)

    def __post_init__(self):
        check_fields(self, "tracking.stop")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ImageBlur:
    """Image-space smoothing of the tracking loss, the textbook way to widen a photometric basin.

    Attributes:
      radius_px: 0 (SplaTAM) compares render and frame pixel by pixel; R > 0 compiles the smoothing: the masked
        residuals (render - frame, colour and depth) pass through a Gaussian filter of ``sigma_px`` std truncated
        at R px before the L1 sum, which is blurring render and frame together. A shape: it does not follow the
        width.
      sigma_px: the filter's std (0 with ``radius_px`` > 0 is the unblurred loss).
    """

    radius_px: int = param(0, "px", static=True, low=0)
    sigma_px: float = param(0.0, "px", low=0.0)

    def __post_init__(self):
        check_fields(self, "tracking.blur")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CoarseToFine:
    """Coarse-to-fine tracking (``adam`` only; needs ``tracking.blur.radius_px``): a Gaussian pyramid's smoothing
    without its subsampling.

    Attributes:
      iters: 0 (SplaTAM) tracks at full detail only; I > 0 runs I iterations first, split over ``levels`` levels
        from the coarsest, each on every pixel with the residuals blurred at ``sigma_px`` x 2^(levels - 1 - level)
        px, then the strided and full iterations; only the full ones compete for the best pose. The step sizes
        decay over all iterations.
      levels: the pyramid's levels.
      sigma_px: the finest level's blur std.
    """

    iters: int = param(0, "iterations", low=0)
    levels: int = param(2, "count", low=1)
    sigma_px: float = param(1.0, "px", low=0.0)

    def __post_init__(self):
        check_fields(self, "tracking.coarse")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Exposure:
    """Exposure compensation in the colour term.

    Attributes:
      match: (traced bool) scale the render's colour per channel to the frame's brightness before the colour term
        (:func:`gsjax.slam.losses.exposure_gain`), so that a camera's auto exposure changing after the map was made
        is not mistaken for motion. False: SplaTAM.
    """

    match: bool = param(False, "flag")

    def __post_init__(self):
        check_fields(self, "tracking.exposure")


@register_config
@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """Camera tracking (method_spec A.6): a fixed number of iterations on the pose tangent (left perturbation).

    Attributes:
      iters: optimisation iterations per frame.
      optimizer: ``"adam"`` (SplaTAM parity: a fresh Adam per frame) or ``"lm"`` (Levenberg-Marquardt with
        optimistix on the masked residuals, Jacobian by forward mode).
      lr_trans: Adam step size of the translation part rho.
      lr_rot: Adam step size of the rotation part phi. SplaTAM's quaternion learning rate q corresponds to about
        2 q here (a unit quaternion's vector part moves by half the angle).
      lambda_color: weight of the summed L1 colour term.
      lambda_depth: weight of the summed L1 depth term.
      sil_threshold: pixels enter the loss where the rendered silhouette exceeds this (and depth is valid).
      lr_final_ratio: the Adam step sizes decay exponentially over the iterations to this fraction (1 = constant,
        SplaTAM). Adam's steps do not shrink near the optimum, so a constant step leaves the pose jittering within
        about one step; decaying it lets the last iterations settle.
      best_pose: ``"pre_step"`` keeps the pose whose loss was lowest; ``"post_step"`` reproduces SplaTAM's
        off-by-one (stores the pose after the step taken from the best loss).
      normalized_depth: compare the observed depth with the rendered depth divided by the silhouette, D / S,
        instead of SplaTAM's D = sum w z. With S < 1 (young maps, low resolution) D underestimates depth by
        (1 - S) z, which biases the camera along its axis by about that much; D / S removes the bias.
      strided_iters: 0 (SplaTAM) tracks on every pixel only; S > 0 first runs S iterations on a quarter of the
        pixels, every other one of each row and column (the four such grids in turn), rendered exactly as the full
        render renders them (:meth:`gsjax.camera.Intrinsics.strided`) at a fraction of its cost, then the ``iters``
        iterations on every pixel from there; only those compete for the best pose. ``adam`` keeps one state over
        all S + ``iters`` (the strided loss is scaled by 4, the pixel ratio, and the step sizes decay over all);
        ``lm`` solves on one grid with at most S steps, then on every pixel from its solution.
      reselect_every: 1 (SplaTAM) chooses every pixel's contributors (binning and the selection walk) at each
        iteration's own pose; R > 1 chooses them at iterations 0, R, 2R, ... (counted over coarse, strided and full
        iterations; the strided grids take the full image's slots at their pixels) and composites those slots at
        the poses in between, with the render and its gradient exact for those slots (``adam`` only; see
        :func:`gsjax.raster.select_slots`). The map is fixed while a frame is tracked and the pose moves by
        millimetres, so few slots that matter change. Each iteration's loss (and so the best pose's, the frame's
        ``tracking_loss``) is the composite of the slots it was given.
      guard: the divergence guard (:class:`DivergenceGuard`).
      stop: stopping early (:class:`EarlyStop`).
      blur: image-space smoothing of the loss (:class:`ImageBlur`).
      coarse: coarse-to-fine tracking (:class:`CoarseToFine`).
      exposure: exposure compensation (:class:`Exposure`).
    """

    iters: int = param(40, "iterations", low=1)
    optimizer: str = param("adam", "choice", static=True, choices=TRACKING_OPTIMIZERS)
    lr_trans: float = param(2e-3, "m", low=0.0)
    lr_rot: float = param(8e-4, "rad", low=0.0)
    lambda_color: float = param(0.5, "weight", low=0.0)
    lambda_depth: float = param(1.0, "weight", low=0.0)
    sil_threshold: float = param(0.99, "ratio", low=0.0, high=1.0)
    lr_final_ratio: float = param(1.0, "ratio", low=0.0, low_open=True, high=1.0)
    best_pose: str = param("pre_step", "choice", choices=BEST_POSE)
    normalized_depth: bool = param(False, "flag", static=True)
    strided_iters: int = param(0, "iterations", low=0)
    reselect_every: int = param(1, "iterations", low=1)
    guard: DivergenceGuard = DivergenceGuard()
    stop: EarlyStop = EarlyStop()
    blur: ImageBlur = ImageBlur()
    coarse: CoarseToFine = CoarseToFine()
    exposure: Exposure = Exposure()

    def __post_init__(self):
        check_fields(self, "tracking")
        coarse = is_checkable(self.coarse.iters) and bool(np.any(np.asarray(self.coarse.iters)))
        if coarse and not self.blur.radius_px:
            raise ValueError("tracking.coarse.iters needs tracking.blur.radius_px > 0 (the coarse levels' filter)")
        if coarse and self.optimizer != "adam":
            raise ValueError("tracking.coarse.iters runs with tracking.optimizer adam only")
