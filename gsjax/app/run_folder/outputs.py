"""The end of a run: evaluate the trajectory against every frame with a valid ground-truth pose (both ATE
variants, RPE, a constant-pose baseline), render the evaluation frames with the final map (canonical rendering)
for PSNR / MS-SSIM / SSIM / depth L1 (and CB-KNN's K and rho maps when CB-KNN smooths renders), and write
``trajectory.txt``, ``groundtruth.txt``, ``trajectory.png``, ``renders/``, ``map.ply``, ``report.html`` and, last,
``metrics.json`` atomically; and the summary printed at the end."""

from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.run_folder.run_warnings import run_warnings
from gsjax.camera import invert_transform
from gsjax.config.text import config_to_dict
from gsjax.data.sequence import Sequence
from gsjax.eval.renders import evaluation_frames, frame_render_metrics, render_metrics
from gsjax.eval.run_input import RunInput
from gsjax.eval.run_metrics import CBKNNSummary, RenderMetrics, RunMetrics
from gsjax.eval.trajectory import ate_rmse_c2w, evaluate_trajectory
from gsjax.io import run_folder as folder
from gsjax.io.images import render_panel, save_rgb_png
from gsjax.io.plots import plot_cbknn_maps, plot_trajectory_top_view
from gsjax.io.ply import write_ply
from gsjax.io.trajectory import write_tum_trajectory
from gsjax.raster import render
from gsjax.slam.config import SlamConfig
from gsjax.slam.state import SlamState
from gsjax.slam.system import StepOutputs

if TYPE_CHECKING:
    from gsjax.app.run_folder.checkpoints import CheckpointLedger


class OutputOptions(NamedTuple):
    """Where a run's outputs go and what is rendered for them: the ``out`` folder; render metrics on t = 0 and
    (t + 1) % ``eval_every`` == 0 (SplaTAM's rule); ``samples`` render-vs-input panels in ``renders/``."""

    out: Path
    eval_every: int = 5
    samples: int = 3


def run_record(sequence: Sequence, config: SlamConfig, *, chunk: int, seed: int, describe: dict | None = None,
               frames: int | None = None, sweep: dict | None = None) -> RunInput:
    """What ``config.json`` holds for a run of ``frames`` (default: all) of ``sequence``: ``describe`` (the command's
    account of the input), the size, chunk and seed, the camera (intrinsics at the working resolution, the depth
    files' units per metre), the config as a dict, and a sweep's ``sweep`` entry."""
    k = sequence.intrinsics
    camera = dict(fx=float(k.fx), fy=float(k.fy), cx=float(k.cx), cy=float(k.cy), width=k.width, height=k.height,
                  depth_scale=sequence.depth_scale)
    return RunInput(describe=dict(describe or {}), frames=len(sequence) if frames is None else frames, width=k.width,
                    height=k.height, chunk=chunk, seed=seed, camera=camera, config=config_to_dict(config), sweep=sweep)


def finish_run(sequence: Sequence, config: SlamConfig, options: OutputOptions, state: SlamState, outputs: StepOutputs,
               timings: dict, record: RunInput, *, input_warnings: Iterable[str] = (),
               resume_warnings: Iterable[str] = (), checkpoints: CheckpointLedger | None = None,
               frames: dict | None = None) -> RunMetrics:
    """The one way from a finished run to ``RunMetrics`` and every output file, for ``gsjax run`` and ``gsjax
    sweep``: evaluate it and write ``trajectory.txt``, ``groundtruth.txt`` (when the sequence has ground truth),
    ``trajectory.png``, ``renders/``, ``map.ply``, ``report.html`` and ``metrics.json`` into ``options.out``.

    ``outputs``: the per-frame :class:`gsjax.slam.system.StepOutputs` on the host ([T, ...] numpy arrays);
    ``timings``: stage times (s);
    ``record``: what ``config.json`` holds; ``metrics.json``'s warnings are ``input_warnings`` (what opening the
    sequence reported), the run's own (:func:`gsjax.app.run_folder.run_warnings.run_warnings` of ``outputs``) and
    ``resume_warnings``; ``checkpoints``: the checkpoints the run wrote; ``frames``: host frames the run still
    holds, by index (:func:`gsjax.eval.renders.is_evaluation_frame` ones; the others are read from the sequence again).
    """
    def read(t: int):
        return frames[t] if frames and t in frames else sequence.read_host(t)

    warnings = [*input_warnings, *run_warnings(sequence, config, outputs, read), *resume_warnings]
    return _write_outputs(sequence, config, options, state, outputs, timings, record, warnings, checkpoints, read)


