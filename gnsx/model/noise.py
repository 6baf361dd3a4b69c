"""Training noise: DeepMind's random walk on the velocity history.

A learned simulator fed its own predictions drifts away from the training distribution. Corrupting the
input positions during training with noise of the size of that drift teaches the model to pull particles
back. The noise walks through the velocities because that is how prediction errors accumulate in a
rollout: each predicted acceleration error changes every later velocity.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from gnsx.core.constants import KINEMATIC_PARTICLE_ID


def random_walk_noise(
    position_sequence: Tensor,
    noise_std: float,
    particle_type: Tensor,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Position noise whose velocities form a random walk, zero for static particles.

    Each of the ``H`` velocity steps gets independent noise ``N(0, (noise_std / sqrt(H))^2)``; the velocity
    noise is the cumulative sum of those steps, so ``noise_std`` is the std of the noise on the most
    recent velocity (DeepMind: 6.7e-4 for H = 5, i.e. 3e-4 per step). The position noise is the cumulative
    sum of the velocity noise, with zero noise on the oldest position. With ``H = 1`` this is the
    simplified model's scheme: ``eps ~ N(0, noise_std^2)`` on the current velocity and current position
    (``p~ = p + eps``, ``v~ = v + eps``), the previous position untouched.

    Args:
        position_sequence: ``[num_particles, H + 1, dim]`` positions, oldest first (only the shape, dtype
            and device are used).
        noise_std: std of the noise on the most recent velocity, length per frame (dt = 1).
        particle_type: ``[num_particles]`` int64; particles of type ``KINEMATIC_PARTICLE_ID`` get no noise.
        generator: optional torch generator (on the tensors' device) for reproducible draws.

    Returns:
        ``[num_particles, H + 1, dim]`` noise to add to ``position_sequence``.
    """
    num_particles, num_frames, dim = position_sequence.shape
    num_velocities = num_frames - 1
    step_noise = torch.randn(
        (num_particles, num_velocities, dim),
        generator=generator,
        dtype=position_sequence.dtype,
        device=position_sequence.device,
    ) * (noise_std / math.sqrt(num_velocities))
    velocity_noise = torch.cumsum(step_noise, dim=1)
    position_noise = torch.cat(
        [torch.zeros_like(velocity_noise[:, :1]), torch.cumsum(velocity_noise, dim=1)], 1
    )
    dynamic = (particle_type != KINEMATIC_PARTICLE_ID).to(position_sequence.dtype)
    return position_noise * dynamic[:, None, None]
