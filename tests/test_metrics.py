"""Metrics on hand-made cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gnsx.evaluation import metrics
from gnsx.evaluation.metrics import (
    centre_of_mass_mse,
    earth_movers_distance,
    kinetic_energy,
    kinetic_energy_error,
    neighbour_count,
    out_of_bounds,
    position_mse,
    position_mse_per_frame,
)


def _blob(n: int, dim: int = 2, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.2, 0.6, size=(n, dim))


# ------------------------------------------------------------------------------------------- Earth Mover's


@pytest.mark.parametrize("method", ["exact", "sinkhorn", "auto"])
def test_identical_sets_cost_nothing(method):
    a = _blob(40)
    assert earth_movers_distance(a, a.copy(), method=method) == pytest.approx(0.0, abs=2e-3)


@pytest.mark.parametrize("dim", [2, 3])
def test_shifted_set_costs_the_shift_length(dim):
    a = _blob(50, dim)
    shift = np.array([0.03, -0.04, 0.012][:dim])
    assert earth_movers_distance(a, a + shift, method="exact") == pytest.approx(
        np.linalg.norm(shift), rel=1e-9
    )


def test_sinkhorn_shift_is_close_to_the_shift_length():
    a = _blob(40)
    shift = np.array([0.03, 0.04])  # |s| = 0.05
    value = earth_movers_distance(a, a + shift, method="sinkhorn")
    # The entropic plan blurs, so it never undercuts the exact value by more than rounding, and stays close.
    assert 0.05 - 1e-4 <= value <= 0.05 * 1.05


def test_emd_ignores_particle_identity_where_mse_does_not():
    a = _blob(30)
    shuffled = a[np.random.default_rng(1).permutation(len(a))]
    assert earth_movers_distance(a, shuffled) == pytest.approx(0.0, abs=1e-8)
    assert position_mse(shuffled, a) > 1e-3


def test_emd_hand_made_cases():
    square_bottom = np.array([[0.0, 0.0], [1.0, 0.0]])
    square_top = np.array([[0.0, 1.0], [1.0, 1.0]])
    assert earth_movers_distance(square_bottom, square_top) == pytest.approx(1.0)
    # Unequal sizes with uniform weights: both halves of the mass travel 1 to the middle point.
    assert earth_movers_distance(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([[1.0, 0.0]])) == pytest.approx(
        1.0
    )
    # One of three particles moves by 0.3: the mean distance moved is 0.1.
    a = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    b = a.copy()
    b[0] += [0.3, 0.0]
    assert earth_movers_distance(a, b) == pytest.approx(0.1)


def test_sinkhorn_agrees_with_exact_on_a_perturbed_set():
    a = _blob(80)
    b = a + np.random.default_rng(2).normal(0.0, 0.01, a.shape)
    exact = earth_movers_distance(a, b, method="exact")
    approx = earth_movers_distance(a, b, method="sinkhorn")
    assert exact * 0.98 <= approx <= exact * 1.2


def test_auto_switches_to_sinkhorn_above_the_size_limit(monkeypatch):
    calls = []
    original = metrics.sinkhorn_cost
    monkeypatch.setattr(metrics, "sinkhorn_cost", lambda *a, **k: calls.append(1) or original(*a, **k))
    a = _blob(20)
    earth_movers_distance(a, a + 0.01, method="auto")
    assert not calls
    monkeypatch.setattr(metrics, "EXACT_EMD_MAX_PARTICLES", 10)
    earth_movers_distance(a, a + 0.01, method="auto")
    assert calls


def test_emd_rejects_bad_input():
    with pytest.raises(ValueError, match="method"):
        earth_movers_distance(_blob(3), _blob(3), method="fast")
    with pytest.raises(ValueError, match=r"\[N, D\]"):
        earth_movers_distance(_blob(3, 2), _blob(3, 3))
    with pytest.raises(ValueError, match="at least one"):
        earth_movers_distance(np.zeros((0, 2)), _blob(3))


# ------------------------------------------------------------------------------------------- MSE and others


def test_position_mse_known_values_numpy_and_torch():
    true = np.zeros((2, 3, 2))
    predicted = true.copy()
    predicted[:, 0] = [0.1, 0.0]  # particle 0 off by 0.1 in x in both frames
    # 2 frames x 3 particles x 2 dims = 12 entries, 2 of them 0.01.
    assert position_mse(predicted, true) == pytest.approx(0.02 / 12)
    mask = np.array([True, False, False])
    assert position_mse(predicted, true, mask) == pytest.approx(0.01 / 2)
    assert position_mse(torch.tensor(predicted), torch.tensor(true), torch.tensor(mask)) == pytest.approx(
        0.005
    )
    np.testing.assert_allclose(position_mse_per_frame(predicted, true, mask), [0.005, 0.005])
    with pytest.raises(ValueError, match="mask"):
        position_mse_per_frame(predicted, true, np.array([True]))


def test_kinetic_energy_of_uniform_motion():
    dt = 0.0025
    velocity = np.array([1.0, -2.0])  # m/s, |v|^2 = 5
    positions = np.stack([np.zeros((4, 2)) + t * dt * velocity for t in range(5)])  # [5, 4, 2]
    energy = kinetic_energy(positions, dt)
    assert energy.shape == (4,)
    np.testing.assert_allclose(energy, 2.5)
    # Masked static particles do not dilute the mean.
    positions[:, 3] = 0.0
    np.testing.assert_allclose(kinetic_energy(positions, dt, np.array([1, 1, 1, 0], bool)), 2.5)
    assert kinetic_energy_error(energy, energy) == 0.0
    assert kinetic_energy_error(0.5 * energy, energy) == pytest.approx(0.5)


def test_neighbour_count_on_a_lattice():
    h = 0.01
    grid = np.stack(np.meshgrid(np.arange(3), np.arange(3), indexing="ij"), -1).reshape(-1, 2) * h
    # 3x3 lattice, radius just over the spacing: centre 4, edge midpoints 3, corners 2 neighbours.
    assert neighbour_count(grid, 1.1 * h) == pytest.approx((4 + 4 * 3 + 4 * 2) / 9)
    # Diagonals join at radius > sqrt(2) h: centre 8, edges 5, corners 3.
    assert neighbour_count(grid, 1.5 * h) == pytest.approx((8 + 4 * 5 + 4 * 3) / 9)
    # A compressed copy (volume loss) has more neighbours at the same radius.
    assert neighbour_count(grid * 0.5, 1.1 * h) > neighbour_count(grid, 1.1 * h)
    only_centre_row = np.zeros(9, bool)
    only_centre_row[[1, 4, 7]] = True  # (0,1), (1,1), (2,1): a line of 3
    assert neighbour_count(grid, 1.1 * h, only_centre_row) == pytest.approx(4 / 3)


def test_out_of_bounds_counts_particles_outside_the_walls():
    bounds = np.array([[0.1, 0.9], [0.1, 0.9]])
    frames = np.array([[[0.5, 0.5], [0.95, 0.5], [0.5, 0.05]], [[0.5, 0.5], [0.5, 0.5], [0.9, 0.9]]])
    np.testing.assert_array_equal(out_of_bounds(frames, bounds), [2, 0])
    np.testing.assert_array_equal(out_of_bounds(frames, bounds, np.array([True, True, False])), [1, 0])
    assert int(out_of_bounds(frames[0], bounds)) == 2


def test_centre_of_mass_error_is_the_common_offset_part_of_the_mse():
    rng = np.random.default_rng(0)
    true = rng.uniform(0.1, 0.9, (5, 40, 2))
    shift = np.array([0.03, -0.04])
    # A rigid shift is all centre of mass; a shuffle that keeps the mean is all shape.
    assert centre_of_mass_mse(true + shift, true) == pytest.approx(position_mse(true + shift, true))
    shuffled = true.copy()
    shuffled[:, :20] += 0.01
    shuffled[:, 20:] -= 0.01
    assert centre_of_mass_mse(shuffled, true) == pytest.approx(0.0, abs=1e-20)
    # In general the two parts add up to the MSE.
    noisy = true + rng.normal(0.0, 0.02, true.shape) + shift
    offset = (noisy - true).mean(axis=1, keepdims=True)
    shape_part = position_mse(noisy - offset, true)
    assert centre_of_mass_mse(noisy, true) + shape_part == pytest.approx(position_mse(noisy, true))
    mask = np.arange(40) < 10  # only the masked particles count
    assert centre_of_mass_mse(true + shift, true, mask) == pytest.approx(np.mean(shift**2))


def test_water_area_counts_occupied_cells():
    square = np.stack(np.meshgrid(np.arange(10), np.arange(10)), -1).reshape(-1, 2) * 0.01 + 0.0005
    assert metrics.water_area(square, 0.01) == pytest.approx(100 * 1e-4)
    assert metrics.water_area(square * 0.5, 0.01) == pytest.approx(25 * 1e-4)  # a quarter
    assert metrics.water_area(np.full((3, 2), np.nan), 0.01) == 0.0


def test_area_ratio_sees_water_packed_and_spread_and_the_spacing_is_measured():
    rng = np.random.default_rng(0)
    lattice = np.stack(np.meshgrid(np.arange(40), np.arange(20)), -1).reshape(-1, 2) * 0.0156 + 0.2
    jittered = lattice + rng.uniform(-0.1, 0.1, lattice.shape) * 0.0156
    spacing = metrics.particle_spacing(jittered)
    assert spacing == pytest.approx(0.0156, rel=0.05)  # the lattice spacing, not the closest pairs
    assert metrics.area_ratio(jittered, jittered, spacing) == 1.0
    centre = jittered.mean(0)
    packed = centre + (jittered - centre) * 0.5  # the same particles in half the width and height
    assert metrics.area_ratio(packed, jittered, spacing) == pytest.approx(0.25, abs=0.1)
    assert metrics.area_ratio(centre + (jittered - centre) * 2.0, jittered, spacing) > 2.0
    assert np.isnan(metrics.area_ratio(jittered, np.full((3, 2), np.nan), spacing))
    assert np.isnan(metrics.particle_spacing(lattice[:1]))
