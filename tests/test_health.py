"""Rollout health: NaN, blow-up speed, walls and ramps (gnsx/evaluation/health.py)."""

import numpy as np
import pytest

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.evaluation.health import BLOW_UP_SPEED_STD, describe, rollout_health, speed_limit, warn_if_unhealthy

METADATA = Metadata(
    bounds=[[0.1, 0.9], [0.1, 0.9]],
    sequence_length=9,
    default_connectivity_radius=0.035,
    dim=2,
    dt=0.0025,
    vel_mean=[0.0, 0.0],
    vel_std=[0.002, 0.002],
    acc_mean=[0.0, 0.0],
    acc_std=[1e-4, 1e-4],
)


def _scene(frames=10, step=(0.001, 0.0)):
    """Two water particles moving at ``step`` per frame above a horizontal ramp of 11 static particles."""
    ramp = np.stack([np.linspace(0.3, 0.4, 11), np.full(11, 0.3)], 1)
    water = np.array([[0.32, 0.35], [0.36, 0.35]])
    t = np.arange(frames)[:, None, None]
    moving = water[None] + t * np.asarray(step)[None, None]
    positions = np.concatenate([moving, np.broadcast_to(ramp, (frames, 11, 2))], axis=1)
    types = np.array([WATER_PARTICLE_ID] * 2 + [KINEMATIC_PARTICLE_ID] * 11)
    return positions, types


def test_a_calm_rollout_is_healthy():
    positions, types = _scene()
    health = rollout_health(positions, types, METADATA)
    assert health["max_speed"] == pytest.approx(0.001 / 0.0025)
    assert health["speed_limit"] == pytest.approx(BLOW_UP_SPEED_STD * 0.002 / 0.0025)
    assert not health["blew_up"] and health["nonfinite"] == 0 and health["ramp_crossings"] == 0
    assert describe(health) == "" and not warn_if_unhealthy(health, "x")


def test_nan_and_excess_speed_are_blow_ups(capsys):
    positions, types = _scene()
    positions[5, 0] = np.nan
    health = rollout_health(positions, types, METADATA)
    assert health["blew_up"] and health["nonfinite"] == 2
    fast, _ = _scene(step=(1.01 * speed_limit(METADATA), 0.0))
    health = rollout_health(fast, types, METADATA)
    assert health["blew_up"] and "blow-up speed" in describe(health)
    assert warn_if_unhealthy(health, "the rollout")
    assert capsys.readouterr().err.startswith("warning: the rollout blew up: a particle reached")


def test_particles_outside_and_steps_through_ramps_are_counted():
    positions, types = _scene(step=(0.0, -0.01))  # straight down through the ramp at y = 0.3
    health = rollout_health(positions, types, METADATA)
    assert health["ramp_crossings"] == 2  # each water particle crosses once
    positions[:, 0, 0] -= 0.25  # the first particle falls outside the left wall, beside the ramp
    health = rollout_health(positions, types, METADATA)
    assert health["out_of_bounds_final"] == 1 and health["out_of_bounds_max"] == 1
    assert health["ramp_crossings"] == 1
    assert not health["blew_up"]  # outside and through ramps are counted, not blow-ups
