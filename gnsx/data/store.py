"""gnsx's own dataset format: flat ``.npy`` files built for memory-mapped random frame access.

Layout of a dataset folder ``{root}``::

    {root}/metadata.json                 DeepMind's schema (see gnsx.data.metadata), written last
    {root}/{split}/positions.npy         float32 [sum_i T_i * N_i, D]
    {root}/{split}/particle_type.npy     int64   [sum_i N_i]
    {root}/{split}/index.npy             structured [num_trajectories], one row per trajectory

with ``split`` one of ``train``, ``valid``, ``test`` (any other simple name is allowed too).

``positions.npy`` holds every trajectory of the split back to back, each frame-major: rows
``position_offset_i .. position_offset_i + T_i * N_i`` of trajectory ``i`` reshape to ``[T_i, N_i, D]``
(frame ``k``, particle ``j`` is row ``position_offset_i + k * N_i + j``). The frames ``k-h .. k+1`` a training
sample needs are therefore one contiguous read, and ``np.load(..., mmap_mode="r")`` serves them from the page
cache without loading the split (a full WaterRamps train split is ~10 GB). ``particle_type.npy`` is the
concatenation of every trajectory's ``[N_i]`` type ids (types are constant in time).

``index.npy`` has the int64 fields ``key`` (DeepMind's context key), ``num_frames`` (T_i), ``num_particles``
(N_i), ``position_offset`` (first row in ``positions.npy``) and ``type_offset`` (first entry in
``particle_type.npy``); offsets are the running sums of ``T_i * N_i`` and ``N_i``, and the readers check that
they are. All three files are plain ``.npy`` (no pickle), readable by any numpy::

    index = np.load("train/index.npy")
    pos = np.load("train/positions.npy", mmap_mode="r")
    i = index[0]
    traj0 = pos[i["position_offset"] : i["position_offset"] + i["num_frames"] * i["num_particles"]]
    traj0 = traj0.reshape(i["num_frames"], i["num_particles"], -1)

Writing streams: each trajectory is validated (:func:`~gnsx.data.validate.check_trajectory`) and appended
to the open files, and the ``.npy`` headers (a fixed 128 bytes) are rewritten with the final shapes at the
end, so memory stays at one trajectory. Writes are atomic: everything goes to a hidden temp folder next to the
target that is renamed into place only when complete; on any error it is removed, and an existing split or
dataset is replaced only when ``overwrite=True``.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from gnsx.core.constants import SPLITS
from gnsx.core.errors import DataError
from gnsx.core.runstate import liveness, pid_alive
from gnsx.data.metadata import Metadata, compute_statistics
from gnsx.data.trajectory import Trajectory
from gnsx.data.validate import check_trajectory, trajectory_where

log = logging.getLogger("gnsx")

# Inside a dataset's temporary folder while it is written: who writes it (pid, its start time, host), so a
# later write can tell a folder left by a killed writer from one still being written.
_OWNER_FILE = ".writer.json"

METADATA_FILE = "metadata.json"
POSITIONS_FILE = "positions.npy"
PARTICLE_TYPE_FILE = "particle_type.npy"
INDEX_FILE = "index.npy"
#: Row layout of ``index.npy``.
INDEX_DTYPE = np.dtype(
    [
        ("key", "<i8"),
        ("num_frames", "<i8"),
        ("num_particles", "<i8"),
        ("position_offset", "<i8"),
        ("type_offset", "<i8"),
    ]
)
POSITION_DTYPE = np.dtype("<f4")
PARTICLE_TYPE_DTYPE = np.dtype("<i8")
# A fixed .npy header size (a multiple of 64, as the format requires) so the header can be rewritten with the
# final shape after streaming the data; 128 bytes fit any shape with 20-digit extents.
_NPY_HEADER_BYTES = 128
_SPLIT_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


# --------------------------------------------------------------------------------------------- reading


class SplitReader(Sequence[Trajectory]):
    """Random access to one stored split: ``reader[i]`` is a :class:`Trajectory` backed by a memmap.

    Args:
        root: the dataset folder (holding ``metadata.json`` and the split folders).
        split: split name, e.g. ``"train"``.
        mmap: memory-map ``positions.npy`` (default; constant memory, pages shared between DataLoader
            workers) or, with ``False``, load it into memory.

    ``reader[i].position`` is a read-only ``[T_i, N_i, D]`` float32 view into the split's positions and
    ``reader[i].particle_type`` a read-only ``[N_i]`` int64 view. Pickling (DataLoader workers under spawn)
    sends only the path, and the unpickled reader maps the files again.

    Raises:
        DataError: missing split or file, truncated or corrupt ``.npy``, or an index inconsistent with the
            array sizes, naming the file.
    """

    def __init__(self, root: str | os.PathLike, split: str, mmap: bool = True):
        self.root = Path(root)
        self.split = split
        self.mmap = mmap
        self._open()

    def _open(self) -> None:
        folder = self.root / self.split
        if not folder.is_dir():
            found = list_splits(self.root) if self.root.is_dir() else []
            raise DataError(
                str(folder), f"split '{self.split}' not found (splits here: {', '.join(found) or 'none'})"
            )
        index = _load_npy(folder / INDEX_FILE, mmap=False)
        positions = _load_npy(folder / POSITIONS_FILE, mmap=self.mmap)
        particle_type = _load_npy(folder / PARTICLE_TYPE_FILE, mmap=False)
        _check_split_arrays(folder, index, positions, particle_type)
        positions.flags.writeable = False
        particle_type.flags.writeable = False
        self._index = index
        self._positions = positions  # [sum_i T_i * N_i, D]
        self._particle_type = particle_type  # [sum_i N_i]

    def __getstate__(self) -> dict[str, Any]:
        return {"root": self.root, "split": self.split, "mmap": self.mmap}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._open()

    def __len__(self) -> int:
        return int(self._index.shape[0])

    def __getitem__(self, i: int | slice) -> Any:  # Trajectory, or list[Trajectory] for a slice
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        row = self._index[self._check_index(i)]
        num_frames, num_particles = int(row["num_frames"]), int(row["num_particles"])
        start = int(row["position_offset"])
        position = self._positions[start : start + num_frames * num_particles].reshape(
            num_frames, num_particles, self.dim
        )
        type_start = int(row["type_offset"])
        particle_type = self._particle_type[type_start : type_start + num_particles]
        return Trajectory(position=position, particle_type=particle_type, key=int(row["key"]))

    def __iter__(self) -> Iterator[Trajectory]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"SplitReader({str(self.root)!r}, {self.split!r}, trajectories={len(self)}, dim={self.dim})"

    def _check_index(self, i: int) -> int:
        n = len(self)
        j = int(i)
        if j < 0:
            j += n
        if not 0 <= j < n:
            raise IndexError(f"trajectory {i} out of range: split '{self.split}' has {n}")
        return j

    @property
    def dim(self) -> int:
        """Spatial dimension D."""
        return int(self._positions.shape[1])

    @property
    def keys(self) -> np.ndarray:
        """``[num_trajectories]`` int64 keys."""
        return self._index["key"].copy()

    @property
    def frame_counts(self) -> np.ndarray:
        """``[num_trajectories]`` int64 number of frames T_i of each trajectory."""
        return self._index["num_frames"].copy()

    @property
    def particle_counts(self) -> np.ndarray:
        """``[num_trajectories]`` int64 number of particles N_i of each trajectory."""
        return self._index["num_particles"].copy()

    @property
    def total_frames(self) -> int:
        """Frames summed over all trajectories of the split."""
        return int(self._index["num_frames"].sum())

    def check_finite(self, chunk_rows: int = 1 << 21) -> None:
        """Raise :class:`DataError` at the first NaN or Inf position of the split, naming the file,
        trajectory, frame and particle (``data/small/train/positions.npy, trajectory 3: field 'position':
        frame 40 has NaN (particle 7)``). Streams ``positions.npy`` in chunks of ``chunk_rows`` rows."""
        total = self._positions.shape[0]
        for start in range(0, total, chunk_rows):
            chunk = np.asarray(self._positions[start : start + chunk_rows])
            finite = np.isfinite(chunk).all(axis=1)
            if finite.all():
                continue
            row = start + int(np.flatnonzero(~finite)[0])
            t = int(np.searchsorted(self._index["position_offset"], row, side="right")) - 1
            local = row - int(self._index["position_offset"][t])
            frame, particle = divmod(local, int(self._index["num_particles"][t]))
            kind = "NaN" if np.isnan(self._positions[row]).any() else "Inf"
            where = trajectory_where(self.root / self.split / POSITIONS_FILE, t)
            raise DataError(where, f"field 'position': frame {frame} has {kind} (particle {particle})")

    def num_frames(self, i: int) -> int:
        """Frames T_i of trajectory ``i``."""
        return int(self._index["num_frames"][self._check_index(i)])

    def num_particles(self, i: int) -> int:
        """Particles N_i of trajectory ``i``."""
        return int(self._index["num_particles"][self._check_index(i)])

    def particle_type(self, i: int) -> np.ndarray:
        """Read-only ``[N_i]`` int64 type ids of trajectory ``i`` (without touching positions)."""
        row = self._index[self._check_index(i)]
        start = int(row["type_offset"])
        return self._particle_type[start : start + int(row["num_particles"])]


def open_split(
    root: str | os.PathLike, split: str, metadata: Metadata, check_values: bool = True
) -> SplitReader:
    """A :class:`SplitReader` checked against the dataset's metadata before anything reads it.

    Args:
        metadata: the dataset's (``load_metadata(root)``): its ``dim`` must be the positions' dimension.
        check_values: also scan every position for NaN/Inf (:meth:`SplitReader.check_finite`; ~0.1 s per
            100 MB of positions), so bad data is named at the start instead of a NaN loss or a failing
            rollout later.

    Raises:
        DataError: naming the metadata file or the positions file, trajectory, frame and particle.
    """
    reader = SplitReader(root, split)
    if len(reader) and reader.dim != metadata.dim:
        raise DataError(
            str(Path(root) / METADATA_FILE),
            f"key 'dim' is {metadata.dim} but {Path(root) / split / POSITIONS_FILE} holds {reader.dim}-D "
            "positions",
        )
    if check_values:
        reader.check_finite()
    return reader


def load_metadata(root: str | os.PathLike) -> Metadata:
    """The validated, complete metadata of the dataset at ``root`` (``{root}/metadata.json``)."""
    return Metadata.load(Path(root) / METADATA_FILE)


def list_splits(root: str | os.PathLike) -> list[str]:
    """Split folders under ``root`` (those holding an ``index.npy``), DeepMind's splits first."""
    root = Path(root)
    names = sorted(
        p.name for p in root.iterdir() if (p / INDEX_FILE).is_file() and not p.name.startswith(".")
    )
    return [s for s in SPLITS if s in names] + [s for s in names if s not in SPLITS]


