"""Trained simulators from checkpoints: where a run keeps its weights, reading them safely, checking that
they fit the run or data at hand, and naming the model.

``train.py`` saves Lightning checkpoints of :class:`~gnsx.training.system.GNSSystem` (``<run dir>/checkpoints/``);
every hyperparameter is saved with them, so a checkpoint alone rebuilds its model.

Reading never unpickles arbitrary objects: :func:`read_checkpoint` uses ``torch.load(weights_only=True)``
(tensors, containers and plain values only; a Lightning checkpoint of gnsx needs nothing else). A bad file
gets one of three messages (:class:`~gnsx.core.errors.CheckpointError`): not a checkpoint, truncated, or a
checkpoint of another model config (naming the config it was trained with and the one expected).
"""

from __future__ import annotations

import math
import pickle
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from gnsx.core.errors import CheckpointError
from gnsx.model.simulator import LearnedSimulator

#: Model settings that change behaviour at run time only (not the weights, not the training).
#: The dataset facts a simulator is built with, besides its architecture (``hyper_parameters["model"]``).
SIMULATOR_FACTS = ("dim", "bounds", "radius", "vel_mean", "vel_std", "acc_mean", "acc_std")
#: Lightning saves the training module's weights; the simulator is its submodule ``simulator``.
SIMULATOR_PREFIX = "simulator."

RUNTIME_KEYS = frozenset({"neighbor_search", "cull", "compile"})
#: Model settings that older checkpoints may hold but the model no longer takes: dropped when one is read.
#: ``freeze_speed`` (approximate freezing, a run-time switch of the model until 2026-12-07) is now a rule of
#: the rollout (:mod:`gnsx.rules.freezing`), chosen where a rollout is run; an old checkpoint's value (always
#: None in the shipped and trained configs) is not carried over.
RETIRED_KEYS = frozenset({"freeze_speed"})
#: The checkpoint keys gnsx needs.
REQUIRED_KEYS = ("state_dict", "hyper_parameters")
#: A model applied to data whose connectivity radius differs by more than this factor is refused.
RADIUS_TOLERANCE = 2.0
#: How zip files (torch's format since 1.6) start, and how legacy torch pickles start.
_ZIP_MAGIC = b"PK\x03\x04"
_PICKLE_MAGIC = b"\x80"


