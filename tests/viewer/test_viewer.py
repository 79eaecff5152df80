"""The viewer without a browser: what ``gsjax view`` serves of a finished run (keyframe inputs from its checkpoints,
renders of its map, the ground truth drawn from the estimate's first pose), what the live viewer keeps after an
update, and the one-line errors of ``gsjax view``. (In a real browser: ``tests/test_ui_browser.py``.)"""

from __future__ import annotations

import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.session.runner import run_slam
from gsjax.io.images import to_uint8
from gsjax.io.ply import read_ply
from gsjax.raster import render
from gsjax.viewer import open_run
from gsjax.viewer.live import LiveViewer
from tests.support.tiny_slam import FRAMES, relative_gt_w2c, run_options, tiny_config, tiny_sequence


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer") / "run"
    return out, run_slam(tiny_sequence(), tiny_config(), run_options(out))


@pytest.fixture
def served(finished):
    viewer = open_run(finished[0], port=0)
    yield viewer
    viewer.stop()


def test_view_serves_the_runs_keyframes_renders_and_ground_truth(finished, served):
    out, metrics = finished
    assert served.url.startswith("http://127.0.0.1:") and served.port > 0
    trajectory = served._trajectory
    assert len(trajectory.c2w) == FRAMES and trajectory.keyframes.tolist() == metrics.keyframe_frames == [0, 4]
    # The ground truth starts at the estimate's first pose (the first camera: identity in the map's frame).
    assert trajectory.gt_frames.tolist() == list(range(FRAMES))
    np.testing.assert_allclose(trajectory.gt_c2w, np.linalg.inv(relative_gt_w2c()), atol=1e-5)
    images = served._images
    for keyframe in (0, 4):
        stored = to_uint8(tiny_sequence().read_host(keyframe).color)  # the input, as the keyframe store kept it
        np.testing.assert_array_equal(images.input_image(keyframe), stored)
        w2c = np.linalg.inv(trajectory.c2w[keyframe]).astype(np.float32)
        expected = to_uint8(np.asarray(render(read_ply(out / "map.ply"), w2c, tiny_sequence().intrinsics).color))
        np.testing.assert_array_equal(images.render_image(keyframe), expected)
    assert images.input_image(1) is None  # not a keyframe
    assert served._slider.max == FRAMES - 1 and served._slider.value == FRAMES - 1


def test_the_live_viewer_keeps_what_a_chunk_brought(finished):
    sequence = tiny_sequence()
    live = LiveViewer(sequence, tiny_config(), port=0)
    try:
        seen = []

        def observe(state, outputs):
            live.update(state, outputs)
            seen.append((len(live.viewer._trajectory.c2w), sorted(live._images.known())))

        run_slam(sequence, tiny_config(), run_options(finished[0].parent / "live"), observe=observe)
    finally:
        live.stop()
    assert seen == [(3, [0]), (6, [0, 4])] and live.seconds > 0


def test_view_refuses_what_it_cannot_serve_with_one_line(finished, tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing"), "--port", "0"]) == 2
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    assert main(["view", str(unfinished), "--port", "0"]) == 2
    assert main(["view", str(finished[0]), "--host", "10.255.255.1", "--port", "0"]) == 2  # not this machine's
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and all(line.startswith("gsjax view: error: ") for line in errors)
    assert "no such run directory" in errors[0]
    assert "metrics.json" in errors[1] and "not a finished gsjax run" in errors[1]
    assert "cannot listen on host '10.255.255.1'" in errors[2]
