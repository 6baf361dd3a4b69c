"""Hydra configs compose, the Lightning system trains, checkpoints, resumes and evaluates."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from gnsx.data.metadata import Metadata
from gnsx.training.builders import build_system, samples_before
from gnsx.training.model_settings import architecture
from gnsx.training.precision import resolve_precision
from gnsx.training.system import GNSSystem

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"

#: A model small enough that a few training steps take a fraction of a second.
TINY = ["model.latent_size=8", "model.mlp_hidden_size=8", "model.mp_steps=2"]


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


class _FakeDataModule:
    metadata = Metadata(
        bounds=[[0.1, 0.9], [0.1, 0.9]],
        sequence_length=10,
        default_connectivity_radius=0.05,
        dim=2,
        dt=0.0025,
        vel_mean=[0.0, -1e-4],
        vel_std=[2e-3, 2e-3],
        acc_mean=[0.0, -1e-5],
        acc_std=[2e-4, 2e-4],
    )


@pytest.mark.parametrize("model", ["simplified", "simplified_wall10", "simplified_pairwise", "original"])
@pytest.mark.parametrize(
    "group",
    [
        "trainer=cpu",
        "trainer=gpu",
        "trainer=ddp",
        "logger=none",
        "logger=csv",
        "data=waterramps",
        "train=paper",
    ],
)
def test_every_config_composes_and_instantiates(model, group):
    cfg = _compose([f"model={model}", group])
    system = build_system(cfg, _FakeDataModule())
    sim = system.simulator
    assert sim.input_frames == cfg.model.history + 1
    n = 30
    sequence = 0.3 + 0.4 * torch.rand(n, sim.input_frames, 2)
    particle_type = torch.full((n,), 5)
    assert sim(sequence, particle_type).shape == (n, 2)


def test_model_configs_match_the_paper_table():
    simplified = architecture(_compose(["model=simplified"]).model)
    original = architecture(_compose(["model=original"]).model)
    assert (simplified["latent_size"], simplified["mp_steps"], simplified["history"]) == (64, 5, 1)
    assert (original["latent_size"], original["mp_steps"], original["history"]) == (128, 10, 5)
    assert simplified["type_encoding"] == "scalar" and original["type_encoding"] == "embedding"
    assert simplified["wall_clip"] == (0.0, 1.0) and original["wall_clip"] == (-1.0, 1.0)
    assert not simplified["edge_residual"] and original["edge_residual"]


def test_default_model_is_the_simplified_one_with_a_longer_wall_feature_and_pair_forces():
    default = architecture(_compose([]).model)
    paper = architecture(_compose(["model=simplified"]).model)
    assert default["wall_clip"] == (0.0, 10.0) and paper["wall_clip"] == (0.0, 1.0)
    assert default["decoder"] == "pairwise" and "decoder" not in paper  # LearnedSimulator's default: "node"
    changed = ("name", "wall_clip", "decoder", "gravity")
    assert {k: v for k, v in default.items() if k not in changed} == {
        k: v for k, v in paper.items() if k not in changed
    }


def _run_train(tmp_path: Path, dataset: Path, name: str, extra: list[str]) -> Path:
    run_dir = tmp_path / name
    cmd = [
        sys.executable, str(ROOT / "train.py"), f"data.root={dataset}", "data.generate_if_missing=false",
        f"hydra.run.dir={run_dir}", "evaluate.pretrained=null", *TINY, *extra,
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return run_dir


def _logged_steps(run_dir: Path) -> list[int]:
    steps = []
    for path in (run_dir / "csv").glob("version_*/metrics.csv"):
        with open(path) as f:
            steps += [int(row["step"]) for row in csv.DictReader(f) if row.get("train/loss")]
    return steps


def test_train_py_end_to_end_then_resume(tmp_path, tiny_dataset):
    common = ["logger=csv", "train.log_every_n_steps=1", "train.checkpoint_every_n_steps=3",
              "train.permanent_every_n_steps=6", "train.val_every_n_steps=3",
              "train.max_time=null"]  # fmt: skip
    first = _run_train(
        tmp_path, tiny_dataset, "first", [*common, "train.max_steps=6", "evaluate.render=true"]
    )
    ckpts = sorted(p.name for p in (first / "checkpoints").glob("*.ckpt"))
    assert "last.ckpt" in ckpts and "step00000006.ckpt" in ckpts
    assert (first / "checkpoints" / "permanent" / "step00000006.ckpt").exists()
    results = json.loads((first / "results.json").read_text())
    assert results["test"]["trajectories"] >= 1 and results["test"]["rollout_mse"] > 0
    # trainer.precision=auto (the default) ran what this CPU suits, and says which.
    assert results["precision"] == resolve_precision("auto", "cpu")
    assert (first / "test_rollout.gif").stat().st_size > 0
    state = torch.load(first / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert state["global_step"] == 6

    # Resume: one override; the step, optimizer and schedule come back from the checkpoint.
    second = _run_train(
        tmp_path,
        tiny_dataset,
        "second",
        [*common, "train.max_steps=9", f"train.ckpt_path={first}", "evaluate.enabled=false"],  # fmt: skip
    )
    steps = _logged_steps(second)
    assert steps and min(steps) >= 6 and max(steps) <= 9
    resumed = torch.load(second / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert resumed["global_step"] == 9
    system = GNSSystem.load_from_checkpoint(second / "checkpoints" / "last.ckpt", map_location="cpu")
    assert system.hparams.model["latent_size"] == 8
    # The LR schedule continued: lr at step 9 of a decay over max_steps=9 is lr_final.
    assert resumed["lr_schedulers"][0]["last_epoch"] == 9


def test_pushforward_and_mirror_training_read_longer_windows_and_train(tmp_path, tiny_dataset):
    from gnsx.data.datamodule import FrameDataset
    from gnsx.data.store import SplitReader

    reader = SplitReader(tiny_dataset, "train")
    frames = [reader.num_frames(i) for i in range(len(reader))]
    plain, pushed = FrameDataset(reader, history=1), FrameDataset(reader, history=1, lead=2)
    assert len(plain) == sum(t - 2 for t in frames) and len(pushed) == sum(t - 4 for t in frames)
    sample = pushed[len(pushed) - 1]  # the last window ends on the last frame
    assert sample.position_sequence.shape[1] == 4
    assert torch.equal(sample.next_position, torch.from_numpy(reader[len(reader) - 1].position[-1].copy()))
    run = _run_train(
        tmp_path, tiny_dataset, "pushforward",
        ["logger=csv", "train.max_steps=3", "train.max_time=null", "train.pushforward_steps=1",
         "train.mirror=true", "evaluate.enabled=false"],
    )  # fmt: skip
    assert json.loads((run / "results.json").read_text())["global_step"] == 3
    system = GNSSystem.load_from_checkpoint(run / "checkpoints" / "last.ckpt", map_location="cpu")
    assert system.hparams.pushforward_steps == 1 and system.hparams.mirror is True


def test_wandb_offline_run_is_written_and_finished(tmp_path, tiny_dataset):
    run = _run_train(
        tmp_path,
        tiny_dataset,
        "wb",
        [
            "logger=wandb",
            "train.loss=huber",  # the config path of the optional loss
            "train.max_steps=2",
            "train.val_every_n_steps=2",
            "train.max_time=null",
            "evaluate.render=false",
        ],  # fmt: skip
    )
    offline_runs = list((run / "wandb").glob("offline-run-*"))
    assert len(offline_runs) == 1
    assert list(offline_runs[0].glob("*.wandb"))


def test_config_has_no_unresolved_interpolations():
    cfg = OmegaConf.to_container(_compose([]), resolve=True)
    assert cfg["train"]["lr_decay_end"] == cfg["train"]["max_steps"]
    assert cfg["data"]["root"] == "data/small"


@pytest.mark.slow  # end-to-end (~10-25 s): `make test-slow`; keeps `make test` under 5 min
def test_ddp_with_two_cpu_processes_over_gloo(tmp_path, tiny_dataset):
    run = _run_train(
        tmp_path,
        tiny_dataset,
        "ddp",
        [
            "trainer=ddp",
            "trainer.accelerator=cpu",
            "trainer.devices=2",
            "logger=csv",
            "train.max_steps=4",
            "train.val_every_n_steps=4",
            "train.max_time=null",
            "evaluate.enabled=false",
        ],  # fmt: skip
    )
    # Lightning re-launched the script for rank 1 (it logs to its own file) and rank 0 saved the checkpoint.
    assert (run / "train_ddp_process_1.log").exists()
    state = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert state["global_step"] == 4


def test_samples_before_estimates_older_checkpoints_from_the_config_that_trained_them(tmp_path):
    """A checkpoint from before the sample count (the shipped weights) counts its steps x its config's batch:
    shipped layout (config.yaml beside it) and run layout (.hydra/config.yaml above checkpoints/permanent/);
    a recorded count wins; with no config it counts from 0 (the budget rule can only get stricter)."""
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    OmegaConf.save(OmegaConf.create({"data": {"batch_size": 2}}), shipped / "config.yaml")
    assert samples_before(shipped / "model.ckpt", {"global_step": 40000})[0] == 80000
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(OmegaConf.create({"data": {"batch_size": 8}}), run / ".hydra" / "config.yaml")
    ckpt = run / "checkpoints" / "permanent" / "step00000010.ckpt"
    assert samples_before(ckpt, {"global_step": 10})[0] == 80
    assert samples_before(ckpt, {"global_step": 10, "gnsx_samples_seen": 7}) == (7, "counted")
    assert samples_before(tmp_path / "alone" / "x.ckpt", {"global_step": 10})[0] == 0


def test_init_weights_fine_tunes_from_a_checkpoint_with_a_fresh_schedule(tmp_path, tiny_dataset):
    """train.init_weights: the run starts from the checkpoint's weights (and statistics), step 0, fresh
    schedule; with a learning rate of ~0 the weights stay the checkpoint's. Its training samples count the
    first run's (the shipped weights' budget is in samples: tests/test_pretrained.py)."""
    common = ["logger=none", "train.max_time=null", "evaluate.enabled=false"]
    first = _run_train(tmp_path, tiny_dataset, "first", [*common, "train.max_steps=3", "data.batch_size=2"])
    tuned = _run_train(
        tmp_path, tiny_dataset, "tuned",
        [*common, "train.max_steps=2", f"train.init_weights={first}", "train.lr_init=1e-30",
         "train.lr_final=1e-30", "train.noise_std=0", "data.batch_size=1"],
    )  # fmt: skip
    before = torch.load(first / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    after = torch.load(tuned / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert after["global_step"] == 2  # a fresh run, not a resumed one
    assert before["gnsx_samples_seen"] == 3 * 2
    assert after["gnsx_samples_seen"] == 3 * 2 + 2 * 1
    assert json.loads((tuned / "results.json").read_text())["samples_seen"] == 8
    for key, value in before["state_dict"].items():
        assert torch.allclose(after["state_dict"][key], value, atol=1e-6), key
    for key in ("vel_std", "acc_std", "bounds"):
        assert after["hyper_parameters"][key] == before["hyper_parameters"][key]
