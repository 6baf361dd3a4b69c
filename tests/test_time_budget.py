"""TimeBudget: a run shrunk to its wall-clock budget keeps a complete LR/noise schedule; throughput CLI."""

from __future__ import annotations

import json
import time

import lightning as L
import pytest
import torch
from torch import nn

from gnsx.training.schedule import learning_rate
from gnsx.training.time_budget import TimeBudget, fitted_steps, parse_duration


def test_parse_duration_and_fitted_steps():
    assert parse_duration("00:00:09:00") == 540.0
    assert parse_duration("01:02:03:04") == ((24 + 2) * 60 + 3) * 60 + 4
    assert parse_duration(12) == 12.0 and parse_duration(None) is None
    with pytest.raises(ValueError, match="DD:HH:MM:SS"):
        parse_duration("09:00")
    # 10 steps/s for 100 s at 90%: 900 more steps after the 200 done; never more than max_steps.
    assert fitted_steps(10_000, 200, 10.0, 100.0, 0.9) == 1100
    assert fitted_steps(1000, 200, 10.0, 100.0, 0.9) == 1000
    assert fitted_steps(10_000, 200, 10.0, -5.0, 0.9) == 200


class _SlowModule(L.LightningModule):
    """Sleeps ``step_s`` per step; its LR decay is scaled like GNSSystem's (set_schedule_scale)."""

    def __init__(self, step_s: float, max_steps: int):
        super().__init__()
        self.layer = nn.Linear(1, 1)
        self.step_s = step_s
        self.max_steps = max_steps
        self.schedule_scale = 1.0
        self.lrs: list[float] = []

    def set_schedule_scale(self, factor: float) -> None:
        self.schedule_scale = factor

    def training_step(self, batch, batch_idx):
        time.sleep(self.step_s)
        self.lrs.append(self.trainer.optimizers[0].param_groups[0]["lr"])
        return self.layer(batch[0]).square().mean()

    def configure_optimizers(self):
        optimizer = torch.optim.SGD(self.parameters(), lr=1.0)

        def factor(step):
            return learning_rate(step, 1.0, 0.01, 0, int(round(self.max_steps * self.schedule_scale)))

        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    def train_dataloader(self):
        data = torch.utils.data.TensorDataset(torch.randn(10_000, 1))
        return torch.utils.data.DataLoader(data, batch_size=1)


def _trainer(max_steps: int, *callbacks) -> L.Trainer:
    """A bare CPU Trainer for these callbacks: no logger, checkpoints, progress bar or validation batches."""
    return L.Trainer(
        max_steps=max_steps, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=list(callbacks), limit_val_batches=0,
    )  # fmt: skip


def test_time_budget_shrinks_the_run_and_completes_the_schedule(caplog):
    """~100 steps/s and a 1.5 s budget: far fewer than 10,000 steps fit, and the LR still reaches its end."""
    module = _SlowModule(step_s=0.01, max_steps=10_000)
    budget = TimeBudget(1.5, calibration_steps=20, safety=0.9)
    trainer = _trainer(10_000, budget)
    with caplog.at_level("WARNING", logger="gnsx"):
        trainer.fit(module)
    assert budget.fitted is not None and 20 < budget.fitted < 300
    assert trainer.global_step == budget.fitted
    assert module.lrs[-1] < 0.02  # decayed to ~lr_final, not cut short at lr ~ 1
    assert any("Time budget" in r.message for r in caplog.records)
    state = budget.state_dict()
    assert state["planned_steps"] == 10_000 and state["fitted"] == budget.fitted
    assert (
        state["trained_s"] > 1.0
    )  # the training time (the budget, give or take the load), kept for a resume


def test_time_budget_leaves_a_run_that_fits_alone():
    module = _SlowModule(step_s=0.0, max_steps=30)
    budget = TimeBudget(60.0, calibration_steps=10)
    trainer = _trainer(30, budget)
    trainer.fit(module)
    assert budget.fitted is None and trainer.global_step == 30 and module.schedule_scale == 1.0


