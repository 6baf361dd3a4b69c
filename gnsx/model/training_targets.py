"""Training targets: a simulator's predictions and the normalised accelerations it should have predicted, on
noise-corrupted inputs (DeepMind's training step), with the pushforward trick and an unrolled loss as options.

Kept apart from :class:`~gnsx.model.simulator.LearnedSimulator` (which predicts) because it is how the model is
trained, not what it computes: :class:`gnsx.training.system.GNSSystem` calls it every step.
"""

from __future__ import annotations

import torch
from torch import Tensor

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.model.noise import random_walk_noise
from gnsx.model.simulator import LearnedSimulator


def noisy_training_pair(
    simulator: LearnedSimulator,
    position_sequence: Tensor,
    next_position: Tensor,
    particle_type: Tensor,
    noise_std: float,
    batch: Tensor | None = None,
    generator: torch.Generator | None = None,
    position_correction: float = 0.0,
    pushforward_steps: int = 0,
) -> tuple[Tensor, Tensor]:
    """One loss step's ``(predicted, target)``, both ``[N, D]``: :func:`noisy_training_rollout` with
    ``unroll_steps = 1`` (DeepMind's training step, with the pushforward trick when asked)."""
    predicted, target = noisy_training_rollout(
        simulator,
        position_sequence,
        next_position,
        particle_type,
        noise_std,
        batch,
        generator=generator,
        position_correction=position_correction,
        pushforward_steps=pushforward_steps,
    )
    return predicted[0], target[0]


