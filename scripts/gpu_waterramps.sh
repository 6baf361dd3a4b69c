#!/usr/bin/env bash
# Issue 9, item 7: train the shipped model's configuration (simplified_pairwise) on the `waterramps` preset
# (R = 0.015, ~1.5k particles, 601 frames) on a lent GPU, for what one device call allows. The GPU machine
# generates the training and validation trajectories (~12 s of one core each on the 2-core CPU; 124 took 217 s
# with 16 processes on the H200's machine) and
# trains; the test trajectories are not made there: they are generated and scored on the CPU afterwards
# (`make waterramps-eval`), so the lease goes to training. Everything lands in $OUT (at most 8 files):
# gpu.txt (GPU, generation time), train_log.txt, metrics.csv, results.json, last.ckpt, permanent.tgz.
#   carried: .whl  hydra-core, omegaconf, antlr4 and tfrecord (pip wheel), crc32c wheels for the image's Python 3.12
#            (scripts/gpu_pretrain.sh says how; POT is not needed: nothing here scores EMD)
#   DRY=1 OUT=/tmp/out bash scripts/gpu_waterramps.sh   # the same steps on this CPU, tiny, to catch errors
#   (2026-12-04 it ran with PYTHONPATH=<a folder whose sitecustomize.py makes `import wandb`, `import ot` and
#   `import imageio_ffmpeg` fail>, as they do on the image, and both stages passed before the lease.)
# STAGE=finetune (a second call on the still-warm machine, as on 2026-12-04): a fresh schedule from the first
# stage's last.ckpt on the same data, LR 5e-4 decayed to 1e-5 over FT_BUDGET (3 min); writes ft_last.ckpt,
# ft_metrics.csv, ft_results.json.
# Knobs: TRAIN (training trajectories, 120), BUDGET (fit's wall clock, DD:HH:MM:SS), BATCH (32), LR (2e-3:
# the GPU recipe of the small preset's, scripts/gpu_pretrain.sh), WORKERS (simulation processes, 16).
set -euo pipefail
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg WANDB_MODE=offline
OUT=${OUT:?set OUT}
mkdir -p "$OUT"
PY=python3 TRAINER=gpu TRAIN=${TRAIN:-120} VALID=4 WORKERS=${WORKERS:-16} BUDGET=${BUDGET:-00:00:05:00}
BATCH=${BATCH:-32} LR=${LR:-2e-3} VAL_EVERY=${VAL_EVERY:-2000} LOADERS=4
if [ "${DRY:-0}" = 1 ]; then
  PY=${PY_DRY:-.venv/bin/python} TRAINER=cpu TRAIN=2 VALID=1 WORKERS=2 BUDGET=00:00:00:40 BATCH=2 VAL_EVERY=20
  LOADERS=0
else
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
  nvidia-smi --query-gpu=name,memory.total --format=csv | tee "$OUT/gpu.txt"
  nproc | sed 's/^/cpu cores: /' | tee -a "$OUT/gpu.txt"
fi
export PYTHONPATH=${PYTHONPATH:+$PYTHONPATH:}$PWD
DATA=/tmp/gnsx_data/waterramps_gpu
RUN=/tmp/gnsx_run_waterramps
# The recipe of both stages; each stage adds its data, schedule and run folder.
recipe=(data=waterramps data.root="$DATA" data.batch_size="$BATCH" data.num_workers="$LOADERS"
  trainer="$TRAINER" train=pretrain train.max_steps=40000 train.fit_to_max_time=true
  train.val_every_n_steps="$VAL_EVERY" train.val_max_trajectories=2 train.checkpoint_every_n_steps=500
  train.permanent_every_n_steps=1000 train.checkpoint_every_minutes=1 logger=csv evaluate.enabled=false
  evaluate.render=false evaluate.pretrained=null)

if [ "${STAGE:-base}" = finetune ]; then
  FT=/tmp/gnsx_run_waterramps_ft
  [ -f "$RUN/checkpoints/last.ckpt" ] || { echo "no first stage in $RUN: run the script without STAGE first"; exit 2; }
  rm -rf "$FT"
  trap 'cp -L "$FT/checkpoints/last.ckpt" "$OUT/ft_last.ckpt"; cp "$FT/results.json" "$OUT/ft_results.json";
        cp "$(ls "$FT"/csv/version_*/metrics.csv | tail -1)" "$OUT/ft_metrics.csv"; ls -la "$OUT"' EXIT
  $PY train.py "${recipe[@]}" train.init_weights="$RUN/checkpoints/last.ckpt" train.lr_init=5e-4 \
    train.max_time="${FT_BUDGET:-00:00:03:00}" hydra.run.dir="$FT" 2>&1 | grep -vE "it/s|^\s*$" | tail -40 \
    | tee "$OUT/ft_train_log.txt"
  exit 0
fi
rm -rf "$DATA" "$RUN"

# Whatever happens below, bring back what the run left.
save() {
  [ -f "$RUN/results.json" ] && cp "$RUN/results.json" "$OUT/results.json"
  ls "$RUN"/csv/version_*/metrics.csv >/dev/null 2>&1 && cp "$(ls "$RUN"/csv/version_*/metrics.csv | tail -1)" "$OUT/metrics.csv"
  # Only the last and the permanent checkpoints (2.1 MB each with the optimizer): the running ones made the
  # 2026-12-04 tarball 19 MB, over the 16 MB a file may have to come back.
  [ -f "$RUN/checkpoints/last.ckpt" ] && cp -L "$RUN/checkpoints/last.ckpt" "$OUT/last.ckpt"
  [ -d "$RUN/checkpoints/permanent" ] && tar czf "$OUT/permanent.tgz" -C "$RUN" checkpoints/permanent .hydra
  ls -la "$OUT"
}
trap save EXIT

start=$(date +%s)
$PY -m gnsx.data generate --preset waterramps --out "$DATA" --seed 0 --train "$TRAIN" --valid "$VALID" \
  --test 0 --workers "$WORKERS" 2>&1 | tail -1
echo "generated $TRAIN + $VALID trajectories in $(( $(date +%s) - start )) s" | tee -a "$OUT/gpu.txt"

# The small preset's GPU recipe (make pretrain-gpu): batch 32, LR 2e-3 decayed to 1e-5, steps fitted to the
# budget; validation rollouts on 2 trajectories (their cost is budgeted too) and a permanent checkpoint
# every 1000 steps; last.ckpt every minute, so a cut call still brings weights back.
$PY train.py "${recipe[@]}" train.lr_init="$LR" train.max_time="$BUDGET" hydra.run.dir="$RUN" \
  2>&1 | grep -vE "it/s|^\s*$" | tail -60 | tee "$OUT/train_log.txt"
echo "train.py finished $(( $(date +%s) - start )) s after the start of generation" | tee -a "$OUT/gpu.txt"
