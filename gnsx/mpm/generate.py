"""Simulate scenes into trajectories, and whole WaterRamps-like datasets into gnsx's on-disk format.

Every trajectory's randomness (its scene and its particle placement) comes from ``(seed, split, index)``
alone, so a dataset does not depend on the number of worker processes or the order they finish in. Each
worker runs torch on one thread: at a few thousand particles one MPM process per core beats one process
on all cores, and a fixed thread count keeps float results identical between runs.

Generation is resumable. While :func:`generate_dataset` writes ``out``, each worker keeps every trajectory it
finishes in a cache folder next to it, ``<out>.partial/<split>/<index:06d>.npz`` (written to a temp name and
renamed, so a file there is always complete), with ``<out>.partial/generation.json`` naming the preset
settings, seed and solver settings it belongs to. ``out`` itself is only created by the final atomic swap of
the store. A generation killed after 14 minutes (SIGKILL, Ctrl-C, the end of a session) thus loses at most the
trajectories in flight: rerunning it with the same ``out``, preset and seed loads the cached trajectories,
simulates only the missing ones, and writes a dataset identical to an uninterrupted one (trajectory ``i`` of a
split is a function of ``(preset, seed, split, i)``). The cache is removed once the dataset is written.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import shutil
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from gnsx.core.atomic import atomic_path, write_json
from gnsx.core.constants import KINEMATIC_PARTICLE_ID, SPLITS, WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.store import write_dataset
from gnsx.data.trajectory import Trajectory
from gnsx.mpm.presets import Preset, get_preset
from gnsx.mpm.scenes import (
    Scene,
    ramp_particles,
    sample_dam_scene,
    sample_rest_scene,
    sample_scene,
    water_particles,
)
from gnsx.mpm.solver import MLSMPMSolver

log = logging.getLogger("gnsx")

#: Suffix of the folder next to ``out`` that keeps the finished trajectories of an unfinished generation.
CACHE_SUFFIX = ".partial"
#: The cache's record of what it was generated for (written before its first trajectory).
CACHE_RECORD_FILE = "generation.json"
_CACHE_FORMAT = 1
_CACHED_FILE = "{index:06d}.npz"
# Preset fields that do not change any trajectory: the counts only say how many to generate (trajectory i of
# a split is the same in a 100- and a 400-trajectory dataset), so a cache serves a rerun with other counts.
_FIELDS_NOT_IN_TRAJECTORIES = ("trajectories",)
#: Preset fields added after caches were first written, with the value every older record was made with: a
#: record that lacks one was generated with it, so it is no reason to refuse that cache.
_PRESET_FIELDS_ADDED = {"dam_fraction": 0.0}
#: The fourth seed word of :func:`rest_rng` (scene_rng's seeds have three).
_REST_STREAM = 1


def check_scene(scene: Scene, preset: Preset, where: str = "scene") -> None:
    """Reject scenes the model cannot start from: no water block, or a block outside the walls."""
    lo, hi = preset.bounds
    if not scene.blocks:
        raise DataError(where, "no water block (add one under 'blocks')")
    for i, block in enumerate(scene.blocks):
        if min(block.lower) < lo or max(block.upper) > hi:
            raise DataError(f"{where}.blocks[{i}]", f"extends outside the walls [{lo}, {hi}]^2")


def initial_state(scene: Scene, preset: Preset, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scene's particles as the MPM generator makes them: water first (type 5), then ramps (type 3).

    Returns:
        ``position [N, 2]`` float32 (m), ``velocity [N, 2]`` float32 (m/s; 0 for ramps), ``particle_type [N]``
        int64.
    """
    rng = np.random.default_rng(seed)
    water, velocity = water_particles(
        scene, preset.particle_spacing, rng, jitter=preset.jitter, clearance=preset.ramp_clearance
    )
    if len(water) == 0:
        raise DataError("scene", "no water particle (every block lies inside a ramp's band)")
    ramps = ramp_particles(scene, preset.ramp_spacing)
    position = np.concatenate([water, ramps]).astype(np.float32)
    velocity = np.concatenate([velocity, np.zeros_like(ramps)]).astype(np.float32)
    particle_type = np.concatenate(
        [np.full(len(water), WATER_PARTICLE_ID), np.full(len(ramps), KINEMATIC_PARTICLE_ID)]
    ).astype(np.int64)
    return position, velocity, particle_type


