"""Readers and writers for the dataset formats users hold, and conversion into gnsx's store.

=============  ==================  ===============================================================
``fmt``        files               module
=============  ==================  ===============================================================
``tfrecord``   ``{split}.tfrecord``  DeepMind ``learning_to_simulate`` (WaterRamps ...), :mod:`.tfrecord`
``npz``        ``{split}.npz``       geoelements/gns, :mod:`.npz` (numpy-only unpickler, no code)
``h5``         ``{split}.h5``        LagrangeBench, :mod:`.hdf5`
=============  ==================  ===============================================================

Each source folder may hold a ``metadata.json`` (DeepMind's schema) beside the split files. :func:`convert`
keeps it (validated) and computes what it lacks: ``sequence_length`` and the normalisation statistics from the
data; ``bounds``, ``dt`` and ``default_connectivity_radius`` cannot be derived and must come from the caller
(CLI ``--bounds``, ``--dt``, ``--radius``) when the folder has no metadata with them. Particle type ids can be
remapped on the way (``type_map``; LagrangeBench's ids differ from DeepMind's, see :mod:`.hdf5`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.constants import NUM_PARTICLE_TYPES, SPLITS
from gnsx.core.errors import DataError
from gnsx.data.formats.hdf5 import read_h5, write_h5
from gnsx.data.formats.npz import read_npz, write_npz
from gnsx.data.formats.tfrecord import read_tfrecord, write_tfrecord
from gnsx.data.metadata import Metadata, read_metadata_json
from gnsx.data.store import METADATA_FILE, SplitReader, list_splits, load_metadata, write_dataset
from gnsx.data.trajectory import Trajectory

#: Format name -> file suffix of ``{split}{suffix}``.
FORMAT_SUFFIXES = {"tfrecord": ".tfrecord", "npz": ".npz", "h5": ".h5"}
FORMATS = tuple(FORMAT_SUFFIXES)

_WRITERS: dict[str, Callable[[Path, Iterable[Trajectory]], int]] = {
    "tfrecord": write_tfrecord,
    "npz": write_npz,
    "h5": write_h5,
}

__all__ = [
    "FORMATS",
    "FORMAT_SUFFIXES",
    "convert",
    "detect_format",
    "export_dataset",
    "read_split",
    "split_file",
    "write_split_as",
]


def split_file(src_dir: str | os.PathLike, split: str, fmt: str) -> Path:
    """The path of ``split`` in format ``fmt`` under ``src_dir``: ``{src_dir}/{split}{suffix}``."""
    return Path(src_dir) / f"{split}{FORMAT_SUFFIXES[_check_format(fmt)]}"


def detect_format(src_dir: str | os.PathLike) -> str:
    """The format of the split files in ``src_dir`` (``"tfrecord"``, ``"npz"`` or ``"h5"``).

    Raises:
        DataError: no split file of any format, or files of several formats (pass ``fmt`` explicitly).
    """
    src = Path(src_dir)
    if not src.is_dir():
        raise DataError(str(src), "source folder not found")
    found = [fmt for fmt, suffix in FORMAT_SUFFIXES.items() if any(src.glob(f"*{suffix}"))]
    if not found:
        expected = ", ".join(f"{{split}}{suffix}" for suffix in FORMAT_SUFFIXES.values())
        raise DataError(str(src), f"no dataset files found (looked for {expected})")
    if len(found) > 1:
        raise DataError(str(src), f"files of several formats ({', '.join(found)}); choose one with --format")
    return found[0]


def read_split(
    src_dir: str | os.PathLike, split: str, fmt: str | None = None, dim: int | None = None
) -> Iterator[Trajectory]:
    """Iterate over the validated trajectories of one split of a source dataset, one in memory at a time.

    Args:
        src_dir: folder holding ``{split}{suffix}`` (and usually ``metadata.json``).
        split: e.g. ``"train"``.
        fmt: ``"tfrecord"``, ``"npz"`` or ``"h5"``; ``None`` detects it (:func:`detect_format`).
        dim: spatial dimension, needed by TFRecord only (its records do not store it); ``None`` reads
            ``dim`` from ``{src_dir}/metadata.json``. For the other formats it is checked when given.

    Raises:
        DataError: missing file or metadata (raised here, before iteration starts), then per-trajectory
            errors naming the file, trajectory, field and frame during iteration.
    """
    fmt = _check_format(fmt) if fmt is not None else detect_format(src_dir)
    path = split_file(src_dir, split, fmt)
    if not path.is_file():
        raise DataError(str(path), f"split file not found (format {fmt})")
    if fmt == "tfrecord":
        if dim is None:
            meta_path = Path(src_dir) / METADATA_FILE
            raw = read_metadata_json(meta_path)
            if "dim" not in raw:
                raise DataError(str(meta_path), "missing key 'dim' (TFRecord positions need it)")
            dim = Metadata.from_dict(raw, where=str(meta_path), partial=True).dim
        return read_tfrecord(path, dim)
    trajectories = read_npz(path) if fmt == "npz" else read_h5(path)
    return trajectories if dim is None else _check_dim(trajectories, dim, path)


def write_split_as(
    fmt: str, dst_dir: str | os.PathLike, split: str, trajectories: Iterable[Trajectory]
) -> int:
    """Write ``trajectories`` as ``{dst_dir}/{split}{suffix}`` in format ``fmt`` (atomic); return the count.

    TFRecord readers also need a ``metadata.json`` with ``dim`` beside the file (see :func:`export_dataset`).
    """
    path = split_file(dst_dir, split, fmt)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _WRITERS[fmt](path, trajectories)


def export_dataset(
    root: str | os.PathLike, dst_dir: str | os.PathLike, fmt: str, overwrite: bool = False
) -> dict[str, int]:
    """Export a gnsx dataset to another format: every split plus ``metadata.json``; return counts per split.

    Raises:
        DataError: unreadable source, or a destination split file / metadata that exists (without overwrite).
    """
    fmt = _check_format(fmt)
    meta = load_metadata(root)
    dst = Path(dst_dir)
    splits = list_splits(root)
    targets = [split_file(dst, split, fmt) for split in splits] + [dst / METADATA_FILE]
    existing = [str(p) for p in targets if p.exists()]
    if existing and not overwrite:
        raise DataError(existing[0], "already exists; pass overwrite=True (CLI: --overwrite) to replace it")
    dst.mkdir(parents=True, exist_ok=True)
    counts = {split: write_split_as(fmt, dst, split, SplitReader(root, split)) for split in splits}
    meta.save(dst / METADATA_FILE)
    return counts


def convert(
    src_dir: str | os.PathLike,
    dst_root: str | os.PathLike,
    fmt: str | None = None,
    overwrite: bool = False,
    *,
    bounds: Sequence[Sequence[float]] | None = None,
    dt: float | None = None,
    radius: float | None = None,
    type_map: Mapping[int, int] | None = None,
) -> Metadata:
    """Convert a source dataset (every split file found) into a gnsx store at ``dst_root``.

    Args:
        src_dir: folder with ``{split}{suffix}`` files for some of ``train``, ``valid``, ``test``.
        dst_root: gnsx dataset folder to write (atomically; see :func:`~gnsx.data.store.write_dataset`).
        fmt: source format; ``None`` detects it.
        overwrite: replace an existing gnsx dataset at ``dst_root``.
        bounds: ``[dim][lo, hi]``; overrides / supplies the metadata's ``bounds`` (and ``dim`` when absent).
        dt: seconds between frames; overrides / supplies ``dt``.
        radius: overrides / supplies ``default_connectivity_radius``.
        type_map: ``{source id: gnsx id}`` applied to every particle type (ids not listed are kept), e.g.
            LagrangeBench to DeepMind ``{0: 5, 1: 3, 2: 3, 3: 0}``; the statistics use the mapped types.

    Returns:
        The written metadata: the source's (validated; other keys kept verbatim), with the caller's values,
        and ``sequence_length`` and statistics computed from the data when the source lacks them.

    Raises:
        DataError: unknown or ambiguous format, no split files, invalid source metadata, missing
            ``bounds``/``dt``/radius (listing the CLI flags to pass), or any bad trajectory.
    """
    src, dst = Path(src_dir), Path(dst_root)
    if not src.is_dir():
        raise DataError(str(src), "source folder not found")
    if dst.resolve() == src.resolve():
        raise DataError(str(dst), "destination is the source folder; choose another folder")
    fmt = _check_format(fmt) if fmt is not None else detect_format(src)
    splits = [split for split in SPLITS if split_file(src, split, fmt).is_file()]
    if not splits:
        names = ", ".join(split_file(src, s, fmt).name for s in SPLITS)
        raise DataError(str(src), f"no split files in format {fmt} (looked for {names})")

    meta_path = src / METADATA_FILE
    raw: dict[str, Any] = read_metadata_json(meta_path) if meta_path.is_file() else {}
    if bounds is not None:
        raw["bounds"] = [[float(lo), float(hi)] for lo, hi in bounds]
    if dt is not None:
        raw["dt"] = float(dt)
    if radius is not None:
        raw["default_connectivity_radius"] = float(radius)
    if "dim" not in raw and "bounds" in raw:
        raw["dim"] = len(raw["bounds"])
    flags = {
        "bounds": "--bounds LO HI [LO HI ...]",
        "dt": "--dt SECONDS",
        "default_connectivity_radius": "--radius R",
    }
    missing = [key for key in flags if raw.get(key) is None]
    if missing:
        source = f"{meta_path} lacks" if meta_path.is_file() else f"no {METADATA_FILE}, so gnsx lacks"
        raise DataError(
            str(src),
            f"{source} {', '.join(missing)}: pass {', '.join(flags[k] for k in missing)}",
        )
    meta = Metadata.from_dict(raw, where=str(meta_path), partial=True)
    sources = {split: read_split(src, split, fmt, dim=meta.dim) for split in splits}
    if type_map:
        lookup = _type_lookup(type_map)
        sources = {split: _remap_types(trajs, lookup) for split, trajs in sources.items()}
    return write_dataset(dst, sources, meta, overwrite=overwrite, metadata_where=str(meta_path))


def _check_format(fmt: str) -> str:
    if fmt not in FORMAT_SUFFIXES:
        raise DataError("format", f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    return fmt


def _type_lookup(type_map: Mapping[int, int]) -> np.ndarray:
    """``[NUM_PARTICLE_TYPES]`` int64 table: entry ``t`` is the gnsx id of source id ``t``."""
    lookup = np.arange(NUM_PARTICLE_TYPES, dtype=np.int64)
    for source, target in type_map.items():
        for value in (source, target):
            if not 0 <= int(value) < NUM_PARTICLE_TYPES:
                raise DataError(
                    "type_map", f"type id {value} outside 0..{NUM_PARTICLE_TYPES - 1} in {dict(type_map)}"
                )
        lookup[int(source)] = int(target)
    return lookup


def _remap_types(trajectories: Iterable[Trajectory], lookup: np.ndarray) -> Iterator[Trajectory]:
    for traj in trajectories:
        # Readers have validated the ids (0..NUM_PARTICLE_TYPES-1), so they index the table safely.
        yield Trajectory(position=traj.position, particle_type=lookup[traj.particle_type], key=traj.key)


def _check_dim(trajectories: Iterator[Trajectory], dim: int, path: Path) -> Iterator[Trajectory]:
    for i, traj in enumerate(trajectories):
        if traj.dim != dim:
            raise DataError(
                f"{path}, trajectory {i}",
                f"field 'position': dim is {traj.dim} but the metadata's dim is {dim}",
            )
        yield traj
