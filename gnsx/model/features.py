"""Node and edge features of the particle graph, built on the fly from a short window of positions.

Order follows the paper (section 6.2): bound distance, radius graph, edge distance, normalisation. Absolute
positions never enter a feature, so the model is translation invariant (shifting the particles *and* the
bounds together leaves every feature unchanged). All time derivatives are per-frame finite differences
(dt = 1), the units of the dataset statistics (WaterRamps' ``vel_std`` ~2e-3 is metres per frame).
"""

from __future__ import annotations

import torch
from torch import Tensor

from gnsx.core.constants import NUM_PARTICLE_TYPES


def velocity_sequence(position_sequence: Tensor) -> Tensor:
    """Per-frame velocities ``v[t] = p[t] - p[t-1]``.

    Args:
        position_sequence: ``[num_particles, num_frames, dim]`` positions, oldest first.

    Returns:
        ``[num_particles, num_frames - 1, dim]`` velocities (length per frame), oldest first.
    """
    return position_sequence[:, 1:] - position_sequence[:, :-1]


def velocity_features(position_sequence: Tensor, vel_mean: Tensor, vel_std: Tensor) -> Tensor:
    """Normalised velocity history, flattened oldest first.

    Args:
        position_sequence: ``[num_particles, history + 1, dim]`` positions, oldest first.
        vel_mean, vel_std: ``[dim]`` training-set velocity statistics (length per frame).

    Returns:
        ``[num_particles, history * dim]``: ``(v[t] - vel_mean) / vel_std`` for the ``history`` velocities,
        ordered ``[v_oldest_x, v_oldest_y, ..., v_latest_x, v_latest_y]``.
    """
    velocities = (velocity_sequence(position_sequence) - vel_mean) / vel_std
    return velocities.flatten(start_dim=1)


def wall_features(position: Tensor, bounds: Tensor, radius: float, clip: tuple[float, float]) -> Tensor:
    """Distances to the lower and upper wall of each dimension, in units of the radius, clipped.

    Clipping makes the feature constant (no information) for particles farther than ``radius`` from a wall,
    the same "only the neighbourhood matters" bias as the radius graph. The simplified model clips to
    (0, 1); DeepMind's GNS to (-1, 1), which also tells a particle that left the domain by how much.

    Args:
        position: ``[num_particles, dim]`` most recent positions.
        bounds: ``[dim, 2]`` domain ``[lower, upper]`` per dimension, same units as ``position``.
        radius: connectivity radius (same units).
        clip: ``(low, high)`` clip range of the normalised distances.

    Returns:
        ``[num_particles, 2 * dim]``: ``[lower_0, ..., lower_{dim-1}, upper_0, ..., upper_{dim-1}]``
        (DeepMind's order), each ``clip(distance / radius)``.
    """
    to_lower = position - bounds[:, 0]
    to_upper = bounds[:, 1] - position
    distances = torch.cat([to_lower, to_upper], dim=1) / radius
    return distances.clamp(min=clip[0], max=clip[1])


def type_scalar_feature(particle_type: Tensor, dtype: torch.dtype = torch.float32) -> Tensor:
    """The material type as one scalar in [0, 1]: ``type / (NUM_PARTICLE_TYPES - 1)``.

    The paper stores the type as one scalar without saying how it is scaled; dividing by the largest id
    keeps it in the same range as the clipped wall features (water 5 -> 0.625, boundary 3 -> 0.375).

    Args:
        particle_type: ``[num_particles]`` int64 type ids in ``[0, NUM_PARTICLE_TYPES)``.

    Returns:
        ``[num_particles, 1]`` of ``dtype``.
    """
    return (particle_type.to(dtype) / (NUM_PARTICLE_TYPES - 1)).unsqueeze(1)


def edge_features(position: Tensor, edge_index: Tensor, radius: float) -> Tensor:
    """Relative displacement of each edge's sender and its length, in units of the radius.

    Args:
        position: ``[num_particles, dim]`` most recent positions.
        edge_index: ``[2, num_edges]`` int64, row 0 sender j, row 1 receiver i.
        radius: connectivity radius (same units as ``position``).

    Returns:
        ``[num_edges, dim + 1]``: ``[(p_j - p_i) / radius, |p_j - p_i| / radius]`` (DeepMind's sign:
        sender minus receiver). Lengths lie in [0, 1] for a radius graph.
    """
    senders, receivers = edge_index
    displacement = (position.index_select(0, senders) - position.index_select(0, receivers)) / radius
    distance = torch.linalg.vector_norm(displacement, dim=1, keepdim=True)
    return torch.cat([displacement, distance], dim=1)


def wall_contact_gate(position: Tensor, bounds: Tensor, radius: float) -> Tensor:
    """``[N, 1]`` weight of the pairwise model's wall force: 1 within one radius of the nearest wall, 0 beyond
    two, linear between (continuous, so a particle's acceleration does not jump as it crosses the band).

    Two radii: the MPM solver's walls act through its grid (a quadratic B-spline spans 1.5 cells, ~1.3 R on
    the small preset), and beyond that water feels a wall only through the water in between, which the pair
    forces carry.

    Args:
        position: ``[N, D]`` most recent positions (data units).
        bounds: ``[D, 2]``.
        radius: R (data units).
    """
    nearest = torch.minimum(position - bounds[:, 0], bounds[:, 1] - position).amin(dim=1, keepdim=True)
    return (2.0 - nearest / radius).clamp(0.0, 1.0)
