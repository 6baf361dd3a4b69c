"""The training losses on the normalised acceleration (gnsx.training.system.acceleration_loss)."""

from __future__ import annotations

import math

import pytest
import torch

from gnsx.training.system import GNSSystem, acceleration_loss


def test_mse_is_squared_error_summed_over_dims_averaged_over_particles():
    predicted, target = torch.randn(7, 2), torch.randn(7, 2)
    expected = ((predicted - target) ** 2).sum(-1).mean()
    assert torch.allclose(acceleration_loss(predicted, target, "mse"), expected)


def test_huber_is_squared_inside_delta_linear_outside_and_continuous():
    delta = 1.5
    zero = torch.zeros(1, 2)
    for length in (0.0, 0.3, 1.0, 1.5, 2.0, 40.0):
        error = torch.tensor([[length * 0.6, length * 0.8]])  # |error| = length
        got = acceleration_loss(error, zero, "huber", delta).item()
        want = length**2 if length <= delta else 2 * delta * length - delta**2
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9)
    # Value and slope match at delta.
    below = acceleration_loss(torch.tensor([[delta - 1e-4, 0.0]]), zero, "huber", delta).item()
    above = acceleration_loss(torch.tensor([[delta + 1e-4, 0.0]]), zero, "huber", delta).item()
    assert (above - below) / 2e-4 == pytest.approx(2 * delta, rel=1e-2)


def test_huber_is_rotation_invariant_and_has_finite_gradients_at_zero():
    error = torch.randn(50, 2) * 3
    angle = 0.7
    rotation = torch.tensor([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    target = torch.zeros(50, 2)
    a = acceleration_loss(error, target, "huber", 1.0)
    b = acceleration_loss(error @ rotation.T, target, "huber", 1.0)
    assert torch.allclose(a, b, atol=1e-5)
    predicted = torch.zeros(3, 2, requires_grad=True)
    acceleration_loss(predicted, torch.zeros(3, 2), "huber", 1.0).backward()
    assert torch.isfinite(predicted.grad).all() and (predicted.grad == 0).all()


def test_huber_keeps_free_fall_near_gravity_when_rare_impacts_look_alike():
    """The reason the option exists: 3% unforeseeable impacts (+15) among free-fall samples (-0.565)."""
    target = torch.cat([torch.full((97, 1), -0.565), torch.full((3, 1), 15.0)])
    target = torch.cat([torch.zeros_like(target), target], dim=1)  # [100, 2], acceleration along y
    best = {}
    for kind in ("mse", "huber"):
        guess = torch.zeros(1, 2, requires_grad=True)
        optimizer = torch.optim.Adam([guess], lr=0.05)
        for _ in range(800):
            optimizer.zero_grad()
            acceleration_loss(guess.expand(100, 2), target, kind, 1.0).backward()
            optimizer.step()
        best[kind] = guess[0, 1].item()
    assert best["mse"] == pytest.approx(target[:, 1].mean().item(), abs=0.02)  # ~ -0.10: a third of g
    assert best["huber"] < -0.5  # close to gravity's -0.565


def test_unknown_loss_is_a_clear_error():
    with pytest.raises(ValueError, match="loss must be one of"):
        GNSSystem(
            model={}, dim=2, bounds=[[0, 1], [0, 1]], radius=0.1, vel_mean=[0, 0], vel_std=[1, 1],
            acc_mean=[0, 0], acc_std=[1, 1], loss="l1",
        )  # fmt: skip
