"""ROS bags as datasets (issue 39): the synthetic room written as a ROS 1 bag and as ROS 2 bags (sqlite3, mcap),
raw and compressed, reads back as the same frames as the TUM folder layout, bit for bit; SLAM on the bag gives the
folder's trajectory; topics, pairing, the camera and the ground truth; bad bags give one clear error naming them."""

from __future__ import annotations

import dataclasses
import json
import warnings

import cv2
import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.data import BagOptions, DatasetError, DatasetWarning, open_sequence, write_rosbag, write_tum
from gsjax.data.bag_images import camera_info_message, color_message, decode_depth, depth_message
from gsjax.data.bag_write import BagTopics
from tests.support.tiny_slam import CHUNK, FRAMES, TINY_OVERRIDES, tiny_sequence

TUM_SCALE = 5000.0  # the TUM layout's depth units: a bag written at the same scale holds the same raw values


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_tum(tiny_sequence(), tmp_path_factory.mktemp("tum") / "room")


@pytest.mark.parametrize("ros, storage, compressed", [(1, "sqlite3", False), (1, "sqlite3", True),
                                                      (2, "sqlite3", False), (2, "mcap", True)])
def test_a_bag_reads_back_the_folder_s_frames_bit_for_bit(tmp_path, folder, ros, storage, compressed):
    path = write_rosbag(tiny_sequence(), tmp_path / ("room.bag" if ros == 1 else "room"), ros=ros, storage=storage,
                        compressed=compressed, depth_scale=TUM_SCALE)
    bag = open_sequence("rosbag", path, depth_scale=TUM_SCALE, bag=BagOptions(gt_frames=("world", "camera")))
    tum = open_sequence("tum", folder)
    assert len(bag) == len(tum) == FRAMES and bag.intrinsics == tum.intrinsics
    for i in range(FRAMES):
        a, b = bag.read_host(i), tum.read_host(i)
        np.testing.assert_array_equal(a.color, b.color)
        np.testing.assert_array_equal(a.depth, b.depth)
    (t_bag, c2w_bag, valid_bag), (t_tum, c2w_tum, valid_tum) = bag.gt_trajectory(), tum.gt_trajectory()
    np.testing.assert_allclose(t_bag, t_tum, atol=1e-6)  # ns stamps vs the folder's microseconds
    np.testing.assert_allclose(c2w_bag, c2w_tum, atol=1e-9)
    assert valid_bag.all() and valid_tum.all()


def test_slam_on_a_bag_gives_the_folder_s_trajectory(tmp_path, folder, capsys):
    bag = write_rosbag(tiny_sequence(), tmp_path / "room.bag", depth_scale=TUM_SCALE)
    common = ["--max-frames", str(FRAMES), "--chunk", str(CHUNK), "--no-progress",
              *[token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]]
    assert main(["run", "--out", str(tmp_path / "tum"), "--dataset", "tum", "--path", str(folder), *common]) == 0
    assert main(["run", "--out", str(tmp_path / "bag"), "--dataset", "rosbag", "--path", str(bag), "--depth-scale",
                 str(TUM_SCALE), "--groundtruth", str(folder / "groundtruth.txt"), *common]) == 0
    capsys.readouterr()

    def poses(run):
        lines = (tmp_path / run / "trajectory.txt").read_text().splitlines()
        return [line.split()[1:] for line in lines if line and not line.startswith("#")]

    assert poses("bag") == poses("tum")  # the estimate, digit for digit (stamps: ns vs microseconds)
    metrics = {run: json.loads((tmp_path / run / "metrics.json").read_text()) for run in ("tum", "bag")}
    assert metrics["bag"]["trajectory"]["ate_rmse_c2w_cm"] == metrics["tum"]["trajectory"]["ate_rmse_c2w_cm"]
    record = json.loads((tmp_path / "bag" / "config.json").read_text())
    assert record["dataset"] == "rosbag" and record["bag"]["groundtruth"] == str(folder / "groundtruth.txt")


def test_synth_writes_a_bag_that_runs_and_evaluates(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["synth", "--out", str(out), "--frames", "3", "--format", "rosbag", "--ros", "2"]) == 0
    sequence = open_sequence("rosbag", out / "synthetic", bag=BagOptions(gt_frames=("world", "camera")))
    assert len(sequence) == 3 and sequence.gt_trajectory()[2].all() and sequence.depth_scale == 1000.0
    estimate = out / "estimate.txt"
    from gsjax.io.trajectory import write_tum_trajectory

    times, c2w, _ = sequence.gt_trajectory()
    write_tum_trajectory(estimate, times, c2w)
    assert main(["eval", "--est", str(estimate), "--gt", str(out / "synthetic"), "--dataset", "rosbag",
                 "--gt-frames", "world,camera", "--out", str(out / "m.json")]) == 0
    assert json.loads((out / "m.json").read_text())["ate_rmse_c2w_m"] < 1e-9
    capsys.readouterr()


# ------------------------------------------------------------------------------------------- hand-made bags


