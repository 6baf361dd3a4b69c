"""geoelements/gns ``.npz`` files: ``{split}.npz``, a dict of trajectories.

Layout (geoelements/gns ``docs/gns_data.md`` and ``gns/data_loader.py``): ``np.savez_compressed(path,
**{name: (positions, particle_type[, material_property])})``, so each member ``name.npy`` is a pickled object
array ``[2]`` (or ``[3]``) holding ``positions`` ``[T, N, D]`` (float32 or float64) and ``particle_type``
``[N]`` (or one scalar type for every particle). Datasets shipped by geoelements name the members
``simulation_trajectory_<i>``; newer files may instead hold one member ``gns_data``, an array of such tuples.
``material_property`` (a per-particle feature gnsx does not model) is ignored.

**Pickle**: object arrays can only be stored pickled, and a plain unpickler runs whatever code a malicious
file names. gnsx never calls one on data: the object members are read by :class:`NumpyUnpickler`, which
rebuilds numpy arrays, dtypes and scalars and refuses any other global (a :class:`~gnsx.core.errors.DataError`
naming the member and the refused name), and every other member with ``allow_pickle=False``. gnsx's own
store never holds object arrays.

Keys: the trailing integer of the member name (``simulation_trajectory_12`` -> 12), else the member's position
in the file. The writer names members ``simulation_trajectory_<key>`` and streams them into the zip one at a
time (``np.savez_compressed`` would need every trajectory in memory).
"""

from __future__ import annotations

import importlib
import io
import os
import pickle
import re
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from gnsx.core.atomic import atomic_path
from gnsx.core.errors import DataError
from gnsx.data.trajectory import Trajectory
from gnsx.data.validate import check_trajectory, trajectory_where

GNS_DATA_KEY = "gns_data"
MEMBER_PREFIX = "simulation_trajectory_"
_TRAILING_INT = re.compile(r"(\d+)$")
# Errors a damaged zip member or pickle can raise while loading.
_LOAD_ERRORS = (
    ValueError,
    OSError,
    EOFError,
    KeyError,
    zipfile.BadZipFile,
    zlib.error,
    pickle.UnpicklingError,
)


