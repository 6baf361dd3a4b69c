"""Error sources by regime (gnsx.evaluation.regimes): the labels follow the true motion, and the errors land
in the regime and horizon they belong to."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.evaluation.regimes import (
    FLIGHT,
    IMPACT,
    POOL,
    UNLABELLED,
    ballistic_onestep,
    classify,
    onestep_positions,
    paired_ratios,
    paired_table,
    table,
    trajectory_sources,
)

G = np.array([0.0, -1e-4])  # per frame^2


def _trajectory(frames: int = 40):
    """Particle 0 falls freely, 1 rests, 2 falls then stops dead on a floor at frame 20, 3 is a wall."""
    t = np.arange(frames, dtype=np.float64)[:, None]
    falling = np.array([0.2, 0.8]) + np.array([1e-3, 0.0]) * t + 0.5 * G * t**2
    resting = np.broadcast_to(np.array([0.5, 0.1]), (frames, 2))
    stopped = falling.copy() + [0.3, 0.0]
    stopped[20:] = stopped[19]
    wall = np.broadcast_to(np.array([0.0, 0.0]), (frames, 2))
    position = np.stack([falling, resting, stopped, wall], axis=1)  # [T, 4, 2]
    types = np.array([WATER_PARTICLE_ID] * 3 + [KINEMATIC_PARTICLE_ID])
    return position, types


def test_regimes_follow_the_true_motion():
    position, types = _trajectory()
    labels = classify(position, types, G)
    assert (labels[[0, -1]] == UNLABELLED).all() and (labels[:, 3] == UNLABELLED).all()
    assert (labels[1:-1, 0] == FLIGHT).all()  # ballistic to float rounding
    assert (labels[1:-1, 1] == POOL).all()
    # The stop: the frame of impact decelerates at ~50 g; afterwards it rests.
    assert labels[19, 2] == IMPACT and (labels[1:19, 2] == FLIGHT).all() and (labels[21:-1, 2] == POOL).all()


def test_errors_land_in_their_regime_and_horizon():
    position, types = _trajectory()
    labels = classify(position, types, G)
    predicted = position.copy()
    predicted[12:, 1] += 0.01  # only the resting particle goes wrong, from frame 12 on
    out = trajectory_sources(predicted, None, position, labels, input_frames=2)
    assert out["rollout"]["flight"] == 0.0 and out["rollout"]["pool"] > 0
    assert out["horizon"]["10"] == 0.0 and out["horizon"]["all"] > 0  # frames 2..11 are exact
    assert np.isnan(out["horizon"]["100"])  # fewer predicted frames than that
    assert sum(out["share"].values()) == pytest.approx(1.0)
    assert "onestep" not in out


def test_one_step_predictions_start_from_true_frames():
    class Constant:
        """A stand-in simulator: next position = last + last velocity (no acceleration)."""

        input_frames = 2

        def predict_positions(self, sequence, particle_type, batch=None):
            return sequence[:, -1] + (sequence[:, -1] - sequence[:, -2])

    position, types = _trajectory(24)
    onestep = onestep_positions(Constant(), torch.tensor(position), torch.tensor(types))
    assert np.isnan(onestep[:2]).all()
    expected = 2 * position[1:-1] - position[:-2]
    assert np.allclose(onestep[2:], expected)
    labels = classify(position, types, G)
    out = trajectory_sources(position, onestep, position, labels, input_frames=2)
    # Missing gravity costs |g|^2 / 2 per coordinate in flight, nothing at rest.
    assert out["onestep"]["flight"] == pytest.approx(float(G @ G) / 2) and out["onestep"]["pool"] == 0.0


def test_the_baselines_one_step_error_is_what_departs_from_gravity():
    position, types = _trajectory()
    labels = classify(position, types, G)
    onestep = ballistic_onestep(position, G)
    assert np.isnan(onestep[:2]).all()
    out = trajectory_sources(position, onestep, position, labels, input_frames=2)
    # Exact in flight; at rest it adds gravity the floor takes away: |g|^2 / 2 per coordinate.
    assert out["onestep"]["flight"] == pytest.approx(0.0, abs=1e-20)
    assert out["onestep"]["pool"] == pytest.approx(float(G @ G) / 2)
    # The table divides a model's one-step MSE by the baseline's, regime by regime.
    half = {"pool": (0.5 * float(G @ G) / 2, 0.0), "flight": (0.0, 0.0), "impact": (1.0, 0.0)}
    base = {
        "horizon": {"all": (1.0, 0.0)},
        "rollout": {r: (1.0, 0.0) for r in half},
        "share": {r: (1 / 3, 0.0) for r in half},
        "onestep": {"pool": (out["onestep"]["pool"], 0.0), "flight": (0.0, 0.0), "impact": (2.0, 0.0)},
    }
    model = base | {"onestep": half}
    lines = table({"physics-free baseline": base, "model": model})
    pool_row = next(line for line in lines if line.startswith("| model | pool"))
    impact_row = next(line for line in lines if line.startswith("| model | impact"))
    assert pool_row.endswith("| 0.5 |") and impact_row.endswith("| 0.5 |")
    assert next(line for line in lines if line.startswith("| model | flight")).endswith("| – |")


def _rows(scale: float, wobble: float = 1.0, n: int = 6):
    """Per-trajectory rows (trajectory_sources' shape) whose errors are ``scale`` x a made-up reference,
    times ``wobble`` on every other trajectory."""
    rows = []
    for i in range(n):
        factor = scale * (wobble if i % 2 else 1 / wobble) * (i + 1)
        figures = {key: factor * 1e-3 for key in ("flight", "impact", "pool")}
        rows.append({"horizon": {"10": factor * 1e-6, "all": factor * 1e-2}, "rollout": dict(figures),
                     "onestep": dict(figures), "share": {"flight": 0.2, "impact": 0.7, "pool": 0.1}})  # fmt: skip
    return rows


def test_a_model_is_paired_with_the_reference_trajectory_by_trajectory():
    """Half the reference's error on every trajectory reads 0.5x with no spread, whatever the trajectories'
    own scale; a model that wobbles around the reference is a tie; different trajectories are refused."""
    reference = _rows(1.0)
    halved = paired_ratios(_rows(0.5), reference)
    assert set(halved) == {"horizon", "rollout", "onestep"}
    for group in halved.values():
        for centre, low, high, n in group.values():
            assert centre == pytest.approx(0.5) and low == pytest.approx(0.5) and high == pytest.approx(0.5)
            assert n == 6
    wobbling = paired_ratios(_rows(1.0, wobble=1.5), reference)
    centre, low, high, _ = wobbling["horizon"]["all"]
    assert centre == pytest.approx(1.0) and low < 1 < high
    text = "\n".join(paired_table({"new": halved, "wobbly": wobbling}, "shipped"))
    assert "0.5x [0.5, 0.5]" in text and "(tie)" in text.split("| wobbly |")[1]
    assert "(tie)" not in text.split("| new |")[1].split("\n")[0]
    with pytest.raises(ValueError, match="same trajectories"):
        paired_ratios(_rows(0.5, n=5), reference)
