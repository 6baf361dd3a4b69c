# gnsx: every target creates/uses the project's own virtual environment in .venv.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
# torch is installed first and pinned: on these machines 2.13.0 is a CPU wheel on disk; an unpinned
# torch would pull a multi-GB CUDA build. Override for a GPU box: make install TORCH_SPEC='torch==2.13.0'
TORCH_SPEC ?= torch==2.13.0
DATA ?= data/small
RUN ?=

.DEFAULT_GOAL := help
.PHONY: help install demo train test test-slow lint format data data-waterramps budget budget-keep fig9-trained fig9-trained-keep radius-trained versus-trained pretrain pretrain-pairwise pretrain-gpu pretrain-dam waterramps-eval bench-train evaluate simulate hardcases fig9-mini radius-mini learning learning-long learning-long-keep demo-choice equal-budget fig9 radius report bench bench-cull bench-bound clean study study-serve install-browser validate-mpm sensitivity

help: ## Show this help
	@grep -E '^[a-zA-Z0-9_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}'

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q "$(TORCH_SPEC)"
	$(PIP) install -q -e '.[dev]'
	touch $@

install: $(VENV)/.installed ## Create .venv and install gnsx with its dependencies (torch pinned first)
	@# The fused CPU inference kernels (gnsx/model/fused.py): built once per machine (~30 s), cached after.
	@$(PY) -c "import sys; from gnsx.model import fused; sys.exit(fused.build())" || \
		echo "warning: no C++ toolchain for the fused kernels; gnsx runs its eager path (same results, slower)"

demo: install ## Main job: generate the small preset, train the simplified GNS, evaluate, render (<= 15 min on CPU)
	$(PY) train.py

train: install ## Train with Hydra overrides, e.g. make train ARGS='model=original train.max_steps=2000'
	$(PY) train.py $(ARGS)

test: install ## Fast test suite (CPU, a few minutes)
	$(PY) -m pytest -q

test-slow: install ## Slow tests: end-to-end training, sweeps, benchmarks
	$(PY) -m pytest -q -m slow

lint: install ## ruff lint + format check
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: install ## Apply ruff formatting and fixes
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

data: install ## Generate the small default preset into data/small
	$(PY) -m gnsx.data generate --preset small --out $(DATA)

validate-mpm: install ## MPM ground truth vs Martin & Moyce, hydrostatics, rest, impacts; before/after table + figure (~20 min)
	$(PY) -m gnsx.mpm.validate --out outputs/validate-mpm $(ARGS)

data-waterramps: install ## Generate the full WaterRamps-like preset (1000/100/100 x 601 frames; hours)
	$(PY) -m gnsx.data generate --preset waterramps --out data/waterramps

PRETRAIN_DIR ?= outputs/pretrain/small
pretrain: install ## Train the shipped weights' recipe on CPU: the paper's 64/5 with its schedule, 200k steps on 400 scenes (~3.5 h of one thread; rerun to resume), then ship the last checkpoint
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	$(PY) train.py --config-dir sweeps --config-name learning_long learning_arm=paperlr hydra.run.dir=$(PRETRAIN_DIR) \
		$$([ -f $(PRETRAIN_DIR)/checkpoints/last.ckpt ] && echo train.ckpt_path=$(PRETRAIN_DIR)) $(ARGS)
	$(PY) -m gnsx.training.export $(PRETRAIN_DIR) pretrained/small

PRETRAIN_PAIRWISE_DIR ?= outputs/pretrain/small_pairwise
pretrain-pairwise: install ## The recipe of the weights shipped before 2026-12-07 (pairwise decoder, 100k steps, hours; rerun to resume), exported behind the rest gate to outputs/pretrain/small_pairwise/export
	$(PY) train.py data=small_400 train=pretrain hydra.run.dir=$(PRETRAIN_PAIRWISE_DIR) evaluate.render=false $(ARGS) \
		$$([ -f $(PRETRAIN_PAIRWISE_DIR)/checkpoints/last.ckpt ] && echo train.ckpt_path=$(PRETRAIN_PAIRWISE_DIR))
	$(PY) -m gnsx.training.export $(PRETRAIN_PAIRWISE_DIR) $(PRETRAIN_PAIRWISE_DIR)/export --select-best-val

