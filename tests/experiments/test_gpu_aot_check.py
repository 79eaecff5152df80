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


@pytest.mark.parametrize("flops, nbytes, compute_ms, memory_ms, bound", [
    (67e9, 3.35e9, 1.0, 1.0, "memory"),  # a tie counts as memory-bound
    (6.7e9, 6.7e9, 0.1, 2.0, "memory"),
    (134e9, 0.335e9, 2.0, 0.1, "compute"),
    (0.0, 0.0, 0.0, 0.0, "memory"),
])
def test_roofline_floor_is_the_larger_of_the_compute_and_memory_times(flops, nbytes, compute_ms, memory_ms, bound):
    found = aot.roofline(flops, nbytes)  # an H100/H200: 67 TFLOP/s fp32, 3.35 TB/s
    assert found["compute_ms"] == pytest.approx(compute_ms) and found["memory_ms"] == pytest.approx(memory_ms)
    assert found["floor_ms"] == pytest.approx(max(compute_ms, memory_ms)) and found["bound"] == bound
    assert aot.roofline(1e12, 1e9, dict(flops=1e12, bandwidth=1e12))["floor_ms"] == pytest.approx(1000.0)


# Optimized-HLO lines as XLA 0.10.2 prints them (shapes shrunk, the Triton IR left out).
HLO = """\
  %pallas_call.10 = (s32[2,2,4]{2,1,0}, s32[2,3,4]{2,1,0}, s32[2,4]{1,0}, f32[2,4]{1,0}) custom-call(%a, %b), \
custom_call_target="__gpu$xla.gpu.triton", operand_layout_constraints={s32[2]{0}, f32[2,64]{1,0}, f32[2,64]{1,0}, \
f32[2,64]{1,0}, f32[2,64]{1,0}, f32[2,64]{1,0}, f32[2,64]{1,0}, f32[2,4]{1,0}, f32[2,4]{1,0}}, \
api_version=API_VERSION_TYPED_FFI, metadata={op_name="jit(f)/pallas_call"}, backend_config={grid_x = 2 : i32, \
name = "_walk_kernel", num_warps = 1 : i32}
  %pallas_call.11 = (f32[8]{0}, f32[8]{0}) custom-call(%c), custom_call_target="__gpu$xla.gpu.triton", \
operand_layout_constraints={f32[3,8]{1,0}}, api_version=API_VERSION_TYPED_FFI, \
backend_config={name = "_composite_kernel"}
  ROOT %sort.8.1 = (s32[10]{0}, s32[10]{0}) sort(%param_0, %iota.8.1), dimensions={0}, to_apply=%region_5.15
  %while.63 = (s32[], f32[3,8]{1,0}) while(%tuple.262), condition=%c, body=%b, \
backend_config={"known_trip_count":{"n":"3"},"known_init_step":{"init":"0","step":"1"}}
  %while.64 = (s32[]) while(%tuple.263), condition=%c, body=%b
  %cond.69 = (f32[4]{0}) conditional(%smooth.1, %x, %y), true_computation=%t, false_computation=%f
"""


def test_hlo_inventory_sizes_the_pallas_calls_and_sorts_xla_cannot_see():
    found = aot.hlo_inventory(HLO, {"sort_8_1": 5})
    walk, composite = found["pallas_calls"]
    walk_bytes = (2 + 6 * 2 * 64 + 2 * 2 * 4) * 4 + (2 * 2 * 4 + 2 * 3 * 4 + 2 * 4 + 2 * 4) * 4
    assert walk == dict(kernel="_walk_kernel", bytes=walk_bytes, flops=17 * 2 * 64 * 4, transcendentals=2 * 64 * 4)
    assert composite == dict(kernel="_composite_kernel", bytes=(3 * 8 + 2 * 8) * 4, flops=14 * 3 * 8, transcendentals=0)
    assert found["sorts"] == [dict(name="sort.8.1", bytes=80, launches=5)]
    assert (found["while_trip_counts"], found["conditionals"]) == ([3, None], 1)
    costs = aot.program_costs({"flops": 100.0, "bytes accessed": 1000.0}, found)
    estimate = costs["estimate"]
    assert estimate["flops"] == 100 + walk["flops"] + composite["flops"]
    assert estimate["sort_extra_pass_bytes"] == 2 * 80 * 4  # four passes beyond XLA's one
    assert estimate["bytes"] == 1000 + walk_bytes + composite["bytes"] + 2 * 80 * 4
    assert costs["roofline"] == aot.roofline(estimate["flops"], estimate["bytes"])
    assert costs["roofline_xla"] == aot.roofline(100.0, 1000.0)


def test_an_iteration_from_its_stages_adds_their_floors_and_names_the_largest():
    stages = {name: dict(flops=f, bytes=b, **aot.roofline(f, b)) for name, f, b in
              [("bin", 0.0, 6.7e9), ("walk", 67e9, 0.0), ("composite", 0.0, 3.35e9)]}
    found = aot.iteration_from_stages(stages, ["bin", "walk", "composite"], goal_ms=3.0)
    assert found["floor_ms"] == pytest.approx(2.0 + 1.0 + 1.0) and found["bounded_by"] == "bin"
    assert found["floor_vs_goal"] == pytest.approx(4.0 / 3.0)
    assert found["memory_ms"] == pytest.approx(3.0) and found["compute_ms"] == pytest.approx(1.0)


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
