"""The deviceless GPU compile check's reading of XLA's and ptxas's reports (experiments/gpu_aot_check.py); the
compile itself needs jax's CUDA plugin and runs with `make gpu-aot`, outside the suite."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
import gpu_aot_check as aot

# Lines as XLA 0.10.2's thunk sequence dump and CUDA 13's ptxas print them (the check's own run, 2026-12-04).
THUNKS = (
    "001: kCustomKernel [source       | next=004 (3)  ] loop_select_fusion_1 grid: [1, 1, 1] threads: [64, 1, 1]"
    "  shared_memory: 0 bytes\n"
    "146: kCustomKernel [prev=145 (1) | next=147 (1)  ] _walk_kernel grid: [4800, 1, 1] threads: [64, 1, 1]"
    "  shared_memory: 512 bytes\n"
    "        433: kCustomKernel       [prev=432 (1) | next=434 (1)] _composite_kernel__1 grid: [2125, 1, 1]"
    " threads: [128, 1, 1]  shared_memory: 0 bytes\n"
    "150: kSequential\n"
)
PTXAS = """\
ptxas info    : 0 bytes gmem
ptxas info    : Compiling entry function '_walk_kernel' for 'sm_90a'
ptxas info    : Function properties for _walk_kernel
    8 bytes stack frame, 16 bytes spill stores, 12 bytes spill loads
ptxas info    : Used 48 registers, used 1 barriers, 1024 bytes smem
ptxas info    : Compile time = 16.260 ms
ptxas info    : Compiling entry function '_composite_kernel' for 'sm_90a'
ptxas info    : Function properties for _composite_kernel
    0 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads
ptxas info    : Used 44 registers, used 0 barriers
"""


def test_thunks_give_every_kernel_launch_with_its_grid_threads_and_shared_memory():
    kernels = aot.parse_thunks(THUNKS)
    assert kernels == [
        dict(name="loop_select_fusion_1", grid=[1, 1, 1], threads=64, shared_bytes=0),
        dict(name="_walk_kernel", grid=[4800, 1, 1], threads=64, shared_bytes=512),
        dict(name="_composite_kernel__1", grid=[2125, 1, 1], threads=128, shared_bytes=0),
    ]


def test_ptxas_report_gives_registers_spills_and_shared_memory_per_function():
    found = aot.parse_ptxas(PTXAS)
    assert found["_walk_kernel"] == dict(stack=8, spill_stores=16, spill_loads=12, registers=48, barriers=1, smem=1024)
    assert found["_composite_kernel"] == dict(stack=0, spill_stores=0, spill_loads=0, registers=44, barriers=0)


@pytest.mark.parametrize("threads, registers, shared, blocks, limit, share", [
    (64, 48, 512, 21, "registers", 42 / 64),  # 1536 registers a warp: 42 warps of 64 fit, 21 blocks of 2
    (128, 32, 0, 16, "threads", 1.0),  # 2048 threads / 128
    (128, 40, 0, 12, "registers", 48 / 64),  # 1280 a warp: 51 warps, 12 blocks of 4
    (32, 16, 0, 32, "blocks", 0.5),  # 32 blocks of one warp: half the SM's 64 warps
    (256, 32, 100_000, 2, "shared_memory", 16 / 64),  # 233472 // 100000 = 2 blocks of 8 warps
    (64, 33, 0, 25, "registers", 50 / 64),  # 33 x 32 = 1056 rounds up to 1280 a warp: 51 warps, 25 blocks of 2
])
def test_occupancy_takes_the_tightest_of_the_sm_limits(threads, registers, shared, blocks, limit, share):
    found = aot.occupancy(threads, registers, shared)
    assert (found["blocks_per_sm"], found["limited_by"]) == (blocks, limit)
    assert found["occupancy"] == pytest.approx(share)


def test_pallas_kernel_rows_are_grouped_by_kernel_with_their_launch_count(tmp_path):
    (tmp_path / "module_0001.jit_f.thunk_sequence.txt").write_text(THUNKS + THUNKS.splitlines()[1] + "\n")
    (tmp_path / "module_0001.jit_f.7.ptx").write_text(".visible .entry _walk_kernel(\n")  # 30 bytes
    rows = aot.kernel_report(*aot.dumped(tmp_path, "jit_f"), {"_walk_kernel", "_composite_kernel"}, ptxas=None)
    walk, composite = rows
    assert (walk["name"], walk["launches"], walk["ptx_bytes"]) == ("_walk_kernel", 2, 30)
    assert (composite["name"], composite["launches"], composite["ptx_bytes"]) == ("_composite_kernel", 1, None)


def test_the_gpu_check_collects_the_ahead_of_time_programs_and_their_failure(tmp_path):
    import gpu_check

    kernel = dict(name="_walk_kernel", grid=[1, 1, 1], threads=64, shared_bytes=512, registers=48, spill_stores=0,
                  occupancy=0.65625, launches=1)
    report = dict(programs={"track": dict(compile_s=2.0, pallas_kernels=[kernel], run=dict(max_relative_difference=0))})
    (tmp_path / "aot").mkdir()
    (tmp_path / "aot" / "gpu_aot.json").write_text(json.dumps(report))
    found = gpu_check.collect(tmp_path)["aot"]
    assert found["error"] is None
    assert found["programs"]["track"] == dict(compile_s=2.0, error=None, run=dict(max_relative_difference=0), kernels=[
        dict(name="_walk_kernel", registers=48, spill_stores=0, shared_bytes=512, occupancy=0.65625)])
    (tmp_path / "aot" / "gpu_aot.json").write_text(json.dumps(dict(programs={}, error="no CUDA plugin")))
    assert gpu_check.collect(tmp_path)["aot"] == dict(error="no CUDA plugin", programs={})


def test_without_jax_cuda_plugin_the_check_names_the_step_that_cannot_be_done(tmp_path, monkeypatch):
    import importlib.util

    if importlib.util.find_spec("jax_plugins") and importlib.util.find_spec("jax_plugins.xla_cuda13"):
        pytest.skip("the CUDA plugin is installed here: the check would compile (make gpu-aot)")
    monkeypatch.setenv("XLA_FLAGS", "")  # main() adds its dump folder; restored after the test
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    assert aot.main(["--out", str(tmp_path)]) == 1
    found = json.loads((tmp_path / "gpu_aot.json").read_text())
    assert found["error"].startswith("get_topology_desc(platform='cuda'): ") and found["programs"] == {}