def noisy_training_rollout(
    simulator: LearnedSimulator,
    position_sequence: Tensor,
    next_position: Tensor,
    particle_type: Tensor,
    noise_std: float,
    batch: Tensor | None = None,
    generator: torch.Generator | None = None,
    position_correction: float = 0.0,
    pushforward_steps: int = 0,
    unroll_steps: int = 1,
) -> tuple[Tensor, Tensor]:
    """Predictions and targets of the loss steps on noise-corrupted inputs (DeepMind's training step,
    generalised to a short rollout).

    The input gets :func:`random_walk_noise`; the target next position is shifted by ``1 -
    position_correction`` times the noise of the most recent position. With the default 0 (DeepMind's)
    the target acceleration undoes the *velocity* noise but the model is not asked to undo the position
    noise (absolute positions are not among the features): with H = 1, ``a~ = a - eps``. With 1 the
    target leads back to the true next position, ``a~ = a - 2 eps``: the model is asked to undo a
    particle's displacement from its neighbours too, which it can see in its edge vectors, and so
    learns a restoring force against the compression it never sees in the data (a fluid compressed in
    a rollout otherwise stays compressed).

    With ``pushforward_steps = k > 0`` (the pushforward trick, Brandstetter et al. 2022) the model first
    rolls itself out ``k`` steps from the noisy oldest ``H + 1`` frames, without gradient, and the loss
    starts from where it got to: the input's deviation from the truth is then the model's own rollout
    error instead of a random walk alone, and the target treats it as the noise above (undoes the
    velocity deviation, keeps ``1 - position_correction`` of the position deviation).

    With ``unroll_steps = S > 1`` the loss runs over ``S`` consecutive model steps *with* the gradient
    through them: step ``j`` starts from the model's own positions after step ``j - 1`` and is scored
    against the true frame after it, the deviation treated as the noise above. With
    ``position_correction = 0`` step ``j``'s error is the error of its predicted next velocity, so the
    loss is the velocity error along an ``S``-step rollout, and the gradient teaches the model the
    consequences of its errors on the next steps (what a single step cannot: the one-step loss falls
    while the rollout's error does not). ``S = 1`` is the single step, identical to before.

    Args:
        position_sequence: ``[N, history + 1 + k + S - 1, D]`` clean positions, oldest first.
        next_position: ``[N, D]`` clean position of the frame after the last one.
        particle_type: ``[N]`` int64 (static particles get no noise).
        noise_std: std of the noise on the most recent velocity (per frame); 0 disables noise.
        batch: ``[N]`` graph ids or ``None``.
        generator: optional torch generator for the noise.
        position_correction: share of the most recent position deviation the target undoes, in [0, 1].
        pushforward_steps: ``k``, model steps without gradient before the loss steps.
        unroll_steps: ``S``, loss steps with the gradient through them.

    Returns:
        ``(predicted, target)``, both ``[S, N, D]`` normalised accelerations. The loss (masking static
        particles) is the caller's.
    """
    if not 0.0 <= position_correction <= 1.0:
        raise ValueError(f"position_correction must be in [0, 1], got {position_correction}")
    if unroll_steps < 1:
        raise ValueError(f"unroll_steps must be >= 1, got {unroll_steps}")
    frames = simulator.history + 1
    lead = pushforward_steps + unroll_steps - 1
    if pushforward_steps < 0 or position_sequence.shape[1] != frames + lead:
        raise ValueError(
            f"position_sequence has {position_sequence.shape[1]} frames; history {simulator.history} with "
            f"pushforward_steps {pushforward_steps} and unroll_steps {unroll_steps} needs {frames + lead}"
        )
    # The true frames after the H + 1 inputs: the pushforward's, then each loss step's target.
    true_frames = torch.cat([position_sequence, next_position.unsqueeze(1)], dim=1)  # [N, frames+lead+1, D]
    position_sequence = true_frames[:, :frames]
    # The most recent input's deviation from the truth: the noise, or where the model got to.
    deviation = None
    if noise_std > 0:
        noise = random_walk_noise(position_sequence, noise_std, particle_type, generator=generator)
        position_sequence = position_sequence + noise
        deviation = noise[:, -1]
    if pushforward_steps > 0:
        with torch.no_grad():
            for _ in range(pushforward_steps):
                position_sequence = _advance(simulator, position_sequence, particle_type, batch)
        deviation = position_sequence[:, -1] - true_frames[:, frames - 1 + pushforward_steps]
    predictions, targets = [], []
    for step in range(unroll_steps):
        now = frames - 1 + pushforward_steps + step  # the true frame the inputs' last one stands for
        if step > 0:
            deviation = position_sequence[:, -1] - true_frames[:, now]
        target_position = true_frames[:, now + 1]
        if deviation is not None:
            target_position = target_position + (1.0 - position_correction) * deviation
        predicted = simulator(position_sequence, particle_type, batch)
        predictions.append(predicted)
        targets.append(simulator.normalized_target(target_position, position_sequence))
        if step + 1 < unroll_steps:  # the next loss step starts where this prediction moves the particles
            moved = _moved(simulator, predicted, position_sequence, particle_type)
            position_sequence = torch.cat([position_sequence[:, 1:], moved.unsqueeze(1)], dim=1)
    return torch.stack(predictions), torch.stack(targets)


def _advance(
    simulator: LearnedSimulator, position_sequence: Tensor, particle_type: Tensor, batch: Tensor | None
) -> Tensor:
    """The input window ``[N, H + 1, D]`` moved one model step on (:meth:`predict_positions`)."""
    moved = simulator.predict_positions(position_sequence, particle_type, batch)
    return torch.cat([position_sequence[:, 1:], moved.unsqueeze(1)], dim=1)


def _moved(
    simulator: LearnedSimulator,
    normalized_acceleration: Tensor,
    position_sequence: Tensor,
    particle_type: Tensor,
) -> Tensor:
    """Next positions ``[N, D]`` from an already predicted acceleration, static particles held (as
    :meth:`predict_positions`, keeping the graph of the gradient)."""
    static = (particle_type == KINEMATIC_PARTICLE_ID)[:, None]
    moved = simulator.integrate(normalized_acceleration, position_sequence)
    return torch.where(static, position_sequence[:, -1], moved)
