"""The live path (issue 39, part 3) through the RealSense SDK's own playback in real time: a recording played as if
it were a camera goes through the same pipeline, frames SLAM cannot keep up with are dropped and counted (never an
unbounded queue), and SIGTERM stops the run with every output written."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import pytest

from gsjax.app.cli import main
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from tests.support.tiny_slam import CAPACITY, HEIGHT, TINY_OVERRIDES, WIDTH, tiny_config

pytest.importorskip("pyrealsense2")
# The live runs start at H W slots (not the camera's 8 H W): the capacity test grows into this program.
START = CAPACITY // 2
TINY = ["--capacity", str(START),
        *[token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from gsjax.data.realsense_write import write_realsense

    path = tmp_path_factory.mktemp("live") / "room.db3"
    write_realsense(synthetic_sequence(SyntheticConfig(width=WIDTH, height=HEIGHT, num_frames=60)), path)
    return path


def live_result(out):
    metrics = json.loads((out / "metrics.json").read_text())
    live = json.loads((out / "config.json").read_text())["live"]
    return metrics, live


def test_a_recording_played_in_real_time_drops_what_slam_cannot_keep_up_with(recording, tmp_path):
    """A consumer of the run's frames that takes 0.1 s per frame (three frames of the 30 fps playback) makes the run
    slower than the camera, whatever the machine: the camera keeps the newest frames and drops the rest, and every
    captured frame is either processed or counted as dropped."""
    from gsjax.app.session.camera import LiveCamera
    from gsjax.app.session.live import run_live
    from gsjax.app.session.runner import RunOptions

    out = tmp_path / "run"
    run_live(LiveCamera(recording), tiny_config(), RunOptions(out=out, chunk=1, capacity=START, progress=False),
             downscale=1, max_frames=3000, observe=lambda state, outputs: time.sleep(0.1), say=lambda message: None)
    metrics, live = live_result(out)
    for name in ("trajectory.txt", "map.ply", "report.html"):
        assert (out / name).is_file()
    assert live["dropped"] > 0 and metrics["frames"] >= 1
    assert metrics["frames"] + live["dropped"] == live["captured"] <= 60  # every captured frame accounted for
    assert f"live: {live['dropped']} of {live['captured']} captured frames were dropped" in metrics["warnings"][0]


def test_a_live_run_that_outgrows_its_start_capacity_keeps_adding_gaussians_and_says_it_grew(recording, tmp_path,
                                                                                          capsys):
    """Capacity H W / 2, fewer slots than the first frame's new Gaussians (one per pixel with depth): the map doubles
    (said on the terminal), the frame is re-run and nothing is dropped, whatever frames the playback leaves SLAM;
    checkpoints are written as for a recording (a crash keeps what was mapped)."""
    out = tmp_path / "run"
    argv = ["run", "--dataset", "realsense", "--path", str(recording), "--realtime", "--out", str(out), *TINY]
    argv[argv.index("--capacity") + 1] = str(START // 2)
    assert main([*argv, "--checkpoint-every", "1"]) == 0
    log = capsys.readouterr().out
    metrics, _ = live_result(out)
    assert f"found no free slot at frame 0; growing the map to {START} slots and re-running the frame" in log
    assert metrics["capacity"] >= START and metrics["num_gaussians"] > START // 2
    assert metrics["per_frame"]["added"][0] > START // 2 and not any(metrics["per_frame"]["dropped"])
    assert metrics["stage_timings_s"]["regrow_s"] > 0
    assert metrics["checkpoints"]["count"] == metrics["frames"] and (out / "checkpoints").is_dir()


def test_sigterm_stops_a_live_run_and_writes_its_outputs(recording, tmp_path, capsys):
    """SIGTERM once the first frame is checkpointed (not after a fixed time, which a loaded machine can outlast before
    any frame is processed): the run stops there with every output written."""
    out = tmp_path / "run"
    stopped = threading.Event()

    def stop_after_the_first_frame():
        deadline = time.monotonic() + 120
        while not (out / "checkpoints" / "1").is_dir() and time.monotonic() < deadline and not stopped.is_set():
            time.sleep(0.01)
        if not stopped.is_set():
            os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=stop_after_the_first_frame, daemon=True).start()
    try:
        assert main(["run", "--dataset", "realsense", "--path", str(recording), "--realtime", "--out", str(out),
                     *TINY, "--checkpoint-every", "1"]) == 0
    finally:
        stopped.set()
    capsys.readouterr()
    metrics, live = live_result(out)
    assert live["captured"] < 55  # stopped early, not at the end of the 2-second recording
    assert metrics["frames"] >= 1 and (out / "trajectory.txt").is_file() and (out / "map.ply").is_file()
    assert signal.getsignal(signal.SIGTERM) is not None  # the run restored the handler it replaced


def test_live_flags_that_do_not_apply_are_refused(recording, tmp_path, capsys):
    assert main(["run", "--dataset", "realsense", "--path", str(recording), "--realtime", "--resume",
                 "--out", str(tmp_path / "r")]) == 2
    assert "a live camera cannot be re-read" in capsys.readouterr().err
    assert main(["run", "--dataset", "synthetic", "--realtime", "--out", str(tmp_path / "r")]) == 2
    assert "--realtime plays a RealSense recording" in capsys.readouterr().err


def test_no_camera_is_one_clear_error(tmp_path, capsys):
    import pyrealsense2 as rs

    if len(rs.context().query_devices()):
        pytest.skip("a RealSense camera is connected")
    assert main(["run", "--dataset", "realsense", "--path", "live", "--out", str(tmp_path / "cam")]) == 2
    assert "--path live: no RealSense camera is connected" in capsys.readouterr().err
    assert not (tmp_path / "cam" / "metrics.json").exists()
