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
2. no member is about to touch a wall or a static particle it is moving towards: its distance to that
   obstacle, less what it closes in ``lookahead`` frames, is at least ``clearance`` (nothing outside it
   pushes: the MPM's walls and ramps only stop motion into them). "Moving" is the velocity after this
   step's gravity, ``v + g``, so water resting on the floor or on a ramp is touching it.

Members of a free cluster take the exact free-fall step ``p + v + g`` instead of the model's; every other
particle keeps the model's prediction. The model takes over as soon as a body nears a wall, a ramp or other
water, or its particles' velocities part. ``reach``, the radius that joins water into one cluster, is two
connectivity radii: the MPM's particles feel each other from 3 grid cells (2.6 radii on the small preset; the
model itself sees only one radius). The clearance to walls and ramps is its own length, 1.3 radii with one
frame of approach looked ahead. Over 150 training trajectories (``scripts/free_flight_contact.py``) the
truth's isolated rigid clusters heading for a ramp still fell at g with a clearance (so measured) of 1.28
radii or more, while the ones pushed in the next step came as close as 0.68 (5th percentile 0.75); walls push
only at contact (clearance 0). On the 32 tuning trajectories (docs/decisions) clearances of 1-1.5 radii
gave MSE over the first 10 and 50 frames within each other's standard errors; 0.5 radii for walls gave the
highest mean over 50 frames of those tried (1.45e-4 against 1.32-1.37e-4), as if the model predicts an impact
better once it has seen the wall coming; 1.3 was kept for both. Until 2026-12-02 the clearance was the
cluster's 2 radii with no look-ahead, which handed falling blocks to the model up to ~4 frames before the
truth's contact, and the model shuffled their jittered lattices: the new clearance cut MSE over the first 10
frames to 0.13x and over 50 to 0.47x on the 32 tuning trajectories, and left the whole rollout alone (0.99x
[0.94, 1.04]; geometric means of the per-trajectory ratios). A single particle far from everything is a
cluster of its own and falls at g, as the pairwise decoder already makes it. The radii are the data's
(:func:`gnsx.rules.scale.rules_radius`), not the model's: the MPM's reach does not grow with the model's
graph. (When it did, a model with radius 0.05 instead of 0.035 had a reach of 0.1, fewer fresh blocks counted
as free, and its MSE over the first 10 frames was ~250x worse; docs/decisions.)

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

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.rules.scale import rules_gravity, rules_radius

#: Velocity tolerance, as a fraction of the length of the data's velocity std (per frame): the truth's free
#: blocks move as one to float precision; a model's rollout that has started shuffling does not.
TOLERANCE = 0.01
#: Reach (water closer than this is one cluster), in connectivity radii.
REACH = 2.0
#: Clearance to walls and static particles, in connectivity radii (module docstring: measured on the truth).
CLEARANCE = 1.3
#: Frames of approach to a wall or a static particle looked ahead when checking the clearance.
LOOKAHEAD = 1.0


def rigid_clusters(tree: cKDTree, velocity: np.ndarray, reach: float, tolerance: float):
    """Clusters of water and which of them break ranks.

    Args:
        tree: KD-tree over the water's positions ``[M, D]`` (data units).
        velocity: ``[M, D]`` their velocities (data units per frame).
        reach: particles closer than this are one cluster; tolerance: largest velocity difference from the
            cluster's mean velocity of a body that moves as one.
    Returns:
        ``label`` ``[M]`` each particle's cluster, and ``broken`` ``[C]`` bool: a member of the cluster moves
        more than ``tolerance`` off its mean velocity.
    """
    n = len(velocity)
    pairs = tree.query_pairs(reach, output_type="ndarray")
    # Weak components of the one-way pair graph are the undirected ones (measured 1.9 against 2.8 ms for
    # directed=False, which first adds the transposed graph, at 2,300 particles).
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    count, label = connected_components(graph, directed=True, connection="weak")
    size = np.bincount(label, minlength=count)
    mean = np.stack([np.bincount(label, velocity[:, d], count) for d in range(velocity.shape[1])], 1)
    mean /= size[:, None]
    spread = np.linalg.norm(velocity - mean[label], axis=1)
    return label, np.bincount(label, spread > tolerance, count) > 0