def _write_outputs(sequence: Sequence, config: SlamConfig, options: OutputOptions, state: SlamState,
                   outputs: StepOutputs,
                   timings: dict, record: RunInput, warnings: list[str], checkpoints: CheckpointLedger | None,
                   read) -> RunMetrics:
    """:func:`finish_run` once the warnings are worded; ``read(t)``: frame ``t`` on the host."""
    out = Path(options.out)
    t0 = time.perf_counter()
    timestamps, gt_c2w, gt_valid = sequence.gt_trajectory()
    est_c2w = invert_transform(outputs.w2c)
    # Express the estimate in the dataset's world frame when frame 0 has ground truth (so its numbers can be
    # compared with the dataset's files directly); the SLAM world frame is the first camera.
    anchor = gt_c2w[0] if gt_valid[0] else np.eye(4)
    est_world = anchor @ est_c2w
    write_tum_trajectory(out / folder.TRAJECTORY, timestamps, est_world)
    if gt_valid.any():  # for the report and the viewer; the dataset's own poses, in its world frame
        write_tum_trajectory(out / folder.GROUNDTRUTH, timestamps[gt_valid], gt_c2w[gt_valid])

    trajectory, constant_pose = None, None
    # Every frame with a valid GT pose is evaluated; the rigid alignment absorbs the world frames (the SLAM one is
    # the first camera), so frame 0 needs no ground truth.
    if gt_valid.sum() >= 3:
        trajectory = evaluate_trajectory(timestamps, est_c2w, timestamps, gt_c2w, gt_valid=gt_valid)
        identity = np.broadcast_to(np.eye(4), est_c2w.shape).copy()
        constant_pose = 100 * ate_rmse_c2w(identity, gt_c2w, gt_valid).value_m
        aligned = ate_rmse_c2w(est_c2w, gt_c2w, gt_valid)
        used = aligned.used
        plot_trajectory_top_view(out / folder.TRAJECTORY_PLOT, aligned.alignment.apply_points(est_c2w[used, :3, 3]),
                                 gt_c2w[used, :3, 3],
                                 title=f"{sequence.name}: ATE RMSE {100 * aligned.value_m:.2f} cm")
    else:
        plot_trajectory_top_view(out / folder.TRAJECTORY_PLOT, est_c2w[:, :3, 3], None,
                                 title=f"{sequence.name} (no ground truth)")
    render_metrics, cbknn = _render_metrics(sequence, read, config, options, state, outputs)
    write_ply(out / folder.MAP, state.gaussians)
    timings["outputs_s"] = time.perf_counter() - t0
    slam_frames_per_s = len(est_c2w) / timings["slam_s"] if timings["slam_s"] > 0 else None
    metrics = RunMetrics(
        dataset=record.describe.get("dataset"),
        frames=len(est_c2w),
        width=record.width,
        height=record.height,
        trajectory=trajectory,
        constant_pose_ate_rmse_c2w_cm=constant_pose,
        render=render_metrics,
        cbknn=cbknn,
        frames_per_s=slam_frames_per_s,
        seconds_per_frame=(1.0 / slam_frames_per_s) if slam_frames_per_s else None,
        stage_timings_s=timings,
        num_gaussians=int(state.gaussians.num_active()),
        capacity=int(state.gaussians.capacity),
        keyframes=int(state.keyframes.count),
        nonfinite_tracking_iterations=int(state.nonfinite_tracking),
        nonfinite_mapping_iterations=int(state.nonfinite_mapping),
        frames_with_truncated_render=int(np.sum(outputs.truncated)),
        max_truncation_residual=float(np.max(outputs.truncation_residual)),
        skipped_frames=[int(t) for t in np.flatnonzero(outputs.skipped)],
        retried_frames=[int(t) for t in np.flatnonzero(outputs.retried)],
        diverged_frames=[int(t) for t in np.flatnonzero(outputs.diverged)],
        nonfinite_gaussians=int(state.nonfinite_gaussians),
        checkpoints=checkpoints.summary() if checkpoints is not None else None,
        warnings=list(warnings),
        camera=record.camera,
        config=record.config,
        world_from_map=np.asarray(anchor, np.float64).tolist(),
        keyframe_frames=[int(t) for t in np.flatnonzero(outputs.keyframe)],
        per_frame={name: [_json_number(v) for v in getattr(outputs, name)] for name in PER_FRAME},
    )
    from gsjax.report import write_report

    t0 = time.perf_counter()
    write_report(out, metrics=metrics)
    timings["report_s"] = time.perf_counter() - t0
    folder.write_metrics(out, metrics)
    return metrics


# The per-frame outputs metrics.json keeps (the flags are listed as frame numbers: skipped_frames, ...).
PER_FRAME = ("tracking_loss", "mapping_loss", "num_gaussians", "added", "dropped", "gamma", "tracking_iters",
             "depth_valid")


def _json_number(value):
    """An int as is; a float, or None where it is not finite (JSON has no NaN)."""
    if isinstance(value, (bool, int, np.integer)):
        return int(value)
    return float(value) if np.isfinite(value) else None


# A module-level jit: a sweep's configs (and a process's runs) share one traced and compiled program.
@jax.jit
def _cbknn_stats(gaussians, w2c, intrinsics, settings, params, motion):
    return render(gaussians, w2c, intrinsics, settings, cbknn=params, motion=motion).stats.cbknn


