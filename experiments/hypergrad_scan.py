"""One field scanned with whole SLAM runs, its window hypergradient taken along the scan (issue 49).

    python experiments/hypergrad_scan.py                # lr_trans over +-20 %: the 80x60 expected failure's setting
    python experiments/hypergrad_scan.py --variants     # where in SLAM the runs and the derivative part
    python experiments/hypergrad_scan.py --map-step 10,30  # one step's map against the pose it is given

The setting is the slow suite's 80x60 room (``tests/slam/test_hypergrad.py``'s ``room80``): the noisy synthetic
room's first 4 frames at 80x60, the ``cpu`` preset with CB-KNN ``paper``, Adam at a tenth of the learning rates and
10 iterations on every pixel (the 30 strided ones kept), sensor noise only. There the ``unrolled`` ``window``
derivative of the residual with respect to ``tracking.lr_trans`` has the other sign than the runs' differences.

The scan records a whole run at ``v (1 + s)`` for each ``s`` on a grid (``--span``, ``--points``) and takes both
objectives and the frames' densified counts, keyframes and tracking iterations (the run's discrete decisions a
derivative cannot see), the ``window`` and ``frame`` derivatives at every ``--every``-th point, and central
differences at tiny steps (1e-6 to 1e-3). ``--variants`` changes one part of SLAM at a time (``VARIANTS``) and
compares the runs' differences at 5 / 10 / 20 % with the derivatives at ``v``. ``--map-step N,...`` isolates the
map's share: frame 1's step (densification and ``N`` mapping iterations) given its recorded pose moved by ``t`` along
each of the six tangent axes, and frame 2's residual at its recorded pose rendered from that map; its derivative
(forward mode, the hypergradient's program) against the least-squares slope of 21 values of ``t`` in +-0.5 mm
(mrad). Results accumulate in ``--out`` (a JSON file; a rerun computes only what it lacks).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from hypergrad_check import NOISE

from gsjax.config.paths import differentiable_entry, replace_path
from gsjax.config.text import apply_overrides
from gsjax.data import open_sequence
from gsjax.io.atomic import atomic_write_json
from gsjax.slam import hypergrad
from gsjax.slam.presets import preset, with_cbknn_mode

SMOOTH = {"tracking.iters": "10", "tracking.lr_trans": "2e-4", "tracking.lr_rot": "2e-4"}
VARIANTS = {
    "as is": {},
    "CB-KNN off": {"cbknn.mode": "off"},
    "contributors chosen at every iteration": {"tracking.reselect_every": "1", "mapping.reselect_every": "1"},
    "mapping 10 iterations": {"mapping.iters": "10"},
    "mapping 20 iterations": {"mapping.iters": "20"},
    "1 cm map noise": NOISE,
}
TINY = (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3)
STEPS = (0.05, 0.1, 0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--field", default="tracking.lr_trans")
    parser.add_argument("--span", type=float, default=0.2, help="the scan's relative half-width")
    parser.add_argument("--points", type=int, default=41, help="runs on the scan's grid")
    parser.add_argument("--every", type=int, default=5, help="a derivative at every this many grid points")
    parser.add_argument("--variants", action="store_true", help="the variants instead of the scan")
    parser.add_argument("--map-step", default="", help="mapping iteration counts: one step's map against its pose")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "hypergrad_scan_80x60_4f.json")
    args = parser.parse_args()

    sequence = open_sequence("synthetic", max_frames=4, downscale=2, sensor_noise=True)
    intrinsics = sequence.intrinsics
    frames = [sequence.read_host(i) for i in range(len(sequence))]
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    key = args.field
    start = time.time()

    def save() -> None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out, results, indent=1)

    def config_of(overrides: dict[str, str]):
        mode = overrides.get("cbknn.mode", "paper")
        rest = {k: v for k, v in overrides.items() if k != "cbknn.mode"}
        return apply_overrides(with_cbknn_mode(preset("cpu", intrinsics.width), mode), {**SMOOTH, **rest})

    def run(config, value: float, s: float):
        """(the run's objectives and discrete decisions, its window, its config) at ``value (1 + s)``."""
        moved = replace_path(config, key, value * (1 + s))
        window = hypergrad.record(frames, moved, intrinsics)
        out = window.outputs
        summary = {"residual": hypergrad.objective_value(window, moved, intrinsics, "residual"),
                   "ate": hypergrad.objective_value(window, moved, intrinsics, "ate"),
                   "added": np.asarray(out.added).tolist(), "keyframe": np.asarray(out.keyframe).astype(int).tolist(),
                   "tracking_iters": np.asarray(out.tracking_iters).tolist()}
        return summary, window, moved

    def derivatives(window, config, value: float, s: float) -> dict:
        out = {}
        for truncation in ("window", "frame"):
            result = hypergrad.hypergradient(window, config, intrinsics, (key,), objective="residual",
                                             truncation=truncation)
            out[truncation] = value * (1 + s) * result.gradient[key]  # v dJ/dv at v (1 + s), as the runs' differences
        return out

    if args.map_step:
        steps = results.setdefault("map_step", {})
        for iters in args.map_step.split(","):
            if iters not in steps:
                steps[iters] = map_step(frames, intrinsics, config_of({"mapping.iters": iters}))
                print(f"mapping {iters} iterations: {steps[iters]} ({time.time() - start:.0f} s)", flush=True)
                save()
        print(map_step_table(steps))
        return
    if not args.variants:
        config = config_of({})
        value = float(differentiable_entry(config, key).value)
        scan = results.setdefault("scan", {}).setdefault(key, {"runs": {}, "derivatives": {}, "tiny": {}})
        grid = np.round(np.linspace(-args.span, args.span, args.points), 6)
        for i, s in enumerate(grid):
            name = f"{s:+.4f}"
            wanted = i % args.every == 0 or i == len(grid) - 1
            if name in scan["runs"] and (not wanted or name in scan["derivatives"]):
                continue
            scan["runs"][name], window, moved = run(config, value, float(s))
            if wanted:
                scan["derivatives"][name] = derivatives(window, moved, value, float(s))
            print(f"s {name}: {scan['runs'][name]['residual']:.7f} {scan['derivatives'].get(name, '')} "
                  f"({time.time() - start:.0f} s)", flush=True)
            save()
        for h in TINY:
            if f"{h:g}" not in scan["tiny"]:
                ends = [run(config, value, sign * h)[0]["residual"] for sign in (1, -1)]
                scan["tiny"][f"{h:g}"] = (ends[0] - ends[1]) / (2 * h)
                save()
        print(scan_table(scan))
        return
    variants = results.setdefault("variants", {}).setdefault(key, {})
    for name, overrides in VARIANTS.items():
        if name in variants:
            continue
        config = config_of(overrides)
        value = float(differentiable_entry(config, key).value)
        base, window, _ = run(config, value, 0.0)
        ends = {s: [run(config, value, sign * s)[0]["residual"] for sign in (1, -1)] for s in STEPS}
        variants[name] = {"overrides": overrides, "residual": base["residual"],
                          "runs": {f"{s:g}": (a - b) / (2 * s) for s, (a, b) in ends.items()},
                          **derivatives(window, config, value, 0.0)}
        print(name, variants[name], f"({time.time() - start:.0f} s)", flush=True)
        save()
    print(variants_table(variants))


def map_step(frames, intrinsics, config, frame: int = 1, half: float = 5e-4, points: int = 21) -> dict:
    """{axis: (derivative, least-squares slope, scatter)} of frame ``frame + 1``'s residual with respect to the pose
    frame ``frame``'s step is given, along each tangent axis (translations m, rotations rad; ``--map-step``)."""
    import jax
    import jax.numpy as jnp

    from gsjax.camera import perturb_left
    from gsjax.slam.system import sanitize_frame, step
    from gsjax.slam.tracking import GuardedTrack

    window = hypergrad.record(frames, config, intrinsics)
    at = lambda tree, i: jax.tree_util.tree_map(lambda x: x[i], tree)  # noqa: E731
    state, given, recorded = at(window.states, frame), at(window.frames, frame), at(window.outputs, frame)
    following, target = sanitize_frame(at(window.frames, frame + 1)), at(window.outputs, frame + 1).w2c
    differentiable = hypergrad.hypergradient_config(config, "unrolled", "window", "forward")

    def residual(delta, cfg):
        pose = perturb_left(delta, recorded.w2c)
        track = lambda problem, previous: GuardedTrack(  # noqa: E731
            pose, recorded.tracking_loss, recorded.nonfinite, recorded.retried, recorded.diverged,
            recorded.tracking_iters)
        mapped, _ = step(state, given, cfg, intrinsics, track=track)
        return hypergrad._held_out_residual(mapped, following, target, intrinsics, cfg.raster)

    value = jax.jit(lambda d: residual(d, config))
    out = {}
    for axis, name in enumerate(("tx", "ty", "tz", "rx", "ry", "rz")):
        e = jnp.zeros(6).at[axis].set(1.0)
        _, tangent = jax.jit(lambda d, e=e: jax.jvp(lambda x: residual(x, differentiable), (d,), (e,)))(jnp.zeros(6))
        t = np.linspace(-half, half, points)
        values = np.array([float(value(x * e)) for x in t])
        fit = np.polyfit(t, values, 1)
        out[name] = [float(tangent), float(fit[0]), float(np.std(values - np.polyval(fit, t)))]
    return out


def map_step_table(steps: dict) -> str:
    lines = ["| mapping iterations | axis | derivative | runs' slope | scatter |", "|---|---|---|---|---|"]
    for iters, axes in steps.items():
        for name, (d, slope, scatter) in axes.items():
            lines.append(f"| {iters} | {name} | {d:+.4f} | {slope:+.4f} | {scatter:.1e} |")
    return "\n".join(lines)


def scan_table(scan: dict) -> str:
    """Markdown: the derivative at each point against the runs' least-squares slope over the scan."""
    s = np.array(sorted(float(k) for k in scan["runs"]))
    residual = np.array([scan["runs"][f"{x:+.4f}"]["residual"] for x in s])
    slope, intercept = np.polyfit(s, residual, 1)
    lines = [f"runs: least-squares slope {slope:+.5f} over s in [{s[0]:+.2f}, {s[-1]:+.2f}] ({len(s)} runs), "
             f"scatter about it {np.std(residual - (slope * s + intercept)):.2e}; "
             f"J({s[-1]:+.2f}) - J({s[0]:+.2f}) = {residual[-1] - residual[0]:+.2e}",
             "", "| s | J | window v dJ/dv | frame v dJ/dv |", "|---|---|---|---|"]
    for k in sorted(scan["derivatives"], key=float):
        d = scan["derivatives"][k]
        lines.append(f"| {k} | {scan['runs'][k]['residual']:.6f} | {d['window']:+.5f} | {d['frame']:+.5f} |")
    lines += ["", "central differences at tiny steps: " + ", ".join(
        f"{h}: {v:+.4f}" for h, v in scan["tiny"].items())]
    return "\n".join(lines)


def variants_table(variants: dict) -> str:
    lines = ["| variant | runs 5 % | runs 10 % | runs 20 % | window | frame |", "|---|---|---|---|---|---|"]
    for name, v in variants.items():
        runs = " | ".join(f"{v['runs'][f'{s:g}']:+.5f}" for s in STEPS)
        lines.append(f"| {name} | {runs} | {v['window']:+.5f} | {v['frame']:+.5f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
