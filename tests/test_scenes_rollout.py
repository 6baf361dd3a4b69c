"""New initial conditions: scene files, the first frames, rollouts with or without MPM, simulate.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import lightning
import numpy as np
import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.rollout_io import load_rollout
from gnsx.evaluation.scene_rollout import (
    check_scene,
    constant_velocity_history,
    initial_state,
    load_scene,
    rollout_scene,
    save_scene,
)
from gnsx.mpm.generate import simulate_scene
from gnsx.mpm.presets import get_preset
from gnsx.mpm.scenes import Scene, WaterBlock
from gnsx.training.system import GNSSystem

ROOT = Path(__file__).resolve().parents[1]
PRESET = get_preset("small", num_frames=10)
SCENE = Scene(
    blocks=[WaterBlock((0.2, 0.3), (0.35, 0.45), (1.0, -0.5)), WaterBlock((0.6, 0.5), (0.7, 0.6))],
    ramps=[((0.15, 0.2), (0.8, 0.15)), ((0.85, 0.3), (0.85, 0.6))],
)


def _tiny_system(history: int) -> GNSSystem:
    """An untrained tiny model on the small preset's domain and radius."""
    model = {"latent_size": 8, "mlp_hidden_size": 8, "mp_steps": 2, "history": history}
    return GNSSystem(model=model, dim=2, bounds=[[0.1, 0.9], [0.1, 0.9]], radius=0.035, vel_mean=[0.0, -1e-3],
                     vel_std=[2e-3, 2e-3], acc_mean=[0.0, 0.0], acc_std=[1e-4, 1e-4])  # fmt: skip


def test_scene_file_round_trip(tmp_path):
    path = save_scene(SCENE, tmp_path / "scene.yaml")
    back = load_scene(path)
    assert back.to_dict() == SCENE.to_dict()
    assert back.blocks[0].velocity == (1.0, -0.5) and back.ramps[1] == ((0.85, 0.3), (0.85, 0.6))


@pytest.mark.parametrize("path", sorted((ROOT / "scenes").glob("*.yaml")), ids=lambda p: p.stem)
def test_shipped_scene_files_load_and_fit_the_small_preset(path):
    scene = load_scene(path)
    check_scene(scene, get_preset("small"), str(path))
    position, velocity, types = initial_state(scene, get_preset("small"))
    assert (types == WATER_PARTICLE_ID).sum() > 50 and (types == KINEMATIC_PARTICLE_ID).sum() > 5
    assert position.shape == velocity.shape == (len(types), 2)


