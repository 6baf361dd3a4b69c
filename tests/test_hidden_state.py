"""How much the MPM's hidden state (v, C, J) decides the next frame: the variants and their estimators."""

from __future__ import annotations

import numpy as np
import pytest

from gnsx.evaluation.hidden_state import (
    BASELINE,
    VARIANTS,
    density_volume_ratio,
    fd_velocity,
    measure,
    step_frame,
    velocity_gradient,
)
from gnsx.mpm.presets import get_preset
from gnsx.mpm.solver import MLSMPMSolver

PRESET = get_preset("small")
NO_RAMPS = np.zeros((0, 2, 2))


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py: the generator's thread count


def block(lower, upper, jitter: float, seed: int = 0) -> np.ndarray:
    """``[N, 2]`` a lattice block at the preset's spacing, each particle moved up to ``jitter`` spacings."""
    h = PRESET.particle_spacing
    xs, ys = np.arange(lower[0] + h / 2, upper[0], h), np.arange(lower[1] + h / 2, upper[1], h)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    return grid + np.random.default_rng(seed).uniform(-jitter, jitter, grid.shape) * h


def frames(solver: MLSMPMSolver, count: int) -> np.ndarray:
    """``[count, N, 2]`` float64 positions, the solver stepped a frame between them."""
    out = []
    for f in range(count):
        if f:
            solver.step_frame()
        out.append(solver.x.numpy().astype(np.float64))
    return np.stack(out)


def test_the_true_state_reproduces_the_next_frame_after_an_impact():
    ramps = np.array([[[0.2, 0.3], [0.6, 0.2]]])
    x0 = block((0.3, 0.35), (0.45, 0.5), 0.35)
    solver = MLSMPMSolver(x0, np.tile([0.5, -1.0], (len(x0), 1)), ramps, PRESET.particle_spacing,
                          PRESET.solver_settings())  # fmt: skip
    for _ in range(40):  # on the ramp by now: C and J away from 0 and 1
        solver.step_frame()
    state = [t.numpy().copy() for t in (solver.x, solver.v, solver.C, solver.J)]
    assert np.abs(state[2]).max() > 1.0 and np.abs(state[3] - 1).max() > 1e-3
    solver.step_frame()
    np.testing.assert_array_equal(step_frame(ramps, PRESET, *state), solver.x.numpy())


def test_in_free_flight_every_estimate_but_the_packing_gives_the_ballistic_step():
    x0 = block((0.3, 0.5), (0.5, 0.65), 0.35)
    solver = MLSMPMSolver(x0, np.tile([0.8, 0.4], (len(x0), 1)), NO_RAMPS, PRESET.particle_spacing,
                          PRESET.solver_settings())  # fmt: skip
    x = frames(solver, 3)  # frames 0, 1, 2: the step from frame 1
    g = np.array([0.0, -PRESET.gravity * PRESET.frame_dt**2])
    ballistic = 2 * x[1] - x[0] + g
    assert np.abs(x[2] - ballistic).max() < 1e-6  # the MPM's free flight is ballistic
    v = {"fd": fd_velocity(x[0], x[1], PRESET, False), "fd+g": fd_velocity(x[0], x[1], PRESET, True)}
    C = {"lsq": velocity_gradient(x[1], v["fd"], PRESET.default_connectivity_radius)}
    C["zero"] = np.zeros((len(x0), 2, 2))
    J = {"one": np.ones(len(x0))}
    J["density"] = density_volume_ratio(x[1], PRESET.solver_settings(), PRESET.particle_spacing)
    true = (x[1], v["fd+g"], C["zero"], J["one"])  # the block's true state: uniform motion, unstrained
    lag = PRESET.gravity * PRESET.frame_dt**2 * (PRESET.substeps - 1) / (2 * PRESET.substeps)
    for name, keys in VARIANTS.items():
        state = [true[i] if key is None else (v, C, J)[i - 1][key] for i, key in enumerate(keys, start=1)]
        nxt = step_frame(NO_RAMPS, PRESET, x[1], *state)
        if "density" in keys:  # the jittered packing reads a few % dense or thin: pressure where J is 1
            assert np.abs(nxt - ballistic).max() > 1e-5, name
        elif "fd" in keys:  # the mean velocity of the frame lags its end velocity: too fast upwards
            np.testing.assert_allclose(nxt - ballistic, np.tile([0.0, lag], (len(x0), 1)), atol=1e-6)
        else:
            np.testing.assert_allclose(nxt, ballistic, atol=1e-6, err_msg=name)


def test_the_gradient_estimator_recovers_a_linear_velocity_field():
    x = block((0.2, 0.2), (0.4, 0.35), 0.35, seed=1)
    G = np.array([[1.5, -2.0], [0.7, -0.3]])  # 1/s, G[a, b] = dv_a / dx_b
    v = np.array([0.3, -1.0]) + x @ G.T
    np.testing.assert_allclose(velocity_gradient(x, v, 0.035), np.broadcast_to(G, (len(x), 2, 2)), atol=1e-9)
    line = np.stack([np.linspace(0.2, 0.4, 9), np.full(9, 0.5)], -1)  # a jet: only d/dx is seen
    fit = velocity_gradient(line, line @ G.T, 0.035)
    np.testing.assert_allclose(fit[:, :, 0], np.broadcast_to(G[:, 0], (9, 2)), atol=1e-9)
    np.testing.assert_allclose(fit[:, :, 1], 0.0, atol=1e-9)


def test_the_packing_reads_rest_inside_a_regular_block():
    x = block((0.2, 0.2), (0.6, 0.6), 0.0)
    J = density_volume_ratio(x, PRESET.solver_settings(), PRESET.particle_spacing)
    inside = (np.abs(x - 0.4) < 0.1).all(1)
    np.testing.assert_allclose(J[inside], 1.0, atol=1e-4)  # lattice 0.508 dx: a slight ripple


def test_measure_rebuilds_the_dataset_and_the_true_state_is_exact(tiny_dataset):
    preset = get_preset("small", num_frames=30, trajectories={"train": 3, "valid": 1, "test": 1})
    result = measure(preset, 0, "test", 1, 10, data=tiny_dataset)
    assert result["checks"]["dataset_max_abs_m"] == 0.0
    assert result["checks"]["true_state_max_abs_m"] == 0.0
    assert set(result["mse"]) == {BASELINE, *VARIANTS}
    assert sum(result["count"].values()) > 0
