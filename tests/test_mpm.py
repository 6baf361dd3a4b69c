"""The MLS-MPM solver (physics and numerics) and dataset generation, on tiny scenes."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

import gnsx.mpm.generate as generate_module
from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.__main__ import main as data_main
from gnsx.data.store import SplitReader
from gnsx.mpm.generate import (
    generate_dataset,
    is_dam_scene,
    is_rest_scene,
    run_scene,
    scene_rng,
    simulate_scene,
    simulate_split_item,
    split_scene,
)
from gnsx.mpm.presets import get_preset
from gnsx.mpm.scenes import Scene, WaterBlock, sample_rest_scene, sample_scene, scene_particles
from gnsx.mpm.solver import MLSMPMSolver, SolverSettings

pytestmark = pytest.mark.usefixtures("one_thread")


def _block(lower, upper, spacing, rng, jitter=0.3):
    xs = np.arange(lower[0] + spacing / 2, upper[0], spacing)
    ys = np.arange(lower[1] + spacing / 2, upper[1], spacing)
    p = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    return p + rng.uniform(-jitter * spacing, jitter * spacing, p.shape)


def _frame_crossings(position: np.ndarray, ramps: np.ndarray) -> int:
    """How many frame-to-frame particle moves ``[T, N, 2]`` cross one of the segments ``[R, 2, 2]``."""
    count = 0
    a, b = position[:-1].astype(np.float64), position[1:].astype(np.float64)
    for p0, p1 in ramps:
        d = p1 - p0
        normal = np.array([-d[1], d[0]])
        side_a, side_b = (a - p0) @ normal, (b - p0) @ normal
        crossed = (side_a >= 0) != (side_b >= 0)
        frac = side_a / np.where(crossed, side_a - side_b, 1.0)
        t = ((a + frac[..., None] * (b - a) - p0) @ d) / (d @ d)
        count += int((crossed & (t >= 0) & (t <= 1)).sum())
    return count


# ---------------------------------------------------------------------------------------------- numerics


def _reference_substep(x, v, C, J, spacing, s: SolverSettings):
    """Taichi's mpm88 substep, particle by particle in float64 (walls only): the ground truth."""
    dx, dt, g = s.dx, s.dt, s.grid_nodes
    inv_dx, vol = 1.0 / dx, spacing**2
    mass = vol * s.density
    grid_m, grid_v = np.zeros((g, g)), np.zeros((g, g, 2))
    for p in range(len(x)):
        xp = (x[p] - s.grid_origin) * inv_dx
        base = np.floor(xp - 0.5).astype(int)
        fx = xp - base
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
        stress = -dt * 4 * s.stiffness * vol * (J[p] - 1) * inv_dx**2
        affine = stress * np.eye(2) + mass * C[p]
        for i in range(3):
            for j in range(3):
                dpos = (np.array([i, j]) - fx) * dx
                weight = w[i][0] * w[j][1]
                grid_v[base[0] + i, base[1] + j] += weight * (mass * v[p] + affine @ dpos)
                grid_m[base[0] + i, base[1] + j] += weight * mass
    node = s.node_positions()
    for i in range(g):
        for j in range(g):
            if grid_m[i, j] > 0:
                grid_v[i, j] /= grid_m[i, j]
                grid_v[i, j, 1] -= dt * s.gravity
                for axis, coord in ((0, node[i]), (1, node[j])):
                    if coord <= s.wall_lo + 1e-9 and grid_v[i, j, axis] < 0:
                        grid_v[i, j, axis] = 0
                    if coord >= s.wall_hi - 1e-9 and grid_v[i, j, axis] > 0:
                        grid_v[i, j, axis] = 0
    x, v, C, J = x.copy(), v.copy(), C.copy(), J.copy()
    for p in range(len(x)):
        xp = (x[p] - s.grid_origin) * inv_dx
        base = np.floor(xp - 0.5).astype(int)
        fx = xp - base
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
        new_v, new_C = np.zeros(2), np.zeros((2, 2))
        for i in range(3):
            for j in range(3):
                dpos = (np.array([i, j]) - fx) * dx
                weight = w[i][0] * w[j][1]
                new_v += weight * grid_v[base[0] + i, base[1] + j]
                new_C += 4 * inv_dx**2 * weight * np.outer(grid_v[base[0] + i, base[1] + j], dpos)
        v[p], C[p] = new_v, new_C
        x[p] += dt * new_v
        J[p] *= 1 + dt * np.trace(new_C)
    return x, v, C, J


