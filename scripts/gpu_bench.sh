#!/usr/bin/env bash
# The scaling benchmark (issue 10, docs/benchmark.md) on a lent GPU: both models, inference and a training
# step, 1k to 1M particles, the fp32 matmul peak of the same GPU, and a rollout's memory at 50 vs 500 frames.
# Writes scaling_cuda.json, scaling_cuda.png and scaling_cuda.txt to $OUT (3 files). Sizes that do not fit
# --max-seconds (per measurement) or the GPU's memory are skipped with their reason; a few minutes in all.
# Run alone, or from scripts/gpu_pretrain.sh (which calls it first unless SKIP_SCALING=1). Needs, carried, the
# .whl folder gpu_pretrain.sh describes (gnsx.training.system imports the metrics, which need POT).
#   DRY=1 OUT=/tmp/out bash scripts/gpu_bench.sh     # the same steps on this CPU, tiny, to catch errors
set -euo pipefail
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg
OUT=${OUT:?set OUT}
mkdir -p "$OUT"
PY=python3
ARGS=(--device cuda --max-seconds "${MAX_SECONDS:-20}" --rollout-memory --rollout-particles 100000)
if [ "${DRY:-0}" = 1 ]; then
  PY=${PY_DRY:-.venv/bin/python}
  ARGS=(--device cpu --threads 1 --sizes 200 600 --repeats 2 --matmul-size 256 --rollout-memory
        --rollout-frames 5 20 --rollout-particles 100)
elif [ -z "${GNSX_WHEELS_INSTALLED:-}" ]; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=${PYTHONPATH:+$PYTHONPATH:}$PWD
tag=$([ "${DRY:-0}" = 1 ] && echo cpu || echo cuda)
$PY -m gnsx.perf.benchmark "${ARGS[@]}" --json "$OUT/scaling_$tag.json" 2>&1 | tee "$OUT/scaling_$tag.txt"
