"""A corpus of bad inputs to ``gsjax run``, built on the fly from tiny recordings in the TUM and 7-Scenes layouts.

Every case gets an answer and loses nothing:
* an error: exit status 2, exactly one line ``gsjax run: error: ...`` on stderr naming the file or option at fault,
  no traceback; or
* a defined behaviour: the run finishes (exit 0) and a ``warning: ...`` line naming the file (or option) is printed
  and listed in ``metrics.json``'s ``warnings``;
and in both the input recording, and any previous run in ``--out``, are byte-identical afterwards.

The recordings are the 40x30 synthetic room of the SLAM tests (``FRAMES`` frames), and the runs use the same tiny
iteration counts and chunk, so every run reuses one compiled SLAM program.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.data import DatasetError, write_tum
from tests.support.recordings import write_sevenscenes
from tests.support.tiny_slam import CHUNK, FRAMES, HEIGHT, TINY_OVERRIDES, WIDTH, tiny_sequence

RUN_OPTIONS = ["--chunk", str(CHUNK), "--checkpoint-every", str(CHUNK), "--no-progress"] + [
    token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]
LAYOUTS = {"tum": "tum", "7scenes": "7scenes"}


# ------------------------------------------------------------------------------------------------- recordings


def _write_sevenscenes(root: Path) -> Path:
    sequence = tiny_sequence()
    host = [sequence.read_host(i) for i in range(len(sequence))]
    colors = np.stack([np.round(np.asarray(f.color) * 255).astype(np.uint8) for f in host])
    depths = np.stack([np.asarray(f.depth, np.float64) for f in host])
    return write_sevenscenes(root, (sequence.intrinsics, colors, depths, sequence.gt_trajectory()[1]))


@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bases")
    return {"tum": write_tum(tiny_sequence(), root / "tum" / "my_room"), "7scenes": _write_sevenscenes(root / "7s")}


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory, bases) -> Path:
    """A successful run on the clean TUM recording: the previous run of the --out cases, and the reference of the
    warnings that must not change the result."""
    out = tmp_path_factory.mktemp("clean") / "run"
    assert main(["run", "--dataset", "tum", "--path", str(bases["tum"]), "--out", str(out)] + RUN_OPTIONS) == 0
    return out


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes; ``root`` itself if it is a file); empty when it does not
    exist."""
    if root.is_file():
        return {".": root.read_bytes()}
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------------------------- case helpers


def data_lines(path: Path) -> tuple[list[str], list[int]]:
    """All lines of a list file and the positions of its data (non-comment) lines."""
    lines = path.read_text().splitlines()
    return lines, [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]


def edit_lines(path: Path, edit: Callable[[list[str], list[int]], None]) -> None:
    lines, data = data_lines(path)
    edit(lines, data)
    path.write_text("\n".join(lines) + "\n")


def listed(rec: Path, list_name: str, k: int) -> Path:
    """The file of data line k of ``rgb.txt`` / ``depth.txt``."""
    lines, data = data_lines(rec / list_name)
    return rec / lines[data[k]].split()[1]


def line_number(rec: Path, list_name: str, k: int) -> str:
    """``path:N``, the 1-based line of data line k."""
    return f"{rec / list_name}:{data_lines(rec / list_name)[1][k] + 1}"


def write_depth(path: Path, depth_m: np.ndarray, scale: float) -> None:
    assert cv2.imwrite(str(path), np.round(depth_m * scale).astype(np.uint16))


def tum_depth(rec: Path, k: int) -> Path:
    return listed(rec, "depth.txt", k)


def scenes_file(rec: Path, k: int, kind: str) -> Path:
    return rec / f"frame-{k:06d}.{kind}"


@dataclasses.dataclass(frozen=True)
class Case:
    """One bad input: ``setup(rec, out) -> (extra args, the text the message must name)`` changes the copied
    recording (or prepares ``out``); ``pattern`` is a regex the message must match."""

    name: str
    layout: str
    setup: Callable[[Path, Path], tuple[list[str], str]]
    pattern: str


def _unlink(path: Path, named: Path | None = None) -> tuple[list[str], str]:
    path.unlink()
    return [], str(named or path)


def _replace_text(path: Path, text: str, named: str | None = None):
    path.write_text(text)
    return [], named or str(path)


def _args(*args: str, named: str):
    return list(args), named


def _corrupt(path: Path):
    path.write_bytes(b"this is not an image")
    return [], str(path)


