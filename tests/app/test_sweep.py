"""`gsjax sweep`: the grid, one vmapped program per static signature, rows equal to separate `gsjax run`s, the
batch axis sharded over (forced) host devices, and the output files."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.sweep.grid import (
    GridAxis,
    batch_size,
    expand_grid,
    group_by_program,
    parse_grid,
    read_sweep_csv,
    static_fields,
    vmap_width,
)
from gsjax.config.text import apply_overrides
from gsjax.io.trajectory import read_tum_trajectory
from tests.support.tiny_slam import TINY_RUN, tiny_config

GRID = ["--grid", "tracking.lr_trans=0.002,0.004"]
SEEDS = 2
CONFIGS = 4  # 2 values x 2 seeds


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "sweep"
    # --batch 2: two batches through the same compiled program.
    assert main(["sweep", "--out", str(out), *TINY_RUN, *GRID, "--seeds", str(SEEDS), "--batch", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def vmapped_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("vmapped") / "sweep"
    assert main(["sweep", "--out", str(out), *TINY_RUN, *GRID, "--seeds", str(SEEDS), "--vmap-width", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def separate_runs(tmp_path_factory):
    """The sweep's four configs as separate `gsjax run`s (each the tiny program the CLI tests compile)."""
    base = tmp_path_factory.mktemp("separate")
    outs = {}
    for index, (lr, seed) in enumerate([(lr, seed) for lr in ("0.002", "0.004") for seed in range(SEEDS)]):
        out = base / f"{index:03d}"
        assert main(["run", "--out", str(out), *TINY_RUN, "--tracking.lr_trans", lr, "--seed", str(seed)]) == 0
        outs[index] = out
    return outs


# ------------------------------------------------------------------------------------------ the grid


def test_parse_grid_reads_a_field_and_its_values_and_names_bad_axes():
    assert parse_grid("cbknn.params.alpha=0.1, 0.2,0.3") == GridAxis("cbknn.params.alpha", ("0.1", "0.2", "0.3"))
    for bad in ("cbknn.params.alpha", "=0.1,0.2", "cbknn.params.alpha=", "tracking.lr_trans=1,1"):
        with pytest.raises(ValueError, match="--grid"):
            parse_grid(bad)


def test_expand_grid_is_the_product_of_the_axes_times_the_seeds_first_axis_slowest():
    axes = [parse_grid("cbknn.params.alpha=0.1,0.2"), parse_grid("cbknn.params.k0=4,8,16")]
    points = expand_grid(tiny_config(), axes, [0, 1])
    assert len(points) == 12 and [p.index for p in points] == list(range(12))
    assert [(p.values["cbknn.params.alpha"], p.values["cbknn.params.k0"], p.seed) for p in points[:4]] == [
        ("0.1", "4", 0), ("0.1", "4", 1), ("0.1", "8", 0), ("0.1", "8", 1)]
    assert float(points[-1].config.cbknn.params.k0) == 16.0 and float(points[-1].config.cbknn.params.alpha) == 0.2
    alone = apply_overrides(tiny_config(), {"cbknn.params.alpha": "0.1", "cbknn.params.k0": "4"})
    assert points[0].config == alone.with_caps(alone.caps)  # the same values, the grid's common caps pinned


def test_expand_grid_validates_values_like_an_override():
    with pytest.raises(ValueError, match="--grid: --tracking.lr_trans"):
        expand_grid(tiny_config(), [parse_grid("tracking.lr_trans=0.1,-1")], [0])
    with pytest.raises(ValueError, match="unknown field"):
        expand_grid(tiny_config(), [parse_grid("tracking.nope=1,2")], [0])
    with pytest.raises(ValueError, match="more than one axis"):
        expand_grid(tiny_config(), [parse_grid("tracking.iters=1,2"), parse_grid("tracking.iters=3,4")], [0])


def test_traced_fields_share_one_program_and_a_static_field_gives_one_per_value():
    base = tiny_config()
    traced = [parse_grid("cbknn.params.alpha=0.1,0.2"), parse_grid("noise.depth_cm=0,1"),
              parse_grid("cbknn.mode=off,code_parity"), parse_grid("tracking.iters=3,50"),
              parse_grid("mapping.strided_iters=0,4")]  # counts across caps: the sweep's common caps hold them all
    assert len(group_by_program(expand_grid(base, traced, [0, 1]))) == 1
    assert static_fields(base, traced) == []
    # paper's renders carry CB-KNN's correction: its own program, the other modes' rows still one
    modes = [parse_grid("cbknn.mode=off,code_parity,paper"), parse_grid("tracking.iters=3,50")]
    assert [len(g) for g in group_by_program(expand_grid(base, modes, [0]))] == [4, 2]
    assert static_fields(base, modes) == ["cbknn.mode"]
    mixed = [parse_grid("tracking.blur.radius_px=0,4"), parse_grid("tracking.lr_rot=0.001,0.002")]
    groups = group_by_program(expand_grid(base, mixed, [0]))
    assert [len(g) for g in groups] == [2, 2]
    assert {g[0].values["tracking.blur.radius_px"] for g in groups} == {"0", "4"}
    assert static_fields(base, mixed) == ["tracking.blur.radius_px"]


