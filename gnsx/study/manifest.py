"""The study manifest, ``<study>/study.json``: what :mod:`gnsx.study.build` writes and the web app shows.

=================  ======================================================================================
key                meaning
=================  ======================================================================================
``version``        :data:`VERSION`
``name``           the study's name (its folder's name by default)
``seed``           seeds the choice of scenes and, with a participant's id, their order and sides
``groups``         ``[[method_a, method_b], ...]``: the method pairs compared, in report order (MPM first)
``pairs``          ``[{"id", "group", "methods": [a, b], "scene", "files": {method: path}}]``; ``id`` is
                   unique, ``group`` is :func:`group_id` of ``methods``, paths are relative to the study
``render``         how the animations were made (``frames``, ``frame_stride``, ``fps``, ``size``, ``format``)
``sources``        ``{scene: {method: rollout file}}``: where each animation came from
=================  ======================================================================================
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from gnsx.core.errors import DataError

MANIFEST = "study.json"
VERSION = 1


def group_id(method_a: str, method_b: str) -> str:
    """The name of a method pair: ``"MPM vs simplified GNS 64/5"``."""
    return f"{method_a} vs {method_b}"


@dataclass(frozen=True)
class Pair:
    """Two animations of one scene by the two methods of a group."""

    id: str
    group: str
    methods: tuple[str, str]
    scene: str
    files: dict[str, str]


@dataclass(frozen=True)
class Study:
    """A loaded, checked manifest.

    Attributes:
        folder: the study folder (media paths are relative to it).
        digest: SHA-256 of ``study.json``: answers are only ever recorded against one build of a study.
    """

    folder: Path
    name: str
    seed: int
    groups: list[tuple[str, str]]
    pairs: list[Pair]
    render: dict
    digest: str

    def pair(self, pair_id: str) -> Pair:
        """The pair with this id (KeyError when there is none)."""
        for pair in self.pairs:
            if pair.id == pair_id:
                return pair
        raise KeyError(pair_id)

    def media(self, pair: Pair, method: str) -> Path:
        """The animation file of ``method`` in ``pair``."""
        return self.folder / pair.files[method]


def load_study(folder: str | Path) -> Study:
    """Read and check ``<folder>/study.json``.

    Raises:
        DataError: a missing or malformed manifest, duplicate pair ids, a pair whose group or files do not
            match its methods, or a media file that is missing or lies outside the folder.
    """
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise DataError(
            str(folder), f"not a study: no {MANIFEST} (build one with `python -m gnsx.study build`)"
        )
    raw = path.read_bytes()
    try:
        data = json.loads(raw)
    except json.JSONDecodeError as e:
        raise DataError(str(path), f"invalid JSON: {e.msg}") from None
    if not isinstance(data, dict) or data.get("version") != VERSION:
        raise DataError(str(path), f"not a version {VERSION} study manifest")
    try:
        groups = [(str(a), str(b)) for a, b in data["groups"]]
        pairs = [
            Pair(
                id=str(p["id"]),
                group=str(p["group"]),
                methods=(str(p["methods"][0]), str(p["methods"][1])),
                scene=str(p["scene"]),
                files={str(k): str(v) for k, v in p["files"].items()},
            )
            for p in data["pairs"]
        ]
        study = Study(
            folder,
            str(data["name"]),
            int(data["seed"]),
            groups,
            pairs,
            dict(data["render"]),
            hashlib.sha256(raw).hexdigest(),
        )
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise DataError(str(path), f"malformed manifest ({type(e).__name__}: {e})") from None
    _check(study, path)
    return study


def _check(study: Study, path: Path) -> None:
    if not study.pairs:
        raise DataError(str(path), "the study has no pairs")
    seen: set[str] = set()
    root = study.folder.resolve()
    for pair in study.pairs:
        where = f"{path}: pair {pair.id!r}"
        if pair.id in seen:
            raise DataError(where, "duplicate pair id")
        seen.add(pair.id)
        if pair.methods not in study.groups or pair.group != group_id(*pair.methods):
            raise DataError(where, f"group {pair.group!r} is not one of the study's groups")
        if set(pair.files) != set(pair.methods):
            raise DataError(where, f"files for {sorted(pair.files)}, methods {list(pair.methods)}")
        for method in pair.methods:
            media = study.media(pair, method).resolve()
            if not media.is_relative_to(root):
                raise DataError(where, f"{pair.files[method]} lies outside the study folder")
            if not media.is_file():
                raise DataError(where, f"missing animation {pair.files[method]}")
