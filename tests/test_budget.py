"""The budget curve (sweeps/budget.yaml, gnsx.evaluation.report.budget): the sweep trains the grid's 64/5 recipe
at several lengths, and the rule that picks the grid's budget says each of its verdicts; the keep script
commits finished records and unfinished checkpoints; every record names its CPU."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from test_sweeps import _compose_sweep

from gnsx.core.machine import cpu_name
from gnsx.evaluation.report.budget import by_length, decide, main, pooled_errors, ratio_to
from gnsx.evaluation.report.jobs import load_sweep

ROOT = Path(__file__).resolve().parents[1]


def test_the_budget_sweep_is_the_grids_64_5_at_several_lengths():
    budget, grid = _compose_sweep("budget"), _compose_sweep("fig9_mini")
    params = {k: str(v).split(",") for k, v in budget.hydra.sweeper.params.items()}
    assert params["model.latent_size"] == ["64"] and params["model.mp_steps"] == ["5"]
    assert sorted(int(s) for s in params["train.max_steps"]) == [25_000, 50_000, 100_000, 200_000]
    assert sorted(params["seed"]) == ["0", "1"]
    assert params["train.max_steps"][0] == "200000"  # the critical path starts first
    # The recipe is the grid's: the same training settings, so the 64/5 jobs are the grid's cells.
    for key in ("lr_init", "lr_final", "noise_std", "noise_decay", "mirror", "loss", "unroll_steps"):
        assert budget.train[key] == grid.train[key], key
    assert budget.data.root == grid.data.root and budget.model.radius_scale == grid.model.radius_scale
    steps = 50_000
    cfg = _compose_sweep("budget", [f"train.max_steps={steps}"])
    assert (cfg.train.lr_decay_start, cfg.train.lr_decay_end) == (31_250, 46_875)
    assert cfg.train.curve_every_n_steps == steps // 10 and cfg.train.val_max_trajectories == 8
    # fp32 whatever the machine: a run resumed on another CPU kind keeps its numerics.
    assert budget.trainer.precision == "32-true"
    assert budget.evaluate.pretrained == "pretrained/small/model.ckpt"


def _job(root: Path, steps: int, seed: int, errors, baseline=None, status: str = "ok") -> Path:
    folder = root / f"model.latent_size=64,model.mp_steps=5,seed={seed},train.max_steps={steps}"
    (folder / ".hydra").mkdir(parents=True)
    OmegaConf.save(OmegaConf.create({"seed": seed, "train": {"max_steps": steps},
                                     "model": {"latent_size": 64, "mp_steps": 5}}),
                   folder / ".hydra" / "config.yaml")  # fmt: skip
    baseline = baseline if baseline is not None else [0.05] * len(errors)
    rows = [{"trajectory": t, "rollout_mse": float(e), "baseline_mse": float(b), "area_ratio_final": 0.9}
            for t, (e, b) in enumerate(zip(errors, baseline))]  # fmt: skip
    results = {"status": status, "error": None, "rows": rows, "test": {"rollout_mse": float(np.mean(errors))},
               "model_config": {"latent_size": 64, "mp_steps": 5, "radius": 0.0467}, "training_s": steps / 11.0,
               "steps_per_s": 11.0, "train_wall_s": steps / 11.0, "cpu": "test CPU"}  # fmt: skip
    (folder / "results.json").write_text(json.dumps(results))
    return folder


def _errors(level: float, n: int = 16, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return level * np.exp(rng.normal(0.0, 0.3, size=n))


def test_seeds_are_pooled_within_a_trajectory_by_their_geometric_mean(tmp_path):
    _job(tmp_path, 50_000, 0, [0.01, 0.04])
    _job(tmp_path, 50_000, 1, [0.04, 0.01])
    _job(tmp_path, 200_000, 0, [0.02, 0.02])
    _job(tmp_path, 200_000, 1, [0.02, 0.02])
    groups = by_length(load_sweep(tmp_path))
    assert pooled_errors(groups[50_000]) == pytest.approx({0: 0.02, 1: 0.02})
    result = ratio_to(groups[50_000], groups[200_000])
    assert result["ratio"] == pytest.approx(1.0) and result["trajectories"] == 2  # 2 trajectories, not 4


@pytest.mark.parametrize(
    ("levels", "budget"),
    [
        ({25_000: 0.019, 50_000: 0.012, 100_000: 0.0105}, 50_000),  # 50k within 1.3x; 25k is below the floor
        ({25_000: 0.05, 50_000: 0.02, 100_000: 0.0125}, 100_000),  # 50k at 2x: not within; 100k is
        ({25_000: 0.05, 50_000: 0.04, 100_000: 0.03}, 100_000),  # none within: the fallback, 100k
    ],
)
def test_the_rule_picks_the_shortest_length_within_1_3x_of_the_200k_runs(tmp_path, levels, budget):
    for seed in (0, 1):
        _job(tmp_path, 200_000, seed, _errors(0.01, seed=seed))
        for steps, level in levels.items():
            _job(tmp_path, steps, seed, _errors(level, seed=seed))  # the same spread: ratios are exact
    decision = decide(by_length(load_sweep(tmp_path)))
    assert decision["budget"] == budget
    assert decision.get("fallback", False) == (budget == 100_000 and levels[100_000] / 0.01 > 1.3)


def test_the_rule_waits_for_the_reference_and_for_shorter_lengths(tmp_path):
    _job(tmp_path, 200_000, 0, _errors(0.01))
    _job(tmp_path, 100_000, 0, _errors(0.01))
    _job(tmp_path, 100_000, 1, _errors(0.01, seed=1))
    decision = decide(by_length(load_sweep(tmp_path)))
    assert decision["budget"] is None and "reference" in decision["why"]
    _job(tmp_path, 200_000, 1, _errors(0.01, seed=1))
    _job(tmp_path, 50_000, 0, _errors(0.01))  # one seed of 50k: 100k cannot be picked before 50k is read
    decision = decide(by_length(load_sweep(tmp_path)))
    assert decision["budget"] is None and "50,000" in decision["why"]


def test_the_report_writes_its_table_verdict_and_picture(tmp_path):
    sweep = tmp_path / "sweep"
    for seed in (0, 1):
        _job(sweep, 200_000, seed, _errors(0.01, seed=seed))
        _job(sweep, 50_000, seed, _errors(0.011, seed=seed))
    running = _job(sweep, 100_000, 0, _errors(0.01), status="running")
    assert running.is_dir()
    out = tmp_path / "out"
    assert main([str(sweep), "--out", str(out)]) == 0
    text = (out / "budget.md").read_text()
    assert "**The grid's budget: 50,000 steps**" in text
    assert "test CPU" in text and "Not finished" in text
    assert "seed 1 scores" in text  # the 200k seeds against each other
    assert json.loads((out / "budget.json").read_text())["decision"]["budget"] == 50_000
    assert (out / "budget.png").stat().st_size > 0


def test_keep_jobs_commits_records_and_unfinished_checkpoints(tmp_path):
    sweep, keep = tmp_path / "sweep", tmp_path / "keep"
    done = _job(sweep, 50_000, 0, [0.01])
    (done / "checkpoints").mkdir()
    state = {"state_dict": {"w": torch.ones(3)}, "hyper_parameters": {"model": {}}, "global_step": 50_000,
             "optimizer_states": [{"exp_avg": torch.ones(3)}]}  # fmt: skip
    torch.save(state, done / "checkpoints" / "last.ckpt")
    (done / "curve.jsonl").write_text("{}\n")
    unfinished = _job(sweep, 100_000, 0, [0.01], status="running")
    (unfinished / "checkpoints").mkdir()
    (unfinished / "checkpoints" / "last.ckpt").write_bytes(b"weights")
    env = {**os.environ, "BUDGET_DIR": str(sweep), "KEEP": str(keep), "PY": sys.executable}
    out = subprocess.run(["bash", str(ROOT / "scripts" / "keep_jobs.sh")], env=env, capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    assert (keep / done.name / "results.json").is_file() and (keep / done.name / "curve.jsonl").is_file()
    assert not (keep / done.name / "checkpoints").exists()  # a finished job is skipped on resume
    weights = torch.load(
        keep / done.name / "model.ckpt", weights_only=True
    )  # its final weights, no optimizer
    assert "optimizer_states" not in weights and weights["global_step"] == 50_000
    assert (keep / unfinished.name / "checkpoints" / "last.ckpt").read_bytes() == b"weights"
    assert "unfinished" in out and (unfinished / "checkpoints" / "last.ckpt").is_file()  # nothing moved


def test_the_cpu_is_named_with_its_generation_and_matrix_extensions(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    first = "processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Processor\ncpu family\t: 6\nmodel\t\t: 207\n"
    cpuinfo.write_text(
        first + "flags\t\t: fpu avx2 avx512f avx512_bf16\n\nprocessor\t: 1\nmodel name\t: ignored\n"
    )
    name = cpu_name(cpuinfo)
    assert name.startswith("Intel(R) Xeon(R) Processor (family 6 model 207; avx512_bf16;")
    assert "avx2" not in name and "ignored" not in name
    assert cpu_name(tmp_path / "missing")  # unreadable: still a name


def test_the_trained_grid_is_every_cell_and_the_seeds_at_the_budget_in_the_claims_order():
    cfg = _compose_sweep("fig9_trained", ["train.max_steps=50000"])
    jobs = str(cfg.hydra.sweeper.params["fig9_cell"]).split(",")
    assert list(cfg.hydra.sweeper.params) == ["fig9_cell"]  # fig9_mini's latent x MP grid is cleared
    assert jobs[:5] == ["64x5", "16x5", "128x5", "64x1", "64x10"] and len(set(jobs)) == len(jobs) == 24
    cells, seeds = set(), []
    for job in jobs:
        option = OmegaConf.load(ROOT / "sweeps" / "fig9_cell" / f"{job}.yaml")
        cell = (option.model.latent_size, option.model.mp_steps)
        cells.add(cell)
        assert job.split("_")[0] == f"{cell[0]}x{cell[1]}"
        if "seed" in option:
            seeds.append((cell, option.seed))
    assert cells == {(w, m) for w in (16, 32, 64, 128) for m in (1, 3, 5, 10)}
    assert sorted(seeds) == sorted((c, s) for c in [(16, 1), (32, 10), (64, 5), (128, 3)] for s in (1, 2))
    # The recipe of the budget curve, so that its 64/5 jobs are the grid's.
    budget = _compose_sweep("budget", ["train.max_steps=50000"])
    for key in ("max_steps", "lr_init", "lr_final", "lr_decay_start", "lr_decay_end", "noise_std", "mirror"):
        assert cfg.train[key] == budget.train[key], key
    assert cfg.trainer.precision == budget.trainer.precision == "32-true"
    assert cfg.model.mlp_hidden_size == cfg.model.latent_size
    # The budget is never a silent default: without it the config check stops every job at once.
    from gnsx.core.errors import ConfigError
    from gnsx.training.config_checks import check_train_config

    unset = _compose_sweep("fig9_trained")
    assert unset.train.max_steps is None
    with pytest.raises(ConfigError, match="train.max_steps"):
        check_train_config(unset)


def test_the_trained_comparison_is_the_original_with_the_grids_recipe_at_the_budget():
    cfg = _compose_sweep("versus_trained", ["train.max_steps=50000"])
    grid = _compose_sweep("fig9_trained", ["train.max_steps=50000"])
    assert cfg.model.name == "original" and (cfg.model.latent_size, cfg.model.mp_steps) == (128, 10)
    assert (
        cfg.model.mlp_hidden_layers == 2 and cfg.model.history == 5 and cfg.model.type_encoding == "embedding"
    )
    assert cfg.model.radius_scale == 1.0 and cfg.model.noise_std == 6.7e-4  # its own radius and noise
    assert cfg.train.noise_std is None and cfg.train.noise_decay is None
    for key in ("max_steps", "lr_init", "lr_final", "lr_decay_start", "lr_decay_end", "mirror"):
        assert cfg.train[key] == grid.train[key], key
    assert cfg.trainer.precision == grid.trainer.precision and cfg.data.root == grid.data.root
    assert cfg.train.curve_every_n_steps == 5_000 and cfg.train.val_max_trajectories == 8  # figure 7's curve
    assert dict(cfg.hydra.sweeper.params) == {"model": "original", "seed": "0"}


def test_the_trained_radius_sweep_is_the_grids_64_5_at_two_more_radii():
    cfg = _compose_sweep("radius_trained", ["train.max_steps=50000"])
    grid = _compose_sweep("fig9_trained", ["train.max_steps=50000"])
    params = {k: str(v).split(",") for k, v in cfg.hydra.sweeper.params.items()}
    assert params == {"fig9_cell": ["64x5"], "model.radius": ["0.058", "0.035"], "seed": ["0", "1"]}
    for key in ("max_steps", "lr_init", "lr_final", "lr_decay_start", "lr_decay_end", "noise_std", "mirror"):
        assert cfg.train[key] == grid.train[key], key
    assert cfg.trainer.precision == "32-true" and cfg.sweep.name == "radius_trained"
    assert (cfg.model.latent_size, cfg.model.mp_steps) == (64, 5)
