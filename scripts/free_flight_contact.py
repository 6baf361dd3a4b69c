"""How close the MPM truth's free bodies of water come to a wall or a ramp while still falling at g.

    .venv/bin/python scripts/free_flight_contact.py data/small_400 train 150

The measurement behind :data:`gnsx.rules.freeflight.CLEARANCE`. For every frame of the first ``frames`` of
each trajectory, the water is split into clusters as :class:`gnsx.rules.freeflight.FreeFlight` does
(:func:`gnsx.rules.freeflight.rigid_clusters`, particles closer than ``REACH`` connectivity radii), and a
cluster is kept when it moves as one body (velocities within the rule's tolerance of their mean) and lies at
least 3 radii from all other water (the MPM's particles feel each other from ~2.6). For each kept cluster, its
members heading for a wall or a static particle (velocity after gravity) give a distance to that obstacle less
one frame of approach, the rule's test; the smallest over the members is the cluster's clearance. Printed, in
connectivity radii, for the clusters whose next step is still free fall (every member's acceleration within
1e-6 of g per frame^2, a few float32 round-offs) and for those whose next step is not: the first set's low
percentiles are how close the truth lets a body come before anything pushes it.
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.spatial import cKDTree

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.store import load_metadata, open_split
from gnsx.evaluation.scoring import gravity_per_frame
from gnsx.rules.freeflight import LOOKAHEAD, REACH, TOLERANCE, obstacle_gaps, rigid_clusters

#: Largest deviation from g (data units per frame^2) that still counts as free fall.
FREE_FALL = 1e-6
#: Other water at least this far (connectivity radii) from a kept cluster.
ISOLATION = 3.0


def cluster_clearances(position: np.ndarray, static: np.ndarray, bounds, radius, gravity, tolerance, frames):
    """``[(clearance, falls_at_g, obstacle)]`` for the isolated rigid clusters of one trajectory.

    Args:
        position: ``[T, N, 2]`` float64 truth; static: ``[N]`` bool; bounds: ``[2, 2]``; radius, tolerance:
            data units; gravity: ``[2]`` per frame^2; frames: frames examined from frame 1.
    """
    rows = []
    walls = np.asarray(bounds, dtype=np.float64)
    ramps = cKDTree(position[0][static]) if static.any() else None
    for f in range(1, min(len(position) - 1, frames)):
        current = position[f][~static]
        velocity = current - position[f - 1][~static]
        acceleration = position[f + 1][~static] - 2 * current + position[f - 1][~static]
        tree = cKDTree(current)
        label, broken = rigid_clusters(tree, velocity, REACH * radius, tolerance)
        # One frame of approach taken off, as the rule does (``LOOKAHEAD``).
        wall, ramp = obstacle_gaps(tree, velocity + gravity, walls, ramps, 0.2, LOOKAHEAD)
        free = np.linalg.norm(acceleration - gravity, axis=1) <= FREE_FALL
        for c in np.flatnonzero(~broken):
            members = label == c
            others = current[~members]
            if len(others) and cKDTree(others).query(current[members])[0].min() < ISOLATION * radius:
                continue
            for name, distance in (("wall", wall), ("ramp", ramp)):
                closest = distance[members].min()
                if np.isfinite(closest):
                    rows.append((closest / radius, bool(free[members].all()), name))
    return rows


def main(root: str, split: str, trajectories: int, frames: int = 120) -> None:
    metadata = load_metadata(root)
    data = open_split(root, split, metadata)
    radius = float(metadata.default_connectivity_radius)
    tolerance = TOLERANCE * float(np.linalg.norm(np.asarray(metadata.vel_std, dtype=np.float64)))
    gravity = gravity_per_frame(metadata).double().numpy()
    rows = []
    for index in range(min(trajectories, len(data))):
        trajectory = data[index]
        position = trajectory.position.astype(np.float64)
        static = trajectory.particle_type == KINEMATIC_PARTICLE_ID
        rows += cluster_clearances(position, static, metadata.bounds, radius, gravity, tolerance, frames)
    for obstacle in ("wall", "ramp"):
        for free in (True, False):
            values = np.array([r[0] for r in rows if r[2] == obstacle and r[1] == free])
            if len(values) == 0:
                continue
            lo, p1, p5 = values.min(), *np.percentile(values, [1, 5])
            state = "still falling at g" if free else "pushed next step  "
            print(
                f"{obstacle}: {state} {len(values):5d} cluster-frames, clearance min {lo:.2f} "
                f"1st percentile {p1:.2f} 5th {p5:.2f} radii"
            )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]))
