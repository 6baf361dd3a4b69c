"""Render smoke tests: frame counts and sizes of animations, strips and single frames; the colour scheme."""

from __future__ import annotations

import imageio.v2
import imageio.v3 as iio
import numpy as np
import pytest

from gnsx.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.render import GREY, render_frame, render_rollouts, save_animation, save_frame, save_strip, speeds

BOUNDS = np.array([[0.1, 0.9], [0.1, 0.9]])


def _rollout(num_frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Falling water (20 particles) above a static ramp (5 particles): ``[T, 25, 2]`` and types."""
    rng = np.random.default_rng(seed)
    water = rng.uniform(0.3, 0.6, (20, 2))
    ramp = np.stack([np.linspace(0.2, 0.8, 5), np.full(5, 0.2)], 1)
    t = np.arange(num_frames)[:, None, None]
    fall = np.concatenate([water[None] - [0.0, 1e-3] * t**1.0, np.broadcast_to(ramp, (num_frames, 5, 2))], 1)
    types = np.r_[np.full(20, WATER_PARTICLE_ID), np.full(5, KINEMATIC_PARTICLE_ID)]
    return fall, types


def test_render_rollouts_frame_count_and_size():
    positions, types = _rollout(10)
    frames = render_rollouts(
        [positions, positions + 0.01], types, BOUNDS, ["truth", "model"], size=64, frame_stride=3
    )
    assert frames.shape == (4, 64, 128, 3) and frames.dtype == np.uint8  # frames 0, 3, 6, 9
    picked = render_rollouts([positions], types, BOUNDS, size=32, frames=[2, 5])
    assert picked.shape == (2, 32, 32, 3)


@pytest.mark.parametrize("suffix", ["gif", "mp4"])
def test_animation_files_hold_every_frame(tmp_path, suffix):
    positions, types = _rollout(12)
    frames = render_rollouts([positions, positions], types, BOUNDS, size=48, frame_stride=2)
    path = save_animation(frames, tmp_path / f"a.{suffix}", fps=10)
    if suffix == "gif":
        back = iio.imread(path)
        assert back.shape[:3] == (6, 48, 96)
    else:  # MP4 through imageio-ffmpeg
        reader = imageio.v2.get_reader(path)
        assert reader.count_frames() == 6
        assert reader.get_data(0).shape[:2] == (48, 96)
        reader.close()
    with pytest.raises(ValueError, match="unsupported"):
        save_animation(frames, tmp_path / "a.avi")


def test_strip_is_seven_frames_every_hundred(tmp_path):
    positions, types = _rollout(601)
    path = save_strip(
        [positions, positions], types, BOUNDS, tmp_path / "strip.png", ["truth", "model"], size=40
    )
    image = iio.imread(path)
    assert image.shape[:2] == (2 * 40, 7 * 40)  # frames 0, 100, ..., 600; one row per rollout
    short = iio.imread(save_strip([positions[:250]], types, BOUNDS, tmp_path / "s.png", every=100, size=40))
    assert short.shape[:2] == (40, 3 * 40)


def test_save_frame_png_colours_speed_and_greys_static_particles(tmp_path):
    position = np.array([[0.3, 0.5], [0.7, 0.5], [0.5, 0.2]])
    types = np.array([WATER_PARTICLE_ID, WATER_PARTICLE_ID, KINEMATIC_PARTICLE_ID])
    path = save_frame(position, types, BOUNDS, tmp_path / "f.png", speed=np.array([0.0, 1.0, 5.0]), size=100)
    image = iio.imread(path)
    assert image.shape == (100, 100, 3)
    direct = render_frame(position, types, np.array([0.0, 1.0, 5.0]), BOUNDS, 100, speed_scale=1.0)

    def pixel(p):  # the viewport maps [0, 1] to the image, y up
        return direct[99 - round(p[1] * 99), round(p[0] * 99)]

    np.testing.assert_array_equal(image, direct)
    slow, fast, ramp = (pixel(p) for p in position)
    assert fast.sum() > slow.sum()  # fast particles are brighter (towards white)
    np.testing.assert_array_equal(ramp, GREY)  # static particles grey whatever their speed
    np.testing.assert_array_equal(direct[99 - round(0.1 * 99), 50], GREY)  # the lower wall
    assert iio.imread(save_frame(position, types, BOUNDS, tmp_path / "g.png", title="x")).shape == (
        256,
        256,
        3,
    )


def test_speeds_are_per_frame_displacements():
    positions, _ = _rollout(4)
    s = speeds(positions)
    assert s.shape == (4, 25)
    np.testing.assert_allclose(s[0], 0.0)
    np.testing.assert_allclose(s[1:, :20], 1e-3, rtol=1e-6)
    np.testing.assert_allclose(s[1:, 20:], 0.0)
