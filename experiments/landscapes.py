"""Basins of the tracker on real frames: CB-KNN ``off`` and ``paper`` beside the classic ways to widen a photometric
basin, image-space smoothing (``blur``) and coarse-to-fine tracking (``pyramid``), at the cpu preset's 80x60.

    python experiments/landscapes.py --work /work/gsjax_study/landscapes --sequence 7scenes --frames 10,25,40,55
    python experiments/landscapes.py --work /work/gsjax_study/landscapes --sequence replica --frames 1,2,3

Each frame is one ``gsjax landscape --grid2d`` over two axes (default tx x ry; map from SLAM over the frames before
it, or with ``--map-from gt`` at their GT poses; reference = the GT pose): along each axis and over their plane, the
tracker is run from every grid point and counts as converged within 0.5 cm / 0.5 deg, of the reference (``basin``)
and of its own fixed point (``basin_fixed``, where it ends when started at the reference: the basin without the
map's bias). Writes ``experiments/results/landscapes_SEQUENCE.csv`` (per frame, mode and axis or plane: the basins,
for the plane the normalised radius and the converged share, the fixed point's distance from the reference, the
seconds per mode), ``landscapes_SEQUENCE_paired.csv`` (each mode - off over the frames: mean, bootstrap and t
intervals) and ``landscapes_SEQUENCE.png`` (basin_fixed per mode and frame). An existing landscape in ``--work`` is
reused.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
from studies import RESULTS, ROOT, SEQUENCES, paired_rows, write_result_csv

MODES = "off,paper,blur,pyramid"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--sequence", default="7scenes", choices=list(SEQUENCES))
    parser.add_argument("--frames", default="10,25,40,55")
    parser.add_argument("--axes", default="tx,ry")
    parser.add_argument("--steps", default="11")
    parser.add_argument("--extent-cm", default="3")
    parser.add_argument("--extent-deg", default="3")
    parser.add_argument("--modes", default=MODES)
    parser.add_argument("--map-from", default="slam", choices=("slam", "gt"))
    args = parser.parse_args()
    suffix = "" if args.map_from == "slam" else "_gt"
    commands, docs = [], {}
    for frame in [int(f) for f in args.frames.split(",")]:
        out = args.work / f"{args.sequence}_frame{frame:04d}{suffix}"
        command = [sys.executable, "-m", "gsjax", "landscape", "--out", str(out), *SEQUENCES[args.sequence],
                   "--frame", str(frame), "--axes", args.axes, "--steps", args.steps, "--extent-cm", args.extent_cm,
                   "--extent-deg", args.extent_deg, "--map-from", args.map_from, "--modes", args.modes, "--grid2d"]
        commands.append("gsjax " + shlex.join(command[3:]))
        if not (out / "landscape.json").is_file():
            print("running:", commands[-1], flush=True)
            subprocess.run(command + (["--overwrite"] if out.exists() else []), check=True, cwd=ROOT)
        docs[frame] = json.loads((out / "landscape.json").read_text())
    table = []
    for frame, doc in docs.items():
        for mode in doc["modes"]:
            fixed, seconds = doc["fixed_point"][mode], doc["timings_s"][f"{mode}_s"]
            common = dict(frame=frame, mode=mode, fixed_point_cm=fixed["error_cm"], fixed_point_deg=fixed["error_deg"],
                          seconds=seconds)
            for axis, entry in doc["axes"].items():
                table.append(dict(common, where=axis, unit=entry["unit"], basin=entry[mode]["basin"],
                                  basin_fixed=entry[mode]["basin_fixed"], area="", area_fixed=""))
            plane = doc["grid2d"][mode]
            table.append(dict(common, where=" x ".join(doc["grid2d"]["axes"]), unit="fraction of the extent",
                              basin=plane["basin"], basin_fixed=plane["basin_fixed"], area=plane["area"],
                              area_fixed=plane["area_fixed"]))
    columns = ["frame", "mode", "where", "unit", "basin", "basin_fixed", "area", "area_fixed", "fixed_point_cm",
               "fixed_point_deg", "seconds"]
    rounded = [{k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()} for row in table]
    name = f"landscapes_{args.sequence}{suffix}"
    write_result_csv(RESULTS / f"{name}.csv", rounded, columns, commands)
    paired = paired_against_off(table)
    if paired:
        write_result_csv(RESULTS / f"{name}_paired.csv", paired, list(paired[0]), commands)
    plot(table, RESULTS / f"{name}.png", args.sequence)


def paired_against_off(table: list[dict]) -> list[dict]:
    """Each mode - off over the frames (the pairs), per axis or plane, for basin_fixed and (plane) area_fixed
    (:func:`studies.paired_rows`)."""
    out = []
    for metric in ("basin_fixed", "area_fixed"):
        rows = [r for r in table if metric == "basin_fixed" or " x " in r["where"]]
        for mode in dict.fromkeys(r["mode"] for r in rows if r["mode"] != "off"):
            out += paired_rows(rows, ["where"], metric, a="off", b=mode, label="mode", pair="frame")
    return [{k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()} for row in out]


def plot(table: list[dict], path: Path, sequence: str) -> None:
    """basin_fixed per mode (bars) for each axis and the plane (panels), one bar group per frame."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    places = list(dict.fromkeys(r["where"] for r in table))
    modes = list(dict.fromkeys(r["mode"] for r in table))
    frames = list(dict.fromkeys(r["frame"] for r in table))
    fig = Figure(figsize=(4.2 * len(places), 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    width = 0.8 / len(modes)
    for j, place in enumerate(places):
        ax = fig.add_subplot(1, len(places), j + 1)
        for k, mode in enumerate(modes):
            values = [next(r["basin_fixed"] for r in table if (r["where"], r["mode"], r["frame"]) == (place, mode, f))
                      for f in frames]
            ax.bar(np.arange(len(frames)) + (k - (len(modes) - 1) / 2) * width, values, width, label=mode)
        unit = next(r["unit"] for r in table if r["where"] == place)
        ax.set_xticks(np.arange(len(frames)), [f"frame {f}" for f in frames], fontsize=7)
        ax.set_ylabel(f"basin to the fixed point ({unit})", fontsize=8)
        ax.set_title(f"{sequence}: {place}", fontsize=9)
        ax.grid(True, axis="y", linewidth=0.3)
        ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
