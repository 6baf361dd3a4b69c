"""gnsx's store, metadata and validation: round trips, hand-computed statistics, bad inputs, atomicity."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from gnsx.core.errors import DataError
from gnsx.data.metadata import Metadata, compute_statistics
from gnsx.data.store import (
    INDEX_FILE,
    POSITIONS_FILE,
    SplitReader,
    list_splits,
    load_metadata,
    write_dataset,
    write_split,
)
from gnsx.data.trajectory import Trajectory
from gnsx.data.validate import check_trajectory

GEOMETRY = {"bounds": [[0.1, 0.9], [0.1, 0.9]], "default_connectivity_radius": 0.05, "dim": 2, "dt": 0.0025}
STATS = {"vel_mean": [0.0, -1e-4], "vel_std": [2e-3, 2e-3], "acc_mean": [0.0, -1e-5], "acc_std": [2e-4, 2e-4]}


def random_trajectories(n: int, seed: int = 0, dim: int = 2, key0: int = 100) -> list[Trajectory]:
    """Trajectories of varying frame and particle counts, with water (5) and static (3) particles."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        frames, particles = int(rng.integers(4, 9)), int(rng.integers(3, 7))
        start = rng.random((1, particles, dim))
        position = (start + np.cumsum(0.01 * rng.standard_normal((frames, particles, dim)), axis=0)).astype(
            np.float32
        )
        particle_type = np.where(np.arange(particles) == 0, 3, 5).astype(np.int64)
        out.append(Trajectory(position=position, particle_type=particle_type, key=key0 + 7 * i))
    return out


