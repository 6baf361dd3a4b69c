"""Rollouts on disk: gnsx's own ``.npz`` format (no pickle) and DeepMind's rollout pickle for their renderer.

gnsx rollout file (``.npz``, ``np.load(path, allow_pickle=False)`` reads every member):

====================  ===========  ==========================================================================
member                dtype        meaning
====================  ===========  ==========================================================================
``predicted``         float32      ``[T, N, D]`` positions (data units), frame 0 first; the first
                                   ``input_frames`` frames are the model's inputs, the rest its predictions
``particle_type``     int64        ``[N]`` type ids (5 water, 3 static/kinematic, ...)
``input_frames``      int64        ``[]`` number of leading frames that were given, not predicted (H + 1)
``ground_truth``      float32      ``[T, N, D]`` (optional) the reference positions of the same frames
``metadata``          str          ``[]`` a JSON object: the dataset metadata (``bounds``, ``dt``,
                                   ``default_connectivity_radius``, ...) plus what produced the rollout
                                   (``"rollout"``: checkpoint, model, trajectory, ...)
====================  ===========  ==========================================================================

DeepMind's rollout pickle (``learning_to_simulate``'s ``render_rollout.py`` reads it) is a dict with exactly
``initial_positions [input_frames, N, D]``, ``predicted_rollout [T - input_frames, N, D]``,
``ground_truth_rollout [T - input_frames, N, D]``, ``particle_types [N]`` and ``metadata`` (a dict). Pickle is
their format; gnsx writes it but never needs it to read its own files.
"""

from __future__ import annotations

import json
import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.atomic import atomic_path
from gnsx.core.errors import DataError

_REQUIRED = ("predicted", "particle_type", "input_frames", "metadata")
DEEPMIND_KEYS = (
    "initial_positions",
    "predicted_rollout",
    "ground_truth_rollout",
    "particle_types",
    "metadata",
)


@dataclass
class Rollout:
    """One rollout of one scene.

    Attributes:
        predicted: ``[T, N, D]`` float32 positions (data units), inputs included (see ``input_frames``).
        particle_type: ``[N]`` int64.
        input_frames: leading frames of ``predicted`` that were given to the model (``history + 1``).
        ground_truth: ``[T, N, D]`` float32 reference positions, or None.
        metadata: JSON-ready dict: dataset metadata (``bounds``, ``dt``, ...) and provenance.
    """

    predicted: np.ndarray
    particle_type: np.ndarray
    input_frames: int
    ground_truth: np.ndarray | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        self.predicted = np.asarray(self.predicted, np.float32)
        self.particle_type = np.asarray(self.particle_type, np.int64)
        self.input_frames = int(self.input_frames)
        if self.ground_truth is not None:
            self.ground_truth = np.asarray(self.ground_truth, np.float32)
        self._check("rollout")

    def _check(self, where: str) -> None:
        if self.predicted.ndim != 3:
            raise DataError(where, f"predicted must be [T, N, D], got shape {self.predicted.shape}")
        t, n, _ = self.predicted.shape
        if self.particle_type.shape != (n,):
            raise DataError(where, f"particle_type must be [N] = [{n}], got shape {self.particle_type.shape}")
        if not 1 <= self.input_frames <= t:
            raise DataError(where, f"input_frames must be in [1, T = {t}], got {self.input_frames}")
        if self.ground_truth is not None and self.ground_truth.shape != self.predicted.shape:
            raise DataError(
                where,
                f"ground_truth shape {self.ground_truth.shape} differs from predicted {self.predicted.shape}",
            )

    @property
    def bounds(self) -> np.ndarray:
        """``[D, 2]`` walls from the metadata."""
        if "bounds" not in self.metadata:
            raise DataError("rollout metadata", "no 'bounds' key")
        return np.asarray(self.metadata["bounds"], np.float64)


def save_rollout(path: str | os.PathLike, rollout: Rollout) -> Path:
    """Write ``rollout`` as a gnsx rollout ``.npz`` (compressed; atomic: temp file, then rename)."""
    path = Path(path)
    if path.suffix != ".npz":
        raise DataError(str(path), "a gnsx rollout file must end in .npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "predicted": rollout.predicted,
        "particle_type": rollout.particle_type,
        "input_frames": np.asarray(rollout.input_frames, np.int64),
        "metadata": np.asarray(json.dumps(rollout.metadata)),  # a 0-d unicode array, not an object
    }
    if rollout.ground_truth is not None:
        arrays["ground_truth"] = rollout.ground_truth
    # A file object, so numpy adds no ".npz" to the temporary name.
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


def load_rollout(path: str | os.PathLike) -> Rollout:
    """Read a gnsx rollout ``.npz`` (no pickle).

    Raises:
        DataError: missing file or member, wrong shapes, or metadata that is not a JSON object, naming the
            file.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "rollout file not found")
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [key for key in _REQUIRED if key not in npz.files]
            if missing:
                raise DataError(str(path), f"not a gnsx rollout: missing member(s) {missing}")
            members = {key: npz[key] for key in npz.files}
    except ValueError as e:  # object arrays (pickled) or a corrupt archive
        raise DataError(str(path), f"cannot read without pickle: {e}") from None
    try:
        metadata = json.loads(str(members["metadata"]))
    except json.JSONDecodeError as e:
        raise DataError(f"{path}: metadata", f"invalid JSON: {e.msg}") from None
    if not isinstance(metadata, dict):
        raise DataError(f"{path}: metadata", f"expected a JSON object, got {type(metadata).__name__}")
    try:
        return Rollout(
            predicted=members["predicted"],
            particle_type=members["particle_type"],
            input_frames=int(members["input_frames"]),
            ground_truth=members.get("ground_truth"),
            metadata=metadata,
        )
    except DataError as e:
        raise DataError(str(path), e.problem) from None


def to_deepmind(rollout: Rollout) -> dict[str, Any]:
    """DeepMind's rollout dict (see the module docstring); needs ``ground_truth``."""
    if rollout.ground_truth is None:
        raise DataError("rollout", "DeepMind's format needs a ground truth rollout (ground_truth is None)")
    k = rollout.input_frames
    return {
        "initial_positions": rollout.predicted[:k].copy(),
        "predicted_rollout": rollout.predicted[k:].copy(),
        "ground_truth_rollout": rollout.ground_truth[k:].copy(),
        "particle_types": rollout.particle_type.copy(),
        "metadata": dict(rollout.metadata),
    }


def export_deepmind(path: str | os.PathLike, rollout: Rollout) -> Path:
    """Write DeepMind's rollout pickle (``.pkl``) for their ``render_rollout.py``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(to_deepmind(rollout), f)
    return path


def from_deepmind(data: dict[str, Any], where: str = "rollout pickle") -> Rollout:
    """A :class:`Rollout` from DeepMind's rollout dict (e.g. one loaded from their pickle by the caller)."""
    missing = [key for key in DEEPMIND_KEYS if key not in data]
    if missing:
        raise DataError(where, f"missing key(s) {missing}; expected {list(DEEPMIND_KEYS)}")
    initial = np.asarray(data["initial_positions"], np.float32)
    return Rollout(
        predicted=np.concatenate([initial, np.asarray(data["predicted_rollout"], np.float32)]),
        particle_type=np.asarray(data["particle_types"], np.int64),
        input_frames=len(initial),
        ground_truth=np.concatenate([initial, np.asarray(data["ground_truth_rollout"], np.float32)]),
        metadata=dict(data["metadata"]),
    )