def test_substep_matches_particle_by_particle_mpm88():
    """The matmul/index_add transfers equal mpm88's loops, including a particle at each wall."""
    rng = np.random.default_rng(0)
    s = SolverSettings(grid=16, substeps=5, dtype="float64")
    spacing = 0.5 * s.dx
    x = np.concatenate([rng.uniform(0.3, 0.7, (40, 2)), [[0.1, 0.5], [0.9, 0.3], [0.4, 0.1], [0.6, 0.9]]])
    v = rng.normal(0, 1.0, x.shape)
    v[-4:] = [[-1, 0], [1, 0], [0, -1], [0, 1]]  # the wall particles push outwards
    C = rng.normal(0, 5.0, (len(x), 2, 2))
    J = rng.uniform(0.95, 1.05, len(x))
    solver = MLSMPMSolver(x, v, np.zeros((0, 2, 2)), spacing, s, affine=C, volume_ratio=J)
    solver.substep()
    ref_x, ref_v, ref_C, ref_J = _reference_substep(x, v, C, J, spacing, s)
    np.testing.assert_allclose(solver.v.numpy(), ref_v, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(solver.C.numpy(), ref_C, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(solver.J.numpy(), ref_J, rtol=1e-12)
    np.testing.assert_allclose(solver.x.numpy(), np.clip(ref_x, 0.1, 0.9), rtol=0, atol=1e-13)


def test_transfers_conserve_linear_momentum_without_gravity_or_walls():
    rng = np.random.default_rng(1)
    s = SolverSettings(grid=32, gravity=0.0, dtype="float64")
    x = rng.uniform(0.35, 0.65, (300, 2))
    v = rng.normal(0, 0.5, x.shape)
    solver = MLSMPMSolver(x, v, np.zeros((0, 2, 2)), 0.01, s, volume_ratio=rng.uniform(0.97, 1.03, 300))
    before = solver.v.sum(0).clone()
    for _ in range(20):
        solver.substep()
    # Pressure and APIC redistribute momentum between particles but do not create any.
    np.testing.assert_allclose(solver.v.sum(0).numpy(), before.numpy(), atol=1e-10)
    assert not torch.allclose(solver.v, torch.as_tensor(v))  # particles did interact


def test_free_fall_recovers_gravity():
    rng = np.random.default_rng(2)
    s = SolverSettings(grid=32, substeps=10)
    spacing = 0.5 * s.dx
    x = _block((0.35, 0.6), (0.6, 0.8), spacing, rng)
    solver = MLSMPMSolver(x, np.zeros_like(x), np.zeros((0, 2, 2)), spacing, s)
    frames = 40  # 0.1 s: falls ~5 cm, far from the floor
    position = solver.run(frames)
    t = np.arange(frames) * s.frame_dt
    curvature = np.polyfit(t, position[:, :, 1].astype(np.float64).mean(1), 2)[0]
    assert -2 * curvature == pytest.approx(9.8, rel=0.02)
    # Uniform free fall neither compresses nor stretches the water, nor moves it sideways.
    assert np.abs(solver.J.numpy() - 1).max() < 1e-3
    assert np.abs(position[-1, :, 0] - position[0, :, 0]).max() < 1e-4


def test_grid_fits_the_walls():
    for grid in (16, 32, 64):
        s = SolverSettings(grid=grid)
        nodes = s.node_positions()
        assert np.isclose(nodes, s.wall_lo).any() and np.isclose(nodes, s.wall_hi).any()
        assert abs(s.dx - 1 / grid) < 0.05 / grid


# ---------------------------------------------------------------------------------------------- boundaries


#: Water thrown at ramps: from above (a tilted ramp, a steep one crossed by a vertical one), and from below
#: and the right (a horizontal ramp above the water, a vertical ramp to its left), so both sides are tested.
SPLASHES = {
    "from_above": dict(
        lower=(0.3, 0.6),
        upper=(0.7, 0.85),
        velocity=(0.5, -3.0),
        ramps=[[[0.15, 0.45], [0.6, 0.38]], [[0.55, 0.35], [0.85, 0.15]], [[0.65, 0.12], [0.65, 0.45]]],
        frames=160,
    ),
    "from_below_and_side": dict(
        lower=(0.3, 0.15),
        upper=(0.6, 0.35),
        velocity=(-2.0, 3.0),
        ramps=[[[0.2, 0.5], [0.7, 0.5]], [[0.25, 0.12], [0.25, 0.45]]],
        frames=100,
    ),
}


def _splash(name: str, seed: int = 3):
    """The solver (32^2 grid) for one of SPLASHES, its ramps and its number of frames."""
    case = SPLASHES[name]
    rng = np.random.default_rng(seed)
    s = SolverSettings(grid=32)
    spacing = 0.5 * s.dx
    x = _block(case["lower"], case["upper"], spacing, rng)
    v = np.tile([case["velocity"]], (len(x), 1))
    ramps = np.array(case["ramps"])
    return MLSMPMSolver(x, v, ramps, spacing, s), ramps, case["frames"]


def _near_segment(position: np.ndarray, p0: np.ndarray, p1: np.ndarray, distance: float) -> int:
    """How many ``[N, 2]`` positions lie within ``distance`` of the segment, over its length."""
    d = p1 - p0
    t = (position - p0) @ d / (d @ d)
    off = np.abs((position - p0) @ np.array([-d[1], d[0]])) / np.linalg.norm(d)
    return int(((t > 0) & (t < 1) & (off < distance)).sum())


def _run_recording_J(solver: MLSMPMSolver, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``[frames, N, 2]`` and volume ratios ``[frames, N]``, frame 0 the current state."""
    position, volume_ratio = [solver.x.numpy().copy()], [solver.J.numpy().copy()]
    for _ in range(frames - 1):
        solver.step_frame()
        position.append(solver.x.numpy().copy())
        volume_ratio.append(solver.J.numpy().copy())
    return np.stack(position), np.stack(volume_ratio)


def test_dam_break_keeps_the_water_nearly_incompressible():
    """A block collapsing from rest across the floor to the far wall: J within 10 % of rest all along."""
    rng = np.random.default_rng(5)
    s = SolverSettings(grid=32)
    spacing = 0.5 * s.dx
    x = _block((0.1, 0.1), (0.35, 0.35), spacing, rng)
    position, volume_ratio = _run_recording_J(MLSMPMSolver(x, np.zeros_like(x), [], spacing, s), 120)
    assert position[-1, :, 0].max() > 0.8  # the front reached the far side
    assert 0.9 <= volume_ratio.min() and volume_ratio.max() <= 1.1


@pytest.mark.parametrize("name", SPLASHES)
def test_water_stays_in_the_box_and_on_its_side_of_every_ramp(name):
    solver, ramps, frames = _splash(name)
    position, volume_ratio = _run_recording_J(solver, frames)
    assert position.min() >= 0.1 and position.max() <= 0.9
    assert _frame_crossings(position, ramps) == 0
    # The test means something only if the water pressed on every ramp at some point.
    for p0, p1 in ramps:
        assert max(_near_segment(position[f], p0, p1, 0.05) for f in range(0, frames, 10)) > 10
    # Impacts at 3-4 m/s (sound speed 20 m/s) and water squeezed through a ramp-wall gap compress a few
    # particles transiently; the rest stays within 10 % of rest volume, and nothing blows up.
    assert ((volume_ratio > 0.9) & (volume_ratio < 1.1)).mean() > 0.98
    assert 0.5 < volume_ratio.min() and volume_ratio.max() < 1.5


@pytest.mark.parametrize("name", SPLASHES)
def test_grid_colliders_alone_keep_water_out_of_ramps(name, monkeypatch):
    """Without the particle safety net, the mass-sided grid colliders must already stop every particle."""
    monkeypatch.setattr(MLSMPMSolver, "_stop_ramp_crossings", lambda self, x0, x1, v, d0, d1: (x1, v, d1))
    solver, ramps, frames = _splash(name)
    assert _frame_crossings(solver.run(frames), ramps) == 0


def test_wall_overshoot_is_only_round_off(monkeypatch):
    """The grid's wall nodes stop the water; the position clamp only fixes slivers (< 1 % of a cell)."""
    worst = []
    original = MLSMPMSolver._clamp_to_walls

    def record(self, x):
        worst.append(float(torch.maximum(self.settings.wall_lo - x, x - self.settings.wall_hi).max()))
        return original(self, x)

    monkeypatch.setattr(MLSMPMSolver, "_clamp_to_walls", record)
    solver, _, frames = _splash("from_above")
    solver.run(frames)
    assert max(worst) < 0.01 * solver.settings.dx


def test_safety_net_puts_a_crossing_particle_back():
    # No collider nodes at all (band 0): only the particle safety net can stop the particle.
    s = SolverSettings(grid=32, substeps=1, gravity=0.0, collider_band=0.0)
    ramps = np.array([[[0.3, 0.5], [0.7, 0.5]]])
    # 1 cm above the ramp, moving down at 8 m/s: one 2.5 ms step would end 1 cm below it.
    solver = MLSMPMSolver([[0.5, 0.51]], [[0.0, -8.0]], ramps, 0.01, s)
    solver.substep()
    assert solver.ramp_corrections == 1
    assert 0.5 < float(solver.x[0, 1]) < 0.5 + 0.1 * s.dx and abs(float(solver.v[0, 1])) < 1e-6
    # Past the end of the segment nothing stops it.
    solver = MLSMPMSolver([[0.75, 0.51]], [[0.0, -8.0]], ramps, 0.01, s)
    solver.substep()
    assert solver.ramp_corrections == 0 and float(solver.x[0, 1]) < 0.495


def test_bad_inputs_are_refused():
    s = SolverSettings(grid=16)
    with pytest.raises(ValueError, match="inside"):
        MLSMPMSolver([[0.05, 0.5]], [[0.0, 0.0]], np.zeros((0, 2, 2)), 0.01, s)
    with pytest.raises(ValueError, match="zero length"):
        MLSMPMSolver([[0.5, 0.5]], [[0.0, 0.0]], [[[0.2, 0.2], [0.2, 0.2]]], 0.01, s)
    with pytest.raises(ValueError, match="dtype"):
        SolverSettings(dtype="float16")


# ---------------------------------------------------------------------------------------------- trajectories


def _tiny_preset(**changes):
    base = dict(num_frames=30, trajectories={"train": 2, "valid": 1, "test": 1})
    return get_preset("small", **(base | changes))


def test_simulate_scene_layout_and_determinism():
    preset = _tiny_preset()
    scene = Scene([WaterBlock((0.2, 0.5), (0.45, 0.75), (1.0, -0.5))], [((0.15, 0.35), (0.6, 0.3))])
    traj = simulate_scene(scene, preset, seed=7)
    n_water = int((traj.particle_type == WATER_PARTICLE_ID).sum())
    assert traj.position.shape == (30, traj.num_particles, 2) and traj.position.dtype == np.float32
    assert traj.particle_type.dtype == np.int64
    assert set(np.unique(traj.particle_type)) == {WATER_PARTICLE_ID, KINEMATIC_PARTICLE_ID}
    # Frame 0 is exactly the scene's particles; ramp particles never move; water does.
    first, types = scene_particles(
        scene, preset.particle_spacing, np.random.default_rng(7), clearance=preset.ramp_clearance
    )
    np.testing.assert_array_equal(traj.position[0], first)
    np.testing.assert_array_equal(traj.particle_type, types)
    ramp = traj.particle_type == KINEMATIC_PARTICLE_ID
    assert (traj.position[:, ramp] == traj.position[0, ramp]).all()
    assert np.abs(traj.position[-1, :n_water] - traj.position[0, :n_water]).max() > 0.01
    # Same seed, same data; another seed, other particles.
    np.testing.assert_array_equal(simulate_scene(scene, preset, seed=7).position, traj.position)
    assert not np.array_equal(simulate_scene(scene, preset, seed=8).position[0], traj.position[0])


def test_run_scene_reports_solver_and_rejects_blocks_outside_the_walls():
    preset = _tiny_preset(num_frames=5)
    scene = Scene([WaterBlock((0.3, 0.3), (0.5, 0.5))], [])
    traj, solver = run_scene(scene, preset, seed=0)
    assert solver.num_particles == traj.num_particles
    with pytest.raises(DataError, match=r"scene.blocks\[0\]"):
        run_scene(Scene([WaterBlock((0.05, 0.3), (0.5, 0.5))], []), preset, seed=0)


def test_split_items_depend_only_on_seed_split_and_index():
    preset = _tiny_preset(num_frames=4)
    a = simulate_split_item(preset, 5, "train", 1)
    assert a.key == 1
    np.testing.assert_array_equal(a.position, simulate_split_item(preset, 5, "train", 1).position)
    assert a.num_particles != simulate_split_item(preset, 5, "valid", 1).num_particles or not np.array_equal(
        a.position[0], simulate_split_item(preset, 5, "valid", 1).position[0]
    )


def test_rest_fraction_makes_some_training_scenes_pools_and_changes_nothing_else():
    plain, rest = get_preset("small"), get_preset("small", rest_fraction=0.3)
    pools = [i for i in range(100) if is_rest_scene(rest, 0, "train", i)]
    assert 15 <= len(pools) <= 45
    assert not any(is_rest_scene(plain, 0, "train", i) for i in range(100))
    assert not any(is_rest_scene(get_preset("small", rest_fraction=1.0), 0, s, 0) for s in ("valid", "test"))
    for i in range(100):  # every other scene, and the draw of its particles, is the one rest_fraction 0 makes
        a, b = scene_rng(0, "train", i), scene_rng(0, "train", i)
        if i in pools:
            assert sample_rest_scene(a, rest).blocks[0].velocity == (0.0, 0.0)
        else:
            assert sample_scene(a, rest) == sample_scene(b, plain)
            assert a.integers(2**63) == b.integers(2**63)


def test_dam_fraction_keeps_every_pool_and_changes_only_the_scenes_it_makes_dams():
    pools_only = get_preset("small", rest_fraction=0.2)
    both = get_preset("small", rest_fraction=0.2, dam_fraction=0.1)
    dams = [i for i in range(200) if is_dam_scene(both, 0, "train", i)]
    assert 8 <= len(dams) <= 35
    assert not any(is_dam_scene(pools_only, 0, "train", i) for i in range(200))
    assert not any(is_dam_scene(get_preset("small", dam_fraction=1.0), 0, s, 0) for s in ("valid", "test"))
    for i in range(200):
        assert is_rest_scene(both, 0, "train", i) == is_rest_scene(pools_only, 0, "train", i)
        assert not (is_rest_scene(both, 0, "train", i) and i in dams)
        scene, placement = split_scene(both, 0, "train", i)
        if i in dams:
            (block,) = scene.blocks
            assert block.velocity == (0.0, 0.0) and block.lower[1] == both.bounds[0]
        else:
            assert (scene, placement) == split_scene(pools_only, 0, "train", i)


def test_generate_dataset_writes_a_readable_dataset_independent_of_workers(tmp_path):
    # 30 frames: in 12 a block in free flight may not accelerate sideways at all (acc_std 0 is refused).
    preset = _tiny_preset(num_frames=30)
    one = generate_dataset(tmp_path / "one", preset, seed=3, workers=1, progress=False)
    two = generate_dataset(tmp_path / "two", preset, seed=3, workers=2, progress=False)
    meta = json.loads((one / "metadata.json").read_text())
    assert meta["bounds"] == [[0.1, 0.9], [0.1, 0.9]]
    assert meta["sequence_length"] == 29 and meta["dim"] == 2 and meta["dt"] == 0.0025
    assert meta["default_connectivity_radius"] == preset.default_connectivity_radius
    assert all(len(meta[k]) == 2 and min(meta[k]) > 0 for k in ("vel_std", "acc_std"))
    assert meta["gnsx"]["preset"] == "small" and meta["gnsx"]["seed"] == 3
    assert meta["gnsx"]["solver"]["grid"] == 32 and meta["gnsx"]["solver"]["substeps"] == 13
    assert meta["gnsx"]["solver"]["stiffness"] == 2500 and meta["gnsx"]["solver"]["viscosity"] > 0
    for split, count in preset.trajectories.items():
        a, b = SplitReader(one, split), SplitReader(two, split)
        assert len(a) == len(b) == count
        for i in range(count):
            assert a[i].key == i and a[i].num_frames == 30
            np.testing.assert_array_equal(a[i].position, b[i].position)
            np.testing.assert_array_equal(a[i].particle_type, b[i].particle_type)
    assert json.loads((two / "metadata.json").read_text())["vel_std"] == meta["vel_std"]


def test_generate_dataset_refuses_to_overwrite(tmp_path):
    preset = _tiny_preset(num_frames=4, trajectories={"train": 1, "valid": 0, "test": 0})
    out = generate_dataset(tmp_path / "d", preset, workers=1, progress=False, splits=["train"])
    with pytest.raises(DataError, match="already exists"):
        generate_dataset(out, preset, workers=1, progress=False, splits=["train"])
    again = dataclasses.replace(preset, num_frames=5)
    generate_dataset(out, again, workers=1, progress=False, splits=["train"], overwrite=True)
    assert SplitReader(out, "train")[0].num_frames == 5
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("keep me")
    with pytest.raises(DataError, match="not a gnsx dataset"):
        generate_dataset(tmp_path / "other", preset, workers=1, progress=False, overwrite=True)
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(DataError, match="exists and is not a folder"):
        generate_dataset(tmp_path / "file", preset, workers=1, progress=False)
    assert not (tmp_path / "other.partial").exists() and not (tmp_path / "file.partial").exists()


# ------------------------------------------------------------------------------------- resumable generation


class _Killed(Exception):
    """Stands for the kill (SIGKILL, Ctrl-C) that stops a generation part way."""


def _count_simulations(monkeypatch, fail_after: int | None = None) -> list[tuple[str, int]]:
    """The ``(split, index)`` of every trajectory simulated from now on (workers=1 simulates in this
    process); with ``fail_after``, the simulation after that many raises :class:`_Killed`."""
    calls = []

    def counting(preset, seed, split, index):
        if fail_after is not None and len(calls) >= fail_after:
            raise _Killed
        calls.append((split, index))
        return simulate_split_item(preset, seed, split, index)

    monkeypatch.setattr(generate_module, "simulate_split_item", counting)
    return calls


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_killed_generation_resumes_from_its_cache(tmp_path, monkeypatch, caplog):
    preset = _tiny_preset()  # train 2, valid 1, test 1; 30 frames
    out, cache = tmp_path / "d", tmp_path / "d.partial"
    calls = _count_simulations(monkeypatch, fail_after=3)
    with pytest.raises(_Killed):
        generate_dataset(out, preset, seed=3, workers=1, progress=False)
    assert calls == [("train", 0), ("train", 1), ("valid", 0)]
    assert not out.exists()  # only the final swap creates it
    cached = sorted(p.relative_to(cache).as_posix() for p in cache.rglob("*") if p.is_file())
    assert cached == ["generation.json", "train/000000.npz", "train/000001.npz", "valid/000000.npz"]
    record = json.loads((cache / "generation.json").read_text())
    assert record["seed"] == 3 and record["preset_settings"] == json.loads(json.dumps(preset.to_dict()))

    calls = _count_simulations(monkeypatch)
    with caplog.at_level(logging.INFO, logger="gnsx"):
        generate_dataset(out, preset, seed=3, workers=1, progress=False)
    assert calls == [("test", 0)]  # only the missing one
    assert "resuming, 3 of 4 trajectories already simulated" in caplog.text
    assert not cache.exists()
    # Byte for byte what an uninterrupted generation writes (arrays and metadata).
    reference = generate_dataset(tmp_path / "ref", preset, seed=3, workers=1, progress=False)
    assert len(calls) == 5 and _files(out) == _files(reference)


def test_a_cache_of_other_settings_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    preset = get_preset("small", trajectories={"train": 1, "valid": 0, "test": 0})
    out, cache = tmp_path / "d", tmp_path / "d.partial"
    _count_simulations(monkeypatch, fail_after=0)  # any simulation raises _Killed: refusals come first
    with pytest.raises(_Killed):
        generate_dataset(out, preset, seed=0, workers=1, progress=False, splits=["train"])
    record = (cache / "generation.json").read_text()
    for overwrite in (False, True):
        with pytest.raises(DataError) as refused:
            generate_dataset(out, preset, seed=1, workers=1, progress=False, overwrite=overwrite)
        message = str(refused.value)
        assert message.startswith(
            f"{cache}: cache of an unfinished generation with other settings: seed 0 (now 1)"
        )
        assert message.endswith(f"delete {cache} to start over")
    with pytest.raises(DataError, match=r"preset num_frames 250 \(now 5\)"):
        generate_dataset(out, dataclasses.replace(preset, num_frames=5), seed=0, workers=1, progress=False)
    # The CLI: one line, exit status 2.
    argv = ["generate", "--preset", "small", "--out", str(out), "--seed", "2", "--train", "1", "--valid", "0"]
    assert data_main([*argv, "--test", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {cache}: ") and "seed 0 (now 2)" in err and err.count("\n") == 1
    assert (cache / "generation.json").read_text() == record  # never deleted or rewritten
    # A record written before dam_fraction existed was generated without dams: accepted as the same settings.
    older = json.loads(record)
    del older["preset_settings"]["dam_fraction"]
    (cache / "generation.json").write_text(json.dumps(older))
    with pytest.raises(_Killed):
        generate_dataset(out, preset, seed=0, workers=1, progress=False)
    with pytest.raises(DataError, match=r"preset dam_fraction 0.0 \(now 0.5\)"):
        dams = dataclasses.replace(preset, dam_fraction=0.5)
        generate_dataset(out, dams, seed=0, workers=1, progress=False)
    (cache / "generation.json").write_text(record)
    # Other trajectory counts are the same generation (trajectory i does not depend on them): accepted.
    with pytest.raises(_Killed):
        generate_dataset(out, dataclasses.replace(preset, trajectories={"train": 3}), seed=0, workers=1)


def test_a_truncated_cached_file_is_simulated_again(tmp_path, monkeypatch, caplog):
    preset = _tiny_preset(trajectories={"train": 2, "valid": 0, "test": 0})
    out, cache = tmp_path / "d", tmp_path / "d.partial"
    _count_simulations(monkeypatch, fail_after=1)
    with pytest.raises(_Killed):
        generate_dataset(out, preset, seed=3, workers=1, progress=False, splits=["train"])
    first = cache / "train" / "000000.npz"
    with np.load(first) as z:
        expected = z["position"]
    first.write_bytes(first.read_bytes()[: first.stat().st_size // 2])
    (cache / "train" / ".000001.npz.x1y2.tmp").write_bytes(b"PK\x03\x04")  # a write the kill cut short

    calls = _count_simulations(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="gnsx"):
        generate_dataset(out, preset, seed=3, workers=1, progress=False, splits=["train"])
    assert calls == [("train", 0), ("train", 1)]
    assert f"{first}: unreadable" in caplog.text and "simulated again" in caplog.text
    np.testing.assert_array_equal(SplitReader(out, "train")[0].position, expected)
    assert not cache.exists()
