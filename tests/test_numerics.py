"""A NaN/Inf loss or gradient never reaches the weights: the step is skipped and counted, training stops after
too many in a row, and gradient clipping is configurable."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from hydra import compose, initialize_config_dir
from test_train import CONF, TINY

import gnsx.training.system
from gnsx.data.datamodule import ParticleDataModule
from gnsx.data.store import load_metadata
from gnsx.training.builders import build_trainer
from gnsx.training.numerics import Diverged, SkippedSteps, finite_gradients
from gnsx.training.system import GNSSystem

MODEL = {"latent_size": 8, "mlp_hidden_size": 8, "mp_steps": 2}


class _Snapshots(L.Callback):
    """Weights and Adam's first moments before and after every training step."""

    def __init__(self):
        self.steps: list[tuple[dict, dict, dict, dict]] = []

    @staticmethod
    def _state(module, trainer):
        weights = {k: v.detach().clone() for k, v in module.named_parameters()}
        adam = trainer.optimizers[0].state
        moments = {id(p): adam[p]["exp_avg"].clone() for p in module.parameters() if p in adam}
        return weights, moments

    def on_train_batch_start(self, trainer, module, batch, batch_idx):
        self._before = self._state(module, trainer)

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
        self.steps.append((*self._before, *self._state(module, trainer)))


def _fit(dataset, monkeypatch, poison, bad_steps: set[int], max_steps: int, max_skipped: int = 20):
    """Train the tiny model ``max_steps`` steps; ``poison(loss, predicted)`` is the loss of ``bad_steps``."""
    original = gnsx.training.system.acceleration_loss
    calls = []

    def loss_fn(predicted, target, kind="mse", delta=1.0):
        loss = original(predicted, target, kind, delta)
        calls.append(None)
        return poison(loss, predicted) if len(calls) - 1 in bad_steps else loss

    monkeypatch.setattr(gnsx.training.system, "acceleration_loss", loss_fn)
    meta = load_metadata(dataset)
    stats = {key: getattr(meta, key) for key in ("vel_mean", "vel_std", "acc_mean", "acc_std")}
    system = GNSSystem(model=MODEL, dim=meta.dim, bounds=meta.bounds, radius=meta.default_connectivity_radius,
                       lr_init=1e-2, max_skipped_steps=max_skipped, **stats)  # fmt: skip
    snapshots = _Snapshots()
    quiet = {"logger": False, "enable_checkpointing": False, "enable_progress_bar": False}
    quiet |= {"enable_model_summary": False, "limit_val_batches": 0, "num_sanity_val_steps": 0}
    trainer = L.Trainer(max_steps=max_steps, callbacks=[snapshots], accelerator="cpu", **quiet)
    datamodule = ParticleDataModule(dataset, history=1, batch_size=1)
    trainer.fit(system, datamodule=datamodule)
    return system, trainer, snapshots


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize(
    "poison",
    [
        pytest.param(lambda loss, predicted: loss * float("nan"), id="nan-loss"),
        pytest.param(lambda loss, predicted: loss + float("inf"), id="inf-loss"),
        # Finite loss (0 is added) whose gradient is NaN: d sqrt(u)/du = inf at u = 0, times du/dx = 0.
        pytest.param(lambda loss, predicted: loss + torch.sqrt((predicted * 0).sum()), id="nan-gradient"),
    ],
)
def test_a_non_finite_step_is_skipped_and_leaves_weights_and_moments(tiny_dataset, monkeypatch, poison):
    system, trainer, snapshots = _fit(tiny_dataset, monkeypatch, poison, bad_steps={2}, max_steps=4)
    assert trainer.global_step == 4  # the step counter (and the LR schedule) went on
    assert system.skipped.total == 1 and system.skipped.in_a_row == 0
    before, moments_before, after, moments_after = snapshots.steps[2]
    assert _same(before, after) and _same(moments_before, moments_after)
    good_before, _, good_after, _ = snapshots.steps[3]
    assert not _same(good_before, good_after)  # an ordinary step does change them
    assert all(torch.isfinite(p).all() for p in system.parameters())


