"""Trained simulators from checkpoints: where a run keeps its weights, loading them, and naming the model.

``train.py`` saves Lightning checkpoints of :class:`~gnsx.system.GNSSystem` (``<run dir>/checkpoints/``);
every hyperparameter is saved with them, so a checkpoint alone rebuilds its model.
"""

from __future__ import annotations

from pathlib import Path

import torch

from gnsx.model.simulator import LearnedSimulator
from gnsx.system import GNSSystem


def checkpoint_path(path: str | Path) -> Path:
    """A ``.ckpt`` file, or a run directory's ``checkpoints/last.ckpt``.

    Raises:
        FileNotFoundError: naming the path that holds no checkpoint.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "checkpoints" / "last.ckpt"
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no checkpoint here (give a .ckpt file or a run directory)")
    return p


def load_simulator(path: str | Path, device: str | torch.device = "cpu") -> LearnedSimulator:
    """The trained :class:`LearnedSimulator` of a checkpoint (or run directory), eval mode, on ``device``."""

    system = GNSSystem.load_from_checkpoint(checkpoint_path(path), map_location="cpu")
    return system.simulator.to(device).eval()


def model_label(simulator: LearnedSimulator) -> str:
    """``"simplified GNS 64/5"``, ``"original GNS 128/10"`` or ``"GNS <latent>/<steps>"``, from its config."""
    cfg = simulator.config
    size = f"{cfg['latent_size']}/{cfg['mp_steps']}"
    if cfg["history"] == 1 and cfg["type_encoding"] == "scalar" and not cfg["edge_residual"]:
        return f"simplified GNS {size}"
    if cfg["history"] == 5 and cfg["type_encoding"] == "embedding" and cfg["edge_residual"]:
        return f"original GNS {size}"
    return f"GNS {size}"


def slug(label: str) -> str:
    """A folder name for a label (letters, digits, ``-``, ``_``)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label).strip("_") or "model"
