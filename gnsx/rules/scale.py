"""The rules' scales: the data's connectivity radius, whatever radius the model's graph uses, and the data's
gravity, whatever decoder the model has.

The rules model the data's physics (free flight's reach is the MPM grid's, the rest hold's neighbourhood and
the density kernel are the water's particle spacing), so their lengths are in units of the dataset's
connectivity radius. A simulator records that radius with its data's other statistics (``data_radius`` in
:class:`gnsx.model.simulator.LearnedSimulator`'s config, like ``bounds`` and ``vel_std``), because a model
may be trained with a graph radius of its own (``model.radius=0.05`` on data of 0.035).
"""

from __future__ import annotations

import torch

from gnsx.model.checkpoint import trained_data_radius
from gnsx.model.simulator import LearnedSimulator


def rules_radius(simulator: LearnedSimulator) -> float:
    """The dataset's connectivity radius (data units) that the simulator was trained on; the model's own
    radius for checkpoints saved before ``data_radius`` was recorded (they all used the dataset's)."""
    return trained_data_radius(simulator)


def rules_gravity(simulator: LearnedSimulator) -> torch.Tensor | None:
    """The data's gravity, ``[D]`` acceleration per frame^2 (data units, CPU float32), that free flight
    follows and the rest hold scales its thresholds by: the one the pairwise decoder adds to its forces, or the
    one a node-decoder model records in its config (since 2026-12-07; ``python -m gnsx.training.export``
    records it in older ones from their data). None when the model records none."""
    free_fall = getattr(simulator, "free_fall", None)
    if free_fall is not None:
        return (free_fall * simulator.acc_std + simulator.acc_mean).detach().cpu().float()
    gravity = simulator.config.get("gravity")
    return None if gravity is None else torch.tensor(gravity, dtype=torch.float32)