def scene_solver(
    scene: Scene,
    preset: Preset,
    seed: int = 0,
    device: str | torch.device = "cpu",
    *,
    position_noise: float = 0.0,
    noise_seed: int = 0,
) -> tuple[MLSMPMSolver, np.ndarray, np.ndarray]:
    """The preset's solver holding the scene's water at frame 0 (the scene is checked first).

    Args:
        position_noise: standard deviation (m) of Gaussian noise added to every water particle's initial
            position (seeded by ``noise_seed``), clipped into the walls; 0 (the default) adds nothing and
            draws nothing. :mod:`gnsx.evaluation.sensitivity` uses it to measure how far a perturbed start drifts.

    Returns:
        The solver, and the scene's ``position [N, 2]`` float32 and ``particle_type [N]`` of
        :func:`initial_state` (water first, then the ramps the solver holds as segments; the water as the
        solver got it, noise included).
    """
    check_scene(scene, preset)
    initial_position, velocity, particle_type = initial_state(scene, preset, seed)
    water = particle_type == WATER_PARTICLE_ID
    if position_noise > 0.0:
        noise = np.random.default_rng(noise_seed).normal(0.0, position_noise, (int(water.sum()), 2))
        lo, hi = preset.bounds
        moved = np.clip(initial_position[water] + noise, lo, hi)
        initial_position[water] = moved.astype(np.float32)
    solver = MLSMPMSolver(
        initial_position[water],
        velocity[water],
        scene.ramp_array(),
        preset.particle_spacing,
        preset.solver_settings(),
        device=device,
    )
    return solver, initial_position, particle_type


def run_scene(
    scene: Scene,
    preset: Preset,
    seed: int,
    device: str | torch.device = "cpu",
    *,
    position_noise: float = 0.0,
    noise_seed: int = 0,
) -> tuple[Trajectory, MLSMPMSolver]:
    """Simulate ``scene`` with ``preset``'s solver and return the trajectory and the finished solver.

    The solver is returned for its diagnostics (``J``, ``ramp_corrections``, ``wall_clamps``).
    See :func:`simulate_scene` for the arguments and the trajectory layout, :func:`scene_solver` for
    ``position_noise`` and ``noise_seed``.
    """
    solver, initial_position, particle_type = scene_solver(
        scene, preset, seed, device, position_noise=position_noise, noise_seed=noise_seed
    )
    ramps = initial_position[particle_type != WATER_PARTICLE_ID]
    water_position = solver.run(preset.num_frames)  # [T, N_water, 2] float32
    # Ramps are static: the same positions in every frame, after the water (as scene_particles orders them).
    ramp_position = np.broadcast_to(ramps.astype(np.float32), (preset.num_frames, *ramps.shape))
    position = np.ascontiguousarray(np.concatenate([water_position, ramp_position], axis=1))
    return Trajectory(position=position, particle_type=particle_type, key=0), solver


def simulate_scene(scene: Scene, preset: Preset, seed: int, device: str | torch.device = "cpu") -> Trajectory:
    """Simulate one scene for ``preset.num_frames`` frames.

    Args:
        scene: the initial condition.
        preset: solver settings, particle spacings and the number of frames.
        seed: seeds the water particle placement: the same particles as
            :func:`~gnsx.mpm.scenes.scene_particles` with ``np.random.default_rng(seed)`` and the preset's
            spacing, jitter and ``ramp_clearance``.
        device: torch device to simulate on.

    Returns:
        A :class:`Trajectory` with ``position`` ``[num_frames, N, 2]`` float32 (m; frame 0 is the initial
        state; water first, then the static ramp particles, present and unmoved in every frame) and
        ``particle_type`` ``[N]`` int64 (5 water, 3 ramp); ``key`` 0.
    """
    return run_scene(scene, preset, seed, device)[0]


def scene_rng(seed: int, split: str, index: int) -> np.random.Generator:
    """The generator behind trajectory ``index`` of ``split``: a function of the three alone."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    return np.random.default_rng([seed, SPLITS.index(split), index])


def rest_rng(seed: int, split: str, index: int) -> np.random.Generator:
    """The generator that decides whether trajectory ``index`` of ``split`` is a pool at rest.

    A stream apart from :func:`scene_rng`'s, so ``preset.rest_fraction`` changes which scenes are pools but
    not what any other scene is.
    """
    return np.random.default_rng([seed, SPLITS.index(split), index, _REST_STREAM])


def is_rest_scene(preset: Preset, seed: int, split: str, index: int) -> bool:
    """Whether trajectory ``index`` of ``split`` starts as a pool at rest (training split only)."""
    if split != "train" or preset.rest_fraction <= 0.0:
        return False
    return bool(rest_rng(seed, split, index).uniform() < preset.rest_fraction)


def is_dam_scene(preset: Preset, seed: int, split: str, index: int) -> bool:
    """Whether trajectory ``index`` of ``split`` is a dam break (training split only): the rest stream's
    draw falls in ``[rest_fraction, rest_fraction + dam_fraction)``, so dams never take a pool's place."""
    if split != "train" or preset.dam_fraction <= 0.0:
        return False
    u = rest_rng(seed, split, index).uniform()
    return bool(preset.rest_fraction <= u < preset.rest_fraction + preset.dam_fraction)


