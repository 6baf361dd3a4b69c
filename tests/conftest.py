"""Shared fixtures: a tiny real MPM dataset, generated once per test session."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A few short trajectories of the small preset (real MPM, seconds to generate).

    Returns the dataset folder (gnsx format with metadata.json).
    """
    from gnsx.mpm.generate import generate_dataset
    from gnsx.mpm.presets import get_preset

    preset = get_preset("small", num_frames=30, trajectories={"train": 3, "valid": 1, "test": 1})
    root = tmp_path_factory.mktemp("data") / "tiny"
    return generate_dataset(root, preset, seed=0, workers=1, progress=False)
