"""Simulate scenes into trajectories, and whole WaterRamps-like datasets into gnsx's on-disk format.

Every trajectory's randomness (its scene and its particle placement) comes from ``(seed, split, index)``
alone, so a dataset does not depend on the number of worker processes or the order they finish in. Each
worker runs torch on one thread: at a few thousand particles one MPM process per core beats one process
on all cores, and a fixed thread count keeps float results identical between runs.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from gnsx.constants import KINEMATIC_PARTICLE_ID, SPLITS, WATER_PARTICLE_ID
from gnsx.data.store import write_dataset
from gnsx.data.trajectory import Trajectory
from gnsx.errors import DataError
from gnsx.mpm.presets import Preset, get_preset
from gnsx.mpm.scenes import Scene, ramp_particles, sample_scene, water_particles
from gnsx.mpm.solver import MLSMPMSolver


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
    scene: Scene, preset: Preset, seed: int = 0, device: str | torch.device = "cpu"
) -> tuple[MLSMPMSolver, np.ndarray, np.ndarray]:
    """The preset's solver holding the scene's water at frame 0 (the scene is checked first).

    Returns:
        The solver, and the scene's ``position [N, 2]`` float32 and ``particle_type [N]`` of
        :func:`initial_state` (water first, then the ramps the solver holds as segments).
    """
    check_scene(scene, preset)
    initial_position, velocity, particle_type = initial_state(scene, preset, seed)
    water = particle_type == WATER_PARTICLE_ID
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
    scene: Scene, preset: Preset, seed: int, device: str | torch.device = "cpu"
) -> tuple[Trajectory, MLSMPMSolver]:
    """Simulate ``scene`` with ``preset``'s solver and return the trajectory and the finished solver.

    The solver is returned for its diagnostics (``J``, ``ramp_corrections``, ``wall_clamps``).
    See :func:`simulate_scene` for the arguments and the trajectory layout.
    """
    solver, initial_position, particle_type = scene_solver(scene, preset, seed, device)
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


def simulate_split_item(preset: Preset, seed: int, split: str, index: int) -> Trajectory:
    """Trajectory ``index`` of ``split`` in the dataset generated with ``seed`` (key = ``index``)."""
    rng = scene_rng(seed, split, index)
    scene = sample_scene(rng, preset)
    traj = simulate_scene(scene, preset, seed=int(rng.integers(2**63)))
    traj.key = index
    return traj


def _worker_init() -> None:
    torch.set_num_threads(1)


def _task(args: tuple[Preset, int, str, int]) -> Trajectory:
    return simulate_split_item(*args)


@contextmanager
def _one_thread() -> Iterator[None]:
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
    """Simulate every trajectory of ``preset`` and write the dataset to ``out``.

    Trajectory ``i`` of split ``s`` is :func:`simulate_split_item` ``(preset, seed, s, i)``; ``workers``
    processes simulate them in parallel and the store writes them in index order, one at a time. The metadata
    holds DeepMind's keys (bounds, ``sequence_length = num_frames - 1``, the preset's connectivity radius,
    dim 2, dt), statistics computed by the store from the train split, and under ``"gnsx"`` the generation
    facts (preset, seed, solver settings).

    Args:
        out: the dataset folder to create.
        preset: a :class:`Preset` or a preset name.
        seed: dataset seed (non-negative).
        workers: simulation processes; 1 simulates in this process.
        overwrite: replace an existing dataset at ``out``.
        progress: show a tqdm progress bar.
        splits: the splits to generate (default: every split of the preset); must include ``train`` unless
            statistics come from elsewhere.

    Returns:
        ``out`` as a :class:`Path`.

    Raises:
        DataError: ``out`` already holds a dataset (without ``overwrite``) or is a non-empty folder that is
            not a dataset; anything the store rejects.
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
    if (out / "metadata.json").exists() and not overwrite:
        raise DataError(
            str(out), "a dataset already exists here; pass overwrite=True (--overwrite) to replace it"
        )
    if out.is_dir() and any(out.iterdir()) and not (out / "metadata.json").exists():
        raise DataError(
            str(out), "folder exists, is not empty and is not a gnsx dataset; choose another path"
        )

    settings = preset.solver_settings()
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
            "solver": settings.to_dict() | {"dx": settings.dx, "cells": settings.cells},
        },
    }
    counts = {split: int(preset.trajectories.get(split, 0)) for split in splits}
    bar = tqdm(
        total=sum(counts.values()), desc=f"simulating {preset.name}", unit="traj", disable=not progress
    )

    def split_items(pool, split: str) -> Iterator[Trajectory]:
        # Started only when the store asks for this split; imap yields in index order.
        tasks = ((preset, seed, split, i) for i in range(counts[split]))
        results = pool.imap(_task, tasks) if pool is not None else map(_task, tasks)
        for traj in results:
            bar.set_postfix(split=split, particles=traj.num_particles)
            bar.update(1)
            yield traj

    try:
        if workers == 1:
            with _one_thread():
                write_dataset(out, {s: split_items(None, s) for s in splits}, metadata, overwrite=overwrite)
        else:
            # spawn, not fork: a forked child inherits the parent's torch thread pool state and can deadlock.
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(workers, initializer=_worker_init) as pool:
                write_dataset(out, {s: split_items(pool, s) for s in splits}, metadata, overwrite=overwrite)
    finally:
        bar.close()
    return out
