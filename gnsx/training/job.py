"""One job of ``train.py`` as its ``results.json`` records it: who the job is (its sweep, number and
overrides), the one-line reason of a failure (divergence included), the record read back, and whether a
resumable sweep finished the job before.

The record's schema is :mod:`gnsx.evaluation.report`'s; :mod:`gnsx.training.run` writes it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from gnsx.core.machine import cpu_name
from gnsx.training.numerics import Diverged

#: The test metrics every results.json carries (None when the evaluation did not produce one).
TEST_KEYS = ("rollout_mse", "onestep_mse", "emd", "baseline_mse", "ms_per_frame", "peak_memory_mb")


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
        # The CPU this process trains on (timings and hours depend on it; a resumed run records each machine
        # it ran on in "cpus").
        "cpu": cpu_name(),
    }


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


def read_results(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def finished_result(results_path: Path) -> float | None:
    """The test rollout MSE of a job that finished in this folder before, or None: what a resumable sweep
    (``sweep.resume``) skips. Finished: ``status`` ok and a finite test rollout MSE in its results.json, or
    no test score at all when the job ran without its test evaluation (``evaluate.enabled=false``, the
    learning study's arms: their scores are the validation curve's); then NaN."""
    try:
        results = json.loads(results_path.read_text())
    except (OSError, ValueError):
        return None
    if results.get("status") != "ok":
        return None
    if results.get("evaluated") is False:
        return float("nan")
    try:
        value = float(results["test"]["rollout_mse"])
    except (KeyError, TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def run_dir_of(ckpt_path: str | None) -> Path | None:
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