@pytest.mark.parametrize("grid", [["--grid", "tracking.iters=2,4", "--grid", "mapping.iters=1,3"],
                                  ["--grid", "cbknn.mode=off,code_parity,paper"]])
def test_a_sweep_over_iteration_counts_or_cbknn_modes_runs_one_program_per_kind_of_render_equal_to_separate_runs(
        grid, tmp_path, capsys, monkeypatch):
    """The issue's grids: each value a traced leaf of one program (the modes: ``paper`` one, with CB-KNN's correction
    compiled in, ``off`` and ``code_parity`` another). The programs the sweep calls are counted (each would be a
    compilation in a fresh process), and its rows are the separate runs', bit for bit."""
    from gsjax.app.runtime import programs

    keys, key_of = [], programs.program_key
    monkeypatch.setattr(programs, "program_key", lambda *a: keys.append(key_of(*a)) or keys[-1])
    out = tmp_path / "sweep"
    assert main(["sweep", "--out", str(out), *TINY_RUN, *grid]) == 0
    programs_expected = 2 if "cbknn.mode" in grid[1] else 1
    assert len(set(keys)) == programs_expected  # one SLAM program per kind of render
    configs = len(read_sweep_csv(out / "sweep.csv"))
    assert f"gsjax sweep: {configs} configs in {programs_expected} program(s)" in capsys.readouterr().out
    rows = read_sweep_csv(out / "sweep.csv")
    fields = [grid[i + 1].split("=")[0] for i in range(0, len(grid), 2)]
    for row in (rows[0], rows[-1]):  # the grid's corners as separate `gsjax run`s
        alone = tmp_path / f"alone{row['run'][-3:]}"
        overrides = [t for f in fields for t in (f"--{f}", row[f])]
        assert main(["run", "--out", str(alone), *TINY_RUN, *overrides]) == 0
        assert (out / row["run"] / "trajectory.txt").read_bytes() == (alone / "trajectory.txt").read_bytes()
    assert (out / rows[0]["run"] / "trajectory.txt").read_bytes() != (out / rows[-1]["run"] / "trajectory.txt"
                                                                      ).read_bytes()


def test_batch_size_bounds_the_batch_and_the_vmap_width_fills_the_devices():
    assert batch_size(None, 8) == 8 and batch_size(3, 8) == 3 and batch_size(16, 5) == 5
    assert vmap_width(1, 2) == 1 and vmap_width(3, 2) == 4 and vmap_width(4, 1) == 4
    assert vmap_width(None, 1) == (1 if jax.default_backend() == "cpu" else 64)


# ------------------------------------------------------------------------------------------ the sweep


def _trajectory(run: Path) -> np.ndarray:
    return read_tum_trajectory(run / "trajectory.txt")[1]


def test_every_sweep_row_equals_a_separate_run_bit_for_bit(sweep_dir, separate_runs):
    """On CPU (vmap width 1) each config runs the very program `gsjax run` compiles, so rows equal exactly."""
    rows = read_sweep_csv(sweep_dir / "sweep.csv")
    assert len(rows) == CONFIGS
    for row in rows:
        alone = separate_runs[int(row["run"].split("/")[-1])]
        assert (sweep_dir / row["run"] / "trajectory.txt").read_bytes() == (alone / "trajectory.txt").read_bytes()
        metrics = json.loads((alone / "metrics.json").read_text())
        assert float(row["ate_rmse_cm"]) == pytest.approx(metrics["trajectory"]["ate_rmse_c2w_cm"], rel=1e-5)
        assert float(row["psnr_db"]) == pytest.approx(metrics["render"]["mean"]["psnr_db"], rel=1e-5)
        assert json.loads((sweep_dir / row["run"] / "metrics.json").read_text())["config"] == metrics["config"]
    # Not vacuous: the two learning rates give different trajectories.
    assert not np.allclose(_trajectory(separate_runs[0]), _trajectory(separate_runs[2]), atol=1e-4)


