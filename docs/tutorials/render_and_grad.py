# %% [markdown]
# # Render Gaussians and differentiate a camera pose
#
# `gsjax.raster.render` is a pure JAX function of the map, the pose and the camera: it jits, it vmaps, and
# `jax.grad` reaches the pose. Here a few hundred random Gaussians are rendered, then the camera is moved along its
# x axis and the gradient of a photometric loss with respect to the pose's tangent (a left perturbation,
# `se3_exp(delta) @ w2c`) points back to where the picture was taken.

# %%
import os

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from gsjax.camera import make_intrinsics, se3_exp
from gsjax.gaussians import Gaussians
from gsjax.raster import render

TINY = bool(os.environ.get("GSJAX_TUTORIAL_TINY"))  # the test suite runs every tutorial at a tiny size
width, height = (32, 24) if TINY else (160, 120)
camera = make_intrinsics(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, height, width)

rng = np.random.default_rng(0)
n = 60 if TINY else 600
means = np.stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-0.9, 0.9, n), rng.uniform(2.5, 4.0, n)], axis=1)
gaussians = Gaussians.create(means, rgb=rng.uniform(0.0, 1.0, (n, 3)), scales=0.08, opacities=0.8)
w2c = jnp.eye(4)

picture = render(gaussians, w2c, camera)
fig, axes = plt.subplots(1, 2, figsize=(8, 3))
axes[0].imshow(np.clip(np.asarray(picture.color), 0, 1))
axes[0].set_title("colour")
axes[1].imshow(np.asarray(picture.depth), cmap="viridis")
axes[1].set_title("depth (m)")
for ax in axes:
    ax.axis("off")
plt.show()

# %% [markdown]
# The loss compares a render at a perturbed pose with the picture. Its gradient with respect to the translation
# along x is positive for a positive offset and negative for a negative one: gradient descent moves the camera
# back. A central finite difference agrees with `jax.grad`.

# %%
target = picture.color


def loss(delta):
    return jnp.mean((render(gaussians, se3_exp(delta) @ w2c, camera).color - target) ** 2)


loss_and_grad = jax.jit(jax.value_and_grad(loss))
offsets = np.linspace(-0.05, 0.05, 5 if TINY else 11)
values, slopes = [], []
for dx in offsets:
    value, grad = loss_and_grad(jnp.array([dx, 0, 0, 0, 0, 0], jnp.float32))
    values.append(float(value))
    slopes.append(float(grad[0]))

step = 1e-3
at = jnp.array([0.02, 0, 0, 0, 0, 0], jnp.float32)
finite = (loss(at.at[0].add(step)) - loss(at.at[0].add(-step))) / (2 * step)
print(f"d loss / d tx at 2 cm: jax.grad {float(loss_and_grad(at)[1][0]):.5f}, finite difference {float(finite):.5f}")

fig, axes = plt.subplots(1, 2, figsize=(8, 3))
axes[0].plot(100 * offsets, values, "o-")
axes[0].set_xlabel("camera offset along x (cm)")
axes[0].set_ylabel("loss")
axes[1].plot(100 * offsets, slopes, "o-")
axes[1].axhline(0, color="grey", lw=0.5)
axes[1].set_xlabel("camera offset along x (cm)")
axes[1].set_ylabel("d loss / d tx")
plt.tight_layout()
plt.show()
