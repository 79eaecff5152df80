"""``report.html``: one self-contained page of one run, or of several side by side.

The page needs nothing but itself: CSS inline, images inlined as ``data:`` URIs, no script, no font, no request
of any kind. Sections: the metrics table, the trajectory against ground truth, ATE and RPE over time, labelled
render-vs-input samples with error maps, PSNR per frame, Gaussian count and tracking loss over time, timings per
stage, CB-KNN's diagnostics (K and rho maps) when it smoothed renders, warnings and the config (with several
runs: what differs between them first).
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.run_folder import RunRecord
from gsjax.report.figures import Series, series_svg

# How every page gsjax writes begins (so that rewriting one never replaces a file gsjax did not write).
HEADER = "<!doctype html>\n<!-- gsjax report -->\n"

_CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;color:#1b1f24;
margin:0;background:#f6f7f9}
main{max-width:1240px;margin:0 auto;padding:20px 28px 60px}
h1{font-size:22px;margin:8px 0 4px}h2{font-size:17px;margin:30px 0 10px;border-bottom:1px solid #d8dce2;
padding-bottom:4px}h3{font-size:14px;margin:12px 0 6px}
.sub{color:#57606a;margin:0 0 14px}
table{border-collapse:collapse;background:#fff;margin:6px 0 10px}
th,td{border:1px solid #d8dce2;padding:4px 9px;text-align:right;vertical-align:top}
th:first-child,td:first-child{text-align:left}th{background:#eef1f4;font-weight:600}
tr:nth-child(even) td{background:#fafbfc}td.best{font-weight:700;color:#0b5cad}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(520px,1fr));gap:16px}
.card{background:#fff;border:1px solid #d8dce2;border-radius:6px;padding:10px 12px}
figure{margin:8px 0 14px}figcaption{color:#57606a;font-size:13px;margin-top:3px}
img{max-width:100%;height:auto;display:block}img.pixels{image-rendering:pixelated}
pre{background:#fff;border:1px solid #d8dce2;padding:10px;overflow:auto;font-size:12px;max-height:520px}
.note{color:#57606a;font-style:italic}ul.warnings li{margin:3px 0;font-family:ui-monospace,monospace;font-size:12px}
"""


# ------------------------------------------------------------------------------------------------ values


def _scaled(value, factor):
    return None if value is None else value * factor


def _trajectory(m: RunMetrics, name: str):
    return None if m.trajectory is None else getattr(m.trajectory, name)


def _render(m: RunMetrics, name: str):
    return None if m.render.mean is None else m.render.mean.get(name)


def _flags(m: RunMetrics) -> str | None:
    flags = (m.skipped_frames, m.retried_frames, m.diverged_frames)
    if all(f is None for f in flags):
        return None
    return " / ".join(str(len(f or [])) for f in flags)


# (label, value from metrics.json, better: "lower" | "higher" | None, format)
METRICS: tuple[tuple[str, Callable[[RunMetrics], object], str | None, str], ...] = (
    ("ATE RMSE, camera centres (cm)", lambda m: m.ate_cm, "lower", "{:.2f}"),
    ("ATE, SplaTAM's mean of w2c (cm)", lambda m: _trajectory(m, "ate_splatam_mean_w2c_cm"), "lower", "{:.2f}"),
    ("ATE of a constant pose (cm)", lambda m: m.constant_pose_ate_rmse_c2w_cm, None, "{:.2f}"),
    ("RPE translation RMSE (cm / frame)", lambda m: _scaled(_trajectory(m, "rpe_trans_rmse_m"), 100), "lower",
     "{:.3f}"),
    ("RPE rotation RMSE (deg / frame)", lambda m: _trajectory(m, "rpe_rot_rmse_deg"), "lower", "{:.3f}"),
    ("PSNR (dB)", lambda m: m.psnr_db, "higher", "{:.2f}"),
    ("SSIM", lambda m: _render(m, "ssim"), "higher", "{:.3f}"),
    ("MS-SSIM", lambda m: _render(m, "ms_ssim"), "higher", "{:.3f}"),
    ("depth L1 (cm)", lambda m: _render(m, "depth_l1_cm"), "lower", "{:.2f}"),
    ("frames/s", lambda m: m.frames_per_s, "higher", "{:.3f}"),
    ("s/frame", lambda m: m.seconds_per_frame, "lower", "{:.2f}"),
    ("frames", lambda m: m.frames, None, "{}"),
    ("resolution", lambda m: f"{m.width}x{m.height}" if m.width else None, None, "{}"),
    ("Gaussians", lambda m: m.num_gaussians, None, "{}"),
    ("keyframes", lambda m: m.keyframes, None, "{}"),
    ("skipped / retried / diverged frames", _flags, None, "{}"),
    ("warnings", lambda m: len(m.warnings), None, "{}"),
)


