"""Checks every trajectory passes before gnsx stores it: one clear line naming file, trajectory, field, frame.

Readers and the store call :func:`check_trajectory` on each trajectory they produce or write, so a bad input
fails with a :class:`~gnsx.core.errors.DataError` such as::

    data/train.tfrecord, trajectory 12: field 'position': frame 40 has NaN (particle 7)

instead of a NaN loss hours into training.
"""

from __future__ import annotations

import numpy as np

from gnsx.core.constants import NUM_PARTICLE_TYPES
from gnsx.core.errors import DataError
from gnsx.data.trajectory import Trajectory


def trajectory_where(path: object, index: int) -> str:
    """The ``where`` of a trajectory in error messages: ``"<path>, trajectory <index>"``."""
    return f"{path}, trajectory {index}"


def check_trajectory(traj: Trajectory, where: str, dim: int | None = None) -> None:
    """Raise :class:`DataError` unless ``traj`` is a well-formed, finite trajectory.

    Args:
        traj: the trajectory; ``position`` must be a floating ``[num_frames, num_particles, dim]`` array and
            ``particle_type`` an integer ``[num_particles]`` array with ids in ``0..NUM_PARTICLE_TYPES-1``.
        where: names the file and trajectory (see :func:`trajectory_where`); prefixed to every message.
        dim: the spatial dimension the dataset declares (metadata ``dim``); ``None`` skips that check.

    Raises:
        DataError: wrong array type, number of axes or dtype; zero frames or particles; ``particle_type``
            length differing from the number of particles; ``dim`` mismatch; NaN/Inf positions (naming the
            first bad frame and particle); unknown particle types (naming the value and a particle).
    """
    position, particle_type = traj.position, traj.particle_type
    if not isinstance(position, np.ndarray):
        raise DataError(where, f"field 'position': expected a numpy array, got {type(position).__name__}")
    if not isinstance(particle_type, np.ndarray):
        raise DataError(
            where, f"field 'particle_type': expected a numpy array, got {type(particle_type).__name__}"
        )
    if position.ndim != 3:
        raise DataError(
            where, f"field 'position': expected shape [frames, particles, dim], got shape {position.shape}"
        )
    if not np.issubdtype(position.dtype, np.floating):
        raise DataError(where, f"field 'position': dtype {position.dtype} is not a floating type")
    num_frames, num_particles, traj_dim = position.shape
    if num_frames == 0:
        raise DataError(where, f"field 'position': zero frames (shape {position.shape})")
    if num_particles == 0:
        raise DataError(where, f"field 'position': zero particles (shape {position.shape})")
    if dim is not None and traj_dim != dim:
        raise DataError(where, f"field 'position': dim is {traj_dim} but the dataset's dim is {dim}")
    if particle_type.ndim != 1:
        raise DataError(
            where, f"field 'particle_type': expected shape [particles], got shape {particle_type.shape}"
        )
    if not np.issubdtype(particle_type.dtype, np.integer):
        raise DataError(where, f"field 'particle_type': dtype {particle_type.dtype} is not an integer type")
    if particle_type.shape[0] != num_particles:
        raise DataError(
            where,
            f"field 'particle_type': has {particle_type.shape[0]} entries but 'position' has "
            f"{num_particles} particles",
        )

    # One boolean per frame first (cheap), the offending particle only for the first bad frame.
    finite_frames = np.isfinite(position).reshape(num_frames, -1).all(axis=1)
    if not finite_frames.all():
        frame = int(np.flatnonzero(~finite_frames)[0])
        bad = position[frame]
        particle = int(np.flatnonzero(~np.isfinite(bad).all(axis=1))[0])
        kind = "NaN" if np.isnan(bad[particle]).any() else "Inf"
        raise DataError(where, f"field 'position': frame {frame} has {kind} (particle {particle})")

    unknown = (particle_type < 0) | (particle_type >= NUM_PARTICLE_TYPES)
    if unknown.any():
        particle = int(np.flatnonzero(unknown)[0])
        raise DataError(
            where,
            f"field 'particle_type': unknown type {int(particle_type[particle])} (particle {particle}); "
            f"valid ids are 0..{NUM_PARTICLE_TYPES - 1}",
        )
