"""LagrangeBench HDF5 files: ``{split}.h5``, one group per trajectory.

Layout (LagrangeBench ``lagrangebench/data/data.py``): groups ``00000``, ``00001``, ... each holding the
datasets ``position`` ``[T, N, D]`` float32 and ``particle_type`` ``[N]`` (integer). Groups are read in the
order of their names (LagrangeBench lists ``f.keys()``, which h5py sorts by name; numeric names numerically).

Keys: the group attribute ``key`` when present (gnsx's writer stores it, so keys survive a round trip),
else the group name when it is an integer, else its position. Particle type ids are kept as they are:
LagrangeBench's ids (``NodeType``: 0 fluid, 1 solid wall, 2 moving wall, 3 rigid body) are not DeepMind's
(5 water, 3 kinematic boundary, 0 rigid), and gnsx treats type 3 as kinematic: convert LagrangeBench data with
``type_map={0: 5, 1: 3, 2: 3, 3: 0}`` (CLI ``--type-map 0:5,1:3,2:3,3:0``) to get DeepMind's meaning.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import h5py
import numpy as np

from gnsx.core.atomic import atomic_path
from gnsx.core.errors import DataError
from gnsx.data.trajectory import Trajectory
from gnsx.data.validate import check_trajectory, trajectory_where


def read_h5(path: str | os.PathLike) -> Iterator[Trajectory]:
    """Yield the trajectories of a LagrangeBench ``.h5`` file (one group in memory at a time), validated.

    Raises:
        DataError: unreadable/corrupt file, a group without ``position`` or ``particle_type``, or a
            :func:`~gnsx.data.validate.check_trajectory` failure, naming the file, trajectory and group.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DataError(str(path), f"not a readable HDF5 file ({e})") from None
    with f:
        # Numeric order for numeric names, so "100000" follows "99999".
        names = sorted(f.keys(), key=lambda n: (0, int(n), n) if n.isdigit() else (1, 0, n))
        for i, name in enumerate(names):
            where = f"{trajectory_where(path, i)} (group '{name}')"
            group = f[name]
            if not isinstance(group, h5py.Group):
                raise DataError(where, "expected a group with datasets 'position' and 'particle_type'")
            arrays = {}
            for field in ("position", "particle_type"):
                if field not in group:
                    raise DataError(
                        where, f"missing dataset '{field}' (has: {sorted(group.keys()) or 'none'})"
                    )
                try:
                    arrays[field] = group[field][()]
                except (OSError, ValueError) as e:
                    raise DataError(
                        where, f"field '{field}': cannot read: truncated or corrupt ({e})"
                    ) from None
            key = _key(group, name, i)
            particle_type = arrays["particle_type"]
            if np.issubdtype(particle_type.dtype, np.integer):
                particle_type = particle_type.astype(np.int64)
            traj = Trajectory(position=arrays["position"], particle_type=particle_type, key=key)
            check_trajectory(traj, where)
            traj.position = traj.position.astype(np.float32, copy=False)
            yield traj


def _key(group: h5py.Group, name: str, index: int) -> int:
    if "key" in group.attrs:
        return int(group.attrs["key"])
    return int(name) if name.isdigit() else index


def write_h5(path: str | os.PathLike, trajectories: Iterable[Trajectory]) -> int:
    """Write trajectories as a LagrangeBench ``.h5`` (groups ``00000``.., atomic); return the count.

    Groups are named by position (LagrangeBench's convention); each also gets the attribute ``key``.
    """
    path = Path(path)
    count = 0
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        for i, traj in enumerate(trajectories):
            check_trajectory(traj, trajectory_where(path, i))
            group = f.create_group(f"{i:05d}")
            group.create_dataset("position", data=np.asarray(traj.position, dtype=np.float32))
            group.create_dataset("particle_type", data=np.asarray(traj.particle_type, dtype=np.int64))
            group.attrs["key"] = int(traj.key)
            count += 1
    return count
