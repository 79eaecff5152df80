"""RealSense recordings (issue 39): files written by the SDK's own recorder (pyrealsense2 over a software device)
read back exactly, SLAM on them gives the bag's trajectory, and depth is aligned to colour pixel for pixel as the
SDK's ``rs.align`` aligns it, where depth is coarser and where it is finer than colour."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.data import DatasetError, open_sequence, write_rosbag
from tests.support.tiny_slam import CHUNK, FRAMES, TINY_OVERRIDES, tiny_sequence

rs = pytest.importorskip("pyrealsense2")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from gsjax.data.realsense_write import write_realsense

    folder = tmp_path_factory.mktemp("realsense")
    stamps = write_realsense(tiny_sequence(), folder / "room.db3")
    return folder / "room.db3", stamps


def test_an_sdk_recording_reads_back_exactly(recording, tmp_path):
    path, stamps = recording
    recorded = open_sequence("realsense", path)
    bag = open_sequence("rosbag", write_rosbag(tiny_sequence(), tmp_path / "room.bag", depth_scale=1000.0))
    assert len(recorded) == len(bag) == FRAMES and recorded.intrinsics == bag.intrinsics
    assert recorded.depth_scale == 1000.0  # from the recorded Depth_Units option (0.001 m)
    np.testing.assert_array_equal(recorded.timestamps, stamps)
    for i in range(FRAMES):  # PNG colour and compressedDepth: lossless
        np.testing.assert_array_equal(recorded.read_host(i).color, bag.read_host(i).color)
        np.testing.assert_array_equal(recorded.read_host(i).depth, bag.read_host(i).depth)


def test_slam_on_a_recording_gives_the_bag_s_trajectory(recording, tmp_path, capsys):
    path, stamps = recording
    from gsjax.io.trajectory import write_tum_trajectory

    _, c2w, _ = tiny_sequence().gt_trajectory()
    write_tum_trajectory(tmp_path / "gt.txt", stamps, c2w)
    bag = write_rosbag(tiny_sequence(), tmp_path / "room.bag", depth_scale=1000.0)
    common = ["--max-frames", str(FRAMES), "--chunk", str(CHUNK), "--no-progress",
              *[token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]]
    assert main(["run", "--out", str(tmp_path / "bag"), "--dataset", "rosbag", "--path", str(bag),
                 "--gt-frames", "world,camera", *common]) == 0
    assert main(["run", "--out", str(tmp_path / "rs"), "--dataset", "realsense", "--path", str(path),
                 "--groundtruth", str(tmp_path / "gt.txt"), *common]) == 0
    capsys.readouterr()

    def poses(run):
        lines = (tmp_path / run / "trajectory.txt").read_text().splitlines()
        return [line.split()[1:] for line in lines if line and not line.startswith("#")]

    assert poses("rs") == poses("bag")
    metrics = json.loads((tmp_path / "rs" / "metrics.json").read_text())
    assert metrics["trajectory"]["ate_rmse_c2w_cm"] < 1.0


def record_two_cameras(path, depth_size, depth_focal, color_size, color_focal, frames=3):
    """Depth and colour of different cameras, with a depth -> colour offset, recorded by the SDK's recorder."""
    from gsjax.camera import make_intrinsics
    from gsjax.data.realsense_write import SoftwareRecording

    def camera(size, focal):
        return make_intrinsics(focal, focal, (size[0] - 1) / 2, (size[1] - 1) / 2, size[1], size[0])

    offset = rs.extrinsics()
    angle = np.radians(2.0)  # a small turn about y and a baseline, as between a D400's depth and colour cameras
    offset.rotation = [np.cos(angle), 0.0, -np.sin(angle), 0.0, 1.0, 0.0, np.sin(angle), 0.0, np.cos(angle)]
    offset.translation = [0.03, -0.01, 0.002]
    recording = SoftwareRecording(rs, path, camera(depth_size, depth_focal), camera(color_size, color_focal), offset,
                                  0.001)
    rows, cols = np.mgrid[0:depth_size[1], 0:depth_size[0]]
    rng = np.random.default_rng(0)
    for n in range(frames):
        depth = (800 + 10 * cols + 5 * rows + 50 * n).astype(np.uint16)
        depth[5:9, 5:9] = 0  # a hole
        depth[20:26, 30:40] = 600  # a nearer box: occlusion in the colour view
        color = rng.integers(0, 255, (color_size[1], color_size[0], 3), dtype=np.uint8)
        recording.push(n, n * 33.3, depth, color)
        time.sleep(0.034)
    recording.close()
    return path


def sdk_aligned(path):
    """The frames' depth aligned to colour by the SDK (playback, not in real time) -> {frame number: [H, W] raw
    units}. (Under load the SDK's frame syncer drops frames of a short recording: those that came are compared.)"""
    config = rs.config()
    config.enable_device_from_file(str(path), repeat_playback=False)
    pipeline = rs.pipeline()
    profile = pipeline.start(config)
    profile.get_device().as_playback().set_real_time(False)
    align, frames = rs.align(rs.stream.color), {}
    try:
        while True:
            depth = align.process(pipeline.wait_for_frames(2000)).get_depth_frame()
            frames[depth.get_frame_number()] = np.asanyarray(depth.get_data()).copy()
    except RuntimeError:  # the end of the recording
        pass
    pipeline.stop()
    return frames


@pytest.mark.parametrize("depth_size, depth_focal, color_size, color_focal", [
    ((64, 48), 50.0, (80, 60), 70.0),  # depth coarser than colour: each depth pixel fills a rectangle
    ((80, 60), 70.0, (64, 48), 50.0),  # depth finer: each depth pixel lands on one colour pixel
])
def test_depth_is_aligned_to_colour_as_the_sdk_aligns_it(tmp_path, depth_size, depth_focal, color_size,
                                                         color_focal):
    path = record_two_cameras(tmp_path / "two.db3", depth_size, depth_focal, color_size, color_focal, frames=6)
    ours = open_sequence("realsense", path)
    assert (ours.intrinsics.width, ours.intrinsics.height) == color_size  # frames in the colour camera
    theirs = sdk_aligned(path)
    assert len(ours) == 6 and theirs and set(theirs) <= set(range(6))  # the SDK's syncer may drop a few
    for i, aligned in theirs.items():
        depth = ours.read_host(i).depth
        np.testing.assert_array_equal(depth, aligned.astype(np.float32) / np.float32(1000.0))
        assert 0.5 < np.mean(depth > 0) < 1.0  # holes and occlusion gaps, not an empty or a copied image


def test_a_recording_without_colour_or_not_a_recording_is_refused(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("x")
    with pytest.raises(DatasetError, match="notes.txt: not a RealSense recording"):
        open_sequence("realsense", text)
    bag = write_rosbag(tiny_sequence(), tmp_path / "room.bag")  # a bag, but not in the SDK's layout
    with pytest.raises(DatasetError, match=r"room.bag: no depth stream \(a RealSense recording has "
                                           r"/device_0/sensor_N/Depth_0/image/data"):
        open_sequence("realsense", bag)
    assert main(["run", "--out", str(tmp_path / "r"), "--dataset", "realsense", "--path", str(bag),
                 "--rgb-topic", "/x"]) == 2
    assert "--rgb-topic applies to --dataset rosbag" in capsys.readouterr().err
