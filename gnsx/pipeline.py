"""What ``train.py`` does with its Hydra config: data, model, loggers, Lightning fit, test evaluation, pictures.

This is the one module that reads the composed config; everything it calls takes typed arguments.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from omegaconf import DictConfig, OmegaConf

from gnsx.datamodule import ParticleDataModule
from gnsx.system import GNSSystem

log = logging.getLogger("gnsx")

#: Config keys of ``model/*.yaml`` that are not LearnedSimulator architecture arguments.
_NON_ARCH_KEYS = ("name", "noise_std", "radius")


def architecture(model_cfg: DictConfig) -> dict[str, Any]:
    """LearnedSimulator keyword arguments from a ``model/*.yaml`` config."""
    arch = OmegaConf.to_container(model_cfg, resolve=True)
    for key in _NON_ARCH_KEYS:
        arch.pop(key, None)
    arch["wall_clip"] = tuple(arch["wall_clip"])
    return arch


def ensure_dataset(data_cfg: DictConfig) -> Path:
    """The dataset folder, generated with gnsx's MPM solver on first use when the config allows it."""
    root = Path(data_cfg.root)
    if (root / "metadata.json").exists():
        return root
    if not data_cfg.generate_if_missing:
        raise FileNotFoundError(
            f"{root}: no dataset here (metadata.json missing). Generate one with "
            f"`python -m gnsx.data generate --preset {data_cfg.preset} --out {root}` or convert yours with "
            f"`python -m gnsx.data convert SRC {root}`."
        )
    from gnsx.mpm.generate import generate_dataset

    log.info("Generating the '%s' preset into %s (first use)", data_cfg.preset, root)
    generate_dataset(root, data_cfg.preset, seed=data_cfg.generate_seed)
    return root


def build_system(cfg: DictConfig, datamodule: ParticleDataModule) -> GNSSystem:
    """A fresh GNSSystem whose data facts (bounds, radius, statistics) come from the dataset's metadata."""
    meta = datamodule.metadata
    train = cfg.train
    return GNSSystem(
        model=architecture(cfg.model),
        dim=meta.dim,
        bounds=[list(map(float, b)) for b in meta.bounds],
        radius=float(cfg.model.radius if cfg.model.radius is not None else meta.default_connectivity_radius),
        vel_mean=list(meta.vel_mean),
        vel_std=list(meta.vel_std),
        acc_mean=list(meta.acc_mean),
        acc_std=list(meta.acc_std),
        noise_std=float(train.noise_std if train.noise_std is not None else cfg.model.noise_std),
        noise_decay=float(train.noise_decay),
        lr_init=float(train.lr_init),
        lr_final=float(train.lr_final),
        lr_decay_start=int(train.lr_decay_start),
        lr_decay_end=int(train.lr_decay_end),
    )


def build_loggers(cfg: DictConfig, run_dir: Path) -> list:
    """CSV (always, unless logger=none) and wandb (offline unless logger.offline=false)."""
    loggers = []
    if cfg.logger.csv:
        from lightning.pytorch.loggers import CSVLogger

        # A new version_<k> folder per (re)start, so resuming never overwrites an earlier curve.
        loggers.append(CSVLogger(save_dir=str(run_dir), name="csv"))
    if cfg.logger.wandb:
        from lightning.pytorch.loggers import WandbLogger

        loggers.append(
            WandbLogger(
                project=cfg.logger.project,
                group=cfg.logger.group,
                name=run_dir.name if cfg.logger.group is None else f"{cfg.logger.group}/{run_dir.name}",
                save_dir=str(run_dir),
                offline=bool(cfg.logger.offline),
                config=OmegaConf.to_container(cfg, resolve=True),
            )
        )
    return loggers


def resolve_checkpoint(path: str | None) -> str | None:
    """A .ckpt file, or a previous run directory (its ``checkpoints/last.ckpt``)."""
    if path is None:
        return None
    p = Path(path)
    if p.is_dir():
        p = p / "checkpoints" / "last.ckpt"
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no checkpoint to resume from")
    return str(p)


def build_trainer(cfg: DictConfig, run_dir: Path, loggers: list) -> L.Trainer:
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
    )
    permanent = ModelCheckpoint(
        dirpath=ckpt_dir / "permanent",
        filename="step{step:08d}",
        auto_insert_metric_name=False,
        every_n_train_steps=int(train.permanent_every_n_steps),
        save_top_k=-1,
    )
    return L.Trainer(
        **OmegaConf.to_container(cfg.trainer, resolve=True),
        max_steps=int(train.max_steps),
        max_time=train.max_time,
        val_check_interval=int(train.val_every_n_steps),
        check_val_every_n_epoch=None,
        num_sanity_val_steps=0,
        log_every_n_steps=int(train.log_every_n_steps),
        logger=loggers if loggers else False,
        callbacks=[running, permanent, TQDMProgressBar(refresh_rate=50)],
        default_root_dir=str(run_dir),
        enable_model_summary=True,
    )


def run_training(cfg: DictConfig) -> float | None:
    """Train, then evaluate on the test split; returns the test rollout MSE (None when evaluation is off)."""
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    L.seed_everything(int(cfg.seed), workers=True)
    torch.set_float32_matmul_precision("high")
    ensure_dataset(cfg.data)
    datamodule = ParticleDataModule(
        cfg.data.root,
        history=int(cfg.model.history),
        batch_size=int(cfg.data.batch_size),
        num_workers=int(cfg.data.num_workers),
        val_max_trajectories=cfg.train.val_max_trajectories,
        test_max_trajectories=cfg.evaluate.max_trajectories,
    )
    system = build_system(cfg, datamodule)
    loggers = build_loggers(cfg, run_dir)
    result: float | None = None
    try:
        trainer = build_trainer(cfg, run_dir, loggers)
        log.info("Model: %s, %d parameters", cfg.model.name, system.simulator.num_parameters())
        trainer.fit(system, datamodule=datamodule, ckpt_path=resolve_checkpoint(cfg.train.ckpt_path))
        if cfg.evaluate.enabled and trainer.is_global_zero:
            from gnsx.evaluate import evaluate_run

            summary = evaluate_run(cfg, system.simulator, datamodule, run_dir, loggers)
            result = summary["rollout_mse"]
    finally:
        if cfg.logger.wandb:
            import wandb

            wandb.finish()
    return result


def write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically (temp file, then rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2))
    os.replace(tmp, path)