PRETRAIN_GPU_DIR ?= outputs/pretrain/small_gpu
pretrain-gpu: install ## pretrain-pairwise's recipe on one GPU (batch 32, LR 2e-3, 4.5 min fitted schedule), exported to outputs/pretrain/small_gpu/export
	$(PY) train.py data=small_400 data.batch_size=32 data.num_workers=4 trainer=gpu train=pretrain \
		train.max_steps=40000 train.max_time=00:00:04:30 train.fit_to_max_time=true train.lr_init=2e-3 \
		train.val_every_n_steps=2000 train.val_max_trajectories=4 train.checkpoint_every_n_steps=500 \
		train.permanent_every_n_steps=2000 evaluate.render=false hydra.run.dir=$(PRETRAIN_GPU_DIR) $(ARGS)
	$(PY) -m gnsx.training.export $(PRETRAIN_GPU_DIR) $(PRETRAIN_GPU_DIR)/export --select-best-val

PRETRAIN_DAM_DIR ?= outputs/pretrain/small_dam
pretrain-dam: install ## Two-stage recipe (15k steps on 400 scenes, then 8k on pools and dam breaks; ~25 min): exported to outputs/pretrain/small_dam/export, not shipped (docs/decisions)
	$(PY) train.py data=small_400 train=pretrain train.max_steps=15000 train.val_every_n_steps=5000 \
		train.permanent_every_n_steps=1000 evaluate.enabled=false evaluate.render=false \
		hydra.run.dir=$(PRETRAIN_DAM_DIR)/base $(ARGS) \
		$$([ -f $(PRETRAIN_DAM_DIR)/base/checkpoints/last.ckpt ] && echo train.ckpt_path=$(PRETRAIN_DAM_DIR)/base)
	$(PY) train.py data=small_rest_dam train=finetune evaluate.render=false hydra.run.dir=$(PRETRAIN_DAM_DIR)/finetune $(ARGS) \
		$$([ -f $(PRETRAIN_DAM_DIR)/finetune/checkpoints/last.ckpt ] \
			&& echo train.ckpt_path=$(PRETRAIN_DAM_DIR)/finetune train.init_weights=null \
			|| echo train.init_weights=$(PRETRAIN_DAM_DIR)/base/checkpoints/permanent/step00010000.ckpt)
	$(PY) -m gnsx.training.export $(PRETRAIN_DAM_DIR)/finetune $(PRETRAIN_DAM_DIR)/export --select-best-val

WATERRAMPS_EVAL ?= data/waterramps_eval
waterramps-eval: install ## Score a waterramps-preset model (CKPT=run dir or .ckpt) on 16 test trajectories made here (~3 min once) against the baseline
	@[ -n "$(CKPT)" ] || { echo "set CKPT=<run dir or .ckpt of a waterramps-preset model> (scripts/gpu_waterramps.sh trains one)"; exit 2; }
	@[ -f $(WATERRAMPS_EVAL)/metadata.json ] || $(PY) -m gnsx.data generate --preset waterramps \
		--out $(WATERRAMPS_EVAL) --seed 0 --train 2 --valid 4 --test 16
	$(PY) evaluate.py checkpoint=$(CKPT) data.root=$(WATERRAMPS_EVAL) split=test metrics.timing_repeats=0 \
		metrics.emd_every=50 $(ARGS)

