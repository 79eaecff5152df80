#!/usr/bin/env bash
# The GPU check of the Pallas hot path, in one prepared script (< 10 min on a fresh GPU machine with JAX installed,
# no network; gsjax runs from the checkout via PYTHONPATH):
#   1. the GPU tests (tests/raster/test_gpu.py): compiled Pallas vs XLA on a 640x480 map, values and gradients;
#   2. gsjax bench, xla and pallas, at 640x480 and 1200x680;
#   3. a 40-frame full-resolution (640x480) run of the 7-Scenes sample with the replica preset (40 tracking +
#      60 mapping iterations per frame), on the default backend (pallas on a GPU);
#   4. the ahead-of-time path (experiments/gpu_aot_check.py --run): the programs compiled for an H100 from its
#      description, as on a machine without a GPU, then loaded onto this GPU, run, and compared with jax.jit;
# and writes one JSON of results, $OUT/gpu_check.json (default OUT=outputs/gpu_check).
#
# Prepare on a machine with the data (no GPU needed), then carry the two ignored folders:
#   bash experiments/gpu_check.sh --prepare     # .gpu_data/7scenes (40 frames), .whl/ (dm-pix, absent there)
#   device run: bash experiments/gpu_check.sh   (carry: .gpu_data, .whl)
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-outputs/gpu_check}
DATA=${GSJAX_SHARED_DATA:-../shared/data}/7scenes_redkitchen
FRAMES=40
# A dry run on a CPU (the script's plumbing only): SIZES=32x24 RUN_FRAMES=2 RUN_EXTRA="--downscale 8" OUT=/tmp/gc
SIZES=${SIZES:-640x480,1200x680}
RUN_FRAMES=${RUN_FRAMES:-$FRAMES}
RUN_EXTRA=${RUN_EXTRA:-}
PY=${PYTHON:-python3}

if [ "${1:-}" = "--prepare" ]; then
    set -e
    mkdir -p .gpu_data/7scenes
    cp "$DATA/camera-intrinsics.txt" .gpu_data/7scenes/
    for i in $(seq 0 $((FRAMES - 1))); do cp "$DATA"/frame-$(printf %06d "$i").* .gpu_data/7scenes/; done
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux2014_x86_64 -d .whl dm-pix==0.4.5
    du -sh .gpu_data .whl
    exit 0
fi

mkdir -p "$OUT"
rm -f "$OUT/tests.jsonl"
export PYTHONPATH=.
if ! "$PY" -c "import dm_pix" 2>/dev/null && ls .whl/*.whl >/dev/null 2>&1; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH=.:/tmp/site
fi
export GSJAX_CACHE_DIR=${GSJAX_CACHE_DIR:-/tmp/gsjax_cache}
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"; } \
    | tee "$OUT/gpu.txt"
"$PY" -c "import jax; print('jax', jax.__version__, jax.devices())" | tee -a "$OUT/gpu.txt"

start=$SECONDS
step() {  # step NAME TIMEOUT_S COMMAND...: run with a time limit, record status and seconds
    local name=$1 limit=$2; shift 2
    local t0=$SECONDS
    timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
    local status=$?
    echo "{\"step\": \"$name\", \"status\": $status, \"seconds\": $((SECONDS - t0))}" >> "$OUT/steps.jsonl"
    tail -n 25 "$OUT/$name.log"
}
rm -f "$OUT/steps.jsonl"
GSJAX_GPU_REPORT="$OUT/tests.jsonl" step tests 120 "$PY" -m pytest -q -p no:cacheprovider tests/raster/test_gpu.py
step bench 180 "$PY" -m gsjax bench --backend xla,pallas --sizes "$SIZES" --repeats 5 \
    --out "$OUT/bench.json"
if [ -d .gpu_data/7scenes ]; then
    step run 150 "$PY" -m gsjax run --dataset 7scenes --path .gpu_data/7scenes --preset replica \
        --max-frames "$RUN_FRAMES" --out "$OUT/run" --overwrite --no-progress $RUN_EXTRA
else
    echo '{"step": "run", "status": "skipped: no .gpu_data/7scenes (bash experiments/gpu_check.sh --prepare)"}' \
        >> "$OUT/steps.jsonl"
fi
step aot 120 "$PY" experiments/gpu_aot_check.py --out "$OUT/aot" --run
"$PY" experiments/gpu_check.py "$OUT" && echo "total $((SECONDS - start)) s"
