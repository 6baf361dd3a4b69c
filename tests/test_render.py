"""Render tests: frame counts and sizes of animations, strips and single frames; the colour scheme; particle
discs sized from the particle spacing (a lattice of water is painted solid)."""

from __future__ import annotations

import imageio.v2
import imageio.v3 as iio
import numpy as np
import pytest

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.evaluation.render import (
    BACKGROUND,
    GREY,
    colour_scale,
    disc_radii,
    particle_spacing,
    render_frame,
    render_rollouts,
    save_animation,
    save_frame,
    save_strip,
    speeds,
)

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


def _lattice(spacing: float, nx: int = 15, ny: int = 10, jitter: float = 0.0) -> np.ndarray:
    """``[nx * ny, 2]`` water particles on a square lattice from (0.3, 0.3), optionally jittered."""
    grid = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), -1).reshape(-1, 2)
    offsets = np.random.default_rng(0).uniform(-jitter, jitter, grid.shape) * spacing
    return 0.3 + (grid + offsets) * spacing


def _background_share(image: np.ndarray, position: np.ndarray, size: int) -> float:
    """The share of (near-)background pixels in the bounding box of the particle centres."""
    (c0, y0), (c1, y1) = np.round(np.array([position.min(0), position.max(0)]) * (size - 1)).astype(int)
    box = image[size - 1 - y1 : size - y0, c0 : c1 + 1].astype(int)
    return float((np.abs(box - BACKGROUND).sum(-1) < 60).mean())


def _painted(image: np.ndarray, blank: np.ndarray = BACKGROUND) -> int:
    """The number of pixels that differ from ``blank``."""
    return int((image != blank).any(-1).sum())


@pytest.mark.parametrize("spacing", [0.009, 0.0156, 0.025])
def test_lattice_of_water_is_painted_solid(spacing):
    position = _lattice(spacing)
    types = np.full(len(position), WATER_PARTICLE_ID)
    speed = np.zeros(len(position))
    image = render_frame(position, types, speed, BOUNDS)  # discs sized from the data
    assert _background_share(image, position, 256) < 0.1
    dots = render_frame(position, types, speed, BOUNDS, dot_px=1)  # the override: 1-pixel discs
    assert _background_share(dots, position, 256) > 0.3


def test_jittered_lattice_spacing_and_radius():
    """The spacing is the lattice's even when jittered, and the radius scales with it and with the size."""
    s = 0.0156
    for jitter in (0.0, 0.35):
        dynamic, static = particle_spacing(_lattice(s, jitter=jitter), np.full(150, WATER_PARTICLE_ID))
        assert dynamic == pytest.approx(s, rel=0.06) and static is None
    ramp = np.stack([np.linspace(0.2, 0.8, 61), np.full(61, 0.2)], 1)  # 0.01 apart
    position = np.concatenate([_lattice(s), ramp])
    types = np.r_[np.full(150, WATER_PARTICLE_ID), np.full(61, KINEMATIC_PARTICLE_ID)]
    dynamic, static = particle_spacing(position, types)
    assert static == pytest.approx(0.01, rel=1e-6)
    water, ramps = disc_radii((dynamic, static), BOUNDS, 256)
    assert water > 0.5 * s * 255  # neighbours' discs overlap
    assert 1 <= ramps < water  # ramps are thinner lines
    assert disc_radii((1.5 * dynamic, static), BOUNDS, 256)[0] == pytest.approx(1.5 * water)
    assert disc_radii((dynamic, static), BOUNDS, 512)[0] == pytest.approx(water * 511 / 255)
    assert disc_radii((1.0, None), BOUNDS, 256)[0] == pytest.approx(256 / 40)  # capped: sparse stay dots
    assert disc_radii((None, None), BOUNDS, 256) == (1.0, 1.0)


def test_dot_px_override_sets_the_disc_size():
    position = np.array([[0.5, 0.5]])
    types = np.array([WATER_PARTICLE_ID])

    empty = render_frame(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), BOUNDS, 100)  # the walls alone

    def painted(**kwargs):
        image = render_frame(position, types, np.zeros(1), BOUNDS, 100, supersample=1, **kwargs)
        return _painted(image, empty)

    assert painted(dot_px=3) == 29  # pixels within 3 of the centre
    assert painted(dot_px=6) == 113
    assert painted() == 5  # one particle: no spacing, the 1-pixel fallback
    positions, types = _rollout(3)
    small, large = (
        _painted(render_rollouts([positions], types, BOUNDS, size=64, dot_px=dot_px)[:, 20:])
        for dot_px in (1, 4)
    )
    assert large > 3 * small


def test_disc_size_is_fixed_per_rollout_from_its_first_frame(tmp_path):
    """A pool that compresses later keeps the discs of the first frame in animations and strips."""
    first = _lattice(0.02)
    positions = np.stack([first, 0.3 + (first - 0.3) * 0.5])  # frame 1: half the spacing
    types = np.full(len(first), WATER_PARTICLE_ID)
    radius = disc_radii(particle_spacing(first, types), BOUNDS, 256)
    speed, scale = speeds(positions), colour_scale(speeds(positions), types)
    frame = render_rollouts([positions], types, BOUNDS, frames=[1])[0]
    alone = render_frame(positions[1], types, speed[1], BOUNDS, 256, scale, *radius)
    np.testing.assert_array_equal(frame[20:], alone[20:])  # below the title
    own = render_frame(positions[1], types, speed[1], BOUNDS, 256, scale)
    assert _painted(own) < _painted(alone)  # frame 1's own spacing would draw smaller discs
    strip = iio.imread(save_strip([positions], types, BOUNDS, tmp_path / "s.png", every=1, count=2, size=256))
    np.testing.assert_array_equal(strip[20:, 256:], alone[20:])


def test_fast_particles_and_ramps_are_drawn_on_top():
    # A slow and a fast water particle 3 pixels apart (discs of 4), and a ramp particle 3 pixels to the left.
    types = np.array([WATER_PARTICLE_ID, WATER_PARTICLE_ID, KINEMATIC_PARTICLE_ID])
    # Size 101: 100 pixels per unit, so 0.5 -> pixel 50, 0.53 -> 53, 0.47 -> 47.
    position = np.array([[0.5, 0.5], [0.53, 0.5], [0.47, 0.5]])
    speed = np.array([0.0, 1.0, 0.0])
    image = render_frame(position, types, speed, BOUNDS, 101, 1.0, dot_px=4, static_dot_px=1)
    fast = render_frame(position[1:2], types[1:2], np.ones(1), BOUNDS, 101, 1.0, dot_px=4)
    np.testing.assert_array_equal(image[50, 50:56], fast[50, 50:56])  # the fast disc covers the slow one
    np.testing.assert_array_equal(image[50, 47], GREY)  # the ramp covers the slow disc
    assert image[50, 53].sum() > image[50, 48].sum() > image[50, 44].sum()  # fast, slow, background


def test_non_finite_positions_are_not_drawn():
    position, types = _rollout(1)
    position = position[0].copy()
    position[3] = np.nan
    position[4] = [np.inf, 0.5]
    image = render_frame(position, types, np.zeros(len(position)), BOUNDS, 64)
    radii = disc_radii(particle_spacing(position, types), BOUNDS, 64)  # from the finite particles
    kept = np.delete(np.arange(len(types)), [3, 4])
    clean = render_frame(position[kept], types[kept], np.zeros(len(kept)), BOUNDS, 64, 1.0, *radii)
    np.testing.assert_array_equal(image, clean)
