"""Water in free flight falls at g: a cluster that touches nothing and moves as one body feels only gravity.

In the MPM ground truth a block launched at rest density keeps every particle's velocity equal until it
reaches a wall, a ramp or other water: pressure comes from compression and viscosity from velocity
differences, and such a block has neither, so gravity is its only force. A learned model reads the jittered
lattice of a fresh block as slightly compressed here and stretched there and predicts small pair forces, which
a rollout integrates: the shipped weights' blocks fall at g as a whole (the pairwise decoder's pair forces
cancel) but their particles shuffle inside, and over the first 10 frames the model's error is 10x the
physics-free baseline's, which is exact in free flight.

:class:`FreeFlight` is the rule for that state, applied to each model rollout step before the rest hold, the
density limit and the boundary. Water particles are grouped into clusters: connected components of the
graph that joins particles closer than ``reach``. A cluster is *free* when

1. every member's velocity lies within ``tolerance`` of the cluster's mean velocity (one body: no velocity
   differences, so no viscous stress, and no deformation since the last frame), and
2. no member lies within ``reach`` of a wall or of a static particle that it is moving towards (nothing
   outside it pushes: the MPM's walls and ramps only stop motion into them). "Moving" is the velocity after
   this step's gravity, ``v + g``, so water resting on the floor or on a ramp is touching it.

Members of a free cluster take the exact free-fall step ``p + v + g`` instead of the model's; every other
particle keeps the model's prediction. The model takes over as soon as a body comes within ``reach`` of
something or its particles' velocities part. ``reach`` is two connectivity radii: the MPM's particles feel a
wall from 1.5 grid cells, a ramp from 2.5 and each other from 3 (its quadratic stencil reaches 1.5 cells, a
ramp's collider nodes 1 cell from the segment), so 1.3, 2.2 and 2.6 radii on the small preset; the model
itself sees only one radius. On the 8 validation trajectories (README, Decisions) one, two and three radii
could not be told apart over the whole rollout, and one and two cut the error of the first 10 frames by three
orders of magnitude. A single particle far from everything is a cluster of its own and falls at g, as the
pairwise decoder already makes it. The radii are the data's (:attr:`LearnedSimulator.rules_radius`), not
the model's: the MPM's reach does not grow with the model's graph. (When it did, a model with radius 0.05
instead of 0.035 had a reach of 0.1, fewer fresh blocks counted as free, and its MSE over the first 10
frames was ~250x worse; README, Decisions.)

Cost: scipy's pairs within ``reach`` and their connected components, on the CPU, every step
(``scripts/free_flight_cost.py``: median frames 1-18% slower at 400-2,300 particles, within the spread in two
of four runs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from torch import Tensor

from gnsx.constants import KINEMATIC_PARTICLE_ID

#: Velocity tolerance, as a fraction of the length of the data's velocity std (per frame): the truth's free
#: blocks move as one to float precision; a model's rollout that has started shuffling does not.
TOLERANCE = 0.01
#: Reach (cluster radius and clearance to walls and static particles), in connectivity radii.
REACH = 2.0


@dataclass(frozen=True)
class FreeFlight:
    """Free-flying rigid clusters of water fall at exactly ``gravity``.

    Attributes:
        gravity: ``[D]`` acceleration per frame^2 (data units), e.g. ``(0, -9.8 dt^2)``.
        bounds: ``[D, 2]`` walls ``[lower, upper]`` per axis.
        reach: particles closer than this are one cluster; a cluster closer than this to a wall or a static
            particle is not free (data units).
        tolerance: largest velocity difference from the cluster's mean (data units per frame).
    """

    gravity: Tensor
    bounds: Tensor
    reach: float
    tolerance: float

    @classmethod
    def for_simulator(
        cls, simulator, tolerance: float = TOLERANCE, reach: float = REACH
    ) -> FreeFlight | None:
        """Thresholds from the model's data: ``tolerance * |vel_std|``, ``reach`` connectivity radii, and the
        gravity its pairwise decoder adds. None for a node-decoder model (it has no gravity of its own)."""
        free_fall = getattr(simulator, "free_fall", None)
        if free_fall is None:
            return None
        return cls(
            gravity=(free_fall * simulator.acc_std + simulator.acc_mean).detach().cpu(),
            bounds=simulator.bounds.detach().cpu(),
            reach=reach * float(simulator.rules_radius),
            tolerance=tolerance * float(simulator.vel_std.norm()),
        )

    def free_particles(self, window: Tensor, particle_type: Tensor) -> Tensor:
        """``[N]`` bool: the water particles of free clusters, from ``window`` ``[N, F, D]`` (F >= 2)."""
        current = window[:, -1].detach().cpu().double().numpy()
        velocity = current - window[:, -2].detach().cpu().double().numpy()
        static = (particle_type == KINEMATIC_PARTICLE_ID).cpu().numpy()
        water = np.flatnonzero(~static)
        free = np.zeros(len(current), dtype=bool)
        if len(water) == 0:
            return torch.from_numpy(free).to(window.device)
        points = current[water]
        tree = cKDTree(points)
        pairs = tree.query_pairs(self.reach, output_type="ndarray")
        n = len(water)
        # Weak components of the one-way pair graph are the undirected ones (measured 1.9 against 2.8 ms
        # for directed=False, which first adds the transposed graph, at 2,300 particles).
        graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
        count, label = connected_components(graph, directed=True, connection="weak")
        # Per cluster: the mean velocity, then each member's distance from it.
        size = np.bincount(label, minlength=count)
        mean = np.stack([np.bincount(label, velocity[water, d], count) for d in range(points.shape[1])], 1)
        mean /= size[:, None]
        spread = np.linalg.norm(velocity[water] - mean[label], axis=1)
        # Touching: within reach of a wall or a static particle, and moving towards it (after gravity).
        heading = velocity[water] + self.gravity.double().numpy()
        bounds = self.bounds.double().numpy()
        near_lower = (points - bounds[:, 0] < self.reach) & (heading < 0)
        near_upper = (bounds[:, 1] - points < self.reach) & (heading > 0)
        touching = (near_lower | near_upper).any(axis=1)
        if static.any():
            near = tree.sparse_distance_matrix(cKDTree(current[static]), self.reach, output_type="ndarray")
            i, j = near["i"], near["j"]
            towards = np.einsum("kd,kd->k", heading[i], current[static][j] - points[i]) > 0
            touching[i[towards]] = True
        # A cluster is free when no member breaks ranks or touches anything.
        broken = np.bincount(label, (spread > self.tolerance) | touching, count) > 0
        free[water] = ~broken[label]
        return torch.from_numpy(free).to(window.device)

    def apply(self, window: Tensor, next_position: Tensor, particle_type: Tensor) -> tuple[Tensor, Tensor]:
        """``next_position`` ``[N, D]`` with free clusters on their free-fall step, and the ``[N]`` free mask
        (the rules after this one leave those particles alone)."""
        free = self.free_particles(window, particle_type)
        if not bool(free.any()):
            return next_position, free
        current = window[:, -1]
        falling = current + (current - window[:, -2]) + self.gravity.to(current)
        return torch.where(free[:, None], falling, next_position), free
