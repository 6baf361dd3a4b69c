"""Roll a trained simulator out on a scene you describe (water blocks with velocity, ramps), configured by
Hydra (conf/simulate.yaml).

    python simulate.py checkpoint=outputs/2026-11-26/13-00-00 scene=scenes/dam_break.yaml
    python simulate.py checkpoint=pretrained/small/model.ckpt scene=scenes/two_blocks.yaml mpm=true
    python simulate.py checkpoint=... 'scene={blocks:[{lower:[0.2,0.1],upper:[0.4,0.4],velocity:[1,0]}]}'

Writes into the Hydra run directory (outputs/simulate/<date>/<time>/): scene.yaml, rollout.npz, rollout.gif,
strip.png and, with mpm=true, comparison.gif (MPM | model), rollout.pkl (DeepMind's format) and errors.json.
See gnsx/scene_rollout.py for the scene format and how the model's first frames are made.
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from gnsx.checkpoints import checkpoint_path, load_simulator, model_label
from gnsx.mpm.presets import get_preset
from gnsx.mpm.scenes import Scene
from gnsx.scene_rollout import load_scene, simulate_to_folder


@hydra.main(version_base="1.3", config_path="conf", config_name="simulate")
def main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    if isinstance(cfg.scene, DictConfig):
        scene = Scene.from_dict(OmegaConf.to_container(cfg.scene, resolve=True), where="scene (override)")
    else:
        scene = load_scene(cfg.scene)
    checkpoint = checkpoint_path(cfg.checkpoint)
    simulator = load_simulator(checkpoint, cfg.device)
    summary = simulate_to_folder(
        simulator,
        scene,
        get_preset(cfg.preset),
        run_dir,
        num_frames=cfg.num_frames,
        seed=int(cfg.seed),
        ground_truth=bool(cfg.mpm),
        label=cfg.label or model_label(simulator),
        provenance={"checkpoint": str(checkpoint), "preset": cfg.preset},
        formats=tuple(cfg.render.formats),
        frame_stride=int(cfg.render.frame_stride),
        fps=int(cfg.render.fps),
        strip_every=int(cfg.render.strip_every),
        strip_count=int(cfg.render.strip_count),
        emd_every=int(cfg.emd_every),
    )
    print(json.dumps({k: v for k, v in summary.items() if k != "files"}, indent=2))
    for name, path in summary["files"].items():
        print(f"{name:>16}: {path}")


if __name__ == "__main__":
    main()
