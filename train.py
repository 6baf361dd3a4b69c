"""Train a GNS with Lightning, configured by Hydra (configs in conf/).

    python train.py                                  # simplified GNS on the small preset (~15 min on CPU)
    python train.py model=original train.max_steps=2000
    python train.py train.ckpt_path=outputs/2026-11-26/13-00-00    # resume a run (its checkpoints/last.ckpt)
    python train.py -m model.latent_size=32,64 model.mp_steps=3,5  # Hydra multirun sweep

A run writes everything into its Hydra run directory: checkpoints/, csv/, wandb/, results.json and the test
rollout animation. The returned value (test rollout MSE) is what Hydra sweepers optimise. Bad input (an
unknown override, a bad value, a missing or bad dataset or checkpoint) prints one line and exits 2;
``--debug`` (or GNSX_DEBUG=1) shows the traceback (docs/robustness.md).
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from gnsx.core.cli import hydra_task, run_hydra


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
@hydra_task
def main(cfg: DictConfig) -> float | None:
    # Imported here: a bad override fails in a second, without torch.
    from gnsx.training.run import run_training

    return run_training(cfg)


if __name__ == "__main__":
    run_hydra(main)
