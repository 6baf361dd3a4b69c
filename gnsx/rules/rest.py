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

or when

4. it belongs to a **level pool**: the calm water (slow, no particle within ``radius`` faster than ``speed``)
   fills every column of width ``radius`` from wall to wall, its top surface is level to within ``level``,
   and the lowest calm particle of every column lies within ``radius`` of the floor or of a static particle.

Test 2 is what velocity alone cannot do (docs/culling.md: a block at the top of its arc is slow too, but it
falls at g, so it is not held). Test 3 lets motion spread: a block placed at rest in a corner has a free face
whose particles the model accelerates at about g, so their neighbours are not held and the dam breaks; with
tests 1-2 alone the shipped weights held that block in place (0.06 m/s against the MPM's 2.2). A held particle
wakes as soon as the model predicts a push on it or on a neighbour. The thresholds are fractions of the data's
velocity std and of the gravity the model falls at, so they follow the dataset's units.

Test 4 is hydrostatics, which a local model cannot learn for deep water: a message passes ``radius`` per
message-passing step, so the simplified model (5 steps, R = 0.035 m) sees 0.175 m around a particle, and
water deeper than that cannot know it is supported. In a wall-to-wall block 0.78 m deep (the ``dense_10x``
hard case; the MPM holds it still, 0.15 m/s at most) the shipped weights predict the interior to fall at
0.67-0.97 g (mean of each 8 cm band above 0.18 m; 0.51 g in the lowest band; 2026-12-03, first frame), so
tests 2-3 hold almost none of it and the column collapses to 45% of its area. A level pool from wall to wall
is at rest whatever its depth (every horizontal pressure gradient is zero), so test 4 holds it without asking
the model; it lets go as soon as anything moves near the water: a fast particle wakes the calm ones within
``radius``, their column's calm top drops by about ``radius``, which is more than ``level``, and the whole
pool goes back to tests 1-3. A block placed at rest with a free face (a dam) is not wall to wall, one placed
in the air is not supported, and the truth's settling pools of the ``small`` test split never are calm
throughout (at most 26% of their water is under ``speed`` in frames 149, 174, ..., 249), so test 4 leaves them
to the model. Only in 2D, with gravity along -y (the datasets here); other dimensions skip it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from gnsx.model.neighbors import radius_graph
from gnsx.rules.scale import rules_gravity, rules_radius

#: Speed threshold, as a fraction of the length of the data's velocity std (per frame).
SPEED = 0.03
#: Acceleration threshold, as a fraction of the gravity the model falls at (per frame^2).
ACCELERATION = 0.5
#: A neighbour predicted to accelerate at more than this fraction of g keeps a particle awake (0.7 woke the
#: pool at rest; 1.0 held it and still broke the dam of the ``on_walls`` hard case).
WAKE_ACCELERATION = 1.0
#: Test 4's tolerance on the pool's surface, as a fraction of the radius: the MPM's blocks start level to
#: 0.22-0.24 R (``pool_rest``, ``dense_10x``: highest minus lowest column top), and a woken column drops ~1 R.
LEVEL = 0.5


@dataclass(frozen=True)
class RestHold:
    """Hold slow, unaccelerated particles among calm neighbours.

    Attributes:
        speed: largest current speed held (data units per frame).
        acceleration: largest predicted acceleration held (data units per frame^2).
        wake_acceleration: a neighbour accelerating faster than this (per frame^2) keeps a particle awake.
        radius: neighbourhood radius (data units), the data's connectivity radius
            (:func:`~gnsx.rules.scale.rules_radius`).
        level: test 4's tolerance on a pool's surface (data units); ``None`` skips test 4.
        walls: ``(left, right)`` x of the box's walls and ``floor`` its lower y (data units), for test 4.
    """

    speed: float
    acceleration: float
    wake_acceleration: float
    radius: float
    level: float | None = None
    walls: tuple[float, float] = (0.0, 1.0)
    floor: float = 0.0

    @classmethod
    def for_simulator(
        cls,
        simulator,
        speed: float = SPEED,
        acceleration: float = ACCELERATION,
        wake_acceleration: float = WAKE_ACCELERATION,
        level: float | None = LEVEL,
    ) -> RestHold:
        """Thresholds from the model's data statistics: ``speed * |vel_std|`` and ``acceleration * |g|``, with
        ``g`` the data's gravity (:func:`gnsx.rules.scale.rules_gravity`); for a model that records none
        (node-decoder checkpoints before 2026-12-07) ``|acc_std|`` stands in for it. Test 4 (``level``, a
        fraction of the radius; ``None``: off) uses the model's box."""
        vel = float(simulator.vel_std.norm())
        recorded = rules_gravity(simulator)
        gravity = float((simulator.acc_std if recorded is None else recorded).norm())
        radius = rules_radius(simulator)
        bounds = simulator.bounds.double().cpu()
        return cls(
            speed * vel,
            acceleration * gravity,
            wake_acceleration * gravity,
            radius,
            level=None if level is None else level * radius,
            walls=(float(bounds[0, 0]), float(bounds[0, 1])),
            floor=float(bounds[-1, 0]),
        )

    def apply(
        self, window: Tensor, next_position: Tensor, moves: Tensor, static: Tensor | None = None
    ) -> Tensor:
        """``next_position`` ``[N, D]`` with the held particles of ``moves`` ``[N]`` (bool) at their current
        position; ``window`` ``[N, F, D]`` (F >= 2) the model's input frames, oldest first; ``static``
        ``[N]`` (bool) the static particles that can support a pool (test 4; ``None``: the floor alone)."""
        current = window[:, -1]
        velocity = current - window[:, -2]
        acceleration = next_position - current - velocity
        slow = velocity.norm(dim=-1) <= self.speed
        magnitude = acceleration.norm(dim=-1)
        hold = moves & slow & (magnitude <= self.acceleration)
        graph = None
        if bool(hold.any()):
            # Test 3: a restless neighbour (moving, or accelerating past wake_acceleration) wakes a particle.
            restless = moves & ~(slow & (magnitude <= self.wake_acceleration))
            graph = radius_graph(current, self.radius)
            hold = hold & ~_marked(graph, restless)
        candidates = moves & slow
        if (
            self.level is not None
            and current.shape[-1] == 2
            and bool(candidates.any())
            and _fills_every_column(current[candidates, 0], self)  # cheap: no graph for falling water
        ):
            # Test 4: any fast particle (a static obstacle that moves too) wakes the calm water around it.
            graph = radius_graph(current, self.radius) if graph is None else graph
            calm = candidates & ~_marked(graph, ~slow)
            supports = _marked(graph, static) if static is not None else torch.zeros_like(calm)
            if level_pool(current, calm, supports, self):
                hold = hold | calm
        return torch.where(hold[:, None], current, next_position)


def _marked(graph: Tensor, mark: Tensor) -> Tensor:
    """``[N]`` bool: the particles with a neighbour (``graph`` ``[2, E]``, sender -> receiver) in ``mark``."""
    senders, receivers = graph
    return torch.zeros_like(mark).index_fill_(0, receivers[mark[senders]], True)


def _columns(x: Tensor, hold: RestHold) -> tuple[Tensor, int]:
    """Test 4's column (``[M]`` int64) of each x (``[M]``, data units) and the number of columns: the box
    between ``hold.walls`` cut into equal columns at least ``hold.radius`` wide."""
    left, right = hold.walls
    columns = max(int((right - left) // hold.radius), 1)
    column = ((x.double() - left) / (right - left) * columns).floor().long().clamp(0, columns - 1)
    return column, columns


def _fills_every_column(x: Tensor, hold: RestHold) -> bool:
    """Whether particles at x (``[M]``) lie in every column of :func:`_columns`: necessary for test 4."""
    column, columns = _columns(x, hold)
    return _covers(column, columns)


def _covers(column: Tensor, columns: int) -> bool:
    return bool((torch.bincount(column, minlength=columns) > 0).all())


def level_pool(position: Tensor, calm: Tensor, supported: Tensor, hold: RestHold) -> bool:
    """Test 4 of :class:`RestHold`: whether the ``calm`` particles (``[N]`` bool of ``position`` ``[N, 2]``)
    form a supported pool with a level surface from wall to wall.

    The box between ``hold.walls`` is cut into columns at least ``hold.radius`` wide; every column must hold
    calm water, the highest calm particle of every column must lie within ``hold.level`` of every other
    column's, and the lowest one within ``hold.radius`` of ``hold.floor`` or be ``supported`` (``[N]`` bool: a
    static neighbour). Water above a gap in a column is not looked for (a slab at rest over a pool).
    """
    x, y = position[calm, 0].double(), position[calm, 1].double()
    column, columns = _columns(x, hold)
    if not _covers(column, columns):
        return False
    device = x.device
    top = torch.full((columns,), -math.inf, dtype=torch.float64, device=device)
    top = top.scatter_reduce(0, column, y, "amax")
    if float(top.max() - top.min()) > hold.level:
        return False
    bottom = torch.full_like(top, math.inf).scatter_reduce(0, column, y, "amin")
    on_floor = bottom - hold.floor <= hold.radius
    # A column resting on a ramp: its lowest calm particle touches a static one.
    lowest = y == bottom[column]
    on_static = torch.zeros(columns, dtype=torch.bool, device=device)
    on_static = on_static.index_fill_(0, column[lowest & supported[calm]], True)
    return bool((on_floor | on_static).all())