def _load_npy(path: Path, mmap: bool) -> np.ndarray:
    """Load a ``.npy`` without pickle, checking its size against its header first (clear truncation error)."""
    if not path.is_file():
        raise DataError(str(path), "file not found")
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(f)
            data_offset = f.tell()
            size = os.fstat(f.fileno()).st_size
    except (ValueError, OSError, EOFError) as e:
        raise DataError(str(path), f"not a readable .npy file ({e})") from None
    if fortran_order or dtype.hasobject:
        raise DataError(str(path), "unexpected .npy layout (Fortran order or object dtype)")
    expected = data_offset + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if size < expected:
        raise DataError(
            str(path), f"truncated: {size} bytes, but its header declares shape {shape} needing {expected}"
        )
    if size > expected:
        raise DataError(str(path), f"corrupt: {size - expected} bytes after the array of shape {shape}")
    if int(np.prod(shape)) == 0:
        return np.zeros(shape, dtype=dtype)  # memmap cannot map zero bytes
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DataError(str(path), f"cannot read ({e})") from None


def _check_split_arrays(
    folder: Path, index: np.ndarray, positions: np.ndarray, particle_type: np.ndarray
) -> None:
    """Cross-check ``index.npy`` with the array sizes so a corrupt split fails at open, not mid-training."""
    index_path, pos_path, type_path = (
        folder / INDEX_FILE,
        folder / POSITIONS_FILE,
        folder / PARTICLE_TYPE_FILE,
    )
    if index.dtype.names is None or set(INDEX_DTYPE.names) - set(index.dtype.names) or index.ndim != 1:
        raise DataError(
            str(index_path), f"expected a 1-D array with fields {INDEX_DTYPE.names}, got dtype {index.dtype}"
        )
    if positions.ndim != 2 or positions.dtype != POSITION_DTYPE:
        raise DataError(
            str(pos_path), f"expected float32 [rows, dim], got {positions.dtype} shape {positions.shape}"
        )
    if particle_type.ndim != 1 or not np.issubdtype(particle_type.dtype, np.integer):
        raise DataError(
            str(type_path),
            f"expected int64 [particles], got {particle_type.dtype} shape {particle_type.shape}",
        )
    frames = index["num_frames"].astype(np.int64)
    particles = index["num_particles"].astype(np.int64)
    if len(index) and (frames.min() < 1 or particles.min() < 1):
        bad = int(np.flatnonzero((frames < 1) | (particles < 1))[0])
        raise DataError(str(index_path), f"trajectory {bad}: non-positive num_frames or num_particles")
    rows = frames * particles
    position_offset = np.concatenate([[0], np.cumsum(rows)[:-1]]) if len(index) else rows
    type_offset = np.concatenate([[0], np.cumsum(particles)[:-1]]) if len(index) else particles
    for field, expected in (("position_offset", position_offset), ("type_offset", type_offset)):
        wrong = np.flatnonzero(index[field] != expected)
        if wrong.size:
            i = int(wrong[0])
            raise DataError(
                str(index_path),
                f"trajectory {i}: {field} is {int(index[field][i])}, expected {int(expected[i])}",
            )
    if int(rows.sum()) != positions.shape[0]:
        raise DataError(
            str(pos_path),
            f"holds {positions.shape[0]} rows but {INDEX_FILE} describes {int(rows.sum())} "
            "(sum of num_frames * num_particles)",
        )
    if int(particles.sum()) != particle_type.shape[0]:
        raise DataError(
            str(type_path),
            f"holds {particle_type.shape[0]} entries but {INDEX_FILE} describes {int(particles.sum())}",
        )


