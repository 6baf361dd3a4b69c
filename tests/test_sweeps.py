"""Sweeps: the sweep configs compose, a Hydra multirun trains/evaluates/measures every job, a failing job is
recorded and does not stop the others, and the report is built from the multirun directory."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import imageio.v3 as iio
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from gnsx.evaluation.report import build_report, load_sweep
from gnsx.training.job import as_divergence, one_line
from gnsx.training.numerics import Diverged
from gnsx.training.time_budget import TrainingClock

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "sweeps"
CONF = ROOT / "conf"
HAS_BENCHMARK = importlib.util.find_spec("gnsx.perf.benchmark") is not None


def _compose_sweep(name: str, overrides: list[str] | None = None):
    # The same search path as `train.py --config-dir sweeps`: the sweep files first, then conf/.
    with initialize_config_dir(config_dir=str(SWEEPS), version_base="1.3"):
        return compose(
            config_name=name,
            overrides=[f"hydra.searchpath=[file://{CONF}]", *(overrides or [])],
            return_hydra_config=True,
        )


def _grid(cfg) -> dict[str, list[str]]:
    return {k: str(v).split(",") for k, v in cfg.hydra.sweeper.params.items()}


def test_fig9_sweeps_are_the_papers_grid():
    for name in ("fig9", "fig9_mini"):
        cfg = _compose_sweep(name)
        grid = _grid(cfg)
        assert sorted(grid["model.latent_size"], key=int) == ["16", "32", "64", "128"]
        assert sorted(grid["model.mp_steps"], key=int) == ["1", "3", "5", "10"]
        assert cfg.sweep.name == name and cfg.logger.group == name
        # "Embedding size" sizes the MLPs too; the rest is the simplified GNS.
        assert cfg.model.mlp_hidden_size == cfg.model.latent_size
        assert cfg.model.history == 1 and cfg.model.type_encoding == "scalar"
    full, mini = _compose_sweep("fig9"), _compose_sweep("fig9_mini")
    assert full.data.preset == "waterramps" and full.train.max_steps == 1_600_000
    assert mini.data.preset == "small" and mini.trainer.accelerator == "cpu" and mini.train.max_time is None
    # The same recipe for every cell, on every test trajectory, resumable cell by cell (issue: figure 9 for real).
    assert mini.train.max_steps == 10_000 and mini.evaluate.max_trajectories is None and mini.sweep.resume
    raw = OmegaConf.to_container(OmegaConf.load(SWEEPS / "fig9_mini.yaml").hydra, resolve=False)
    assert raw["sweep"]["subdir"] == "${hydra.job.override_dirname}"
    assert "data.root" in raw["job"]["config"]["override_dirname"]["exclude_keys"]
    # Parallel jobs must not oversubscribe a 2-core machine.
    assert "Joblib" in mini.hydra.launcher._target_
    assert mini.hydra.launcher.n_jobs * mini.sweep.torch_threads <= 2


def test_fig9_mini_trains_at_the_papers_radius_with_the_papers_recipe_compressed():
    """Figure 9 as the paper ran it: the simplified model's radius (0.020/0.015 x the data's default, not a
    fixed number), its noise decayed with the LR, no mirror, lr 1e-4 held to 62.5% of the run and decayed to
    1e-6 by 93.75% (1.0M and 1.5M of its 1.6M steps)."""
    mini = _compose_sweep("fig9_mini")
    assert mini.model.radius is None and mini.model.radius_scale == pytest.approx(0.020 / 0.015, rel=1e-4)
    assert mini.train.noise_std is None and mini.train.noise_decay is None and not mini.train.mirror
    assert (mini.model.noise_std, mini.model.noise_decay) == (3e-4, 0.4)
    steps = mini.train.max_steps
    assert (mini.train.lr_init, mini.train.lr_final) == (1e-4, 1e-6)
    assert (mini.train.lr_decay_start / steps, mini.train.lr_decay_end / steps) == (0.625, 0.9375)
    assert mini.data.root.endswith("small_400")


def test_radius_sweeps_scale_waterramps_radii_to_the_small_preset():
    full, mini = _compose_sweep("radius"), _compose_sweep("radius_mini")
    full_radii = [float(r) for r in _grid(full)["model.radius"]]
    mini_radii = [float(r) for r in _grid(mini)["model.radius"]]
    assert 0.014 in full_radii and 0.020 in full_radii  # the paper's discussion
    # The same radius / default-radius ratios (0.035 on the small preset, 0.015 on WaterRamps).
    assert len(mini_radii) == len(full_radii)
    for small, large in zip(mini_radii, full_radii):
        assert small == pytest.approx(large * 0.035 / 0.015, rel=0.02)
    for cfg in (full, mini):
        grid = _grid(cfg)
        assert grid["model.latent_size"] == ["64"] and grid["model.mp_steps"] == ["5"]


def test_launcher_configs_compose():
    targets = {
        "sequential": "BasicLauncher",
        "parallel": "JoblibLauncher",
        "slurm": "SlurmLauncher",
        "slurm_local": "LocalLauncher",
    }
    for name, target in targets.items():
        cfg = _compose_sweep("fig9_mini", [f"hydra/launcher={name}"])
        assert cfg.hydra.launcher._target_.endswith(target)
    assert _compose_sweep("fig9", ["hydra/launcher=slurm"]).hydra.launcher.gpus_per_node == 1


def test_non_finite_positions_count_as_divergence_and_reasons_are_one_line():
    error = as_divergence(ValueError("data must be finite, check for nan or inf values"))
    assert isinstance(error, Diverged) and one_line(error).startswith("diverged: positions became NaN/Inf")
    other = ValueError("something else")
    assert as_divergence(other) is other
    assert one_line(RuntimeError("first line\nsecond line")) == "RuntimeError: first line"
    assert len(one_line(RuntimeError("x" * 1000))) == 300


def test_training_clock_leaves_validation_out(monkeypatch):
    now = [100.0]
    monkeypatch.setattr("gnsx.training.time_budget.time.perf_counter", lambda: now[0])
    clock = TrainingClock()
    assert clock.summary() == {"train_wall_s": None, "train_steps": 0, "steps_per_s": None}
    trainer = SimpleNamespace(global_step=10)  # a resumed run: its own steps only
    clock.on_train_start(trainer, None)
    for _ in range(20):
        now[0] += 0.5
        trainer.global_step += 1
        clock.on_train_batch_end(trainer, None, None, None, 0)
    clock.on_validation_start(trainer, None)
    now[0] += 5.0
    clock.on_validation_end(trainer, None)
    clock.on_train_end(trainer, None)
    summary = clock.summary()
    assert summary["train_steps"] == 20
    assert summary["train_wall_s"] == pytest.approx(15.0)
    assert summary["steps_per_s"] == pytest.approx(2.0)


def _multirun(tmp_path: Path, dataset: Path, sweep_dir: Path, extra: list[str], timeout: int = 300):
    cmd = [
        sys.executable, str(ROOT / "train.py"), "-m",
        "--config-dir", str(SWEEPS), "--config-name", "fig9_mini",
        f"hydra.sweep.dir={sweep_dir}", f"data.root={dataset}", "data.generate_if_missing=false",
        "train.max_steps=3", "sweep.frame=20", "sweep.bench.num_particles=300", "sweep.bench.repeats=2",
        *extra,
    ]  # fmt: skip
    env = {**os.environ, "WANDB_MODE": "offline", "MPLBACKEND": "Agg"}
    return subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=timeout, env=env)


#: Makes exactly one cell of the grid (latent 8, 1 MP step) fail on bad input: its history resolves to -1
#: (refused by the config checks before training), every other cell's to 1. It is the first job, so the test
#: also shows that the jobs after a failure still run.
FAIL_FIRST_CELL = [
    "+fail_8_1=-1",
    "model.history='${oc.select:fail_${model.latent_size}_${model.mp_steps},1}'",
]


def _results(sweep_dir: Path) -> dict[str, dict]:
    out = {}
    for path in sorted(sweep_dir.glob("*/results.json")):
        results = json.loads(path.read_text())
        out[results["name"]] = results
    return out


def test_grid_multirun_records_every_job_and_the_report_shows_them(tmp_path, tiny_dataset):
    sweep_dir = tmp_path / "multirun"
    done = _multirun(
        tmp_path, tiny_dataset, sweep_dir,
        ["hydra/launcher=sequential", "model.latent_size=8,16", "model.mp_steps=1,2", *FAIL_FIRST_CELL],
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = _results(sweep_dir)
    names = [f"model.latent_size={latent},model.mp_steps={mp}" for latent in (8, 16) for mp in (1, 2)]
    assert sorted(results) == sorted(names)

    failed = results[names[0]]
    assert failed["status"] == "failed" and failed["job"] == 0
    assert failed["error"] == "ConfigError: model.history=-1: must be >= 1"  # refused before training
    assert failed["test"]["rollout_mse"] is None
    for name in names[1:]:
        job = results[name]
        assert job["status"] == "ok" and job["error"] is None, job["error"]
        assert job["sweep"] == "fig9_mini"
        latent, mp = (int(part.split("=")[1]) for part in name.split(","))
        assert (job["model_config"]["latent_size"], job["model_config"]["mp_steps"]) == (latent, mp)
        assert job["model_config"]["mlp_hidden_size"] == latent
        # The simplified model's radius: model.radius_scale (0.020/0.015) x the tiny data's default 0.035.
        assert job["model_config"]["radius"] == pytest.approx(1.3333 * 0.035)
        assert job["train_steps"] == 3 and job["steps_per_s"] > 0 and job["train_wall_s"] > 0
        assert job["parameters"] > 0 and job["job_wall_s"] >= job["train_wall_s"]
        assert math.isfinite(job["test"]["rollout_mse"]) and job["test"]["rollout_mse"] > 0
        assert job["test"]["ms_per_frame"] > 0
        assert set(job["test"]) >= {"rollout_mse", "onestep_mse", "emd", "baseline_mse", "peak_memory_mb"}
        assert iio.imread(job["frame_png"]).shape == (256, 256, 3) and job["frame"] == 20
        if HAS_BENCHMARK:
            assert job["bench"]["ms_per_frame"] > 0 and job["bench"]["num_particles"] >= 250
        else:
            assert "gnsx.perf.benchmark" in job["bench"]["error"]
    # One wandb run per job, the failed one included.
    job_dirs = sorted(sweep_dir.glob("*model.latent_size=*"))
    assert len(job_dirs) == 4  # one folder per cell, named by its overrides (resumable)
    for job_dir in job_dirs:
        assert len(list((job_dir / "wandb").glob("offline-run-*/*.wandb"))) == 1

    # Resumable: a rerun skips the finished cells untouched; a cell killed after its checkpoint resumes there.
    finished = {name: (sweep_dir / results[name]["run_dir"]).resolve() / "results.json" for name in names[1:]}
    before = {name: path.read_text() for name, path in finished.items()}
    killed = finished[names[-1]]
    killed.unlink()
    again = _multirun(
        tmp_path, tiny_dataset, sweep_dir,
        ["hydra/launcher=sequential", "model.latent_size=8,16", "model.mp_steps=1,2", *FAIL_FIRST_CELL],
    )  # fmt: skip
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    log = again.stdout + again.stderr
    assert (
        log.count("skipped (sweep.resume)") == 2 and log.count("resuming from its checkpoints/last.ckpt") == 1
    )
    for name in names[1:-1]:
        assert finished[name].read_text() == before[name]
    assert json.loads(killed.read_text())["status"] == "ok"

    outputs = build_report(sweep_dir)
    grid = iio.imread(outputs["grid"])
    scatter = iio.imread(outputs["speed_vs_error"])
    assert grid.ndim == 3 and grid.shape[1] > grid.shape[0]  # 2 rows x (2 models + ground truth) columns
    assert scatter.ndim == 3
    markdown = outputs["markdown"].read_text()
    for name in names:
        assert name in markdown
    assert "model.history=-1: must be >= 1" in markdown and "## Failed jobs" in markdown
    assert markdown.count("| ok |") == 3 and markdown.count("| failed |") == 1
    assert list(outputs["wandb"].glob("*.wandb"))
    assert [job.status for job in load_sweep(sweep_dir)] == ["failed", "ok", "ok", "ok"]


def test_single_run_failure_is_recorded_then_raised(tmp_path, tiny_dataset):
    """A run that diverges (an absurd learning rate: every step after the first has a NaN loss) is recorded
    as failed in results.json and ends with one line and exit status 1 (bad input exits 2 before writing
    anything: tests/test_bad_input.py)."""
    run_dir = tmp_path / "single"
    cmd = [
        sys.executable, str(ROOT / "train.py"), f"hydra.run.dir={run_dir}", f"data.root={tiny_dataset}",
        "data.generate_if_missing=false", "logger=none", "model.latent_size=8", "model.mlp_hidden_size=8",
        "model.mp_steps=1", "train.lr_init=1e30", "train.lr_final=1e30", "train.max_skipped_steps=2",
        "train.max_steps=20", "train.max_time=null", "evaluate.enabled=false",
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr[-3000:]
    assert done.stderr.strip().splitlines()[-1].startswith("error: diverged: 3 steps in a row")
    assert "Traceback" not in done.stderr
    results = json.loads((run_dir / "results.json").read_text())
    assert results["status"] == "failed" and results["error"].startswith("diverged: 3 steps in a row")
    assert results["multirun"] is False and results["job"] is None
    assert results["skipped_steps"] == 3 and results["global_step"] < 20


def _failing_and_working_job(tmp_path: Path, dataset: Path, launcher: str) -> Path:
    sweep_dir = tmp_path / launcher
    done = _multirun(
        tmp_path, dataset, sweep_dir,
        [f"hydra/launcher={launcher}", "model.latent_size=-1,8", "model.mp_steps=1", "logger=csv"],
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = _results(sweep_dir)
    error = results["model.latent_size=-1,model.mp_steps=1"]["error"]
    assert error == "ConfigError: model.latent_size=-1: must be >= 1"  # bad input, refused before training
    assert results["model.latent_size=8,model.mp_steps=1"]["status"] == "ok"
    report = build_report(sweep_dir, wandb_mode="disabled")
    assert "model.latent_size=-1: must be >= 1" in report["markdown"].read_text()
    return sweep_dir


@pytest.mark.slow  # end-to-end (~10-25 s): `make test-slow`; keeps `make test` under 5 min
def test_submitit_local_launcher(tmp_path, tiny_dataset):
    """The Slurm launch path (pickled jobs, one subprocess each) through submitit's local executor."""
    sweep_dir = _failing_and_working_job(tmp_path, tiny_dataset, "slurm_local")
    assert list((sweep_dir / ".submitit").glob("*/*_result.pkl"))


