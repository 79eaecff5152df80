"""Compile gsjax's GPU path for an NVIDIA H100/H200 on a machine without a GPU (XLA's deviceless, ahead-of-time
compilation) and report what the compilers say of every Pallas kernel.

    make gpu-aot                                      # a venv with jax's CUDA plugin (.venv-gpu-aot), then this
    python experiments/gpu_aot_check.py --out outputs/gpu_aot [--run]

Programs, each lowered with ``backend="pallas"`` for a one-GPU topology described by a ``GpuTargetConfigProto``
(:data:`H100`: an H100 SXM's figures; an H200 has the same SM 9.0, SM count and per-SM limits, more and faster memory)
and compiled by XLA's GPU compiler (Triton for the Pallas kernels, then ptxas) on this CPU:

- ``render_fwd_bwd_640x480``: a render and its gradient w.r.t. every Gaussian field and the pose (as mapping and the
  benchmark differentiate);
- ``track_iteration_1200x680``: one tracking iteration of the ``replica`` preset in ``paper`` mode (the loss and its
  gradient w.r.t. the pose tangent; the canonical and the CB-KNN render, selected by a traced keyframe flag);
- ``map_iteration_1200x680``: one mapping iteration's loss and gradient w.r.t. the Gaussian parameters.

Per program (``OUT/gpu_aot.json``): compile seconds, XLA's memory estimate (arguments, outputs, temporaries), the
compiler's warnings, the GPU kernels it launches, and for each Pallas kernel its grid, threads and shared memory per
block (XLA's thunk sequence), its PTX size and ``ptxas -v``'s registers per thread, spills and stack frame, and the
theoretical occupancy these allow on an SM 9.0 GPU. The executables are serialized to ``OUT/<program>.xla`` and the
Pallas kernels' PTX kept in ``OUT/ptx/``.

Per program also its cost on paper (:func:`program_costs`): XLA's cost analysis of the optimized HLO (flops,
transcendentals, bytes accessed), what it cannot see, estimated (the Pallas kernels, a ``-1`` each to XLA: their
operands read and results written once, their loop bodies' flops counted from :mod:`gsjax.raster.pallas`; the sorts:
one pass to XLA, as many passes as the compiled sort launches kernels), and the roofline floor of each count on an
H100/H200 (:data:`PEAK`, :func:`roofline`). XLA counts a while loop's body once and a conditional's flops over
more than the branch that runs: the 1200x680 programs' counts (three checkpointed compositing batches, both renders
of the keyframe flag) are not one iteration's. ``--roofline PATH`` therefore also compiles the tracking iteration's
stages apart, each without loops or branches (:func:`track_stages`: projection, binning, the selection walk, the
compositing forward and backward, with the loss), and writes the programs' and stages' floors to PATH.

``--run`` (on a GPU): each serialized executable is loaded back onto the device and run on the benchmark's room map,
and its outputs are compared with ``jax.jit`` of the same function on that device: the ahead-of-time path and the
usual one, checked as one (``experiments/gpu_check.sh`` does this).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import pickle
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

# An SM 9.0 GPU with 132 SMs (H100 SXM, H200): the limits the compiler plans with. Runtime 13.0: the CUDA plugin's.
H100 = """
gpu_device_info {
  threads_per_block_limit: 1024
  threads_per_warp: 32
  shared_memory_per_block: 49152
  shared_memory_per_core: 233472
  threads_per_core_limit: 2048
  core_count: 132
  fpus_per_core: 128
  block_dim_limit_x: 2147483647
  block_dim_limit_y: 65535
  block_dim_limit_z: 65535
  memory_bandwidth: 3352320000000
  l2_cache_size: 52428800
  clock_rate_ghz: 1.98
  device_memory_size: 84929347584
  shared_memory_per_block_optin: 232448
  cuda_compute_capability { major: 9 minor: 0 }
  registers_per_core_limit: 65536
  registers_per_block_limit: 65536
}
runtime_version { major: 13 minor: 0 patch: 0 }
platform_name: "CUDA"
dnn_version_info { major: 9 minor: 8 }
device_description_str: "NVIDIA H100 80GB HBM3"
"""
SM90 = dict(registers=65536, threads=2048, blocks=32, shared_bytes=233472, register_unit=256)

THUNK = re.compile(r"kCustomKernel\s+\[[^\]]*\]\s+(?P<name>\S+) grid: \[(?P<grid>[\d, ]+)\] "
                   r"threads: \[(?P<threads>[\d, ]+)\]\s+shared_memory: (?P<shared>\d+) bytes")
# An H100 SXM's datasheet peaks: fp32 FLOP/s without tensor cores, HBM bytes/s (an H200: the same FLOP/s, 4.8 TB/s).
PEAK = dict(flops=67e12, bandwidth=3.35e12)
TRACK_GOAL_MS = 3.0  # the tracking iteration's time goal at 1200x680
# The Pallas kernels' loop bodies in float operations (and exponentials) per unit of :func:`pallas_units`, counted
# from gsjax.raster.pallas: the walk's alpha test (13 with the exp), transmittance update and the two comparisons per
# (list entry, pixel); the blend of colour, depth, silhouette, depth^2 per (slot, pixel); its backward pass (the
# replay of the transmittance, 2, and the suffix recurrence with the five gradients, 25).
PALLAS_FLOPS = {"_walk_kernel": (17, 1), "_composite_kernel": (14, 0), "_composite_bwd_kernel": (27, 0)}
DTYPE_BYTES = dict(pred=1, s8=1, u8=1, s16=2, u16=2, f16=2, bf16=2, s32=4, u32=4, f32=4, s64=8, u64=8, f64=8)
HLO_ARRAY = re.compile(r"\b(?P<dtype>pred|[suf]\d+|bf16)\[(?P<dims>[\d,]*)\]")
HLO_INSTRUCTION = re.compile(r"^\s*(?:ROOT )?%(?P<name>\S+) = (?P<shape>.*?) (?P<op>[a-z][\w-]*)\(")
PTXAS_FUNCTION = re.compile(r"Compiling entry function '(?P<name>[^']+)'")
PTXAS_FRAME = re.compile(r"(?P<stack>\d+) bytes stack frame, (?P<spill_stores>\d+) bytes spill stores, "
                         r"(?P<spill_loads>\d+) bytes spill loads")
PTXAS_USED = re.compile(r"Used (?P<registers>\d+) registers(?:, used (?P<barriers>\d+) barriers)?"
                        r"(?:, (?P<smem>\d+) bytes smem)?")


def parse_thunks(text: str) -> list[dict]:
    """The GPU kernels of XLA's thunk sequence dump: name, grid, threads per block, shared memory per block (bytes)."""
    kernels = []
    for m in THUNK.finditer(text):
        grid = [int(x) for x in m["grid"].split(",")]
        threads = [int(x) for x in m["threads"].split(",")]
        kernels.append(dict(name=m["name"], grid=grid, threads=math.prod(threads), shared_bytes=int(m["shared"])))
    return kernels


