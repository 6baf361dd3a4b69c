"""Which of the simulator's rules hold a model's rollout, besides the walls and ramps.

A learned model predicts accelerations; the rollout loop (:func:`gnsx.model.rollout.rollout`) then applies,
each step and in this order, rules that are the simulator's, not learned (their steps:
:func:`gnsx.rules.rollout.constraints`):

==================  ===========================================  =============================================
field               rule                                         module
==================  ===========================================  =============================================
``free_flight``     a free rigid cluster of water falls at g     :class:`gnsx.rules.freeflight.FreeFlight`
``hold_rest``       water at rest stays at rest                  :class:`gnsx.rules.rest.RestHold`
``level_pool``      a level pool from wall to wall is at rest    :class:`gnsx.rules.rest.RestHold`, test 4
``incompressible``  water does not compress                      :class:`gnsx.rules.density.DensityLimit`
==================  ===========================================  =============================================

and last the walls and ramps (:class:`gnsx.model.boundary.Boundary`, the model's), switched by the rollout's
own ``constrain`` (``False``: the network alone, not even the walls).

**Every rule is off by default**: a figure of gnsx measures the network (with the walls and ramps, the
scene's geometry, which hold the MPM's particles too). The rules are a production mode for users who want
game-style stability, one switch for the whole set: ``rules=production`` (the Hydra config group
``conf/rules/``; :meth:`Rules.production`). They were tuned on the small preset and replace what the model
predicts where they act (free flight replaces the model's step by the physics-free baseline's), so a figure
with rules measures the model and the rules together; evaluation prints and records it *beside* the raw
figure, labelled, never instead of it. The physics-free baseline never gets rules, only the boundary.
``results.json`` records the rules of each table it holds.

Approximate freezing (:mod:`gnsx.rules.freezing`) is a rule of the same layer but not one of these switches:
it trades accuracy for speed, is set by a speed (``freeze_speed``) and is measured by
``gnsx.perf.benchmark --freeze-check``, not by the evaluation's tables.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gnsx.core.errors import ConfigError


@dataclass(frozen=True)
class Rules:
    """The switches of the rollout's rules (all off by default: the raw network; see the module docstring)."""

    free_flight: bool = False
    hold_rest: bool = False
    incompressible: bool = False
    #: Test 4 of the rest hold (hydrostatics of deep water); only with ``hold_rest``. Added 2026-12-03.
    level_pool: bool = False

    @classmethod
    def none(cls) -> Rules:
        """Every rule off: the model and the boundary alone (the default)."""
        return cls()

    @classmethod
    def production(cls) -> Rules:
        """Every rule on: the opt-in production mode (``rules=production``)."""
        return cls(free_flight=True, hold_rest=True, incompressible=True, level_pool=True)

    def any(self) -> bool:
        """Whether any rule is on (a table with these rules differs from the raw one)."""
        return any(dataclasses.astuple(self))

    def label(self) -> str:
        """``"raw"`` or ``"with rules (free_flight, hold_rest, ...)"``, for table titles."""
        on = [name for name, value in self.to_dict().items() if value]
        return f"with rules ({', '.join(on)})" if on else "raw"

    def to_dict(self) -> dict[str, bool]:
        return dataclasses.asdict(self)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None, where: str = "rules") -> Rules:
        """Rules from a config block; absent keys keep their default (off).

        Raises:
            ConfigError: an unknown key, or a value that is not a boolean, naming ``where.<key>``.
        """
        values = dict(values or {})
        fields = {f.name for f in dataclasses.fields(cls)}
        for key, value in values.items():
            if key not in fields:
                raise ConfigError(f"{where}.{key}", f"unknown rule; rules are {', '.join(sorted(fields))}")
            if not isinstance(value, bool):
                raise ConfigError(f"{where}.{key}={value}", "must be true or false")
        return cls(**values)

    @classmethod
    def from_config(cls, config: Any, key: str, where: str | None = None) -> Rules:
        """Rules from the block at ``key`` of an OmegaConf config (absent: all off); errors name ``where``
        (default ``key``), e.g. ``rules.hold_rest``."""
        from omegaconf import OmegaConf

        block = OmegaConf.select(config, key, default=None)
        return cls.from_mapping(None if block is None else OmegaConf.to_container(block), where or key)

    @classmethod
    def from_results(cls, results: Mapping[str, Any]) -> Rules:
        """The rules a ``results.json`` was scored with. Files written before the ``rules`` block name
        ``incompressible`` and ``hold_rest`` at the top level, or nothing (the boundary alone); neither had
        free flight, and files before 2026-12-03 no ``level_pool`` (test 4 did not exist: off)."""
        if "rules" in results:
            return cls(**{"level_pool": False, **results["rules"]})
        return cls(
            free_flight=False,
            hold_rest=bool(results.get("hold_rest", False)),
            incompressible=bool(results.get("incompressible", False)),
            level_pool=False,
        )
