"""Autoregressive rollouts: the learned simulator fed its own predictions, and the physics-free baseline.

Both apply the same :class:`gnsx.model.boundary.Boundary` to every step (box walls, static segments), so a
rollout never leaves the box or tunnels through a ramp, and the model is scored against a baseline held to the
same walls. The model's rollout also gets the simulator's rules (:class:`gnsx.model.rules.Rules`, all on by
default): free flight (:class:`gnsx.model.freeflight.FreeFlight`: a free rigid cluster of water falls at g),
the rest hold (:class:`gnsx.model.rest.RestHold`: water at rest stays at rest) and the density limit
(:class:`gnsx.model.density.DensityLimit`: water does not compress). The baseline gets none of them: with
them, constant velocity plus gravity would be a position-based fluid solver, not physics-free.
``constrain=False`` gives the raw model (what it would do on its own)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor
from tqdm import tqdm

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.model.boundary import Boundary
from gnsx.model.density import DensityLimit
from gnsx.model.freeflight import FreeFlight
from gnsx.model.rest import LEVEL, RestHold
from gnsx.model.rules import Rules
from gnsx.model.simulator import LearnedSimulator


@torch.inference_mode()
def rollout(
    simulator: LearnedSimulator,
    initial_positions: Tensor,
    particle_type: Tensor,
    num_steps: int,
    static_positions: Tensor | None = None,
    progress: bool = False,
    constrain: bool = True,
    rules: Rules | None = None,
) -> Tensor:
    """Predict ``num_steps`` frames by feeding each prediction back as input.

    Args:
        simulator: the model (its mode is not changed; it has no dropout or batch norm).
        initial_positions: ``[N, history + 1, D]`` the first ``simulator.input_frames`` frames, oldest first.
        particle_type: ``[N]`` int64.
        num_steps: number of frames to predict.
        static_positions: optional ``[num_steps, N, D]`` positions of the static (kinematic) particles for
            each predicted frame (e.g. the ground truth, DeepMind's convention for moving obstacles); only
            the rows of static particles are read. ``None``: static particles stay at their last input
            position.
        progress: show a tqdm progress bar.
        constrain: apply the scene's :class:`Boundary` (the model's box, segments between the static
            particles of the last input frame) and the ``rules`` to every predicted frame; ``False``: the raw
            model.
        rules: with ``constrain``, which of the simulator's rules apply before the boundary, in this order:
            free flight (:class:`FreeFlight`: a free rigid cluster falls at g; the rules after it leave its
            particles alone), the rest hold (:class:`RestHold`), the density limit (:class:`DensityLimit`).
            ``None``: none of them (:class:`Rules`' defaults: the raw network held by the walls and ramps).

    Returns:
        ``[num_steps, N, D]`` predicted positions of frames ``history + 1 ... history + num_steps``.
    """
    frames = simulator.input_frames
    if initial_positions.dim() != 3 or initial_positions.shape[1] != frames:
        raise ValueError(
            f"rollout: initial_positions must be [num_particles, {frames}, dim] (the model reads "
            f"{frames} frames), got {tuple(initial_positions.shape)}"
        )
    num_particles, _, dim = initial_positions.shape
    if static_positions is not None and tuple(static_positions.shape) != (num_steps, num_particles, dim):
        raise ValueError(
            f"rollout: static_positions must be [num_steps, N, D] = [{num_steps}, {num_particles}, {dim}], "
            f"got {tuple(static_positions.shape)}"
        )
    static = (particle_type == KINEMATIC_PARTICLE_ID)[:, None]  # [N, 1]
    dynamic = ~static[:, 0]
    boundary = None
    if constrain:
        boundary = Boundary.from_particles(simulator.bounds.cpu(), initial_positions[:, -1], particle_type)
    rules = (rules or Rules()) if constrain else Rules.none()
    limit = None
    if rules.incompressible:
        radius = float(simulator.rules_radius)
        limit = DensityLimit.from_particles(initial_positions[:, 0], particle_type, radius)
    rest = None
    if rules.hold_rest:
        rest = RestHold.for_simulator(simulator, level=LEVEL if rules.level_pool else None)
    flight = FreeFlight.for_simulator(simulator) if rules.free_flight else None
    window = initial_positions
    predictions = []
    for step in tqdm(range(num_steps), desc="rollout", disable=not progress):
        next_position = simulator.predict_positions(window, particle_type)  # static held at window[:, -1]
        if static_positions is not None:
            next_position = torch.where(static, static_positions[step], next_position)
        moves = dynamic  # the particles the rules below may move
        if flight is not None:
            next_position, free = flight.apply(window, next_position, particle_type)
            moves = dynamic & ~free
        if rest is not None:
            next_position = rest.apply(window, next_position, moves, static[:, 0])
        if limit is not None:
            allowed = limit.allowed_density(window[:, -1], dynamic)  # no water pushed below its last density
            next_position = limit.apply(next_position, moves, allowed)
        if boundary is not None:
            next_position = boundary.apply(window[:, -1], next_position, dynamic)
        predictions.append(next_position)
        window = torch.cat([window[:, 1:], next_position[:, None]], dim=1)
    if not predictions:
        return initial_positions.new_empty((0, num_particles, dim))
    return torch.stack(predictions)


@torch.inference_mode()
def physics_free_baseline(
    initial_positions: Tensor,
    particle_type: Tensor,
    num_steps: int,
    gravity_per_frame: Tensor,
    bounds: Tensor | Sequence[Sequence[float]],
) -> Tensor:
    """Constant velocity plus gravity, held by the scene's boundary: what a learned model must beat.

    Each step: ``v <- v + g``, ``p <- boundary(p + v)`` (clamped into ``bounds``, pushed back from the static
    segments, :class:`Boundary`), then ``v <- p_new - p_old`` so a particle that hits a wall or a ramp stops
    moving into it (a perfectly inelastic wall) instead of piling up speed. Static particles never move.

    Args:
        initial_positions: ``[N, F, D]`` with ``F >= 2`` frames, oldest first (the last two give v).
        particle_type: ``[N]`` int64.
        num_steps: number of frames to predict.
        gravity_per_frame: ``[D]`` acceleration per frame^2 (e.g. the data's mean water acceleration, or
            ``9.8 * dt**2`` in -y).
        bounds: ``[D, 2]`` domain ``[lower, upper]`` per dimension.

    Returns:
        ``[num_steps, N, D]`` positions of the next ``num_steps`` frames.
    """
    if initial_positions.dim() != 3 or initial_positions.shape[1] < 2:
        raise ValueError(
            "physics_free_baseline: initial_positions must be [N, >= 2, D], "
            f"got {tuple(initial_positions.shape)}"
        )
    bounds = torch.as_tensor(bounds, dtype=initial_positions.dtype, device=initial_positions.device)
    gravity = torch.as_tensor(
        gravity_per_frame, dtype=initial_positions.dtype, device=initial_positions.device
    )
    moves = particle_type != KINEMATIC_PARTICLE_ID  # [N]
    dynamic = moves.to(initial_positions.dtype)[:, None]  # [N, 1]
    position = initial_positions[:, -1]
    boundary = Boundary.from_particles(bounds.cpu(), position, particle_type)
    velocity = (position - initial_positions[:, -2]) * dynamic
    frames = []
    for _ in range(num_steps):
        velocity = velocity + gravity * dynamic
        # Static particles may lie outside the domain (DeepMind's ramps do not); the boundary never moves
        # them.
        next_position = boundary.apply(position, position + velocity, moves)  # static velocity is 0
        velocity = next_position - position
        position = next_position
        frames.append(position)
    if not frames:
        return initial_positions.new_empty((0, *initial_positions[:, -1].shape))
    return torch.stack(frames)
