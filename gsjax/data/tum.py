"""TUM RGB-D: reader and writer.

Layout (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats): ``rgb.txt`` and ``depth.txt`` list
``timestamp filename`` per line, ``groundtruth.txt`` lists ``timestamp tx ty tz qx qy qz qw`` (camera-to-world,
m), lines starting with ``#`` are comments; depth is 16-bit PNG with 5000 units per metre, 0 invalid.

A list whose timestamps are out of order is sorted, and a timestamp listed twice keeps its first line, each with a
:class:`DatasetWarning` naming the list file.

Association (as TUM's ``associate.py``): colour and depth timestamps are paired one-to-one, greedily by smallest
time difference, within 0.02 s; a colour frame with no depth partner is dropped, and so is a depth image with no
colour partner (each with a warning giving the count; an error when no pair is left). Each kept frame takes the
ground-truth sample nearest in time if it lies within 0.02 s; otherwise its pose is flagged invalid. Samples that
are not finite or whose quaternion is far from unit length are left out, with a warning. The frame's timestamp is
its colour timestamp.

Intrinsics, first found wins: the ``intrinsics`` argument (an Intrinsics, or (fx, fy, cx, cy) at the size of the
first depth image); ``intrinsics.json`` beside ``rgb.txt`` (``fx, fy, cx, cy`` and optionally ``width, height``,
else the first colour image's size); the Freiburg camera named by the directory (``freiburg1``/``fr1``... in its
name or its parent's), with the values of the TUM documentation at 640x480. Lens distortion (fr1, fr2) is not
modelled, as in SplaTAM.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from gsjax.camera import Intrinsics, make_intrinsics, quaternion_to_rotation_np
from gsjax.data.errors import DatasetError, DatasetWarning
from gsjax.data.images import image_size
from gsjax.data.listing import FrameFiles, GivenIntrinsics, given_intrinsics, read_json_numbers
from gsjax.data.poses import data_lines, parse_numbers, warn_bad_poses
from gsjax.data.sequence import Sequence
from gsjax.eval.association import associate_timestamps
from gsjax.io.atomic import atomic_write_json, atomic_write_text
from gsjax.io.trajectory import write_tum_trajectory

DEPTH_SCALE = 5000.0  # raw units per metre
MAX_TIME_DIFFERENCE = 0.02  # s, for colour-depth and colour-groundtruth association
# Freiburg camera intrinsics (fx, fy, cx, cy) at 640x480 from the TUM RGB-D documentation.
FREIBURG_INTRINSICS = {
    1: (517.3, 516.5, 318.6, 255.3),
    2: (520.9, 521.0, 325.1, 249.7),
    3: (535.4, 539.2, 320.1, 247.6),
}
_FREIBURG_NAME = re.compile(r"(?:^|[^a-z0-9])(?:freiburg|fr)([123])(?:[^0-9]|$)", re.IGNORECASE)


def list_tum(path: Path, intrinsics: GivenIntrinsics = None) -> FrameFiles:
    """List a TUM RGB-D sequence directory (see the module docstring); no image is decoded except, at most, one
    colour image for its size when ``intrinsics.json`` gives none."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: TUM sequence directory is missing")
    rgb_times, rgb_names = _read_file_list(path / "rgb.txt")
    depth_times, depth_names = _read_file_list(path / "depth.txt")
    if not rgb_times.size:
        raise DatasetError(f"{path / 'rgb.txt'}: empty sequence (no colour frames listed)")
    rgb_idx, depth_idx = associate(rgb_times, depth_times, MAX_TIME_DIFFERENCE)
    if not rgb_idx.size:
        raise DatasetError(
            f"{path / 'depth.txt'}: no depth association: none of the {rgb_times.size} colour timestamps has a depth "
            f"timestamp within {MAX_TIME_DIFFERENCE} s"
        )
    # Each warning names the list whose entries are left unused.
    for listed, paired, name, other in ((rgb_times, rgb_idx, "rgb.txt", "colour frames have no depth image"),
                                        (depth_times, depth_idx, "depth.txt", "depth images have no colour frame")):
        if paired.size < listed.size:
            warnings.warn(f"{path / name}: {listed.size - paired.size} of {listed.size} {other} within "
                          f"{MAX_TIME_DIFFERENCE} s and are skipped", DatasetWarning, stacklevel=2)
    times = rgb_times[rgb_idx]
    c2w, valid = read_groundtruth_at(path / "groundtruth.txt", times)
    depth_paths = [path / depth_names[i] for i in depth_idx]
    camera = given_intrinsics(intrinsics, depth_paths[0])
    return FrameFiles(
        name=path.name,
        color_paths=[path / rgb_names[i] for i in rgb_idx],
        depth_paths=depth_paths,
        timestamps=times,
        c2w=c2w,
        pose_valid=valid,
        intrinsics=camera if camera is not None else _tum_intrinsics(path, path / rgb_names[rgb_idx[0]]),
        depth_scale=DEPTH_SCALE,
    )


