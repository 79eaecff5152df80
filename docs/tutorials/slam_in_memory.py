# %% [markdown]
# # SLAM in memory on the synthetic room
#
# `gsjax.slam.run` is the whole SLAM loop with no files: frames in, poses, per-frame outputs and the final map out
# (the same chunked `lax.scan` as `gsjax run`). Here it runs on the built-in synthetic room, a ray-cast scene with
# exact depth and ground-truth poses, with the `cpu` preset, and the estimate is compared with the ground truth.

# %%
import os

import matplotlib.pyplot as plt

from gsjax import slam
from gsjax.camera import invert_transform
from gsjax.config.text import apply_overrides
from gsjax.data import open_sequence
from gsjax.eval import ate_rmse_c2w

TINY = bool(os.environ.get("GSJAX_TUTORIAL_TINY"))
sequence = open_sequence("synthetic", max_frames=6 if TINY else 30, downscale=4 if TINY else 2)
config = slam.preset("cpu", sequence.intrinsics.width)  # the preset's pixel settings at this width
if TINY:  # a few iterations: the test suite checks that the tutorial runs, not how well
    config = apply_overrides(config, {"tracking.iters": "3", "tracking.strided_iters": "0", "mapping.iters": "2",
                                      "mapping.strided_iters": "0"})
frames = [sequence.read_host(i) for i in range(len(sequence))]
result = slam.run(frames, config, sequence.intrinsics, chunk=3 if TINY else 8)
print(f"{len(frames)} frames at {sequence.intrinsics.width}x{sequence.intrinsics.height}: "
      f"{int(result.state.gaussians.num_active())} Gaussians, {int(result.state.keyframes.count)} keyframes")

# %% [markdown]
# The estimate is in the first camera's frame; the ATE aligns it rigidly onto the ground truth first (as evo does).

# %%
_, gt_c2w, valid = sequence.gt_trajectory()
est_c2w = invert_transform(result.w2c)
ate = ate_rmse_c2w(est_c2w, gt_c2w, valid)
print(f"ATE RMSE {100 * ate.value_m:.2f} cm over {int(ate.used.sum())} frames")

aligned = ate.alignment.apply_points(est_c2w[ate.used, :3, 3])
plt.figure(figsize=(4, 4))
plt.plot(gt_c2w[:, 0, 3], gt_c2w[:, 2, 3], "k-", label="ground truth")
plt.plot(aligned[:, 0], aligned[:, 2], "o-", ms=3, label="gsjax")
plt.xlabel("x (m)")
plt.ylabel("z (m)")
plt.axis("equal")
plt.legend()
plt.title("camera centres, top view")
plt.show()

# %%
plt.figure(figsize=(6, 2.5))
plt.plot(result.outputs.tracking_loss, label="tracking loss")
plt.plot(result.outputs.mapping_loss, label="mapping loss")
plt.xlabel("frame")
plt.legend()
plt.show()
