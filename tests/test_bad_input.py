"""Bad input at every entry point: one line naming the file, field, frame or override, exit status 2, no
traceback, nothing written.

Most cases run in-process (the Hydra task functions are called with a composed config, the argparse mains
with an argv); a few subprocesses check the real exit status and stderr. With ``GNSX_BAD_INPUT_TABLE=<file>``
the cases' actual messages are written there as the markdown table of docs/robustness.md.
"""

from __future__ import annotations

import datetime
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf, open_dict
from test_evaluate import TINY as TINY_MODEL
from test_evaluate import save_tiny_checkpoint

from gnsx.core.cli import run_main, user_message
from gnsx.data.store import load_metadata
from gnsx.data.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
SHIPPED = ROOT / "pretrained" / "small" / "model.ckpt"
GEOMETRY = {"bounds": [[0.1, 0.9], [0.1, 0.9]], "default_connectivity_radius": 0.05, "dim": 2, "dt": 0.0025}
TINY = [f"model.{key}={value}" for key, value in TINY_MODEL.items()]
#: (case, message) of every case run, for the docs table.
MESSAGES: list[tuple[str, str]] = []


def _script(name: str):
    spec = importlib.util.spec_from_file_location(f"{name}_script", ROOT / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", autouse=True)
def _table():
    yield
    target = os.environ.get("GNSX_BAD_INPUT_TABLE")
    if target:
        rows = ["| case | message (stderr, exit status 2) |", "|---|---|"]
        rows += [f"| {case} | `` {message.replace('|', '/')} `` |" for case, message in MESSAGES]
        Path(target).write_text("\n".join(rows) + "\n")


def _one_line(err: str, tmp_path: Path, case: str, progress: bool = False) -> str:
    """The single ``error: ...`` line of ``err`` (asserted), tmp_path shortened, recorded for the docs.

    ``progress``: a progress bar (carriage returns, no newline) may come before the line.
    """
    if progress:
        err = err.rsplit("\r", 1)[-1].split("\n", 1)[-1] if "\r" in err else err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith("error: ") and "Traceback" not in err, err
    message = err.strip().replace(str(tmp_path) + "/", "").replace(str(ROOT) + "/", "")
    MESSAGES.append((case, message))
    return message


def _hydra_task(script: str, config: str, overrides: list[str], tmp_path: Path, capsys, case: str) -> str:
    """Run ``<script>.py``'s task function with a composed config (as Hydra would); it must exit 2."""
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name=config, overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(tmp_path / "run")
    HydraConfig.instance().set_config(cfg)
    task_cfg = OmegaConf.masked_copy(cfg, [key for key in cfg if key != "hydra"])
    main = _script(script).main
    with pytest.raises(SystemExit) as exit_:
        main(task_cfg)
    assert exit_.value.code == 2
    return _one_line(capsys.readouterr().err, tmp_path, case)


def _cli(main, argv: list[str], tmp_path: Path, capsys, case: str, progress: bool = False, **kwargs) -> str:
    try:
        code = run_main(main, argv, **kwargs)
    except SystemExit as exit_:  # argparse's usage errors exit (with one line, gnsx.core.cli.ArgumentParser)
        code = exit_.code
    assert code == 2
    return _one_line(capsys.readouterr().err, tmp_path, case, progress)


# -- files ---------------------------------------------------------------------------------------------------
@pytest.fixture
def dataset(tiny_dataset, tmp_path) -> Path:
    """A private copy of the tiny dataset (cases poke NaN or a wrong dim into it)."""
    return Path(shutil.copytree(tiny_dataset, tmp_path / "ds"))


def _checkpoint(bad_checkpoints: dict[str, Path], name: str, tmp_path: Path) -> str:
    """A file of :func:`bad_checkpoints` by name, or a path with ``{tmp}`` for the test's folder."""
    return str(bad_checkpoints.get(name) or name.replace("{tmp}", str(tmp_path)))


def _poke_nan(root: Path, split: str, trajectory: int, frame: int, particle: int) -> None:
    index = np.load(root / split / "index.npy")
    row = index["position_offset"][trajectory] + frame * index["num_particles"][trajectory] + particle
    positions = np.load(root / split / "positions.npy", mmap_mode="r+")
    positions[row, 1] = np.nan
    positions.flush()


def _metadata_3d(root: Path) -> None:
    """Rewrite a 2-D dataset's metadata.json as a consistent 3-D one (the positions stay 2-D)."""
    meta = json.loads((root / "metadata.json").read_text())
    meta.update(dim=3, bounds=[*meta["bounds"], [0.1, 0.9]])
    for key in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
        meta[key] = [*meta[key], meta[key][-1]]
    (root / "metadata.json").write_text(json.dumps(meta))


@pytest.fixture
def bad_checkpoints(tmp_path, tiny_dataset) -> dict[str, Path]:
    """A text file, a truncated checkpoint, a file with pickled objects, mismatched weights, another model."""
    folder = tmp_path / "ckpt"
    folder.mkdir()
    good = save_tiny_checkpoint(folder / "good.ckpt", load_metadata(tiny_dataset), TINY_MODEL)
    (folder / "notes.ckpt").write_text("not a checkpoint\n")
    data = good.read_bytes()
    (folder / "truncated.ckpt").write_bytes(data[: len(data) // 2])
    pickled = {"state_dict": {}, "hyper_parameters": {"model": {}}, "made": datetime.date(2026, 1, 1)}
    torch.save(pickled, folder / "pickled.ckpt")
    state = torch.load(good, weights_only=True)
    state["state_dict"] = {k: v[..., :1] if v.ndim == 2 else v for k, v in state["state_dict"].items()}
    torch.save(state, folder / "mismatch.ckpt")
    meta = load_metadata(tiny_dataset)
    meta.default_connectivity_radius = 0.012  # a WaterRamps-like model: 3x smaller radius than the data's
    save_tiny_checkpoint(folder / "other_data.ckpt", meta, TINY_MODEL)
    return {path.stem: path for path in folder.iterdir()}


# -- python -m gnsx.data -------------------------------------------------------------------------------------
def _data_main(argv):
    from gnsx.data.__main__ import _run

    return _run(argv)


def _npz_source(folder: Path, metadata: dict, nan: bool = False, frames: int = 8) -> Path:
    position = np.random.default_rng(0).random((frames, 6, 2)).astype(np.float32)
    if nan:
        position[3, 2, 1] = np.nan
    item = np.empty(2, dtype=object)
    item[0], item[1] = position, np.array([5, 5, 5, 5, 3, 3])
    folder.mkdir()
    np.savez(folder / "train.npz", simulation_trajectory_0=item)
    (folder / "metadata.json").write_text(json.dumps(metadata))
    return folder


@pytest.mark.parametrize(
    ("case", "argv", "expected"),
    [
        ("generate: negative --seed", ["--seed", "-1"], "--seed=-1: must be >= 0"),
        ("generate: --workers 0", ["--workers", "0"], "--workers=0: must be >= 1"),
        ("generate: unknown --preset", ["--preset", "nope"], "--preset: unknown preset 'nope'"),
        (
            "generate: --out under a file",
            ["--out", "{tmp}/file/ds"],
            "--out file/ds: file is a file, not a folder",
        ),
        (
            "generate: negative --train",
            ["--train", "-3"],
            "--train/--valid/--test: trajectory counts must be >= 0",
        ),
    ],
)
def test_generate_flags(case, argv, expected, tmp_path, capsys):
    (tmp_path / "file").write_text("a file")
    args = {"--preset": "small", "--out": str(tmp_path / "out")}
    for flag, value in zip(argv[::2], argv[1::2]):
        args[flag] = value.replace("{tmp}", str(tmp_path))
    argv = ["generate", *[x for pair in args.items() for x in pair]]
    assert expected in _cli(_data_main, argv, tmp_path, capsys, case)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # nothing written


def _nan_trajectory(preset, seed, split, index):
    """Stands in for the MPM solver: trajectory ``index`` with a NaN at frame 3, particle 1."""
    position = np.random.default_rng(index).random((5, 4, 2)).astype(np.float32)
    position[3, 1, 0] = np.nan
    return Trajectory(position, np.full(4, 5), key=index)


def test_generate_names_nan_from_the_solver(tmp_path, capsys, monkeypatch):
    import gnsx.mpm.generate

    monkeypatch.setattr(gnsx.mpm.generate, "simulate_split_item", _nan_trajectory)
    argv = ["generate", "--preset", "small", "--out", str(tmp_path / "ds"), "--workers", "1"]
    message = _cli(
        _data_main,
        [*argv, "--train", "1", "--valid", "0", "--test", "0"],
        tmp_path,
        capsys,
        "generate: the solver returns NaN",
        progress=True,
    )
    assert message == "error: ds/train, trajectory 0: field 'position': frame 3 has NaN (particle 1)"
    assert not (tmp_path / "ds").exists()


def test_generate_refuses_an_unfinished_generation_of_other_settings(tmp_path, capsys, monkeypatch):
    """A killed generation leaves its finished trajectories in <out>.partial; a rerun with another seed must
    not mix them in (nor delete hours of simulation): one line naming the cache and what differs."""
    import gnsx.mpm.generate

    monkeypatch.setattr(gnsx.mpm.generate, "simulate_split_item", _nan_trajectory)
    argv = ["generate", "--preset", "small", "--out", str(tmp_path / "ds"), "--workers", "1"]
    counts = ["--train", "1", "--valid", "0", "--test", "0"]
    assert run_main(_data_main, [*argv, *counts, "--seed", "0"]) == 2  # the NaN, after caching trajectory 0
    capsys.readouterr()
    record = (tmp_path / "ds.partial" / "generation.json").read_bytes()
    message = _cli(
        _data_main, [*argv, *counts, "--seed", "1"], tmp_path, capsys, "generate: a cache of another seed"
    )
    assert message.startswith(
        "error: ds.partial: cache of an unfinished generation with other settings: seed 0"
    )
    assert (tmp_path / "ds.partial" / "generation.json").read_bytes() == record


def test_convert_cases(tmp_path, capsys):
    nan = _npz_source(tmp_path / "nan", GEOMETRY, nan=True)
    message = _cli(
        _data_main, ["convert", str(nan), str(tmp_path / "a")], tmp_path, capsys, "convert: NaN positions"
    )
    assert message == (
        "error: nan/train.npz, trajectory 0 (member 'simulation_trajectory_0'): field 'position': frame 3 "
        "has "
        "NaN (particle 2)"
    )
    three_d = _npz_source(tmp_path / "3d", {**GEOMETRY, "dim": 3, "bounds": [[0.1, 0.9]] * 3})
    message = _cli(
        _data_main,
        ["convert", str(three_d), str(tmp_path / "b")],
        tmp_path,
        capsys,
        "convert: 3-D metadata over 2-D data",
    )
    assert "3d/train.npz, trajectory 0: field 'position': dim is 2 but the metadata's dim is 3" in message
    long = _npz_source(tmp_path / "seq", {**GEOMETRY, "sequence_length": 20})
    message = _cli(
        _data_main,
        ["convert", str(long), str(tmp_path / "c")],
        tmp_path,
        capsys,
        "convert: DeepMind metadata.json whose sequence_length disagrees with the data",
    )
    assert message.startswith(
        "error: seq/metadata.json: key 'sequence_length' is 20 (21 frames per trajectory) but trajectory 0 "
        "of "
        "split 'train' has 8 frames"
    )
    message = _cli(
        _data_main,
        ["convert", str(tmp_path / "nowhere"), str(tmp_path / "d")],
        tmp_path,
        capsys,
        "convert: missing source folder",
    )
    assert message == "error: nowhere: source folder not found"
    message = _cli(_data_main, ["convert", str(nan)], tmp_path, capsys, "convert: missing argument")
    assert "the following arguments are required: dst (see --help)" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["3d", "nan", "seq"]  # nothing written


class _Payload:
    """Unpickling this runs ``touch <marker>``: what a malicious .npz could hold."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_convert_never_runs_code_from_an_npz(tmp_path, capsys):
    marker = tmp_path / "ran"
    item = np.empty(2, dtype=object)
    item[0], item[1] = _Payload(marker), np.array([5, 5])
    (tmp_path / "evil").mkdir()
    np.savez(tmp_path / "evil" / "train.npz", simulation_trajectory_0=item)
    (tmp_path / "evil" / "metadata.json").write_text(json.dumps(GEOMETRY))
    message = _cli(_data_main, ["convert", str(tmp_path / "evil"), str(tmp_path / "out")], tmp_path, capsys,
                   "convert: an .npz whose pickle names code")  # fmt: skip
    assert message == (
        "error: evil/train.npz (member 'simulation_trajectory_0'): refused global "
        f"{os.system.__module__}.system: gnsx reads numpy arrays only from data files (no pickled code)"
    )
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_info_names_3d_metadata_over_2d_positions(dataset, tmp_path, capsys):
    _metadata_3d(dataset)
    message = _cli(_data_main, ["info", str(dataset)], tmp_path, capsys, "info: 3-D metadata over 2-D data")
    assert message == "error: ds/metadata.json: key 'dim' is 3 but ds/train/positions.npy holds 2-D positions"


# -- train.py ------------------------------------------------------------------------------------------------
def _train(overrides: list[str], tmp_path, capsys, case: str, dataset: Path | None = None) -> str:
    data = [f"data.root={dataset}", "data.generate_if_missing=false"] if dataset else []
    return _hydra_task("train", "config", [*data, "logger=none", *TINY, *overrides], tmp_path, capsys, case)


@pytest.mark.parametrize(
    ("case", "override", "expected"),
    [
        ("train: max_steps -1", "train.max_steps=-1", "error: train.max_steps=-1: must be >= 1"),
        ("train: max_steps 0", "train.max_steps=0", "error: train.max_steps=0: must be >= 1"),
        (
            "train: max_steps not a number",
            "train.max_steps=abc",
            "error: train.max_steps=abc: expected an integer",
        ),
        ("train: threads 0", "threads=0", "error: threads=0: must be >= 1"),
        ("train: negative seed", "seed=-1", "error: seed=-1: must be >= 0"),
        (
            "train: bad model setting",
            "model.type_encoding=bogus",
            "error: model.type_encoding=bogus: must be one of ('scalar', 'embedding'), got 'bogus'",
        ),
        (
            "train: noise correction above 1",
            "train.noise_correction=1.5",
            "error: train.noise_correction=1.5: must be in [0, 1]",
        ),
        (
            "train: unknown precision",
            "trainer.precision=fp8",
            "error: trainer.precision=fp8: expected one of auto, 32-true, 32, bf16-mixed, 16-mixed, "
            "bf16-true, 16-true, 64-true, 64",
        ),
        (
            "train: negative pushforward steps",
            "train.pushforward_steps=-1",
            "error: train.pushforward_steps=-1: must be >= 0",
        ),
        (
            "train: mirror that is not true or false",
            "train.mirror=sometimes",
            "error: train.mirror=sometimes: must be true or false",
        ),
        (
            "train: a rollout rule that is not true or false",
            "rules.hold_rest=maybe",
            "error: rules.hold_rest=maybe: must be true or false",
        ),
        ("train: unknown loss", "train.loss=l1", "error: train.loss=l1: expected one of mse, huber"),
        ("train: bad max_time", "train.max_time=soon", "error: train.max_time=soon: expected DD:HH:MM:SS"),
        (
            "train: negative gradient clip",
            "train.gradient_clip_val=-1",
            "error: train.gradient_clip_val=-1: expected a positive",
        ),
        (
            "train: missing dataset",
            "data.root={tmp}/nowhere",
            "error: data.root=nowhere: no dataset here (nowhere/metadata.json missing)",
        ),
    ],
)
def test_train_settings(case, override, expected, tmp_path, capsys):
    overrides = [override.replace("{tmp}", str(tmp_path)), "data.generate_if_missing=false"]
    assert _train(overrides, tmp_path, capsys, case).startswith(expected)
    assert not (tmp_path / "run" / "results.json").exists()


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("{rest_fraction: 2}", "preset 'small': rest_fraction must be a probability in [0, 1]"),
        ("{rest_fractoin: 0.2}", "preset 'small': unknown field(s) ['rest_fractoin']"),
    ],
)
def test_train_bad_preset_override_is_named_before_generating(override, expected, tmp_path, capsys):
    overrides = [f"data.root={tmp_path}/new", f"data.preset_overrides={override}"]
    message = _train(overrides, tmp_path, capsys, "train: bad preset override")
    assert message.startswith(f"error: data.preset_overrides: {expected}")
    assert not (tmp_path / "new").exists() and not (tmp_path / "new.partial").exists()


def test_train_unknown_preset_names_data_preset(tmp_path, capsys):
    overrides = [f"data.root={tmp_path}/new", "data.preset=bogus"]
    message = _train(overrides, tmp_path, capsys, "train: unknown preset")
    assert message.startswith(
        "error: data.preset=bogus: unknown preset 'bogus'; known presets: small, waterramps"
    )
    assert not (tmp_path / "new").exists()


def test_train_data_with_nan_is_named_before_training(dataset, tmp_path, capsys):
    _poke_nan(dataset, "train", trajectory=1, frame=5, particle=3)
    message = _train([], tmp_path, capsys, "train: NaN in the training positions", dataset)
    assert (
        message
        == "error: ds/train/positions.npy, trajectory 1: field 'position': frame 5 has NaN (particle 3)"
    )


def test_train_data_with_3d_metadata(dataset, tmp_path, capsys):
    _metadata_3d(dataset)
    message = _train([], tmp_path, capsys, "train: 3-D metadata over 2-D data", dataset)
    assert message == "error: ds/metadata.json: key 'dim' is 3 but ds/train/positions.npy holds 2-D positions"


@pytest.mark.parametrize(
    ("case", "checkpoint", "expected"),
    [
        (
            "train: resume from a file that is not a checkpoint",
            "notes",
            "error: ckpt/notes.ckpt: not a checkpoint (not a PyTorch file: starts with b'not ', 17 bytes)",
        ),
        ("train: resume from a truncated checkpoint", "truncated", "error: ckpt/truncated.ckpt: truncated ("),
        (
            "train: resume from a checkpoint of another model config",
            "good",
            "error: train.ckpt_path=ckpt/good.ckpt: trained with model latent_size=8, mlp_hidden_size=8, "
            "mp_steps=2",
        ),
        (
            "train: resume from a run directory without checkpoints",
            "{tmp}/ckpt",
            "error: train.ckpt_path=ckpt: no checkpoint here (ckpt/checkpoints/last.ckpt missing)",
        ),
    ],
)
def test_train_resume(case, checkpoint, expected, bad_checkpoints, dataset, tmp_path, capsys):
    path = _checkpoint(bad_checkpoints, checkpoint, tmp_path)
    other = ["model.latent_size=16"] if checkpoint == "good" else []
    message = _train([f"train.ckpt_path={path}", *other], tmp_path, capsys, case, dataset)
    assert message.startswith(expected)
    if checkpoint == "good":
        assert "this run's config differs: latent_size 8 (checkpoint) vs 16" in message


def test_train_init_weights_of_another_model_config(bad_checkpoints, dataset, tmp_path, capsys):
    path = _checkpoint(bad_checkpoints, "good", tmp_path)
    case = "train: fine-tune from a checkpoint of another model config"
    message = _train([f"train.init_weights={path}", "model.latent_size=16"], tmp_path, capsys, case, dataset)
    assert message.startswith("error: train.init_weights=ckpt/good.ckpt: trained with model latent_size=8")


def test_train_init_weights_with_resume(bad_checkpoints, dataset, tmp_path, capsys):
    path = _checkpoint(bad_checkpoints, "good", tmp_path)
    case = "train: fine-tune and resume at once"
    message = _train(
        [f"train.init_weights={path}", f"train.ckpt_path={path}"], tmp_path, capsys, case, dataset
    )
    assert message == (
        "error: train.init_weights=ckpt/good.ckpt: cannot be combined with train.ckpt_path (a resumed run "
        "has its own weights); set one of them"
    )


def test_composition_errors_are_one_line():
    from hydra.errors import HydraException

    cases = {
        "train.max_stepz=5": "Could not override 'train.max_stepz'. To append to your config use "
        "+train.max_stepz=5 (Key 'max_stepz' is not in struct)",
        "model=foo": "In 'config': Could not find 'model/foo'. Available options in 'model': original, "
        "simplified, simplified_pairwise, simplified_wall10",
        "train.max_steps": "Error parsing override 'train.max_steps', missing EQUAL at '<EOF>'",
    }
    for override, expected in cases.items():
        with (
            initialize_config_dir(config_dir=str(CONF), version_base="1.3"),
            pytest.raises(HydraException) as err,
        ):
            compose(config_name="config", overrides=[override])
        assert user_message(err.value) == expected
        MESSAGES.append((f"train: bad override `{override}`", f"error: {expected}"))


# -- evaluate.py ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("case", "checkpoint", "expected"),
    [
        ("evaluate: a file that is not a checkpoint", "notes", "error: ckpt/notes.ckpt: not a checkpoint"),
        ("evaluate: a truncated checkpoint", "truncated", "error: ckpt/truncated.ckpt: truncated ("),
        (
            "evaluate: a file with pickled objects (refused by the safe loader)",
            "pickled",
            "error: ckpt/pickled.ckpt: not a gnsx checkpoint: it holds a pickled datetime.date, which "
            "the safe loader (weights_only) refuses",
        ),
        (
            "evaluate: weights of another model config than their hyper-parameters",
            "mismatch",
            "error: ckpt/mismatch.ckpt: its weights are of another model config than its hyper-parameters "
            "say (latent_size=8, mlp_hidden_size=8, mp_steps=2): ",
        ),
        (
            "evaluate: a model trained on other data (radius 0.012 vs 0.035)",
            "other_data",
            "error: ckpt/other_data.ckpt: trained with dim 2, bounds [[0.1, 0.9], [0.1, 0.9]], radius 0.012, "
            "but the dataset ds (2-D) has radius 0.035 (0.34x apart): the model does not fit",
        ),
        (
            "evaluate: missing checkpoint",
            "{tmp}/nowhere.ckpt",
            "error: checkpoint=nowhere.ckpt: no such file or run directory",
        ),
    ],
)
def test_evaluate_checkpoints(case, checkpoint, expected, bad_checkpoints, dataset, tmp_path, capsys):
    path = _checkpoint(bad_checkpoints, checkpoint, tmp_path)
    overrides = [f"checkpoint={path}", f"data.root={dataset}", "logger=none", "render.enabled=false"]
    assert _hydra_task("evaluate", "evaluate", overrides, tmp_path, capsys, case).startswith(expected)
    assert not list((tmp_path / "run").glob("*.json"))  # nothing written


@pytest.mark.parametrize(
    ("case", "overrides", "expected"),
    [
        ("evaluate: NaN in the test positions", ["{good}", "+nan=1"],
         "error: ds/test/positions.npy, trajectory 0: field 'position': frame 2 has NaN (particle 0)"),
        ("evaluate: no checkpoint given", [],
         "error: checkpoint: missing; pass checkpoint=... on the command line"),
        ("evaluate: one label too many", ["{good}", "labels=[a,b]"],
         "error: labels=['a', 'b']: 2 labels for 1 checkpoints; give one label per checkpoint"),
        ("evaluate: unknown split", ["{good}", "split=nope"],
         "error: ds/nope: split 'nope' not found (splits here: train, valid, test)"),
        ("evaluate: max_trajectories 0", ["{good}", "max_trajectories=0"],
         "error: max_trajectories=0: must be >= 1"),
    ],
)  # fmt: skip
def test_evaluate_data_and_settings(case, overrides, expected, bad_checkpoints, dataset, tmp_path, capsys):
    overrides = list(overrides)
    if "+nan=1" in overrides:
        overrides.remove("+nan=1")
        _poke_nan(dataset, "test", trajectory=0, frame=2, particle=0)
    good = f"checkpoint={bad_checkpoints['good']}"
    overrides = [good if o == "{good}" else o for o in overrides]
    overrides += [f"data.root={dataset}", "logger=none", "render.enabled=false"]
    assert _hydra_task("evaluate", "evaluate", overrides, tmp_path, capsys, case) == expected


# -- simulate.py ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("case", "overrides", "expected"),
    [
        (
            "simulate: a small-preset model on preset=waterramps",
            ["preset=waterramps"],
            "error: pretrained/small/model.ckpt: trained with dim 2, bounds [[0.1, 0.9], [0.1, 0.9]], "
            "radius 0.0466655 (on data of default radius 0.035), but preset=waterramps has radius 0.015 (2.3x "
            "apart): the model does not fit; use preset=small (or allow_mismatch=true to run it anyway)",
        ),
        (
            "simulate: unknown key inside a scene block",
            ["scene={blocks:[{lower:[0.2,0.2],upper:[0.4,0.4],velocty:[1,0]}]}"],
            "error: scene (override).blocks[0]: unknown key(s) ['velocty'] (did you mean 'velocity'?); "
            "expected "
            "'lower', 'upper', 'velocity'",
        ),
        ("simulate: missing scene file", ["scene={tmp}/nope.yaml"], "error: nope.yaml: scene file not found"),
        ("simulate: negative seed", ["seed=-1"], "error: seed=-1: must be >= 0"),
        ("simulate: unknown preset", ["preset=big"], "error: preset=big: unknown preset 'big'"),
        (
            "simulate: fewer frames than the model reads",
            ["num_frames=2"],
            "error: num_frames=2: must be >= 3",
        ),
        (
            "simulate: a file that is not a checkpoint",
            ["checkpoint={tmp}/ckpt/notes.ckpt"],
            "error: ckpt/notes.ckpt: not a checkpoint",
        ),
    ],
)
def test_simulate(case, overrides, expected, bad_checkpoints, tmp_path, capsys):
    overrides = [f"checkpoint={SHIPPED}", *[o.replace("{tmp}", str(tmp_path)) for o in overrides]]
    assert _hydra_task("simulate", "simulate", overrides, tmp_path, capsys, case).startswith(expected)
    assert not (tmp_path / "run").exists()  # nothing written


# -- the other CLIs ------------------------------------------------------------------------------------------
def test_pretrained_throughput_report_benchmark(bad_checkpoints, tmp_path, capsys):
    from gnsx.evaluation import report
    from gnsx.perf import benchmark, throughput
    from gnsx.training import export as pretrained

    (tmp_path / "file").write_text("a file")
    message = _cli(
        pretrained._main,
        [str(tmp_path / "nowhere"), str(tmp_path / "dest")],
        tmp_path,
        capsys,
        "pretrained: missing run directory",
    )
    assert message == "error: nowhere: no such run directory"
    message = _cli(
        pretrained._main,
        [str(tmp_path), str(tmp_path / "file" / "dest")],
        tmp_path,
        capsys,
        "pretrained: DEST under a file",
    )
    assert message == "error: DEST file/dest: file is a file, not a folder"
    message = _cli(
        throughput._main,
        ["--data", str(tmp_path / "nowhere")],
        tmp_path,
        capsys,
        "throughput: missing dataset",
    )
    assert message.startswith("error: --data nowhere: no gnsx dataset here")
    message = _cli(
        throughput._main,
        ["--data", str(ROOT / "pretrained" / "small"), "--batch-size", "2", "0"],
        tmp_path,
        capsys,
        "throughput: --batch-size 0",
    )
    assert message == "error: --batch-size=0: must be >= 1"
    # gnsx.evaluation.report and gnsx.perf.benchmark through gnsx.core.cli.run_main with their user errors
    # (their __main__ blocks should call it so: see docs/robustness.md).
    message = _cli(
        report.main,
        [str(tmp_path / "nowhere")],
        tmp_path,
        capsys,
        "report: missing sweep folder",
        user_errors=(FileNotFoundError,),
    )
    assert message == "error: nowhere: no such multirun directory"
    message = _cli(
        benchmark.main,
        ["--particles", "0", "--models", "simplified"],
        tmp_path,
        capsys,
        "benchmark: --particles 0",
        user_errors=(ValueError,),
    )
    assert message.startswith("error: packed_scene: need num_particles >= 1")


# -- the real processes: exit status, one line on stderr, --debug ------------------------------------------
def test_processes_exit_2_with_one_line_and_debug_shows_the_traceback(tmp_path, bad_checkpoints):
    env = {**os.environ, "WANDB_MODE": "disabled"}
    env.pop("GNSX_DEBUG", None)
    train, evaluate = [sys.executable, str(ROOT / "train.py")], [sys.executable, str(ROOT / "evaluate.py")]
    runs = {
        "override": [*train, "train.max_stepz=5"],
        "task": [*evaluate, f"checkpoint={bad_checkpoints['truncated']}", "logger=none"],
        "argparse": [sys.executable, "-m", "gnsx.data", "generate", "--preset", "small", "--seed", "-1",
                     "--out", str(tmp_path / "ds")],
        "debug": [*train, "train.max_stepz=5", "--debug"],
    }  # fmt: skip
    pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True}
    jobs = {name: subprocess.Popen(args, cwd=tmp_path, env=env, **pipes) for name, args in runs.items()}
    done = {name: (job.wait(timeout=120), job.communicate()[1]) for name, job in jobs.items()}
    for name in ("override", "task", "argparse"):
        code, err = done[name]
        assert code == 2 and err.count("\n") == 1 and err.startswith("error: "), (name, err[-2000:])
    assert "train.max_stepz" in done["override"][1] and "truncated (" in done["task"][1]
    assert "--seed=-1: must be >= 0" in done["argparse"][1]
    code, err = done["debug"]
    assert code == 1 and "Traceback" in err and "ConfigCompositionException" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt"]  # no dataset, no run folder left