def _small_colour(path: Path):
    assert cv2.imwrite(str(path), np.zeros((HEIGHT // 2, WIDTH // 2, 3), np.uint8))
    return [], str(path)


def _eight_bit_depth(path: Path):
    assert cv2.imwrite(str(path), np.full((HEIGHT, WIDTH), 200, np.uint8))
    return [], str(path)


def _shift_depth_stamps(rec: Path):
    def edit(lines, data):
        for i in data:
            stamp, name = lines[i].split()
            lines[i] = f"{float(stamp) + 1.0:.6f} {name}"

    edit_lines(rec / "depth.txt", edit)
    return [], str(rec / "depth.txt")


def _line_without_file(rec: Path):
    edit_lines(rec / "rgb.txt", lambda lines, data: lines.append("1.500000"))
    return [], f"{rec / 'rgb.txt'}:{len((rec / 'rgb.txt').read_text().splitlines())}"


def _bad_stamp(rec: Path):
    named = line_number(rec, "rgb.txt", 2)
    edit_lines(rec / "rgb.txt", lambda lines, data: lines.__setitem__(data[2], "noon " + lines[data[2]].split()[1]))
    return [], named


def _gt_unparsable(rec: Path):
    edit_lines(rec / "groundtruth.txt", lambda lines, data: lines.append("0.5 0 0 zero 0 0 0 1"))
    return [], f"{rec / 'groundtruth.txt'}:{len((rec / 'groundtruth.txt').read_text().splitlines())}"


def _out_is_file(rec: Path, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("my notes\n")
    return [], f"--out {out}"


def _out_under_file(rec: Path, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("my notes\n")
    return ["--out", str(out / "run")], f"--out {out / 'run'}"


def _out_not_empty(rec: Path, out: Path):
    out.mkdir(parents=True)
    (out / "thesis.tex").write_text("\\documentclass{article}\n")
    return [], f"--out {out}"


def _short_pose_row(path: Path):
    path.write_text("1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n")
    return [], f"{path}:2"


ERRORS = [
    # TUM layout: the lists
    Case("rgb list missing", "tum", lambda r, o: _unlink(r / "rgb.txt"), r"file is missing"),
    Case("depth list missing", "tum", lambda r, o: _unlink(r / "depth.txt"), r"file is missing"),
    Case("list line without a file name", "tum", lambda r, o: _line_without_file(r),
         r"expected 'timestamp filename'"),
    Case("unparsable timestamp", "tum", lambda r, o: _bad_stamp(r), r"cannot parse timestamp 'noon'"),
    Case("empty colour list", "tum", lambda r, o: _replace_text(r / "rgb.txt", "# timestamp filename\n"),
         r"empty sequence"),
    Case("no colour-depth association", "tum", lambda r, o: _shift_depth_stamps(r), r"no depth association"),
    # TUM layout: the images
    Case("listed colour image missing", "tum", lambda r, o: _unlink(listed(r, "rgb.txt", 2)), r"image is missing"),
    Case("listed depth image missing", "tum", lambda r, o: _unlink(tum_depth(r, 3)), r"image is missing"),
    Case("colour image corrupt", "tum", lambda r, o: _corrupt(listed(r, "rgb.txt", 0)), r"cannot be read"),
    Case("depth image 8-bit", "tum", lambda r, o: _eight_bit_depth(tum_depth(r, 0)),
         r"must be 16-bit unsigned or float, got uint8"),
    Case("colour and depth sizes differ", "tum", lambda r, o: _small_colour(listed(r, "rgb.txt", 0)),
         r"colour image is 20x15 \(WxH\) but its depth image .* is 40x30"),
    # TUM layout: camera and ground truth
    Case("no intrinsics", "tum", lambda r, o: _unlink(r / "intrinsics.json", named=r), r"--intrinsics FX,FY,CX,CY"),
    Case("intrinsics.json malformed", "tum", lambda r, o: _replace_text(r / "intrinsics.json", '{"fx": 30}'),
         r"cannot read fx, fy, cx, cy"),
    Case("groundtruth line unparsable", "tum", lambda r, o: _gt_unparsable(r), r"cannot parse numbers"),
    # options
    Case("--intrinsics with three numbers", "tum", lambda r, o: _args("--intrinsics", "30,30,20", named="--intrinsics"),
         r"expected FX,FY,CX,CY: four numbers"),
    Case("--intrinsics with a negative focal length", "tum",
         lambda r, o: _args("--intrinsics=-30,30,20,15", named="--intrinsics"), r"FX and FY must be > 0"),
    Case("--intrinsics for another image size", "tum",
         lambda r, o: _args("--intrinsics", "525,525,319.5,239.5", named="--intrinsics"),
         r"principal point \(319.5, 239.5\) lies outside the 40x30 images"),
    Case("--depth-scale 0", "tum", lambda r, o: _args("--depth-scale", "0", named="--depth-scale"),
         r"expected a number > 0"),
    Case("--depth-scale not a number", "tum", lambda r, o: _args("--depth-scale", "mm", named="--depth-scale"),
         r"expected a number > 0"),
    Case("--downscale larger than the image", "tum", lambda r, o: _args("--downscale", "64", named="--downscale 64"),
         r"leaves no pixel of the 40x30 images"),
    Case("--max-frames 0", "tum", lambda r, o: _args("--max-frames", "0", named="--max-frames"), r"must be >= 1"),
    Case("--path missing", "tum", lambda r, o: _args("--path", str(r / "nowhere"), named=f"--path {r / 'nowhere'}"),
         r"no such directory"),
    Case("--out an existing file", "tum", _out_is_file, r"is an existing file, not a directory"),
    Case("--out under a file", "tum", _out_under_file, r"cannot be created: .* is a file"),
    Case("--out not empty, not a run", "tum", _out_not_empty, r"is not empty and holds no gsjax run"),
    Case("--resume with --overwrite", "tum", lambda r, o: _args("--resume", "--overwrite", named="--overwrite"),
         r"not allowed with argument --resume"),
    Case("--viewer-host not of this machine", "tum",
         lambda r, o: _args("--viewer", "--viewer-host", "10.255.255.1", named="'10.255.255.1'"),
         r"viewer cannot listen on host"),
    Case("--viewer-port out of range", "tum", lambda r, o: _args("--viewer", "--viewer-port", "70000",
                                                                  named="--viewer-port"), r"port number 0-65535"),
    Case("--raster.backend unknown", "tum", lambda r, o: _args("--raster.backend", "cuda", named="--raster.backend"),
         r"must be one of auto, xla, pallas, got 'cuda'"),
    # 7-Scenes layout
    Case("7-Scenes colour image missing", "7scenes", lambda r, o: _unlink(scenes_file(r, 2, "color.png")),
         r"colour image is missing \(its depth image frame-000002.depth.png is present"),
    Case("7-Scenes depth image missing", "7scenes", lambda r, o: _unlink(scenes_file(r, 3, "depth.png")),
         r"image is missing"),
    Case("7-Scenes colour image corrupt", "7scenes", lambda r, o: _corrupt(scenes_file(r, 0, "color.png")),
         r"cannot be read"),
    Case("7-Scenes calibration not pinhole", "7scenes",
         lambda r, o: _replace_text(r / "camera-intrinsics.txt", "25 3 16\n0 25 12\n0 0 1\n"),
         r"not a pinhole calibration matrix"),
    Case("7-Scenes pose file unparsable", "7scenes", lambda r, o: _short_pose_row(scenes_file(r, 1, "pose.txt")),
         r"expected 4 numbers, got 3"),
]


def _copy(bases, layout: str, tmp_path: Path) -> Path:
    rec = tmp_path / "data" / bases[layout].name
    shutil.copytree(bases[layout], rec)
    return rec


def _run(layout: str, rec: Path, out: Path, extra: list[str], capsys) -> tuple[int, str, str]:
    args = ["run", "--dataset", layout, "--path", str(rec), "--out", str(out)] + RUN_OPTIONS + extra
    status = main(args)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return status, captured.out, captured.err


@pytest.mark.parametrize("case", ERRORS, ids=[case.name for case in ERRORS])
def test_a_bad_input_exits_2_with_one_line_naming_it_and_changes_nothing(tmp_path, bases, case, capsys):
    rec, out = _copy(bases, case.layout, tmp_path), tmp_path / "out" / "run"
    extra, named = case.setup(rec, out)
    before, out_before = snapshot(rec), snapshot(out)
    status, _, err = _run(case.layout, rec, out, extra, capsys)
    lines = err.strip().splitlines()
    assert status == 2, err
    assert len(lines) == 1 and lines[0].startswith("gsjax run: error: "), err
    assert named in lines[0], lines[0]
    assert re.search(case.pattern, lines[0]), lines[0]
    assert snapshot(rec) == before
    assert snapshot(out) == out_before
    if not out_before:
        assert not out.exists()


def test_out_holding_a_previous_run_is_refused_without_touching_a_byte(tmp_path, bases, clean_run, capsys):
    out = tmp_path / "previous"
    shutil.copytree(clean_run, out)
    before = snapshot(out)
    status, _, err = _run("tum", bases["tum"], out, [], capsys)
    assert status == 2 and err.strip().splitlines() == [err.strip()], err
    assert f"--out {out} holds a previous run" in err and "--resume" in err and "--overwrite" in err
    assert snapshot(out) == before


def test_overwrite_replaces_a_previous_run_and_keeps_other_files(tmp_path, bases, clean_run, capsys):
    out = tmp_path / "previous"
    shutil.copytree(clean_run, out)
    (out / "notes.txt").write_text("mine\n")
    (out / "renders" / "stale.png").write_bytes(b"old")
    status, _, err = _run("tum", bases["tum"], out, ["--overwrite"], capsys)
    assert status == 0, err
    assert (out / "notes.txt").read_text() == "mine\n" and not (out / "renders" / "stale.png").exists()
    for name in ("trajectory.txt", "map.ply"):
        assert (out / name).read_bytes() == (clean_run / name).read_bytes(), name


def test_debug_shows_the_traceback(tmp_path, bases):
    rec = _copy(bases, "tum", tmp_path)
    listed(rec, "rgb.txt", 1).unlink()
    with pytest.raises(DatasetError, match="image is missing"):
        main(["run", "--dataset", "tum", "--path", str(rec), "--out", str(tmp_path / "o"), "--debug"] + RUN_OPTIONS)


# ------------------------------------------------------------------------------------------ defined behaviours


def _swap_lines(rec: Path, list_name: str):
    def edit(lines, data):
        lines[data[1]], lines[data[3]] = lines[data[3]], lines[data[1]]

    edit_lines(rec / list_name, edit)
    return [], line_number(rec, list_name, 2)  # the first line whose timestamp goes back


def _repeat_line(rec: Path, list_name: str):
    edit_lines(rec / list_name, lambda lines, data: lines.insert(data[2] + 1, lines[data[2]]))
    return [], line_number(rec, list_name, 3)


def _extra_depth(rec: Path):
    def edit(lines, data):
        lines.append(f"99.000000 {lines[data[0]].split()[1]}")

    edit_lines(rec / "depth.txt", edit)
    return [], str(rec / "depth.txt")


def _zero_depth(path: Path, scale: float):
    write_depth(path, np.zeros((HEIGHT, WIDTH)), scale)
    return [], str(path)


def _gt_line(rec: Path, k: int, values: str):
    lines, data = data_lines(rec / "groundtruth.txt")
    lines[data[k]] = f"{lines[data[k]].split()[0]} {values}"
    (rec / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return [], f"{rec / 'groundtruth.txt'}:{data[k] + 1}"


def _drop_gt_line(rec: Path, k: int):
    edit_lines(rec / "groundtruth.txt", lambda lines, data: lines.pop(data[k]))
    return [], ""


def _scaled_pose(path: Path):
    pose = np.loadtxt(path)
    pose[:3, :3] *= 1.2
    np.savetxt(path, pose)
    return [], str(path)


@dataclasses.dataclass(frozen=True)
class Handled(Case):
    """A bad input with a defined behaviour: ``check(metrics, out, clean_run)`` asserts what the run did."""

    check: Callable[[dict, Path, Path], None] = lambda metrics, out, clean: None


def same_as_clean(metrics, out, clean):
    """Sorting, dropping repeats or unpaired images restores the clean recording: the very same run."""
    for name in ("trajectory.txt", "map.ply"):
        assert (out / name).read_bytes() == (clean / name).read_bytes(), name


def skipped(*frames_):
    def check(metrics, out, clean):
        assert metrics["skipped_frames"] == list(frames_)
        assert metrics["frames"] == FRAMES and metrics["trajectory"]["num_evaluated"] == FRAMES

    return check


def evaluated(count):
    def check(metrics, out, clean):
        assert metrics["trajectory"]["num_evaluated"] == count and metrics["skipped_frames"] == []
        assert (out / "map.ply").is_file() and metrics["frames"] == FRAMES

    return check


HANDLED = [
    Handled("colour list out of order", "tum", lambda r, o: _swap_lines(r, "rgb.txt"),
            r"timestamps out of order .*; the list is sorted", same_as_clean),
    Handled("colour list with a repeated line", "tum", lambda r, o: _repeat_line(r, "rgb.txt"),
            r"listed more than once .*; each repeat is dropped", same_as_clean),
    Handled("depth list with a repeated line", "tum", lambda r, o: _repeat_line(r, "depth.txt"),
            r"listed more than once", same_as_clean),
    Handled("depth image without a colour frame", "tum", lambda r, o: _extra_depth(r),
            r"1 of 7 depth images have no colour frame within 0.02 s and are skipped", same_as_clean),
    Handled("all-zero depth frame", "tum", lambda r, o: _zero_depth(tum_depth(r, 3), 5000.0),
            r"frame 3 .*: only 0.0% of the pixels have valid depth .* constant-velocity prediction", skipped(3)),
    Handled("first frame without depth", "tum", lambda r, o: _zero_depth(tum_depth(r, 0), 5000.0),
            r"frame 0 .*the map starts at the first frame with depth", skipped(0)),
    Handled("depth in the wrong unit", "tum", lambda r, o: _args("--depth-scale", "50", named="--depth-scale"),
            r"median depth .* m is outside 0.1-20 m; the depth scale \(50 raw units per metre\) looks wrong"),
    Handled("non-finite ground-truth pose", "tum", lambda r, o: _gt_line(r, 2, "nan 0 0 0 0 0 1"),
            r"pose has non-finite values; left out of the evaluation", evaluated(FRAMES - 1)),
    Handled("non-rigid ground-truth pose", "tum", lambda r, o: _gt_line(r, 2, "0 0 0 0 0 0 2"),
            r"not a rigid transform \(quaternion norm 2, not 1\); left out of the evaluation", evaluated(FRAMES - 1)),
    Handled("7-Scenes non-rigid pose", "7scenes", lambda r, o: _scaled_pose(scenes_file(r, 4, "pose.txt")),
            r"not a rigid transform .*left out of the evaluation", evaluated(FRAMES - 1)),
    Handled("7-Scenes non-finite pose", "7scenes",
            lambda r, o: _replace_text(scenes_file(r, 1, "pose.txt"), "nan nan nan nan\n" * 4),
            r"pose has non-finite values", evaluated(FRAMES - 1)),
    Handled("7-Scenes all-zero depth frame", "7scenes", lambda r, o: _zero_depth(scenes_file(r, 2, "depth.png"), 1e3),
            r"frame 2 .*: only 0.0% of the pixels have valid depth", skipped(2)),
]


@pytest.mark.parametrize("case", HANDLED, ids=[case.name for case in HANDLED])
def test_a_handled_input_runs_with_a_warning_naming_it(tmp_path, bases, clean_run, case, capsys):
    rec, out = _copy(bases, case.layout, tmp_path), tmp_path / "out" / "run"
    extra, named = case.setup(rec, out)
    before = snapshot(rec)
    status, _, err = _run(case.layout, rec, out, extra, capsys)
    assert status == 0, err
    warned = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert len(warned) == 1, err
    assert named in warned[0] and re.search(case.pattern, warned[0]), warned[0]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["warnings"] == [warned[0].removeprefix("warning: ")]
    case.check(metrics, out, clean_run)
    assert snapshot(rec) == before


def test_frame_zero_without_ground_truth_is_evaluated_on_the_other_frames(tmp_path, bases, capsys):
    rec = _copy(bases, "tum", tmp_path)
    _drop_gt_line(rec, 0)
    out = tmp_path / "run"
    status, _, err = _run("tum", rec, out, [], capsys)
    assert status == 0 and "warning" not in err, err
    evaluated(FRAMES - 1)(json.loads((out / "metrics.json").read_text()), out, None)



def test_a_frame_unreadable_mid_run_stops_with_one_line_and_the_run_resumes_once_fixed(tmp_path, bases, clean_run,
                                                                                       capsys):
    rec, out = _copy(bases, "tum", tmp_path), tmp_path / "run"
    bad = listed(rec, "rgb.txt", CHUNK + 1)  # in the second chunk: the first is done and checkpointed
    good = bad.read_bytes()
    _corrupt(bad)
    status, _, err = _run("tum", rec, out, [], capsys)
    assert status == 2 and err.strip().splitlines() == [f"gsjax run: error: {bad}: colour image cannot be read "
                                                        "(not an image OpenCV can decode)"], err
    bad.write_bytes(good)
    status, _, err = _run("tum", rec, out, [], capsys)
    assert status == 2 and "holds a previous run" in err  # nothing is redone or lost by accident
    status, _, err = _run("tum", rec, out, ["--resume"], capsys)
    assert status == 0, err
    same_as_clean(None, out, clean_run)
