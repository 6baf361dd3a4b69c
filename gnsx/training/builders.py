"""The objects a run trains with, built from its config: the :class:`GNSSystem` (fresh, or with a
checkpoint's weights for fine-tuning), the Lightning Trainer with its checkpointing, the training clock
(optionally fitted to a time budget), and the process-wide settings (float32 matmul precision, threads per
process).
"""

from __future__ import annotations

import logging
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from omegaconf import DictConfig, OmegaConf

from gnsx.core.errors import ConfigError
from gnsx.data.datamodule import ParticleDataModule
from gnsx.model.checkpoint import read_checkpoint
from gnsx.training.inputs import resolve_checkpoint
from gnsx.training.model_settings import (
    combine_std,
    connectivity_radius,
    model_arguments,
    training_noise,
)
from gnsx.training.precision import resolve_precision
from gnsx.training.resilience import AtomicCheckpointIO, remove_stale_temporaries, wall_clock_checkpoint
from gnsx.training.system import GNSSystem, samples_of
from gnsx.training.time_budget import TimeBudget, TrainingClock, parse_duration

log = logging.getLogger("gnsx")


def build_system(cfg: DictConfig, datamodule: ParticleDataModule) -> GNSSystem:
    """A fresh GNSSystem whose data facts (bounds, radius, statistics) come from the dataset's metadata.

    With ``train.init_weights`` (fine-tuning) the weights, the bounds and the normalisation statistics are the
    checkpoint's (the weights were trained for those statistics); the schedule and the optimizer start fresh.
    """
    meta = datamodule.metadata
    train = cfg.train
    facts = {
        "bounds": [list(map(float, b)) for b in meta.bounds],
        **{key: list(getattr(meta, key)) for key in ("vel_mean", "vel_std", "acc_mean", "acc_std")},
    }
    noise = training_noise(cfg)
    radius, radius_source = connectivity_radius(cfg, meta)
    init = resolve_checkpoint(OmegaConf.select(train, "init_weights", default=None), "train.init_weights")
    state = read_checkpoint(init) if init is not None else None
    if state is not None:
        facts = {key: state["hyper_parameters"][key] for key in facts}  # already widened if they were
    elif OmegaConf.select(cfg.model, "widen_stats_by_noise", default=False):
        for key in ("vel_std", "acc_std"):
            facts[key] = combine_std(facts[key], noise["noise_std"])
        log.info("Normalisation stds widened by the noise %.3g (model.widen_stats_by_noise): vel_std %s, "
                 "acc_std %s", noise["noise_std"], _short(facts["vel_std"]), _short(facts["acc_std"]))  # fmt: skip
    log.info("Model %s: connection radius %g (%s); noise %.3g from %s, decay x%g from %s", cfg.model.name,
             radius, radius_source, noise["noise_std"], noise["noise_std_source"], noise["noise_decay"],
             noise["noise_decay_source"])  # fmt: skip
    system = GNSSystem(
        model=model_arguments(cfg.model, meta),
        dim=meta.dim,
        radius=radius,
        **facts,
        noise_std=noise["noise_std"],
        noise_decay=noise["noise_decay"],
        noise_correction=float(OmegaConf.select(train, "noise_correction", default=0.0)),
        pushforward_steps=int(OmegaConf.select(train, "pushforward_steps", default=0)),
        unroll_steps=int(OmegaConf.select(train, "unroll_steps", default=1)),
        mirror=bool(OmegaConf.select(train, "mirror", default=False)),
        lr_init=float(train.lr_init),
        lr_final=float(train.lr_final),
        lr_decay_start=int(train.lr_decay_start),
        lr_decay_end=int(train.lr_decay_end),
        lr_warmup_steps=int(OmegaConf.select(train, "lr_warmup_steps", default=0)),
        lr_schedule=str(OmegaConf.select(train, "lr_schedule", default="exponential")),
        loss=str(train.loss),
        huber_delta=float(train.huber_delta),
        max_skipped_steps=int(OmegaConf.select(train, "max_skipped_steps", default=20)),
    )
    if state is not None:
        system.load_state_dict(state["state_dict"])
        before, how = samples_before(Path(init), state)
        system.samples_seen = before
        log.info("Weights from %s (train.init_weights, %s training samples, %s); a fresh schedule and "
                 "optimizer", init, f"{before:,}", how)  # fmt: skip
    return system


def _short(values: list[float]) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in values) + "]"


def samples_before(path: Path, state: dict) -> tuple[int, str]:
    """Training samples the weights of checkpoint ``path`` (loaded as ``state``) have seen, and how we know.

    Checkpoints since 2026-12-03 record the count (:func:`gnsx.training.system.samples_of`). For an older one (the
    shipped ``pretrained/small`` among them) it is estimated as its ``global_step`` times the batch size of
    the config that trained it: ``config.yaml`` beside the file (shipped weights) or the run's
    ``.hydra/config.yaml`` above ``checkpoints/[permanent/]``. Without either it is 0, which can only make the
    budget rule (tests/test_pretrained.py) stricter.
    """
    counted = samples_of(state)
    if counted is not None:
        return counted, "counted"
    step = int(state.get("global_step") or 0)
    for folder in path.parents[:3]:
        for config in (folder / "config.yaml", folder / ".hydra" / "config.yaml"):
            batch = OmegaConf.select(OmegaConf.load(config), "data.batch_size") if config.is_file() else None
            if batch is not None:
                return step * int(batch), f"estimated: {step:,} steps x batch {batch} of {config}"
    return 0, "unknown: an older checkpoint with no config beside it; counted from 0"


