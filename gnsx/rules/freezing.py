"""Approximate freezing: water at rest, far from anything that moves, is held like a static particle and not
decoded.

Exact culling (:mod:`gnsx.model.culling`) skips the work that cannot change a prediction; freezing goes
further and skips predictions that are merely small. A dynamic particle is *frozen* for one step when

1. it is at rest: every velocity of its input window (per-frame position differences) is at most ``speed``
   long (data units per frame), and
2. its neighbourhood rests: no dynamic particle that is not at rest lies within
   :attr:`~gnsx.model.simulator.LearnedSimulator.hops` hops of it in the radius graph (the model's
   receptive field).

A frozen particle keeps its most recent position; only the others are decoded (so, with culling, only their
neighbourhoods are computed) and integrated. The approximation: the frozen particle's own predicted motion,
small while its neighbourhood rests, is dropped. A frozen particle's velocity becomes 0, so it stays frozen
until a moving particle comes within that many hops. Measured error and its failure case (a block frozen at
the top of its arc) are in ``docs/culling.md``; ``python -m gnsx.perf.benchmark --freeze-check`` measures it.

Off by default and opt-in (a speed, ``freeze_speed``): it changes the results, unlike culling, so it is a rule
of the rollout, not a switch of the model. It acts on the model's step, before the network
(:func:`gnsx.model.rollout.rollout`'s ``predict``), where the other rules act after it.
"""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.model.culling import hop_distance
from gnsx.model.features import velocity_sequence
from gnsx.model.neighbors import radius_graph
from gnsx.model.simulator import LearnedSimulator


@dataclass(frozen=True)
class Freezing:
    """Freezing of particles at rest for one simulator (module docstring).

    Attributes:
        simulator: the model whose steps are frozen in part (its radius graph and receptive field are used).
        speed: largest speed of a particle at rest, data units per frame (> 0).
    """

    simulator: LearnedSimulator
    speed: float

    def __post_init__(self) -> None:
        if not self.speed > 0:
            raise ValueError(f"freeze_speed must be > 0, got {self.speed}")

    def frozen_particles(
        self,
        position_sequence: Tensor,
        particle_type: Tensor,
        batch: Tensor | None = None,
        edge_index: Tensor | None = None,
    ) -> Tensor:
        """Dynamic particles at rest in a resting neighbourhood, ``[N]`` bool.

        Args:
            position_sequence: ``[N, history + 1, D]`` positions, oldest first (data units).
            particle_type: ``[N]`` int64; batch: ``[N]`` graph ids or ``None``.
            edge_index: the radius graph ``[2, E]`` of the most recent positions when already built (self
                edges or not: they change no hop distance).
        """
        simulator = self.simulator
        dynamic = particle_type != KINEMATIC_PARTICLE_ID
        if edge_index is None:
            edge_index = radius_graph(
                position_sequence[:, -1], simulator.radius, batch, method=simulator.neighbor_search
            )
        speed = velocity_sequence(position_sequence).norm(dim=-1).amax(dim=1)  # [N]
        resting = dynamic & (speed <= self.speed)
        steps = simulator.hops
        return resting & (hop_distance(edge_index, dynamic & ~resting, steps) > steps)

    def predict_positions(
        self, position_sequence: Tensor, particle_type: Tensor, batch: Tensor | None = None
    ) -> Tensor:
        """Next positions ``[N, D]``: :meth:`LearnedSimulator.predict_positions` with the frozen particles
        held at their most recent position and left out of the decoding. The freeze test needs the whole
        graph, so it is built once, for the test and the network."""
        graph = self.simulator.build_graph(position_sequence, particle_type, batch)
        frozen = self.frozen_particles(position_sequence, particle_type, edge_index=graph[1])
        return self.simulator.predict_positions(
            position_sequence, particle_type, batch, held=frozen, graph=graph
        )