def _render_metrics(sequence, read, config: SlamConfig, options: OutputOptions, state: SlamState,
                    outputs: StepOutputs) -> tuple[RenderMetrics, CBKNNSummary | None]:
    """SplaTAM's rendering metrics (:mod:`gsjax.eval.renders`) on the evaluation frames; ``mean`` is None when no
    frame is left.

    ``options.samples`` of those frames, spread evenly, get a labelled render-vs-input panel in
    ``renders/frame_T.png``; when CB-KNN smooths renders (``paper``), they are also rendered with CB-KNN (the
    frame's own motion gamma) for its diagnostics: K and rho maps in ``renders/cbknn_T.png`` and, returned second,
    their statistics (None otherwise)."""
    frames = evaluation_frames(outputs.skipped, options.eval_every)
    if not frames:
        return RenderMetrics(), None
    samples = set(np.unique(np.linspace(0, len(frames) - 1, min(options.samples, len(frames))).round().astype(int)))
    smoothing = config.cbknn.smooth_renders
    params = config.cbknn.params
    per_frame, diagnostics = [], []
    (Path(options.out) / folder.RENDERS).mkdir(parents=True, exist_ok=True)
    for position, t in enumerate(frames):
        frame = read(t)
        out, values = frame_render_metrics(state.gaussians, outputs.w2c[t], sequence.intrinsics, config.raster,
                                           frame.color, frame.depth)
        per_frame.append(values)
        if position not in samples:
            continue
        panel = render_panel(np.asarray(out.color), frame.color, np.asarray(out.depth), frame.depth)
        save_rgb_png(folder.render_panel(options.out, t), panel)
        if smoothing:
            gamma = float(outputs.gamma[t])
            stats = jax.device_get(_cbknn_stats(state.gaussians, jnp.asarray(outputs.w2c[t], jnp.float32),
                                                sequence.intrinsics, config.raster, params, jnp.float32(gamma)))
            diagnostics.append(_cbknn_sample(stats, t, gamma, params.cell, folder.cbknn_panel(options.out, t)))
    cbknn = None
    if smoothing:
        cbknn = CBKNNSummary(mode=config.cbknn.mode, alpha=float(params.alpha), k0=float(params.k0),
                             beta=float(params.beta), cell=params.cell, samples=diagnostics)
    return render_metrics(frames, per_frame), cbknn


def _cbknn_sample(stats, frame: int, gamma: float, cell: int, path: Path) -> dict:
    """One sample frame's CB-KNN statistics (:class:`gsjax.raster.cbknn.CBKNNStats` on the host), and its K and rho
    maps plotted to ``path``."""
    k_map, rho_map = np.asarray(stats.k_map), np.asarray(stats.rho_map)
    entry = dict(frame=frame, gamma=gamma, k_mean=float(k_map.mean()), k_min=int(k_map.min()), k_max=int(k_map.max()),
                 rho_max=float(rho_map.max()), empty_cells=float(np.mean(rho_map == 0)),
                 mean_shift_px=float(stats.mean_shift_px), fraction_fewer_than_k=float(stats.fraction_fewer_than_k))
    plot_cbknn_maps(path, k_map, rho_map, cell,
                    title=f"frame {frame}: gamma {gamma:.2f}, mean K {entry['k_mean']:.2f}, mean shift "
                          f"{entry['mean_shift_px']:.3f} px, {100 * entry['fraction_fewer_than_k']:.0f}% of pixels "
                          "with fewer contributors than K")
    return entry


def summary_lines(metrics: RunMetrics, out: Path) -> list[str]:
    """A short human summary of a finished run."""
    lines = []
    traj = metrics.trajectory
    if traj:
        lines.append(f"ATE RMSE (camera centres) {traj.ate_rmse_c2w_cm:.2f} cm; SplaTAM's mean-of-w2c ATE "
                     f"{traj.ate_splatam_mean_w2c_cm:.2f} cm; "
                     f"constant pose {metrics.constant_pose_ate_rmse_c2w_cm:.2f} cm")
    render_mean = metrics.render.mean
    if render_mean is None:
        lines.append("no render metrics: no evaluation frame has usable depth")
    else:
        lines.append(f"PSNR {render_mean['psnr_db']:.2f} dB, MS-SSIM {render_mean['ms_ssim']:.3f} "
                     f"({int(render_mean['ms_ssim_scales'])} scales), SSIM {render_mean['ssim']:.3f}, depth L1 "
                     f"{render_mean['depth_l1_cm']:.2f} cm on {len(metrics.render.frames)} frames")
    if metrics.warnings:
        lines.append(f"{len(metrics.warnings)} warning(s), listed in metrics.json")
    if metrics.frames_per_s:
        lines.append(f"{metrics.frames} frames, {metrics.seconds_per_frame:.2f} s/frame, "
                     f"{metrics.num_gaussians} Gaussians")
    written = [name + "/" * (Path(out) / name).is_dir() for name in folder.RUN_FILES if (Path(out) / name).exists()]
    lines.append(f"outputs in {Path(out).resolve()}: {' '.join(written)}")
    return lines