def split_scene(preset: Preset, seed: int, split: str, index: int) -> tuple[Scene, int]:
    """The scene of trajectory ``index`` of ``split`` (dataset ``seed``) and the seed of its particle
    placement (the ``seed`` argument of :func:`simulate_scene`)."""
    rng = scene_rng(seed, split, index)
    if is_rest_scene(preset, seed, split, index):
        sample = sample_rest_scene
    elif is_dam_scene(preset, seed, split, index):
        sample = sample_dam_scene
    else:
        sample = sample_scene
    scene = sample(rng, preset)
    return scene, int(rng.integers(2**63))


def simulate_split_item(preset: Preset, seed: int, split: str, index: int) -> Trajectory:
    """Trajectory ``index`` of ``split`` in the dataset generated with ``seed`` (key = ``index``)."""
    scene, placement_seed = split_scene(preset, seed, split, index)
    traj = simulate_scene(scene, preset, seed=placement_seed)
    traj.key = index
    return traj


def _worker_init() -> None:
    torch.set_num_threads(1)


def _task(args: tuple[Preset, int, str, int, Path | None]) -> Trajectory:
    """Simulate one trajectory and, given a cache path, keep it there (in the worker, so a trajectory is
    saved as soon as it is finished, whatever order the others finish in)."""
    preset, seed, split, index, cache_file = args
    traj = simulate_split_item(preset, seed, split, index)
    if cache_file is not None:
        _save_cached(cache_file, traj)
    return traj


def generation_cache(out: str | os.PathLike) -> Path:
    """The cache folder of a generation into ``out``: ``<out>.partial`` next to it."""
    out = Path(out)
    if out.name in ("", ".", ".."):
        out = Path(os.path.abspath(out))
    return out.with_name(out.name + CACHE_SUFFIX)


