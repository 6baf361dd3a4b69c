"""Readers/writers for DeepMind TFRecord, geoelements .npz, LagrangeBench .h5; convert into the store."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from tfrecord import example_pb2
from tfrecord.reader import tfrecord_iterator
from tfrecord.writer import TFRecordWriter

from gnsx.core.errors import DataError
from gnsx.data.formats import (
    FORMATS,
    convert,
    detect_format,
    export_dataset,
    read_split,
    split_file,
    write_split_as,
)
from gnsx.data.metadata import compute_statistics
from gnsx.data.store import SplitReader, load_metadata
from gnsx.data.trajectory import Trajectory

GEOMETRY = {"bounds": [[0.1, 0.9], [0.1, 0.9]], "default_connectivity_radius": 0.05, "dim": 2, "dt": 0.0025}
STATS = {"vel_mean": [0.0, -1e-4], "vel_std": [2e-3, 2e-3], "acc_mean": [0.0, -1e-5], "acc_std": [2e-4, 2e-4]}


def random_trajectories(n: int, seed: int = 0, dim: int = 2, key0: int = 40) -> list[Trajectory]:
    """Trajectories of varying frame and particle counts with water (5), sand (6) and static (3) particles."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        frames, particles = int(rng.integers(4, 9)), int(rng.integers(3, 7))
        position = rng.random((frames, particles, dim)).astype(np.float32)
        particle_type = rng.choice(np.array([3, 5, 6]), size=particles).astype(np.int64)
        particle_type[0] = 5  # at least one moving particle per trajectory
        out.append(Trajectory(position=position, particle_type=particle_type, key=key0 + 3 * i))
    return out