def test_scene_errors_name_the_file_and_field(tmp_path):
    with pytest.raises(DataError, match="not found"):
        load_scene(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("blocks:\n  - lower: [0.2, 0.2]\n    upper: [0.1, 0.5]\n")
    with pytest.raises(DataError, match=r"bad\.yaml\.blocks\[0\]: lower .* below and left"):
        load_scene(bad)
    bad.write_text("blocks: [unclosed\n")
    with pytest.raises(DataError, match="invalid YAML"):
        load_scene(bad)
    outside = Scene(blocks=[WaterBlock((0.05, 0.2), (0.3, 0.4))])
    with pytest.raises(DataError, match=r"blocks\[0\]: extends outside the walls"):
        check_scene(outside, PRESET)
    with pytest.raises(DataError, match="no water block"):
        check_scene(Scene(ramps=SCENE.ramps), PRESET)


def test_constant_velocity_history():
    position = np.array([[0.5, 0.5], [0.2, 0.3]], np.float32)
    velocity = np.array([[1.0, -2.0], [0.0, 0.0]], np.float32)
    frames = constant_velocity_history(position, velocity, dt=0.01, history=2)
    assert frames.shape == (3, 2, 2)
    np.testing.assert_allclose(frames[-1], position)  # the scene's state is the newest frame
    np.testing.assert_allclose(frames[0, 0], [0.48, 0.54], rtol=1e-6)  # p0 - 2 v dt
    np.testing.assert_allclose(frames[1, 0], [0.49, 0.52], rtol=1e-6)
    np.testing.assert_allclose(frames[:, 1], np.broadcast_to(position[1], (3, 2)))  # at rest: unmoved


def test_initial_state_is_the_mpm_initial_state():
    position, velocity, types = initial_state(SCENE, PRESET, seed=7)
    traj = simulate_scene(SCENE, get_preset("small", num_frames=3), seed=7)
    np.testing.assert_array_equal(types, traj.particle_type)
    np.testing.assert_allclose(position, traj.position[0], atol=1e-6)
    water = types == WATER_PARTICLE_ID
    assert {tuple(v) for v in velocity[water]} == {(1.0, -0.5), (0.0, 0.0)}
    np.testing.assert_array_equal(velocity[~water], 0.0)


@pytest.mark.parametrize("history", [1, 5])
def test_rollout_scene_with_and_without_ground_truth(history):
    simulator = _tiny_system(history).simulator.eval()
    alone = rollout_scene(simulator, SCENE, PRESET, num_frames=9, seed=1)
    assert alone.predicted.shape[0] == 9 and alone.ground_truth is None
    assert alone.history_source == "constant_velocity" and alone.input_frames == history + 1
    position, velocity, _ = initial_state(SCENE, PRESET, seed=1)
    np.testing.assert_allclose(alone.predicted[history], position)
    step = alone.predicted[history] - alone.predicted[history - 1]
    np.testing.assert_allclose(step, velocity * PRESET.frame_dt, atol=1e-6)
    static = alone.particle_type == KINEMATIC_PARTICLE_ID
    np.testing.assert_array_equal(alone.predicted[-1, static], position[static])  # ramps never move

    both = rollout_scene(simulator, SCENE, PRESET, num_frames=9, seed=1, ground_truth=True)
    assert both.history_source == "mpm" and both.ground_truth.shape == both.predicted.shape
    np.testing.assert_array_equal(both.predicted[: history + 1], both.ground_truth[: history + 1])
    with pytest.raises(ValueError, match="num_frames"):
        rollout_scene(simulator, SCENE, PRESET, num_frames=history + 1)


def test_simulate_entry_point_with_mpm(tmp_path):
    ckpt = tmp_path / "tiny.ckpt"
    system = _tiny_system(1)
    torch.save({"state_dict": system.state_dict(), "hyper_parameters": dict(system.hparams),
                "pytorch-lightning_version": lightning.__version__}, ckpt)  # fmt: skip
    run = tmp_path / "sim"
    inline = (
        "scene={blocks:[{lower:[0.2,0.2],upper:[0.4,0.4],velocity:[1.0,0.0]}],ramps:[[[0.5,0.3],[0.8,0.2]]]}"
    )
    cmd = [sys.executable, str(ROOT / "simulate.py"), f"checkpoint={ckpt}", inline, "num_frames=12",
           "mpm=true", "render.strip_every=5", "render.frame_stride=2", "label=tiny",
           f"hydra.run.dir={run}"]  # fmt: skip
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    errors = json.loads((run / "errors.json").read_text())
    assert errors["history_source"] == "mpm" and errors["rollout_mse"] > 0 and errors["emd"] > 0
    rollout = load_rollout(run / "rollout.npz")
    assert rollout.predicted.shape == rollout.ground_truth.shape and rollout.predicted.shape[0] == 12
    assert rollout.metadata["rollout"]["scene"]["blocks"][0]["velocity"] == [1.0, 0.0]
    assert load_scene(run / "scene.yaml").ramps == [((0.5, 0.3), (0.8, 0.2))]
    assert iio.imread(run / "comparison.gif").shape[:3] == (6, 256, 512)  # MPM | model, every 2nd frame
    assert iio.imread(run / "rollout.gif").shape[:3] == (6, 256, 256)
    assert iio.imread(run / "strip.png").shape[:2] == (2 * 192, 3 * 192)  # frames 0, 5, 10; two rows
    assert (run / "rollout.pkl").is_file()
