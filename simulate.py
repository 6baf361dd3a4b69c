"""Roll a trained simulator out on a scene you describe (water blocks with velocity, ramps), configured by
Hydra (conf/simulate.yaml).

    python simulate.py checkpoint=outputs/2026-11-26/13-00-00 scene=scenes/dam_break.yaml
    python simulate.py checkpoint=pretrained/small/model.ckpt scene=scenes/two_blocks.yaml mpm=true
    python simulate.py checkpoint=... 'scene={blocks:[{lower:[0.2,0.1],upper:[0.4,0.4],velocity:[1,0]}]}'

Writes into the Hydra run directory (outputs/simulate/<date>/<time>/): scene.yaml, rollout.npz, rollout.gif,
strip.png and, with mpm=true, comparison.gif (MPM | model), rollout.pkl (DeepMind's format) and errors.json.
See gnsx/evaluation/scene_rollout.py for the scene format and how the model's first frames are made. Bad input (a scene
with an unknown key, a model of another preset than ``preset``, a negative seed, a file that is not a
checkpoint) prints one line and exits 2; ``--debug`` shows the traceback. The rollout is held by the scene's
walls and ramps (gnsx/model/boundary.py); one that still blows up (NaN, or a particle beyond the blow-up speed
of gnsx/evaluation/health.py) prints a warning, writes its files and exits 3.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from gnsx.core.cli import hydra_task, run_hydra
from gnsx.core.errors import ConfigError
from gnsx.training.config_checks import check_simulate_config

#: Exit status of a rollout that blew up (NaN, or a particle beyond the blow-up speed; gnsx/evaluation/health.py).
EXIT_BLEW_UP = 3


@hydra.main(version_base="1.3", config_path="conf", config_name="simulate")
@hydra_task
def main(cfg: DictConfig) -> None:
    check_simulate_config(cfg)
    # Imported here: a bad override fails in a second, without loading torch.
    from gnsx.core.threads import apply_threads
    from gnsx.evaluation.scene_rollout import load_scene, simulate_to_folder
    from gnsx.model.checkpoint import (
        check_fits,
        checkpoint_path,
        load_simulator,
        model_label,
        trained_data_radius,
    )
    from gnsx.mpm.presets import PRESETS, get_preset
    from gnsx.mpm.scenes import Scene
    from gnsx.rules.rules import Rules

    try:
        preset = get_preset(cfg.preset)
    except KeyError as error:
        raise ConfigError(f"preset={cfg.preset}", str(error.args[0])) from None
    if isinstance(cfg.scene, DictConfig):
        scene = Scene.from_dict(OmegaConf.to_container(cfg.scene, resolve=True), where="scene (override)")
    else:
        scene = load_scene(cfg.scene)
    checkpoint = checkpoint_path(cfg.checkpoint)
    simulator = load_simulator(checkpoint, cfg.device)
    check_simulate_config(cfg, input_frames=simulator.input_frames)
    if not cfg.get("allow_mismatch", False):
        bounds = [list(preset.bounds)] * 2
        data_radius = trained_data_radius(simulator)
        trained = [
            p.name for p in PRESETS.values() if math.isclose(p.default_connectivity_radius, data_radius)
        ]
        hint = f"; use preset={trained[0]}" if trained else "; use the preset it was trained on"
        check_fits(simulator, str(checkpoint), bounds, preset.default_connectivity_radius, 2,
                   f"preset={preset.name}", hint + " (or allow_mismatch=true to run it anyway)")  # fmt: skip
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    apply_threads(cfg.threads)
    summary = simulate_to_folder(
        simulator,
        scene,
        preset,
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
        rules=Rules.from_config(cfg, "rules"),
    )
    print(json.dumps({k: v for k, v in summary.items() if k != "files"}, indent=2))
    for name, path in summary["files"].items():
        print(f"{name:>16}: {path}")
    if summary["blew_up"]:
        # The files are written (to look at what went wrong), but a script must not take this for a result.
        sys.exit(EXIT_BLEW_UP)


if __name__ == "__main__":
    run_hydra(main)