def test_too_many_skipped_steps_in_a_row_stop_training(tiny_dataset, monkeypatch):
    poison = lambda loss, predicted: loss * float("nan")  # noqa: E731
    with pytest.raises(Diverged, match=r"4 steps in a row had a non-finite loss or gradient \(from step 1: "
                                       r"loss is nan; train.max_skipped_steps=3\)"):  # fmt: skip
        _fit(tiny_dataset, monkeypatch, poison, bad_steps=set(range(1, 10)), max_steps=10, max_skipped=3)


def test_skipped_steps_counts_runs_of_skips():
    skipped = SkippedSteps(max_in_a_row=2)
    skipped.skip(5, "loss is nan")
    skipped.skip(6, "loss is inf")
    skipped.ok()
    skipped.skip(9, "a gradient is NaN or Inf")
    assert (skipped.total, skipped.in_a_row, skipped.first) == (3, 1, (9, "a gradient is NaN or Inf"))
    skipped.skip(10, "loss is nan")
    with pytest.raises(Diverged, match="3 steps in a row"):
        skipped.skip(11, "loss is nan")
    layer = torch.nn.Linear(2, 1)
    layer(torch.ones(1, 2)).sum().backward()
    assert finite_gradients(layer.parameters())
    layer.weight.grad[0, 0] = float("inf")
    assert not finite_gradients(layer.parameters())


def test_gradient_clipping_and_wall_clock_checkpoints_are_configurable(tmp_path):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, "train.gradient_clip_val=0.5", "logger=none",
                                                       "train.checkpoint_every_minutes=3"])  # fmt: skip
        default = compose(config_name="config", overrides=["logger=none"])
    trainer = build_trainer(cfg, tmp_path, [])
    assert trainer.gradient_clip_val == 0.5 and trainer.gradient_clip_algorithm == "norm"
    timed = [c for c in trainer.checkpoint_callbacks if c._train_time_interval is not None]
    assert len(timed) == 1 and timed[0]._train_time_interval.total_seconds() == 180
    assert build_trainer(default, tmp_path, []).gradient_clip_val is None
    assert default.train.checkpoint_every_minutes == 2 and default.threads == "auto"


def test_a_diverged_run_is_one_line_with_exit_status_1(capsys, monkeypatch):
    from gnsx.core.cli import hydra_task

    monkeypatch.delenv("GNSX_DEBUG", raising=False)

    @hydra_task
    def task(cfg):
        raise Diverged("4 steps in a row had a non-finite loss or gradient")

    with pytest.raises(SystemExit) as exit_:
        task(None)
    assert exit_.value.code == 1
    assert capsys.readouterr().err == "error: diverged: 4 steps in a row had a non-finite loss or gradient\n"


def test_threads_auto_leaves_busy_cores_alone(monkeypatch):
    from gnsx.core import threads

    assert threads.choose_threads(1, cores=2, load=0.1) == 2  # idle: every core
    assert threads.choose_threads(1, cores=2, load=1.0) == 1  # one core busy elsewhere
    assert threads.choose_threads(1, cores=2, load=3.5) == 1  # never fewer than 1
    assert threads.choose_threads(2, cores=8, load=0.0) == 4  # shared among DDP ranks
    assert threads.choose_threads(1, cores=64, load=0.0) == threads.MAX_THREADS
    assert 0.0 <= threads.machine_load(window_s=0.05) <= threads.available_cores() + 0.5
    before = torch.get_num_threads()
    monkeypatch.setattr(threads, "machine_load", lambda: 5.0)
    try:
        assert threads.apply_threads("auto") == 1 and torch.get_num_threads() == 1
        assert threads.apply_threads(2) == 2 and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