def assert_same(a: list[Trajectory], b: list[Trajectory]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.key == y.key
        assert np.array_equal(x.particle_type, y.particle_type)
        assert x.position.dtype == y.position.dtype == np.float32
        assert np.array_equal(x.position, y.position)


def tree(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` with its bytes (to prove a dataset was not touched)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


# ----------------------------------------------------------------------------------------------- metadata


def test_metadata_save_load_keeps_extra_keys_verbatim(tmp_path):
    extra = {"context_mean": [0.5], "gnsx": {"preset": "small", "seed": 3}}
    meta = Metadata.from_dict({**GEOMETRY, "sequence_length": 600, **STATS, **extra}, where="x")
    path = tmp_path / "metadata.json"
    meta.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["metadata.json"]  # the temp file was renamed away
    loaded = Metadata.load(path)
    assert loaded == meta
    assert loaded.extra == extra
    assert json.loads(path.read_text())["gnsx"] == {"preset": "small", "seed": 3}
    assert loaded.bounds_array().shape == (2, 2)
    assert loaded.bounds_array()[1, 1] == 0.9


def test_metadata_accepts_numpy_values_and_geoelements_sections(tmp_path):
    meta = Metadata.from_dict(
        {
            **GEOMETRY,
            "bounds": np.array([[0.0, 1.0], [0.0, 2.0]]),
            "dim": np.int64(2),
            "sequence_length": 9.0,
        },
        partial=True,
    )
    assert meta.dim == 2 and meta.sequence_length == 9 and meta.bounds == [[0.0, 1.0], [0.0, 2.0]]
    assert not meta.has_statistics
    path = tmp_path / "metadata.json"
    sections = {"train": {**GEOMETRY, "sequence_length": 320, **STATS}, "rollout": {"sequence_length": 500}}
    path.write_text(json.dumps(sections))
    loaded = Metadata.load(path)
    assert loaded.sequence_length == 320
    assert loaded.extra == {"rollout": {"sequence_length": 500}}


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "metadata file not found"),
        ("{not json", "invalid JSON at line 1"),
        ({**GEOMETRY, **STATS}, "missing key(s) 'sequence_length'"),
        ({**GEOMETRY, "sequence_length": 5}, "missing key(s) 'vel_mean', 'vel_std', 'acc_mean', 'acc_std'"),
        (
            {**GEOMETRY, "sequence_length": 5, **STATS, "vel_std": [1e-3, 1e-3, 1e-3]},
            "key 'vel_std': expected",
        ),
        ({**GEOMETRY, "sequence_length": 5, **STATS, "acc_std": [1e-3, 0.0]}, "key 'acc_std': every entry"),
        ({**GEOMETRY, "sequence_length": 5, **STATS, "bounds": [[0, 1]]}, "key 'bounds': expected 2"),
        ({**GEOMETRY, "sequence_length": 5, **STATS, "bounds": [[0, 1], [1, 0]]}, "entry 1 has lo=1.0"),
        ({**GEOMETRY, "sequence_length": 5, **STATS, "dim": "2"}, "key 'dim': expected an integer"),
        ({**GEOMETRY, "sequence_length": 5, **STATS, "dt": -1}, "key 'dt': must be > 0"),
    ],
)
def test_metadata_errors_name_file_and_key(tmp_path, content, expected):
    path = tmp_path / "metadata.json"
    if content is not None:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(DataError) as err:
        Metadata.load(path)
    assert str(err.value).startswith(f"{path}: ")
    assert expected in str(err.value)


# ----------------------------------------------------------------------------------------------- statistics


def test_statistics_match_a_hand_computation_and_exclude_static_particles():
    # Particle 0 is water, particle 1 static (type 3) and moving wildly: it must not count.
    a = np.zeros((4, 2, 2), np.float32)
    a[:, 0, 0] = [0, 1, 3, 6]  # v = 1, 2, 3;  a = 1, 1
    a[:, 0, 1] = [0, 0, 1, 1]  # v = 0, 1, 0;  a = 1, -1
    a[:, 1, 0] = [100, 0, 100, 0]
    b = np.zeros((3, 1, 2), np.float32)
    b[:, 0, 0] = [0, 2, 2]  # v = 2, 0;  a = -2
    b[:, 0, 1] = [5, 5, 3]  # v = 0, -2; a = -2
    only_static = Trajectory(np.arange(12, dtype=np.float32).reshape(3, 2, 2), np.array([3, 3]), key=9)
    stats = compute_statistics(
        [Trajectory(a, np.array([5, 3]), 0), only_static, Trajectory(b, np.array([6]), 1)]
    )
    # vel x: 1,2,3,2,0   vel y: 0,1,0,0,-2   acc x: 1,1,-2   acc y: 1,-1,-2  (population std)
    np.testing.assert_allclose(stats["vel_mean"], [1.6, -0.2])
    np.testing.assert_allclose(stats["vel_std"], np.sqrt([3.6 - 1.6**2, 1.0 - 0.2**2]))
    np.testing.assert_allclose(stats["acc_mean"], [0.0, -2 / 3], atol=1e-15)
    np.testing.assert_allclose(stats["acc_std"], np.sqrt([2.0, 2.0 - 4 / 9]))


def test_streaming_statistics_equal_numpy_on_the_concatenation():
    trajectories = random_trajectories(5, seed=3)
    stats = compute_statistics(iter(trajectories))  # a one-shot iterator is enough
    vel = np.concatenate(
        [np.diff(t.position[:, t.particle_type != 3], axis=0).reshape(-1, 2) for t in trajectories]
    )
    acc = np.concatenate(
        [np.diff(t.position[:, t.particle_type != 3], n=2, axis=0).reshape(-1, 2) for t in trajectories]
    )
    np.testing.assert_allclose(stats["vel_mean"], vel.astype(np.float64).mean(0), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(stats["vel_std"], vel.astype(np.float64).std(0), rtol=1e-5)
    np.testing.assert_allclose(stats["acc_std"], acc.astype(np.float64).std(0), rtol=1e-4)


def test_statistics_without_dynamic_particles_is_an_error():
    static = Trajectory(np.zeros((5, 2, 2), np.float32), np.array([3, 3]), 0)
    with pytest.raises(DataError, match="no non-static particle"):
        compute_statistics([static], where="data/train")


# ----------------------------------------------------------------------------------------------- validate


def _traj(position=None, particle_type=None):
    position = np.zeros((5, 3, 2), np.float32) if position is None else position
    particle_type = np.array([5, 5, 3]) if particle_type is None else particle_type
    return Trajectory(position, particle_type, 0)


def _nan_at_frame_3():
    p = np.zeros((5, 3, 2), np.float32)
    p[3, 1, 0] = np.nan
    p[4, 0, 1] = np.nan
    return p


@pytest.mark.parametrize(
    ("traj", "dim", "expected"),
    [
        (
            _traj(np.zeros((5, 3), np.float32)),
            None,
            "field 'position': expected shape [frames, particles, dim]",
        ),
        (_traj(np.zeros((0, 3, 2), np.float32)), None, "field 'position': zero frames"),
        (_traj(np.zeros((5, 0, 2), np.float32), np.zeros(0, np.int64)), None, "zero particles"),
        (_traj(), 3, "field 'position': dim is 2 but the dataset's dim is 3"),
        (_traj(particle_type=np.array([5, 5])), None, "field 'particle_type': has 2 entries but"),
        (_traj(particle_type=np.array([5.0, 5.0, 3.0])), None, "field 'particle_type': dtype float64"),
        (_traj(_nan_at_frame_3()), None, "field 'position': frame 3 has NaN (particle 1)"),
        (
            _traj(np.full((5, 3, 2), np.inf, np.float32)),
            None,
            "field 'position': frame 0 has Inf (particle 0)",
        ),
        (
            _traj(particle_type=np.array([5, 12, 3])),
            None,
            "field 'particle_type': unknown type 12 (particle 1)",
        ),
        (_traj(particle_type=np.array([5, 5, -1])), None, "unknown type -1 (particle 2)"),
    ],
)
def test_check_trajectory_names_field_and_frame(traj, dim, expected):
    with pytest.raises(DataError) as err:
        check_trajectory(traj, "data/train.npz, trajectory 4", dim=dim)
    assert str(err.value).startswith("data/train.npz, trajectory 4: ")
    assert expected in str(err.value)


def test_check_trajectory_accepts_a_good_one():
    check_trajectory(_traj(np.random.default_rng(0).random((5, 3, 2))), "x", dim=2)


# ----------------------------------------------------------------------------------------------- store


def test_write_dataset_then_read_back_exactly(tmp_path):
    train, valid = random_trajectories(4, seed=1), random_trajectories(2, seed=2, key0=0)
    root = tmp_path / "ds"
    meta = write_dataset(root, {"train": iter(train), "valid": iter(valid), "test": iter([])}, GEOMETRY)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # no temp folders left
    assert list_splits(root) == ["train", "valid", "test"]
    assert load_metadata(root) == meta
    # sequence_length and statistics were filled from the train split
    assert meta.sequence_length == min(t.num_frames for t in train) - 1
    assert meta.vel_std == pytest.approx(compute_statistics(train)["vel_std"], rel=1e-12)

    reader = SplitReader(root, "train")
    assert_same(list(reader), train)
    assert_same(list(SplitReader(root, "valid", mmap=False)), valid)
    assert len(SplitReader(root, "test")) == 0
    assert reader.dim == 2
    assert reader.total_frames == sum(t.num_frames for t in train)
    assert [reader.num_frames(i) for i in range(4)] == [t.num_frames for t in train]
    assert reader.num_particles(-1) == train[-1].num_particles
    assert reader[-1].key == train[-1].key
    assert reader.keys.tolist() == [t.key for t in train]
    with pytest.raises(IndexError):
        reader[4]
    traj = reader[2]
    assert isinstance(traj.position, np.memmap)
    assert not traj.position.flags.writeable
    assert traj.position.flags.c_contiguous  # frames k-h..k+1 are one contiguous read
    with pytest.raises(ValueError):
        traj.position[0, 0, 0] = 1.0
    # Pickling (spawned DataLoader workers) sends the path, not the data.
    blob = pickle.dumps(reader)
    assert len(blob) < 1000
    assert_same(list(pickle.loads(blob)), train)


def test_store_files_are_plain_npy_as_documented(tmp_path):
    train = random_trajectories(3, seed=4)
    write_dataset(tmp_path / "ds", {"train": train}, {**GEOMETRY, **STATS})
    index = np.load(tmp_path / "ds/train/index.npy")
    positions = np.load(tmp_path / "ds/train/positions.npy", mmap_mode="r")
    types = np.load(tmp_path / "ds/train/particle_type.npy")
    assert positions.dtype == np.float32 and types.dtype == np.int64
    row = index[1]
    start = row["position_offset"]
    traj = positions[start : start + row["num_frames"] * row["num_particles"]].reshape(
        row["num_frames"], row["num_particles"], -1
    )
    assert np.array_equal(traj, train[1].position)
    assert np.array_equal(
        types[row["type_offset"] : row["type_offset"] + row["num_particles"]], train[1].particle_type
    )
    assert load_metadata(tmp_path / "ds").vel_std == STATS["vel_std"]  # given statistics are kept


def test_existing_dataset_is_refused_then_replaced_with_overwrite(tmp_path):
    root = tmp_path / "ds"
    write_dataset(root, {"train": random_trajectories(2, seed=5)}, GEOMETRY)
    before = tree(root)
    with pytest.raises(DataError, match="already exists; pass overwrite=True"):
        write_dataset(root, {"train": random_trajectories(3, seed=6)}, GEOMETRY)
    assert tree(root) == before
    write_dataset(root, {"train": random_trajectories(3, seed=6)}, GEOMETRY, overwrite=True)
    assert len(SplitReader(root, "train")) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_overwrite_refuses_a_folder_that_is_not_a_dataset(tmp_path):
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "thesis.tex").write_text("precious")
    with pytest.raises(DataError, match="not a gnsx dataset"):
        write_dataset(tmp_path / "home", {"train": random_trajectories(1)}, GEOMETRY, overwrite=True)
    assert (tmp_path / "home" / "thesis.tex").read_text() == "precious"


def test_failed_write_leaves_nothing_and_keeps_the_existing_dataset(tmp_path):
    root = tmp_path / "ds"
    write_dataset(root, {"train": random_trajectories(2, seed=7)}, GEOMETRY)
    before = tree(root)
    bad = random_trajectories(3, seed=8)
    bad[2].position[3, 1, 0] = np.nan
    with pytest.raises(DataError) as err:
        write_dataset(root, {"train": random_trajectories(2), "valid": bad}, GEOMETRY, overwrite=True)
    assert str(err.value) == f"{root / 'valid'}, trajectory 2: field 'position': frame 3 has NaN (particle 1)"
    assert tree(root) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]

    # A generator that dies mid-way (a crashed solver) leaves no trace either.
    def crashing():
        yield from random_trajectories(2)
        raise RuntimeError("solver exploded")

    with pytest.raises(RuntimeError, match="solver exploded"):
        write_dataset(tmp_path / "new", {"train": crashing()}, GEOMETRY)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_a_killed_writes_temporary_folder_is_removed_by_the_next_write(tmp_path, caplog):
    """SIGKILL leaves ``.<name>.tmp-*`` behind; the next write of that dataset removes it when its writer is
    gone (a dead pid on this host), and leaves a live writer's folder and one of unknown origin alone."""
    import socket
    import subprocess
    import sys

    from gnsx.core.runstate import liveness

    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    dead_pid = int(dead.stdout)
    folders = {name: tmp_path / f".ds.tmp-{name}" for name in ("killed", "live", "unknown", "other_host")}
    for folder in folders.values():
        (folder / "train").mkdir(parents=True)
        (folder / "train" / "position.npy").write_bytes(b"x" * 1000)
    (folders["killed"] / ".writer.json").write_text(
        json.dumps({"pid": dead_pid, "pid_start": None, "host": socket.gethostname(), "heartbeat": 0})
    )
    (folders["live"] / ".writer.json").write_text(json.dumps(liveness()))
    (folders["other_host"] / ".writer.json").write_text(
        json.dumps({"pid": dead_pid, "pid_start": None, "host": "elsewhere", "heartbeat": 0})
    )
    with caplog.at_level("INFO", logger="gnsx"):
        write_dataset(tmp_path / "ds", {"train": random_trajectories(2)}, GEOMETRY)
    assert not folders["killed"].exists()
    assert folders["live"].exists() and folders["unknown"].exists() and folders["other_host"].exists()
    assert f"{folders['unknown']}: left by an unfinished earlier write" in caplog.text
    # The writer record is not part of the dataset.
    assert not (tmp_path / "ds" / ".writer.json").exists()


def test_write_dataset_checks_dim_and_needs_train_for_statistics(tmp_path):
    with pytest.raises(DataError, match="dim is 3 but the dataset's dim is 2"):
        write_dataset(tmp_path / "ds", {"train": random_trajectories(2, dim=3)}, GEOMETRY)
    with pytest.raises(DataError, match="no 'train' split"):
        write_dataset(tmp_path / "ds", {"valid": random_trajectories(2)}, {**GEOMETRY, "sequence_length": 5})
    with pytest.raises(DataError, match="missing key"):
        write_dataset(tmp_path / "ds", {"train": random_trajectories(2)}, {"dim": 2})
    assert list(tmp_path.iterdir()) == []


def test_write_split_is_atomic_and_refuses_to_overwrite(tmp_path):
    assert write_split(tmp_path, "train", random_trajectories(3)) == 3
    before = tree(tmp_path)
    with pytest.raises(DataError, match="split already exists"):
        write_split(tmp_path, "train", random_trajectories(1))
    bad = random_trajectories(2)
    bad[1].particle_type[0] = 42
    with pytest.raises(DataError, match="trajectory 1: field 'particle_type': unknown type 42"):
        write_split(tmp_path, "train", bad, overwrite=True)
    assert tree(tmp_path) == before
    with pytest.raises(DataError, match="invalid split name"):
        write_split(tmp_path, "../escape", random_trajectories(1))


def test_corrupt_splits_give_clear_errors(tmp_path):
    root = tmp_path / "ds"
    write_dataset(root, {"train": random_trajectories(3)}, GEOMETRY)
    with pytest.raises(DataError, match="split 'valid' not found \\(splits here: train\\)"):
        SplitReader(root, "valid")

    positions = root / "train" / POSITIONS_FILE
    data = positions.read_bytes()
    positions.write_bytes(data[:-12])
    with pytest.raises(DataError) as err:
        SplitReader(root, "train")
    assert str(err.value).startswith(f"{positions}: truncated")
    positions.write_bytes(data + b"\0" * 8)
    with pytest.raises(DataError, match="corrupt: 8 bytes after the array"):
        SplitReader(root, "train", mmap=False)
    positions.write_bytes(data)

    index_path = root / "train" / INDEX_FILE
    index = np.load(index_path)
    index["num_frames"][1] += 1
    np.save(index_path, index)
    with pytest.raises(DataError) as err:
        SplitReader(root, "train")
    assert str(err.value).startswith(f"{index_path}: trajectory 2: position_offset")

    (root / "train" / "particle_type.npy").unlink()
    with pytest.raises(DataError, match="particle_type.npy: file not found"):
        SplitReader(root, "train")