def obstacle_gaps(
    tree: cKDTree,
    heading: np.ndarray,
    bounds: np.ndarray,
    statics: cKDTree | None,
    search: float,
    lookahead: float,
) -> tuple[np.ndarray, np.ndarray]:
    """How close each particle is to the walls and to the static particles it is heading for.

    Args:
        tree: KD-tree over the particles' positions ``[M, D]`` (data units).
        heading: ``[M, D]`` their velocity after gravity (per frame).
        bounds: ``[D, 2]`` walls ``[lower, upper]`` per axis.
        statics: KD-tree over the static particles, or ``None``.
        search: static particles farther than this are not looked at (data units).
        lookahead: frames of approach taken off each distance.

    Returns:
        ``wall`` and ``ramp``, both ``[M]``: the smallest distance to a wall (a static particle) that the
        particle is moving towards, less ``lookahead`` frames of its approach to it; ``inf`` when it is moving
        towards none (within ``search``).
    """
    points = tree.data
    lower = points - bounds[:, 0] + lookahead * heading  # heading < 0: its approach taken off
    upper = bounds[:, 1] - points - lookahead * heading
    wall = np.where(heading < 0, lower, np.where(heading > 0, upper, np.inf)).min(axis=1)
    ramp = np.full(len(points), np.inf)
    if statics is not None:
        near = tree.sparse_distance_matrix(statics, search, output_type="ndarray")
        i, j, distance = near["i"], near["j"], near["v"]
        unit = (statics.data[j] - points[i]) / np.maximum(distance, 1e-300)[:, None]
        closing = np.einsum("kd,kd->k", heading[i], unit)  # approach per frame
        towards = closing > 0
        np.minimum.at(ramp, i[towards], (distance - lookahead * closing)[towards])
    return wall, ramp


@dataclass(frozen=True)
class FreeFlight:
    """Free-flying rigid clusters of water fall at exactly ``gravity``.

    Attributes:
        gravity: ``[D]`` acceleration per frame^2 (data units), e.g. ``(0, -9.8 dt^2)``.
        bounds: ``[D, 2]`` walls ``[lower, upper]`` per axis.
        reach: particles closer than this are one cluster (data units).
        tolerance: largest velocity difference from the cluster's mean (data units per frame).
        clearance: a member heading for a wall or a static particle closer than this (after ``lookahead``
            frames of approach) makes its cluster not free (data units).
        lookahead: frames of approach subtracted from the distance to an obstacle.
    """

    gravity: Tensor
    bounds: Tensor
    reach: float
    tolerance: float
    clearance: float
    lookahead: float = LOOKAHEAD

    @classmethod
    def for_simulator(
        cls,
        simulator,
        tolerance: float = TOLERANCE,
        reach: float = REACH,
        clearance: float = CLEARANCE,
        lookahead: float = LOOKAHEAD,
    ) -> FreeFlight | None:
        """Thresholds from the model's data: ``tolerance * |vel_std|``, ``reach`` and ``clearance``
        connectivity radii, and the data's gravity (:func:`gnsx.rules.scale.rules_gravity`). None for a model
        that records no gravity (node-decoder checkpoints before 2026-12-07)."""
        gravity = rules_gravity(simulator)
        if gravity is None:
            return None
        return cls(
            gravity=gravity,
            bounds=simulator.bounds.detach().cpu(),
            reach=reach * rules_radius(simulator),
            tolerance=tolerance * float(simulator.vel_std.norm()),
            clearance=clearance * rules_radius(simulator),
            lookahead=float(lookahead),
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
        label, broken = rigid_clusters(tree, velocity[water], self.reach, self.tolerance)
        # Touching: moving towards a wall or a static particle (after gravity) and within the clearance of it
        # once this step's approach (``lookahead`` frames of it) is taken off the distance.
        heading = velocity[water] + self.gravity.double().numpy()
        search = self.clearance + self.lookahead * float(np.linalg.norm(heading, axis=1).max())
        statics = cKDTree(current[static]) if static.any() else None
        wall, ramp = obstacle_gaps(
            tree, heading, self.bounds.double().numpy(), statics, search, self.lookahead
        )
        touching = np.minimum(wall, ramp) < self.clearance
        # A cluster is free when no member breaks ranks or touches anything.
        broken |= np.bincount(label, touching, len(broken)) > 0
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
