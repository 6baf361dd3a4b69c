"""The in-memory unit of every dataset: one trajectory of particle positions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Trajectory:
    """One simulated scene.

    Attributes:
        position: ``[num_frames, num_particles, dim]`` float32 positions (data units, WaterRamps: metres).
        particle_type: ``[num_particles]`` int64 type ids (5 water, 3 static boundary; see
            :mod:`gnsx.core.constants`). Constant over the trajectory.
        key: an integer id (DeepMind's context ``key``); the index in its split when unknown.
    """

    position: np.ndarray
    particle_type: np.ndarray
    key: int = 0

    @property
    def num_frames(self) -> int:
        return int(self.position.shape[0])

    @property
    def num_particles(self) -> int:
        return int(self.position.shape[1])

    @property
    def dim(self) -> int:
        return int(self.position.shape[2])