def read_npz(path: str | os.PathLike) -> Iterator[Trajectory]:
    """Yield the trajectories of a geoelements/gns ``.npz`` (one member in memory at a time), validated.

    Raises:
        DataError: unreadable zip, a damaged member, a member not shaped ``(positions, particle_type)``, or a
            :func:`~gnsx.data.validate.check_trajectory` failure, naming the file and trajectory (and member).
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "file not found")
    try:
        archive = zipfile.ZipFile(path)
    except _LOAD_ERRORS as e:
        with open(path, "rb") as f:
            single = f.read(6) == b"\x93NUMPY"
        if single:
            raise DataError(str(path), "expected an .npz archive, found a single .npy array") from None
        raise DataError(str(path), f"not a readable .npz file ({e})") from None
    with archive:
        names = [n[: -len(".npy")] for n in archive.namelist() if n.endswith(".npy")]
        if GNS_DATA_KEY in names:
            items = _load_member(archive, GNS_DATA_KEY, path)
            for i, item in enumerate(items):
                where = f"{trajectory_where(path, i)} (member '{GNS_DATA_KEY}'[{i}])"
                yield _to_trajectory(item, key=i, where=where)
            return
        for i, name in enumerate(names):
            where = f"{trajectory_where(path, i)} (member '{name}')"
            match = _TRAILING_INT.search(name)
            key = int(match.group(1)) if match else i
            yield _to_trajectory(_load_member(archive, name, path), key=key, where=where)


#: The only globals an object member may name: numpy's array, dtype and scalar reconstruction.
_NUMPY_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy._core.numeric", "_frombuffer"),
}


class NumpyUnpickler(pickle.Unpickler):
    """An unpickler that rebuilds numpy arrays, dtypes and scalars and refuses every other global (so no
    code named by a data file runs). ``numpy.core`` (numpy 1) and ``numpy._core`` (numpy 2) are the same."""

    def find_class(self, module: str, name: str):
        canonical = module.replace("numpy.core.", "numpy._core.", 1)
        if (canonical, name) not in _NUMPY_GLOBALS:
            raise pickle.UnpicklingError(f"refused global {module}.{name}")
        for candidate in (canonical, module.replace("numpy._core.", "numpy.core.", 1)):
            try:
                return getattr(importlib.import_module(candidate), name)
            except (ImportError, AttributeError):
                continue
        raise pickle.UnpicklingError(f"cannot find {module}.{name}")


def _load_member(archive: zipfile.ZipFile, name: str, path: Path) -> np.ndarray:
    """Member ``name`` of the archive: plain arrays with ``allow_pickle=False``, object arrays through
    :class:`NumpyUnpickler`."""
    where = f"{path} (member '{name}')"
    try:
        data = io.BytesIO(archive.read(f"{name}.npy"))
        version = np.lib.format.read_magic(data)
        header = (
            np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        )
        shape, fortran_order, dtype = header(data)
        if not dtype.hasobject:
            data.seek(0)
            return np.lib.format.read_array(data, allow_pickle=False)
        array = NumpyUnpickler(data).load()
    except pickle.UnpicklingError as e:
        if str(e).startswith("refused global"):
            raise DataError(
                where, f"{e}: gnsx reads numpy arrays only from data files (no pickled code)"
            ) from None
        raise DataError(where, f"cannot read: truncated or corrupt ({e})") from None
    except _LOAD_ERRORS as e:
        raise DataError(where, f"cannot read: truncated or corrupt ({e})") from None
    if not isinstance(array, np.ndarray):
        raise DataError(where, f"expected an array, the pickle holds {type(array).__name__}")
    return array


def _to_trajectory(item: object, key: int, where: str) -> Trajectory:
    """``(positions [T,N,D], particle_type [N] or scalar[, material_property])`` to a validated Trajectory."""
    if isinstance(item, np.ndarray) and item.ndim == 0 and item.dtype.hasobject:
        item = item.item()  # a tuple saved as a 0-d object array
    if not isinstance(item, np.ndarray | tuple | list | np.void) or len(item) not in (2, 3):
        shape = getattr(item, "shape", None)
        raise DataError(
            where,
            f"expected a (positions, particle_type[, material_property]) tuple, got {type(item).__name__}"
            + (f" of shape {shape}" if shape is not None else ""),
        )
    position = np.asarray(item[0])
    particle_type = np.asarray(item[1])
    if position.ndim == 3 and particle_type.ndim == 0:
        # geoelements allows one scalar type for all particles (its loader np.full()s it).
        particle_type = np.full(position.shape[1], particle_type)
    if np.issubdtype(particle_type.dtype, np.floating) and np.all(particle_type == np.round(particle_type)):
        particle_type = particle_type.astype(np.int64)  # integral floats: some writers store types as float
    if np.issubdtype(particle_type.dtype, np.integer):
        particle_type = particle_type.astype(np.int64)
    traj = Trajectory(position=position, particle_type=particle_type, key=key)
    check_trajectory(traj, where)
    traj.position = position.astype(np.float32, copy=False)
    return traj


def write_npz(path: str | os.PathLike, trajectories: Iterable[Trajectory]) -> int:
    """Write trajectories as a geoelements/gns ``.npz`` (compressed, streamed, atomic); return the count.

    Members are ``simulation_trajectory_<key>`` object arrays ``(positions float32 [T,N,D],
    particle_type int64 [N])``, exactly what ``np.savez_compressed(path, **{name: (pos, types)})`` produces.

    Raises:
        DataError: a bad trajectory, or two trajectories with the same key (member names would collide).
    """
    path = Path(path)
    seen: set[int] = set()
    with (
        atomic_path(path) as tmp,
        zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf,
    ):
        for i, traj in enumerate(trajectories):
            where = trajectory_where(path, i)
            check_trajectory(traj, where)
            key = int(traj.key)
            if key in seen:
                raise DataError(where, f"duplicate key {key}: npz member names must be unique")
            seen.add(key)
            item = np.empty(2, dtype=object)
            item[0] = np.ascontiguousarray(traj.position, dtype=np.float32)
            item[1] = np.ascontiguousarray(traj.particle_type, dtype=np.int64)
            with zf.open(f"{MEMBER_PREFIX}{key}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, item, allow_pickle=True)
    return len(seen)
