"""Tracking-loss landscapes on several 7-Scenes frames: basin widths and slopes of CB-KNN ``off`` vs ``paper``.

    python experiments/landscapes.py --work /tmp/gsjax_landscapes --frames 10,25,40 --axes tx,tz,ry

Each frame is one `gsjax landscape` (map from SLAM over the frames before it, or with ``--map-from gt`` at their GT
poses; reference = the GT pose). Writes ``experiments/results/landscapes.csv`` (``landscapes_gt.csv`` for GT maps;
per frame, axis and mode: basin width, loss and |gradient| at the grid's ends, the loss's minimum offset) and
``landscapes.png`` (every frame's loss curves, normalised per frame).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
from studies import RESULTS, ROOT, SEQUENCES, write_result_csv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--frames", default="10,25,40")
    parser.add_argument("--axes", default="tx,tz,ry")
    parser.add_argument("--steps", default="13")
    parser.add_argument("--extent-cm", default="3")
    parser.add_argument("--extent-deg", default="3")
    parser.add_argument("--sequence", default="7scenes", choices=list(SEQUENCES))
    parser.add_argument("--map-from", default="slam", choices=("slam", "gt"))
    args = parser.parse_args()
    suffix = "" if args.map_from == "slam" else "_gt"
    commands, docs = [], {}
    for frame in [int(f) for f in args.frames.split(",")]:
        out = args.work / f"{args.sequence}_frame{frame:04d}{suffix}"
        command = [sys.executable, "-m", "gsjax", "landscape", "--out", str(out), *SEQUENCES[args.sequence],
                   "--frame", str(frame), "--axes", args.axes, "--steps", args.steps, "--extent-cm", args.extent_cm,
                   "--extent-deg", args.extent_deg, "--map-from", args.map_from]
        commands.append("gsjax " + shlex.join(command[3:]))
        if not (out / "landscape.json").is_file():
            print("running:", commands[-1], flush=True)
            subprocess.run(command + (["--overwrite"] if out.exists() else []), check=True, cwd=ROOT)
        docs[frame] = json.loads((out / "landscape.json").read_text())
    table = []
    for frame, doc in docs.items():
        for axis, entry in doc["axes"].items():
            offsets = np.asarray(entry["offsets"])
            for mode in ("off", "paper"):
                loss, grad = np.asarray(entry[mode]["loss"]), np.asarray(entry[mode]["grad"])
                table.append(dict(frame=frame, axis=axis, unit=entry["unit"], mode=mode, basin=entry[mode]["basin"],
                                  argmin=float(offsets[np.argmin(loss)]), loss_at_0=float(np.interp(0, offsets, loss)),
                                  loss_rise_at_ends=float(0.5 * (loss[0] + loss[-1]) - loss.min()),
                                  mean_abs_grad=float(np.mean(np.abs(grad)))))
    write_result_csv(RESULTS / f"landscapes{suffix}.csv", table, list(table[0]), commands)
    plot(docs, RESULTS / f"landscapes{suffix}.png")


def plot(docs: dict, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    axes = list(next(iter(docs.values()))["axes"])
    fig = Figure(figsize=(4 * len(axes), 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    for j, axis in enumerate(axes):
        ax = fig.add_subplot(1, len(axes), j + 1)
        for frame, doc in docs.items():
            entry = doc["axes"][axis]
            for mode, style in (("off", "-"), ("paper", "--")):
                loss = np.asarray(entry[mode]["loss"])
                ax.plot(entry["offsets"], loss / loss.min(), style, linewidth=1,
                        label=f"frame {frame} {mode} (basin {entry[mode]['basin']:g})")
        ax.set_xlabel(f"{axis} ({docs[next(iter(docs))]['axes'][axis]['unit']})")
        ax.set_ylabel("tracking loss / its minimum")
        ax.grid(True, linewidth=0.3)
        ax.legend(fontsize=6)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
