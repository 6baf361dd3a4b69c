"""The Lightning system: trains a :class:`~gnsx.model.simulator.LearnedSimulator` (paper section 7).

Kept apart from the model (Lightning's style guide): this file owns the loss, the optimizer and the LR/noise
schedules, and validation rollouts; the ``nn.Module`` owns the physics. All constructor arguments are saved as
hyperparameters, so ``GNSSystem.load_from_checkpoint(path)`` rebuilds the model with no config at hand.
"""

from __future__ import annotations

from typing import Any

import lightning as L
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.evaluation.scoring import evaluate_trajectory
from gnsx.model.checkpoint import simulator_from_hparams
from gnsx.model.mirror import random_mirror
from gnsx.model.training_targets import noisy_training_rollout
from gnsx.training.numerics import SkippedSteps, drop_gradients, finite_gradients
from gnsx.training.schedule import LR_SCHEDULES, learning_rate, noise_std, warmup_factor

#: Training losses on the normalised acceleration (``train.loss``).
LOSSES = ("mse", "huber")


def acceleration_loss(predicted: torch.Tensor, target: torch.Tensor, kind: str = "mse", delta: float = 1.0):
    """Mean over particles of a loss on the normalised-acceleration error vector ``e = predicted - target``.

    ``"mse"``: ``|e|^2`` (eq. 7; DeepMind's loss). ``"huber"``: ``|e|^2`` for ``|e| <= delta`` and
    ``2 delta |e| - delta^2`` above (same value and slope at ``delta``), on the vector's length so the loss
    stays rotation invariant. Why offer it: wall and block impacts give normalised accelerations of 10-50 that
    the model cannot foresee from its neighbourhood, and under MSE a few of them pull the prediction for every
    similar-looking particle (a block in free fall) away from gravity; past ``delta`` an error's pull is
    capped.

    Args:
        predicted, target: ``[N, D]``.
    Returns:
        a scalar tensor.
    """
    squared = ((predicted - target) ** 2).sum(dim=-1)  # [N]
    if kind == "mse":
        return squared.mean()
    if kind != "huber":
        raise ValueError(f"acceleration_loss: kind must be one of {LOSSES}, got {kind!r}")
    # The clamp keeps sqrt's gradient finite at e = 0 (that branch is not selected there anyway).
    length = squared.clamp_min(delta * delta).sqrt()
    return torch.where(squared <= delta * delta, squared, 2 * delta * length - delta * delta).mean()


SAMPLES_KEY = "gnsx_samples_seen"


def samples_of(checkpoint: dict) -> int | None:
    """Training samples the checkpoint's weights have seen (:attr:`GNSSystem.samples_seen`, fine-tunes
    counting their start), or None for checkpoints from before 2026-12-03, which did not record it."""
    value = checkpoint.get(SAMPLES_KEY)
    return None if value is None else int(value)


