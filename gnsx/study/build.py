"""Building a study: choose pairs of animations by method pair, render them, write the manifest.

Groups are method pairs: every pair of the methods found (MPM, original, simplified gives the paper's three:
MPM vs original, MPM vs simplified, original vs simplified), or of the methods asked for. Each group gets
``pairs_per_group`` scenes that both of its methods animated, drawn at random (seeded); across groups the
scenes used least so far are drawn first, so the groups show as many different scenes as there are.

Every method's animation of a scene is rendered once with :mod:`gnsx.evaluation.render`, at one colour scale and disc
size for the whole scene (from its ground truth when there is one, else from its first method), so colours
and sizes never tell the methods apart. Animations carry no titles. Files are
``media/<scene>/<method slug>.<gif|mp4>``; the manifest (:mod:`gnsx.study.manifest`) lists the pairs.
"""

from __future__ import annotations

import itertools
import random
import shutil
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.errors import DataError
from gnsx.model.checkpoint import slug
from gnsx.study.manifest import MANIFEST, VERSION, group_id
from gnsx.study.scenes import TRUTH, Scene, collect_scenes, methods_in
from gnsx.study.store import ANSWERS

#: The paper's survey: 8 pairs in each of its 3 groups.
PAIRS_PER_GROUP = 8
FORMATS = ("gif", "mp4")


@dataclass(frozen=True)
class RenderSettings:
    """How the animations are rendered.

    Attributes:
        frames: show the first ``frames`` frames (None: all that every method of the scene has).
        frame_stride: keep every ``frame_stride``-th of them.
        fps: frames per second of the animation.
        size: pixels per side.
        format: ``"gif"`` (plays everywhere) or ``"mp4"`` (H.264, smaller).
    """

    frames: int | None = None
    frame_stride: int = 2
    fps: int = 25
    size: int = 256
    format: str = "gif"

    def check(self) -> None:
        """Raises DataError naming the setting out of range."""
        if self.frames is not None and self.frames < 2:
            raise DataError("--frames", f"at least 2 frames, got {self.frames}")
        for name in ("frame_stride", "fps", "size"):
            if getattr(self, name) < 1:
                raise DataError(f"--{name.replace('_', '-')}", f"must be >= 1, got {getattr(self, name)}")
        if self.size < 32:
            raise DataError("--size", f"at least 32 pixels, got {self.size}")
        if self.format not in FORMATS:
            raise DataError("--format", f"one of {list(FORMATS)}, got {self.format!r}")


def method_groups(methods: Sequence[str]) -> list[tuple[str, str]]:
    """Every pair of ``methods`` in their order: MPM, original, simplified -> the paper's three groups."""
    return list(itertools.combinations(methods, 2))


def choose_pairs(
    scenes: Mapping[str, Sequence[str]], groups: Sequence[tuple[str, str]], per_group: int, seed: int
) -> list[dict]:
    """``per_group`` scenes for every group, among the scenes that both of its methods animated.

    Args:
        scenes: scene key -> the methods that animated it.
        groups: the method pairs.
        per_group: scenes (pairs) per group.
        seed: the draw's seed; ties in use across groups are broken at random.
    Returns:
        ``[{"id", "group", "methods", "scene"}]`` in group order; ids are ``g<group>-<scene>``.
    Raises:
        DataError: a group with fewer scenes than ``per_group``.
    """
    rng = random.Random(seed)
    used: Counter[str] = Counter()
    pairs = []
    for g, (a, b) in enumerate(groups, start=1):
        common = sorted(key for key, methods in scenes.items() if a in methods and b in methods)
        if len(common) < per_group:
            raise DataError(
                "--pairs-per-group",
                f"{group_id(a, b)}: {len(common)} scenes have both methods, {per_group} pairs asked "
                "(ask fewer, or give rollouts of more trajectories)",
            )
        rng.shuffle(common)
        common.sort(key=lambda key: used[key])  # stable: least used first, shuffled within a use count
        for key in sorted(common[:per_group]):
            used[key] += 1
            pairs.append({"id": f"g{g}-{key}", "group": group_id(a, b), "methods": [a, b], "scene": key})
    return pairs