def apply_matmul_precision(cfg: DictConfig) -> str:
    """``torch.set_float32_matmul_precision`` from ``trainer.float32_matmul_precision`` (default
    ``"highest"``: true fp32 products; ``"high"`` would let CUDA use TF32). Returns the setting."""
    precision = str(OmegaConf.select(cfg, "trainer.float32_matmul_precision", default="highest"))
    if precision not in ("highest", "high", "medium"):
        raise ConfigError(f"trainer.float32_matmul_precision={precision}", "must be highest, high or medium")
    torch.set_float32_matmul_precision(precision)
    return precision


def local_processes(cfg: DictConfig) -> int:
    """Training processes of this node that share its CPU cores (DDP ranks; 1 otherwise)."""
    devices = OmegaConf.select(cfg, "trainer.devices", default=1)
    strategy = str(OmegaConf.select(cfg, "trainer.strategy", default="auto"))
    return int(devices) if isinstance(devices, int) and "ddp" in strategy else 1


def training_clock(cfg: DictConfig) -> TrainingClock:
    """The run's clock: a :class:`TimeBudget` (a TrainingClock that also fits the run to ``train.max_time``)
    when ``train.fit_to_max_time``, else a plain :class:`TrainingClock`.

    ``train.budget_counts_validation: false`` makes ``max_time`` training time only (validation rollouts
    excluded; the TimeBudget stops the fit), with ``train.budget_safety`` of the remaining time planned for.
    """
    train = cfg.train
    if not (train.fit_to_max_time and train.max_time is not None):
        return TrainingClock()
    return TimeBudget(
        parse_duration(train.max_time),
        int(train.calibration_steps),
        safety=float(OmegaConf.select(train, "budget_safety", default=0.9)),
        count_validation=bool(OmegaConf.select(train, "budget_counts_validation", default=True)),
    )


def build_trainer(cfg: DictConfig, run_dir: Path, loggers: list, callbacks: list | None = None) -> L.Trainer:
    """The Lightning Trainer of ``trainer/`` and ``train/``, with checkpointing and ``callbacks`` added.

    Checkpoints (``run_dir/checkpoints/``): the 5 most recent every ``train.checkpoint_every_n_steps``,
    permanent ones every ``train.permanent_every_n_steps``, and ``last.ckpt`` also every
    ``train.checkpoint_every_minutes`` of wall time; all written atomically (:mod:`gnsx.training.resilience`).
    ``train.gradient_clip_val`` clips the gradient norm (null: no clipping).
    """
    train = cfg.train
    ckpt_dir = run_dir / "checkpoints"
    running = ModelCheckpoint(
        dirpath=ckpt_dir,
        filename="step{step:08d}",
        auto_insert_metric_name=False,
        every_n_train_steps=int(train.checkpoint_every_n_steps),
        save_top_k=5,
        monitor="step",
        mode="max",
        save_last=True,
        enable_version_counter=False,  # the wall-clock callback writes last.ckpt too: no last-v1.ckpt
    )
    permanent = ModelCheckpoint(
        dirpath=ckpt_dir / "permanent",
        filename="step{step:08d}",
        auto_insert_metric_name=False,
        every_n_train_steps=int(train.permanent_every_n_steps),
        save_top_k=-1,
    )
    checkpoints = [running, permanent]
    minutes = OmegaConf.select(train, "checkpoint_every_minutes", default=None)
    if minutes:
        checkpoints.append(wall_clock_checkpoint(ckpt_dir, float(minutes)))
    remove_stale_temporaries(ckpt_dir)
    trainer_args = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer_args.pop(
        "float32_matmul_precision", None
    )  # gnsx's, not a Trainer argument (apply_matmul_precision)
    requested = trainer_args.get("precision", "32-true")
    trainer_args["precision"] = resolve_precision(requested, trainer_args.get("accelerator", "auto"))
    if str(requested) == "auto":
        log.info("Precision: %s (trainer.precision=auto, gnsx.training.precision)", trainer_args["precision"])
    # Training time only (validation excluded): the TimeBudget stops the fit, as Lightning's Timer counts
    # validation. Validation at intervals of training time or steps replaces Lightning's loop (CurveValidation).
    counts_validation = bool(OmegaConf.select(train, "budget_counts_validation", default=True))
    if any(OmegaConf.select(train, key, default=None) is not None
           for key in ("val_every_minutes", "curve_every_n_steps")):  # fmt: skip
        trainer_args["limit_val_batches"] = 0
    return L.Trainer(
        **trainer_args,
        plugins=[AtomicCheckpointIO()],
        gradient_clip_val=OmegaConf.select(train, "gradient_clip_val", default=None),
        gradient_clip_algorithm="norm",
        max_steps=int(train.max_steps),
        max_time=train.max_time if counts_validation else None,  # config_checks: false needs fit_to_max_time
        val_check_interval=int(train.val_every_n_steps),
        check_val_every_n_epoch=None,
        num_sanity_val_steps=0,
        log_every_n_steps=int(train.log_every_n_steps),
        logger=loggers if loggers else False,
        callbacks=[*checkpoints, TQDMProgressBar(refresh_rate=50), *(callbacks or [])],
        default_root_dir=str(run_dir),
        enable_model_summary=True,
    )