def _format(value, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return fmt.format(value)


# ------------------------------------------------------------------------------------------------ html


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _img(data: bytes, alt: str, pixels: bool = False) -> str:
    """An inline image: PNG (the run's image files) or SVG (the page's plots), told by their first bytes."""
    mime = "image/png" if data.startswith(b"\x89PNG") else "image/svg+xml"
    encoded = base64.b64encode(data).decode("ascii")
    cls = ' class="pixels"' if pixels else ""
    return f'<img{cls} alt="{_e(alt)}" src="data:{mime};base64,{encoded}">'


def _figure(data: bytes, alt: str, caption: str = "", pixels: bool = False) -> str:
    cap = f"<figcaption>{_e(caption)}</figcaption>" if caption else ""
    return f"<figure>{_img(data, alt, pixels)}{cap}</figure>"


def _note(text: str) -> str:
    return f'<p class="note">{_e(text)}</p>'


def _table(header: list[str], rows: list[list[str]], raw: bool = False) -> str:
    """A table; cells are escaped unless ``raw`` (then they are HTML ``<td>`` contents, e.g. with a class)."""
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(c if raw else f"<td>{_e(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _describe(run: RunRecord) -> str:
    r, m = run.record.to_json() if run.record else {}, run.metrics
    parts = [f"dataset {r.get('dataset') or m.dataset or '?'}"]
    if r.get("sequence"):
        parts.append(f"sequence {r['sequence']}")
    for key, label in (("preset", "preset"), ("cbknn", "CB-KNN"), ("seed", "seed")):
        if r.get(key) is not None:
            parts.append(f"{label} {r[key]}")
    if r.get("sweep"):
        parts.append(", ".join(f"{k}={v}" for k, v in r["sweep"].get("values", {}).items()))
    if r.get("path"):
        parts.append(f"path {r['path']}")
    return "; ".join(parts)


# ------------------------------------------------------------------------------------------------ sections


def _metrics_section(runs: list[RunRecord]) -> str:
    if len(runs) == 1:
        m = runs[0].metrics
        rows = [[label, _format(get(m), fmt)] for label, get, _, fmt in METRICS]
        return _table(["metric", "value"], rows)
    values = [[get(run.metrics) for run in runs] for _, get, _, _ in METRICS]
    best = []
    for (_, _, better, _), column in zip(METRICS, values):
        numbers = [v for v in column if isinstance(v, (int, float)) and math.isfinite(v)]
        best.append(None if better is None or len(numbers) < 2 else (min if better == "lower" else max)(numbers))
    rows = []
    for i, run in enumerate(runs):
        cells = [f"<td>{_e(run.name)}</td>"]
        for (_, _, _, fmt), column, top in zip(METRICS, values, best):
            cls = ' class="best"' if top is not None and column[i] == top else ""
            cells.append(f"<td{cls}>{_e(_format(column[i], fmt))}</td>")
        rows.append(cells)
    return _table(["run"] + [label for label, _, _, _ in METRICS], rows, raw=True) + _note(
        "Bold: the best value of a column (lower error, higher PSNR / SSIM / MS-SSIM / frames/s).")


def _trajectory_section(runs: list[RunRecord]) -> str:
    def plot(run: RunRecord) -> str:  # the run's own trajectory.png
        path = run.path / "trajectory.png"
        return _figure(path.read_bytes(), "trajectory top view") if path.is_file() else _note("No trajectory.png.")

    cards = [f'<div class="card"><h3>{_e(run.name)}</h3>{plot(run)}</div>' for run in runs]
    intro = _note("Top view of the camera centres: the estimate after the rigid alignment onto the ground truth that "
                  "the ATE uses; grey segments join each frame's estimate to its ground truth.")
    return intro + f'<div class="grid">{"".join(cards)}</div>'


def _errors_section(runs: list[RunRecord]) -> str:
    ate, rpe_t, rpe_r = [], [], []
    for run in runs:
        per_frame = _trajectory(run.metrics, "per_frame")
        if not per_frame:
            continue
        ate.append(Series(run.name, np.asarray(per_frame["est_index"]), 100 * np.asarray(per_frame["ate_c2w_m"])))
        rows = np.asarray(per_frame["rpe_est_index"])
        rpe_t.append(Series(run.name, rows, 100 * np.asarray(per_frame["rpe_trans_m"])))
        rpe_r.append(Series(run.name, rows, np.asarray(per_frame["rpe_rot_deg"])))
    if not ate:
        return _note("No per-frame trajectory errors: the run has no ground truth (or predates per-frame errors).")
    panels = [("ATE (cm)", ate), ("RPE translation (cm)", rpe_t), ("RPE rotation (deg)", rpe_r)]
    return _figure(series_svg(panels), "ATE and RPE over time",
                   "Per frame: the camera-centre error after alignment (ATE) and the error of the motion from the "
                   "previous frame (RPE).")


def _drift_section(runs: list[RunRecord]) -> str:
    """Where the error enters: the unaligned camera error per frame and its change, beside what could cause it."""
    error, change, loss, depth, motion = [], [], [], [], []
    for run in runs:
        found = run.drift()
        if found is None:
            continue
        frames = found.frames
        error.append(Series(run.name, frames, 100 * found.error_m))
        change.append(Series(run.name, frames[1:], 100 * np.diff(found.error_m)))
        steps = np.linalg.norm(np.diff(run.est_c2w[:, :3, 3], axis=0), axis=1)
        motion.append(Series(run.name, np.arange(1, len(run.est_c2w)), 100 * steps))
        per_frame = run.metrics.per_frame
        if per_frame.get("tracking_loss"):
            loss.append(Series(run.name, np.arange(len(per_frame["tracking_loss"])),
                               np.asarray([np.nan if v is None else v for v in per_frame["tracking_loss"]], float)))
        if per_frame.get("depth_valid"):
            depth.append(Series(run.name, np.arange(len(per_frame["depth_valid"])),
                                100 * np.asarray(per_frame["depth_valid"], float)))
    if not error:
        return _note("No ground truth to compare with.")
    panels = [("camera error, unaligned (cm)", error), ("its change per frame (cm)", change),
              ("tracking loss", loss), ("valid depth (% of pixels)", depth), ("camera motion per frame (cm)", motion)]
    return _figure(series_svg([p for p in panels if p[1]]), "camera error over time, unaligned",
                   "The ground truth started at the first estimated pose, then the distance between the camera "
                   "centres per frame (no alignment, so the error shows where it enters, unlike the ATE), its change "
                   "from the previous frame, and beside them the tracking loss, the valid depth and the camera's "
                   "motion.")


def _renders_section(runs: list[RunRecord]) -> str:
    def caption(run: RunRecord, frame: int) -> str:
        values = run.metrics.render.at(frame)
        if values is not None:
            return (f"frame {frame}: PSNR {values['psnr_db']:.2f} dB, SSIM {values['ssim']:.3f}, depth L1 "
                    f"{100 * values['depth_l1_m']:.2f} cm (the final map rendered at the estimated pose)")
        return f"frame {frame}"

    cards = []
    for run in runs:
        figures = [_figure(path.read_bytes(), f"render vs input, frame {frame}", caption(run, frame), pixels=True)
                   for frame, path in run.panels]
        body = "".join(figures) or _note("No render samples in renders/.")
        cards.append(body if len(runs) == 1 else f'<div class="card"><h3>{_e(run.name)}</h3>{body}</div>')
    return "".join(cards) if len(runs) == 1 else f'<div class="grid">{"".join(cards)}</div>'


def _psnr_section(runs: list[RunRecord]) -> str:
    psnr = []
    for run in runs:
        frames, per_frame = run.metrics.render.frames, run.metrics.render.per_frame
        if frames and per_frame:
            psnr.append(Series(run.name, np.asarray(frames), np.asarray([p["psnr_db"] for p in per_frame])))
    if not psnr:
        return _note("No evaluation frame had usable depth.")
    return _figure(series_svg([("PSNR (dB)", psnr)], markers=True), "PSNR per frame",
                   "On the evaluation frames (t = 0 and every eval_every-th), masked by valid input depth.")


def _map_section(runs: list[RunRecord]) -> str:
    count, loss = [], []
    for run in runs:
        per_frame = run.metrics.per_frame
        if per_frame:
            frames = np.arange(len(per_frame["num_gaussians"]))
            count.append(Series(run.name, frames, np.asarray(per_frame["num_gaussians"], float)))
            loss.append(Series(run.name, frames, np.asarray([np.nan if v is None else v
                                                             for v in per_frame["tracking_loss"]], float)))
    if not count:
        return _note("No per-frame series: the run predates them.")
    return _figure(series_svg([("Gaussians", count), ("tracking loss", loss)]), "Gaussian count and tracking loss",
                   "Active Gaussians after each frame, and the tracking loss at the frame's final pose.")


def _timings_section(runs: list[RunRecord]) -> str:
    stages: list[str] = []
    for run in runs:
        for name in run.metrics.stage_timings_s:
            if name not in stages:
                stages.append(name)
    if not stages:
        return _note("No timings recorded.")

    def cell(run, name):
        value = run.metrics.stage_timings_s.get(name)
        return "–" if value is None else f"{value:.2f}"

    if len(runs) == 1:
        return _table(["stage", "seconds"], [[s.removesuffix("_s"), cell(runs[0], s)] for s in stages])
    return _table(["run"] + [s.removesuffix("_s") for s in stages],
                  [[run.name] + [cell(run, s) for s in stages] for run in runs])


def _cbknn_section(runs: list[RunRecord]) -> str | None:
    parts = []
    for run in runs:
        cbknn = run.metrics.cbknn
        mode = _cbknn_mode(run) or (cbknn.mode if cbknn else None)
        title = f"<h3>{_e(run.name)}</h3>" if len(runs) > 1 else ""
        if cbknn:
            rows = [[str(s["frame"]), f"{s['gamma']:.2f}", f"{s['k_mean']:.2f}", f"{s['k_min']}-{s['k_max']}",
                     f"{s['rho_max']:.2f}", f"{100 * s['empty_cells']:.0f}", f"{s['mean_shift_px']:.3f}",
                     f"{100 * s['fraction_fewer_than_k']:.1f}"] for s in cbknn.samples]
            params = (f"mode {cbknn.mode}: alpha {cbknn.alpha:g}, K0 {cbknn.k0:g}, beta {cbknn.beta:g}, "
                      f"{cbknn.cell} px cells")
            images = "".join(_figure(path.read_bytes(), f"CB-KNN K and rho maps, frame {frame}")
                             for frame, path in run.cbknn_panels)
            parts.append(title + _note(params) + _table(
                ["frame", "gamma", "mean K", "K range", "max rho", "empty cells %", "mean shift (px)",
                 "pixels with fewer contributors than K %"], rows) + images)
        elif mode == "code_parity":
            parts.append(title + _note("code_parity: only the released code's 3D smoothing of the mapping-overlap "
                                       "samples; no per-pixel kernel, so no K or rho maps."))
        elif len(runs) > 1 and mode:
            parts.append(title + _note(f"CB-KNN {mode}."))
    if not any(run.metrics.cbknn or _cbknn_mode(run) == "code_parity" for run in runs):
        return None
    return _note("The final map rendered with CB-KNN at the sample frames' estimated poses and their motion gamma: "
                 "K is the kernel size per cell, rho the density of Gaussian centres (1 = mean of the non-empty "
                 "cells).") + "".join(parts)


def _warnings_section(runs: list[RunRecord]) -> str:
    parts = []
    for run in runs:
        warnings = run.metrics.warnings
        title = f"<h3>{_e(run.name)}</h3>" if len(runs) > 1 else ""
        items = "".join(f"<li>{_e(w)}</li>" for w in warnings)
        parts.append(title + (f'<ul class="warnings">{items}</ul>' if warnings else _note("No warnings.")))
    return "".join(parts)


def _cbknn_mode(run: RunRecord) -> str | None:
    """The CB-KNN mode the command line asked for (``config.json``), or None."""
    return run.record.describe.get("cbknn") if run.record else None


def _flatten(tree, prefix: str = "") -> dict[str, object]:
    if isinstance(tree, dict):
        flat = {}
        for key, value in tree.items():
            flat.update(_flatten(value, f"{prefix}{key}."))
        return flat
    return {prefix[:-1]: tree}


def _config_section(runs: list[RunRecord]) -> str:
    parts = []
    if len(runs) > 1:
        flat = [_flatten(run.record.to_json() if run.record else {}) for run in runs]
        keys = [k for k in dict.fromkeys(k for f in flat for k in f) if len({json.dumps(f.get(k)) for f in flat}) > 1]
        if keys:
            rows = [[run.name] + [json.dumps(f.get(k)) for k in keys] for run, f in zip(runs, flat)]
            parts.append("<h3>What differs</h3>" + _table(["run"] + keys, rows))
        else:
            parts.append(_note("The runs' configs are identical."))
    for run in runs:
        text = json.dumps(run.record.to_json(), indent=2) if run.record else "(no config.json)"
        summary = "config.json" if len(runs) == 1 else f"{run.name}: config.json"
        parts.append(f"<details{' open' if len(runs) == 1 else ''}><summary>{_e(summary)}</summary>"
                     f"<pre>{_e(text)}</pre></details>")
    return "".join(parts)


# ------------------------------------------------------------------------------------------------ page


def report_html(runs: list[RunRecord]) -> str:
    """The page for ``runs`` (one: that run's report; several: side by side)."""
    if not runs:
        raise ValueError("a report needs at least one run")
    if len(runs) == 1:
        title = f"gsjax run {runs[0].name}"
        subtitle = _e(_describe(runs[0]))
    else:
        title = f"gsjax: {len(runs)} runs side by side"
        subtitle = "<br>".join(f"<b>{_e(run.name)}</b>: {_e(_describe(run))}" for run in runs)
    sections = [
        ("metrics", "Metrics", _metrics_section(runs)),
        ("trajectory", "Trajectory against ground truth", _trajectory_section(runs)),
        ("errors", "ATE and RPE over time", _errors_section(runs)),
        ("drift", "Camera error over time, unaligned", _drift_section(runs)),
        ("renders", "Renders against inputs", _renders_section(runs)),
        ("psnr", "PSNR per frame", _psnr_section(runs)),
        ("map", "Gaussians and tracking loss over time", _map_section(runs)),
        ("timings", "Timings per stage (s)", _timings_section(runs)),
        ("cbknn", "CB-KNN diagnostics", _cbknn_section(runs)),
        ("warnings", "Warnings", _warnings_section(runs)),
        ("config", "Config", _config_section(runs)),
    ]
    body = "".join(f'<section id="{key}"><h2>{_e(heading)}</h2>{content}</section>'
                   for key, heading, content in sections if content is not None)
    return (f"{HEADER}<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head>"
            f"<body><main><h1>{_e(title)}</h1><p class=\"sub\">{subtitle}</p>{body}</main></body></html>\n")


def is_report(path: Path) -> bool:
    """Whether ``path`` is a page gsjax wrote (so replacing it loses nothing a user made)."""
    try:
        with open(path, "rb") as f:
            return f.read(len(HEADER)) == HEADER.encode()
    except OSError:
        return False
