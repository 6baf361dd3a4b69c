"""Boundary handling of rollouts: box walls and static segments (gnsx/model/boundary.py)."""

import numpy as np
import pytest
import torch
from test_simulator import METADATA, make_simulator

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.model import physics_free_baseline, rollout
from gnsx.model.boundary import Boundary

BOUNDS = [[0.1, 0.9], [0.1, 0.9]]
SPACING = 0.01


def _ramp(start, end, spacing=SPACING) -> np.ndarray:
    """``[K, 2]`` static particles every ``spacing`` along a segment (the MPM generator's layout)."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    count = int(round(np.linalg.norm(end - start) / spacing)) + 1
    return start + np.linspace(0, 1, count)[:, None] * (end - start)


def _scene(water, ramps):
    """Positions ``[N, 2]`` float32 and types ``[N]``: water first, then the static particles of the ramps."""
    statics = np.concatenate(ramps) if ramps else np.zeros((0, 2))
    water = np.asarray(water, float).reshape(-1, 2)
    position = torch.tensor(np.concatenate([water, statics]), dtype=torch.float32)
    types = torch.tensor([WATER_PARTICLE_ID] * len(water) + [KINEMATIC_PARTICLE_ID] * len(statics))
    return position, types


def test_a_ramp_of_particles_becomes_a_chain_of_segments():
    position, types = _scene([[0.5, 0.5]], [_ramp([0.2, 0.3], [0.6, 0.3])])
    boundary = Boundary.from_particles(BOUNDS, position, types)
    assert boundary.num_segments == 40  # 41 particles along the ramp, neighbours only
    assert np.all(np.abs(boundary.segments[:, 0] - boundary.segments[:, 1]) == 1)
    assert boundary.pushback == pytest.approx(0.05 * SPACING)


def test_a_particle_crossing_a_ramp_is_put_back_on_its_side_keeping_its_tangential_motion():
    position, types = _scene([[0.405, 0.302]], [_ramp([0.2, 0.3], [0.6, 0.3])])
    boundary = Boundary.from_particles(BOUNDS, position, types)
    proposed = position.clone()
    proposed[0] = torch.tensor([0.409, 0.290])  # 1.2 cm down through the ramp, 4 mm along it
    dynamic = types != KINEMATIC_PARTICLE_ID
    assert boundary.count_crossings(position, proposed, types) == 1
    result = boundary.apply(position, proposed, dynamic)
    assert result[0, 0].item() == pytest.approx(0.409, abs=1e-6)  # motion along the ramp kept
    assert result[0, 1].item() == pytest.approx(0.3 + boundary.pushback, abs=1e-6)  # on the skin above
    assert boundary.count_crossings(position, result, types) == 0
    assert torch.equal(result[1:], proposed[1:])  # static particles untouched


def test_steps_that_do_not_cross_are_left_alone():
    position, types = _scene([[0.405, 0.302], [0.1, 0.5], [0.65, 0.25]], [_ramp([0.2, 0.3], [0.6, 0.3])])
    boundary = Boundary.from_particles(BOUNDS, position, types)
    proposed = position.clone()
    proposed[0] += torch.tensor([0.004, 0.001])  # along, above the ramp
    proposed[2] += torch.tensor([0.0, 0.1])  # past the ramp's end: it goes around, not through
    result = boundary.apply(position, proposed, types != KINEMATIC_PARTICLE_ID)
    assert torch.equal(result, proposed)


def test_a_corner_of_two_ramps_is_not_a_gap():
    corner = [_ramp([0.3, 0.5], [0.5, 0.3]), _ramp([0.5, 0.3], [0.7, 0.5])]  # a V
    position, types = _scene([[0.5, 0.32]], corner)
    boundary = Boundary.from_particles(BOUNDS, position, types)
    proposed = position.clone()
    proposed[0] = torch.tensor([0.5, 0.25])  # straight down through the V's tip
    result = boundary.apply(position, proposed, types != KINEMATIC_PARTICLE_ID)
    assert boundary.count_crossings(position, result, types) == 0
    assert result[0, 1].item() > 0.29


def test_walls_clamp_dynamic_particles_but_never_static_ones():
    position, types = _scene([[0.12, 0.5], [0.88, 0.11]], [_ramp([0.05, 0.5], [0.08, 0.5])])
    boundary = Boundary.from_particles(BOUNDS, position, types)
    proposed = position.clone()
    proposed[0] = torch.tensor([0.05, 0.5])
    proposed[1] = torch.tensor([0.95, 0.02])
    result = boundary.apply(position, proposed, types != KINEMATIC_PARTICLE_ID)
    assert result[0].tolist() == pytest.approx([0.1, 0.5])
    assert result[1].tolist() == pytest.approx([0.9, 0.1])
    assert torch.equal(result[2:], position[2:])  # static particles outside the box stay there


def test_three_dimensional_scenes_get_walls_only():
    position = torch.rand(20, 3) * 0.5 + 0.2
    types = torch.tensor([KINEMATIC_PARTICLE_ID] * 10 + [WATER_PARTICLE_ID] * 10)
    boundary = Boundary.from_particles([[0.0, 1.0]] * 3, position, types)
    assert boundary.num_segments == 0
    result = boundary.apply(position, position + 2.0, types != KINEMATIC_PARTICLE_ID)
    assert torch.all(result[10:] == 1.0)


def test_the_mpm_ground_truth_never_crosses_its_ramps(tiny_dataset):
    """The segments model the MPM's colliders: the data the models learn from has no crossing."""
    from gnsx.data.store import SplitReader

    crossings = 0
    for trajectory in SplitReader(tiny_dataset, "train"):
        position, types = trajectory.position, trajectory.particle_type
        boundary = Boundary.from_particles(BOUNDS, position[0], types)
        assert boundary.num_segments > 0
        for t in range(len(position) - 1):
            crossings += boundary.count_crossings(position[t], position[t + 1], types)
    assert crossings == 0


