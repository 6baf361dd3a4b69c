#!/usr/bin/env bash
# Copy a resumable sweep's jobs into a folder that is committed, so that a fresh machine resumes the sweep:
#   BUDGET_DIR=<sweep folder> KEEP=<committed folder> bash scripts/keep_jobs.sh
# A finished job (results.json "status": "ok") keeps its record: results.json, curve.jsonl, the grid's frames,
# .hydra, and its final weights as model.ckpt (no optimizer state, gnsx.training.export.strip_checkpoint: what a
# report needs to roll the cell out again, e.g. the grid's animation; ~0.7 MB at 64/5, ~5 MB at 128/10). An
# unfinished one keeps the same plus its checkpoints/last.ckpt (optimizer included) to resume from; a finished
# job's is dropped (it is skipped on resume). The .gitignore admits both under docs/**/jobs/.
# Nothing is removed from the sweep folder; a job that has neither a record nor a checkpoint is left out.
set -euo pipefail
src=${BUDGET_DIR:?set BUDGET_DIR=<sweep folder>}
keep=${KEEP:?set KEEP=<folder to commit>}
py=${PY:-.venv/bin/python}
[ -d "$src" ] || { echo "keep_jobs: no sweep folder $src" >&2; exit 2; }
for job in "$src"/*/; do
    job=${job%/}
    name=$(basename "$job")
    [ -f "$job/results.json" ] || [ -f "$job/checkpoints/last.ckpt" ] || continue
    dest="$keep/$name"
    mkdir -p "$dest"
    for f in results.json curve.jsonl frame_0150.png frame_truth_0150.png; do
        [ -f "$job/$f" ] && cp "$job/$f" "$dest/"
    done
    [ -d "$job/.hydra" ] && { mkdir -p "$dest/.hydra"; cp "$job"/.hydra/*.yaml "$dest/.hydra/"; }
    if grep -qs '"status": "ok"' "$job/results.json"; then
        rm -rf "$dest/checkpoints"
        if [ -f "$job/checkpoints/last.ckpt" ] && [ ! -f "$dest/model.ckpt" ]; then
            "$py" -c 'import sys; from gnsx.training.export import strip_checkpoint; strip_checkpoint(*map(__import__("pathlib").Path, sys.argv[1:]))' \
                "$job/checkpoints/last.ckpt" "$dest/model.ckpt"
        fi
        echo "finished:   $dest"
    elif [ -f "$job/checkpoints/last.ckpt" ]; then
        mkdir -p "$dest/checkpoints"
        cp "$job/checkpoints/last.ckpt" "$dest/checkpoints/last.ckpt"
        echo "unfinished: $dest (checkpoints/last.ckpt kept)"
    fi
done
