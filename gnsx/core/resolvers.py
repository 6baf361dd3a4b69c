"""The config resolvers gnsx's Hydra configs use, registered with OmegaConf when :mod:`gnsx` is imported.

``${steps_fraction:0.625,${train.max_steps}}``: a point of a schedule as a fraction of the run's length, in whole
steps. Why: a schedule stated in fractions (the paper's lr held to 1.0M of its 1.6M steps, then decayed) keeps
its shape when a run's length changes, as when a study arm of 22,800 steps becomes a 200k long run.
"""

from __future__ import annotations

from omegaconf import OmegaConf


def steps_fraction(fraction: float | str, steps: int | str) -> int:
    """``round(fraction x steps)``: e.g. ``steps_fraction(0.625, 22800) == 14250``."""
    return int(round(float(fraction) * int(steps)))


def register() -> None:
    """Register every resolver (idempotent: a second call replaces the first)."""
    OmegaConf.register_new_resolver("steps_fraction", steps_fraction, replace=True)


register()
