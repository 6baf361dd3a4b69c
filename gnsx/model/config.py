"""The checks of a :class:`~gnsx.model.simulator.LearnedSimulator`'s configuration, apart from the model so
that the simulator reads as the paper's model: every argument's range, and the choices it names."""

from __future__ import annotations

from typing import Any

from gnsx.model.graph_network import DECODERS
from gnsx.model.neighbors import METHODS

#: Encodings of the material type: one scalar (``type / 8``, the paper's) or a learned embedding (DeepMind's).
TYPE_ENCODINGS = ("scalar", "embedding")


def check_config(cfg: dict[str, Any]) -> None:
    """Check a :class:`~gnsx.model.simulator.LearnedSimulator` config (its ``config`` dict of plain values).

    Raises:
        ValueError: ``LearnedSimulator: <key> must ...`` (the training config checks turn it into the
            ``model.<key>`` override that was wrong).
    """
    dim = cfg["dim"]
    if dim < 1:
        raise ValueError(f"LearnedSimulator: dim must be >= 1, got {dim}")
    if len(cfg["bounds"]) != dim or any(len(pair) != 2 for pair in cfg["bounds"]):
        raise ValueError(f"LearnedSimulator: bounds must be [dim={dim}][2], got {cfg['bounds']}")
    for name in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
        if len(cfg[name]) != dim:
            raise ValueError(f"LearnedSimulator: {name} must have dim={dim} values, got {cfg[name]}")
    for name in ("vel_std", "acc_std"):
        if any(not v > 0 for v in cfg[name]):
            raise ValueError(f"LearnedSimulator: {name} must be > 0, got {cfg[name]}")
    if not cfg["radius"] > 0:
        raise ValueError(f"LearnedSimulator: radius must be > 0, got {cfg['radius']}")
    if cfg["data_radius"] is not None and not cfg["data_radius"] > 0:
        raise ValueError(f"LearnedSimulator: data_radius must be None or > 0, got {cfg['data_radius']}")
    if cfg["history"] < 1:
        raise ValueError(f"LearnedSimulator: history must be >= 1, got {cfg['history']}")
    if cfg["type_encoding"] not in TYPE_ENCODINGS:
        raise ValueError(
            f"LearnedSimulator: type_encoding must be one of {TYPE_ENCODINGS}, got {cfg['type_encoding']!r}"
        )
    if len(cfg["wall_clip"]) != 2 or cfg["wall_clip"][0] > cfg["wall_clip"][1]:
        raise ValueError(f"LearnedSimulator: wall_clip must be (low, high), got {cfg['wall_clip']}")
    if cfg["decoder"] not in DECODERS:
        raise ValueError(f"LearnedSimulator: decoder must be one of {DECODERS}, got {cfg['decoder']!r}")
    if cfg["gravity"] is not None and len(cfg["gravity"]) != dim:
        raise ValueError(f"LearnedSimulator: gravity must have dim={dim} values, got {cfg['gravity']}")
    if cfg["neighbor_search"] not in METHODS:
        raise ValueError(
            f"LearnedSimulator: neighbor_search must be one of {METHODS}, got {cfg['neighbor_search']!r}"
        )