class _Validator(L.Callback):
    """Pauses the clock for ``pause_s`` every ``every`` steps, as CurveValidation does while it rolls out."""

    def __init__(self, clock, every: int, pause_s: float):
        self.clock, self.every, self.pause_s, self.pauses = clock, every, pause_s, 0

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if trainer.global_step % self.every == 0:
            with self.clock.paused():
                time.sleep(self.pause_s)
            self.pauses += 1


def test_a_training_time_budget_leaves_validation_out_and_stops_the_fit():
    """count_validation=False: 1 s of training at ~100 steps/s, with 0.2 s pauses every 20 steps (~1 s of
    validation in all). The fit stops near 1 s of training although its wall time is ~2 s, and the resumed
    state carries the training time spent."""
    module = _SlowModule(step_s=0.01, max_steps=10_000)
    budget = TimeBudget(1.0, calibration_steps=20, safety=1.0, count_validation=False)
    validator = _Validator(budget, every=20, pause_s=0.2)
    trainer = _trainer(10_000, budget, validator)
    start = time.perf_counter()
    trainer.fit(module)
    wall = time.perf_counter() - start
    summary = budget.summary()
    assert validator.pauses >= 3
    assert summary["validation_s"] == pytest.approx(0.2 * validator.pauses, rel=0.2)
    assert 0.9 < summary["training_s"] < 1.25  # the budget, validation excluded
    assert wall > summary["training_s"] + summary["validation_s"] * 0.9
    assert module.lrs[-1] < 0.05  # the schedule was fitted to the training time, not to the wall time
    resumed = TimeBudget(1.0, count_validation=False)
    resumed.load_state_dict(budget.state_dict())
    assert resumed.total_training_s() == pytest.approx(summary["training_s"], rel=0.05)


class _SpeedsUp(_SlowModule):
    """Slow (``slow_s`` per step) for the first ``slow_steps`` steps, as under a passing load, then fast."""

    def __init__(self, slow_s: float, fast_s: float, slow_steps: int, max_steps: int):
        super().__init__(slow_s, max_steps)
        self.fast_s, self.slow_steps = fast_s, slow_steps

    def training_step(self, batch, batch_idx):
        if self.global_step >= self.slow_steps:
            self.step_s = self.fast_s
        return super().training_step(batch, batch_idx)


def test_a_training_time_budget_grows_the_run_again_when_the_rate_recovers(caplog):
    """Calibrated during a slow spell (20 ms/step), the run would stop after ~half its budget once steps
    take 5 ms; the re-plan on the recent rate grows it back, so the budget is used (count_validation=False)."""
    module = _SpeedsUp(slow_s=0.02, fast_s=0.005, slow_steps=40, max_steps=100_000)
    budget = TimeBudget(2.0, calibration_steps=20, safety=0.95, count_validation=False)
    budget.replan_every = 25
    trainer = _trainer(100_000, budget)
    with caplog.at_level("WARNING", logger="gnsx"):
        trainer.fit(module)
    first = 20 + int(2.0 * 0.95 / 0.02)  # what the calibration alone would have fitted: ~115 steps
    assert budget.fitted > 1.5 * first and trainer.global_step == budget.fitted
    assert budget.summary()["training_s"] > 0.75 * 2.0
    assert module.lrs[-1] < 0.05  # the grown schedule still completes
    assert any("instead of" in r.message for r in caplog.records)


def test_throughput_cli_reports_rates(tiny_dataset, tmp_path, capsys):
    from gnsx.perf.throughput import main

    out = tmp_path / "rates.json"
    assert main(["--data", str(tiny_dataset), "--batch-size", "2", "--steps", "10", "--warmup", "3",
                 "--threads", "1", "--json", str(out)]) == 0  # fmt: skip
    (result,) = json.loads(out.read_text())
    assert result["steps_per_s"] > 0 and result["samples_per_s"] == pytest.approx(2 * result["steps_per_s"])
    assert "samples/s" in capsys.readouterr().out
    assert main(["--data", str(tmp_path / "missing")]) == 2  # one line on stderr (gnsx.core.cli)
    assert (
        capsys.readouterr().err == f"error: --data {tmp_path / 'missing'}: no gnsx dataset here "
        "(metadata.json missing); `make data` makes one\n"
    )
