"""Approximate freezing (gnsx.rules.freezing): resting water far from motion is held and not decoded; the
model's own step is untouched, and old checkpoints that recorded ``freeze_speed`` in the model still load."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_culling import POSITION_TOLERANCE, make, window_of

from gnsx.core.constants import WATER_PARTICLE_ID
from gnsx.model import rollout
from gnsx.model.checkpoint import simulator_from_hparams
from gnsx.rules import Freezing, rollout_with_rules


def pool_and_block():
    """A pool at rest on the left, a block moving down on the right, farther apart than the model's reach,
    and one resting particle beside the block: ``(position [N, 2], velocity [N, 2], types [N], pool
    size)``."""
    spacing = 0.0156
    pool = 0.11 + spacing * torch.cartesian_prod(torch.arange(8), torch.arange(6)).float()
    block = (
        torch.tensor([0.75, 0.6]) + spacing * torch.cartesian_prod(torch.arange(5), torch.arange(5)).float()
    )
    beside_block = torch.tensor([[0.75 - 2 * spacing, 0.6]])  # at rest, but next to the moving block
    position = torch.cat([pool, block, beside_block])
    velocity = torch.zeros_like(position)
    velocity[len(pool) : len(pool) + len(block)] = torch.tensor([0.0, -2e-3])
    types = torch.full((len(position),), WATER_PARTICLE_ID)
    return position, velocity, types, len(pool)


def test_freezing_holds_resting_water_far_from_motion_only():
    simulator = make("simplified")
    freezing = Freezing(simulator, 1e-5)
    position, velocity, types, pool = pool_and_block()
    window = window_of(position, velocity, simulator.history)
    frozen = freezing.frozen_particles(window, types)
    assert bool(frozen[:pool].all()) and not bool(frozen[pool:].any())
    with torch.no_grad():
        held = freezing.predict_positions(window, types)
        free = simulator.predict_positions(window, types)
    assert torch.equal(held[frozen], window[frozen, -1])
    assert not torch.equal(free[frozen], window[frozen, -1])  # the model would have moved them
    torch.testing.assert_close(held[~frozen], free[~frozen], **POSITION_TOLERANCE)  # the pool is out of reach
    # Something moving into reach wakes the pool up.
    moved = position.clone()
    moved[pool:] = moved[pool:] - torch.tensor([0.55, 0.45])
    assert not bool(freezing.frozen_particles(window_of(moved, velocity, 1), types)[:pool].all())
    assert np.isclose(simulator.reach, 5 * 0.035)


def test_frozen_rollout_goes_through_the_one_loop():
    simulator = make("simplified")
    position, velocity, types, pool = pool_and_block()
    window = window_of(position, velocity, simulator.history)
    frozen = rollout_with_rules(simulator, window, types, 3, freeze_speed=1e-5)
    freezing = Freezing(simulator, 1e-5)
    assert torch.equal(frozen, rollout(simulator, window, types, 3, predict=freezing.predict_positions))
    assert torch.equal(frozen[:, :pool], position[:pool].expand(3, -1, -1))  # the pool never moves
    assert torch.equal(rollout_with_rules(simulator, window, types, 3), rollout(simulator, window, types, 3))


def test_speed_is_checked():
    with pytest.raises(ValueError, match="freeze_speed"):
        Freezing(make("simplified"), 0.0)


def test_a_checkpoint_that_recorded_freeze_speed_still_loads():
    """Until 2026-12 ``freeze_speed`` was a model setting, so a checkpoint's ``hyper_parameters["model"]``
    may hold it; it is dropped on reading (gnsx.model.checkpoint.RETIRED_KEYS), ``data_radius`` is kept."""
    simulator = make("simplified", data_radius=0.03)
    hparams = {key: simulator.config[key] for key in ("dim", "bounds", "radius")} | {
        key: simulator.config[key] for key in ("vel_mean", "vel_std", "acc_mean", "acc_std")
    }
    model = {k: v for k, v in simulator.config.items() if k not in hparams}
    rebuilt = simulator_from_hparams(hparams | {"model": model | {"freeze_speed": 1e-5}})
    assert "freeze_speed" not in rebuilt.config and rebuilt.config["data_radius"] == 0.03