def parse_ptxas(text: str) -> dict[str, dict]:
    """``ptxas -v``'s report per entry function: registers per thread, barriers, static shared memory, stack frame
    and spill bytes."""
    found: dict[str, dict] = {}
    name = None
    for line in text.splitlines():
        if m := PTXAS_FUNCTION.search(line):
            name = m["name"]
            found[name] = {}
        elif name and (m := PTXAS_FRAME.search(line)):
            found[name].update({k: int(v) for k, v in m.groupdict().items()})
        elif name and (m := PTXAS_USED.search(line)):
            found[name].update({k: int(v) for k, v in m.groupdict().items() if v is not None})
    return found


def occupancy(threads: int, registers: int, shared_bytes: int, sm: dict = SM90) -> dict:
    """Theoretical occupancy of a kernel on one SM: resident blocks per SM under each limit (threads, registers
    allocated per warp in units of ``register_unit``, shared memory, blocks), the binding one, and the resident
    warps as a share of the SM's maximum."""
    warps = math.ceil(threads / 32)
    per_warp = math.ceil(registers * 32 / sm["register_unit"]) * sm["register_unit"]
    limits = dict(threads=sm["threads"] // (warps * 32), blocks=sm["blocks"],
                  registers=(sm["registers"] // per_warp) // warps if per_warp else sm["blocks"],
                  shared_memory=sm["shared_bytes"] // shared_bytes if shared_bytes else sm["blocks"])
    blocks = min(limits.values())
    return dict(blocks_per_sm=blocks, limited_by=min(limits, key=limits.get),
                occupancy=blocks * warps * 32 / sm["threads"])


def roofline(flops: float, bytes_accessed: float, peak: dict = PEAK) -> dict:
    """Time floor (ms) of a program of ``flops`` float operations and ``bytes_accessed`` bytes of memory traffic on a
    device of ``peak`` FLOP/s and bytes/s: each count's own floor, the larger, and which bounds it."""
    compute_ms, memory_ms = 1e3 * flops / peak["flops"], 1e3 * bytes_accessed / peak["bandwidth"]
    return dict(compute_ms=compute_ms, memory_ms=memory_ms, floor_ms=max(compute_ms, memory_ms),
                bound="memory" if memory_ms >= compute_ms else "compute")


def hlo_arrays(shape: str) -> list[tuple[int, ...]]:
    """The array shapes of an HLO shape string (one, or a tuple's), bytes per element last: [(dims..., bytes)]."""
    return [(*(int(d) for d in m["dims"].split(",") if d), DTYPE_BYTES[m["dtype"]]) for m in HLO_ARRAY.finditer(shape)]


def pallas_units(kernel: str, operands: list[tuple[int, ...]]) -> int:
    """Loop-body runs of a Pallas kernel of :data:`PALLAS_FLOPS` from its operand shapes (``hlo_arrays``): (list
    entry, pixel) pairs of the walk, every entry of every list walked (an upper bound: it stops where all pixels of
    a tile have), (slot, pixel) pairs of the compositing."""
    if kernel == "_walk_kernel":  # operands: count [B], six features [B, M], pixel u, v [B, T^2]
        return math.prod(operands[1][:-1]) * operands[7][-2]
    return math.prod(operands[0][:-1])  # alpha [K, P]


def hlo_inventory(text: str, launches: dict[str, int]) -> dict:
    """What XLA's cost analysis cannot see in an optimized HLO module ``text``, estimated: per Pallas call (target
    ``__gpu$xla.gpu.triton``) its operand and result bytes and loop-body flops (:data:`PALLAS_FLOPS`); per sort its
    bytes and kernel ``launches`` (by thunk name); the while loops' trip counts and the number of conditionals (XLA
    counts a loop's body once, a conditional's flops over more than the branch that runs)."""
    pallas, sorts, trips, conditionals = [], [], [], 0
    for line in text.splitlines():
        if not (m := HLO_INSTRUCTION.match(line)):
            continue
        if m["op"] == "custom-call" and "__gpu$xla.gpu.triton" in line:
            kernel = re.search(r'name = "(\w+)"', line)[1]
            operands = hlo_arrays(re.search(r"operand_layout_constraints=\{(.*?)\}, \w+=", line)[1])
            size = sum(math.prod(a) for a in operands + hlo_arrays(m["shape"]))
            flops, exps = (n * pallas_units(kernel, operands) for n in PALLAS_FLOPS.get(kernel, (0, 0)))
            pallas.append(dict(kernel=kernel, bytes=size, flops=flops, transcendentals=exps))
        elif m["op"] == "sort":
            sorts.append(dict(name=m["name"], bytes=sum(math.prod(a) for a in hlo_arrays(m["shape"])),
                              launches=launches.get(m["name"].replace(".", "_"), 0)))
        elif m["op"] == "while":
            trips.append(int(t[1]) if (t := re.search(r'known_trip_count":\{"n":"(\d+)"', line)) else None)
        conditionals += m["op"] == "conditional"
    return dict(pallas_calls=pallas, sorts=sorts, while_trip_counts=trips, conditionals=conditionals)


def xla_cost_analysis(compiled) -> dict[str, float]:
    """XLA's cost analysis (HloCostAnalysis) of a compiled program. A deviceless GPU executable has none
    (GetCostAnalysis: UNIMPLEMENTED); the same analysis then runs on the CPU client, over its optimized HLO."""
    import jax
    from jax._src.lib import _jax

    if (found := compiled.cost_analysis()) is not None:
        return found
    modules = compiled.runtime_executable().hlo_modules()
    assert len(modules) == 1, "one HLO module per program"
    return _jax.hlo_module_cost_analysis(jax.devices("cpu")[0].client, modules[0])


def program_costs(xla: dict[str, float], inventory: dict) -> dict:
    """XLA's counts (``xla``, :func:`xla_cost_analysis`), the estimates of :func:`hlo_inventory` and the roofline of
    each: ``xla`` counts a Pallas call as -1 flops and -1 bytes (none are added back here) and a sort as one pass;
    ``estimate`` adds the Pallas calls' flops and bytes and the sorts' other passes (a read and a write of all their
    operands per launch)."""
    pallas = {k: sum(call[k] for call in inventory["pallas_calls"]) for k in ("flops", "bytes", "transcendentals")}
    sort_passes = sum(2 * s["bytes"] * max(s["launches"] - 1, 0) for s in inventory["sorts"])
    estimate = dict(flops=xla["flops"] + pallas["flops"],
                    transcendentals=xla.get("transcendentals", 0.0) + pallas["transcendentals"],
                    bytes=xla["bytes accessed"] + pallas["bytes"] + sort_passes,
                    pallas_bytes=pallas["bytes"], sort_extra_pass_bytes=sort_passes)
    return dict(cost_analysis=xla, inventory=inventory,
                roofline_xla=roofline(xla["flops"], xla["bytes accessed"]), estimate=estimate,
                roofline=roofline(estimate["flops"], estimate["bytes"]))


def kernel_name(entry: str) -> str:
    """The function name of a kernel entry: XLA numbers the repeated ones ``name__1``, ``name__2``, ..."""
    return re.sub(r"__\d+$", "", entry)


def dumped(dump: Path, module: str) -> tuple[list[dict], dict[str, Path]]:
    """What XLA's dump folder holds of ``module``: its GPU kernel launches (:func:`parse_thunks`) and the PTX file of
    every entry function."""
    thunks = [k for path in dump.glob(f"module_*.{module}.thunk_sequence.txt") for k in parse_thunks(path.read_text())]
    ptx = {}
    for path in sorted(dump.glob(f"module_*.{module}.*.ptx")):
        for m in re.finditer(r"\.entry (\w+)\(", path.read_text()):
            ptx[m[1]] = path
    return thunks, ptx


def kernel_report(thunks: list[dict], ptx: dict[str, Path], names: set[str], ptxas: str | None) -> list[dict]:
    """Per kernel launch of a function in ``names``: its launch figures, PTX size and ptxas's resources, one row per
    distinct compiled kernel with the number of launches."""
    rows: dict[tuple, dict] = {}
    for thunk in thunks:
        kernel = kernel_name(thunk["name"])
        if kernel not in names:
            continue
        row = dict(thunk, name=kernel, ptx_bytes=ptx[thunk["name"]].stat().st_size if thunk["name"] in ptx else None)
        if ptxas and thunk["name"] in ptx:
            with tempfile.TemporaryDirectory() as tmp:
                done = subprocess.run([ptxas, "-arch=sm_90a", "-v", str(ptx[thunk["name"]]), "-o",
                                       str(Path(tmp) / "k.cubin")], capture_output=True, text=True)
            resources = parse_ptxas(done.stdout + done.stderr).get(thunk["name"], {})
            row.update(resources, ptxas_status=done.returncode)
            if "registers" in resources:
                row.update(occupancy(thunk["threads"], resources["registers"],
                                     thunk["shared_bytes"] + resources.get("smem", 0)))
        key = tuple(json.dumps(v) for k, v in row.items())
        rows.setdefault(key, dict(row, launches=0))["launches"] += 1
    return list(rows.values())


def find_ptxas() -> str | None:
    """ptxas on the PATH, else the one of the ``nvidia-cuda-nvcc`` wheel (``make gpu-aot`` installs it)."""
    if found := shutil.which("ptxas"):
        return found
    import importlib.util

    spec = importlib.util.find_spec("nvidia")
    for root in spec.submodule_search_locations if spec else []:
        for path in sorted(Path(root).glob("*/bin/ptxas")):
            return str(path)
    return None


@contextlib.contextmanager
def captured_stderr(path: Path):
    """Send this process's file descriptor 2 (where XLA's C++ logs go) to ``path`` while inside."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "w") as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)


def paper_config(width: int):
    """The ``replica`` preset in ``paper`` mode for images ``width`` px wide, rendering with the Pallas kernels."""
    from gsjax.slam.presets import preset, with_cbknn_mode

    config = with_cbknn_mode(preset("replica", width), "paper")
    return dataclasses.replace(config, raster=dataclasses.replace(config.raster, backend="pallas"))


def programs():
    """name -> (function, example arguments as numpy/jax arrays on the host): the three programs of the docstring."""
    import jax
    import jax.numpy as jnp

    from gsjax.app.bench import bench_map, weighted_outputs
    from gsjax.camera import se3_exp
    from gsjax.gaussians import Gaussians
    from gsjax.raster import render
    from gsjax.slam.losses import mapping_loss
    from gsjax.slam.tracking import TrackingProblem, tracking_objective
    from gsjax.slam.views import render_view

    def render_program():
        g, w2c, intrinsics = bench_map(640, 480)
        settings = paper_config(640).raster

        def render_fwd_bwd(fields, active, w2c, delta, weights):
            def loss(fields, delta):
                out = render(Gaussians(*fields, active), se3_exp(delta) @ w2c, intrinsics, settings)
                return weighted_outputs(out, weights)
            return jax.value_and_grad(loss, argnums=(0, 1))(fields, delta)

        weights = jax.random.normal(jax.random.PRNGKey(0), (480, 640, 6))
        fields = (g.means, g.log_scales, g.logit_opacities, g.rgb)
        return render_fwd_bwd, (fields, g.active, w2c, jnp.zeros(6), weights)

    def slam_programs():
        g, w2c, intrinsics = bench_map(1200, 680)
        config = paper_config(1200)
        canonical = dataclasses.replace(config.raster, backend="xla")
        observed = jax.jit(lambda g, w2c: render(g, w2c, intrinsics, canonical))(g, w2c)
        start = se3_exp(jnp.asarray([0.01, 0.0, 0.0, 0.0, 0.0087, 0.0], jnp.float32)) @ w2c

        def track_iteration(g, color, depth, start, smooth, gamma, delta):
            problem = TrackingProblem(g, color, depth, start, intrinsics, smooth, gamma)
            return jax.value_and_grad(tracking_objective(problem, config).loss)(delta)

        def map_iteration(params, active, w2c, color, depth, smooth, gamma):
            def loss(params):
                view = render_view(Gaussians(*params, active), w2c, intrinsics, config.raster, config.cbknn, smooth,
                                   gamma)
                m = config.mapping
                return mapping_loss(view, color, depth, m.lambda_color, m.lambda_depth, m.ssim_weight)
            return jax.value_and_grad(loss)(params)

        keyframe, gamma = jnp.bool_(True), jnp.float32(0.5)
        params = (g.means, g.log_scales, g.logit_opacities, g.rgb)
        return {
            "track_iteration_1200x680": (track_iteration, (g, observed.color, observed.depth, start, keyframe, gamma,
                                                           jnp.zeros(6))),
            "map_iteration_1200x680": (map_iteration, (params, g.active, start, observed.color, observed.depth,
                                                       keyframe, gamma)),
        }

    return {"render_fwd_bwd_640x480": render_program(), **slam_programs()}


def track_stages(example) -> dict:
    """name -> (function, example arguments, abstract where not on the host): the tracking iteration of
    :func:`programs` (its ``example``) in stages, each a program without loops or branches: ``project``, ``bin`` (its
    two sorts), ``walk`` (the tile lists' gathers and the selection's Pallas kernel), and per render, canonical and
    CB-KNN (``_cbknn``, a keyframe), the compositing at that selection through the tracking loss: its value
    (``composite_fwd``) and its value and gradient (``composite_fwd_bwd``), in one batch of all slots. (The program
    composites in checkpointed batches: the forward, then the forward again and the backward pass.)"""
    import jax
    import jax.numpy as jnp

    from gsjax.data.room import room_intrinsics
    from gsjax.raster.binning import TileGrid, bin_gaussians
    from gsjax.raster.project import project
    from gsjax.raster.render import SlotSelection
    from gsjax.raster.select import select_contributors
    from gsjax.slam.tracking import TrackingProblem, tracking_objective

    g, color, depth, start, _, gamma, delta = example
    intrinsics = room_intrinsics(*depth.shape)
    config = paper_config(intrinsics.width)
    raster = config.raster
    grid = TileGrid.for_image(intrinsics.height, intrinsics.width, raster.tile_size)
    slots = raster.max_contributors * grid.num_tiles * grid.pixels_per_tile
    one_batch = dataclasses.replace(config, raster=dataclasses.replace(raster, slots_per_batch=slots))

    def project_stage(g, w2c):
        return project(g, w2c, intrinsics, raster.near, raster.dilation)

    def bin_stage(projected):
        return bin_gaussians(projected.uv, projected.extent, projected.depth, projected.visible, grid,
                             raster.tile_capacity, raster.intersection_capacity(g.capacity, grid))

    def walk_stage(projected, tiles):
        return select_contributors(projected, tiles, grid, raster.max_contributors, raster.tiles_per_batch, True)

    projected = jax.eval_shape(project_stage, g, start)
    tiles = jax.eval_shape(bin_stage, projected)
    count = jax.ShapeDtypeStruct((), jnp.int32)
    selection = SlotSelection(*jax.eval_shape(walk_stage, projected, tiles), count, count)
    stages = dict(project=(project_stage, (g, start)), bin=(bin_stage, (projected,)),
                  walk=(walk_stage, (projected, tiles)))
    for suffix, keyframe in (("", False), ("_cbknn", True)):
        def loss(delta, selection, g, color, depth, start, gamma, keyframe=keyframe):
            problem = TrackingProblem(g, color, depth, start, intrinsics, keyframe, gamma)  # a constant branch
            return tracking_objective(problem, one_batch).loss(delta, selection)

        arguments = (delta, selection, g, color, depth, start, gamma)
        stages[f"composite_fwd{suffix}"] = (loss, arguments)
        stages[f"composite_fwd_bwd{suffix}"] = (jax.value_and_grad(loss), arguments)
    return stages


def roofline_summary(cost: dict, goal_ms: float | None = None) -> dict:
    """The roofline figures of :func:`program_costs`' result ``cost``, with the floor's share of ``goal_ms``."""
    estimate, inventory = cost["estimate"], cost["inventory"]
    xla = cost["cost_analysis"]
    summary = dict(estimate, **cost["roofline"],
                   xla=dict(flops=xla["flops"], bytes=xla["bytes accessed"],
                            transcendentals=xla.get("transcendentals", 0.0), **cost["roofline_xla"]),
                   pallas_calls=len(inventory["pallas_calls"]),
                   sort_launches=[s["launches"] for s in inventory["sorts"]],
                   while_trip_counts=inventory["while_trip_counts"], conditionals=inventory["conditionals"])
    if goal_ms:
        summary["floor_vs_goal"] = summary["floor_ms"] / goal_ms
    return summary


def iteration_from_stages(stages: dict, names: list[str], goal_ms: float) -> dict:
    """The stages ``names`` of :func:`roofline_summary`s ``stages`` run one after another: their counts and floors
    added, the stage with the largest floor, and the total's share of ``goal_ms``."""
    total = {k: sum(stages[n][k] for n in names) for k in ("flops", "bytes", "compute_ms", "memory_ms", "floor_ms")}
    return dict(total, stages=names, bounded_by=max(names, key=lambda n: stages[n]["floor_ms"]),
                floor_vs_goal=total["floor_ms"] / goal_ms)


def compare(a, b) -> float:
    """Largest absolute difference over the leaves of two pytrees of arrays, relative to the largest magnitude."""
    import jax
    import numpy as np

    worst = 0.0
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        worst = max(worst, float(np.max(np.abs(x - y), initial=0.0) / max(np.max(np.abs(y), initial=0.0), 1e-12)))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/gpu_aot"))
    parser.add_argument("--programs", default="", help="comma-separated subset of the program names")
    parser.add_argument("--keep-dump", action="store_true", help="keep XLA's whole dump (OUT/xla_dump, ~100 MB)")
    parser.add_argument("--roofline", type=Path,
                        help="also compile the tracking iteration's stages; write the programs' and stages' roofline "
                             "(JSON) here")
    parser.add_argument("--run", action="store_true",
                        help="on a GPU: load each serialized executable and compare its outputs with jax.jit's")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    dump = args.out / "xla_dump"
    shutil.rmtree(dump, ignore_errors=True)
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_dump_to={dump.resolve()}".strip()
    if not args.run:
        os.environ.setdefault("JAX_PLATFORMS", "cpu")  # nothing runs on a GPU: no driver needed

    import jax
    from jax.experimental import serialize_executable, topologies

    from gsjax.raster import pallas

    kernels = {name for name in dir(pallas) if name.endswith("_kernel")}
    ptxas = find_ptxas()
    result = dict(jax=jax.__version__, target=H100.strip(), ptxas=ptxas, programs={})
    try:
        topology = topologies.get_topology_desc(platform="cuda", target_config=H100, topology="1x1x1")
    except Exception as error:  # no CUDA plugin: say which step cannot be done here, and why
        result["error"] = f"get_topology_desc(platform='cuda'): {type(error).__name__}: {error}"
        print(json.dumps(result, indent=1))
        (args.out / "gpu_aot.json").write_text(json.dumps(result, indent=1))
        return 1
    mesh = topologies.make_mesh(topology, (1,), ("gpu",))
    replicated = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())

    def compile_for_gpu(name, fn, example, report):
        """``fn`` on ``example`` compiled for the target (None on error, in ``report`` with the compile time and the
        compiler's warnings) and its GPU kernels (thunks) and PTX; the program's costs (:func:`program_costs`)."""
        fn.__name__ = fn.__qualname__ = name  # the module's name in the dump: jit_<name>
        abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=replicated), example)
        log = args.out / f"{name}.log"
        t0 = time.perf_counter()
        try:
            with captured_stderr(log):
                compiled = jax.jit(fn).lower(*abstract).compile()
        except Exception as error:
            report["error"] = f"{type(error).__name__}: {str(error)[:2000]}"
        report["compile_s"] = round(time.perf_counter() - t0, 2)
        report["compiler_warnings"] = sorted({line.split("] ", 1)[-1].strip() for line in log.read_text().splitlines()
                                              if line[:1] in "WE" and "] " in line})
        if "error" in report:
            return None, [], {}
        thunks, ptx = dumped(dump, f"jit_{name}")
        launches = Counter(kernel_name(thunk["name"]) for thunk in thunks)
        report["cost"] = program_costs(xla_cost_analysis(compiled), hlo_inventory(compiled.as_text(), launches))
        return compiled, thunks, ptx

    chosen = [p for p in args.programs.split(",") if p]
    examples = programs()
    for name, (fn, example) in examples.items():
        if chosen and name not in chosen:
            continue
        report: dict = {}
        compiled, thunks, ptx = compile_for_gpu(name, fn, example, report)
        if compiled is not None:
            memory = compiled.memory_analysis()
            report["memory_mib"] = {k: round(getattr(memory, f"{k}_size_in_bytes") / 2**20, 2)
                                    for k in ("argument", "output", "temp", "alias")}
            report["gpu_kernels"] = len(thunks)
            report["pallas_kernels"] = kernel_report(thunks, ptx, kernels, ptxas)
            (args.out / "ptx").mkdir(exist_ok=True)
            for entry, path in ptx.items():
                if kernel_name(entry) in kernels:
                    shutil.copyfile(path, args.out / "ptx" / f"{name}.{entry}.ptx")
            payload = serialize_executable.serialize(compiled)
            (args.out / f"{name}.xla").write_bytes(pickle.dumps(payload))
            report["serialized_mib"] = round(len(payload[0]) / 2**20, 2)
            if args.run:
                report["run"] = run_on_device(fn, example, payload)
        result["programs"][name] = report
        print(name, json.dumps(report, indent=1), flush=True)
    if args.roofline:
        result["track_stages"] = {}
        for stage, (fn, example) in track_stages(examples["track_iteration_1200x680"][1]).items():
            report = result["track_stages"][stage] = {}
            compile_for_gpu(f"track_1200x680_{stage}", fn, example, report)
            print(stage, json.dumps(report["cost"]["roofline"] if "cost" in report else report), flush=True)
        write_roofline(args.roofline, result, shlex.join([os.path.relpath(sys.executable), os.path.relpath(__file__),
                                                          *(sys.argv[1:] if argv is None else argv)]))
    (args.out / "gpu_aot.json").write_text(json.dumps(result, indent=1))
    if not args.keep_dump:
        shutil.rmtree(dump, ignore_errors=True)
    print(f"wrote {args.out / 'gpu_aot.json'} and the Pallas kernels' PTX in {args.out / 'ptx'}")
    reports = [*result["programs"].values(), *result.get("track_stages", {}).values()]
    return 0 if all("error" not in r and "error" not in r.get("run", {}) for r in reports) else 1


