"""The rules on the model's rollout: each rule as a step of :func:`gnsx.model.rollout.rollout`.

The rollout loop is the model's (:mod:`gnsx.model.rollout`); the rules come in through its two extension
points and add no loop of their own:

* ``constraints`` (after the network, before the walls and ramps), in this order: free flight
  (:class:`~gnsx.rules.freeflight.FreeFlight`: its particles are then left alone by the rules after it), the
  rest hold (:class:`~gnsx.rules.rest.RestHold`), the density limit
  (:class:`~gnsx.rules.density.DensityLimit`);
* ``predict`` (the model's step): approximate freezing (:class:`~gnsx.rules.freezing.Freezing`).
"""

from __future__ import annotations

from torch import Tensor

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.model.rollout import Constraint, rollout
from gnsx.model.simulator import LearnedSimulator
from gnsx.rules.density import DensityLimit
from gnsx.rules.freeflight import FreeFlight
from gnsx.rules.freezing import Freezing
from gnsx.rules.rest import LEVEL, RestHold
from gnsx.rules.rules import Rules
from gnsx.rules.scale import rules_radius


def constraints(
    rules: Rules, simulator: LearnedSimulator, initial_positions: Tensor, particle_type: Tensor
) -> list[Constraint]:
    """The rollout constraints of the rules that are on, for one scene, in the order they apply.

    Args:
        rules: which rules (:class:`Rules`).
        simulator: the model (the rules' thresholds come from its data: :meth:`FreeFlight.for_simulator`,
            :meth:`RestHold.for_simulator`, :func:`rules_radius`).
        initial_positions: ``[N, F, D]`` the rollout's input frames, oldest first; the density limit takes
            the scene's rest density from the oldest.
        particle_type: ``[N]`` int64.
    Returns:
        :data:`gnsx.model.rollout.Constraint` callables; empty when no rule is on. Free flight is left out
        for a node-decoder model (no gravity of its own), the density limit for a scene of fewer than two
        water particles.
    """
    static = particle_type == KINEMATIC_PARTICLE_ID  # [N]
    dynamic = ~static
    steps: list[Constraint] = []
    flight = FreeFlight.for_simulator(simulator) if rules.free_flight else None
    if flight is not None:

        def free_flight(window: Tensor, next_position: Tensor, moves: Tensor) -> tuple[Tensor, Tensor]:
            next_position, free = flight.apply(window, next_position, particle_type)
            return next_position, moves & ~free  # the rules after it leave free clusters alone

        steps.append(free_flight)
    if rules.hold_rest:
        rest = RestHold.for_simulator(simulator, level=LEVEL if rules.level_pool else None)

        def hold_rest(window: Tensor, next_position: Tensor, moves: Tensor) -> tuple[Tensor, Tensor]:
            return rest.apply(window, next_position, moves, static), moves

        steps.append(hold_rest)
    limit = None
    if rules.incompressible:
        limit = DensityLimit.from_particles(initial_positions[:, 0], particle_type, rules_radius(simulator))
    if limit is not None:

        def incompressible(window: Tensor, next_position: Tensor, moves: Tensor) -> tuple[Tensor, Tensor]:
            allowed = limit.allowed_density(window[:, -1], dynamic)  # no water pushed below its last density
            return limit.apply(next_position, moves, allowed), moves

        steps.append(incompressible)
    return steps


def rollout_with_rules(
    simulator: LearnedSimulator,
    initial_positions: Tensor,
    particle_type: Tensor,
    num_steps: int,
    rules: Rules | None = None,
    freeze_speed: float | None = None,
    *,
    static_positions: Tensor | None = None,
    progress: bool = False,
    constrain: bool = True,
) -> Tensor:
    """:func:`gnsx.model.rollout.rollout` with the simulator's rules: ``[num_steps, N, D]`` positions.

    Args:
        simulator, initial_positions, particle_type, num_steps, static_positions, progress: as
            :func:`~gnsx.model.rollout.rollout`.
        rules: the rules after the network (:class:`Rules`); ``None``: none (the raw network held by the walls
            and ramps).
        freeze_speed: approximate freezing at this speed (:class:`Freezing`, data units per frame); ``None``:
            off.
        constrain: the rules and the walls and ramps; ``False``: the raw model (freezing still applies: it is
            the model's step).
    """
    rules = rules or Rules.none()
    steps = constraints(rules, simulator, initial_positions, particle_type) if constrain else []
    freezing = None if freeze_speed is None else Freezing(simulator, freeze_speed)
    return rollout(
        simulator,
        initial_positions,
        particle_type,
        num_steps,
        static_positions=static_positions,
        progress=progress,
        constrain=constrain,
        constraints=steps,
        predict=None if freezing is None else freezing.predict_positions,
    )
