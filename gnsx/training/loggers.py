"""A run's loggers: CSV and wandb (grouped by sweep), and at the end the job's results put into its wandb
run's summary before it finishes (exit code 1 for a failed job)."""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from gnsx.training.job import one_line

log = logging.getLogger("gnsx")


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


def finish_wandb(results: dict) -> None:
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
