# %% [markdown]
# # A loss landscape and its basin, with jax.grad
#
# Tracking minimises a photometric and depth loss over the camera pose with the map held fixed. Moving the pose
# away from where SLAM put it and evaluating the loss (and its gradient, by `jax.grad` through the renderer) draws
# the landscape the tracker descends; starting the tracker itself from each offset shows its basin: the offsets
# from which it returns (within 0.5 cm and 0.5 degrees). `gsjax landscape` does the same from the command line.

# %%
import os

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from gsjax import slam
from gsjax.config.text import apply_overrides
from gsjax.data import open_sequence
from gsjax.frame import to_device
from gsjax.slam.landscape import basin_width, converged, directions, landscape
from gsjax.slam.system import tracking_problem

TINY = bool(os.environ.get("GSJAX_TUTORIAL_TINY"))
frame, chunk = (5, 3) if TINY else (10, 8)
sequence = open_sequence("synthetic", max_frames=frame + 1, downscale=4 if TINY else 2)
config = slam.preset("cpu", sequence.intrinsics.width)
if TINY:
    config = apply_overrides(config, {"tracking.iters": "3", "tracking.strided_iters": "0", "mapping.iters": "2",
                                      "mapping.strided_iters": "0"})
frames = [sequence.read_host(i) for i in range(frame + 1)]
built = slam.run(frames[:frame], config, sequence.intrinsics, chunk=chunk)  # the map of the frames before
reference = slam.run(frames, config, sequence.intrinsics, chunk=chunk).w2c[frame]  # where SLAM puts frame t

target = to_device(frames[frame])
problem = tracking_problem(built.state, target.color, target.depth, config, sequence.intrinsics)
problem = problem._replace(w2c_init=jnp.asarray(reference))

# %% [markdown]
# Offsets along the camera's x axis (cm) and about its y axis (degrees), around the reference pose.

# %%
steps = 5 if TINY else 7
offsets = jnp.stack([jnp.linspace(-3.0, 3.0, steps), jnp.linspace(-3.0, 3.0, steps)])
result = landscape(problem, config, directions(("tx", "ry")), offsets, batch=1)
fig, axes = plt.subplots(1, 2, figsize=(9, 3))
for a, (name, unit) in enumerate((("tx", "cm"), ("ry", "deg"))):
    ok = converged(result.error_cm[a], result.error_deg[a])
    basin = basin_width(np.asarray(offsets[a]), ok)
    axes[a].plot(offsets[a], result.loss[a], "k-")
    axes[a].scatter(offsets[a], result.loss[a], c=np.where(ok, "tab:green", "tab:red"), zorder=3)
    axes[a].set_xlabel(f"offset along {name} ({unit})")
    axes[a].set_title(f"{name}: basin {basin:g} {unit} (green: the tracker returns)")
    print(f"{name}: loss slope (jax.grad) at the ends {float(result.grad[a, 0]):+.1f}, "
          f"{float(result.grad[a, -1]):+.1f} per {unit}; basin {basin:g} {unit}")
axes[0].set_ylabel("tracking loss")
plt.tight_layout()
plt.show()
