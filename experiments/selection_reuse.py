"""How many contributor slots change while one frame is tracked, and what compositing stale slots costs: the
measurement behind ``tracking.reselect_every`` (issue 37).

    python experiments/selection_reuse.py --sequence synthetic_noisy [--frame 16] [--out FILE.json]
    python experiments/selection_reuse.py --sequence 7scenes --path ../shared/data/7scenes_redkitchen

Builds the map of frames 0..T-1 with the ``cpu`` preset (as ``profile_frame.py``), then runs 40 plain Adam
iterations of frame T's tracking on every pixel from the constant-velocity prediction, each choosing its own
contributors, and records the poses. At iterations 1, 2, 5, 10, 20 and 40 it compares the slots chosen there with
those chosen at the start pose: the fraction of slots and of pixels that differ, and the tracking loss and pose
gradient when the start's slots are composited at that pose instead (relative to choosing them there).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

sys.path.insert(0, str(Path(__file__).resolve().parent))
from profile_frame import open_sequence_for

ITERATIONS = (1, 2, 5, 10, 20, 40)


def measure(sequence, config, frame_index: int) -> list[dict]:
    from gsjax import slam
    from gsjax.frame import to_device, without_ground_truth
    from gsjax.slam.optimizers import pose_optimizer
    from gsjax.slam.system import tracking_problem
    from gsjax.slam.tracking import tracking_objective

    frames = [sequence.read_host(i) for i in range(frame_index + 1)]
    state = slam.run(frames[:frame_index], config, sequence.intrinsics, seed=0).state
    frame = to_device(without_ground_truth(frames[frame_index]))
    objective = tracking_objective(tracking_problem(state, frame.color, frame.depth, config, sequence.intrinsics),
                                   config)
    fresh = jax.jit(jax.value_and_grad(objective.loss))
    reused = jax.jit(jax.value_and_grad(objective.loss))  # (delta, selection)
    select = jax.jit(objective.select)
    optimizer = pose_optimizer(config.tracking)  # per-component steps: the tracker's {"rho", "phi"} tangent
    delta = {"rho": jnp.zeros(3, jnp.float32), "phi": jnp.zeros(3, jnp.float32)}
    opt_state = optimizer.init(delta)
    tangent = lambda d: jnp.concatenate([d["rho"], d["phi"]])  # noqa: E731
    poses = [tangent(delta)]
    for _ in range(max(ITERATIONS)):
        _, grad = fresh(poses[-1])
        updates, opt_state = optimizer.update({"rho": grad[:3], "phi": grad[3:]}, opt_state)
        delta = optax.apply_updates(delta, updates)
        poses.append(tangent(delta))
    start = select(poses[0])
    ids0 = np.asarray(start.ids)
    rows = []
    for i in ITERATIONS:
        here = select(poses[i])
        ids = np.asarray(here.ids)
        used = (ids0 >= 0) | (ids >= 0)
        changed = (ids0 != ids) & used
        loss, grad = reused(poses[i], here)
        stale_loss, stale_grad = reused(poses[i], start)
        rows.append(dict(iteration=i, moved_mm=1e3 * float(jnp.linalg.norm(poses[i][:3])),
                         turned_deg=float(jnp.degrees(jnp.linalg.norm(poses[i][3:]))),
                         slots_changed=float(changed.sum() / max(used.sum(), 1)),
                         pixels_changed=float(changed.any(0).mean()),
                         loss_rel_error=float(abs(stale_loss - loss) / loss),
                         grad_rel_error=float(jnp.linalg.norm(stale_grad - grad) / jnp.linalg.norm(grad))))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequence", default="synthetic_noisy", choices=("synthetic", "synthetic_noisy", "7scenes"))
    parser.add_argument("--path", type=Path, default=None)
    parser.add_argument("--frame", type=int, default=16)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    from gsjax.app.runtime.cache import enable_compilation_cache

    enable_compilation_cache()
    sequence, config = open_sequence_for(args.sequence, args.path, args.frame + 1)
    rows = measure(sequence, config, args.frame)
    print(f"{args.sequence}, frame {args.frame}: slots chosen at the start pose, composited later")
    print("iteration | moved mm | turned deg | slots changed | pixels changed | loss rel. error | grad rel. error")
    for r in rows:
        print(f"{r['iteration']:9d} | {r['moved_mm']:8.2f} | {r['turned_deg']:10.3f} | {r['slots_changed']:13.3f} | "
              f"{r['pixels_changed']:14.3f} | {r['loss_rel_error']:15.2e} | {r['grad_rel_error']:15.2e}")
    if args.out:
        args.out.write_text(json.dumps(dict(sequence=args.sequence, frame=args.frame, rows=rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
