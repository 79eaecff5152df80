"""Evaluation metrics: trajectory errors (numpy float64) and image/depth metrics (pure JAX).

See :mod:`gsjax.eval.trajectory` for the two ATE variants (true RMSE of camera centres vs SplaTAM's mean of
w2c translations) and the unaligned drift per frame, :mod:`gsjax.eval.image` for PSNR / SSIM / MS-SSIM / depth L1
(no LPIPS), :mod:`gsjax.eval.renders` for a finished map's render metrics, :mod:`gsjax.eval.run_metrics` and
:mod:`gsjax.eval.run_input` for ``metrics.json`` and ``config.json`` as typed records, and :mod:`gsjax.eval.stats`
for studies' paired differences with bootstrap intervals.
"""

from gsjax.eval.association import associate_timestamps
from gsjax.eval.image import (
    depth_l1,
    ms_ssim,
    psnr,
    psnr_splatam,
    render_metrics_splatam,
    ssim,
    ssim_splatam,
)
from gsjax.eval.stats import PairedDifference, paired_difference
from gsjax.eval.trajectory import (
    Alignment,
    AteResult,
    RpeResult,
    ate_rmse_c2w,
    ate_splatam_mean_w2c,
    evaluate_trajectory,
    rpe,
    umeyama_alignment,
)

__all__ = [
    "Alignment",
    "AteResult",
    "PairedDifference",
    "RpeResult",
    "associate_timestamps",
    "ate_rmse_c2w",
    "ate_splatam_mean_w2c",
    "depth_l1",
    "evaluate_trajectory",
    "ms_ssim",
    "paired_difference",
    "psnr",
    "psnr_splatam",
    "render_metrics_splatam",
    "rpe",
    "ssim",
    "ssim_splatam",
    "umeyama_alignment",
]