def render_scene(
    scene: Scene, methods: Sequence[str], folder: Path, settings: RenderSettings
) -> dict[str, str]:
    """Render ``methods``' animations of ``scene`` into ``folder``, all at one colour scale and disc size.

    Returns:
        method -> file name (inside ``folder``).
    """
    from gnsx.evaluation.render import (
        colour_scale,
        disc_radii,
        particle_spacing,
        render_frame,
        save_animation,
        speeds,
    )

    reference = scene.positions[TRUTH if TRUTH in scene.positions else methods[0]]
    length = min(len(scene.positions[m]) for m in methods)
    if settings.frames is not None:
        length = min(length, settings.frames)
    picks = range(0, length, settings.frame_stride)
    scale = colour_scale(speeds(reference[:length]), scene.particle_type)
    radii = disc_radii(particle_spacing(reference[0], scene.particle_type), scene.bounds, settings.size)
    names = {}
    for method in methods:
        positions = scene.positions[method][:length]
        speed = speeds(positions)
        frames = np.stack(
            [
                render_frame(
                    positions[t], scene.particle_type, speed[t], scene.bounds, settings.size, scale, *radii
                )
                for t in picks
            ]
        )
        name = f"{slug(method)}.{settings.format}"
        save_animation(frames, folder / name, fps=settings.fps)
        names[method] = name
    return names


def _check_methods(found: Sequence[str], asked: Sequence[str] | None) -> list[str]:
    """The methods to compare: ``asked`` (each one found, no repeats) or every one found; at least two."""
    methods = list(asked) if asked else list(found)
    missing = [m for m in methods if m not in found]
    if missing:
        raise DataError("--methods", f"no rollouts of {missing}; found {list(found)}")
    if len(set(methods)) != len(methods):
        raise DataError("--methods", f"a method is named twice: {methods}")
    if len(methods) < 2:
        raise DataError("--rollouts", f"a study needs two methods or more, found {list(found)}")
    slugs = Counter(slug(m) for m in methods)
    clash = [m for m in methods if slugs[slug(m)] > 1]
    if clash:
        raise DataError("--methods", f"{clash} share a file name ({slug(clash[0])}); rename one (NAME=PATH)")
    return methods


def build_study(
    sources: Sequence[str | Path],
    out: str | Path,
    pairs_per_group: int = PAIRS_PER_GROUP,
    methods: Sequence[str] | None = None,
    settings: RenderSettings = RenderSettings(),
    seed: int = 0,
    name: str | None = None,
    force: bool = False,
) -> Path:
    """Build a study into ``out``: animations in ``out/media/`` and the manifest ``out/study.json``.

    Args:
        sources: rollout files or folders, each optionally ``NAME=PATH``
            (:func:`~gnsx.study.scenes.collect_scenes`).
        pairs_per_group: pairs (scenes) per method pair.
        methods: the methods to compare, in report order (default: every one found, MPM first).
        settings: how to render the animations.
        seed: seeds the scenes drawn for each group (and, in the web app, each participant's order).
        name: the study's name (default: ``out``'s folder name).
        force: rebuild a study that already has answers (they would no longer match it).
    Returns:
        the manifest's path.
    Raises:
        DataError: bad settings or rollouts, too few scenes, or a study with answers and no ``force``.
    """
    out = Path(out)
    settings.check()
    if pairs_per_group < 1:
        raise DataError("--pairs-per-group", f"must be >= 1, got {pairs_per_group}")
    if (out / ANSWERS).exists() and not force:
        raise DataError(str(out), f"already has answers ({ANSWERS}); build into a new folder (or --force)")
    scenes = collect_scenes(sources)
    methods = _check_methods(methods_in(scenes), methods)
    groups = method_groups(methods)
    pairs = choose_pairs({k: list(s.positions) for k, s in scenes.items()}, groups, pairs_per_group, seed)

    media = out / "media"
    if media.exists():
        shutil.rmtree(media)  # only the build's own folder: no stale animations of an earlier build
    needed: dict[str, set[str]] = {}
    for pair in pairs:
        needed.setdefault(pair["scene"], set()).update(pair["methods"])
    files: dict[str, dict[str, str]] = {}
    for key, wanted in sorted(needed.items()):
        ordered = [m for m in methods if m in wanted]
        names = render_scene(scenes[key], ordered, media / key, settings)
        files[key] = {m: f"media/{key}/{file}" for m, file in names.items()}
    for pair in pairs:
        pair["files"] = {m: files[pair["scene"]][m] for m in pair["methods"]}
    manifest = {
        "version": VERSION,
        "name": name or out.resolve().name,
        "seed": seed,
        "groups": [list(g) for g in groups],
        "pairs": pairs,
        "render": asdict(settings),
        "sources": {
            key: {m: scenes[key].sources[m] for m in sorted(wanted)} for key, wanted in sorted(needed.items())
        },
    }
    out.mkdir(parents=True, exist_ok=True)
    ignore = out / ".gitignore"
    if not ignore.exists():  # a study (media, answers) is data, not source; delete this file to commit one
        ignore.write_text("*\n")
    return write_json(out / MANIFEST, manifest)
