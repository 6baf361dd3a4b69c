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


def test_time_budget_shrinks_the_run_and_completes_the_schedule(caplog):
    """~100 steps/s and a 1.5 s budget: far fewer than 10,000 steps fit, and the LR still reaches its end."""
    module = _SlowModule(step_s=0.01, max_steps=10_000)
    budget = TimeBudget(1.5, calibration_steps=20, safety=0.9)
    trainer = L.Trainer(
        max_steps=10_000, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[budget], limit_val_batches=0,
    )  # fmt: skip
    with caplog.at_level("WARNING", logger="gnsx"):
        trainer.fit(module)
    assert budget.fitted is not None and 20 < budget.fitted < 300
    assert trainer.global_step == budget.fitted
    assert module.lrs[-1] < 0.02  # decayed to ~lr_final, not cut short at lr ~ 1
    assert any("Time budget" in r.message for r in caplog.records)
    assert budget.state_dict() == {"planned_steps": 10_000, "fitted": budget.fitted}


def test_time_budget_leaves_a_run_that_fits_alone():
    module = _SlowModule(step_s=0.0, max_steps=30)
    budget = TimeBudget(60.0, calibration_steps=10)
    trainer = L.Trainer(
        max_steps=30, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[budget], limit_val_batches=0,
    )  # fmt: skip
    trainer.fit(module)
    assert budget.fitted is None and trainer.global_step == 30 and module.schedule_scale == 1.0


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
