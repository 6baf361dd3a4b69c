"""DeepMind ``learning_to_simulate`` TFRecord files (WaterRamps etc.), read and written without TensorFlow.

File framing (TFRecord), per record::

    uint64 length | uint32 masked_crc32c(length bytes) | length bytes of data | uint32 masked_crc32c(data)

Each record's data is a serialised ``tf.train.SequenceExample`` (``tfrecord.example_pb2``, bundled with the
PyPI ``tfrecord`` package):

- context ``key``: ``int64_list`` with one value (the trajectory id; DeepMind defaults it to 0);
- context ``particle_type``: ``bytes_list`` with one value, the raw little-endian int64 array ``[N]``;
- feature list ``position``: one ``bytes_list`` feature per frame, each the raw float32 array ``[N * dim]``;
- feature list ``step_context`` (only in datasets whose metadata has ``context_mean``): one raw float32 vector
  per frame. gnsx's :class:`~gnsx.data.trajectory.Trajectory` has no global context, so it is accepted and
  ignored.

``dim`` is not in the records: it comes from the ``metadata.json`` beside them. The ``tfrecord`` package's own
reader skips the CRCs, so gnsx frames records itself and checks both CRCs, naming the file and record index
of a truncated or corrupt record.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

import crc32c
import numpy as np
from google.protobuf.message import DecodeError
from tfrecord import example_pb2

from gnsx.core.atomic import atomic_path
from gnsx.core.errors import DataError
from gnsx.data.trajectory import Trajectory
from gnsx.data.validate import check_trajectory, trajectory_where

_CRC_MASK_DELTA = 0xA282EAD8


def masked_crc(data: bytes | memoryview) -> int:
    """TFRecord's masked CRC32-C of ``data`` (rotate right by 15, add a constant), as in TensorFlow."""
    crc = crc32c.crc32c(data)
    return (((crc >> 15) | (crc << 17)) + _CRC_MASK_DELTA) & 0xFFFFFFFF


def iter_records(path: str | os.PathLike) -> Iterator[tuple[int, bytes]]:
    """Yield ``(record_index, data)`` for each record of a TFRecord file, checking lengths and both CRCs.

    Raises:
        DataError: ``"<path>: record <i>: ..."`` for a truncated record or a CRC mismatch.
    """
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise DataError(str(path), f"cannot open: {e.strerror or e}") from None
    with f:
        size = os.fstat(f.fileno()).st_size
        index = 0
        while True:
            offset = f.tell()
            header = f.read(12)
            if not header:
                return
            where = f"{path}: record {index} (byte offset {offset})"
            if len(header) < 12:
                raise DataError(
                    where, f"truncated: file ends inside the record header ({len(header)} of 12 bytes)"
                )
            length_bytes, (length_crc,) = header[:8], struct.unpack("<I", header[8:])
            if masked_crc(length_bytes) != length_crc:
                raise DataError(where, "corrupt: length header fails its CRC check")
            (length,) = struct.unpack("<Q", length_bytes)
            if offset + 12 + length + 4 > size:
                raise DataError(
                    where,
                    f"truncated: the record needs {length + 4} more bytes, the file has {size - offset - 12}",
                )
            data = f.read(length)
            (data_crc,) = struct.unpack("<I", f.read(4))
            if masked_crc(data) != data_crc:
                raise DataError(where, "corrupt: record data fails its CRC check")
            yield index, data
            index += 1


def read_tfrecord(path: str | os.PathLike, dim: int) -> Iterator[Trajectory]:
    """Yield the trajectories of a DeepMind TFRecord file, validated, one record in memory at a time.

    Args:
        path: ``{split}.tfrecord``.
        dim: spatial dimension (metadata ``dim``): each frame's float32 count must be ``N * dim``.

    Raises:
        DataError: naming the file, record index and field (framing, protobuf, layout or
            :func:`~gnsx.data.validate.check_trajectory` errors).
    """
    for index, data in iter_records(path):
        where = trajectory_where(path, index)
        traj = _decode(data, dim, where, index)
        check_trajectory(traj, where, dim=dim)
        yield traj


def _decode(data: bytes, dim: int, where: str, index: int) -> Trajectory:
    example = example_pb2.SequenceExample()
    try:
        example.ParseFromString(data)
    except DecodeError as e:
        raise DataError(where, f"not a tf.train.SequenceExample ({e})") from None
    context = example.context.feature
    lists = example.feature_lists.feature_list
    if "particle_type" not in context:
        raise DataError(where, f"missing context field 'particle_type' (has: {sorted(context) or 'none'})")
    if "position" not in lists:
        raise DataError(where, f"missing feature list 'position' (has: {sorted(lists) or 'none'})")

    key = index  # DeepMind parses a missing key as 0; the record index is the more useful id.
    if "key" in context:
        values = context["key"].int64_list.value
        if len(values) != 1:
            raise DataError(where, f"context field 'key': expected one int64, got {len(values)} values")
        key = int(values[0])

    type_bytes = b"".join(context["particle_type"].bytes_list.value)
    if len(type_bytes) % 8:
        raise DataError(
            where, f"context field 'particle_type': {len(type_bytes)} bytes is not a whole int64 array"
        )
    particle_type = np.frombuffer(type_bytes, dtype="<i8").astype(np.int64)
    num_particles = particle_type.shape[0]

    frames = lists["position"].feature
    position = np.empty((len(frames), num_particles, dim), dtype=np.float32)
    for k, feature in enumerate(frames):
        raw = b"".join(feature.bytes_list.value)
        if len(raw) != 4 * num_particles * dim:
            raise DataError(
                where,
                f"field 'position': frame {k} has {len(raw)} bytes, expected {4 * num_particles * dim} "
                f"({num_particles} particles x dim {dim} x float32)",
            )
        position[k] = np.frombuffer(raw, dtype="<f4").reshape(num_particles, dim)
    return Trajectory(position=position, particle_type=particle_type, key=key)


def encode_trajectory(traj: Trajectory) -> bytes:
    """Serialise one trajectory as DeepMind's ``tf.train.SequenceExample`` (the record data, unframed)."""
    position = np.ascontiguousarray(traj.position, dtype="<f4")  # [T, N, D]
    example = example_pb2.SequenceExample()
    example.context.feature["key"].int64_list.value.append(int(traj.key))
    example.context.feature["particle_type"].bytes_list.value.append(
        np.ascontiguousarray(traj.particle_type, dtype="<i8").tobytes()
    )
    frames = example.feature_lists.feature_list["position"].feature
    for frame in position:
        frames.add().bytes_list.value.append(frame.tobytes())
    return example.SerializeToString()


def write_record(f: BinaryIO, data: bytes) -> None:
    """Append one framed record (length, CRCs) to an open binary file."""
    length = struct.pack("<Q", len(data))
    f.write(length + struct.pack("<I", masked_crc(length)) + data + struct.pack("<I", masked_crc(data)))


def write_tfrecord(path: str | os.PathLike, trajectories: Iterable[Trajectory]) -> int:
    """Write trajectories as a DeepMind TFRecord file (atomic: temp file, then rename); return the count.

    Each trajectory is validated first; ``step_context`` is never written.
    """
    path = Path(path)
    count = 0
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        for i, traj in enumerate(trajectories):
            check_trajectory(traj, trajectory_where(path, i))
            write_record(f, encode_trajectory(traj))
            count += 1
    return count