def write_roofline(path: Path, result: dict, command: str) -> None:
    """The roofline of ``result``'s programs and tracking stages (:func:`roofline_summary`) and of a tracking
    iteration from its stages (:func:`iteration_from_stages`), canonical and keyframe, as the program composites (the
    forward, then the forward again with the backward pass) and in one batch (the forward once), to ``path`` (JSON)."""
    goal = {"track_iteration_1200x680": TRACK_GOAL_MS}
    programs = {n: roofline_summary(r["cost"], goal.get(n)) for n, r in result["programs"].items() if "cost" in r}
    stages = {n: roofline_summary(r["cost"]) for n, r in result["track_stages"].items() if "cost" in r}
    iterations = {}
    for kind, suffix in (("canonical", ""), ("keyframe", "_cbknn")):
        names = ["project", "bin", "walk", f"composite_fwd{suffix}", f"composite_fwd_bwd{suffix}"]
        if set(names) <= set(stages):  # as compiled (checkpointed batches), and with the slots kept (one batch)
            iterations[f"track_iteration_1200x680_{kind}"] = iteration_from_stages(stages, names, TRACK_GOAL_MS)
            iterations[f"track_iteration_1200x680_{kind}_one_batch"] = iteration_from_stages(
                stages, names[:3] + names[4:], TRACK_GOAL_MS)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(dict(
        command=command, jax=result["jax"], peak=PEAK, goal_ms=goal,
        method=("flops, bytes, transcendentals: estimates = XLA's cost analysis of the optimized HLO (xla) + the "
                "Pallas calls' operand/result bytes and loop-body flops (gsjax.raster.pallas, counted by hand) + the "
                "sorts' passes beyond XLA's one (a read and a write per kernel launch); floor_ms = max(flops / peak "
                "flops, bytes / bandwidth); XLA counts a while body once and a conditional's flops over more than one "
                "branch (both branches' Pallas calls and sorts are counted too): see track_stages"),
        programs=programs, track_stages=stages, track_iterations_from_stages=iterations), indent=1))


def run_on_device(fn, example, payload) -> dict:
    """Load the serialized executable onto this machine's GPU, run it on ``example`` and compare with jax.jit."""
    import jax
    from jax.experimental import serialize_executable

    try:
        loaded = serialize_executable.deserialize_and_load(*payload, backend="cuda")
        device = jax.devices("cuda")[0]
        on_device = jax.device_put(example, device)
        aot = jax.block_until_ready(loaded(*on_device))
        jitted = jax.block_until_ready(jax.jit(fn)(*on_device))
        return dict(max_relative_difference=compare(aot, jitted))
    except Exception as error:
        return dict(error=f"{type(error).__name__}: {str(error)[:2000]}")


if __name__ == "__main__":
    sys.exit(main())