def _save_cached(path: Path, traj: Trajectory) -> None:
    """Write ``traj`` to ``path`` (``.npz``: ``position``, ``particle_type``, ``key``) atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:  # a file object: np.savez would append ".npz"
        np.savez(
            f,
            position=np.asarray(traj.position, dtype=np.float32),  # as the store converts: same bytes
            particle_type=np.asarray(traj.particle_type, dtype=np.int64),
            key=np.int64(traj.key),
        )


def _load_cached(path: Path, index: int, num_frames: int) -> Trajectory | str:
    """The cached trajectory at ``path``, or why it is unusable (unreadable, truncated, wrong layout)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            position, particle_type, key = z["position"], z["particle_type"], int(z["key"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        return f"unreadable ({type(e).__name__}: {e})"
    if position.dtype != np.float32 or position.ndim != 3 or position.shape[0] != num_frames:
        return f"position is {position.dtype} {position.shape}, expected float32 [{num_frames}, N, D]"
    if particle_type.dtype != np.int64 or particle_type.shape != position.shape[1:2]:
        expected = f"int64 [{position.shape[1]}]"
        return f"particle_type is {particle_type.dtype} {particle_type.shape}, expected {expected}"
    if key != index:
        return f"holds trajectory {key}, not {index}"
    return Trajectory(position=position, particle_type=particle_type, key=key)


def _json_ready(value: Any) -> Any:
    """``value`` as it reads back from JSON (tuples become lists), so records compare equal."""
    return json.loads(json.dumps(value))


def _record_differences(found: dict, expected: dict) -> list[str]:
    """What differs between a cache's record and this generation's, e.g. ``seed 0 (now 3)``."""
    if found.get("format") != expected["format"]:
        return [f"cache format {found.get('format')!r} (this gnsx writes {expected['format']})"]
    differences = []
    if found.get("seed") != expected["seed"]:
        differences.append(f"seed {found.get('seed')!r} (now {expected['seed']!r})")
    for section, label in (("preset_settings", "preset"), ("solver", "solver")):
        old, new = found.get(section), expected[section]
        if not isinstance(old, dict):
            differences.append(f"no {label} settings recorded")
            break
        if section == "preset_settings":
            old = {**_PRESET_FIELDS_ADDED, **old}
        fields = [
            f"{label} {key} {old.get(key)!r} (now {new.get(key)!r})"
            for key in sorted(set(old) | set(new))
            if key not in _FIELDS_NOT_IN_TRAJECTORIES and old.get(key) != new.get(key)
        ]
        differences += fields
        if fields:
            break  # the solver settings follow from the preset's: listing both would repeat it
    if len(differences) > 4:
        differences = [*differences[:3], f"{len(differences) - 3} more"]
    return differences


def _open_cache(cache: Path, record: dict) -> None:
    """Start the cache folder with its record, or check that an existing one was made for ``record``.

    Raises:
        DataError: naming the cache folder, when it belongs to other settings, is unreadable, or is not a
            cache; it is never deleted here (it may hold hours of simulation).
    """
    record_path = cache / CACHE_RECORD_FILE
    delete = f"delete {cache} to start over"
    if cache.exists() and not cache.is_dir():
        raise DataError(
            str(cache), f"exists and is not a folder (gnsx keeps unfinished generations here); {delete}"
        )
    if record_path.is_file():
        try:
            found = json.loads(record_path.read_text())
        except (OSError, ValueError) as e:
            raise DataError(str(record_path), f"unreadable generation cache record ({e}); {delete}") from None
        if not isinstance(found, dict):
            raise DataError(str(record_path), f"not a generation cache record; {delete}")
        differences = _record_differences(found, record)
        if differences:
            raise DataError(
                str(cache),
                f"cache of an unfinished generation with other settings: {'; '.join(differences)}; "
                f"rerun with those settings to finish it, or {delete}",
            )
        return
    if cache.is_dir() and any(not p.name.startswith(".") for p in cache.iterdir()):
        raise DataError(
            str(cache), f"exists but is not a generation cache (no {CACHE_RECORD_FILE}); {delete}"
        )
    cache.mkdir(parents=True, exist_ok=True)
    write_json(record_path, record)


def _scan_cache(cache: Path, counts: dict[str, int], num_frames: int) -> dict[str, set[int]]:
    """``{split: indices}`` of the usable cached trajectories; unusable files are deleted with a warning.

    Temp files of writes a kill interrupted are hidden (``.name.tmp``) and ignored.
    """
    usable: dict[str, set[int]] = {}
    for split, count in counts.items():
        folder = cache / split
        folder.mkdir(exist_ok=True)
        usable[split] = set()
        for index in range(count):
            path = folder / _CACHED_FILE.format(index=index)
            if not path.is_file():
                continue
            loaded = _load_cached(path, index, num_frames)
            if isinstance(loaded, Trajectory):
                usable[split].add(index)
                continue
            log.warning(
                "%s: %s; discarding it, trajectory %d of '%s' is simulated again", path, loaded, index, split
            )
            path.unlink(missing_ok=True)
    return usable


@contextmanager
def one_thread() -> Iterator[None]:
    """Run torch on one thread inside the block (as a worker would), then restore the caller's setting."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def generate_dataset(
    out: str | Path,
    preset: Preset | str,
    seed: int = 0,
    workers: int = 2,
    overwrite: bool = False,
    progress: bool = True,
    splits: Sequence[str] | None = None,
) -> Path:
    """Simulate every trajectory of ``preset`` and write the dataset to ``out``; resumes a killed run.

    Trajectory ``i`` of split ``s`` is :func:`simulate_split_item` ``(preset, seed, s, i)``; ``workers``
    processes simulate them in parallel and the store writes them in index order, one at a time. The metadata
    holds DeepMind's keys (bounds, ``sequence_length = num_frames - 1``, the preset's connectivity radius,
    dim 2, dt), statistics computed by the store from the train split, and under ``"gnsx"`` the generation
    facts (preset, seed, solver settings).

    Resuming: the store writes ``out`` only at the end, so each finished trajectory is also kept in
    :func:`generation_cache` ``(out)`` (``<out>.partial/<split>/<index:06d>.npz``, written atomically by the
    worker that simulated it, next to a ``generation.json`` recording the preset settings, seed and solver
    settings). A kill then loses at most the trajectories in flight: a rerun with the same ``out``, preset and
    seed loads the cached trajectories (the progress bar starts at their count), simulates only the missing
    ones, and writes the same arrays an uninterrupted run would. A cached file that fails to load is
    discarded with a warning and simulated again; temp files of interrupted writes are ignored. Once the
    dataset is written the cache folder is removed. The preset's trajectory counts may differ between the
    runs (trajectory ``i`` does not depend on them); any other preset setting or the seed may not. The cache
    needs as much disk as the dataset until the end.

    Args:
        out: the dataset folder to create.
        preset: a :class:`Preset` or a preset name.
        seed: dataset seed (non-negative).
        workers: simulation processes; 1 simulates in this process.
        overwrite: replace an existing dataset at ``out`` (a matching cache is still used, a cache of
            other settings is still refused).
        progress: show a tqdm progress bar.
        splits: the splits to generate (default: every split of the preset); must include ``train`` unless
            statistics come from elsewhere.

    Returns:
        ``out`` as a :class:`Path`.

    Raises:
        DataError: ``out`` already holds a dataset (without ``overwrite``) or is a non-empty folder that is
            not a dataset; the cache folder belongs to another preset or seed (the message names it and what
            differs; it is never deleted for you), or is not a cache; anything the store rejects.
    """
    out = Path(out)
    if isinstance(preset, str):
        preset = get_preset(preset)
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    splits = list(SPLITS if splits is None else splits)
    for split in splits:
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; expected some of {SPLITS}")
    # Refuse before hours of simulation, not after (the store would refuse too, at the end).
    if out.exists() and not out.is_dir():
        raise DataError(str(out), "exists and is not a folder; choose another path")
    if (out / "metadata.json").exists() and not overwrite:
        raise DataError(
            str(out), "a dataset already exists here; pass overwrite=True (--overwrite) to replace it"
        )
    if out.is_dir() and any(out.iterdir()) and not (out / "metadata.json").exists():
        raise DataError(
            str(out), "folder exists, is not empty and is not a gnsx dataset; choose another path"
        )

    settings = preset.solver_settings()
    solver = settings.to_dict() | {"dx": settings.dx, "cells": settings.cells}
    metadata = {
        "bounds": [list(preset.bounds), list(preset.bounds)],
        "sequence_length": preset.num_frames - 1,
        "default_connectivity_radius": preset.default_connectivity_radius,
        "dim": 2,
        "dt": preset.frame_dt,
        "gnsx": {
            "generator": "gnsx.mpm (2D MLS-MPM water, mpm88 scheme)",
            "preset": preset.name,
            "preset_settings": preset.to_dict(),
            "seed": seed,
            "solver": solver,
        },
    }
    counts = {split: int(preset.trajectories.get(split, 0)) for split in splits}
    cache = generation_cache(out)
    record = {"format": _CACHE_FORMAT, "preset_settings": preset.to_dict(), "seed": seed, "solver": solver}
    _open_cache(cache, _json_ready(record))
    cached = _scan_cache(cache, counts, preset.num_frames)
    total, resumed = sum(counts.values()), sum(len(indices) for indices in cached.values())
    missing = total - resumed
    if resumed:
        log.info("%s: resuming, %d of %d trajectories already simulated", cache, resumed, total)
    desc = f"simulating {preset.name}" + (f" ({resumed} resumed)" if resumed else "")
    bar = tqdm(total=total, initial=resumed, desc=desc, unit="traj", disable=not progress)

    def cache_file(split: str, index: int) -> Path:
        return cache / split / _CACHED_FILE.format(index=index)

    def split_items(pool, split: str) -> Iterator[Trajectory]:
        # Started only when the store asks for this split; imap yields the missing ones in index order, and
        # the cached ones are slotted in between, so the store still gets every trajectory in index order.
        todo = [i for i in range(counts[split]) if i not in cached[split]]
        tasks = ((preset, seed, split, i, cache_file(split, i)) for i in todo)
        results = pool.imap(_task, tasks) if pool is not None else map(_task, tasks)
        for i in range(counts[split]):
            if i in cached[split]:
                traj = _load_cached(cache_file(split, i), i, preset.num_frames)
                if not isinstance(traj, Trajectory):  # it loaded a moment ago: changed under us
                    log.warning("%s: %s; simulating it again", cache_file(split, i), traj)
                    with one_thread():
                        traj = _task((preset, seed, split, i, cache_file(split, i)))
            else:
                traj = next(results)
                bar.update(1)
            bar.set_postfix(split=split, particles=traj.num_particles)
            yield traj

    try:
        if workers == 1 or missing <= 1:
            with one_thread():
                write_dataset(out, {s: split_items(None, s) for s in splits}, metadata, overwrite=overwrite)
        else:
            # spawn, not fork: a forked child inherits the parent's torch thread pool state and can deadlock.
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(min(workers, missing), initializer=_worker_init) as pool:
                write_dataset(out, {s: split_items(pool, s) for s in splits}, metadata, overwrite=overwrite)
    finally:
        bar.close()
    # Written: the cache has served its purpose (on any failure above it stays, for the rerun).
    try:
        shutil.rmtree(cache)
    except OSError as e:
        log.warning("%s: could not remove the generation cache (%s); delete it by hand", cache, e)
    return out
