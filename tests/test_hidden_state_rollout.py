"""The MPM rolled out with a two-frame memory (gnsx.evaluation.hidden_state_rollout): free flight stays
ballistic when the velocity is corrected for its lag and drifts when it is not; carrying J keeps a resting
block's volume where resetting it lets the block sink into itself."""

from __future__ import annotations

import numpy as np
import pytest

from gnsx.evaluation.hidden_state_rollout import table, two_frame_rollout
from gnsx.mpm.presets import get_preset
from gnsx.mpm.solver import MLSMPMSolver

PRESET = get_preset("small")
NO_RAMPS = np.zeros((0, 2, 2))
G = np.array([0.0, -PRESET.gravity * PRESET.frame_dt**2])  # m per frame^2


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py: the generator's thread count


def _block(lower, upper) -> np.ndarray:
    h = PRESET.particle_spacing
    xs, ys = np.arange(lower[0] + h / 2, upper[0], h), np.arange(lower[1] + h / 2, upper[1], h)
    return np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)


def _true_frames(x0: np.ndarray, v0, count: int) -> np.ndarray:
    solver = MLSMPMSolver(x0, np.tile(v0, (len(x0), 1)), NO_RAMPS, PRESET.particle_spacing,
                          PRESET.solver_settings())  # fmt: skip
    out = [solver.x.numpy().astype(np.float64)]
    for _ in range(count - 1):
        solver.step_frame()
        out.append(solver.x.numpy().astype(np.float64))
    return np.stack(out)


def test_free_flight_is_ballistic_with_the_lag_corrected_and_drifts_without():
    true = _true_frames(_block((0.3, 0.6), (0.45, 0.72)), [0.6, 0.5], 12)
    ballistic = true[1] + np.arange(1, 11)[:, None, None] * (true[1] - true[0]) + np.cumsum(np.arange(1, 11))[
        :, None, None] * G  # fmt: skip
    np.testing.assert_allclose(true[2:], ballistic, atol=1e-6)  # the MPM's free flight is ballistic
    corrected = two_frame_rollout(PRESET, NO_RAMPS, true[:2], 12, "fd+g", carry_j=False)
    plain = two_frame_rollout(PRESET, NO_RAMPS, true[:2], 12, "fd", carry_j=False)
    np.testing.assert_array_equal(corrected[:2], true[:2])
    assert np.abs(corrected - true).max() < 1e-6
    # The plain finite difference is the frame's mean velocity; stepping it as the end-of-frame velocity
    # adds the lag g dt^2 (S-1)/(2S) every frame: the drift grows with the frames.
    drift = np.abs(plain - true)[:, :, 1].max(axis=1)
    assert drift[-1] > 10 * drift[3] > 0 and drift[-1] > 1e-5


def test_carrying_j_keeps_a_resting_pool_from_sinking_into_itself():
    """A pool from wall to wall at rest: J = 1 at every frame forgets the compression that holds the water
    up, so it sinks a little more each frame; the solver's own J carried along holds it where it rests."""
    low, high = PRESET.bounds
    true = _true_frames(_block((low, low), (high, low + 0.06)), [0.0, 0.0], 40)  # settled: hydrostatic rest
    rest = true[-1][:, 1].mean()
    assert abs(true[-2][:, 1].mean() - rest) < 1e-5
    reset = two_frame_rollout(PRESET, NO_RAMPS, true[-2:], 60, "fd", carry_j=False)
    carried = two_frame_rollout(PRESET, NO_RAMPS, true[-2:], 60, "fd", carry_j=True)
    sunk_reset, sunk_carried = rest - reset[-1][:, 1].mean(), rest - carried[-1][:, 1].mean()
    assert sunk_reset > 3e-4  # m: 0.7 mm over 58 frames when measured
    assert sunk_reset > 10 * abs(sunk_carried)
    assert rest - reset[30][:, 1].mean() < sunk_reset  # and still sinking


def test_the_table_lists_each_rollout_with_its_ratio_and_area():
    summary = {"physics-free baseline": {"10": (1e-9, 1e-10), "50": (1e-6, 1e-7), "100": (1e-4, 1e-5),
                                         "all": (1e-2, 1e-3), "area_ratio_final": (0.5, 0.05)},
               "two frames (fd, lsq, J=1)": {"10": (1e-8, 1e-9), "50": (1e-6, 1e-7), "100": (1e-5, 1e-6),
                                             "all": (5e-3, 1e-4), "area_ratio_final": (0.8, 0.02)}}  # fmt: skip
    lines = table({"summary": summary, "x_baseline": {"two frames (fd, lsq, J=1)": (2.0, 1.5, 2.7, 16)}})
    assert lines[2].startswith("| physics-free baseline |") and lines[2].endswith("| 1 | 0.50 ± 0.05 |")
    assert "2x [1.5, 2.7]" in lines[3] and lines[3].endswith("| 0.80 ± 0.02 |")