def assert_same(a: list[Trajectory], b: list[Trajectory]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.key == y.key
        assert y.particle_type.dtype == np.int64 and np.array_equal(x.particle_type, y.particle_type)
        assert y.position.dtype == np.float32 and np.array_equal(x.position, y.position)


def make_source(folder: Path, fmt: str, splits: dict[str, list[Trajectory]], metadata: dict | None) -> Path:
    for split, trajectories in splits.items():
        assert write_split_as(fmt, folder, split, trajectories) == len(trajectories)
    if metadata is not None:
        (folder / "metadata.json").write_text(json.dumps(metadata))
    return folder


# ----------------------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("dim", [2, 3])
def test_writer_reader_round_trip_is_exact(tmp_path, fmt, dim):
    trajectories = random_trajectories(4, seed=dim, dim=dim)
    make_source(tmp_path, fmt, {"valid": trajectories}, {**GEOMETRY, "dim": dim, "bounds": [[0, 1]] * dim})
    assert detect_format(tmp_path) == fmt
    assert_same(trajectories, list(read_split(tmp_path, "valid")))
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # temp files renamed


def test_tfrecord_file_has_deepminds_sequence_example_layout(tmp_path):
    trajectories = random_trajectories(3, seed=1)
    path = split_file(tmp_path, "train", "tfrecord")
    write_split_as("tfrecord", tmp_path, "train", trajectories)
    # Parsed with the tfrecord package's framing and protobuf classes only, not gnsx's reader.
    records = [bytes(view) for view in tfrecord_iterator(str(path))]  # it reuses one buffer: copy
    assert len(records) == 3
    for raw, traj in zip(records, trajectories, strict=True):
        example = example_pb2.SequenceExample()
        example.ParseFromString(raw)
        context = example.context.feature
        assert sorted(context) == ["key", "particle_type"]
        assert list(context["key"].int64_list.value) == [traj.key]
        assert list(context["particle_type"].bytes_list.value) == [traj.particle_type.astype("<i8").tobytes()]
        assert sorted(example.feature_lists.feature_list) == ["position"]
        frames = example.feature_lists.feature_list["position"].feature
        assert len(frames) == traj.num_frames
        for k, feature in enumerate(frames):
            assert list(feature.bytes_list.value) == [traj.position[k].astype("<f4").tobytes()]


def test_reads_tfrecord_written_by_the_tfrecord_package(tmp_path):
    # An independent writer (its own framing and CRCs), with DeepMind's layout and an extra step_context.
    trajectories = random_trajectories(2, seed=2)
    writer = TFRecordWriter(str(tmp_path / "test.tfrecord"))
    for traj in trajectories:
        writer.write(
            {"key": (traj.key, "int"), "particle_type": (traj.particle_type.tobytes(), "byte")},
            {
                "position": ([frame.tobytes() for frame in traj.position], "byte"),
                "step_context": ([np.float32([0.5]).tobytes()] * traj.num_frames, "byte"),
            },
        )
    writer.close()
    (tmp_path / "metadata.json").write_text(json.dumps({**GEOMETRY, "sequence_length": 5}))
    assert_same(trajectories, list(read_split(tmp_path, "test", "tfrecord")))


def test_reads_geoelements_npz_layouts(tmp_path):
    trajectories = random_trajectories(3, seed=3)

    def item(traj, particle_type=None):
        # What np.savez(**{name: (positions, types)}) stored before numpy refused ragged tuples.
        out = np.empty(2, dtype=object)
        out[0] = traj.position.astype(np.float64)  # geoelements' converters write float64
        out[1] = traj.particle_type if particle_type is None else particle_type
        return out

    np.savez_compressed(
        tmp_path / "train.npz", **{f"simulation_trajectory_{t.key}": item(t) for t in trajectories}
    )
    assert_same(trajectories, list(read_split(tmp_path, "train", "npz")))

    # The 'gns_data' layout, and one scalar type for all particles (geoelements' loader np.full()s it).
    uniform = Trajectory(trajectories[0].position, np.full(trajectories[0].num_particles, 6), key=0)
    gns_data = np.empty(1, dtype=object)
    gns_data[0] = item(uniform, np.int64(6))
    np.savez(tmp_path / "valid.npz", gns_data=gns_data)
    assert_same([uniform], list(read_split(tmp_path, "valid", "npz")))


def test_reads_lagrangebench_h5_without_key_attributes(tmp_path):
    trajectories = random_trajectories(3, seed=4, key0=0)  # keys 0, 3, 6: the group names
    with h5py.File(tmp_path / "train.h5", "w") as f:
        for traj in trajectories:
            f.create_dataset(f"{traj.key:05d}/position", data=traj.position)
            f.create_dataset(f"{traj.key:05d}/particle_type", data=traj.particle_type)
    assert_same(trajectories, list(read_split(tmp_path, "train", "h5")))


# ----------------------------------------------------------------------------------------------- bad input


def _tfrecord_source(tmp_path: Path, n: int = 3) -> Path:
    make_source(
        tmp_path, "tfrecord", {"train": random_trajectories(n, seed=5)}, {**GEOMETRY, "sequence_length": 5}
    )
    return tmp_path / "train.tfrecord"


def test_truncated_tfrecord_names_file_and_record(tmp_path):
    path = _tfrecord_source(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[:-30])
    reader = read_split(tmp_path, "train")
    assert next(reader).key == 40  # records before the damage still read
    next(reader)
    with pytest.raises(DataError) as err:
        next(reader)
    assert str(err.value).startswith(f"{path}: record 2 (byte offset ")
    assert "truncated: the record needs" in str(err.value)
    path.write_bytes(data + data[:5])
    with pytest.raises(DataError, match="record 3 .*truncated: file ends inside the record header"):
        list(read_split(tmp_path, "train"))


def test_corrupt_tfrecord_fails_its_crc(tmp_path):
    path = _tfrecord_source(tmp_path)
    data = bytearray(path.read_bytes())
    first_length = int.from_bytes(data[:8], "little")
    data[12 + first_length + 4 + 12 + 40] ^= 0xFF  # a byte inside record 1's data
    path.write_bytes(bytes(data))
    with pytest.raises(
        DataError, match=r"train.tfrecord: record 1 \(byte offset \d+\): corrupt: record data fails"
    ):
        list(read_split(tmp_path, "train"))
    data[3] ^= 0x01  # record 0's length field
    path.write_bytes(bytes(data))
    with pytest.raises(DataError, match="record 0 .*corrupt: length header fails its CRC"):
        list(read_split(tmp_path, "train"))


def test_tfrecord_with_the_wrong_dim_names_the_field_and_frame(tmp_path):
    path = _tfrecord_source(tmp_path)
    (tmp_path / "metadata.json").write_text(json.dumps({**GEOMETRY, "dim": 3, "bounds": [[0, 1]] * 3}))
    with pytest.raises(DataError) as err:
        list(read_split(tmp_path, "train"))
    assert str(err.value).startswith(f"{path}, trajectory 0: field 'position': frame 0 has ")
    (tmp_path / "metadata.json").unlink()
    with pytest.raises(DataError, match="metadata.json: metadata file not found"):
        read_split(tmp_path, "train")


def test_tfrecord_missing_field_is_named(tmp_path):
    writer = TFRecordWriter(str(tmp_path / "train.tfrecord"))
    writer.write({"key": (1, "int")}, {"position": ([b"\0" * 8], "byte")})
    writer.close()
    (tmp_path / "metadata.json").write_text(json.dumps(GEOMETRY))
    with pytest.raises(
        DataError, match=r"trajectory 0: missing context field 'particle_type' \(has: \['key'\]\)"
    ):
        list(read_split(tmp_path, "train"))


def test_npz_and_h5_bad_inputs_name_file_and_trajectory(tmp_path):
    trajectories = random_trajectories(3, seed=6)
    trajectories[1].position[2, 0, 1] = np.inf
    with pytest.raises(DataError, match="train.npz, trajectory 1: field 'position': frame 2 has Inf"):
        write_split_as("npz", tmp_path, "train", trajectories)
    assert list(tmp_path.iterdir()) == []  # the failed write left nothing

    trajectories[1].position[2, 0, 1] = 0.5
    write_split_as("npz", tmp_path, "train", trajectories)
    data = (tmp_path / "train.npz").read_bytes()
    (tmp_path / "train.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="train.npz: not a readable .npz file"):
        list(read_split(tmp_path, "train", "npz"))

    with h5py.File(tmp_path / "valid.h5", "w") as f:
        f.create_dataset("00000/position", data=trajectories[0].position)
        f.create_dataset("00000/particle_type", data=trajectories[0].particle_type)
        f.create_dataset("00001/position", data=trajectories[1].position)
    with pytest.raises(DataError) as err:
        list(read_split(tmp_path, "valid", "h5"))
    assert str(err.value) == (
        f"{tmp_path / 'valid.h5'}, trajectory 1 (group '00001'): "
        "missing dataset 'particle_type' (has: ['position'])"
    )
    (tmp_path / "test.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(DataError, match="test.h5: not a readable HDF5 file"):
        list(read_split(tmp_path, "test", "h5"))


def test_npz_member_with_a_damaged_payload_is_named(tmp_path):
    write_split_as("npz", tmp_path, "train", random_trajectories(2, seed=7))
    path = tmp_path / "train.npz"
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    with zipfile.ZipFile(path, "w") as zf:  # rewrite with the second member's pickle cut short
        for name, blob in members.items():
            zf.writestr(name, blob[: len(blob) // 2] if name == "simulation_trajectory_43.npy" else blob)
    reader = read_split(tmp_path, "train", "npz")
    assert next(reader).key == 40
    with pytest.raises(
        DataError, match="member 'simulation_trajectory_43'.*cannot read: truncated or corrupt"
    ):
        next(reader)


def test_detect_format_errors(tmp_path):
    with pytest.raises(DataError, match="no dataset files found"):
        detect_format(tmp_path)
    (tmp_path / "train.npz").touch()
    (tmp_path / "train.h5").touch()
    with pytest.raises(DataError, match=r"several formats \(npz, h5\); choose one with --format"):
        detect_format(tmp_path)
    with pytest.raises(DataError, match="unknown format 'csv'"):
        read_split(tmp_path, "train", "csv")


# ----------------------------------------------------------------------------------------------- convert


def test_convert_tfrecord_keeps_source_metadata_and_round_trips(tmp_path):
    train, test = random_trajectories(4, seed=8), random_trajectories(2, seed=9, key0=0)
    shortest = min(t.num_frames for t in train + test)  # sequence_length must agree with the data
    source_meta = {**GEOMETRY, "sequence_length": shortest - 1, **STATS, "context_mean": [0.25]}
    src = make_source(tmp_path / "src", "tfrecord", {"train": train, "test": test}, source_meta)
    meta = convert(src, tmp_path / "dst")
    assert meta.to_dict() == source_meta  # kept verbatim, statistics not recomputed
    assert load_metadata(tmp_path / "dst") == meta
    assert_same(train, list(SplitReader(tmp_path / "dst", "train")))
    assert_same(test, list(SplitReader(tmp_path / "dst", "test")))
    with pytest.raises(DataError, match="dataset already exists"):
        convert(src, tmp_path / "dst")
    with pytest.raises(DataError, match="destination is the source folder"):
        convert(src, src, overwrite=True)


@pytest.mark.parametrize("fmt", ["npz", "h5"])
def test_convert_without_metadata_needs_flags_then_computes_statistics(tmp_path, fmt):
    train = random_trajectories(3, seed=10)
    src = make_source(tmp_path / "src", fmt, {"train": train, "valid": train[:1]}, None)
    with pytest.raises(DataError) as err:
        convert(src, tmp_path / "dst")
    assert str(err.value) == (
        f"{src}: no metadata.json, so gnsx lacks bounds, dt, default_connectivity_radius: "
        "pass --bounds LO HI [LO HI ...], --dt SECONDS, --radius R"
    )
    with pytest.raises(DataError, match="lacks dt: pass --dt SECONDS"):
        convert(src, tmp_path / "dst", bounds=[[0, 1], [0, 1]], radius=0.1)
    assert not (tmp_path / "dst").exists()

    meta = convert(src, tmp_path / "dst", bounds=[[0, 1], [0, 2]], dt=0.01, radius=0.1)
    assert (meta.dim, meta.dt, meta.default_connectivity_radius) == (2, 0.01, 0.1)
    assert meta.bounds == [[0.0, 1.0], [0.0, 2.0]]
    assert meta.sequence_length == min(t.num_frames for t in train) - 1
    expected = compute_statistics(train)
    for key, value in expected.items():
        assert getattr(meta, key) == pytest.approx(value, rel=1e-12)
    assert_same(train, list(SplitReader(tmp_path / "dst", "train")))


def test_convert_remaps_particle_types(tmp_path):
    train = random_trajectories(2, seed=11)
    src = make_source(tmp_path / "src", "h5", {"train": train}, {**GEOMETRY, **STATS, "sequence_length": 3})
    convert(src, tmp_path / "dst", type_map={5: 0, 3: 1})
    stored = list(SplitReader(tmp_path / "dst", "train"))
    for original, converted in zip(train, stored, strict=True):
        expected = np.select(
            [original.particle_type == 5, original.particle_type == 3], [0, 1], original.particle_type
        )
        assert np.array_equal(converted.particle_type, expected)
    with pytest.raises(DataError, match="type id 12 outside"):
        convert(src, tmp_path / "dst2", type_map={5: 12})


def test_convert_stops_at_a_bad_source_trajectory_and_writes_nothing(tmp_path):
    train = random_trajectories(3, seed=12)
    train[2].position[1, 2, 0] = np.nan
    src = tmp_path / "src"
    src.mkdir()
    with h5py.File(src / "train.h5", "w") as f:  # written directly: gnsx's writer would refuse the NaN
        for i, traj in enumerate(train):
            f.create_dataset(f"{i:05d}/position", data=traj.position)
            f.create_dataset(f"{i:05d}/particle_type", data=traj.particle_type)
    (src / "metadata.json").write_text(json.dumps({**GEOMETRY, **STATS, "sequence_length": 3}))
    with pytest.raises(DataError) as err:
        convert(src, tmp_path / "dst")
    assert str(err.value) == (
        f"{src / 'train.h5'}, trajectory 2 (group '00002'): field 'position': frame 1 has NaN (particle 2)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_convert_rejects_invalid_source_metadata(tmp_path):
    src = make_source(
        tmp_path / "src", "npz", {"train": random_trajectories(1)}, {**GEOMETRY, "vel_std": [1.0]}
    )
    with pytest.raises(DataError) as err:
        convert(src, tmp_path / "dst")
    assert str(err.value).startswith(f"{src / 'metadata.json'}: key 'vel_std': expected a list of 2 numbers")


def test_export_then_convert_back_is_exact(tmp_path):
    train = random_trajectories(3, seed=13)
    src = make_source(tmp_path / "src", "npz", {"train": train}, {**GEOMETRY, **STATS, "sequence_length": 3})
    convert(src, tmp_path / "store")
    counts = export_dataset(tmp_path / "store", tmp_path / "tf", "tfrecord")
    assert counts == {"train": 3}
    with pytest.raises(DataError, match="already exists"):
        export_dataset(tmp_path / "store", tmp_path / "tf", "tfrecord")
    convert(tmp_path / "tf", tmp_path / "store2")
    assert_same(train, list(SplitReader(tmp_path / "store2", "train")))
    assert load_metadata(tmp_path / "store2") == load_metadata(tmp_path / "store")