def checkpoint_path(path: str | Path, name: str = "checkpoint") -> Path:
    """A ``.ckpt`` file, or a run directory's ``checkpoints/last.ckpt``.

    Args:
        name: the setting that gave ``path`` (``checkpoint``, ``train.ckpt_path``), for the message.

    Raises:
        CheckpointError: naming the setting and the path that holds no checkpoint.
    """
    p = Path(path)
    if p.is_dir():
        last = p / "checkpoints" / "last.ckpt"
        if not last.is_file():
            found = sorted((p / "checkpoints").glob("*.ckpt")) if (p / "checkpoints").is_dir() else []
            hint = (
                f"; it has {found[-1].name}, pass that file"
                if found
                else ("; the run stopped before its first checkpoint" if (p / ".hydra").is_dir() else "")
            )
            raise CheckpointError(f"{name}={path}", f"no checkpoint here ({last} missing){hint}")
        return last
    if not p.exists():
        raise CheckpointError(f"{name}={path}", "no such file or run directory")
    return p


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict of a gnsx checkpoint file, loaded with ``weights_only=True`` onto the CPU.

    Raises:
        CheckpointError: ``"<path>: not a checkpoint ..."``, ``"<path>: truncated ..."`` or
            ``"<path>: not a gnsx checkpoint ..."`` (a torch file without gnsx's hyperparameters).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as error:
        raise CheckpointError(str(path), f"cannot read: {error.strerror or error}") from None
    size = path.stat().st_size
    if size == 0:
        raise CheckpointError(str(path), "truncated (0 bytes: an empty file)")
    if head == _ZIP_MAGIC and not zipfile.is_zipfile(path):
        raise CheckpointError(
            str(path),
            f"truncated ({size} bytes; the file ends before its zip directory, e.g. a copy or save that "
            "was cut short); use an earlier checkpoint (checkpoints/step*.ckpt)",
        )
    if head[:4] != _ZIP_MAGIC and head[:1] != _PICKLE_MAGIC:
        raise CheckpointError(
            str(path), f"not a checkpoint (not a PyTorch file: starts with {head!r}, {size} bytes)"
        )
    if head == _ZIP_MAGIC:
        with zipfile.ZipFile(path) as archive:
            if not any(name.endswith("data.pkl") for name in archive.namelist()):
                raise CheckpointError(str(path), "not a checkpoint (a zip file, but not a PyTorch archive)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        # weights_only refuses anything but tensors and plain containers: not something train.py wrote.
        found = re.search(r"GLOBAL ([\w.]+)", str(error))
        what = f"a pickled {found.group(1)}" if found else "pickled objects"
        raise CheckpointError(
            str(path),
            f"not a gnsx checkpoint: it holds {what}, which the safe loader (weights_only) refuses",
        ) from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile) as error:
        message = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        kind = "truncated or corrupt" if head == _ZIP_MAGIC else "not a checkpoint"
        raise CheckpointError(str(path), f"{kind} ({message[:160]})") from None
    if not isinstance(state, Mapping) or any(key not in state for key in REQUIRED_KEYS):
        keys = sorted(state)[:6] if isinstance(state, Mapping) else type(state).__name__
        raise CheckpointError(
            str(path),
            f"not a gnsx checkpoint (a PyTorch file without {' and '.join(REQUIRED_KEYS)}; it holds {keys})",
        )
    hparams = state["hyper_parameters"]
    if not isinstance(hparams, Mapping) or not isinstance(hparams.get("model"), Mapping):
        raise CheckpointError(str(path), "not a gnsx checkpoint (its hyper_parameters have no 'model')")
    return dict(state)


def describe_model(model: Mapping[str, Any]) -> str:
    """``"latent_size=64, mp_steps=5, ..."``: a model config (weights-relevant keys only)."""
    skip = RUNTIME_KEYS | RETIRED_KEYS
    return ", ".join(f"{key}={_plain(value)}" for key, value in model.items() if key not in skip)


def model_differences(trained: Mapping[str, Any], expected: Mapping[str, Any]) -> list[str]:
    """``["latent_size: 64 (checkpoint) vs 128", ...]`` for keys both configs set, run-time keys ignored."""
    out = []
    for key in trained:
        if key in RUNTIME_KEYS or key in RETIRED_KEYS or key not in expected:
            continue
        a, b = _plain(trained[key]), _plain(expected[key])
        if a != b:
            out.append(f"{key} {a} (checkpoint) vs {b}")
    return out


def check_resume(path: str | Path, model: Mapping[str, Any], dim: int, radius: float, name: str) -> dict:
    """Read the checkpoint a run resumes from; refuse one of another model config.

    Args:
        model: this run's architecture (:func:`gnsx.training.model_settings.architecture`).
        dim, radius: this run's data dimension and connectivity radius.
        name: the override that named the checkpoint (``train.ckpt_path``, ``train.init_weights``).
    Returns:
        the checkpoint dict (:func:`read_checkpoint`).
    Raises:
        CheckpointError: ``"train.ckpt_path=<path>: trained with model latent_size=64, ... but this run's
            config differs: latent_size 64 (checkpoint) vs 128. Use the checkpoint's model settings, or start
            a new run without train.ckpt_path"``.
    """
    state = read_checkpoint(path)
    hparams = state["hyper_parameters"]
    trained = dict(hparams["model"])
    differences = model_differences(trained, model)
    for key, value in (("dim", dim), ("radius", radius)):
        if key in hparams and not _close(hparams[key], value):
            differences.append(f"{key} {_plain(hparams[key])} (checkpoint) vs {_plain(value)}")
    if differences:
        raise CheckpointError(
            f"{name}={path}",
            f"trained with model {describe_model(trained)}, dim={hparams.get('dim')}, "
            f"radius={hparams.get('radius')}, but this run's config differs: {'; '.join(differences)}. "
            f"Use the checkpoint's model settings, or start a new run without {name}",
        )
    return state


def load_simulator(path: str | Path, device: str | torch.device = "cpu") -> LearnedSimulator:
    """The trained :class:`LearnedSimulator` of a checkpoint (or run directory), eval mode, on ``device``.

    Raises:
        CheckpointError: see :func:`read_checkpoint`; also weights that do not fit the model their own
            hyperparameters describe (a checkpoint of another gnsx version, or edited).
    """
    path = checkpoint_path(path)
    state = read_checkpoint(path)
    hparams = dict(state["hyper_parameters"])
    try:
        simulator = simulator_from_hparams(hparams)
    except (KeyError, TypeError, ValueError) as error:
        raise CheckpointError(
            str(path), f"its hyper-parameters do not build a gnsx model ({error}); another gnsx version?"
        ) from None
    weights = state["state_dict"]
    # The training module (gnsx.training.system.GNSSystem) holds the simulator as its only submodule, so
    # every weight is "simulator.<name>"; anything else is another model's.
    foreign = [key for key in weights if not key.startswith(SIMULATOR_PREFIX)]
    try:
        if foreign:
            raise RuntimeError(f"weights:\nUnexpected key(s) in state_dict: {', '.join(foreign[:5])}")
        simulator.load_state_dict({k[len(SIMULATOR_PREFIX) :]: v for k, v in weights.items()}, strict=True)
    except RuntimeError as error:
        problems = [line.strip() for line in str(error).splitlines()[1:] if line.strip()]
        first = problems[0] if problems else str(error).splitlines()[0]
        raise CheckpointError(
            str(path),
            f"its weights are of another model config than its hyper-parameters say "
            f"({describe_model(hparams['model'])}): {len(problems)} problem(s), first: {first[:200]}",
        ) from None
    return simulator.to(device).eval()


def simulator_from_hparams(hparams: Mapping[str, Any]) -> LearnedSimulator:
    """The untrained :class:`LearnedSimulator` that a checkpoint's hyper-parameters describe: the dataset facts
    (:data:`SIMULATOR_FACTS`) plus the architecture (``hparams["model"]``), as the training module builds it.
    Keys of :data:`RETIRED_KEYS` are dropped (old checkpoints). ``data_radius``, which the rules read
    (:func:`gnsx.rules.scale.rules_radius`), stays: it is a fact of the data the model records.

    Raises:
        KeyError: a fact is missing; TypeError, ValueError: the arguments do not build a model.
    """
    model = {key: value for key, value in hparams["model"].items() if key not in RETIRED_KEYS}
    return LearnedSimulator(**{key: hparams[key] for key in SIMULATOR_FACTS}, **model)


def check_fits(
    simulator: LearnedSimulator,
    where: str,
    bounds: list[list[float]],
    radius: float,
    dim: int,
    target: str,
    hint: str = "",
) -> None:
    """Refuse to apply a model to data (or a preset) unlike its training data.

    The model's dimension and walls must be the data's, and the default radius of the data it was trained on
    (``data_radius``; its own radius for checkpoints that do not record it) within a factor
    :data:`RADIUS_TOLERANCE` of this data's (a radius sweep's or the paper's radius on the same data stays
    inside; a small-preset model, R = 0.035, on WaterRamps-size particles, R = 0.015, does not: its particles
    would be ~2.3x too close for what it learned).

    Args:
        where: the checkpoint (for the message).
        bounds, radius, dim: the data's (metadata or preset).
        target: what the data is, e.g. ``"preset=waterramps"`` or ``"the dataset data/small"``.
        hint: appended to the message (what to do instead).
    Raises:
        CheckpointError: naming the checkpoint, what it was trained with and what ``target`` has.
    """
    cfg = simulator.config
    data_radius = trained_data_radius(simulator)
    trained = f"dim {cfg['dim']}, bounds {cfg['bounds']}, radius {cfg['radius']:g}"
    if not _close(data_radius, cfg["radius"]):
        trained += f" (on data of default radius {data_radius:g})"
    problems = []
    if cfg["dim"] != dim:
        problems.append(f"dim {dim}")
    elif any(not _close(a, b) for pa, pb in zip(cfg["bounds"], bounds) for a, b in zip(pa, pb)):
        problems.append(f"bounds {[[float(v) for v in pair] for pair in bounds]}")
    ratio = data_radius / float(radius)
    if not 1 / RADIUS_TOLERANCE <= ratio <= RADIUS_TOLERANCE:
        problems.append(f"radius {radius:g} ({ratio:.2g}x apart)")
    if problems:
        raise CheckpointError(
            where,
            f"trained with {trained}, but {target} has {', '.join(problems)}: the model does not fit{hint}",
        )


def trained_data_radius(simulator: LearnedSimulator) -> float:
    """The default connectivity radius of the data the model was trained on (``data_radius``), or its own
    radius for checkpoints that do not record it (they all used the data's)."""
    data_radius = simulator.config.get("data_radius")
    return float(simulator.config["radius"] if data_radius is None else data_radius)


def model_label(simulator: LearnedSimulator) -> str:
    """``"simplified GNS 64/5"``, ``"original GNS 128/10"`` or ``"GNS <latent>/<steps>"``, from its config."""
    cfg = simulator.config
    size = f"{cfg['latent_size']}/{cfg['mp_steps']}"
    if cfg["history"] == 1 and cfg["type_encoding"] == "scalar" and not cfg["edge_residual"]:
        return f"simplified GNS {size}"
    if cfg["history"] == 5 and cfg["type_encoding"] == "embedding" and cfg["edge_residual"]:
        return f"original GNS {size}"
    return f"GNS {size}"


def slug(label: str) -> str:
    """A folder name for a label (letters, digits, ``-``, ``_``)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label).strip("_") or "model"


def _plain(value: Any) -> Any:
    """Tuples as lists, so a config read back from a checkpoint compares equal to the config at hand."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def _close(a: Any, b: Any) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-12)
    except (TypeError, ValueError):
        return a == b
