"""Figure: what CB-KNN does to a render of a noisy map (writes docs/figures/cbknn_effect.png).

A map is built from the synthetic room (frame 0, SplaTAM's one-Gaussian-per-pixel initialisation at opacity 0.9),
then its parameters are perturbed as a SLAM map's are by noisy optimisation: centres jittered by 0.4 px-footprints,
colours by N(0, 0.08), a third of the Gaussians removed to open sparse holes. It is rendered from frame 5's pose
canonically and with CB-KNN (paper settings: alpha 0.2 px, K0 5, beta 0.3, motion 0.5), and the figure shows both
renders, their difference, the input, and the K and rho maps.

    python experiments/cbknn_effect.py [--out docs/figures/cbknn_effect.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from gsjax.camera import se3_inverse
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.gaussians import Gaussians, gaussians_from_rgbd
from gsjax.raster import RasterSettings, render
from gsjax.raster.cbknn import CBKNN


def noisy_map(seed: int = 0):
    sequence = synthetic_sequence(SyntheticConfig())
    frame = sequence[0]
    g = gaussians_from_rgbd(frame.color, frame.depth, sequence.intrinsics, frame.c2w, opacity=0.9)
    key_pos, key_col, key_drop = jax.random.split(jax.random.PRNGKey(seed), 3)
    footprint = jnp.exp(g.log_scales)[:, None]
    means = g.means + 0.4 * footprint * jax.random.normal(key_pos, g.means.shape)
    rgb = g.rgb + 0.08 * jax.random.normal(key_col, g.rgb.shape)
    active = g.active & (jax.random.uniform(key_drop, g.active.shape) > 0.33)
    return Gaussians(means, g.log_scales, g.logit_opacities, rgb, active), sequence


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    figure = Path(__file__).resolve().parents[1] / "docs" / "figures" / "cbknn_effect.png"
    parser.add_argument("--out", type=Path, default=figure)
    args = parser.parse_args(argv)
    gaussians, sequence = noisy_map()
    frame = sequence[5]
    w2c = se3_inverse(frame.c2w)
    settings = RasterSettings()
    canonical = render(gaussians, w2c, sequence.intrinsics, settings)
    smoothed = render(gaussians, w2c, sequence.intrinsics, settings, cbknn=CBKNN(), motion=0.5)
    stats = smoothed.stats.cbknn
    diff = np.abs(np.asarray(smoothed.color) - np.asarray(canonical.color)).mean(-1)
    err_c = float(np.abs(np.clip(canonical.color, 0, 1) - frame.color).mean())
    err_s = float(np.abs(np.clip(smoothed.color, 0, 1) - frame.color).mean())

    fig, axes = plt.subplots(2, 3, figsize=(11, 5.6), constrained_layout=True)
    panels = [
        (np.clip(canonical.color, 0, 1), f"canonical render (L1 to input {err_c:.4f})", None),
        (np.clip(smoothed.color, 0, 1), f"CB-KNN render (L1 to input {err_s:.4f})", None),
        (diff, f"|CB-KNN - canonical| (mean {diff.mean():.4f})", "magma"),
        (np.asarray(frame.color), "input frame (ground truth)", None),
        (np.asarray(stats.k_map), "K per 8x8 cell", "viridis"),
        (np.asarray(stats.rho_map), "rho (density / mean of non-empty cells)", "viridis"),
    ]
    for ax, (image, title, cmap) in zip(axes.ravel(), panels):
        shown = ax.imshow(image, cmap=cmap, interpolation="nearest")
        if cmap is not None:
            fig.colorbar(shown, ax=ax, shrink=0.8)
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    fig.suptitle(
        f"CB-KNN on a noisy map: alpha 0.2 px, K0 5, beta 0.3, motion 0.5; mean shift "
        f"{float(stats.mean_shift_px):.3f} px, {100 * float(stats.fraction_fewer_than_k):.1f}% px with fewer than K "
        "contributors",
        fontsize=10,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