def associate(first: np.ndarray, second: np.ndarray, max_difference: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs (i, j) with |first[i] - second[j]| <= max_difference, chosen greedily by smallest
    difference (TUM's associate.py) -> (i [P], j [P]) sorted by i.

    For colour/depth pairing: two streams at the same rate, where each image may be used once, so a colour frame
    loses its nearest depth image to a nearer colour frame (and then takes the next free one or none). Not
    :func:`gsjax.eval.association.associate_timestamps`, the nearest-neighbour rule for poses, under which two
    colour frames could share one depth image."""
    order = np.argsort(second)
    sorted_second = second[order]
    candidates = []
    for i, t in enumerate(first):
        lo, hi = np.searchsorted(sorted_second, [t - max_difference, t + max_difference], side="left")
        for k in range(lo, min(hi + 1, len(sorted_second))):
            difference = abs(sorted_second[k] - t)
            if difference <= max_difference:
                candidates.append((difference, i, int(order[k])))
    used_first, used_second, pairs = set(), set(), []
    for _, i, j in sorted(candidates):
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    pairs.sort()
    return np.array([p[0] for p in pairs], np.int64), np.array([p[1] for p in pairs], np.int64)


def _read_file_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """``timestamp filename`` lines -> (timestamps [N] float64 strictly ascending, file names [N]); out-of-order
    lines are sorted and repeated timestamps keep their first line, each with a warning naming ``path``."""
    entries, lines = [], []
    for n, line in data_lines(path):
        fields = line.split()
        if len(fields) < 2:
            raise DatasetError(f"{path}:{n}: expected 'timestamp filename', got {line.strip()[:80]!r}")
        try:
            stamp = float(fields[0])
        except ValueError:
            raise DatasetError(f"{path}:{n}: cannot parse timestamp {fields[0]!r}") from None
        if not np.isfinite(stamp):
            raise DatasetError(f"{path}:{n}: timestamp {fields[0]!r} is not a finite number")
        entries.append((stamp, fields[1]))
        lines.append(n)
    stamps = np.array([e[0] for e in entries], np.float64)
    backwards = np.flatnonzero(np.diff(stamps) < 0)
    if backwards.size:
        k = int(backwards[0]) + 1
        warnings.warn(f"{path}:{lines[k]}: timestamps out of order ({stamps[k]:.6f} after {stamps[k - 1]:.6f}, "
                      f"{backwards.size} such line(s)); the list is sorted by timestamp", DatasetWarning, stacklevel=3)
    order = np.argsort(stamps, kind="stable")  # repeats stay in file order: the first line comes first
    repeated = np.flatnonzero(np.diff(stamps[order]) == 0) + 1
    if repeated.size:
        k = int(order[repeated[0]])
        warnings.warn(f"{path}:{lines[k]}: timestamp {stamps[k]:.6f} is listed more than once ({repeated.size} "
                      f"repeated line(s)); each repeat is dropped, the first line kept", DatasetWarning, stacklevel=3)
    keep = np.delete(order, repeated)
    return stamps[keep], [entries[i][1] for i in keep]


def read_groundtruth_at(path: Path, times: np.ndarray,
                        max_dt: float = MAX_TIME_DIFFERENCE) -> tuple[np.ndarray, np.ndarray]:
    """The nearest pose of the TUM trajectory file ``path`` within ``max_dt`` s of each of ``times`` [T] s ->
    (c2w [T, 4, 4], valid [T]); all invalid when the file is absent (TUM's test sequences have none). Non-finite
    samples and samples whose quaternion is not of unit length are left out, with a warning.

    Nearest neighbour, the rule of trajectory evaluation (:func:`gsjax.eval.association.associate_timestamps`), not
    :func:`associate`'s one-to-one matching: GT is sampled far faster than the frames (100 Hz vs 30 Hz), so each
    frame simply takes its nearest sample."""
    c2w, valid = np.tile(np.eye(4), (times.size, 1, 1)), np.zeros(times.size, bool)
    lines = data_lines(path) if path.exists() else []
    rows = np.stack([parse_numbers(line, 8, f"{path}:{n}") for n, line in lines]) if lines else np.zeros((0, 8))
    where = [f"{path}:{n}" for n, _ in lines]
    finite = np.isfinite(rows).all(axis=-1)
    quat_norm = np.linalg.norm(np.where(finite[:, None], rows[:, 4:], 0.5), axis=-1)  # non-finite rows: norm 1
    rigid = np.abs(quat_norm - 1.0) <= 1e-2
    warn_bad_poses(where, ~finite, "pose has non-finite values")
    if not rigid.all():
        norm = quat_norm[np.flatnonzero(~rigid)[0]]
        warn_bad_poses(where, ~rigid, f"pose is not a rigid transform (quaternion norm {norm:.4g}, not 1)")
    rows = rows[finite & rigid]
    frame_idx, row_idx = associate_timestamps(times, rows[:, 0], max_dt)
    picked = rows[row_idx]
    q_xyzw = picked[:, 4:] / np.linalg.norm(picked[:, 4:], axis=-1, keepdims=True)
    c2w[frame_idx, :3, :3] = quaternion_to_rotation_np(np.roll(q_xyzw, 1, axis=-1))
    c2w[frame_idx, :3, 3] = picked[:, 1:4]
    valid[frame_idx] = True
    return c2w, valid


def _tum_intrinsics(path: Path, first_color: Path) -> Intrinsics:
    json_path = path / "intrinsics.json"
    if json_path.exists():
        values = read_json_numbers(json_path, ("fx", "fy", "cx", "cy"), ("width", "height"))
        if "width" in values and "height" in values:
            height, width = int(values["height"]), int(values["width"])
        else:
            height, width = image_size(first_color)
        try:
            return make_intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], height, width)
        except ValueError as err:
            raise DatasetError(f"{json_path}: {err}") from None
    for name in (path.resolve().name, path.resolve().parent.name):
        match = _FREIBURG_NAME.search(name)
        if match:
            return make_intrinsics(*FREIBURG_INTRINSICS[int(match.group(1))], height=480, width=640)
    raise DatasetError(
        f"{path}: cannot determine the camera intrinsics: no intrinsics.json beside rgb.txt and the directory name "
        "names no Freiburg camera (freiburg1/2/3 or fr1/2/3); give them with --intrinsics FX,FY,CX,CY "
        "(open_sequence(..., intrinsics=(fx, fy, cx, cy))) or in an intrinsics.json beside rgb.txt"
    )


def write_tum(sequence: Sequence, out_dir: Path) -> Path:
    """Write a sequence in the TUM RGB-D layout that :func:`list_tum` reads back.

    Colour as 8-bit PNG (rounded), depth as 16-bit PNG with 5000 units per metre (rounded; depths beyond
    65535 / 5000 = 13.1 m are an error), ``groundtruth.txt`` (:func:`gsjax.io.trajectory.write_tum_trajectory`)
    with a line for each frame with a valid pose only (a missing pose has no line, as in TUM's own files), and
    ``intrinsics.json`` (fx, fy, cx, cy, width, height). Every file is written atomically.

    Args:
      sequence: the frames (read one at a time) and their ground truth.
      out_dir: the sequence directory (created if missing).

    Returns:
      ``out_dir``.
    """
    from gsjax.io.images import save_color_png, save_depth_png  # imported here: it pulls in matplotlib

    out_dir = Path(out_dir)
    (out_dir / "rgb").mkdir(parents=True, exist_ok=True)
    (out_dir / "depth").mkdir(parents=True, exist_ok=True)
    times, c2w, valid = sequence.gt_trajectory()
    rgb_lines = ["# color images", f"# file: '{sequence.name}'", "# timestamp filename"]
    depth_lines = ["# depth maps", f"# file: '{sequence.name}'", "# timestamp filename"]
    for i, stamp in enumerate(times):
        frame = sequence.read_host(i)
        name = f"{stamp:.6f}.png"
        save_depth_png(out_dir / "depth" / name, frame.depth, scale=DEPTH_SCALE)
        save_color_png(out_dir / "rgb" / name, frame.color)
        rgb_lines.append(f"{stamp:.6f} rgb/{name}")
        depth_lines.append(f"{stamp:.6f} depth/{name}")
    k = sequence.intrinsics
    calib = {name: float(getattr(k, name)) for name in ("fx", "fy", "cx", "cy")}
    calib |= {"width": k.width, "height": k.height}
    atomic_write_json(out_dir / "intrinsics.json", calib)
    for file_name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines)):
        atomic_write_text(out_dir / file_name, "\n".join(lines) + "\n")
    write_tum_trajectory(out_dir / "groundtruth.txt", times[valid], c2w[valid])
    return out_dir
