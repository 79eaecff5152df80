"""A long run of the synthetic scene: memory, time per frame, Gaussian count and checkpoint cost every 100 frames.

    python experiments/long_run.py --frames 1000 --work /tmp/gsjax_long [--downscale 4]

Runs ``gsjax run --dataset synthetic --max-frames N --downscale F`` in process (the ``cpu`` preset, default
``--checkpoint-every 8``) and records after each chunk: the process's resident memory (VmRSS) and peak (VmHWM)
from ``/proc/self/status``, the wall time of the frames since the last mark, active Gaussians and capacity, each
checkpoint's seconds and bytes written, and the checkpoint directory's size. Writes
``experiments/results/long_run.json``. The measurement is :func:`long_run` below, which
``tests/app/test_slow_long_run.py`` imports and asserts on.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
from pathlib import Path


def _status_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # not Linux: the peak is what there is


def long_run(frames: int, work: Path, downscale: int = 4, every: int = 100, checkpoint_every: int = 8,
             overrides: dict | None = None) -> dict:
    """Run SLAM on ``frames`` synthetic frames into ``work`` (overwritten); return the measurement.

    ``overrides``: dotted config overrides (e.g. tiny iteration counts for a quick memory check)."""
    from gsjax.app.run_folder import checkpoints as checkpoint
    from gsjax.app.run_folder.checkpoints import checkpoint_bytes
    from gsjax.app.runtime.cache import enable_compilation_cache
    from gsjax.app.session.runner import RunOptions, run_slam
    from gsjax.config.text import apply_overrides
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
    from gsjax.slam.presets import preset

    enable_compilation_cache()
    base = SyntheticConfig(num_frames=frames)
    sequence = synthetic_sequence(SyntheticConfig(width=base.width // downscale, height=base.height // downscale,
                                                  num_frames=frames))
    config = apply_overrides(preset("cpu", sequence.intrinsics.width), overrides or {})
    options = RunOptions(out=Path(work), progress=False, overwrite=True, checkpoint_every=checkpoint_every)
    saves: list[dict] = []
    save = checkpoint.Checkpoints.save

    def timed_save(self, state, ledger, *args):
        t0 = time.perf_counter()
        written = save(self, state, ledger, *args)
        saves.append(dict(frames_done=ledger.frames_done, seconds=time.perf_counter() - t0, bytes=written,
                          capacity=int(state.gaussians.capacity)))
        return written

    marks: list[dict] = []
    last = dict(frames=0, time=time.perf_counter())

    def on_chunk(done: int) -> None:
        if done // every == last["frames"] // every and done != frames:
            return
        now = time.perf_counter()
        marks.append(dict(frames=done, rss_mib=_status_kib("VmRSS") / 1024, peak_rss_mib=_status_kib("VmHWM") / 1024,
                          s_per_frame=(now - last["time"]) / (done - last["frames"]),
                          checkpoint_dir_mib=checkpoint_bytes(Path(work) / "checkpoints") / 2**20,
                          last_checkpoint_kib=saves[-1]["bytes"] / 1024 if saves else None,
                          last_checkpoint_s=saves[-1]["seconds"] if saves else None))
        last.update(frames=done, time=now)
        print(json.dumps(marks[-1]), flush=True)

    checkpoint.Checkpoints.save = timed_save
    try:
        metrics = run_slam(sequence, config, options, describe=dict(dataset="synthetic"), on_chunk=on_chunk)
    finally:
        checkpoint.Checkpoints.save = save
    stored = checkpoint.Checkpoints(Path(work) / "checkpoints")
    try:
        per_frame = {name: values.tolist() for name, values in stored.outputs(frames)._asdict().items()}
    finally:
        stored.close()
    return dict(frames=frames, width=sequence.intrinsics.width, height=sequence.intrinsics.height,
                marks=marks, checkpoints=saves, ate_cm=metrics.ate_cm,
                constant_pose_cm=metrics.constant_pose_ate_rmse_c2w_cm, psnr_db=metrics.psnr_db,
                capacity=metrics.capacity,
                initial_capacity=2 * sequence.intrinsics.width * sequence.intrinsics.height,
                num_gaussians=metrics.num_gaussians, retried_frames=metrics.retried_frames,
                diverged_frames=metrics.diverged_frames, nonfinite_gaussians=metrics.nonfinite_gaussians,
                seconds_per_frame=metrics.seconds_per_frame, keyframes=metrics.keyframes,
                gaussians_per_100=per_frame["num_gaussians"][every - 1::every],
                max_gaussians=max(per_frame["num_gaussians"]), max_added=max(per_frame["added"]),
                all_poses_finite=bool(all(map(math.isfinite, (x for m in per_frame["w2c"] for r in m for x in r)))))


ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--downscale", type=int, default=4)
    parser.add_argument("--checkpoint-every", type=int, default=8)
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a config override")
    parser.add_argument("--result", type=Path, default=RESULTS / "long_run.json")
    parser.add_argument("--work", type=Path, required=True)
    args = parser.parse_args(argv)
    overrides = dict(item.split("=", 1) for item in args.set)
    result = long_run(args.frames, args.work, args.downscale, checkpoint_every=args.checkpoint_every,
                      overrides=overrides)
    result["command"] = " ".join(["python", "experiments/long_run.py", *(argv or sys.argv[1:])])
    path = args.result
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