def _falling_scene():
    """Water above a ramp, falling fast enough to tunnel through it unconstrained."""
    water = [[0.35 + 0.01 * i, 0.33] for i in range(10)]
    position, types = _scene(water, [_ramp([0.2, 0.3], [0.6, 0.3])])
    velocity = torch.zeros_like(position)
    velocity[types != KINEMATIC_PARTICLE_ID] = torch.tensor([0.0, -0.012])  # 1.2 cm per frame downwards
    initial = torch.stack([position - velocity, position], dim=1)  # [N, 2, 2]
    return initial, types


def test_the_baseline_lands_on_a_ramp_instead_of_tunnelling():
    initial, types = _falling_scene()
    frames = physics_free_baseline(initial, types, 50, torch.tensor([0.0, -1e-4]), BOUNDS)
    water = types != KINEMATIC_PARTICLE_ID
    assert torch.all(frames[:, water, 1] > 0.3)  # never below the ramp
    assert torch.allclose(frames[-1, water, 1], torch.full((10,), 0.3 + 0.05 * SPACING), atol=1e-5)


@pytest.mark.parametrize("constrain", [True, False])
def test_a_constrained_rollout_stays_in_the_box_and_above_the_ramp(constrain):
    """Random weights with a large acceleration scale throw particles everywhere; the boundary holds them."""
    initial, types = _falling_scene()
    simulator = make_simulator({}, acc_std=[5e-3, 5e-3], radius=METADATA["radius"])
    frames = rollout(simulator, initial, types, 30, constrain=constrain)
    water = types != KINEMATIC_PARTICLE_ID
    bounds = torch.tensor(BOUNDS)
    inside = ((frames[:, water] >= bounds[:, 0]) & (frames[:, water] <= bounds[:, 1])).all()
    boundary = Boundary.from_particles(BOUNDS, initial[:, -1], types)
    previous = torch.cat([initial[:, -1][None], frames[:-1]])
    crossings = sum(boundary.count_crossings(previous[t], frames[t], types) for t in range(len(frames)))
    if constrain:
        assert inside and crossings == 0
    else:  # the raw model is what the boundary is for
        assert not inside or crossings > 0


def test_a_step_from_the_skin_past_a_segments_end_onto_it_is_caught():
    """Measured on a shipped-weights rollout: a particle in the skin of a vertical ramp, just below its lower
    end, stepped diagonally up across the line onto the segment."""
    ramp = _ramp([0.18, 0.3], [0.18, 0.4])
    position, types = _scene([[0.18 + 0.0495 * SPACING, 0.2991]], [ramp])
    boundary = Boundary.from_particles(BOUNDS, position, types)
    proposed = position.clone()
    proposed[0] = torch.tensor([0.18 - 0.07 * SPACING, 0.3014])
    assert boundary.count_crossings(position, proposed, types) == 1
    result = boundary.apply(position, proposed, types != KINEMATIC_PARTICLE_ID)
    assert boundary.count_crossings(position, result, types) == 0