def test_vmapped_sweep_rows_equal_separate_runs_to_float32_rounding(vmapped_dir, separate_runs):
    rows = read_sweep_csv(vmapped_dir / "sweep.csv")
    assert len(rows) == CONFIGS and json.loads((vmapped_dir / "sweep.json").read_text())["vmap_width"] == 2
    worst_ate = 0.0
    for row in rows:
        alone = separate_runs[int(row["run"].split("/")[-1])]
        # vmap reduces some float32 sums in another order. Measured: poses within 2e-8 m for three of the four
        # configs; in the fourth a rounding-level difference flips a discrete choice at frame 3 (a pixel at the
        # silhouette threshold, or which of two nearly equal tracking losses is lowest): 2e-5 m there, 3e-4 m two
        # frames later; the largest ATE difference 1.2e-4 cm.
        np.testing.assert_allclose(_trajectory(vmapped_dir / row["run"]), _trajectory(alone), atol=1e-3)
        metrics = json.loads((alone / "metrics.json").read_text())
        worst_ate = max(worst_ate, abs(float(row["ate_rmse_cm"]) - metrics["trajectory"]["ate_rmse_c2w_cm"]))
        assert float(row["psnr_db"]) == pytest.approx(metrics["render"]["mean"]["psnr_db"], abs=0.05)
    assert worst_ate < 0.02  # cm


