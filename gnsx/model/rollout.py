"""Autoregressive rollouts: the learned simulator fed its own predictions, and the physics-free baseline.

Both apply the same :class:`gnsx.model.boundary.Boundary` to every step (box walls, static segments), so a
rollout never leaves the box or tunnels through a ramp, and the model is scored against a baseline held to the
same walls. ``constrain=False`` gives the raw model (what it would do on its own).

:func:`rollout` is the one rollout loop of gnsx. Two optional arguments let a layer above change a step
without a loop of its own: ``predict`` replaces the model's step (:data:`Predict`), and ``constraints``
correct its prediction before the boundary (:data:`Constraint`). The model layer defines neither; the
simulator's hand-written rules (:mod:`gnsx.rules`: free flight, the rest hold, the density limit, and the
approximate freezing of water at rest) come in through them. The baseline gets no constraints: with them,
constant velocity plus gravity would be a position-based fluid solver, not physics-free."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor
from tqdm import tqdm

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.model.boundary import Boundary
from gnsx.model.simulator import LearnedSimulator

#: The model's step: ``predict(window, particle_type) -> next_position``, with ``window`` ``[N, F, D]`` the
#: input frames (oldest first), ``particle_type`` ``[N]`` int64 and ``next_position`` ``[N, D]`` (data units);
#: static particles keep their most recent position. Default: :meth:`LearnedSimulator.predict_positions`.
Predict = Callable[[Tensor, Tensor], Tensor]
#: A correction of one step's prediction: ``constraint(window, next_position, moves) -> (next_position,
#: moves)``. ``window`` ``[N, F, D]`` is the step's input, ``next_position`` ``[N, D]`` the positions so far
#: (the model's, corrected by the constraints before this one), ``moves`` ``[N]`` bool the particles this
#: constraint may move (the dynamic ones, less those an earlier constraint has taken over). It returns the
#: corrected positions and the particles the constraints after it may move.
Constraint = Callable[[Tensor, Tensor, Tensor], tuple[Tensor, Tensor]]


@torch.inference_mode()
def rollout(
    simulator: LearnedSimulator,
    initial_positions: Tensor,
    particle_type: Tensor,
    num_steps: int,
    static_positions: Tensor | None = None,
    progress: bool = False,
    constrain: bool = True,
    constraints: Sequence[Constraint] = (),
    predict: Predict | None = None,
) -> Tensor:
    """Predict ``num_steps`` frames by feeding each prediction back as input.

    Each step: the model's next positions (``predict``), the static particles' given positions, the
    ``constraints`` in order, and last the :class:`Boundary`.

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
        constrain: apply the ``constraints`` and the scene's :class:`Boundary` (the model's box, segments
            between the static particles of the last input frame) to every predicted frame; ``False``: the
            raw model.
        constraints: with ``constrain``, corrections of each step's prediction before the boundary
            (:data:`Constraint`; :func:`gnsx.rules.rollout.constraints` builds the simulator's rules). Empty
            (default): the network held by the walls and ramps alone.
        predict: the model's step (:data:`Predict`); ``None``: ``simulator.predict_positions``. Applies with
            or without ``constrain`` (e.g. :class:`gnsx.rules.freezing.Freezing`'s step).

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
    constraints = tuple(constraints) if constrain else ()
    predict = simulator.predict_positions if predict is None else predict
    window = initial_positions
    predictions = []
    for step in tqdm(range(num_steps), desc="rollout", disable=not progress):
        next_position = predict(window, particle_type)  # static held at window[:, -1]
        if static_positions is not None:
            next_position = torch.where(static, static_positions[step], next_position)
        moves = dynamic
        for constraint in constraints:
            next_position, moves = constraint(window, next_position, moves)
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