class GNSSystem(L.LightningModule):
    """Loss, optimisation and validation of a learned simulator.

    Args:
        model: LearnedSimulator's architecture arguments (latent_size, mp_steps, history, ...).
        dim, bounds, radius, vel_mean, vel_std, acc_mean, acc_std: dataset facts from its metadata
            (statistics are per-frame differences, data units).
        noise_std: std of the training noise on the most recent velocity at the start of training.
        noise_decay: factor applied to the noise std by the end of the LR decay (paper: 0.4).
        noise_correction: share of the input position noise the target undoes (0: DeepMind's; 1: the
            target is the true next position; :func:`gnsx.model.training_targets.noisy_training_pair`).
        pushforward_steps: model steps without gradient before the loss step (the pushforward trick; the
            datamodule must give samples that many frames longer); 0: DeepMind's single step.
        unroll_steps: model steps the loss averages over, with the gradient through them
            (:func:`gnsx.model.training_targets.noisy_training_rollout`; the datamodule must give samples
            ``unroll_steps - 1`` frames longer); 1: DeepMind's single step.
        mirror: train on each sample or its left-right reflection, with probability 1/2
            (:mod:`gnsx.model.mirror`).
        lr_init, lr_final, lr_decay_start, lr_decay_end: exponential LR decay (paper eq. 8).
        lr_schedule: ``"exponential"`` (the paper's) or ``"deepmind"`` (DeepMind's; see
            :func:`gnsx.training.schedule.learning_rate`).
        lr_warmup_steps: linear LR ramp over the first steps (:func:`gnsx.training.schedule.warmup_factor`; 0: none).
        onestep_stride: validation one-step MSE uses every ``onestep_stride``-th frame of each trajectory.
        loss: ``"mse"`` (the paper's and DeepMind's: squared error of the normalised acceleration) or
            ``"huber"`` (squared below ``huber_delta``, linear above, on the error vector's length; see
            :func:`acceleration_loss`).
        huber_delta: where the Huber loss turns linear, in normalised-acceleration units.
        max_skipped_steps: training stops (:class:`~gnsx.training.numerics.Diverged`) after more than this many
            optimizer steps in a row were skipped for a NaN/Inf loss or gradient (0: never); a skipped step
            leaves every weight untouched (:mod:`gnsx.training.numerics`).
    """

    def __init__(
        self,
        *,
        model: dict[str, Any],
        dim: int,
        bounds: list[list[float]],
        radius: float,
        vel_mean: list[float],
        vel_std: list[float],
        acc_mean: list[float],
        acc_std: list[float],
        noise_std: float = 3.0e-4,
        noise_decay: float = 0.4,
        noise_correction: float = 0.0,
        pushforward_steps: int = 0,
        unroll_steps: int = 1,
        mirror: bool = False,
        lr_init: float = 1.0e-4,
        lr_final: float = 1.0e-6,
        lr_decay_start: int = 1_000_000,
        lr_decay_end: int = 1_500_000,
        lr_warmup_steps: int = 0,
        lr_schedule: str = "exponential",
        onestep_stride: int = 10,
        loss: str = "mse",
        huber_delta: float = 1.0,
        max_skipped_steps: int = 20,
    ):
        super().__init__()
        if lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"GNSSystem: lr_schedule must be one of {LR_SCHEDULES}, got {lr_schedule!r}")
        if loss not in LOSSES:
            raise ValueError(f"GNSSystem: loss must be one of {LOSSES}, got {loss!r}")
        if not 0.0 <= noise_correction <= 1.0:
            raise ValueError(f"GNSSystem: noise_correction must be in [0, 1], got {noise_correction}")
        if pushforward_steps < 0:
            raise ValueError(f"GNSSystem: pushforward_steps must be >= 0, got {pushforward_steps}")
        if unroll_steps < 1:
            raise ValueError(f"GNSSystem: unroll_steps must be >= 1, got {unroll_steps}")
        if not huber_delta > 0:
            raise ValueError(f"GNSSystem: huber_delta must be > 0, got {huber_delta}")
        self.save_hyperparameters()
        self.skipped = SkippedSteps(max_skipped_steps)
        self._skipping = False  # the current step was skipped
        # Training samples (graphs) the weights have seen, counting the run a fine-tune started from
        # (``gnsx.training.builders.build_system`` sets it from ``train.init_weights``): the shipped weights' budget
        # is measured in samples, whatever the batch size or the number of runs (tests/test_pretrained.py).
        # Per process under DDP, and a resumed run of a checkpoint from before 2026-12-03 counts from 0:
        # both undercount, so the budget rule can only be stricter.
        self.samples_seen = 0
        # One construction path for training and for loading (gnsx.model.checkpoint): the saved
        # hyper-parameters alone rebuild this simulator.
        self.simulator = simulator_from_hparams(self.hparams)

    # -- schedules -------------------------------------------------------------------------------------------
    def _lr_kwargs(self) -> dict:
        h = self.hparams
        scale = self.schedule_scale
        return dict(
            lr_init=h.lr_init,
            lr_final=h.lr_final,
            decay_start=int(round(h.lr_decay_start * scale)),
            decay_end=int(round(h.lr_decay_end * scale)),
            kind=h.get("lr_schedule", "exponential"),  # absent from checkpoints before 2026-12-06
        )

    #: Factor on the LR decay's start and end steps (1: as configured); set by :meth:`set_schedule_scale`.
    schedule_scale: float = 1.0

    def set_schedule_scale(self, factor: float) -> None:
        """Compress (``factor < 1``) the LR and noise schedule in steps, e.g. to fit a run shortened to
        ``factor`` of its steps by :class:`gnsx.training.time_budget.TimeBudget`. Both are read at every step."""
        if not factor > 0:
            raise ValueError(f"set_schedule_scale: factor must be > 0, got {factor}")
        self.schedule_scale = float(factor)

    def current_noise_std(self) -> float:
        """Noise std at the current optimizer step (decays with the LR; restored on resume with the step)."""
        return noise_std(
            self.global_step, self.hparams.noise_std, self.hparams.noise_decay, **self._lr_kwargs()
        )

    def configure_optimizers(self):
        # fused: one kernel over all ~60 parameter tensors instead of a dozen ops per tensor (Adam's step went
        # from 5.5 to 1.7 ms of a ~90 ms CPU training step); same update as the default implementation.
        optimizer = torch.optim.Adam(self.parameters(), lr=self.hparams.lr_init, fused=True)
        # The lambda reads the schedule at every step, so set_schedule_scale takes effect mid-run.
        scheduler = torch.optim.lr_scheduler.LambdaLR(
            optimizer,
            lambda step: (
                learning_rate(step, **self._lr_kwargs())
                / self.hparams.lr_init
                * warmup_factor(step, self.hparams.get("lr_warmup_steps", 0))
            ),  # lr_warmup_steps is absent from checkpoints before 2026-12-03
        )
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    # -- training --------------------------------------------------------------------------------------------
    def training_step(self, batch, batch_idx: int) -> torch.Tensor:
        self._skipping = False
        std = self.current_noise_std()
        correction = self.hparams.get("noise_correction", 0.0)  # absent from checkpoints before 2026-12-01
        sequence, next_position = batch.position_sequence, batch.next_position
        if self.hparams.get("mirror", False):  # absent from checkpoints before 2026-12-02
            sequence, next_position = random_mirror(
                sequence, next_position, self.simulator.bounds, batch.batch, num_graphs=batch.num_graphs
            )
        predicted, target = noisy_training_rollout(
            self.simulator,
            sequence,
            next_position,
            batch.particle_type,
            std,
            batch.batch,
            position_correction=correction,
            pushforward_steps=self.hparams.get("pushforward_steps", 0),  # absent from older checkpoints
            unroll_steps=self.hparams.get("unroll_steps", 1),  # absent from checkpoints before 2026-12-07
        )  # [S, N, D] each
        # Averaged over dynamic particles: static particles are never moved by the model, so they are not in
        # the loss. With an unrolled loss, the mean over its steps.
        dynamic = batch.particle_type != KINEMATIC_PARTICLE_ID
        h = self.hparams
        loss = torch.stack(
            [
                acceleration_loss(p[dynamic], t[dynamic], h.loss, h.huber_delta)
                for p, t in zip(predicted, target)
            ]
        ).mean()
        size = int(batch.num_graphs)
        self.samples_seen += size
        bad = not bool(torch.isfinite(loss.detach()))
        # Every rank skips together (gnsx.training.numerics); a single process decides alone.
        if bool(self.trainer.strategy.reduce_boolean_decision(bad, all=False)):
            self._skip(f"loss is {float(loss.detach()):g}")
            # A zero loss on the parameters alone: backward (and DDP's all-reduce) run on finite zeros, and
            # on_before_optimizer_step drops them, so the optimizer changes nothing.
            return sum((p * 0).sum() for p in self.parameters() if p.requires_grad)
        self.log("train/loss", loss, prog_bar=True, batch_size=size)
        self.log("train/noise_std", std, batch_size=size)
        self.log("train/lr", self.trainer.optimizers[0].param_groups[0]["lr"], batch_size=size)
        return loss

    def _skip(self, reason: str) -> None:
        self._skipping = True
        self.skipped.skip(self.global_step, reason)
        self.log("train/skipped_steps", float(self.skipped.total), batch_size=1)

    def on_before_optimizer_step(self, optimizer) -> None:
        """Drop the gradients of a skipped step, or non-finite ones (before clipping and the optimizer): the
        optimizer then changes no weight and no moment."""
        if self._skipping:
            drop_gradients(self.parameters())
        elif not finite_gradients(self.parameters()):
            drop_gradients(self.parameters())
            self._skip("a gradient is NaN or Inf")

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        if not self._skipping:
            self.skipped.ok()

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["gnsx_skipped_steps"] = int(self.skipped.total)
        checkpoint[SAMPLES_KEY] = int(self.samples_seen)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.skipped.total = int(checkpoint.get("gnsx_skipped_steps", 0))
        self.samples_seen = samples_of(checkpoint) or 0

    # -- validation: full rollouts ---------------------------------------------------------------------
    def validation_step(self, trajectory: dict, batch_idx: int) -> None:
        # Rollouts are scored in fp32 whatever the training precision (gnsx.training.precision): under bf16-mixed,
        # Lightning's autocast would otherwise reach the rollout, and the checkpoint choice would rest on
        # bf16 rollouts that evaluation never runs.
        with torch.autocast(self.device.type, enabled=False):
            metrics = evaluate_trajectory(
                self.simulator,
                trajectory["position"],
                trajectory["particle_type"],
                onestep_stride=self.hparams.onestep_stride,
            )
        for name, value in metrics.items():
            # sync_dist: under DDP each rank rolls out its share of the trajectories; log their mean.
            self.log(f"val/{name}", value, batch_size=1, prog_bar=name == "rollout_mse", sync_dist=True)
