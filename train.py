"""Train a GNS with Lightning, configured by Hydra (configs in conf/).

    python train.py                                  # simplified GNS on the small preset (~15 min on CPU)
    python train.py model=original train.max_steps=2000
    python train.py train.ckpt_path=outputs/2026-11-26/13-00-00    # resume a run (its checkpoints/last.ckpt)
    python train.py -m model.latent_size=32,64 model.mp_steps=3,5  # Hydra multirun sweep

A run writes everything into its Hydra run directory: checkpoints/, csv/, wandb/, results.json and the test
rollout animation. The returned value (test rollout MSE) is what Hydra sweepers optimise.
"""

from __future__ import annotations

import logging

import hydra
from omegaconf import DictConfig

from gnsx.pipeline import run_training

log = logging.getLogger(__name__)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> float | None:
    return run_training(cfg)


if __name__ == "__main__":
    main()
