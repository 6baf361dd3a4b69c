"""What ``train.py`` does with its Hydra config: data, model, loggers, Lightning fit, test evaluation,
pictures, and the bookkeeping of one job: training time and speed, ``results.json``, failure handling, wandb
grouping.

This is the one module that reads the composed config; everything it calls takes typed arguments.

Every run writes ``results.json`` into its run directory (schema in :mod:`gnsx.evaluation.report`): ``"status":
"running"`` when it starts (with its pid, host and a heartbeat, :mod:`gnsx.core.runstate`), ``"ok"`` or
``"failed"`` (with a one-line ``"error"``) when it ends, ``"interrupted"`` when a later run or reader finds
it killed. Bad input is refused before anything is written (:func:`check_inputs`). A job whose training
diverges (too many NaN/Inf steps in a row, :mod:`gnsx.training.numerics`) or whose test rollout becomes NaN/Inf
fails with an error starting ``"diverged:"``. In a Hydra
multirun a failed job returns NaN instead of raising, so the other jobs of the sweep still run (Hydra's
launchers stop the whole sweep at the first exception); a single run re-raises after recording. Sweep configs
(``sweeps/*.yaml``) add a ``sweep`` block: its name groups the wandb runs, and it asks for one rendered frame
of the first test rollout and a speed/memory benchmark at WaterRamps size for each job.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from lightning.fabric.utilities.rank_zero import rank_zero_only
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from omegaconf import DictConfig, OmegaConf, open_dict

from gnsx.core import runstate
from gnsx.core.atomic import write_json
from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.core.errors import ConfigError, GnsxError, RunFailed
from gnsx.core.threads import apply_threads
from gnsx.data.datamodule import ParticleDataModule
from gnsx.data.metadata import Metadata
from gnsx.evaluation.evaluate import evaluate_run
from gnsx.evaluation.scoring import gravity_per_frame
from gnsx.model.checkpoint import check_resume, checkpoint_path, read_checkpoint
from gnsx.model.registry import MODEL_CONFIG_EXTRAS
from gnsx.model.simulator import LearnedSimulator
from gnsx.training.config_checks import check_train_config
from gnsx.training.numerics import Diverged
from gnsx.training.precision import resolve_precision
from gnsx.training.resilience import (
    AtomicCheckpointIO,
    Heartbeat,
    remove_stale_temporaries,
    wall_clock_checkpoint,
)
from gnsx.training.system import GNSSystem, samples_of
from gnsx.training.time_budget import TimeBudget, TrainingClock, parse_duration

log = logging.getLogger("gnsx")

#: Config keys of ``model/*.yaml`` that are not LearnedSimulator architecture arguments.
_NON_ARCH_KEYS = MODEL_CONFIG_EXTRAS
#: The test metrics every results.json carries (None when the evaluation did not produce one).
TEST_KEYS = ("rollout_mse", "onestep_mse", "emd", "baseline_mse", "ms_per_frame", "peak_memory_mb")


def architecture(model_cfg: DictConfig) -> dict[str, Any]:
    """LearnedSimulator keyword arguments from a ``model/*.yaml`` config."""
    arch = OmegaConf.to_container(model_cfg, resolve=True)
    for key in _NON_ARCH_KEYS:
        arch.pop(key, None)
    arch["wall_clip"] = tuple(arch["wall_clip"])
    return arch


def model_arguments(model_cfg: DictConfig, meta: Metadata) -> dict[str, Any]:
    """:func:`architecture` plus what the data decides: the pairwise decoder's gravity (the baseline's
    ``g dt^2`` from the data's ``dt``, :func:`gnsx.evaluation.scoring.gravity_per_frame`) unless the config sets one."""
    model = architecture(model_cfg)
    if model.get("decoder") == "pairwise" and model.get("gravity") is None:
        model["gravity"] = gravity_per_frame(meta).tolist()
    # The rules' length scale is the data's, whatever radius the graph uses (LearnedSimulator.rules_radius).
    model["data_radius"] = float(meta.default_connectivity_radius)
    return model


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


def apply_matmul_precision(cfg: DictConfig) -> str:
    """``torch.set_float32_matmul_precision`` from ``trainer.float32_matmul_precision`` (default
    ``"highest"``: true fp32 products; ``"high"`` would let CUDA use TF32). Returns the setting."""
    precision = str(OmegaConf.select(cfg, "trainer.float32_matmul_precision", default="highest"))
    if precision not in ("highest", "high", "medium"):
        raise ConfigError(f"trainer.float32_matmul_precision={precision}", "must be highest, high or medium")
    torch.set_float32_matmul_precision(precision)
    return precision


def combine_std(std: list[float], noise_std: float) -> list[float]:
    """DeepMind's ``_combine_std``: ``sqrt(std^2 + noise_std^2)`` per dimension (data units)."""
    return [math.sqrt(float(s) ** 2 + float(noise_std) ** 2) for s in std]


def training_noise(cfg: DictConfig) -> dict[str, Any]:
    """The training noise's std and decay and where each comes from: the model config (``model.noise_std``,
    ``model.noise_decay``: the paper's recipe for the simplified model, DeepMind's for the original) unless the
    train config sets one explicitly (``train.noise_std``/``train.noise_decay`` not null), which is then an
    override, logged and recorded in results.json (``model_config.noise_std_source``)."""
    out: dict[str, Any] = {}
    for key, default in (("noise_std", None), ("noise_decay", 1.0)):
        override = OmegaConf.select(cfg.train, key, default=None)
        model_value = OmegaConf.select(cfg.model, key, default=default)
        if override is not None:
            out[key], out[f"{key}_source"] = (
                float(override),
                f"train.{key} (overrides model.{key}={model_value})",
            )
        elif model_value is not None:
            out[key], out[f"{key}_source"] = float(model_value), f"model.{key}"
        else:
            raise ConfigError(f"model.{key}", f"not set, and train.{key} is null: set one of them")
    return out


#: Where the connection radius comes from when ``model.radius`` is null.
DATA_RADIUS = "the dataset's default_connectivity_radius"


def connectivity_radius(cfg: DictConfig, meta: Metadata) -> tuple[float, str]:
    """The connection radius the model's graph uses and where it comes from (:func:`radius_source`).

    ``model.radius`` when set; else ``model.radius_scale`` (default 1) times the dataset's
    ``default_connectivity_radius``. Why a scale: a radius is a data fact (in particle spacings), so a model
    whose radius differs from DeepMind's says so relative to the data. The simplified model's 0.020 / 0.015
    is the paper's 0.020 at WaterRamps, whose default radius is 0.015 (its sections 6.2.1 and 9.0.1), and so
    0.0467 on the small preset (default 0.035).
    """
    if cfg.model.radius is not None:
        return float(cfg.model.radius), radius_source(cfg)
    return radius_scale(cfg) * float(meta.default_connectivity_radius), radius_source(cfg)


def radius_scale(cfg: DictConfig) -> float:
    """``model.radius_scale`` (1 when absent or null)."""
    scale = float(OmegaConf.select(cfg.model, "radius_scale", default=None) or 1.0)
    if not scale > 0:
        raise ConfigError(f"model.radius_scale={scale}", "must be > 0")
    return scale


def radius_source(cfg: DictConfig) -> str:
    """Where the model's radius comes from, as results.json's ``model_config.radius_source`` records it."""
    if cfg.model.radius is not None:
        return "model.radius"
    scale = radius_scale(cfg)
    return DATA_RADIUS if scale == 1.0 else f"model.radius_scale={scale:g} x {DATA_RADIUS}"


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


def build_loggers(cfg: DictConfig, run_dir: Path, name: str | None = None, group: str | None = None) -> list:
    """CSV (always, unless logger=none) and wandb (offline unless logger.offline=false).

    Args:
        name: the wandb run's name (default: the run directory's name); sweeps pass the job's overrides.
        group: the wandb group (default: ``logger.group``); sweeps pass the sweep's name.
    """
    loggers = []
    if cfg.logger.csv:
        from lightning.pytorch.loggers import CSVLogger

        # A new version_<k> folder per (re)start, so resuming never overwrites an earlier curve.
        loggers.append(CSVLogger(save_dir=str(run_dir), name="csv"))
    if cfg.logger.wandb:
        from lightning.pytorch.loggers import WandbLogger

        group = group if group is not None else cfg.logger.group
        if name is None:
            name = run_dir.name if group is None else f"{group}/{run_dir.name}"
        wandb_logger = WandbLogger(
            project=cfg.logger.project,
            group=group,
            name=name,
            save_dir=str(run_dir),
            offline=bool(cfg.logger.offline),
            config=OmegaConf.to_container(cfg, resolve=True),
        )
        # Start the run now rather than at the first logged metric, so that a job failing before it trains
        # still has its wandb run (finished with exit code 1).
        _ = wandb_logger.experiment
        loggers.append(wandb_logger)
    return loggers


def resolve_checkpoint(path: str | None, name: str = "train.ckpt_path") -> str | None:
    """A .ckpt file, or a previous run directory (its ``checkpoints/last.ckpt``); None stays None.

    Raises:
        CheckpointError: naming the override ``name`` and what is missing.
    """
    return None if path is None else str(checkpoint_path(path, name=name))


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


# -- one job: timing, divergence, results --------------------------------------------------------------------
# Diverged lives in gnsx.training.numerics (the system raises it after too many non-finite steps in a row); callers
# that caught it from this module still can.


def one_line(error: BaseException, limit: int = 300) -> str:
    """``"Type: first line of the message"`` (``"diverged: ..."`` for :class:`Diverged`), at most ``limit``
    characters: the reason a failed job shows in its results.json and in the sweep report."""
    message = str(error).strip().splitlines()[0] if str(error).strip() else ""
    text = message if isinstance(error, Diverged) else f"{type(error).__name__}: {message}".rstrip(": ")
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _swept_keys(hydra_cfg: DictConfig) -> set[str]:
    """Config keys that take several values in this multirun (``a,b``, ``range(...)``, ``choice(...)``): those
    of the sweep config's ``hydra.sweeper.params`` and of the command line (which Hydra saved in the sweep's
    ``multirun.yaml`` before launching). Single values only pin a setting for every job."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = OmegaConf.select(hydra_cfg, "sweeper.params", default=None) or {}
    overrides = [f"{key}={value}" for key, value in params.items()]
    saved = Path(hydra_cfg.sweep.dir) / "multirun.yaml"
    if hydra_cfg.mode == RunMode.MULTIRUN and saved.is_file():
        overrides += list(OmegaConf.select(OmegaConf.load(saved), "hydra.overrides.task", default=None) or [])
    parsed = OverridesParser.create().parse_overrides(overrides)
    return {o.get_key_element() for o in parsed if o.is_sweep_override()}


def job_identity(cfg: DictConfig, hydra_cfg: DictConfig) -> dict[str, Any]:
    """Who this job is: its sweep, number and overrides (all of them, and the swept ones)."""
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    overrides = list(hydra_cfg.overrides.task)
    swept_keys = _swept_keys(hydra_cfg)
    swept = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") in swept_keys]
    return {
        "sweep": OmegaConf.select(cfg, "sweep.name", default=None),
        "job": int(hydra_cfg.job.num) if multirun else None,
        "multirun": multirun,
        "overrides": overrides,
        "swept": swept,
        # The wandb run name: the swept values, else (a single run) every override.
        "name": ",".join(swept) or hydra_cfg.job.override_dirname or Path(hydra_cfg.runtime.output_dir).name,
    }


def model_summary(cfg: DictConfig, system: GNSSystem) -> dict[str, Any]:
    """The model's name, architecture, effective radius (the dataset's when ``model.radius`` is null), training
    noise and normalisation, each setting with where it came from. Values are the built system's; sources are
    the config's (:func:`connectivity_radius`, :func:`training_noise`)."""
    arch = architecture(cfg.model)
    arch["wall_clip"] = list(arch["wall_clip"])
    noise = training_noise(cfg)
    return {"name": str(cfg.model.name), **arch, "radius": float(system.hparams.radius),
            "radius_source": radius_source(cfg),
            "noise_std": float(system.hparams.noise_std),
            "noise_std_source": noise["noise_std_source"], "noise_decay": float(system.hparams.noise_decay),
            "noise_decay_source": noise["noise_decay_source"],
            "widen_stats_by_noise": bool(OmegaConf.select(cfg.model, "widen_stats_by_noise", default=False)),
            "acc_std": list(system.hparams.acc_std), "vel_std": list(system.hparams.vel_std)}  # fmt: skip


def as_divergence(error: Exception) -> Exception:
    """Positions that became NaN/Inf (a diverging rollout, or noisy training inputs) fail inside the neighbour
    search (scipy: "data must be finite") before any error is computed: report them as :class:`Diverged`."""
    if isinstance(error, ValueError) and "must be finite" in str(error):
        return Diverged(f"positions became NaN/Inf ({one_line(error)})")
    return error


def check_finite_rollout(summary: dict) -> None:
    """Raise :class:`Diverged` when the test rollout error is NaN or infinite."""
    value = summary.get("rollout_mse")
    if value is None or not math.isfinite(float(value)):
        raise Diverged(f"test rollout MSE is {value}")


def data_spacing(metadata: Metadata, position: np.ndarray, particle_type: np.ndarray) -> float:
    """Typical distance between neighbouring fluid particles (data units): the generator's particle spacing
    when the metadata records it (gnsx presets), else the median nearest-neighbour distance of the dynamic
    particles of ``position [N, D]`` (e.g. the first frame of a test trajectory)."""
    settings = metadata.extra.get("gnsx", {}).get("preset_settings", {})
    if settings.get("particle_spacing"):
        return float(settings["particle_spacing"])
    from scipy.spatial import cKDTree

    fluid = position[particle_type != KINEMATIC_PARTICLE_ID]
    distances, _ = cKDTree(fluid).query(fluid, k=2)
    return float(np.median(distances[:, 1]))


def benchmark_at_scale(
    simulator: LearnedSimulator,
    metadata: Metadata,
    spacing: float,
    num_particles: int,
    device: torch.device,
    warmup: int,
    repeats: int,
) -> dict[str, Any]:
    """Inference speed and peak memory of one step (graph build included, :func:`gnsx.perf.benchmark.
    measure_inference`) on a packed scene of ``num_particles`` (WaterRamps' largest scenes have ~2.3k) at the
    data's particle spacing, so each particle has as many neighbours as in training.

    When that many particles do not fit in the data's domain at its spacing (the small preset's particles are
    coarse), the domain is enlarged by steps of 25%: speed and memory do not depend on where the walls are.

    Returns :func:`~gnsx.evaluation.timing.measure_inference`'s dict plus ``spacing`` and ``domain_scale``.
    """
    from gnsx.evaluation.timing import measure_inference, packed_scene

    bounds = metadata.bounds_array().astype(np.float64)  # [D, 2]
    extent = bounds[:, 1] - bounds[:, 0]
    for attempt in range(8):
        scale = 1.25**attempt
        try:
            grown = np.stack([bounds[:, 0], bounds[:, 0] + scale * extent], axis=1)
            sequence, particle_type = packed_scene(num_particles, spacing, grown, simulator.history)
            break
        except ValueError:
            if attempt == 7:
                raise
    measured = measure_inference(
        simulator.to(device), sequence, particle_type, warmup=warmup, repeats=repeats
    )
    return {**measured, "spacing": spacing, "domain_scale": scale}


def render_test_frame(
    simulator: LearnedSimulator, trajectory: dict, metadata: Metadata, frame: int, out_dir: Path
) -> dict[str, str | int]:
    """Roll the model out on one test trajectory up to ``frame``; save that frame, predicted and true, as PNG.

    Args:
        trajectory: ``position [T, N, D]`` and ``particle_type [N]`` tensors (ground truth).
        frame: the frame to draw, clamped to the trajectory (the paper's figure 9 shows one frame per model).
    Returns:
        ``{"frame", "frame_png", "frame_truth_png"}`` (paths of 256 x 256 images, particles coloured by speed
        on the ground truth's colour scale, so every model of a sweep is drawn alike).
    """
    import imageio.v3 as iio

    from gnsx.evaluation.render import render_frame, speeds
    from gnsx.model.rollout import rollout

    position, particle_type = trajectory["position"], trajectory["particle_type"]
    frames = simulator.input_frames
    frame = int(min(max(frame, frames), position.shape[0] - 1))
    simulator = simulator.cpu().eval()
    predicted = rollout(simulator, position[:frames].transpose(0, 1), particle_type.cpu(), frame - frames + 1)
    predicted = torch.cat([position[:frames], predicted]).numpy()  # [frame + 1, N, D]
    truth = position[: frame + 1].numpy()
    types = particle_type.numpy()
    true_speed = speeds(truth)
    scale = float(np.percentile(true_speed[:, types != KINEMATIC_PARTICLE_ID], 99)) or 1.0
    bounds = metadata.bounds_array()
    paths = {"frame": frame}
    for key, positions in (("frame_png", predicted), ("frame_truth_png", truth)):
        image = render_frame(positions[frame], types, speeds(positions[frame - 1 : frame + 1])[1], bounds,
                             speed_scale=scale)  # fmt: skip
        path = out_dir / f"{key.removesuffix('_png')}_{frame:04d}.png"
        iio.imwrite(path, image)
        paths[key] = str(path)
    return paths


def _read_results(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _finish_wandb(results: dict) -> None:
    """Put the job's results into its wandb run's summary and finish it (exit code 1 for a failed job)."""
    import wandb

    run = wandb.run
    if run is not None:
        try:
            run.config.update({"job": {k: results.get(k) for k in ("sweep", "job", "overrides", "swept")}},
                              allow_val_change=True)  # fmt: skip
            flat = {k: v for k, v in results.items() if isinstance(v, (int, float, str, bool)) or v is None}
            for section in ("test", "bench"):
                for k, v in (results.get(section) or {}).items():
                    if isinstance(v, (int, float, str)):
                        flat[f"{section}/{k}"] = v
            run.summary.update(flat)
            if results.get("frame_png") and Path(results["frame_png"]).is_file():
                run.log({"frame": wandb.Image(results["frame_png"], caption=results.get("name"))})
        except Exception as error:  # a logging problem must not hide the job's own result or failure
            log.warning("wandb: could not record the results (%s)", one_line(error))
    wandb.finish(exit_code=0 if results.get("status") == "ok" else 1)


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


def local_processes(cfg: DictConfig) -> int:
    """Training processes of this node that share its CPU cores (DDP ranks; 1 otherwise)."""
    devices = OmegaConf.select(cfg, "trainer.devices", default=1)
    strategy = str(OmegaConf.select(cfg, "trainer.strategy", default="auto"))
    return int(devices) if isinstance(devices, int) and "ddp" in strategy else 1


def schedule_summary(cfg: DictConfig, trainer: L.Trainer, clock: TrainingClock, system: GNSSystem) -> dict:
    """How many steps the run got against its schedule (also logged): ``global_step``, ``scheduled_steps``
    (``train.max_steps``), ``fitted_steps`` (the time budget's, or None), ``skipped_steps`` (NaN/Inf) and
    ``samples_seen`` (training samples the final weights have seen, a fine-tune's start included)."""
    planned = getattr(clock, "planned_steps", None) or int(cfg.train.max_steps)
    fitted = getattr(clock, "fitted", None)
    done = int(trainer.global_step)
    summary = {"global_step": done, "scheduled_steps": planned, "fitted_steps": fitted,
               "skipped_steps": int(system.skipped.total),
               "samples_seen": int(system.samples_seen)}  # fmt: skip
    rate = clock.summary().get("steps_per_s")
    fitted_text = f"; the time budget fitted the schedule to {fitted:,}" if fitted else ""
    log.info(
        "Steps: %s of %s scheduled (%.0f%%%s), %s steps/s on %d thread(s); %d skipped for a NaN/Inf loss or "
        "gradient",
        f"{done:,}", f"{planned:,}", 100.0 * done / planned, fitted_text,
        f"{rate:.1f}" if rate else "?", torch.get_num_threads(), summary["skipped_steps"],
    )  # fmt: skip
    return summary


def _train_and_evaluate(
    cfg: DictConfig, run_dir: Path, record: dict, loggers: list, datamodule: ParticleDataModule
) -> float | None:
    """Train, then evaluate on the test split; fills ``record`` and ``loggers`` as it goes (they survive a
    failure). Returns the test rollout MSE (None when evaluation is off)."""
    # Parallel sweep jobs on one machine (the joblib launcher) set sweep.torch_threads: n_jobs x threads
    # should not exceed the cores. Otherwise `threads` (auto: gnsx.core.threads).
    threads = OmegaConf.select(cfg, "sweep.torch_threads", default=None) or cfg.get("threads")
    record["threads"] = apply_threads(threads, processes=local_processes(cfg))
    L.seed_everything(int(cfg.seed), workers=True)
    record["float32_matmul_precision"] = apply_matmul_precision(cfg)
    loggers.extend(
        build_loggers(cfg, run_dir, name=record["name"], group=cfg.logger.group or record["sweep"])
    )
    system = build_system(cfg, datamodule)
    record["model_config"] = model_summary(cfg, system)
    record["parameters"] = system.simulator.num_parameters()
    clock = training_clock(cfg)
    callbacks = [clock]
    val_every_minutes = OmegaConf.select(cfg.train, "val_every_minutes", default=None)
    curve_every_n_steps = OmegaConf.select(cfg.train, "curve_every_n_steps", default=None)
    if val_every_minutes is not None or curve_every_n_steps is not None:
        from gnsx.training.curves import CurveValidation

        every_s = None if val_every_minutes is None else 60.0 * float(val_every_minutes)
        every_n_steps = None if every_s is not None else int(curve_every_n_steps)
        record["curve_every"] = {"minutes": val_every_minutes, "steps": every_n_steps}
        callbacks.append(CurveValidation(clock, every_s, run_dir / "curve.jsonl", every_n_steps=every_n_steps,
                                         loss_every_n_steps=int(cfg.train.log_every_n_steps)))  # fmt: skip
        record["curve"] = str(run_dir / "curve.jsonl")

    def beat(fields: dict) -> None:
        record.update(fields)
        write_json(run_dir / "results.json", record)

    trainer = build_trainer(cfg, run_dir, loggers, callbacks=[*callbacks, Heartbeat(beat)])
    record["precision"] = str(trainer.precision)
    log.info("Model: %s, %d parameters", cfg.model.name, record["parameters"])
    try:
        trainer.fit(system, datamodule=datamodule, ckpt_path=resolve_checkpoint(cfg.train.ckpt_path))
        # The final weights into last.ckpt: Lightning's last.ckpt follows the step and wall-clock
        # checkpoints, and a run whose fitted step count is not a multiple of checkpoint_every_n_steps ends
        # between two of them (the equal-budget runs of 2026-12-06 left last.ckpt 435 and 630 steps before
        # their end). The test evaluation below scores these weights; export and evaluate.py read last.ckpt.
        trainer.save_checkpoint(run_dir / "checkpoints" / "last.ckpt")
    finally:
        record.update(clock.summary())
        record.update(schedule_summary(cfg, trainer, clock, system))
    record["evaluated"] = bool(cfg.evaluate.enabled)
    if not (cfg.evaluate.enabled and trainer.is_global_zero):
        return None
    # The benchmark runs where the model trained (Lightning moves it back to the CPU after fit).
    device = trainer.strategy.root_device
    summary = evaluate_run(cfg, system.simulator, datamodule, run_dir, loggers)
    check_finite_rollout(summary)
    frame = OmegaConf.select(cfg, "sweep.frame", default=None)
    bench = OmegaConf.select(cfg, "sweep.bench", default=None)
    metadata = datamodule.metadata
    if frame is not None or bench is not None:
        first = datamodule.test_set[0]
    if frame is not None:
        record.update(render_test_frame(system.simulator, first, metadata, int(frame), run_dir))
    if bench is not None:
        spacing = bench.get("spacing") or data_spacing(
            metadata, first["position"][0].numpy(), first["particle_type"].numpy()
        )
        try:
            record["bench"] = benchmark_at_scale(
                system.simulator, metadata, float(spacing), int(bench.num_particles), device,
                warmup=int(bench.get("warmup", 3)), repeats=int(bench.get("repeats", 20)),
            )  # fmt: skip
        except Exception as error:  # e.g. out of memory at WaterRamps size: a result, not a failed job
            record["bench"] = {"error": one_line(error)}
            log.warning("Benchmark at %d particles failed: %s", int(bench.num_particles), one_line(error))
    return float(summary["rollout_mse"])


def run_training(cfg: DictConfig) -> float | None:
    """Train, then evaluate on the test split; returns the test rollout MSE (None when evaluation is off).

    Checks every input first (:func:`check_inputs`): bad input raises a one-line
    :class:`~gnsx.core.errors.GnsxError` before anything is written (a multirun job records it and returns
    NaN). Then writes ``results.json`` (see the module docstring), "running" with the process's liveness
    (:mod:`gnsx.core.runstate`) and a heartbeat while it trains; a killed earlier run in this directory, and the
    run this one resumes from, are marked "interrupted". In a multirun a failed job returns NaN; a single run
    re-raises (``gnsx.core.cli`` prints bad input and divergence as one line).
    """
    start = time.perf_counter()
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    identity = job_identity(cfg, hydra_cfg)
    results_path = run_dir / "results.json"
    if OmegaConf.select(cfg, "sweep.resume", default=False):
        done = finished_result(results_path)
        if done is not None:
            score = "no test evaluation" if math.isnan(done) else f"test rollout MSE {done:.4g}"
            log.info("%s: finished earlier (%s): skipped (sweep.resume)", run_dir, score)
            return done
        if (run_dir / "checkpoints" / "last.ckpt").is_file() and cfg.train.ckpt_path is None:
            log.info("%s: resuming from its checkpoints/last.ckpt (sweep.resume)", run_dir)
            with open_dict(cfg):
                cfg.train.ckpt_path = str(run_dir)
    writer = rank_zero_only.rank == 0  # DDP: one process writes the results
    bad_input: GnsxError | None = None
    datamodule: ParticleDataModule | None = None
    try:
        datamodule = check_inputs(cfg)
    except GnsxError as error:
        if not identity["multirun"]:
            raise  # nothing written: an earlier results.json in this folder stays as it was
        bad_input = error  # a sweep job records it below, like any failure
    run_dir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"status": "running", "error": None, **identity, "run_dir": str(run_dir)}
    if writer:
        previous = runstate.mark_interrupted(results_path)
        if previous is not None:
            log.warning("%s: the previous run here was %s", results_path, previous["error"])
            record["previous"] = {key: previous.get(key) for key in ("status", "error", "global_step")}
        resumed = _run_dir_of(cfg.train.ckpt_path)
        if resumed is not None and resumed.resolve() != run_dir.resolve():
            runstate.mark_interrupted(resumed / "results.json", resumed_in=str(run_dir))
        record.update(runstate.liveness())
        write_json(results_path, record)
    loggers: list = []
    result: float | None = None
    try:
        if bad_input is not None:
            # The sweep's wandb group still shows the job (finished with exit code 1).
            loggers.extend(build_loggers(cfg, run_dir, name=identity["name"],
                                         group=cfg.logger.group or identity["sweep"]))  # fmt: skip
            raise bad_input
        result = _train_and_evaluate(cfg, run_dir, record, loggers, datamodule)
        record["status"] = "ok"
    except Exception as error:  # a sweep job records any failure and lets the other jobs run
        reason = as_divergence(error)
        record["status"], record["error"] = "failed", one_line(reason)
        expected = isinstance(reason, GnsxError | RunFailed)  # one line (gnsx.core.cli), no traceback
        if identity["multirun"]:
            log.error("Job %s failed: %s", identity["name"], record["error"], exc_info=not expected)
        elif not expected:
            log.error("Job %s failed: %s", identity["name"], record["error"])  # the traceback follows
        if not identity["multirun"]:
            if reason is not error:
                raise reason from error
            raise
        result = float("nan")
    finally:
        if record["status"] == "running":  # KeyboardInterrupt, SystemExit, SIGTERM
            record["status"], record["error"] = runstate.INTERRUPTED, "interrupted (stopped by a signal)"
        record["job_wall_s"] = time.perf_counter() - start
        # evaluate_run wrote the test summary (and its per-trajectory rows) into results.json: keep them.
        results = {**_read_results(results_path), **record}
        results["test"] = {key: None for key in TEST_KEYS} | (results.get("test") or {})
        results.setdefault("bench", None)
        if writer:
            write_json(results_path, results)
        if cfg.logger.wandb:
            _finish_wandb(results)
    return result


def finished_result(results_path: Path) -> float | None:
    """The test rollout MSE of a job that finished in this folder before, or None: what a resumable sweep
    (``sweep.resume``) skips. Finished: ``status`` ok and a finite test rollout MSE in its results.json, or
    no test score at all when the job ran without its test evaluation (``evaluate.enabled=false``, the
    learning study's arms: their scores are the validation curve's); then NaN."""
    try:
        results = json.loads(results_path.read_text())
        value = (results.get("test") or {}).get("rollout_mse")
        value = float("nan") if value is None and results.get("evaluated") is False else float(value)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if results.get("status") != "ok":
        return None
    return value if math.isfinite(value) or results.get("evaluated") is False else None


def _run_dir_of(ckpt_path: str | None) -> Path | None:
    """The run directory a ``train.ckpt_path`` belongs to (a run dir, or ``<run>/checkpoints/x.ckpt``)."""
    if ckpt_path is None:
        return None
    path = Path(ckpt_path)
    if path.is_dir():
        return path
    for parent in path.parents:
        if parent.name == "checkpoints":
            return parent.parent
    return None
