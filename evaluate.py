"""Evaluate trained simulators on a dataset split, configured by Hydra (conf/evaluate.yaml).

    python evaluate.py checkpoint=outputs/2026-11-26/13-00-00              # a run directory or a .ckpt
    python evaluate.py checkpoint='[runs/original,runs/simplified]' render.formats='[gif,mp4]'   # figure 8
    python evaluate.py checkpoint=pretrained/small/model.ckpt split=valid save.deepmind=true

Everything lands in the Hydra run directory (outputs/evaluate/<date>/<time>/): results.json, per model
trajectories.csv, per_frame.csv and rollouts/*.npz, and comparison.gif + strip.png. The returned value (the
first model's rollout MSE) is what Hydra sweepers optimise. Bad input (a file that is not a checkpoint, a
model unlike the data, NaN in the data, a bad override) prints one line and exits 2; ``--debug`` shows the
traceback.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, ListConfig, OmegaConf

from gnsx.core.cli import hydra_task, run_hydra
from gnsx.training.config_checks import check_evaluate_config


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
@hydra_task
def main(cfg: DictConfig) -> float:
    check_evaluate_config(cfg)
    # Imported here: a bad override fails in a second, without loading torch.
    from gnsx.core.threads import apply_threads
    from gnsx.evaluation.evaluate import evaluate_checkpoints
    from gnsx.rules.rules import Rules
    from gnsx.training.loggers import build_loggers

    run_dir = Path(HydraConfig.get().runtime.output_dir)
    apply_threads(cfg.threads)
    checkpoints = list(cfg.checkpoint) if isinstance(cfg.checkpoint, ListConfig) else [cfg.checkpoint]
    loggers = build_loggers(cfg, run_dir)
    try:
        results = evaluate_checkpoints(
            checkpoints,
            cfg.data.root,
            run_dir,
            split=cfg.split,
            labels=OmegaConf.to_container(cfg.labels) if cfg.labels is not None else None,
            max_trajectories=cfg.max_trajectories,
            device=cfg.device,
            **OmegaConf.to_container(cfg.metrics),
            save_rollouts=cfg.save.rollouts,
            deepmind=cfg.save.deepmind,
            render=cfg.render.enabled,
            render_trajectory=cfg.render.trajectory,
            render_formats=list(cfg.render.formats),
            frame_stride=cfg.render.frame_stride,
            fps=cfg.render.fps,
            strip_every=cfg.render.strip_every,
            strip_count=cfg.render.strip_count,
            loggers=loggers,
            allow_mismatch=bool(OmegaConf.select(cfg, "allow_mismatch", default=False)),
            rules=Rules.from_config(cfg, "rules"),
        )
        for logger in loggers:
            logger.finalize("success")
    finally:
        if cfg.logger.wandb:
            import wandb

            wandb.finish()
    print(f"Results: {run_dir / 'results.json'}")
    return results["models"][0]["summary"]["rollout_mse"]


if __name__ == "__main__":
    run_hydra(main)
