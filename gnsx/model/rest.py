"""Water at rest stays at rest: a particle that is slow and that the model barely accelerates, among
neighbours that are calm too, is held.

A learned simulator's prediction for water at rest is small but not zero, and a rollout integrates it: the
shipped weights' pool at rest, wall to wall, sloshes at 38-49x the MPM's speed and drifts 5.6-6.0 cm per 100
frames (docs/hardcases.md). Physics engines stop such creep by putting bodies to sleep; :class:`RestHold` is
that rule for particles, applied to each rollout step before the density limit and the boundary. A dynamic
particle keeps its position (its velocity becomes zero) when

1. its current velocity is at most ``speed`` (data units per frame),
2. its predicted acceleration is at most ``acceleration`` (per frame^2), and
3. no dynamic particle within ``radius`` moves faster than ``speed`` or is predicted to accelerate at more
   than ``wake_acceleration``.

Test 2 is what velocity alone cannot do (docs/culling.md: a block at the top of its arc is slow too, but it
falls at g, so it is not held). Test 3 lets motion spread: a block placed at rest in a corner has a free face
whose particles the model accelerates at about g, so their neighbours are not held and the dam breaks; with
tests 1-2 alone the shipped weights held that block in place (0.06 m/s against the MPM's 2.2). A held particle
wakes as soon as the model predicts a push on it or on a neighbour. The thresholds are fractions of the data's
velocity std and of the gravity the model falls at, so they follow the dataset's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from gnsx.model.neighbors import radius_graph

#: Speed threshold, as a fraction of the length of the data's velocity std (per frame).
SPEED = 0.03
#: Acceleration threshold, as a fraction of the gravity the model falls at (per frame^2).
ACCELERATION = 0.5
#: A neighbour predicted to accelerate at more than this fraction of g keeps a particle awake (0.7 woke the
#: pool at rest; 1.0 held it and still broke the dam of the ``on_walls`` hard case).
WAKE_ACCELERATION = 1.0


@dataclass(frozen=True)
class RestHold:
    """Hold slow, unaccelerated particles among calm neighbours.

    Attributes:
        speed: largest current speed held (data units per frame).
        acceleration: largest predicted acceleration held (data units per frame^2).
        wake_acceleration: a neighbour accelerating faster than this (per frame^2) keeps a particle awake.
        radius: neighbourhood radius (data units), the model's connectivity radius.
    """

    speed: float
    acceleration: float
    wake_acceleration: float
    radius: float

    @classmethod
    def for_simulator(
        cls,
        simulator,
        speed: float = SPEED,
        acceleration: float = ACCELERATION,
        wake_acceleration: float = WAKE_ACCELERATION,
    ) -> RestHold:
        """Thresholds from the model's data statistics: ``speed * |vel_std|`` and ``acceleration * |g|``, with
        ``g`` the gravity the pairwise decoder adds (:attr:`LearnedSimulator.free_fall`); a node-decoder model
        has no gravity of its own, so ``|acc_std|`` stands in for it."""
        vel = float(simulator.vel_std.norm())
        if getattr(simulator, "free_fall", None) is not None:
            gravity = float((simulator.free_fall * simulator.acc_std + simulator.acc_mean).norm())
        else:
            gravity = float(simulator.acc_std.norm())
        radius = float(simulator.rules_radius)
        return cls(speed * vel, acceleration * gravity, wake_acceleration * gravity, radius)

    def apply(self, window: Tensor, next_position: Tensor, moves: Tensor) -> Tensor:
        """``next_position`` ``[N, D]`` with the held particles of ``moves`` ``[N]`` (bool) at their current
        position; ``window`` ``[N, F, D]`` (F >= 2) the model's input frames, oldest first."""
        current = window[:, -1]
        velocity = current - window[:, -2]
        acceleration = next_position - current - velocity
        slow = velocity.norm(dim=-1) <= self.speed
        magnitude = acceleration.norm(dim=-1)
        hold = moves & slow & (magnitude <= self.acceleration)
        if bool(hold.any()):
            # Test 3: a restless neighbour (moving, or accelerating past wake_acceleration) wakes a particle.
            restless = moves & ~(slow & (magnitude <= self.wake_acceleration))
            senders, receivers = radius_graph(current, self.radius)
            woken = torch.zeros_like(hold).index_fill_(0, receivers[restless[senders]], True)
            hold = hold & ~woken
        return torch.where(hold[:, None], current, next_position)
