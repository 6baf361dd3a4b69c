"""Shared fixtures: a tiny real MPM dataset, generated once per test session."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def one_thread():
    """Torch on one thread for the test: results must not depend on the core count, and on a shared 2-core
    machine two OpenMP threads spin-wait for each other while small graphs gain nothing from a second.
    A module applies it to all its tests with ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


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
