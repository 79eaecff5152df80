"""Kill ``gsjax run`` anywhere and resume: SIGKILL at random traced points (mid-write of checkpoint files and of the
final outputs, at a checkpoint's commit, mid-scan, before the first checkpoint), one after another, each followed
by ``--resume`` (the first resume starts before any checkpoint exists); the finished run equals an uninterrupted one,
and no output is ever half-written. A damaged newest
checkpoint falls back to the previous one with a warning."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gsjax.app.run_folder.checkpoints import Checkpoints
from gsjax.app.session.runner import run_slam
from tests.support.kill_harness import KILL_EXIT
from tests.support.tiny_slam import CHUNK, FRAMES, TINY_RUN, run_options, tiny_config, tiny_sequence

HARNESS = Path(__file__).parents[1] / "support" / "kill_harness.py"
RUN = ["run", *TINY_RUN, "--checkpoint-every", str(CHUNK)]
OUTPUTS = ("trajectory.txt", "map.ply", "trajectory.png")
# Metrics that measure the machine, not the run.
MACHINE_KEYS = ("frames_per_s", "seconds_per_frame", "stage_timings_s", "checkpoints")


def harness(out: Path, trace: Path, kill_at: str = "-", resume: bool = False) -> subprocess.CompletedProcess:
    argv = [*RUN, "--out", str(out)] + (["--resume"] if resume else [])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HARNESS.parent), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, str(HARNESS), str(trace), kill_at, "--", *argv], env=env,
                          capture_output=True, text=True, timeout=600)


def events(trace: Path) -> list[str]:
    return trace.read_text().splitlines() if trace.exists() else []


def comparable(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if k not in MACHINE_KEYS}


def assert_nothing_half_written(out: Path) -> None:
    """Every output that exists is whole: the JSON files parse, the trajectory has a line per frame, and the map and
    the PNGs end as their formats end. (A kill mid-write leaves only a hidden temporary file.)"""
    for name in ("config.json", "metrics.json"):
        if (out / name).exists():
            json.loads((out / name).read_text())
    if (out / "trajectory.txt").exists():
        lines = [x for x in (out / "trajectory.txt").read_text().splitlines() if x and not x.startswith("#")]
        assert len(lines) == FRAMES
    if (out / "map.ply").exists():
        from gsjax.io.ply import read_ply

        read_ply(out / "map.ply")
    for png in [*out.glob("*.png"), *out.glob("renders/*.png")]:
        assert png.read_bytes()[-8:] == b"IEND\xaeB`\x82", png


def pick_kill_points(trace: list[str], seed: int = 2026, count: int = 6) -> list[str]:
    """``count`` events of the uninterrupted run's trace, at random with a fixed seed, in trace order; at least one
    before the first checkpoint, one inside a checkpoint write, one at a checkpoint commit, one mid-run at a scan
    and one in the final outputs."""
    rng = np.random.default_rng(seed)
    first_commit = next(i for i, e in enumerate(trace) if e.startswith("commit:"))
    final = next(i for i, e in enumerate(trace) if e == "write:run/trajectory.txt")
    groups = [
        range(0, first_commit),
        [i for i, e in enumerate(trace) if e.startswith(("write:frames/", "write:keyframes/"))],
        [i for i, e in enumerate(trace) if e.startswith("commit:")],
        [i for i, e in enumerate(trace) if e.startswith("scan:") and i > first_commit],
        range(final, len(trace)),
    ]
    chosen = {int(rng.choice(list(g))) for g in groups}
    rest = [i for i in range(len(trace)) if i not in chosen and trace.count(trace[i]) == 1]
    chosen |= {int(i) for i in rng.choice(rest, size=count - len(chosen), replace=False)}
    return [trace[i] for i in sorted(chosen)]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    base = tmp_path_factory.mktemp("uninterrupted")
    out, trace = base / "run", base / "trace.txt"
    done = harness(out, trace)
    assert done.returncode == 0, done.stderr
    return out, events(trace)


def test_killed_at_random_points_and_resumed_the_run_equals_an_uninterrupted_one(tmp_path, uninterrupted):
    reference, trace = uninterrupted
    assert trace.count("write:run/config.json") == 1 and trace[-1] == "write:run/metrics.json"
    points = pick_kill_points(trace)
    assert len(points) >= 5
    out = tmp_path / "run"
    for n, point in enumerate(points):
        killed = harness(out, tmp_path / f"trace{n}.txt", kill_at=point, resume=n > 0)
        assert killed.returncode == KILL_EXIT, (point, killed.returncode, killed.stderr[-2000:])
        assert events(tmp_path / f"trace{n}.txt")[-1] == point
        assert_nothing_half_written(out)
        if n == 0:  # killed before the first checkpoint: the next --resume must start cleanly from frame 0
            assert trace.index(point) < trace.index(f"commit:{CHUNK}")
            assert not any(p.name.isdigit() for p in (out / "checkpoints").iterdir())  # no step committed
        if point.startswith("write:"):  # killed mid-write: the partial data sits in a temporary file only
            folder, name = point[len("write:"):].split("/")
            where = out if folder == "run" else out / ("renders" if folder == "renders" else f"checkpoints/{folder}")
            assert list(where.glob(f".{name}.*.tmp")), point
    finished = harness(out, tmp_path / "final.txt", resume=True)
    assert finished.returncode == 0, finished.stderr
    assert not list(out.rglob(".*.tmp")), "a resumed run clears what killed writers left"
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert comparable(metrics) == comparable(json.loads((reference / "metrics.json").read_text()))
    names = lambda folder: sorted(p.name for p in (folder / "renders").iterdir())  # noqa: E731
    assert names(out) == names(reference)


# ------------------------------------------------------------------------- damaged checkpoints (in process)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("finished") / "run"
    return out, run_slam(tiny_sequence(), tiny_config(), run_options(out))


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # orbax's reads of the damaged file
@pytest.mark.parametrize("damage", ["state", "frames", "keyframes", "meta"])
def test_a_damaged_newest_checkpoint_falls_back_to_the_previous_one_with_a_warning(tmp_path, finished_run, damage,
                                                                                  capsys):
    reference, reference_metrics = finished_run
    out = Path(shutil.copytree(reference, tmp_path / "run"))
    checkpoints = out / "checkpoints"
    if damage == "state":
        victim = max((p for p in (checkpoints / str(FRAMES) / "state").rglob("*") if p.is_file()),
                     key=lambda p: p.stat().st_size)
    elif damage == "frames":
        victim = checkpoints / "frames" / f"{CHUNK:06d}-{FRAMES:06d}.npz"
    elif damage == "keyframes":
        victim = max((checkpoints / "keyframes").glob("*.npz"))
    else:
        victim = checkpoints / str(FRAMES) / "meta" / "metadata"
    _truncate(victim)
    metrics = run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True))
    err = capsys.readouterr().err
    assert f"checkpoint {checkpoints / str(FRAMES)} cannot be read" in err
    assert any("falling back to an older one" in w for w in metrics.warnings)
    assert damage != "keyframes" or victim.name == "00001.npz"  # one only the newest checkpoint needs
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    assert comparable(dict(metrics.to_json(), warnings=[])) == comparable(dict(reference_metrics.to_json(),
                                                                               warnings=[]))


def test_when_no_checkpoint_can_be_read_the_run_starts_over_with_a_warning(tmp_path, finished_run, capsys):
    reference, _ = finished_run
    out = Path(shutil.copytree(reference, tmp_path / "run"))
    _truncate(out / "checkpoints" / "frames" / f"{0:06d}-{CHUNK:06d}.npz")  # both checkpoints need it
    metrics = run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True))
    assert "the run starts from frame 0" in capsys.readouterr().err
    assert (out / "trajectory.txt").read_bytes() == (reference / "trajectory.txt").read_bytes()
    assert len(metrics.warnings) == 3


def test_a_checkpoint_writes_the_map_and_what_is_new_since_the_previous_one(finished_run):
    """Checkpoints at frames 3 and 6: one frame segment each, and the keyframe images once each (keyframe 0 with
    the first, keyframe 4 with the second); the step directories hold no image."""
    out, metrics = finished_run
    directory = out / "checkpoints"
    assert sorted(p.name for p in (directory / "frames").iterdir()) == ["000000-000003.npz", "000003-000006.npz"]
    assert sorted(p.name for p in (directory / "keyframes").iterdir()) == ["00000.npz", "00001.npz"]
    checkpoints = Checkpoints(directory)
    try:
        assert checkpoints.steps() == [FRAMES, CHUNK]
        ledger = checkpoints.read_ledger(FRAMES)
        assert len(checkpoints.outputs(FRAMES).w2c) == FRAMES
    finally:
        checkpoints.close()
    assert ledger.segments == [[0, CHUNK], [CHUNK, FRAMES]] and ledger.keyframes_saved == 2
    assert metrics.checkpoints.count == 2 and metrics.checkpoints.every_frames == CHUNK
    step_bytes = sum(p.stat().st_size for p in (directory / str(FRAMES)).rglob("*") if p.is_file())
    assert metrics.checkpoints.last_bytes >= step_bytes
    assert not any("color" in p.name or "depth" in p.name for p in (directory / str(FRAMES)).rglob("*"))
