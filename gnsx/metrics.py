"""Error metrics between predicted and ground-truth particle trajectories."""

from __future__ import annotations

import torch


def position_mse(predicted: torch.Tensor, true: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """Mean squared position error per coordinate (DeepMind's rollout MSE convention).

    Args:
        predicted, true: ``[..., N, D]`` positions (data units), e.g. ``[T, N, D]`` for a rollout.
        mask: ``[N]`` bool; only these particles count (e.g. dynamic ones). None: all particles.
    Returns:
        mean over frames, selected particles and dimensions (data units squared).
    """
    error = (predicted - true) ** 2
    if mask is not None:
        error = error[..., mask, :]
    return float(error.mean())
