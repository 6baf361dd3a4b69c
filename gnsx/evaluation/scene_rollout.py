"""New initial conditions: describe a scene, get a learned rollout (and, on request, the MPM ground truth).

A scene file is YAML in :meth:`gnsx.mpm.scenes.Scene.to_dict`'s layout (metres and m/s; walls at the
preset's bounds, 0.1 and 0.9 for the shipped presets)::

    blocks:                       # water blocks, each moving as one at the start
      - lower: [0.15, 0.12]       # lower-left corner
        upper: [0.40, 0.50]       # upper-right corner
        velocity: [1.0, 0.0]      # m/s
    ramps:                        # static segments [[x0, y0], [x1, y1]]
      - [[0.5, 0.3], [0.8, 0.2]]

The water particles are placed exactly as the MPM generator places them (the preset's spacing, jitter and ramp
clearance, :func:`gnsx.mpm.scenes.water_particles` with ``np.random.default_rng(seed)``), so with the ground
truth on both rollouts hold the same particles in the same order.

History: the model reads ``H + 1`` positions (2 for the simplified GNS, 6 for the original). A scene has one
state and a velocity, so without ground truth the earlier frames are made by moving back at constant
velocity, ``p_k = p_0 - (H - k) v dt`` for ``k = 0 .. H`` (frame ``H`` is the scene's state; gravity is
ignored over these few milliseconds). With the ground truth (``ground_truth=True``), the model starts from the
MPM's first ``H + 1`` frames instead, so both rollouts start from the same states and their error measures the
model alone.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import yaml

from gnsx.core.errors import DataError
from gnsx.data.metadata import Metadata
from gnsx.evaluation.health import rollout_health, warn_if_unhealthy
from gnsx.model.simulator import LearnedSimulator
from gnsx.mpm.generate import check_scene, initial_state
from gnsx.mpm.presets import Preset
from gnsx.mpm.scenes import Scene
from gnsx.rules.rollout import rollout_with_rules
from gnsx.rules.rules import Rules


def load_scene(path: str | os.PathLike) -> Scene:
    """Read a scene YAML file (see the module docstring).

    Raises:
        DataError: missing file, invalid YAML, or a malformed field, naming the file and the field.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise DataError(str(path), "scene file not found") from None
    except yaml.YAMLError as e:
        raise DataError(str(path), f"invalid YAML: {e}") from None
    return Scene.from_dict(data if data is not None else {}, where=str(path))


