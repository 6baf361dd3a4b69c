"""Checks of a composed Hydra config before anything runs: a bad setting fails at once, as one line naming
the override (``train.max_steps=-1: expected an integer >= 1``), before a run directory fills up, a logger
starts or a previous run's ``results.json`` is touched.

One function per entry point: :func:`check_train_config`, :func:`check_evaluate_config`,
:func:`check_simulate_config`. They read keys with :func:`OmegaConf.select`, so a config saved by an older
gnsx (without the newer keys) still passes.
"""

from __future__ import annotations

import re
from typing import Any

from omegaconf import DictConfig, OmegaConf

from gnsx.core.cli import check_int, check_number
from gnsx.core.errors import ConfigError

#: ``trainer.precision`` values: gnsx's ``auto`` (:mod:`gnsx.training.precision`) and Lightning's own.
TRAINER_PRECISIONS = (
    "auto",
    "32-true",
    "32",
    "bf16-mixed",
    "16-mixed",
    "bf16-true",
    "16-true",
    "64-true",
    "64",
)
#: Largest seed Lightning's ``seed_everything`` takes (numpy's limit).
MAX_SEED = 2**32 - 1


def _get(cfg: DictConfig, key: str, default: Any = None) -> Any:
    return OmegaConf.select(cfg, key, default=default)


def check_threads(cfg: DictConfig, key: str = "threads") -> None:
    """``threads``: null (torch's default), ``auto`` (:func:`gnsx.core.threads.choose_threads`) or an int >= 1."""
    value = _get(cfg, key)
    if value is None or value == "auto":
        return
    if isinstance(value, str) and not value.strip().lstrip("-").isdigit():
        raise ConfigError(f"{key}={value}", "expected null, auto or an integer >= 1")
    check_int(value, key, minimum=1)


def check_seed(cfg: DictConfig, key: str = "seed") -> int:
    seed = check_int(_get(cfg, key), key, minimum=0)
    if seed > MAX_SEED:
        raise ConfigError(f"{key}={seed}", f"must be <= {MAX_SEED}")
    return seed


def check_train_config(cfg: DictConfig) -> None:
    """Every setting of ``train.py`` that can be wrong on its own (the dataset and a resumed checkpoint are
    checked against each other later, :mod:`gnsx.training.inputs`).

    Raises:
        ConfigError: the first bad setting, e.g. ``train.max_steps=0: must be >= 1``.
    """
    check_seed(cfg)
    check_threads(cfg)
    check_threads(cfg, "sweep.torch_threads")
    for key in ("max_steps", "val_every_n_steps", "checkpoint_every_n_steps", "permanent_every_n_steps",
                "log_every_n_steps", "calibration_steps"):  # fmt: skip
        check_int(_get(cfg, f"train.{key}"), f"train.{key}", minimum=1)
    for key in ("lr_decay_start", "lr_decay_end"):
        check_int(_get(cfg, f"train.{key}"), f"train.{key}", minimum=0)
    check_int(_get(cfg, "train.max_skipped_steps", 0), "train.max_skipped_steps", minimum=0)
    check_int(_get(cfg, "train.pushforward_steps", 0), "train.pushforward_steps", minimum=0)
    check_int(_get(cfg, "train.unroll_steps", 1), "train.unroll_steps", minimum=1)
    check_int(_get(cfg, "train.lr_warmup_steps", 0), "train.lr_warmup_steps", minimum=0)
    check_int(_get(cfg, "train.val_max_trajectories"), "train.val_max_trajectories", 1, allow_none=True)
    for key in ("lr_init", "lr_final", "huber_delta"):
        check_number(_get(cfg, f"train.{key}"), f"train.{key}", positive=True)
    check_number(_get(cfg, "train.noise_decay"), "train.noise_decay", positive=True, allow_none=True)
    if _get(cfg, "train.noise_decay") is None and _get(cfg, "model.noise_decay") is None:
        raise ConfigError("train.noise_decay=null", "and the model config sets no noise_decay: set one")
    schedule = _get(cfg, "train.lr_schedule", "exponential")
    from gnsx.training.schedule import LR_SCHEDULES

    if schedule not in LR_SCHEDULES:
        raise ConfigError(f"train.lr_schedule={schedule}", f"expected one of {', '.join(LR_SCHEDULES)}")
    matmul = _get(cfg, "trainer.float32_matmul_precision", "highest")
    if matmul not in ("highest", "high", "medium"):
        raise ConfigError(f"trainer.float32_matmul_precision={matmul}", "expected highest, high or medium")
    noise = check_number(_get(cfg, "train.noise_std"), "train.noise_std", allow_none=True)
    if noise is not None and noise < 0:
        raise ConfigError(f"train.noise_std={noise}", "must be >= 0 (or null: the model's)")
    mirror = _get(cfg, "train.mirror", False)
    if not isinstance(mirror, bool):
        raise ConfigError(f"train.mirror={mirror}", "must be true or false")
    correction = check_number(_get(cfg, "train.noise_correction", 0.0), "train.noise_correction")
    if not 0.0 <= correction <= 1.0:
        raise ConfigError(f"train.noise_correction={correction}", "must be in [0, 1]")
    for key in ("gradient_clip_val", "checkpoint_every_minutes", "val_every_minutes"):
        check_number(_get(cfg, f"train.{key}"), f"train.{key}", positive=True, allow_none=True)
    if _get(cfg, "train.curve_every_n_steps") is not None:
        check_int(_get(cfg, "train.curve_every_n_steps"), "train.curve_every_n_steps", minimum=1)
    from gnsx.training.system import LOSSES

    if _get(cfg, "train.loss") not in LOSSES:
        raise ConfigError(f"train.loss={_get(cfg, 'train.loss')}", f"expected one of {', '.join(LOSSES)}")
    max_time = _get(cfg, "train.max_time")
    if max_time is not None:
        from gnsx.training.time_budget import parse_duration

        try:
            seconds = parse_duration(max_time)
        except ValueError:
            raise ConfigError(f"train.max_time={max_time}", "expected DD:HH:MM:SS, seconds or null") from None
        if not seconds > 0:
            raise ConfigError(f"train.max_time={max_time}", "must be a positive duration (or null)")
    counts = _get(cfg, "train.budget_counts_validation", True)
    if not isinstance(counts, bool):
        raise ConfigError(f"train.budget_counts_validation={counts}", "must be true or false")
    safety = check_number(_get(cfg, "train.budget_safety", 0.9), "train.budget_safety", positive=True)
    if safety > 1:
        raise ConfigError(f"train.budget_safety={safety}", "must be in (0, 1]")
    if not counts and (max_time is None or not _get(cfg, "train.fit_to_max_time", False)):
        raise ConfigError("train.budget_counts_validation=false",
                          "needs train.max_time and train.fit_to_max_time=true (the budget it changes)")  # fmt: skip
    for key in ("val_every_minutes", "curve_every_n_steps"):
        if _get(cfg, f"train.{key}") is not None and "ddp" in str(_get(cfg, "trainer.strategy", "")):
            raise ConfigError(f"train.{key}", "validates in one process: not with a DDP strategy")
    precision = str(_get(cfg, "trainer.precision", "32-true"))
    if precision not in TRAINER_PRECISIONS:
        raise ConfigError(
            f"trainer.precision={precision}", f"expected one of {', '.join(TRAINER_PRECISIONS)}"
        )
    check_int(_get(cfg, "data.batch_size"), "data.batch_size", minimum=1)
    check_int(_get(cfg, "data.num_workers"), "data.num_workers", minimum=0)
    check_int(_get(cfg, "evaluate.max_trajectories"), "evaluate.max_trajectories", 1, allow_none=True)
    check_rules(cfg, "rules")
    for key in ("latent_size", "mp_steps", "mlp_hidden_size", "history"):
        check_int(_get(cfg, f"model.{key}"), f"model.{key}", minimum=1)
    check_number(_get(cfg, "model.radius"), "model.radius", positive=True, allow_none=True)
    check_model_config(cfg)


