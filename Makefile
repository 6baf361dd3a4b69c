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
.PHONY: help install demo train test test-slow lint format data data-waterramps pretrain evaluate fig9-mini radius-mini report bench clean

help: ## Show this help
	@grep -E '^[a-zA-Z0-9_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}'

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q "$(TORCH_SPEC)"
	$(PIP) install -q -e '.[dev]'
	touch $@

install: $(VENV)/.installed ## Create .venv and install gnsx with its dependencies (torch pinned first)

demo: install ## Main job: generate the small preset, train the simplified GNS, evaluate, render (<= 15 min on CPU)
	$(PY) train.py

train: install ## Train with Hydra overrides, e.g. make train ARGS='model=original trainer.max_steps=2000'
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

data-waterramps: install ## Generate the full WaterRamps-like preset (1000/100/100 x 601 frames; hours)
	$(PY) -m gnsx.data generate --preset waterramps --out data/waterramps

PRETRAIN_DIR := outputs/pretrain/small
pretrain: install ## Train the shipped weights (train=pretrain, 100k steps, hours on CPU; rerun to resume), then ship them
	$(PY) train.py train=pretrain hydra.run.dir=$(PRETRAIN_DIR) evaluate.render=false \
		$$([ -f $(PRETRAIN_DIR)/checkpoints/last.ckpt ] && echo train.ckpt_path=$(PRETRAIN_DIR))
	$(PY) -m gnsx.pretrained $(PRETRAIN_DIR) pretrained/small

clean: ## Remove generated data and run outputs (keeps .venv)
	rm -rf outputs multirun wandb .pytest_cache
