"""Helpers of the study tests (no tests here): synthetic rollout files and a tiny built study."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.data.rollout_io import Rollout, save_rollout
from gnsx.study.build import RenderSettings, build_study

ORIGINAL = "original GNS 128/10"
SIMPLIFIED = "simplified GNS 64/5"
BOUNDS = [[0.1, 0.9], [0.1, 0.9]]
#: Tiny animations: fast to render and to serve.
TINY_RENDER = RenderSettings(frames=8, frame_stride=2, fps=10, size=64)


def scene_positions(index: int, frames: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """A water block falling on a static ramp: ``[T, 36, 2]`` positions and ``[36]`` types; each scene's
    block starts elsewhere."""
    rng = np.random.default_rng(index)
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2) * 0.03
    water = grid + rng.uniform(0.3, 0.5, 2)
    ramp = np.stack([np.linspace(0.2, 0.8, 6), np.full(6, 0.2)], 1)
    t = np.arange(frames)[:, None, None]
    fall = np.array([0.0, -1.0]) * 0.002 * t**2
    positions = np.concatenate([water[None] + fall, np.broadcast_to(ramp, (frames, 6, 2))], axis=1)
    types = np.array([WATER_PARTICLE_ID] * len(water) + [KINEMATIC_PARTICLE_ID] * 6)
    return positions.astype(np.float32), types


def write_rollouts(folder: Path, scenes: int = 4, methods=(ORIGINAL, SIMPLIFIED), frames: int = 10) -> Path:
    """Rollout files as ``evaluate.py`` writes them: ``folder/<method>/rollouts/test_<i>.npz``, each model's
    rollout a slightly different fall from the same first frame, with the ground truth."""
    for k, method in enumerate(methods):
        for i in range(scenes):
            truth, types = scene_positions(i, frames)
            predicted = truth.copy()
            predicted[1:, types == WATER_PARTICLE_ID, 0] += 0.004 * (k + 1) * np.arange(1, frames)[:, None]
            meta = {"bounds": BOUNDS, "rollout": {"model": method, "split": "test", "trajectory": i}}
            rollout = Rollout(predicted, types, input_frames=2, ground_truth=truth, metadata=meta)
            save_rollout(folder / method.split()[0] / "rollouts" / f"test_{i:04d}.npz", rollout)
    return folder


def tiny_study(folder: Path, scenes: int = 3, pairs_per_group: int = 2, **kwargs) -> Path:
    """A study of MPM, the original and the simplified GNS built from :func:`write_rollouts`; its folder."""
    rollouts = write_rollouts(folder / "rollouts", scenes)
    kwargs.setdefault("settings", TINY_RENDER)
    build_study([rollouts], folder / "study", pairs_per_group=pairs_per_group, **kwargs)
    return folder / "study"
