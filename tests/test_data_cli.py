"""``python -m gnsx.data``: info, convert, export and the generate wiring; bad input exits 2 with one line."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from gnsx.data.__main__ import main
from gnsx.data.formats import write_split_as
from gnsx.data.store import SplitReader, load_metadata, write_dataset
from gnsx.data.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = {"bounds": [[0.1, 0.9], [0.1, 0.9]], "default_connectivity_radius": 0.05, "dim": 2, "dt": 0.0025}


def trajectories(n: int, seed: int = 0) -> list[Trajectory]:
    """n trajectories with 4 + i water particles and 2 static ones, 6 + i frames."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        water, frames = 4 + i, 6 + i
        particle_type = np.array([5] * water + [3, 3], dtype=np.int64)
        position = rng.random((frames, water + 2, 2)).astype(np.float32)
        out.append(Trajectory(position, particle_type, key=i))
    return out


def test_info_summarises_splits_frames_and_particles_by_type(tmp_path, capsys):
    write_dataset(tmp_path / "ds", {"train": trajectories(3), "valid": trajectories(1, seed=1)}, GEOMETRY)
    assert main(["info", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    assert "dim 2, dt 0.0025 s, bounds [0.1, 0.9] x [0.1, 0.9], connectivity radius 0.05" in out
    assert "train: 3 trajectories, 21 frames" in out  # 6 + 7 + 8
    assert "frames per trajectory: min 6, mean 7.0, max 8" in out
    assert "type 5 (water): min 4, mean 5.0, max 6" in out
    assert "type 3 (boundary): min 2, mean 2.0, max 2" in out
    assert "valid: 1 trajectories, 6 frames" in out
    vel_std = load_metadata(tmp_path / "ds").vel_std
    assert f"vel_std  [{vel_std[0]:.4g}, {vel_std[1]:.4g}]" in out


def test_convert_with_flags_then_info(tmp_path, capsys):
    src = tmp_path / "src"
    write_split_as("npz", src, "train", trajectories(2))
    argv = ["convert", str(src), str(tmp_path / "dst"), "--bounds", "0", "1", "0", "1", "--dt", "0.01"]
    argv += ["--radius", "0.1", "--type-map", "5:6"]
    assert main(argv) == 0
    assert "wrote" in capsys.readouterr().out
    reader = SplitReader(tmp_path / "dst", "train")
    assert len(reader) == 2
    assert set(reader[0].particle_type.tolist()) == {6, 3}
    assert load_metadata(tmp_path / "dst").bounds == [[0.0, 1.0], [0.0, 1.0]]
    # Existing destination: one line on stderr, exit status 2.
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already exists; pass overwrite=True (CLI: --overwrite)" in err
    assert main([*argv, "--overwrite"]) == 0


def test_export_command(tmp_path, capsys):
    write_dataset(tmp_path / "ds", {"train": trajectories(2)}, GEOMETRY)
    assert main(["export", str(tmp_path / "ds"), str(tmp_path / "h5"), "--format", "h5"]) == 0
    assert (tmp_path / "h5" / "train.h5").is_file()
    assert json.loads((tmp_path / "h5" / "metadata.json").read_text())["dim"] == 2


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["info", "{tmp}/nowhere"], "{tmp}/nowhere/metadata.json: metadata file not found"),
        (["convert", "{tmp}/src", "{tmp}/dst", "--bounds", "0", "1", "0"], "--bounds: expected LO HI pairs"),
        (["convert", "{tmp}/src", "{tmp}/dst", "--type-map", "5-6"], "--type-map: expected SRC:DST pairs"),
        (["convert", "{tmp}/src", "{tmp}/dst"], "{tmp}/src: no metadata.json, so gnsx lacks bounds, dt"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, expected):
    write_split_as("h5", tmp_path / "src", "train", trajectories(1))
    argv = [a.format(tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"error: {expected.format(tmp=tmp_path)}")
    assert captured.err.count("\n") == 1
    assert not (tmp_path / "dst").exists()


def test_module_entry_point_exits_2_without_traceback(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    (src / "train.tfrecord").write_bytes(b"\x05" * 20)  # garbage: fails the length CRC
    (src / "metadata.json").write_text(json.dumps({**GEOMETRY, "sequence_length": 5}))
    result = subprocess.run(
        [sys.executable, "-m", "gnsx.data", "convert", str(src), str(tmp_path / "dst")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.strip() == (
        f"error: {src / 'train.tfrecord'}: record 0 (byte offset 0): "
        "corrupt: length header fails its CRC check"
    )


@dataclasses.dataclass(frozen=True)
class _FakePreset:
    name: str
    trajectories: dict
    frames: int = 250


def test_generate_passes_preset_with_overridden_counts(tmp_path, monkeypatch, capsys):
    calls = []

    def generate_dataset(out, preset, seed=0, workers=2, overwrite=False, progress=True):
        calls.append(dict(out=out, preset=preset, seed=seed, workers=workers, overwrite=overwrite))
        return Path(out)

    presets = {"small": _FakePreset("small", {"train": 24, "valid": 4, "test": 4})}

    def get_preset(name):
        if name not in presets:
            raise KeyError(f"unknown preset '{name}' (known: small)")
        return presets[name]

    monkeypatch.setitem(
        sys.modules, "gnsx.mpm.generate", types.SimpleNamespace(generate_dataset=generate_dataset)
    )
    monkeypatch.setitem(sys.modules, "gnsx.mpm.presets", types.SimpleNamespace(get_preset=get_preset))

    out = tmp_path / "small"
    argv = ["generate", "--preset", "small", "--out", str(out), "--seed", "3", "--valid", "1", "--test", "0"]
    assert main([*argv, "--overwrite"]) == 0
    (call,) = calls
    assert call["preset"] == _FakePreset("small", {"train": 24, "valid": 1, "test": 0})
    assert presets["small"].trajectories == {
        "train": 24,
        "valid": 4,
        "test": 4,
    }  # the preset itself untouched
    assert (call["out"], call["seed"], call["workers"], call["overwrite"]) == (out, 3, 2, True)
    assert main(["generate", "--preset", "huge", "--out", str(out)]) == 2
    assert "--preset: unknown preset 'huge'" in capsys.readouterr().err


@pytest.fixture
def generated_presets(monkeypatch) -> list:
    """The presets ``generate`` would simulate, in call order (the solver itself is replaced)."""
    calls = []

    def generate_dataset(out, preset, seed=0, workers=2, overwrite=False, progress=True):
        calls.append(preset)
        return Path(out)

    monkeypatch.setitem(
        sys.modules, "gnsx.mpm.generate", types.SimpleNamespace(generate_dataset=generate_dataset)
    )
    return calls


def test_generate_with_the_real_presets(tmp_path, generated_presets):
    presets = pytest.importorskip("gnsx.mpm.presets")
    calls = generated_presets
    assert main(["generate", "--preset", "small", "--out", str(tmp_path / "d"), "--train", "3"]) == 0
    expected = {**presets.get_preset("small").trajectories, "train": 3}
    assert calls[0].trajectories == expected
    assert calls[0].num_frames == presets.get_preset("small").num_frames


def test_generate_pool_depth_reaches_the_preset(tmp_path, generated_presets, capsys):
    pytest.importorskip("gnsx.mpm.presets")
    calls = generated_presets
    argv = ["generate", "--preset", "small", "--out", str(tmp_path / "d"), "--rest-fraction", "1"]
    assert main([*argv, "--pool-depth", "0.25", "0.75"]) == 0
    assert calls[0].pool_depth_range == (0.25, 0.75) and calls[0].rest_fraction == 1.0
    assert main([*argv, "--pool-depth", "0.5", "0.2"]) == 2  # min above max
    assert "error: --pool-depth: preset 'small': pool_depth_range must be" in capsys.readouterr().err


def test_generate_dam_fraction_reaches_the_preset_and_is_checked_with_the_pools(
    tmp_path, generated_presets, capsys
):
    calls = generated_presets
    argv = ["generate", "--preset", "small", "--out", str(tmp_path / "d"), "--rest-fraction", "0.2"]
    assert main([*argv, "--dam-fraction", "0.1"]) == 0
    assert calls[0].rest_fraction == 0.2 and calls[0].dam_fraction == 0.1
    assert main([*argv, "--dam-fraction", "0.9"]) == 2  # pools and dams above every scene
    assert "error: --dam-fraction: preset 'small': rest_fraction + dam_fraction must not exceed 1" in (
        capsys.readouterr().err
    )
