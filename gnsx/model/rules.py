"""Which of the simulator's rules hold a model's rollout, besides the walls and ramps.

A learned model predicts accelerations; the rollout loop (:func:`gnsx.model.rollout.rollout`) then applies,
each step and in this order, rules that are the simulator's, not learned:

==================  ===========================================  =============================================
field               rule                                         module
==================  ===========================================  =============================================
``free_flight``     a free rigid cluster of water falls at g     :class:`gnsx.model.freeflight.FreeFlight`
``hold_rest``       water at rest stays at rest                  :class:`gnsx.model.rest.RestHold`
``level_pool``      a level pool from wall to wall is at rest    :class:`gnsx.model.rest.RestHold`, test 4
``incompressible``  water does not compress                      :class:`gnsx.model.density.DensityLimit`
==================  ===========================================  =============================================

and last the walls and ramps (:class:`gnsx.model.boundary.Boundary`), switched by the rollout's own
``constrain`` (``False``: the raw model, none of these). Every rule is on by default; the physics-free
baseline gets none of them, only the boundary. Configs spell the rules as a block (``rules: {free_flight:
true, hold_rest: true, level_pool: true, incompressible: true}``) and ``results.json`` records the block the
rollouts used.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gnsx.core.errors import ConfigError


@dataclass(frozen=True)
class Rules:
    """The switches of the rollout's rules (all on by default; see the module docstring)."""

    free_flight: bool = True
    hold_rest: bool = True
    incompressible: bool = True
    #: Test 4 of the rest hold (hydrostatics of deep water); only with ``hold_rest``. Added 2026-12-03.
    level_pool: bool = True

    @classmethod
    def none(cls) -> Rules:
        """Every rule off: the model and the boundary alone."""
        return cls(free_flight=False, hold_rest=False, incompressible=False, level_pool=False)

    def to_dict(self) -> dict[str, bool]:
        return dataclasses.asdict(self)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None, where: str = "rules") -> Rules:
        """Rules from a config block; absent keys keep their default (on).

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
        """Rules from the block at ``key`` of an OmegaConf config (absent: all on); errors name ``where``
        (default ``key``), e.g. ``evaluate.rules.hold_rest``."""
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