def test_sweep_writes_the_csv_markdown_heat_map_and_a_run_per_config(sweep_dir):
    rows = read_sweep_csv(sweep_dir / "sweep.csv")
    assert list(rows[0]) == ["tracking.lr_trans", "seed", "ate_rmse_cm", "ate_splatam_cm", "psnr_db", "depth_l1_cm",
                             "seconds", "run"]
    assert [(r["tracking.lr_trans"], r["seed"], r["run"]) for r in rows] == [
        ("0.002", "0", "runs/000"), ("0.002", "1", "runs/001"), ("0.004", "0", "runs/002"),
        ("0.004", "1", "runs/003")]
    for row in rows:
        for key in ("ate_rmse_cm", "ate_splatam_cm", "psnr_db", "depth_l1_cm", "seconds"):
            assert np.isfinite(float(row[key])), key
        for name in ("trajectory.txt", "metrics.json", "config.json"):
            assert (sweep_dir / row["run"] / name).is_file()
    markdown = (sweep_dir / "sweep.md").read_text().splitlines()
    assert markdown[0].startswith("| tracking.lr_trans | seed | ate_rmse_cm") and len(markdown) == 2 + CONFIGS
    assert (sweep_dir / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((sweep_dir / "sweep.json").read_text())
    assert (summary["configs"], summary["programs"], summary["batches"]) == (CONFIGS, 1, 2)
    assert summary["grid"] == {"tracking.lr_trans": ["0.002", "0.004"]} and summary["seeds"] == [0, 1]


def test_a_second_sweep_into_the_same_directory_is_refused_unless_overwrite(sweep_dir, capsys):
    before = (sweep_dir / "sweep.csv").read_bytes()
    assert main(["sweep", "--out", str(sweep_dir), *TINY_RUN, *GRID]) == 2
    assert "holds a previous run" in capsys.readouterr().err
    assert (sweep_dir / "sweep.csv").read_bytes() == before


@pytest.mark.parametrize("argv, message", [
    (["--grid", "tracking.lr_trans"], "expected FIELD=V1,V2"),
    (["--grid", "tracking.nope=1,2"], "unknown field"),
    (["--grid", "tracking.lr_trans=1,x"], "cannot read 'x'"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--batch", "0"], "--batch must be >= 1"),
])
def test_bad_sweep_arguments_are_one_line_errors(tmp_path, capsys, argv, message):
    assert main(["sweep", "--out", str(tmp_path / "s"), *TINY_RUN, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "s").exists()


@pytest.mark.slow  # 45 s; the default suite keeps the two-process sweep (width 1), the slow one both sharded cases
def test_the_vmapped_axis_is_sharded_over_two_host_devices_with_the_same_results(vmapped_dir, tmp_path):
    """XLA_FLAGS forces two CPU devices: each vmapped group of 2 is split one config per device."""
    out = tmp_path / "sharded"
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    code = ("import sys, jax; from gsjax.app.cli import main; assert jax.device_count() == 2; "
            "sys.exit(main(sys.argv[1:]))")
    done = subprocess.run([sys.executable, "-c", code, "sweep", "--out", str(out), *TINY_RUN, *GRID,
                           "--seeds", str(SEEDS), "--vmap-width", "2"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "on 2 device(s)" in done.stdout
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["devices"] == 2 and summary["state_devices"] == 2  # the final states lay on both devices
    rows = read_sweep_csv(out / "sweep.csv")
    assert len(rows) == CONFIGS
    for row in rows:
        np.testing.assert_allclose(_trajectory(out / row["run"]), _trajectory(vmapped_dir / row["run"]), atol=1e-3)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _two_processes(argv, timeout: int):
    """Python run with ``argv(i)`` as processes 0 and 1 of one jax.distributed job on this machine (coordinator on
    127.0.0.1) -> (the Popen objects, their (stdout, stderr))."""
    env = dict(os.environ, GSJAX_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{_free_port()}",
               GSJAX_NUM_PROCESSES="2")
    # The suite's own XLA flags stay (compiled as the one-process sweep was); a forced device count does not.
    env["XLA_FLAGS"] = " ".join(f for f in env.get("XLA_FLAGS", "").split()
                                if "xla_force_host_platform_device_count" not in f)
    procs = [subprocess.Popen([sys.executable, *argv(i)], env=dict(env, GSJAX_PROCESS_ID=str(i)),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(2)]
    try:
        return procs, [p.communicate(timeout=timeout) for p in procs]
    finally:
        for p in procs:
            p.kill()


@pytest.mark.parametrize("width", ["1", pytest.param("2", marks=pytest.mark.slow)])
def test_a_sweep_over_two_processes_gives_the_rows_of_one_process_and_only_process_0_writes(
        width, sweep_dir, vmapped_dir, tmp_path):
    """Two processes on this machine join one `gsjax sweep` through jax.distributed (coordinator on 127.0.0.1, CPU
    collectives), one CPU device each. Width 1: each process runs the configs of its device, process 0 gathers them.
    Width 2: each vmapped pair is sharded over the two processes. Process 0 writes everything; process 1 is given its
    own --out, which must stay absent."""
    code = "import sys; from gsjax.app.cli import main; sys.exit(main(sys.argv[1:]))"
    outs = [tmp_path / "p0", tmp_path / "p1"]
    procs, done = _two_processes(lambda i: ["-c", code, "sweep", "--out", str(outs[i]), *TINY_RUN, *GRID, "--seeds",
                                            str(SEEDS), "--devices", "1", "--vmap-width", width], timeout=600)
    for p, (_, err) in zip(procs, done):
        assert p.returncode == 0, err[-2000:]
    assert "on 2 device(s)" in done[0][0]
    assert not outs[1].exists() and "outputs in" not in done[1][0]
    summary = json.loads((outs[0] / "sweep.json").read_text())
    assert summary["devices"] == 2 and summary["configs"] == CONFIGS and summary["vmap_width"] == int(width)
    two_processes = read_sweep_csv(outs[0] / "sweep.csv")
    assert len(two_processes) == CONFIGS
    if width == "1":  # the plain program per config: the rows of the one-process sweep exactly
        assert [{k: v for k, v in r.items() if k != "seconds"} for r in two_processes] == [
            {k: v for k, v in r.items() if k != "seconds"} for r in read_sweep_csv(sweep_dir / "sweep.csv")]
    for row in two_processes:  # configs 1 and 3 ran on process 1's device and were gathered
        mine, reference = _trajectory(outs[0] / row["run"]), _trajectory((sweep_dir if width == "1" else vmapped_dir)
                                                                         / row["run"])
        if width == "1":
            np.testing.assert_array_equal(mine, reference)
        else:
            np.testing.assert_allclose(mine, reference, atol=1e-3)


@pytest.mark.slow
def test_processes_that_finish_their_share_far_apart_still_exchange_results():
    """share_results when one process arrives 40 s after the other: the collectives' own rendezvous gives up after
    30 s (seen as 'Gloo context initialization failed: DEADLINE_EXCEEDED' on a loaded machine); the barrier before
    them waits."""
    code = textwrap.dedent("""
        import sys, time, jax
        from gsjax.app.sweep.devices import maybe_initialize_distributed, share_results
        maybe_initialize_distributed()
        me = jax.process_index()
        if me == 1:
            time.sleep(40)
        shared = share_results([{"ran_by": 0} if me == 0 else None, {"ran_by": 1} if me == 1 else None], "late")
        assert [entry["ran_by"] for entry in shared] == [0, 1], shared
        print("shared", me)
    """)
    procs, done = _two_processes(lambda i: ["-c", code], timeout=300)
    for i, (p, (out, err)) in enumerate(zip(procs, done)):
        assert p.returncode == 0 and f"shared {i}" in out, err[-2000:]
