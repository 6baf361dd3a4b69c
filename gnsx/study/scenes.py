"""Rollout files to study scenes: which methods animated which initial state.

The study is built from gnsx rollout files (:mod:`gnsx.data.rollout_io`), as ``evaluate.py`` writes them
(``<run dir>/<model>/rollouts/<split>_<i>.npz``). Each file gives one scene (an initial state: a trajectory of
a dataset split) animated by one model, and usually the MPM ground truth of the same frames, which becomes the
method :data:`TRUTH`. The method of a file is the model label ``evaluate.py`` stored in it
(``"simplified GNS 64/5"``, ``"original GNS 128/10"``, or the ``labels=`` given there) unless the command line
names it (``NAME=PATH``).

A scene's key is ``<split>_<trajectory>`` from the file's provenance (its file name when it has none). Every
rollout of one scene must start from the same particles at the same positions, and every ground truth of it
must agree: otherwise the files came from different datasets and the pairs would not show the same initial
state, so :func:`collect_scenes` refuses them.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gnsx.core.errors import DataError
from gnsx.data.rollout_io import Rollout, load_rollout

#: The method name of the ground truth (gnsx's MPM solver; the paper's "Taichi-MPM").
TRUTH = "MPM"
#: Positions of the same initial state may differ by float32 round-off between files, no more.
SAME_POSITION_ATOL = 1e-6


@dataclass
class Scene:
    """One initial state and every method's animation of it.

    Attributes:
        key: ``<split>_<trajectory>`` (e.g. ``"test_0003"``), or the file name without its suffix.
        particle_type: ``[N]`` int64.
        bounds: ``[D, 2]`` walls.
        positions: method -> ``[T, N, D]`` float32 positions (data units), frame 0 first.
        sources: method -> the file it came from.
    """

    key: str
    particle_type: np.ndarray
    bounds: np.ndarray
    positions: dict[str, np.ndarray] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)

    def add(self, method: str, positions: np.ndarray, source: str) -> None:
        """Add ``method``'s ``[T, N, D]`` positions from ``source``, checking they start where the others do.

        A second ground truth of the scene is checked against the first and then dropped.

        Raises:
            DataError: another model's rollout of this scene under the same name, a different particle
                count or initial state, or a ground truth that disagrees with the first one.
        """
        first = next(iter(self.positions.values()), None)
        if first is not None and (
            positions.shape[1:] != first.shape[1:]
            or not np.allclose(positions[0], first[0], atol=SAME_POSITION_ATOL)
        ):
            raise DataError(
                source,
                f"scene {self.key} starts from other particles than {next(iter(self.sources.values()))} "
                "(rollouts of different datasets?)",
            )
        if method not in self.positions:
            self.positions[method] = positions
            self.sources[method] = source
            return
        if method != TRUTH:
            raise DataError(
                source,
                f"a second rollout of scene {self.key} by {method!r} (first: {self.sources[method]}); "
                "name the methods apart with NAME=PATH",
            )
        known = self.positions[TRUTH]
        frames = min(len(known), len(positions))
        if not np.allclose(known[:frames], positions[:frames], atol=SAME_POSITION_ATOL, equal_nan=True):
            raise DataError(
                source, f"its ground truth of scene {self.key} differs from that in {self.sources[TRUTH]}"
            )
        if len(positions) > len(known):  # keep the longer of two agreeing ground truths
            self.positions[TRUTH] = positions
            self.sources[TRUTH] = source


def parse_source(spec: str) -> tuple[str | None, Path]:
    """``"NAME=PATH"`` or ``"PATH"`` -> ``(NAME or None, PATH)``.

    A ``=`` only names the method when the whole spec is not an existing path.
    """
    if "=" in spec and not Path(spec).exists():
        name, path = spec.split("=", 1)
        name = name.strip()
        if not name:
            raise DataError(spec, "empty method name before '='")
        return name, Path(path)
    return None, Path(spec)


def rollout_files(path: Path) -> list[Path]:
    """``path`` itself (a ``.npz`` file), or every ``.npz`` under the folder ``path``, sorted.

    Raises:
        DataError: a missing path, a file that is not ``.npz``, or a folder without rollout files.
    """
    if path.is_file():
        if path.suffix != ".npz":
            raise DataError(str(path), "not a gnsx rollout file (.npz)")
        return [path]
    if not path.is_dir():
        raise DataError(str(path), "no such file or folder")
    files = sorted(p for p in path.rglob("*.npz") if p.is_file())
    if not files:
        raise DataError(str(path), "no rollout files (.npz) in this folder; evaluate.py writes them")
    return files


def method_of(rollout: Rollout, path: Path) -> str:
    """The model label ``evaluate.py`` stored in the rollout's provenance (``metadata["rollout"]["model"]``).

    Raises:
        DataError: the file names no model (name it on the command line, ``NAME=PATH``).
    """
    label = (rollout.metadata.get("rollout") or {}).get("model")
    if not isinstance(label, str) or not label.strip():
        raise DataError(str(path), "the rollout names no model; name its method: NAME=PATH")
    return label.strip()


def scene_key(rollout: Rollout, path: Path) -> str:
    """``<split>_<trajectory>`` (e.g. ``test_0003``) from the provenance, else the file name's stem."""
    provenance = rollout.metadata.get("rollout") or {}
    split, index = provenance.get("split"), provenance.get("trajectory")
    if isinstance(split, str) and isinstance(index, int):
        return f"{split}_{index:04d}"
    return path.stem


def collect_scenes(specs: Sequence[str | os.PathLike]) -> dict[str, Scene]:
    """Read every rollout named by ``specs`` (``[NAME=]PATH``, files or folders) into scenes by key.

    Each file adds its model's rollout (method: ``NAME`` or its stored label) and, when it carries one, the
    ground truth (method :data:`TRUTH`) to its scene. Only 2D rollouts can be shown.

    Raises:
        DataError: an unreadable or 3D file, a model named :data:`TRUTH`, or scenes that do not agree
            (:meth:`Scene.add`).
    """
    scenes: dict[str, Scene] = {}
    for spec in specs:
        name, path = parse_source(os.fspath(spec))
        for file in rollout_files(path):
            rollout = load_rollout(file)
            method = name or method_of(rollout, file)
            if method == TRUTH:
                raise DataError(str(file), f"{TRUTH!r} names the ground truth; give the model another name")
            if rollout.predicted.shape[2] != 2:
                raise DataError(
                    str(file), f"only 2D rollouts can be animated, got D = {rollout.predicted.shape[2]}"
                )
            key = scene_key(rollout, file)
            scene = scenes.get(key)
            if scene is None:
                scene = scenes[key] = Scene(key, rollout.particle_type, rollout.bounds)
            elif not np.array_equal(scene.particle_type, rollout.particle_type):
                raise DataError(str(file), f"scene {key} has other particle types than {scene.sources}")
            scene.add(method, rollout.predicted, str(file))
            if rollout.ground_truth is not None:
                scene.add(TRUTH, rollout.ground_truth, str(file))
    return scenes


def methods_in(scenes: dict[str, Scene]) -> list[str]:
    """Every method of the scenes: :data:`TRUTH` first when present, then the others sorted by name."""
    found = {method for scene in scenes.values() for method in scene.positions}
    return ([TRUTH] if TRUTH in found else []) + sorted(found - {TRUTH})