def write_bag(path, frames):
    """A ROS 2 bag of ``frames``: [(stamp s, [(topic, maker(stamp ns, message types) -> message)])]."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    with Writer(path, version=9) as writer:
        made = {}
        for stamp, messages in frames:
            ns = int(round(stamp * 1e9))
            for topic, maker in messages:
                msg = maker(ns, types)
                if topic not in made:
                    made[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
                writer.write(made[topic], ns, store.serialize_cdr(msg, msg.__msgtype__))
    return path


def room_frames(count=3, *, offset=0.0, topics=BagTopics(), info=True, size=(30, 40), color_encoding=None,
                k=None, distortion=None):
    """Messages of the tiny room's frames on ``topics`` (depth ``offset`` s after colour)."""
    sequence = tiny_sequence()
    height, width = size
    k = np.asarray(sequence.intrinsics.matrix(), np.float64) if k is None else k
    frames = []
    for i in range(count):
        frame = sequence.read_host(i)
        color = cv2.resize(frame.color, (width, height)) if size != (30, 40) else frame.color
        stamp = float(sequence.timestamps[i])
        messages = [(topics.rgb, lambda ns, t, c=color: _encoded(color_message(c, ns, "camera", t), color_encoding)),
                    (topics.depth, lambda ns, t, d=frame.depth: depth_message(d, ns + int(offset * 1e9), "camera", t,
                                                                                1000.0))]
        if info:
            messages.append((topics.camera_info, lambda ns, t: _distorted(camera_info_message(k, 40, 30, ns, "camera",
                                                                                             t), distortion)))
        frames.append((stamp, messages))
    return frames


def _encoded(msg, encoding):
    return msg if encoding is None else dataclasses.replace(msg, encoding=encoding)


def _distorted(msg, distortion):
    if distortion is None:
        return msg
    model, d = distortion
    return dataclasses.replace(msg, distortion_model=model, d=np.asarray(d, np.float64))


def test_topics_are_chosen_by_type_or_named_and_ambiguity_lists_the_candidates(tmp_path):
    second = BagTopics(rgb="/other/color/image_raw")
    frames = room_frames(2)
    for stamp, messages in frames:  # a second colour stream
        messages.append((second.rgb, messages[0][1]))
    bag = write_bag(tmp_path / "two", frames)
    with pytest.raises(DatasetError, match=r"two: 2 colour topics \(/camera/color/image_raw, /other/color/image_raw"
                                           r"\); choose one with --rgb-topic"):
        open_sequence("rosbag", bag)
    chosen = open_sequence("rosbag", bag, bag=BagOptions(rgb_topic="/other/color/image_raw"))
    assert len(chosen) == 2
    with pytest.raises(DatasetError, match=r"no topic /nope \(--depth-topic\); its topics: /camera/aligned_depth"):
        open_sequence("rosbag", bag, bag=BagOptions(rgb_topic="/other/color/image_raw", depth_topic="/nope"))


def test_pairing_reports_what_it_dropped_and_refuses_stamps_that_never_pair(tmp_path):
    frames = room_frames(3)
    frames[1] = (frames[1][0], [m for m in frames[1][1] if "depth" not in m[0]])  # frame 1 lost its depth image
    bag = write_bag(tmp_path / "gap", frames)
    with pytest.warns(DatasetWarning, match=r"paired 2 frames: 1 of 3 colour images .* and 0 of 2 depth images"):
        assert len(open_sequence("rosbag", bag)) == 2
    late = write_bag(tmp_path / "late", room_frames(2, offset=1.0))  # depth a second after its colour
    with pytest.raises(DatasetError, match=r"late: no colour frame .* has a depth image .* within 0.02 s "
                                           r"\(--max-time-diff\)"):
        open_sequence("rosbag", late)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(open_sequence("rosbag", late, bag=BagOptions(max_time_diff=1.1))) == 2


def test_the_camera_comes_from_camera_info_or_intrinsics_and_distortion_is_undone(tmp_path):
    with pytest.raises(DatasetError, match=r"no sensor_msgs/CameraInfo topic and no --intrinsics"):
        open_sequence("rosbag", write_bag(tmp_path / "none", room_frames(1, info=False)))
    given = open_sequence("rosbag", tmp_path / "none", intrinsics=(30.0, 31.0, 19.0, 14.0))
    assert (float(given.intrinsics.fx), float(given.intrinsics.fy)) == (30.0, 31.0)
    k = np.asarray(tiny_sequence().intrinsics.matrix(), np.float64)
    d = (-0.2, 0.05, 0.001, -0.001, 0.0)
    bag = write_bag(tmp_path / "distorted", room_frames(1, distortion=("plumb_bob", d)))
    plain = write_bag(tmp_path / "plain", room_frames(1))
    undone, raw = open_sequence("rosbag", bag).read_host(0), open_sequence("rosbag", plain).read_host(0)
    expected = reference_undistort(raw.color, k, d)
    np.testing.assert_allclose(undone.color, expected, atol=1e-5)  # measured: 5e-7
    assert np.abs(raw.color - expected).mean() > 0.01  # the distortion moved the image
    assert set(np.unique(undone.depth)) <= set(np.unique(raw.depth)) | {0.0}  # nearest: no blended depth
    with pytest.raises(DatasetError, match=r"distortion model 'equidistant' with non-zero coefficients cannot be "
                                           r"undone"):
        open_sequence("rosbag", write_bag(tmp_path / "fisheye", room_frames(1, distortion=("equidistant", d[:4]))))


