# %% [markdown]
# # A sweep over CB-KNN's alpha, read back as a table
#
# `gsjax sweep` runs a grid of configs over one sequence. Fields that are traced (learning rates, loss weights,
# CB-KNN's alpha, K0 and beta) share one compiled program, so the grid costs one compilation; each config's run
# folder and one row of `sweep.csv` come out. Here CB-KNN in `paper` mode (smoothed keyframe renders) at three
# values of alpha (the shift toward the neighbours' centroid, px) on the synthetic room with sensor noise.

# %%
import csv
import os
import tempfile
from pathlib import Path

from gsjax.app.cli import main

TINY = bool(os.environ.get("GSJAX_TUTORIAL_TINY"))
out = Path(tempfile.mkdtemp()) / "sweep"
tiny = ["--chunk", "3", "--tracking.iters", "3", "--tracking.strided_iters", "0", "--mapping.iters", "2",
        "--mapping.strided_iters", "0"] if TINY else []  # the test suite's tiny program
alphas = "0.1,0.4" if TINY else "0.1,0.2,0.4"
status = main(["sweep", "--dataset", "synthetic", "--synthetic-noise", "--downscale", "4" if TINY else "2",
               "--max-frames", "6" if TINY else "12", "--cbknn", "paper", "--grid", f"cbknn.params.alpha={alphas}",
               "--out", str(out), "--no-progress", *tiny])
assert status == 0

# %% [markdown]
# `sweep.csv` has a row per config: the swept values, the trajectory and render metrics, its run folder.

# %%
with open(out / "sweep.csv", newline="") as file:
    rows = list(csv.DictReader(file))
columns = ["cbknn.params.alpha", "ate_rmse_cm", "psnr_db", "run"]
print(" | ".join(columns))
for row in rows:
    print(" | ".join(row[c] for c in columns))

# %%
import matplotlib.pyplot as plt  # noqa: E402

plt.figure(figsize=(4, 3))
plt.plot([float(r["cbknn.params.alpha"]) for r in rows], [float(r["ate_rmse_cm"]) for r in rows], "o-")
plt.xlabel("alpha (px)")
plt.ylabel("ATE RMSE (cm)")
plt.title("CB-KNN paper mode, noisy synthetic room")
plt.show()