def save_scene(scene: Scene, path: str | os.PathLike) -> Path:
    """Write ``scene`` as YAML that :func:`load_scene` reads back."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(scene.to_dict(), sort_keys=False, default_flow_style=None))
    return path


def constant_velocity_history(
    position: np.ndarray, velocity: np.ndarray, dt: float, history: int
) -> np.ndarray:
    """``[H + 1, N, D]`` frames ``p_k = p_0 - (H - k) v dt``, oldest first; the last is ``position``.

    Args:
        position: ``[N, D]`` (m); velocity: ``[N, D]`` (m/s); dt: seconds per frame; history: H.
    """
    steps_back = np.arange(history, -1, -1, dtype=np.float64)[:, None, None]  # H, H-1, ..., 0
    return (position[None] - steps_back * velocity[None] * dt).astype(np.float32)


@dataclass
class SceneRollout:
    """A learned rollout of a scene, with the MPM ground truth when it was asked for.

    Attributes:
        predicted: ``[T, N, 2]`` float32 positions, the first ``input_frames`` given, the rest predicted.
        particle_type: ``[N]`` int64.
        input_frames: ``H + 1``.
        ground_truth: ``[T, N, 2]`` float32 MPM positions, or None.
        history_source: ``"mpm"`` (the first frames are the MPM's) or ``"constant_velocity"``.
    """

    predicted: np.ndarray
    particle_type: np.ndarray
    input_frames: int
    ground_truth: np.ndarray | None
    history_source: str


def scene_metadata(simulator: LearnedSimulator, preset: Preset, num_frames: int) -> Metadata:
    """Metadata for a scene rollout: the model's bounds, radius and statistics, the preset's frame dt."""
    cfg = simulator.config
    return Metadata(
        bounds=cfg["bounds"],
        sequence_length=num_frames - 1,
        default_connectivity_radius=cfg["radius"],
        dim=cfg["dim"],
        dt=preset.frame_dt,
        vel_mean=cfg["vel_mean"],
        vel_std=cfg["vel_std"],
        acc_mean=cfg["acc_mean"],
        acc_std=cfg["acc_std"],
        extra={"gnsx": {"preset": preset.name, "preset_settings": preset.to_dict()}},
    )


@torch.inference_mode()
def rollout_scene(
    simulator: LearnedSimulator,
    scene: Scene,
    preset: Preset,
    num_frames: int | None = None,
    seed: int = 0,
    ground_truth: bool = False,
    progress: bool = False,
    constrain: bool = True,
    rules: Rules | None = None,
) -> SceneRollout:
    """Roll the model out on a scene for ``num_frames`` frames (inputs included).

    Args:
        simulator: the trained model (rolled out on its device).
        scene: water blocks and ramps.
        preset: the dataset recipe the model was trained on (particle spacing, ramp spacing, frame dt, walls
            and, for the ground truth, the solver).
        num_frames: frames in all (default ``preset.num_frames``).
        seed: water particle placement seed (the same particles as the MPM run with this seed).
        ground_truth: also simulate the scene with the MPM solver and start the model from its first frames.
        constrain: hold the rollout by the scene's walls and ramps (:class:`gnsx.model.boundary.Boundary`);
            ``False``: the raw model.
        rules: the simulator's rules on the rollout (:class:`gnsx.rules.rules.Rules`; None: none, the raw
            network held by the walls and ramps).
    """
    check_scene(scene, preset)
    num_frames = preset.num_frames if num_frames is None else int(num_frames)
    frames = simulator.input_frames
    if num_frames <= frames:
        raise ValueError(f"num_frames must exceed the model's {frames} input frames, got {num_frames}")
    truth = None
    if ground_truth:
        from gnsx.mpm.generate import simulate_scene

        trajectory = simulate_scene(scene, replace(preset, num_frames=num_frames), seed=seed)
        truth, particle_type = trajectory.position, trajectory.particle_type
        initial = truth[:frames]
        source = "mpm"
    else:
        position, velocity, particle_type = initial_state(scene, preset, seed)
        initial = constant_velocity_history(position, velocity, preset.frame_dt, simulator.history)
        source = "constant_velocity"
    device = simulator.acc_std.device
    window = torch.from_numpy(np.ascontiguousarray(initial)).to(device).transpose(0, 1)  # [N, H+1, 2]
    types = torch.from_numpy(particle_type).to(device)
    steps = num_frames - frames
    predicted = (
        rollout_with_rules(simulator, window, types, steps, rules, progress=progress, constrain=constrain)
        .cpu()
        .numpy()
    )
    return SceneRollout(
        predicted=np.concatenate([initial, predicted]).astype(np.float32),
        particle_type=particle_type,
        input_frames=frames,
        ground_truth=truth,
        history_source=source,
    )


def simulate_to_folder(
    simulator: LearnedSimulator,
    scene: Scene,
    preset: Preset,
    out_dir: str | os.PathLike,
    num_frames: int | None = None,
    seed: int = 0,
    ground_truth: bool = False,
    label: str = "GNS",
    provenance: dict | None = None,
    formats: tuple[str, ...] = ("gif",),
    frame_stride: int = 2,
    fps: int = 25,
    strip_every: int = 100,
    strip_count: int = 7,
    emd_every: int = 10,
    rules: Rules | None = None,
) -> dict:
    """:func:`rollout_scene` (with ``rules``; None: the raw network), then write everything a user looks at
    into ``out_dir``.

    Files: ``scene.yaml`` (the scene as run), ``rollout.npz`` (gnsx rollout file, :mod:`gnsx.data.rollout_io`;
    with the ground truth it holds ``ground_truth`` too), ``rollout.<gif|mp4>`` (the model alone, coloured by
    speed), ``strip.png`` (frames 0, ``strip_every``, ...). With ``ground_truth``: ``comparison.<gif|mp4>``
    (MPM | model side by side), ``rollout.pkl`` (DeepMind's rollout format) and ``errors.json``
    (:func:`gnsx.evaluation.scoring.rollout_errors`: position MSE, EMD, kinetic-energy error, neighbour ratio, ...).

    Returns:
        ``{"out_dir", "particles", "frames", "history_source", "health": {...}, "blew_up", "files": {...},
        "errors": {...} (with ground truth)}``; ``health`` is :func:`gnsx.evaluation.health.rollout_health` (a warning
        line goes to stderr when the rollout blew up).
    """
    import json

    from gnsx.data.rollout_io import Rollout, export_deepmind, save_rollout
    from gnsx.evaluation.render import render_rollouts, save_animation, save_strip
    from gnsx.evaluation.scoring import json_ready, rollout_errors

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rules = rules or Rules()
    result = rollout_scene(
        simulator, scene, preset, num_frames, seed, ground_truth, progress=True, rules=rules
    )
    num_frames = result.predicted.shape[0]
    metadata = scene_metadata(simulator, preset, num_frames)
    health = rollout_health(result.predicted, result.particle_type, metadata, first_frame=result.input_frames)
    warn_if_unhealthy(health, "the rollout")
    info = {"model": label, "scene": scene.to_dict(), "seed": seed, "history_source": result.history_source,
            "rules": rules.to_dict()}  # fmt: skip
    item = Rollout(
        predicted=result.predicted,
        particle_type=result.particle_type,
        input_frames=result.input_frames,
        ground_truth=result.ground_truth,
        metadata=metadata.to_dict() | {"rollout": info | (provenance or {})},
    )
    files = {
        "scene": str(save_scene(scene, out / "scene.yaml")),
        "rollout": str(save_rollout(out / "rollout.npz", item)),
    }
    bounds = metadata.bounds_array()
    panels = [result.predicted] if result.ground_truth is None else [result.ground_truth, result.predicted]
    titles = [label] if result.ground_truth is None else ["MPM ground truth", label]
    alone = render_rollouts(
        [result.predicted], result.particle_type, bounds, [label], frame_stride=frame_stride
    )
    for fmt in formats:
        files[f"animation_{fmt}"] = str(save_animation(alone, out / f"rollout.{fmt}", fps=fps))
    files["strip"] = str(
        save_strip(panels, result.particle_type, bounds, out / "strip.png", titles, strip_every, strip_count)
    )
    summary = {
        "out_dir": str(out),
        "particles": int(result.predicted.shape[1]),
        "frames": int(num_frames),
        "history_source": result.history_source,
        "health": health,
        "blew_up": health["blew_up"],
        "rules": rules.to_dict(),
    }
    if result.ground_truth is not None:
        both = render_rollouts(panels, result.particle_type, bounds, titles, frame_stride=frame_stride)
        for fmt in formats:
            files[f"comparison_{fmt}"] = str(save_animation(both, out / f"comparison.{fmt}", fps=fps))
        files["deepmind"] = str(export_deepmind(out / "rollout.pkl", item))
        errors, _ = rollout_errors(
            result.predicted,
            result.ground_truth,
            result.particle_type,
            result.input_frames,
            metadata,
            emd_every,
        )
        summary["errors"] = errors
        (out / "errors.json").write_text(json.dumps(json_ready(errors | {"history_source": "mpm"}), indent=2))
        files["errors"] = str(out / "errors.json")
    summary["files"] = files
    return summary