bench-train: install ## Training samples/s and steps/s (Lightning loop), e.g. ARGS='--batch-size 2 8 --threads 2 --precision 32-true bf16-mixed'
	@[ -f $(DATA)/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out $(DATA)
	$(PY) -m gnsx.perf.throughput --data $(DATA) $(ARGS)

SWEEP_STAMP := $(shell date +%Y-%m-%d_%H-%M-%S)
SWEEP ?= $(shell ls -dt multirun/*/*/ 2>/dev/null | head -1)
FIG9_MINI_DIR ?= multirun/fig9_mini/main
RADIUS_MINI_DIR ?= multirun/radius_mini/main
fig9-mini: install ## Figure 9 at 10k steps (docs/fig9/steps_10k), the paper's radius and recipe: 16 cells + seeds 1-2 of 16/1, 32/10, 64/5, 128/3, 10k steps each, 16 test trajectories (~2 h 15 min on 2 cores; resumable: rerun to continue), then the report and the claims table
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@# Cells finished in an earlier session and committed (docs/fig9/steps_10k/jobs/) are not trained again.
	@mkdir -p $(FIG9_MINI_DIR); for job in docs/fig9/steps_10k/jobs/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(FIG9_MINI_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(FIG9_MINI_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name fig9_mini hydra.sweep.dir=$(FIG9_MINI_DIR) $(ARGS)
	@# Two more seeds of four cells spread over both axes: the F test of cells against seeds needs them.
	for cell in 16/1 32/10 64/5 128/3; do $(PY) train.py -m --config-dir sweeps --config-name fig9_mini \
		hydra.sweep.dir=$(FIG9_MINI_DIR) model.latent_size=$${cell%/*} model.mp_steps=$${cell#*/} seed=1,2 $(ARGS) \
		|| exit 1; done
	@# Every cell timed again together in this (now quiet) process: in-job timings ran beside another job.
	$(PY) -m gnsx.evaluation.report.retime $(FIG9_MINI_DIR)
	@# Finished cells' records (no checkpoints) go to docs/fig9/steps_10k/jobs/: committed, a later session skips them.
	@for job in $(FIG9_MINI_DIR)/*/; do grep -qs '"status": "ok"' "$$job/results.json" || continue; \
		dest=docs/fig9/steps_10k/jobs/$$(basename "$$job"); mkdir -p "$$dest"; \
		cp "$$job"/results.json "$$dest"/; cp "$$job"/*.png "$$dest"/ 2>/dev/null || true; \
		cp -r "$$job"/.hydra "$$dest"/ 2>/dev/null || true; done
	$(PY) -m gnsx.evaluation.report $(FIG9_MINI_DIR) --out docs/fig9/steps_10k --wandb disabled
	$(PY) -m gnsx.evaluation.report.claims --grid docs/fig9/steps_10k --compare docs/fig9/radius_0.035 \
		--radius docs/radius --versus docs/original-vs-simplified --out docs/fig9/steps_10k

BUDGET_DIR ?= multirun/budget/main
BUDGET_KEEP ?= docs/fig9/budget/jobs
BUDGET_SHIPPED := $(BUDGET_DIR)/model.latent_size=64,model.mp_steps=5,seed=0,train.max_steps=200000
budget: install ## The budget curve: the paper's 64/5 at 25k/50k/100k steps x seeds 0-1 and seed 1 at 200k (~9 h on each of 2 cores; resumable across sessions), then docs/fig9/budget
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@# Seed 0 at 200k is the shipped weights' run (same recipe): its committed record stands in for the job.
	@mkdir -p $(BUDGET_DIR); [ -e "$(BUDGET_SHIPPED)" ] || cp -r docs/learning/long/paperlr "$(BUDGET_SHIPPED)"
	@# Jobs committed by an earlier session (records, or an unfinished job's last.ckpt) resume here.
	@for job in $(BUDGET_KEEP)/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(BUDGET_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(BUDGET_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name budget hydra.sweep.dir=$(BUDGET_DIR) $(ARGS)
	@$(MAKE) --no-print-directory budget-keep
	$(PY) -m gnsx.evaluation.report.budget $(BUDGET_DIR) --out docs/fig9/budget

budget-keep: ## Copy the budget curve's jobs to docs/fig9/budget/jobs to commit: records of finished jobs, last.ckpt of unfinished ones
	@BUDGET_DIR=$(BUDGET_DIR) KEEP=$(BUDGET_KEEP) bash scripts/keep_jobs.sh

FIG9_TRAINED_DIR ?= multirun/fig9_trained/main
FIG9_TRAINED_KEEP ?= docs/fig9/jobs
# The grid's length: the budget curve's pick (docs/fig9/budget/budget.json), or BUDGET=<steps> by hand.
BUDGET ?= $(shell python3 -c "import json; print(json.load(open('docs/fig9/budget/budget.json'))['decision']['budget'] or '')" 2>/dev/null)
fig9-trained: install ## Figure 9 of trained models: 16 cells + seeds 1-2 of 16/1, 32/10, 64/5, 128/3 at the budget curve's length (tens of hours of one thread on each of 2 cores; resumable across sessions), then the report
	@[ -n "$(BUDGET)" ] || { echo "the budget curve has not picked a budget yet (docs/fig9/budget/budget.json): make budget, or set BUDGET=<steps>"; exit 2; }
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@mkdir -p $(FIG9_TRAINED_DIR)
	@# The paper's 64/5 at seeds 0 and 1 are the budget curve's jobs at this length: copied in, not trained twice.
	@for seed in 0 1; do name=fig9_cell=64x5$$([ $$seed = 0 ] || echo _seed$$seed),train.max_steps=$(BUDGET); \
		for src in $(BUDGET_DIR) $(BUDGET_KEEP); do job="$$src/model.latent_size=64,model.mp_steps=5,seed=$$seed,train.max_steps=$(BUDGET)"; \
			[ ! -e "$(FIG9_TRAINED_DIR)/$$name" ] && grep -qs '"status": "ok"' "$$job/results.json" && \
				cp -r "$$job" "$(FIG9_TRAINED_DIR)/$$name" && echo "from the budget curve: $$name"; done; done; true
	@# Jobs committed by an earlier session (records, or an unfinished job's last.ckpt) resume here.
	@for job in $(FIG9_TRAINED_KEEP)/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(FIG9_TRAINED_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(FIG9_TRAINED_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name fig9_trained hydra.sweep.dir=$(FIG9_TRAINED_DIR) \
		train.max_steps=$(BUDGET) $(ARGS)
	@$(MAKE) --no-print-directory fig9-trained-keep
	@# Every cell timed again together in this (now quiet) process: in-job timings ran beside another job.
	$(PY) -m gnsx.evaluation.report.retime $(FIG9_TRAINED_DIR)
	$(PY) -m gnsx.evaluation.report $(FIG9_TRAINED_DIR) --out docs/fig9 --wandb disabled
	@# The radius claim from the trained radius sweep once it has run (make radius-trained), else the 10k one.
	$(PY) -m gnsx.evaluation.report.claims --grid docs/fig9 --compare docs/fig9/steps_10k \
		--radius $$([ -f docs/radius/trained/results.csv ] && echo docs/radius/trained || echo docs/radius) \
		--versus $$([ -f docs/original-vs-simplified/trained/versus.json ] && echo docs/original-vs-simplified/trained || echo docs/original-vs-simplified) \
		--out docs/fig9
	$(PY) -m gnsx.evaluation.report.grid_motion $(FIG9_TRAINED_DIR) --data data/small_400 --out docs/fig9

fig9-trained-keep: ## Copy the trained grid's jobs to docs/fig9/jobs to commit: records of finished jobs, last.ckpt of unfinished ones
	@BUDGET_DIR=$(FIG9_TRAINED_DIR) KEEP=$(FIG9_TRAINED_KEEP) bash scripts/keep_jobs.sh

RADIUS_TRAINED_DIR ?= multirun/radius_trained/main
RADIUS_TRAINED_KEEP ?= docs/radius/trained/jobs
radius-trained: install ## The radius claim on trained models: 64/5 at radius 0.035 and 0.058 x seeds 0-1 at the budget curve's length beside the grid's 64/5 at the paper's 0.0467 (resumable), then docs/radius/trained
	@[ -n "$(BUDGET)" ] || { echo "the budget curve has not picked a budget yet (docs/fig9/budget/budget.json): make budget, or set BUDGET=<steps>"; exit 2; }
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@mkdir -p $(RADIUS_TRAINED_DIR)
	@# The paper's radius is the budget curve's 64/5 at this length, seeds 0 and 1: copied in, not trained again.
	@for seed in 0 1; do name=fig9_cell=64x5,model.radius=0.0467,seed=$$seed,train.max_steps=$(BUDGET); \
		for src in $(BUDGET_DIR) $(BUDGET_KEEP); do job="$$src/model.latent_size=64,model.mp_steps=5,seed=$$seed,train.max_steps=$(BUDGET)"; \
			[ ! -e "$(RADIUS_TRAINED_DIR)/$$name" ] && grep -qs '"status": "ok"' "$$job/results.json" && \
				cp -r "$$job" "$(RADIUS_TRAINED_DIR)/$$name" && echo "from the budget curve: $$name"; done; done; true
	@for job in $(RADIUS_TRAINED_KEEP)/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(RADIUS_TRAINED_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(RADIUS_TRAINED_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name radius_trained hydra.sweep.dir=$(RADIUS_TRAINED_DIR) \
		train.max_steps=$(BUDGET) $(ARGS)
	@BUDGET_DIR=$(RADIUS_TRAINED_DIR) KEEP=$(RADIUS_TRAINED_KEEP) bash scripts/keep_jobs.sh
	$(PY) -m gnsx.evaluation.report.retime $(RADIUS_TRAINED_DIR)
	$(PY) -m gnsx.evaluation.report $(RADIUS_TRAINED_DIR) --out docs/radius/trained --wandb disabled

VERSUS_TRAINED_DIR ?= multirun/versus_trained/main
VERSUS_TRAINED_KEEP ?= docs/original-vs-simplified/trained/jobs
versus-trained: install ## Original vs simplified, trained: the original GNS with the grid's recipe at the budget curve's length (hours of one thread; resumable across sessions) beside the grid's 64/5, then figures 6-8
	@[ -n "$(BUDGET)" ] || { echo "the budget curve has not picked a budget yet (docs/fig9/budget/budget.json): make budget, or set BUDGET=<steps>"; exit 2; }
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@mkdir -p $(VERSUS_TRAINED_DIR)
	@# The simplified partner is the budget curve's 64/5 at this length (seed 0): copied in, not trained again.
	@for src in $(BUDGET_DIR) $(BUDGET_KEEP); do job="$$src/model.latent_size=64,model.mp_steps=5,seed=0,train.max_steps=$(BUDGET)"; \
		name="$(VERSUS_TRAINED_DIR)/model=simplified,seed=0,train.max_steps=$(BUDGET)"; \
		[ ! -e "$$name" ] && grep -qs '"status": "ok"' "$$job/results.json" && cp -r "$$job" "$$name" \
			&& echo "the simplified partner: $$job"; done; true
	@for job in $(VERSUS_TRAINED_KEEP)/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(VERSUS_TRAINED_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(VERSUS_TRAINED_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name versus_trained hydra.sweep.dir=$(VERSUS_TRAINED_DIR) \
		train.max_steps=$(BUDGET) $(ARGS)
	@BUDGET_DIR=$(VERSUS_TRAINED_DIR) KEEP=$(VERSUS_TRAINED_KEEP) bash scripts/keep_jobs.sh
	$(PY) -m gnsx.evaluation.report.versus $(VERSUS_TRAINED_DIR) --data data/small_400 --out docs/original-vs-simplified/trained

LEARNING_DIR ?= multirun/learning/main
learning: install ## The learning study: 10 single arms + 1 combination x 2 seeds, 20 min of one thread each (~5 h on 2 cores; resumable), then docs/learning's table and curves
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@# Jobs finished in an earlier session and committed (docs/learning/jobs/: curves and records) are skipped.
	@mkdir -p $(LEARNING_DIR); for job in docs/learning/jobs/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(LEARNING_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(LEARNING_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name learning hydra.sweep.dir=$(LEARNING_DIR) $(ARGS)
	$(PY) -m gnsx.evaluation.report.learning $(LEARNING_DIR) --out docs/learning --copy-jobs docs/learning/jobs --budget-minutes 20

DEMO_CHOICE_DIR ?= multirun/demo_choice/main
demo-choice: install ## The demo's model: as shipped vs the learning study's winner at the demo's budget (12,200 steps), 2 seeds, one thread each (~55 min; resumable), then docs/learning/demo_choice
	@[ -f data/small/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small
	@mkdir -p $(DEMO_CHOICE_DIR); for job in docs/learning/demo_choice/jobs/*/; do [ -d "$$job" ] || continue; \
		[ -e "$(DEMO_CHOICE_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(DEMO_CHOICE_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name demo_choice hydra.sweep.dir=$(DEMO_CHOICE_DIR) $(ARGS)
	$(PY) -m gnsx.evaluation.report.learning $(DEMO_CHOICE_DIR) --arm-key demo_arm --out docs/learning/demo_choice \
		--copy-jobs docs/learning/demo_choice/jobs

LONG_DIR ?= outputs/learning_long
learning-long: install ## The learning study's winner trained long: ARM=<arm> (sweeps/learning_arm), 200k steps on one thread (~3.5 h; rerun to resume), scored on the test split beside the shipped weights
	@[ -n "$(ARM)" ] || { echo "set ARM=<arm of sweeps/learning_arm/>, e.g. make learning-long ARM=base"; exit 2; }
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 \
		--train 400 --valid 8 --test 16
	@# A run committed mid-way (docs/learning/long/<arm>/: its curve and checkpoints/last.ckpt) resumes here.
	@[ -e $(LONG_DIR)/$(ARM) ] || [ ! -f docs/learning/long/$(ARM)/checkpoints/last.ckpt ] || { mkdir -p $(LONG_DIR); \
		cp -r docs/learning/long/$(ARM) $(LONG_DIR)/$(ARM); echo "resuming from docs/learning/long/$(ARM)"; }
	$(PY) train.py --config-dir sweeps --config-name learning_long learning_arm=$(ARM) hydra.run.dir=$(LONG_DIR)/$(ARM) \
		$$([ -f $(LONG_DIR)/$(ARM)/checkpoints/last.ckpt ] && echo train.ckpt_path=$(LONG_DIR)/$(ARM)) $(ARGS)
	@$(MAKE) --no-print-directory learning-long-keep ARM=$(ARM)

learning-long-keep: install ## Copy a long run's curve, record and config (and, while unfinished, its last.ckpt) to docs/learning/long/ARM, to commit; then docs/learning/long_run.md
	@[ -n "$(ARM)" ] && [ -d $(LONG_DIR)/$(ARM) ] || { echo "no run at $(LONG_DIR)/$(ARM): set ARM=<arm>"; exit 2; }
	@dest=docs/learning/long/$(ARM); mkdir -p $$dest/.hydra $$dest/checkpoints; \
	for f in curve.jsonl results.json; do [ -f $(LONG_DIR)/$(ARM)/$$f ] && cp $(LONG_DIR)/$(ARM)/$$f $$dest/; done; \
	cp $(LONG_DIR)/$(ARM)/.hydra/*.yaml $$dest/.hydra/ 2>/dev/null; \
	if grep -qs '"status": "ok"' $(LONG_DIR)/$(ARM)/results.json; then rm -rf $$dest/checkpoints; \
	else cp $(LONG_DIR)/$(ARM)/checkpoints/last.ckpt $$dest/checkpoints/ && \
		echo "unfinished: commit with git add -f $$dest/checkpoints/last.ckpt"; fi; echo "kept in $$dest"
	$(PY) -m gnsx.evaluation.report.long_run docs/learning/long/*/ --out docs/learning

radius-mini: install ## Connection-radius sweep (5 radii x seeds 0-1, 64/5, fig9-mini's recipe; ~1 h 20 min on 2 cores; resumable), then the report
	@[ -f data/small/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small
	@# Radii finished in an earlier session and committed (docs/radius/jobs/) are not trained again, and
	@# figure 9's 64/5 seeds (same recipe, the preset's default radius 0.035) are the sweep's reference point.
	@mkdir -p $(RADIUS_MINI_DIR); for job in docs/radius/jobs/*/ docs/fig9/radius_0.035/jobs/model.latent_size=64,model.mp_steps=5*/; do \
		[ -d "$$job" ] || continue; \
		[ -e "$(RADIUS_MINI_DIR)/$$(basename "$$job")" ] || cp -r "$$job" "$(RADIUS_MINI_DIR)/"; done
	$(PY) train.py -m --config-dir sweeps --config-name radius_mini hydra.sweep.dir=$(RADIUS_MINI_DIR) $(ARGS)
	$(PY) train.py -m --config-dir sweeps --config-name radius_mini hydra.sweep.dir=$(RADIUS_MINI_DIR) seed=1 $(ARGS)
	$(PY) -m gnsx.evaluation.report.retime $(RADIUS_MINI_DIR)
	$(PY) -m gnsx.evaluation.report $(RADIUS_MINI_DIR)

EQUAL_BUDGET_DIR ?= multirun/equal_budget/main
equal-budget: install ## Simplified vs original GNS, 32 min of training each on 400 scenes, one after the other (~1 h 35 min; resumable), then figures 6-8
	@[ -f data/small_400/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out data/small_400 --train 400 --valid 8 --test 16
	$(PY) train.py -m --config-dir sweeps --config-name equal_budget hydra.sweep.dir=$(EQUAL_BUDGET_DIR) $(ARGS)
	$(PY) -m gnsx.evaluation.report.versus $(EQUAL_BUDGET_DIR) --data data/small_400 --out outputs/original-vs-simplified

fig9: install ## Full figure 9 (WaterRamps, paper schedule), e.g. ARGS='hydra/launcher=slurm hydra.launcher.partition=gpu'
	$(PY) train.py -m --config-dir sweeps --config-name fig9 hydra.sweep.dir=multirun/fig9/$(SWEEP_STAMP) $(ARGS)
	$(PY) -m gnsx.evaluation.report multirun/fig9/$(SWEEP_STAMP)

radius: install ## Full radius sweep (WaterRamps), same ARGS as fig9
	$(PY) train.py -m --config-dir sweeps --config-name radius hydra.sweep.dir=multirun/radius/$(SWEEP_STAMP) $(ARGS)
	$(PY) -m gnsx.evaluation.report multirun/radius/$(SWEEP_STAMP)

report: install ## Report of a sweep: make report SWEEP=multirun/<sweep>/<date_time> (default: the newest)
	@[ -n "$(SWEEP)" ] || { echo "no multirun directory: make report SWEEP=multirun/<sweep>/<date_time>"; exit 1; }
	$(PY) -m gnsx.evaluation.report $(SWEEP)

clean: ## Remove run outputs (outputs/, multirun/, wandb/); keeps data/ and .venv
	rm -rf outputs multirun wandb .pytest_cache

CKPT ?=
SCENE ?= scenes/dam_break.yaml
evaluate: install ## Evaluate checkpoint(s) on a split: make evaluate CKPT=<run dir|.ckpt> [ARGS='split=valid render.formats=[gif,mp4]']
	$(PY) evaluate.py checkpoint=$(CKPT) $(ARGS)

simulate: install ## Roll a model out on a scene: make simulate CKPT=<run dir|.ckpt> SCENE=scenes/two_blocks.yaml [ARGS=mpm=true]
	$(PY) simulate.py checkpoint=$(CKPT) scene=$(SCENE) $(ARGS)

sensitivity: install ## The ground truth's own predictability: MPM reruns of the test split from starts moved by 1e-6..1e-3 m, scored like a model (~3 min)
	test -d $(DATA) || $(MAKE) data
	$(PY) -m gnsx.evaluation.sensitivity --data $(DATA) --split test --deltas 0 1e-6 1e-5 1e-4 1e-3 --out outputs/sensitivity $(ARGS)

hardcases: install ## Hard-case suite (jets, collisions, pool at rest, 10x scenes, 10x horizon): MPM vs raw vs held model
	$(PY) -m gnsx.evaluation.hardcases --checkpoint $(or $(CKPT),pretrained/small) --out outputs/hardcases/$(SWEEP_STAMP) $(ARGS)

bench: install ## Scaling benchmark: ms/frame, memory, GFLOP/s vs particles (1k-100k), simplified / simplified_pairwise / original, inference + training; JSON + plot in outputs/bench (ARGS='--threads 2', '--device cuda', '--particles 2300': one size)
	$(PY) -m gnsx.perf.benchmark $(ARGS)

bench-bound: install ## The frame against the naive-FLOP bound: fused and eager CPU kernels interleaved in one process (docs/speed.md; ARGS='--models simplified original --threads 2')
	$(PY) -m gnsx.perf.bound $(ARGS)

bench-cull: install ## ms/frame with and without exact culling, 5 scenes at WaterRamps size and 10x (ARGS='--threads 2 --models simplified original')
	$(PY) -m gnsx.perf.benchmark --cull $(ARGS)

# The perceptual study (issue 14, the paper's figure 10): docs/study.md.
STUDY ?= day-one
STUDY_DIR ?= studies/$(STUDY)
STUDY_TRAJECTORIES ?= 8
# The default study is the paper's three methods: MPM, the original and the simplified GNS trained for the same
# 32 minutes of training time (`make equal-budget`, docs/original-vs-simplified/), shipped in
# pretrained/equal_budget/. Without them (or with STUDY_ORIGINAL= emptied): MPM vs the shipped simplified weights.
EQUAL_BUDGET_SHIPPED := $(wildcard pretrained/equal_budget/original/model.ckpt)
STUDY_ORIGINAL ?= $(EQUAL_BUDGET_SHIPPED)
STUDY_SIMPLIFIED ?= $(if $(EQUAL_BUDGET_SHIPPED),pretrained/equal_budget/simplified/model.ckpt,pretrained/small/model.ckpt)
STUDY_BUDGET ?= $(if $(EQUAL_BUDGET_SHIPPED),equal 32-minute CPU budget,)
STUDY_COMMA := ,
STUDY_CKPTS = $(if $(STUDY_ORIGINAL),[$(STUDY_ORIGINAL)$(STUDY_COMMA)$(STUDY_SIMPLIFIED)],$(STUDY_SIMPLIFIED))
# Method names carry the budget the models were trained with (shown in the analysis, never to participants).
STUDY_LABELS = $(if $(and $(STUDY_ORIGINAL),$(STUDY_BUDGET)),'labels=["original GNS 128/10$(STUDY_COMMA) $(STUDY_BUDGET)"$(STUDY_COMMA)"simplified GNS 64/5$(STUDY_COMMA) $(STUDY_BUDGET)"]',)
STUDY_NAME = $(if $(and $(STUDY_ORIGINAL),$(STUDY_BUDGET)),--name '$(STUDY) ($(STUDY_BUDGET))',)
study: install ## Build the perceptual study: MPM vs original vs simplified GNS (equal 32-minute CPU budget) into studies/<STUDY>
	@[ ! -f $(STUDY_DIR)/answers.sqlite ] || { echo "$(STUDY_DIR) already has answers: choose another STUDY=<name>"; exit 2; }
	@[ -f $(DATA)/metadata.json ] || $(PY) -m gnsx.data generate --preset small --out $(DATA)
	$(PY) evaluate.py 'checkpoint=$(STUDY_CKPTS)' $(STUDY_LABELS) data.root=$(DATA) max_trajectories=$(STUDY_TRAJECTORIES) \
		threads=1 metrics.emd_every=0 metrics.timing_repeats=0 render.enabled=false logger=none hydra.run.dir=$(STUDY_DIR)/rollouts
	$(PY) -m gnsx.study build --rollouts $(STUDY_DIR)/rollouts --out $(STUDY_DIR) --pairs-per-group $(STUDY_TRAJECTORIES) $(STUDY_NAME) $(ARGS)

study-serve: install ## Run studies/<STUDY> in the browser at localhost:8000 (ARGS='--host 0.0.0.0': your local network)
	$(PY) -m gnsx.study serve $(STUDY_DIR) $(ARGS)

install-browser: ## Debian's chromium + chromedriver for the study's browser test (apt; nothing if installed)
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then \
		echo "chromium and chromedriver are installed"; \
	else \
		sudo=$$([ "$$(id -u)" = 0 ] || echo sudo); \
		$$sudo apt-get update -qq && \
		$$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; \
	fi