def reference_undistort(image, k, d):
    """The pinhole image of the same K, by the plumb_bob model in float64 and bilinear sampling (0 outside)."""
    height, width = image.shape[:2]
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x, y = (u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1]
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    ud, vd = k[0, 0] * xd + k[0, 2], k[1, 1] * yd + k[1, 2]
    u0, v0 = np.floor(ud).astype(int), np.floor(vd).astype(int)
    out = np.zeros(image.shape, np.float64)
    for du in (0, 1):
        for dv in (0, 1):
            weight = (1 - np.abs(ud - (u0 + du))) * (1 - np.abs(vd - (v0 + dv)))
            inside = (u0 + du >= 0) & (u0 + du < width) & (v0 + dv >= 0) & (v0 + dv < height)
            sample = image[np.clip(v0 + dv, 0, height - 1), np.clip(u0 + du, 0, width - 1)]
            out += np.where(inside, weight, 0.0)[..., None] * sample
    return out


@pytest.mark.parametrize("case, message", [
    ("not_a_bag", r"not_a_bag.bag: cannot be read as a ROS bag"),
    ("truncated", r"truncated.bag: cannot be read as a ROS bag \(truncated or damaged"),
    ("folder", r"folder: not a ROS 2 bag folder \(no metadata.yaml\)"),
    ("text", r"notes.txt: not a ROS bag"),
    ("empty", r"empty: the bag holds no messages"),
    ("no_depth", r"no_depth: no depth topic \(sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage of depth\)"),
    ("encoding", r"encoding at 0\.0+ s \(/camera/color/image_raw\): colour encoding 'yuv422' is not read"),
    ("sizes", r"sizes: colour \(/camera/color/image_raw\) is 20x16 but depth \(/camera/aligned_depth_to_color/"
              r"image_raw\) is 40x30 \(WxH\)"),
])
def test_bad_bags_give_one_error_naming_the_bag_and_the_problem(tmp_path, case, message):
    if case == "not_a_bag":
        path = tmp_path / "not_a_bag.bag"
        path.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    elif case == "truncated":
        whole = write_rosbag(tiny_sequence(), tmp_path / "whole.bag")
        path = tmp_path / "truncated.bag"
        path.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    elif case == "folder":
        path = tmp_path / "folder"
        path.mkdir()
    elif case == "text":
        path = tmp_path / "notes.txt"
        path.write_text("hello")
    elif case == "empty":
        path = write_bag(tmp_path / "empty", [])
    elif case == "no_depth":
        path = write_bag(tmp_path / "no_depth", [(s, [m for m in ms if "depth" not in m[0]]) for s, ms in
                                                  room_frames(1)])
    elif case == "encoding":
        path = write_bag(tmp_path / "encoding", room_frames(1, color_encoding="yuv422"))
    else:
        path = write_bag(tmp_path / "sizes", room_frames(1, size=(16, 20)))
    with pytest.raises(DatasetError, match=message):
        open_sequence("rosbag", path).read_host(0)


def test_depth_encodings_and_units():
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_HUMBLE).types
    depth = np.array([[0.0, 1.25], [2.5, np.nan]], np.float32)
    mm = depth_message(depth, 0, "camera", types, 1000.0)
    np.testing.assert_array_equal(decode_depth(mm, None, "x"), [[0.0, 1.25], [2.5, 0.0]])  # 16UC1: millimetres
    np.testing.assert_array_equal(decode_depth(mm, 500.0, "x"), [[0.0, 2.5], [5.0, 0.0]])  # --depth-scale
    packed = depth_message(depth, 0, "camera", types, 1000.0, compressed=True)
    np.testing.assert_array_equal(decode_depth(packed, None, "x"), decode_depth(mm, None, "x"))
    metres = dataclasses.replace(mm, encoding="32FC1", step=8, data=np.frombuffer(depth.tobytes(), np.uint8))
    np.testing.assert_array_equal(decode_depth(metres, None, "x"), [[0.0, 1.25], [2.5, 0.0]])  # NaN: invalid


def test_bag_flags_belong_to_bags(tmp_path, capsys):
    assert main(["run", "--out", str(tmp_path / "r"), "--dataset", "synthetic", "--rgb-topic", "/x"]) == 2
    assert "--rgb-topic applies to --dataset rosbag or realsense only" in capsys.readouterr().err
    assert main(["run", "--out", str(tmp_path / "r"), "--dataset", "rosbag", "--path", str(tmp_path / "nope.bag")]) \
        == 2
    assert "no such bag file or folder" in capsys.readouterr().err
