"""Everything a run reads, checked before it writes anything: the settings, the checkpoints it resumes from or
starts with, and the dataset (generated with gnsx's MPM solver on first use when the config allows it).

Bad input raises a one-line :class:`~gnsx.core.errors.GnsxError` (:mod:`gnsx.core.cli` prints it).
"""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from gnsx.core.errors import ConfigError
from gnsx.data.datamodule import ParticleDataModule
from gnsx.model.checkpoint import check_resume, checkpoint_path, read_checkpoint
from gnsx.training.config_checks import check_train_config
from gnsx.training.model_settings import connectivity_radius, model_arguments

log = logging.getLogger("gnsx")


def resolve_checkpoint(path: str | None, name: str = "train.ckpt_path") -> str | None:
    """A .ckpt file, or a previous run directory (its ``checkpoints/last.ckpt``); None stays None.

    Raises:
        CheckpointError: naming the override ``name`` and what is missing.
    """
    return None if path is None else str(checkpoint_path(path, name=name))


def ensure_dataset(data_cfg: DictConfig) -> Path:
    """The dataset folder, generated with gnsx's MPM solver on first use when the config allows it."""
    root = Path(data_cfg.root)
    if (root / "metadata.json").exists():
        return root
    if not data_cfg.generate_if_missing:
        raise ConfigError(
            f"data.root={root}",
            f"no dataset here ({root / 'metadata.json'} missing); generate one with "
            f"`python -m gnsx.data generate --preset {data_cfg.preset} --out {root}` or convert yours with "
            f"`python -m gnsx.data convert SRC {root}`",
        )
    from gnsx.mpm.generate import generate_dataset
    from gnsx.mpm.presets import get_preset

    counts = OmegaConf.select(data_cfg, "trajectories", default=None)
    fields = OmegaConf.select(data_cfg, "preset_overrides", default=None)
    overrides = {} if fields is None else dict(OmegaConf.to_container(fields, resolve=True))
    if counts is not None:
        overrides["trajectories"] = dict(OmegaConf.to_container(counts, resolve=True))
    # Lists from YAML become the preset's (min, max) tuples.
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    try:
        preset = get_preset(data_cfg.preset, **overrides)
    except KeyError as e:  # the preset's name
        raise ConfigError(f"data.preset={data_cfg.preset}", str(e.args[0])) from None
    except ValueError as e:  # a field or value of the overrides
        raise ConfigError("data.preset_overrides", str(e)) from None
    log.info("Generating the '%s' preset %s into %s (first use)", preset.name, preset.trajectories, root)
    generate_dataset(root, preset, seed=data_cfg.generate_seed)
    return root


def check_inputs(cfg: DictConfig) -> ParticleDataModule:
    """Everything a run reads, checked before it writes anything: the settings, the dataset (generated first
    when missing and ``data.generate_if_missing``), every position of the splits it uses (NaN/Inf named by
    file, trajectory and frame), and the checkpoint it resumes from (one of another model config is
    refused, naming both configs).

    Returns:
        the data module of the checked dataset.
    Raises:
        GnsxError: one line naming the override, file, trajectory and frame.
    """
    check_train_config(cfg)
    resume = resolve_checkpoint(cfg.train.ckpt_path)
    init = resolve_checkpoint(OmegaConf.select(cfg.train, "init_weights", default=None), "train.init_weights")
    if resume is not None and init is not None:
        raise ConfigError(
            f"train.init_weights={cfg.train.init_weights}",
            "cannot be combined with train.ckpt_path (a resumed run has its own weights); set one of them",
        )
    for path in (resume, init):
        if path is not None:
            read_checkpoint(path)  # not a checkpoint, or truncated: said before minutes of data generation
    ensure_dataset(cfg.data)
    datamodule = ParticleDataModule(
        cfg.data.root,
        history=int(cfg.model.history),
        batch_size=int(cfg.data.batch_size),
        num_workers=int(cfg.data.num_workers),
        val_max_trajectories=cfg.train.val_max_trajectories,
        test_max_trajectories=cfg.evaluate.max_trajectories,
        pushforward_steps=int(OmegaConf.select(cfg.train, "pushforward_steps", default=0)),
        unroll_steps=int(OmegaConf.select(cfg.train, "unroll_steps", default=1)),
    )
    datamodule.check(["train", "valid", *(["test"] if cfg.evaluate.enabled else [])])
    if resume is not None or init is not None:
        meta = datamodule.metadata
        radius, _ = connectivity_radius(cfg, meta)
        model = model_arguments(cfg.model, meta)
        for path, name in ((resume, "train.ckpt_path"), (init, "train.init_weights")):
            if path is not None:
                check_resume(path, model, meta.dim, float(radius), name=name)
    return datamodule
