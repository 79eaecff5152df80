# %% [markdown]
# # The hypergradient of ATE with respect to CB-KNN's alpha
#
# gsjax can differentiate what a SLAM run computes with respect to its own config. Here: how the trajectory error
# (ATE, cm) of the first frames of the noisy synthetic room changes with CB-KNN's `alpha` (the shift, in pixels, of
# each pixel's nearest Gaussians toward their centroid in keyframe renders), checked against finite differences.
#
# The tracker is Levenberg-Marquardt (`tracking.optimizer lm`), so a tracked pose is a fixed point of its loss and
# its derivative is the implicit one, `d xi / d alpha = -H^-1 d2L / (d xi d alpha)` with the 6 x 6 Hessian in the
# pose: no iteration is differentiated. The map's dependence on `alpha` is cut at the frame (`truncation="frame"`,
# what `gsjax tune` uses): each frame is tracked again from the state it was tracked from, as recorded.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

from gsjax import slam
from gsjax.config.paths import replace_path
from gsjax.config.text import apply_overrides
from gsjax.data import open_sequence
from gsjax.slam import hypergrad

TINY = bool(os.environ.get("GSJAX_TUTORIAL_TINY"))
ALPHA = "cbknn.params.alpha"
sequence = open_sequence("synthetic", max_frames=6 if TINY else 8, downscale=4 if TINY else 2, sensor_noise=True)
intrinsics = sequence.intrinsics
config = slam.with_cbknn_mode(slam.preset("cpu", intrinsics.width), "paper")
config = apply_overrides(config, {"tracking.optimizer": "lm", "tracking.iters": "5" if TINY else "20",
                                  "tracking.strided_iters": "0", "tracking.reselect_every": "1"})
if TINY:  # a few mapping iterations: the test suite checks that the tutorial runs, not the numbers
    config = apply_overrides(config, {"mapping.iters": "2", "mapping.strided_iters": "0"})
frames = [sequence.read_host(i) for i in range(len(sequence))]
alpha0 = float(config.cbknn.params.alpha)

window = hypergrad.record(frames, config, intrinsics)  # the run, and the state each frame was tracked from
result = hypergrad.hypergradient(window, config, intrinsics, [ALPHA], objective="ate", adjoint="implicit")
slope = 100 * result.gradient[ALPHA]
print(f"{len(frames)} frames at {intrinsics.width}x{intrinsics.height}, alpha {alpha0} px: "
      f"ATE {100 * result.value:.4f} cm, d ATE / d alpha {slope:+.4f} cm/px")

# %% [markdown]
# CB-KNN smooths the renders of keyframes only (frame 0, every fifth frame, the second-to-last), so in this
# truncation `alpha` moves the poses of the keyframes after the first (here frames 4 and 6), and the ATE through
# them. The check: the same function, every frame tracked again from its recorded state, evaluated at
# `alpha +- h`. A tracked pose moves by millimetres per pixel of `alpha`; the loss's pixel mask and each pixel's
# contributors change in steps, and the solver stops at a tolerance, so the function has small jumps of its own
# (about 0.003 cm in ATE here): steps below 0.02 px measure those, not the slope.

# %%
steps = (0.05,) if TINY else (0.02, 0.05, 0.1)
replayed = {alpha0: result.value}
for h in steps:
    for alpha in (alpha0 - h, alpha0 + h):
        replayed[alpha] = hypergrad.replayed_objective(window, replace_path(config, ALPHA, alpha), intrinsics, "ate")
differences = {h: 100 * (replayed[alpha0 + h] - replayed[alpha0 - h]) / (2 * h) for h in steps}
print("h (px) | central difference (cm/px) | hypergradient (cm/px)")
for h, difference in differences.items():
    print(f"{h} | {difference:+.4f} | {slope:+.4f}")
if not TINY:  # measured at 80x60: -0.0206 / -0.0115 / -0.0171 against -0.0243
    assert all(np.sign(d) == np.sign(slope) and 0.4 < d / slope < 2.5 for d in differences.values())

# %%
alphas = np.array(sorted(replayed))
plt.figure(figsize=(5, 3))
plt.plot(alphas, [100 * replayed[a] for a in alphas], "o", label="frames tracked again at alpha")
span = np.array([alphas[0], alphas[-1]])
plt.plot(span, 100 * result.value + slope * (span - alpha0), "-", label="the hypergradient's tangent")
plt.xlabel("alpha (px)")
plt.ylabel("ATE (cm)")
plt.legend()
plt.title("CB-KNN paper, noisy synthetic room")
plt.show()

# %% [markdown]
# Whole runs at `alpha +- h` differ from that function: there `alpha` also moves the map each keyframe's mapping
# builds, and every frame tracked against it after, and the run has jumps of its own (the pixels that densification
# fills, the keyframes' overlap). The `frame` truncation does not follow the map; `truncation="window"` does (with
# `adjoint="implicit"`: each pose at its fixed point on the map the earlier frames' mapping built, that mapping
# differentiated). Here two whole runs at the widest step:

# %%
h = steps[-1]
runs = [hypergrad.objective_value(hypergrad.record(frames, c, intrinsics), c, intrinsics, "ate")
        for c in (replace_path(config, ALPHA, alpha0 + h), replace_path(config, ALPHA, alpha0 - h))]
print(f"whole runs' central difference at h = {h} px: {100 * (runs[0] - runs[1]) / (2 * h):+.4f} cm/px "
      f"(the frames tracked again: {differences[h]:+.4f}; the hypergradient {slope:+.4f})")

# %% [markdown]
# Measured (80x60, 2 CPU cores): the hypergradient -0.0243 cm/px; the frames tracked again -0.0206 / -0.0115 /
# -0.0171 cm/px at h = 0.02 / 0.05 / 0.1 px; following the map (`window`) -0.026 cm/px. Whole runs give -0.116 /
# +0.376 / +0.127 cm/px at h = 0.01 / 0.04 / 0.1 px: their sign changes with the step, so for `alpha` here a whole
# run's difference is not a derivative to check against (for the loss weights it is, and the implicit derivative has
# its sign: `experiments/README.md`). `gsjax tune` follows the `frame` derivative; the guide's [hypergradients and
# tune](../guide/tuning.md) says what that finds against a grid.