@pytest.mark.slow
def test_joblib_launcher(tmp_path, tiny_dataset):
    """The parallel launcher of the mini sweeps (2 loky workers, 1 torch thread each)."""
    _failing_and_working_job(tmp_path, tiny_dataset, "parallel")


def test_benchmark_at_waterramps_size_grows_a_small_domain():
    from gnsx.data.metadata import Metadata
    from gnsx.model.simulator import LearnedSimulator
    from gnsx.training.sweep_extras import benchmark_at_scale

    meta = Metadata(bounds=[[0.1, 0.9], [0.1, 0.9]], sequence_length=10, default_connectivity_radius=0.035,
                    dim=2, dt=0.0025, vel_mean=[0.0, 0.0], vel_std=[2e-3, 2e-3], acc_mean=[0.0, 0.0],
                    acc_std=[1e-4, 1e-4])  # fmt: skip
    facts = {k: getattr(meta, k) for k in ("dim", "bounds", "vel_mean", "vel_std", "acc_mean", "acc_std")}
    simulator = LearnedSimulator(**facts, radius=0.035, latent_size=8, mp_steps=1, mlp_hidden_size=8)
    # 2,300 particles at the small preset's spacing (0.0156) do not fit in [0.1, 0.9]^2: the domain grows.
    result = benchmark_at_scale(simulator, meta, 0.015625, 2300, torch.device("cpu"), warmup=1, repeats=1)
    assert result["num_particles"] == 2300 and result["domain_scale"] > 1
    assert result["ms_per_frame"] > 0 and result["spacing"] == 0.015625
    # Each particle keeps its training neighbourhood: ~pi (R / spacing)^2 neighbours inside the block.
    assert 8 < result["num_edges"] / 2300 < 16
