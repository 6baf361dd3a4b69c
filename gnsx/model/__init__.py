"""The GNS model family: neighbour search, features, noise, graph network, simulator and rollout.

The paper's simplified GNS and DeepMind's original GNS are two configurations of :class:`LearnedSimulator`
(see :mod:`gnsx.model.simulator` for the table of arguments; :mod:`gnsx.model.registry` names them).
:func:`rollout` is the one rollout loop every tool uses; the walls and ramps (:mod:`~gnsx.model.boundary`) act
inside it, and the layer above, the simulator's opt-in rules (:mod:`gnsx.rules`), plugs into it through its
``constraints`` and ``predict`` arguments; the model never imports the rules.
:mod:`gnsx.model.checkpoint` reads a trained simulator back from a Lightning checkpoint file without Lightning.
"""

from gnsx.model.graph_network import MLP, EncodeProcessDecode, InteractionNetwork
from gnsx.model.neighbors import radius_graph
from gnsx.model.noise import random_walk_noise
from gnsx.model.rollout import physics_free_baseline, rollout
from gnsx.model.simulator import LearnedSimulator

__all__ = [
    "MLP",
    "EncodeProcessDecode",
    "InteractionNetwork",
    "LearnedSimulator",
    "physics_free_baseline",
    "radius_graph",
    "random_walk_noise",
    "rollout",
]