# --------------------------------------------------------------------------------------------- writing


def write_split(
    root: str | os.PathLike,
    split: str,
    trajectories: Iterable[Trajectory],
    *,
    overwrite: bool = False,
    dim: int | None = None,
    where: str | None = None,
) -> int:
    """Stream ``trajectories`` into ``{root}/{split}/`` atomically; return how many were written.

    Args:
        root: dataset folder (created if missing).
        split: split name (a plain folder name).
        trajectories: any iterable, consumed once; each is validated and appended, one in memory at a time.
            Positions are stored as float32, types as int64.
        overwrite: replace an existing ``{root}/{split}``; otherwise an existing split is an error.
        dim: the dataset's spatial dimension; ``None`` takes the first trajectory's. An empty split is
            allowed (stored as ``[0, dim]``).
        where: names the split in error messages (default ``{root}/{split}``; :func:`write_dataset` passes
            the final path, not its temp folder).

    Raises:
        DataError: the split exists (without ``overwrite``), or a trajectory fails
            :func:`~gnsx.data.validate.check_trajectory` (the message names the trajectory, field and frame).
            Nothing is left behind: the temp folder is removed and an existing split is untouched.
    """
    root = Path(root)
    _check_split_name(split, root)
    target = root / split
    where = where or str(target)
    if target.exists() and not overwrite:
        raise DataError(
            str(target), "split already exists; pass overwrite=True (CLI: --overwrite) to replace it"
        )
    created_root = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{split}.tmp-", dir=root))
    try:
        count = _write_split_files(tmp, trajectories, dim=dim, where=where)
        SplitReader(tmp.parent, tmp.name)  # re-open what was written: index and sizes must agree
        _swap_into_place(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created_root and root.is_dir() and not any(root.iterdir()):
            root.rmdir()
        raise
    return count


def write_dataset(
    root: str | os.PathLike,
    splits: Mapping[str, Iterable[Trajectory]],
    metadata: Metadata | Mapping[str, Any],
    overwrite: bool = False,
    metadata_where: str | None = None,
) -> Metadata:
    """Write a whole dataset (every split, then ``metadata.json``) atomically; return its final metadata.

    Args:
        root: the dataset folder to create. An existing non-empty folder is replaced only with
            ``overwrite=True``, and only if it is a gnsx dataset (has ``metadata.json``), so a typo cannot
            delete an unrelated folder.
        splits: ``{split: trajectories}``; each iterable is consumed once, in order, one trajectory in memory.
        metadata: :class:`Metadata` or a dict in DeepMind's schema. ``sequence_length`` and the statistics may
            be missing/``None``: ``sequence_length`` becomes the train split's shortest trajectory frames - 1,
            and the statistics are computed (:func:`~gnsx.data.metadata.compute_statistics`) from the written
            train split. A given ``sequence_length`` must agree with the data: no trajectory may be shorter
            than ``sequence_length + 1`` frames.
        metadata_where: names the metadata's source in error messages (e.g. the converted ``metadata.json``).

    Raises:
        DataError: the target exists (without ``overwrite``), bad metadata, statistics missing with no
            ``train`` split, or any bad trajectory. Nothing is left behind; an existing dataset is untouched.
    """
    root = Path(root)
    if isinstance(metadata, Metadata):
        metadata = metadata.to_dict()
    meta = Metadata.from_dict(metadata, where=f"{root / METADATA_FILE} (to write)", partial=True)
    for split in splits:
        _check_split_name(split, root)
    need_train = not meta.has_statistics or meta.sequence_length is None
    if need_train and "train" not in splits:
        raise DataError(
            str(root),
            "metadata lacks sequence_length or statistics and there is no 'train' split to derive them from",
        )
    _check_dataset_target(root, overwrite)

    # Absolute for the file operations: a relative root such as "." has no usable name or parent.
    target = Path(os.path.abspath(root))
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_abandoned_writes(target)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        (tmp / _OWNER_FILE).write_text(json.dumps(liveness()))
        for split, trajectories in splits.items():
            write_split(tmp, split, trajectories, dim=meta.dim, where=str(root / split))
        if meta.sequence_length is not None:
            _check_sequence_length(tmp, root, list(splits), meta.sequence_length, metadata_where)
        if need_train:
            train = SplitReader(tmp, "train")
            if len(train) == 0:
                raise DataError(str(root / "train"), "empty: cannot derive sequence_length or statistics")
            if meta.sequence_length is None:
                meta.sequence_length = int(train.frame_counts.min()) - 1
            if not meta.has_statistics:
                meta = meta.with_statistics(compute_statistics(train, where=str(root / "train")))
        meta = Metadata.from_dict(meta.to_dict(), where=str(root / METADATA_FILE))
        meta.save(tmp / METADATA_FILE)
        (tmp / _OWNER_FILE).unlink()
        _swap_into_place(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return meta


def _check_sequence_length(
    folder: Path, root: Path, splits: list[str], sequence_length: int, where: str | None
) -> None:
    """Refuse a ``sequence_length`` (transitions per trajectory) that promises more frames than a written
    trajectory has (longer trajectories are fine: rollouts use each trajectory's own length)."""
    where = where or str(root / METADATA_FILE)
    frames = sequence_length + 1
    problem = f"key 'sequence_length' is {sequence_length} ({frames} frames per trajectory) but"
    hint = "; fix the key or remove it (gnsx then derives it from the data)"
    for split in splits:
        counts = SplitReader(folder, split).frame_counts
        short = np.flatnonzero(counts < frames)
        if short.size:
            i = int(short[0])
            found = f"trajectory {i} of split '{split}' has {int(counts[i])} frames"
            raise DataError(where, f"{problem} {found}{hint}")


def _write_split_files(folder: Path, trajectories: Iterable[Trajectory], dim: int | None, where: str) -> int:
    """Append every trajectory to ``folder``'s three files; headers get their final shapes at the end."""
    rows: list[tuple[int, int, int, int, int]] = []
    position_rows = 0
    type_entries = 0
    with open(folder / POSITIONS_FILE, "wb") as fpos, open(folder / PARTICLE_TYPE_FILE, "wb") as ftype:
        # Reserve the headers; they are rewritten once the totals are known.
        fpos.write(b"\0" * _NPY_HEADER_BYTES)
        ftype.write(b"\0" * _NPY_HEADER_BYTES)
        for i, traj in enumerate(trajectories):
            check_trajectory(traj, trajectory_where(where, i), dim=dim)
            dim = traj.dim
            position = np.ascontiguousarray(traj.position, dtype=POSITION_DTYPE)  # [T, N, D]
            particle_type = np.ascontiguousarray(traj.particle_type, dtype=PARTICLE_TYPE_DTYPE)  # [N]
            num_frames, num_particles = position.shape[:2]
            rows.append((int(traj.key), num_frames, num_particles, position_rows, type_entries))
            fpos.write(position.data)
            ftype.write(particle_type.data)
            position_rows += num_frames * num_particles
            type_entries += num_particles
        dim = 0 if dim is None else dim
        _write_npy_header(fpos, POSITION_DTYPE, (position_rows, dim))
        _write_npy_header(ftype, PARTICLE_TYPE_DTYPE, (type_entries,))
        for f in (fpos, ftype):
            f.flush()
            os.fsync(f.fileno())
    np.save(folder / INDEX_FILE, np.array(rows, dtype=INDEX_DTYPE).reshape(len(rows)), allow_pickle=False)
    return len(rows)


def _write_npy_header(f: BinaryIO, dtype: np.dtype, shape: tuple[int, ...]) -> None:
    """Write a version-1.0 ``.npy`` header of exactly ``_NPY_HEADER_BYTES`` at the start of ``f``."""
    header = repr({"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape})
    prefix = np.lib.format.magic(1, 0)
    pad = _NPY_HEADER_BYTES - len(prefix) - 2 - len(header) - 1
    if pad < 0:
        raise ValueError(f"npy header for shape {shape} does not fit {_NPY_HEADER_BYTES} bytes")
    text = (header + " " * pad + "\n").encode("latin1")
    f.seek(0)
    f.write(prefix + len(text).to_bytes(2, "little") + text)
    f.seek(0, os.SEEK_END)


def _check_split_name(split: str, root: Path) -> None:
    if not isinstance(split, str) or not _SPLIT_NAME.match(split):
        raise DataError(str(root), f"invalid split name {split!r}: use a plain folder name such as 'train'")


def _check_dataset_target(root: Path, overwrite: bool) -> None:
    """Fail before any work if ``root`` may not be (re)written."""
    if not root.exists():
        return
    if not root.is_dir():
        raise DataError(str(root), "exists and is not a folder")
    if not any(root.iterdir()):
        return  # an empty folder (e.g. made by a job scheduler) is simply replaced
    if not overwrite:
        raise DataError(
            str(root), "dataset already exists; pass overwrite=True (CLI: --overwrite) to replace it"
        )
    if not (root / METADATA_FILE).is_file():
        raise DataError(
            str(root), f"exists but is not a gnsx dataset (no {METADATA_FILE}); refusing to replace it"
        )


def _remove_abandoned_writes(target: Path) -> None:
    """Delete the temporary folders of earlier writes of ``target`` whose writer died (SIGKILL leaves them:
    nothing runs to clean up), so a killed generation does not leak hundreds of MB per attempt.

    Only folders whose writer is known to be gone are deleted: written by a process on this host that no
    longer runs (:func:`gnsx.core.runstate.pid_alive`, pid start time checked). A folder of another host, or of
    a gnsx from before the writer record, is left alone with a warning naming it.
    """
    this_host = liveness()["host"]
    for folder in sorted(target.parent.glob(f".{target.name}.tmp-*")):
        if not folder.is_dir():
            continue
        try:
            owner = json.loads((folder / _OWNER_FILE).read_text())
            pid, start, host = int(owner["pid"]), owner.get("pid_start"), owner["host"]
        except (OSError, ValueError, KeyError, TypeError):
            log.warning("%s: left by an unfinished earlier write of %s (writer unknown); delete it to free "
                        "the space", folder, target)  # fmt: skip
            continue
        if host == this_host and not pid_alive(pid, start):
            log.info("Removing %s, left by a write of %s that was killed (pid %d)", folder, target, pid)
            shutil.rmtree(folder, ignore_errors=True)


def _swap_into_place(tmp: Path, target: Path) -> None:
    """Rename the finished ``tmp`` folder to ``target``, replacing an existing one only after success."""
    if not target.exists():
        os.rename(tmp, target)
        return
    old = target.parent / f".{target.name}.old-{uuid.uuid4().hex[:8]}"
    os.rename(target, old)
    try:
        os.rename(tmp, target)
    except BaseException:
        os.rename(old, target)
        raise
    shutil.rmtree(old, ignore_errors=True)
