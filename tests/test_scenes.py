"""Scenes (data, sampler, particles) and presets."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import yaml
from scipy.spatial import cKDTree

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.mpm.presets import PRESETS, Preset, get_preset
from gnsx.mpm.scenes import (
    Scene,
    WaterBlock,
    ramp_particles,
    sample_dam_scene,
    sample_rest_scene,
    sample_scene,
    scene_particles,
    segment_distance,
    segment_rect_distance,
)

SCENE = Scene(
    blocks=[WaterBlock((0.2, 0.5), (0.6, 0.8), (0.7, -0.4))],
    ramps=[((0.15, 0.4), (0.6, 0.33)), ((0.7, 0.12), (0.7, 0.4))],
)


# ---------------------------------------------------------------------------------------------- Scene data


def test_scene_dict_round_trip_through_yaml():
    d = SCENE.to_dict()
    text = yaml.safe_dump(d)
    assert "!!python" not in text  # plain lists and floats only
    back = Scene.from_dict(yaml.safe_load(text))
    assert back == SCENE
    assert back.to_dict() == d
    np.testing.assert_array_equal(back.ramp_array(), np.array(SCENE.ramps))


def test_scene_from_dict_defaults_velocity_and_accepts_no_ramps():
    scene = Scene.from_dict({"blocks": [{"lower": [0.2, 0.2], "upper": [0.4, 0.3]}]})
    assert scene.blocks[0].velocity == (0.0, 0.0) and scene.ramps == []
    assert scene.ramp_array().shape == (0, 2, 2)


@pytest.mark.parametrize(
    "bad, where",
    [
        ({"blocks": [{"lower": [0.2, 0.2]}]}, r"scene\.blocks\[0\]"),
        ({"blocks": [{"lower": [0.2], "upper": [0.4, 0.3]}]}, r"scene\.blocks\[0\]\.lower"),
        ({"blocks": [{"lower": [0.5, 0.2], "upper": [0.4, 0.3]}]}, r"scene\.blocks\[0\]: lower"),
        ({"blocks": [{"lower": [0.2, "a"], "upper": [0.4, 0.3]}]}, r"scene\.blocks\[0\]\.lower"),
        ({"ramps": [[[0.2, 0.2], [0.2, 0.2]]]}, r"scene\.ramps\[0\]: .*zero-length"),
        ({"ramps": [[[0.2, 0.2]]]}, r"scene\.ramps\[0\]"),
        ({"ramps": [[[0.2, 0.2], [0.3, math.nan]]]}, r"scene\.ramps\[0\]\[1\]"),
        ({"block": []}, r"scene: unknown key\(s\) \['block'\] \(did you mean 'blocks'\?\)"),
        (
            {"blocks": [{"lower": [0.2, 0.2], "upper": [0.4, 0.3], "speed": [1, 0]}]},
            r"scene\.blocks\[0\]: unknown key\(s\) \['speed'\]; expected 'lower', 'upper', 'velocity'",
        ),
    ],
)
def test_scene_from_dict_names_the_bad_field(bad, where):
    with pytest.raises(DataError, match=where):
        Scene.from_dict(bad)


# ---------------------------------------------------------------------------------------------- particles


def test_scene_particles_layout_and_determinism():
    spacing = 0.01
    position, particle_type = scene_particles(SCENE, spacing, np.random.default_rng(0))
    assert position.dtype == np.float32 and particle_type.dtype == np.int64
    water = particle_type == WATER_PARTICLE_ID
    # Water first, then ramps; one water particle per spacing^2 of block area.
    assert water[: water.sum()].all() and (particle_type[water.sum() :] == KINEMATIC_PARTICLE_ID).all()
    assert water.sum() == 40 * 30
    lower, upper = np.array(SCENE.blocks[0].lower), np.array(SCENE.blocks[0].upper)
    assert (position[water] > lower).all() and (position[water] < upper).all()
    same, _ = scene_particles(SCENE, spacing, np.random.default_rng(0))
    other, _ = scene_particles(SCENE, spacing, np.random.default_rng(1))
    np.testing.assert_array_equal(position, same)
    assert not np.array_equal(position, other)


def test_water_is_irregular_but_never_overlapping():
    spacing, jitter = 0.01, 0.35
    position, particle_type = scene_particles(SCENE, spacing, np.random.default_rng(0), jitter=jitter)
    water = position[particle_type == WATER_PARTICLE_ID].astype(np.float64)
    nearest = cKDTree(water).query(water, k=2)[0][:, 1]
    assert nearest.min() >= (1 - 2 * jitter) * spacing - 1e-6
    # Not a lattice: nearest-neighbour distances spread widely, and coordinates do not repeat.
    assert nearest.std() > 0.05 * spacing
    assert len(np.unique(np.round(water[:, 0], 6))) > 0.9 * len(water)


def test_water_clears_the_ramp_bands():
    scene = Scene([WaterBlock((0.2, 0.2), (0.6, 0.6))], [((0.1, 0.4), (0.5, 0.4))])  # the ramp cuts the block
    position, particle_type = scene_particles(scene, 0.01, np.random.default_rng(0), clearance=0.03)
    water = position[particle_type == WATER_PARTICLE_ID]
    assert segment_distance(water.astype(np.float64), scene.ramp_array()).min() >= 0.03
    assert len(water) < 40 * 40 - 0.06 / 0.01 * 30  # a 6 cm band over 30 columns is gone


def test_ramp_particles_line_each_ramp_end_to_end():
    points = ramp_particles(SCENE, ramp_spacing=0.01)
    for p0, p1 in SCENE.ramps:
        d = segment_distance(points, np.array([[p0, p1]]))[:, 0]
        on = points[d < 1e-9]
        steps = np.linalg.norm(np.diff(on, axis=0), axis=1)
        assert np.allclose(on[0], p0) and np.allclose(on[-1], p1)
        assert steps.max() <= 0.01 + 1e-9 and steps.min() > 0.009


# ---------------------------------------------------------------------------------------------- sampler


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_sampled_scenes_respect_the_preset(name):
    preset = get_preset(name)
    lo, hi = preset.bounds[0] + preset.wall_margin, preset.bounds[1] - preset.wall_margin
    ramp_counts, vertical, speeds = [], 0, []
    for seed in range(150):
        scene = sample_scene(np.random.default_rng(seed), preset)
        (block,) = scene.blocks
        w, h = block.size
        assert preset.block_width_range[0] <= w <= preset.block_width_range[1]
        assert preset.block_height_range[0] <= h <= preset.block_height_range[1]
        assert lo <= min(block.lower) and max(block.upper) <= hi
        speeds.append(math.hypot(*block.velocity))
        assert preset.num_ramps_range[0] <= len(scene.ramps) <= preset.num_ramps_range[1]
        ramp_counts.append(len(scene.ramps))
        for p0, p1 in scene.ramps:
            p0, p1 = np.array(p0), np.array(p1)
            length = np.linalg.norm(p1 - p0)
            assert preset.ramp_length_range[0] - 1e-9 <= length <= preset.ramp_length_range[1] + 1e-9
            assert lo - 1e-9 <= min(p0.min(), p1.min()) and max(p0.max(), p1.max()) <= hi + 1e-9
            angle = math.atan2(p1[1] - p0[1], p1[0] - p0[0])
            is_vertical = math.isclose(abs(angle), math.pi / 2, abs_tol=1e-9)
            vertical += is_vertical
            assert is_vertical or abs(angle) <= preset.ramp_max_angle + 1e-9
            gap = segment_rect_distance(p0, p1, np.array(block.lower), np.array(block.upper))
            assert gap >= preset.ramp_clearance
    speeds = np.array(speeds)
    assert (speeds >= preset.speed_range[0]).all() and (speeds <= preset.speed_range[1]).all()
    # The ranges are used, not just respected.
    assert set(ramp_counts) == set(range(preset.num_ramps_range[0], preset.num_ramps_range[1] + 1))
    assert vertical > 0


def test_rest_scenes_are_pools_at_rest_wall_to_wall_with_ramps_above():
    preset = get_preset("small", rest_fraction=1.0)
    lo, hi = preset.bounds
    falling = 0
    for seed in range(100):
        scene = sample_rest_scene(np.random.default_rng(seed), preset)
        pool, *rest = scene.blocks
        assert pool.lower == (lo, lo) and pool.upper[0] == hi and pool.velocity == (0.0, 0.0)
        assert preset.pool_depth_range[0] <= pool.size[1] <= preset.pool_depth_range[1]
        assert len(rest) <= 1 and len(scene.ramps) >= 1
        for block in rest:  # a block starts clear above the pool, inside the margins
            falling += 1
            assert block.lower[1] >= pool.upper[1] + preset.ramp_clearance
            assert block.upper[1] <= hi - preset.wall_margin
            assert preset.speed_range[0] <= math.hypot(*block.velocity) <= preset.speed_range[1]
        for p0, p1 in scene.ramps:
            for block in scene.blocks:
                gap = segment_rect_distance(
                    np.array(p0), np.array(p1), np.array(block.lower), np.array(block.upper)
                )
                assert gap >= preset.ramp_clearance
    assert 25 < falling < 75  # rest_block_probability 0.5, both kinds drawn
    with pytest.raises(ValueError, match="deepest pool"):
        sample_rest_scene(np.random.default_rng(0), get_preset("small", pool_depth_range=(0.1, 0.8)))


def test_dam_scenes_are_one_block_at_rest_on_the_floor_with_ramps_clear():
    preset = get_preset("small", dam_fraction=1.0)
    lo, hi = preset.bounds
    sides = set()
    for seed in range(100):
        scene = sample_dam_scene(np.random.default_rng(seed), preset)
        (block,) = scene.blocks
        assert block.lower[1] == lo and block.velocity == (0.0, 0.0) and len(scene.ramps) >= 1
        assert lo <= block.lower[0] < block.upper[0] <= hi
        assert preset.block_width_range[0] - 1e-12 <= block.size[0] <= preset.block_width_range[1] + 1e-12
        assert preset.block_height_range[0] <= block.size[1] <= preset.block_height_range[1]
        sides.add("left" if block.lower[0] == lo else "right" if block.upper[0] == hi else "free")
        for p0, p1 in scene.ramps:
            corners = np.array(block.lower), np.array(block.upper)
            gap = segment_rect_distance(np.array(p0), np.array(p1), *corners)
            assert gap >= preset.ramp_clearance
    assert sides == {"left", "right", "free"}
    with pytest.raises(ValueError, match="largest block"):
        sample_dam_scene(np.random.default_rng(0), get_preset("small", block_width_range=(0.1, 0.9)))


def test_pools_and_dams_together_cannot_exceed_every_scene():
    get_preset("small", rest_fraction=0.6, dam_fraction=0.4)
    with pytest.raises(ValueError, match=r"rest_fraction \+ dam_fraction must not exceed 1"):
        get_preset("small", rest_fraction=0.6, dam_fraction=0.5)


@pytest.mark.parametrize("field", ["rest_fraction", "dam_fraction", "rest_block_probability"])
def test_rest_probabilities_are_validated(field):
    with pytest.raises(ValueError, match=f"{field} must be a probability"):
        get_preset("small", **{field: 1.5})


def test_sampler_is_deterministic_per_seed():
    preset = get_preset("small")
    a = sample_scene(np.random.default_rng(42), preset)
    assert a == sample_scene(np.random.default_rng(42), preset)
    assert a != sample_scene(np.random.default_rng(43), preset)


def test_sampled_directions_cover_the_circle():
    preset = get_preset("small")
    angles = [
        math.atan2(*sample_scene(np.random.default_rng(s), preset).blocks[0].velocity[::-1])
        for s in range(200)
    ]
    counts = np.histogram(angles, bins=4, range=(-math.pi, math.pi))[0]
    assert counts.min() > 25  # every quadrant, roughly uniformly


def test_waterramps_particle_counts_match_the_real_data():
    """WaterRamps holds ~1.1k-2.3k particles per trajectory; the preset must land in that range."""
    preset = get_preset("waterramps")
    counts = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        scene = sample_scene(rng, preset)
        _, particle_type = scene_particles(
            scene,
            preset.particle_spacing,
            rng,
            ramp_spacing=preset.ramp_spacing,
            clearance=preset.ramp_clearance,
        )
        counts.append(len(particle_type))
    assert 1000 <= min(counts) and max(counts) <= 2400 and np.mean(counts) > 1400


def test_infeasible_ranges_are_reported():
    preset = get_preset("small", block_width_range=(0.9, 0.95))
    with pytest.raises(ValueError, match="does not fit"):
        sample_scene(np.random.default_rng(0), preset)


def test_segment_rectangle_distance():
    lower, upper = np.array([0.2, 0.2]), np.array([0.4, 0.4])
    assert segment_rect_distance(np.array([0.1, 0.3]), np.array([0.5, 0.3]), lower, upper) == 0  # crosses
    assert segment_rect_distance(np.array([0.25, 0.25]), np.array([0.3, 0.3]), lower, upper) == 0  # inside
    assert segment_rect_distance(np.array([0.1, 0.5]), np.array([0.5, 0.5]), lower, upper) == pytest.approx(
        0.1
    )
    # Diagonal past a corner: the corner (0.4, 0.4) is 0.2 / sqrt(2) from the line x + y = 1.
    d = segment_rect_distance(np.array([0.3, 0.7]), np.array([0.7, 0.3]), lower, upper)
    assert d == pytest.approx(0.2 / math.sqrt(2), rel=1e-9)


# ---------------------------------------------------------------------------------------------- presets


def test_presets_follow_their_recipes():
    small, full = get_preset("small"), get_preset("waterramps")
    assert (small.grid, small.num_frames) == (32, 250)
    for preset in (small, get_preset("waterramps")):
        # Stiff water (issue 13): the acoustic Courant number c dt / dx stays at or below 0.4.
        s = preset.solver_settings()
        assert math.sqrt(s.stiffness / s.density) * s.dt / s.dx <= 0.4 + 1e-9
        assert s.viscosity > 0
    assert get_preset("waterramps").solver_settings().density_relaxation > 0
    assert small.trajectories == {"train": 100, "valid": 8, "test": 16}  # 16 test: enough to rank models
    assert small.particle_spacing == pytest.approx(0.5 / 32, rel=0.01)
    assert small.default_connectivity_radius == 0.035
    assert (small.block_width_range, small.block_height_range) == ((0.15, 0.45), (0.15, 0.35))
    assert small.num_ramps_range == (1, 4)
    assert (full.grid, full.num_frames, full.default_connectivity_radius) == (64, 601, 0.015)
    assert full.trajectories == {"train": 1000, "valid": 100, "test": 100}
    # Water may not start where the grid colliders act.
    for preset in (small, full):
        settings = preset.solver_settings()
        assert preset.ramp_clearance > settings.collider_band * settings.dx


def test_get_preset_errors_and_overrides():
    with pytest.raises(KeyError, match="small.*waterramps"):
        get_preset("tiny")
    with pytest.raises(ValueError, match="unknown field"):
        get_preset("small", frames=3)
    with pytest.raises(ValueError, match="unknown split"):
        get_preset("small", trajectories={"training": 3})
    custom = get_preset("small", num_frames=50, trajectories={"train": 3, "valid": 1, "test": 1})
    assert custom.num_frames == 50 and custom.num_trajectories == 5
    assert get_preset("small").num_frames == 250  # the registry is untouched
    get_preset("small").trajectories["train"] = 999  # a caller's copy...
    assert get_preset("small").trajectories["train"] == 100  # ...is not the registry's
    replaced = dataclasses.replace(get_preset("small"), substeps=20)
    assert isinstance(replaced, Preset) and replaced.solver_settings().substeps == 20


def test_preset_to_dict_is_json():
    d = json.loads(json.dumps(get_preset("waterramps").to_dict()))
    assert d["name"] == "waterramps" and d["block_width_range"] == [0.32, 0.48]
