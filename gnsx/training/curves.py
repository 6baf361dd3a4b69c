"""Learning curves: validation rollouts at fixed intervals of training time or of steps, and the training loss,
written to ``curve.jsonl`` for figures 6-7 of an equal-budget comparison and for the learning study.

Lightning validates every N steps or epochs, and its validation counts against a time budget. :class:`CurveValidation`
rolls the model out on the validation trajectories every ``every_s`` seconds of *training* time, or every
``every_n_steps`` optimizer steps, with the clock paused while it validates
(:meth:`gnsx.training.time_budget.TrainingClock.paused`): models of different speed are measured at the same
points of their budget, and validation costs none of them any training. Steps are the interval of the
learning study (docs/learning), whose arms have step budgets fixed in advance so that the machine's load
cannot change what an arm trains.

The file's rows are described in :mod:`gnsx.evaluation.curve_file`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from gnsx.evaluation.curve_file import append_row, read_rows
from gnsx.evaluation.scoring import baseline_errors, evaluate_trajectory
from gnsx.evaluation.spread import mean_se
from gnsx.training.time_budget import TrainingClock

log = logging.getLogger("gnsx")


class CurveValidation(Callback):
    """Validation rollouts every ``every_s`` seconds of training time or every ``every_n_steps`` steps, and the
    loss curve, into ``path``.

    Args:
        clock: the run's training clock (paused while this validates).
        every_s: training seconds between validations (None: ``every_n_steps`` decides); the run's end adds a
            last one.
        every_n_steps: optimizer steps between validations, instead of ``every_s``.
        path: the ``curve.jsonl`` to append to.
        loss_every_n_steps: steps per ``train`` row.
        onestep_stride: as :func:`gnsx.evaluation.scoring.evaluate_trajectory`.

    Validation trajectories are the data module's ``val_set`` (``train.val_max_trajectories`` of them).
    Rank zero validates (the comparison runs in one process).
    """

    def __init__(
        self,
        clock: TrainingClock,
        every_s: float | None,
        path: str | Path,
        loss_every_n_steps: int = 50,
        onestep_stride: int = 10,
        every_n_steps: int | None = None,
    ):
        if (every_s is None) == (every_n_steps is None):
            raise ValueError("CurveValidation: give one of every_s and every_n_steps")
        if every_s is not None and every_s <= 0:
            raise ValueError(f"CurveValidation: every_s must be positive, got {every_s}")
        if every_n_steps is not None and every_n_steps < 1:
            raise ValueError(f"CurveValidation: every_n_steps must be >= 1, got {every_n_steps}")
        self.clock = clock
        self.every_n_steps = None if every_n_steps is None else int(every_n_steps)
        self.every_s = float("inf") if every_s is None else float(every_s)
        self.path = Path(path)
        self.loss_every_n_steps = int(loss_every_n_steps)
        self.onestep_stride = int(onestep_stride)
        self.next_s = self.every_s  # training seconds of the next validation
        self.last_validated_step: int | None = None
        self._losses: list[torch.Tensor] = []  # detached, read once per train row (no device sync a step)

    def state_dict(self) -> dict:
        return {"next_s": self.next_s, "last_validated_step": self.last_validated_step}

    def load_state_dict(self, state_dict: dict) -> None:
        self.next_s = float(state_dict.get("next_s", self.every_s))
        self.last_validated_step = state_dict.get("last_validated_step")

    def _write(self, row: dict) -> None:
        append_row(self.path, row)

    def on_train_start(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero or any(r["kind"] == "baseline" for r in read_rows(self.path)):
            return
        # The scoring library's baseline (walls included), without its EMD: only the rollout MSE is drawn.
        frames, metadata = pl_module.simulator.input_frames, trainer.datamodule.metadata
        values = [
            baseline_errors(t["position"].numpy(), t["particle_type"].numpy(), frames, metadata, emd_every=0)[
                1
            ]["baseline_mse"]
            for t in trainer.datamodule.val_set
        ]
        mean, se = mean_se(values)
        self._write({"kind": "baseline", "rollout_mse": mean, "rollout_mse_se": se, "trajectories": len(values),
                     "rollout_mse_per_trajectory": [float(v) for v in values]})  # fmt: skip

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        loss = outputs.get("loss") if isinstance(outputs, dict) else outputs
        if loss is not None and not getattr(pl_module, "_skipping", False):
            self._losses.append(loss.detach())
        step = trainer.global_step
        if not trainer.is_global_zero:
            return
        if step % self.loss_every_n_steps == 0 and self._losses:
            self._write({"kind": "train", **self._position(trainer, pl_module),
                         "loss": float(torch.stack(self._losses).float().mean())})  # fmt: skip
            self._losses = []
        if self.every_n_steps is not None:
            if step % self.every_n_steps == 0 and step != self.last_validated_step:
                self.validate(trainer, pl_module)
        elif self.clock.total_training_s() >= self.next_s:
            self.validate(trainer, pl_module)
            while self.next_s <= self.clock.total_training_s():
                self.next_s += self.every_s

    def on_train_end(self, trainer, pl_module) -> None:
        if trainer.is_global_zero and self.last_validated_step != trainer.global_step:
            self.validate(trainer, pl_module)  # the curve's last point: the end of the budget

    def _position(self, trainer, pl_module) -> dict:
        return {"step": int(trainer.global_step), "time_s": self.clock.total_training_s(),
                "samples": int(getattr(pl_module, "samples_seen", 0))}  # fmt: skip

    def validate(self, trainer, pl_module) -> dict:
        """Roll out every validation trajectory (raw network, fp32); write, log and return the row."""
        row = {"kind": "val", **self._position(trainer, pl_module)}
        simulator = pl_module.simulator
        was_training = simulator.training
        simulator.eval()
        with self.clock.paused() as paused:
            with torch.inference_mode(), torch.autocast(pl_module.device.type, enabled=False):
                metrics = [
                    evaluate_trajectory(simulator, t["position"], t["particle_type"], self.onestep_stride)
                    for t in trainer.datamodule.val_set
                ]
        simulator.train(was_training)
        rollout = [m["rollout_mse"] for m in metrics]
        row["rollout_mse"], row["rollout_mse_se"] = mean_se(rollout)
        row["onestep_mse"] = float(np.mean([m["onestep_mse"] for m in metrics]))
        row["area_ratio_final"], row["area_ratio_final_se"] = mean_se(
            [m["area_ratio_final"] for m in metrics]
        )
        # Per trajectory (the validation split's order, as the baseline row's): paired ratios with intervals.
        row["rollout_mse_per_trajectory"] = [float(v) for v in rollout]
        row["area_ratio_final_per_trajectory"] = [float(m["area_ratio_final"]) for m in metrics]
        row["validation_s"] = paused.seconds
        row["trajectories"] = len(metrics)
        self._write(row)
        for logger in trainer.loggers:
            logger.log_metrics({f"val_clock/{k}": float(row[k]) for k in
                                ("rollout_mse", "rollout_mse_se", "onestep_mse", "area_ratio_final", "time_s",
                                                      "samples")},
                               step=row["step"])  # fmt: skip
        log.info("Validation at %.0f s of training (step %d): rollout MSE %.3g +- %.2g over %d trajectories "
                 "(%.0f s, not counted)", row["time_s"], row["step"], row["rollout_mse"],
                 row["rollout_mse_se"], len(metrics), row["validation_s"])  # fmt: skip
        self.last_validated_step = row["step"]
        return row
