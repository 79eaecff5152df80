"""report.html and the files behind it: every run writes a self-contained page (inline CSS, images as data URIs, no
script or request) with every section; the per-frame series, ground truth, map frame and CB-KNN diagnostics it
draws on are in the run directory; ``gsjax report`` regenerates it and puts several runs side by side. (Opening it
in a real browser: ``tests/test_ui_browser.py``.)"""

from __future__ import annotations

import base64
import json
import re
import shutil
from xml.etree import ElementTree

import cv2
import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.session.runner import run_slam
from gsjax.eval.run_metrics import read_run_metrics
from gsjax.io.ply import read_ply
from gsjax.io.trajectory import read_tum_trajectory
from gsjax.raster import render
from gsjax.report import read_run, write_report
from gsjax.report.page import HEADER
from tests.support.metrics_schema import assert_valid_metrics
from tests.support.tiny_slam import FRAMES, run_options, tiny_config, tiny_sequence

SECTIONS = ("metrics", "trajectory", "errors", "drift", "renders", "psnr", "map", "timings", "cbknn", "warnings",
            "config")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A CB-KNN paper run and an off run of the tiny synthetic room (the programs the other SLAM tests compile)."""
    base = tmp_path_factory.mktemp("report")
    made = {}
    for mode in ("paper", "off"):
        out = base / mode / "run"
        made[mode] = (out, run_slam(tiny_sequence(), tiny_config(mode), run_options(out), describe=dict(cbknn=mode)))
    return made


def images_of(page: str) -> list[np.ndarray | ElementTree.Element]:
    """Every <img> of the page, decoded: an inline PNG (the run's image files) to its pixels, an inline SVG (the
    plots) to its XML root, which must hold drawn lines."""
    sources = re.findall(r'<img[^>]*\bsrc="([^"]*)"', page)
    decoded = []
    for source in sources:
        kind, data = source.split(",", 1)
        data = base64.b64decode(data)
        if kind == "data:image/png;base64":
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            assert image is not None and image.size > 0
            decoded.append(image)
        else:
            assert kind == "data:image/svg+xml;base64", source[:60]
            root = ElementTree.fromstring(data)
            assert root.tag == "{http://www.w3.org/2000/svg}svg"
            assert any(True for _ in root.iter("{http://www.w3.org/2000/svg}path"))
            decoded.append(root)
    return decoded


def test_the_metrics_json_of_a_paper_and_an_off_run_follow_the_schema(runs):
    paper = assert_valid_metrics(runs["paper"][0] / "metrics.json")
    assert paper["cbknn"]["samples"] and assert_valid_metrics(runs["off"][0] / "metrics.json")["cbknn"] is None


def test_every_run_writes_a_self_contained_report_with_every_section(runs):
    out, metrics = runs["paper"]
    page = (out / "report.html").read_text()
    assert page.startswith(HEADER)
    for section in SECTIONS:
        assert f'<section id="{section}">' in page, section
    for needle in ("http://", "https://", "<script", "<link", "url(", "@import", "@font-face", "<iframe"):
        assert needle not in page.lower(), needle
    # trajectory, errors over time, unaligned error over time, 2 render panels, PSNR, Gaussians/loss, 2 CB-KNN maps
    assert len(images_of(page)) == 9
    assert f"{metrics.trajectory.ate_rmse_c2w_cm:.2f}" in page
    assert f"{metrics.render.mean['psnr_db']:.2f}" in page
    timings = re.search(r'<section id="timings">(.*?)</section>', page, re.S).group(1)
    rows = dict(re.findall(r"<tr><td>([^<]*)</td><td>([^<]*)</td></tr>", timings))
    # Every stage with its seconds, nothing else; but the report's own, timed after the page is written.
    assert rows == {name.removesuffix("_s"): "–" if value is None else f"{value:.2f}"
                    for name, value in metrics.stage_timings_s.items() if name != "report_s"}
    assert {"slam", "checkpoint", "read_frames", "outputs"} <= rows.keys()
    assert "No warnings." in page and "&quot;cbknn&quot;: &quot;paper&quot;" in page  # escaped config.json


def test_the_off_run_has_no_cbknn_section(runs):
    page = (runs["off"][0] / "report.html").read_text()
    assert '<section id="cbknn">' not in page and runs["off"][1].cbknn is None
    assert len(images_of(page)) == 7


def test_metrics_hold_the_per_frame_series_keyframes_and_the_maps_frame(runs):
    out, metrics = runs["paper"]
    assert read_run_metrics(out / "metrics.json") == metrics
    per_frame = metrics.per_frame
    assert {len(v) for v in per_frame.values()} == {FRAMES}
    assert per_frame["num_gaussians"][-1] == metrics.num_gaussians and per_frame["tracking_loss"][0] == 0
    assert metrics.keyframe_frames == [0, 4] and len(metrics.keyframe_frames) == metrics.keyframes
    assert metrics.trajectory.per_frame["est_index"] == list(range(FRAMES))
    # map.ply is in the first camera's frame; world_from_map takes it to trajectory.txt's (the GT's) frame.
    _, gt_c2w, _ = tiny_sequence().gt_trajectory()
    np.testing.assert_allclose(metrics.world_from_map, gt_c2w[0], atol=1e-12)
    run = read_run(out)
    np.testing.assert_allclose(run.map_c2w()[0], np.eye(4), atol=1e-5)
    stamps, gt_read = read_tum_trajectory(out / "groundtruth.txt")
    np.testing.assert_allclose(stamps, tiny_sequence().gt_trajectory()[0], atol=1e-9)
    np.testing.assert_allclose(gt_read, gt_c2w, atol=1e-9)


def test_cbknn_diagnostics_are_the_renders_own_statistics(runs):
    out, metrics = runs["paper"]
    cbknn = metrics.cbknn
    config = tiny_config("paper")
    assert (cbknn.mode, cbknn.k0, cbknn.cell) == ("paper", float(config.cbknn.params.k0), 8)
    assert [s["frame"] for s in cbknn.samples] == [0, 4]
    assert sorted(p.name for p in (out / "renders").glob("cbknn_*.png")) == ["cbknn_000000.png", "cbknn_000004.png"]
    gaussians = read_ply(out / "map.ply")  # the final map, read back independently of the run's memory
    run = read_run(out)
    for sample in cbknn.samples:
        t = sample["frame"]
        w2c = np.linalg.inv(run.map_c2w()[t]).astype(np.float32)
        stats = render(gaussians, w2c, tiny_sequence().intrinsics, config.raster, cbknn=config.cbknn.params,
                       motion=np.float32(sample["gamma"])).stats.cbknn
        assert sample["gamma"] == pytest.approx(metrics.per_frame["gamma"][t])
        assert sample["k_mean"] == pytest.approx(float(np.mean(stats.k_map)), abs=1e-6)
        assert sample["mean_shift_px"] == pytest.approx(float(stats.mean_shift_px), rel=1e-3)
        assert sample["fraction_fewer_than_k"] == pytest.approx(float(stats.fraction_fewer_than_k), abs=1e-3)


def test_gsjax_report_regenerates_a_runs_page_and_compares_runs_side_by_side(runs, tmp_path, capsys):
    paper, off = runs["paper"][0], runs["off"][0]
    (paper / "report.html").unlink()
    assert main(["report", str(paper)]) == 0
    assert (paper / "report.html").read_text().startswith(HEADER)
    out = tmp_path / "compare.html"
    assert main(["report", str(paper), str(off), "--out", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    page = out.read_text()
    assert "2 runs side by side" in page
    # The runs are both called "run": they are told apart by their parents' names.
    assert "paper/run" in page and "off/run" in page
    assert "What differs" in page and 'class="best"' in page
    # trajectories, errors, unaligned errors, panels, PSNR, map, CB-KNN maps
    assert len(images_of(page)) == 2 + 1 + 1 + 4 + 1 + 1 + 2


def test_a_sweeps_directory_reports_its_runs_side_by_side(runs, tmp_path):
    sweep = tmp_path / "sweep"
    for i, mode in enumerate(("paper", "off")):
        shutil.copytree(runs[mode][0], sweep / "runs" / f"{i:03d}")
    (sweep / "sweep.json").write_text("{}")
    assert main(["report", str(sweep)]) == 0
    page = (sweep / "report.html").read_text()
    assert "2 runs side by side" in page and "000" in page and "001" in page


def test_report_refuses_what_it_cannot_use_with_one_line_and_changes_nothing(runs, tmp_path, capsys):
    mine = tmp_path / "notes.html"
    mine.write_text("my own page")
    assert main(["report", str(runs["paper"][0]), "--out", str(mine)]) == 2
    assert mine.read_text() == "my own page"
    unfinished = tmp_path / "unfinished"
    shutil.copytree(runs["off"][0], unfinished)
    (unfinished / "metrics.json").unlink()
    assert main(["report", str(unfinished)]) == 2
    damaged = tmp_path / "damaged"
    shutil.copytree(runs["off"][0], damaged)
    (damaged / "metrics.json").write_text("{not json")
    assert main(["report", str(damaged)]) == 2
    assert main(["report", str(tmp_path / "missing")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 4 and all(line.startswith("gsjax report: error: ") for line in errors)
    assert "not a gsjax report" in errors[0] and str(mine) in errors[0]
    assert "metrics.json" in errors[1] and "not a finished gsjax run" in errors[1]
    assert str(damaged / "metrics.json") in errors[2]
    assert "no such run directory" in errors[3]


def test_a_run_without_ground_truth_reports_the_estimate_alone(runs, tmp_path):
    run = tmp_path / "no_gt"
    shutil.copytree(runs["off"][0], run)
    (run / "groundtruth.txt").unlink()
    metrics = json.loads((run / "metrics.json").read_text())
    metrics["trajectory"] = None
    (run / "metrics.json").write_text(json.dumps(metrics))
    write_report(run)
    page = (run / "report.html").read_text()
    assert "no ground truth" in page and len(images_of(page)) == 5  # no ATE/RPE figure, no unaligned error
    assert "No ground truth to compare with." in page
