"""A 1000-frame run of the synthetic scene (``make test-slow``): no NaN, memory and time per frame flat across
chunks, the Gaussian count within the capacity policy, and checkpoint size and time that do not grow with the run
(``experiments/long_run.py``'s :func:`long_run`, which also takes the same measurement and writes it to
``experiments/results``)."""

from __future__ import annotations

import json
import math
import os
import statistics
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
from long_run import long_run

pytestmark = pytest.mark.slow
FRAMES = 1000


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    work = Path(os.environ["GSJAX_SLOW_WORK"]) if os.environ.get("GSJAX_SLOW_WORK") else tmp_path_factory.mktemp("w")
    result = long_run(FRAMES, work / "long_run")
    (work / "long_run.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def test_a_1000_frame_run_has_no_nan_and_tracks(measured):
    """No NaN anywhere, and a trajectory far better than standing still (experiments/README.md has the numbers;
    this test guards the numerics of a long run, the next one its map, the tracking table's rows accuracy)."""
    assert measured["all_poses_finite"] and math.isfinite(measured["ate_cm"])
    assert measured["nonfinite_gaussians"] == 0 and not measured["diverged_frames"]
    assert measured["ate_cm"] < 0.5 * measured["constant_pose_cm"]


def test_the_map_stays_healthy_over_1000_frames(measured):
    """At 40 px the map no longer thins out: the active Gaussians at frame 1000 are at least 80 % of those at frame
    100 (measured 1497 vs 1324), the ATE stays under 3 cm (2.15) and the final map renders at 22 dB or better
    (23.2; the issue's goal is 25: over 1000 frames the room is passed many times, and the map superposes the
    passes at poses up to ~4.5 cm / 1.4 deg apart). Before the pruning bound followed the pixel footprint and
    colours were bounded: 1175 -> 369 Gaussians, 13 dB, 9.1 cm."""
    counts = measured["gaussians_per_100"]
    assert counts[-1] >= 0.8 * counts[0], counts
    assert measured["psnr_db"] >= 22.0
    assert measured["ate_cm"] <= 3.0


def test_memory_and_time_per_frame_stay_flat(measured):
    marks = measured["marks"]  # after the first chunk past each multiple of 100 frames
    assert [m["frames"] // 100 for m in marks] == list(range(1, FRAMES // 100 + 1)) and marks[-1]["frames"] == FRAMES
    settled = marks[1]["rss_mib"]  # after the first chunks' compilations
    assert marks[-1]["rss_mib"] - settled < 0.05 * settled + 32, [m["rss_mib"] for m in marks]
    assert marks[-1]["peak_rss_mib"] - marks[1]["peak_rss_mib"] < 0.05 * settled + 32
    steady = [m["s_per_frame"] for m in marks[1:]]
    assert max(steady) < 1.5 * min(steady), steady


def test_the_gaussian_count_follows_the_capacity_policy(measured):
    """The capacity starts at 2 H W and only doubles when a chunk could not insert every new Gaussian."""
    capacity, initial = measured["capacity"], measured["initial_capacity"]
    assert capacity >= initial and (capacity // initial) & (capacity // initial - 1) == 0 and capacity % initial == 0
    assert measured["max_gaussians"] <= capacity
    if capacity > initial:
        assert measured["max_gaussians"] + measured["max_added"] > capacity // 2


def test_checkpoint_size_and_time_do_not_grow_with_the_run(measured):
    """At one capacity, a checkpoint writes the map plus a frame segment and at most a few keyframes: the late
    checkpoints are as large and as fast as the early ones."""
    saves = measured["checkpoints"]
    assert len(saves) == math.ceil(FRAMES / 8)
    by_capacity: dict = {}
    for save in saves[1:]:
        by_capacity.setdefault(save["capacity"], []).append(save)
    keyframe_bytes = measured["width"] * measured["height"] * 16 + 1024
    for group in by_capacity.values():
        sizes = [s["bytes"] for s in group]
        assert max(sizes) <= statistics.median(sizes) + 2 * keyframe_bytes, sizes
    early, late = saves[1:21], saves[-20:]
    assert statistics.median(s["seconds"] for s in late) < 2 * statistics.median(s["seconds"] for s in early) + 0.05