#: ``LearnedSimulator: <key> must ...``: the model's own argument checks.
_MODEL_ERROR = re.compile(r"^LearnedSimulator: (\w+) (.*)$", re.S)


def check_model_config(cfg: DictConfig) -> None:
    """Build the configured model once on made-up data facts: its own argument checks (``type_encoding``,
    ``wall_clip``, ``neighbor_search``, unknown keys, ...) then fail here, named as overrides."""
    from gnsx.model.simulator import LearnedSimulator

    arch = OmegaConf.to_container(cfg.model, resolve=True)
    from gnsx.model.registry import MODEL_CONFIG_EXTRAS

    for key in MODEL_CONFIG_EXTRAS:  # config keys that are not model arguments
        arch.pop(key, None)
    facts = {"dim": 2, "bounds": [[0.0, 1.0], [0.0, 1.0]], "radius": 0.1, "vel_mean": [0.0, 0.0],
             "vel_std": [1.0, 1.0], "acc_mean": [0.0, 0.0], "acc_std": [1.0, 1.0]}  # fmt: skip
    try:
        LearnedSimulator(**facts, **arch)
    except TypeError as error:
        raise ConfigError("model", f"not a model setting ({error})") from None
    except ValueError as error:
        match = _MODEL_ERROR.match(str(error))
        if match and match.group(1) in arch:
            key = match.group(1)
            raise ConfigError(f"model.{key}={arch[key]}", match.group(2)) from None
        raise ConfigError("model", str(error)) from None


def check_evaluate_config(cfg: DictConfig) -> None:
    """``evaluate.py``'s settings (checkpoints and data are checked when read)."""
    check_threads(cfg)
    check_int(_get(cfg, "max_trajectories"), "max_trajectories", minimum=1, allow_none=True)
    check_int(_get(cfg, "render.trajectory"), "render.trajectory", minimum=0)
    for key in ("render.frame_stride", "render.fps", "render.strip_every", "render.strip_count"):
        check_int(_get(cfg, key), key, minimum=1)
    check_int(_get(cfg, "metrics.emd_every"), "metrics.emd_every", minimum=0)
    check_int(_get(cfg, "metrics.onestep_stride"), "metrics.onestep_stride", minimum=1)
    check_rules(cfg, "rules")


def check_rules(cfg: DictConfig, key: str) -> None:
    """The rollout rules block at ``key`` (:class:`gnsx.rules.rules.Rules`): known rules, booleans."""
    from gnsx.rules.rules import Rules

    Rules.from_config(cfg, key)


def check_simulate_config(cfg: DictConfig, input_frames: int | None = None) -> None:
    """``simulate.py``'s settings; ``input_frames`` (the model's) bounds ``num_frames`` from below."""
    check_threads(cfg)
    check_seed(cfg)
    minimum = (input_frames or 1) + 1
    check_int(_get(cfg, "num_frames"), "num_frames", minimum=minimum, allow_none=True)
    for key in ("render.frame_stride", "render.fps", "render.strip_every", "render.strip_count"):
        check_int(_get(cfg, key), key, minimum=1)
    check_int(_get(cfg, "emd_every"), "emd_every", minimum=0)
    check_rules(cfg, "rules")
