"""The simulator's hand-written rules: a layer above the model (``gnsx.model``), below evaluation.

The model layer is the paper's learned simulator and DeepMind's rollout: the network, its features, the
walls and ramps, and one rollout loop (:func:`gnsx.model.rollout.rollout`). The rules are not learned and
are off by default; they plug into that loop through its ``constraints`` and ``predict`` arguments
(:mod:`gnsx.rules.rollout`), so the model never imports them:

* :mod:`~gnsx.rules.rules`: :class:`Rules`, the switches (``rules=production``);
* :mod:`~gnsx.rules.freeflight`: a free rigid cluster of water falls at g;
* :mod:`~gnsx.rules.rest`: water at rest stays at rest (and a level pool from wall to wall);
* :mod:`~gnsx.rules.density`: water does not compress;
* :mod:`~gnsx.rules.freezing`: approximate freezing of water at rest, far from motion (a speed feature with
  an error, unlike the model's exact culling);
* :mod:`~gnsx.rules.scale`: the rules' length scale, the data's connectivity radius;
* :mod:`~gnsx.rules.rollout`: the rules as steps of the model's rollout (:func:`rollout_with_rules`).
"""

from gnsx.rules.freezing import Freezing
from gnsx.rules.rollout import constraints, rollout_with_rules
from gnsx.rules.rules import Rules

__all__ = ["Freezing", "Rules", "constraints", "rollout_with_rules"]
