"""The ``curve.jsonl`` of a run validated at fixed intervals of training time
(:class:`gnsx.training.curves.CurveValidation`): writing a row, reading the curves back.

``curve.jsonl`` holds one JSON object per line (appended; a resumed run continues it, and
:func:`read_curve` keeps the last row of each kind and step):

- ``{"kind": "baseline", "rollout_mse": ..., "rollout_mse_se": ..., "trajectories": n}``: the physics-free
  baseline on the same validation trajectories (the level a model must beat), written once;
- ``{"kind": "train", "step", "time_s", "samples", "loss"}``: the mean training loss (normalised
  acceleration units, as logged in ``train/loss``) over the steps since the previous row;
- ``{"kind": "val", "step", "time_s", "samples", "rollout_mse", "rollout_mse_se", "onestep_mse",
  "validation_s"}``: the mean over the validation trajectories of the raw network's rollout MSE (position
  units squared, every predicted frame), its standard error over trajectories, and the seconds the
  validation took (not counted as training); since 2026-12-07 also ``area_ratio_final`` (± ``_se``: the
  water's area at the last frame over the truth's) and, in both kinds of row, ``rollout_mse_per_trajectory``
  (the validation split's order), for paired ratios against the baseline.

``time_s`` is training seconds since the run started (a resumed run's earlier fits included), ``samples``
the training samples the weights have seen.
"""

from __future__ import annotations

import json
import math
from pathlib import Path


def append_row(path: str | Path, row: dict) -> None:
    """Append one row (a JSON object on its own line) to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(row) + "\n")


def read_rows(path: str | Path) -> list[dict]:
    """Every row of a ``curve.jsonl`` (none when the file is missing).

    Raises:
        ValueError: naming the file and line of a row that is not JSON.
    """
    path = Path(path)
    if not path.is_file():
        return []
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except ValueError:
            raise ValueError(f"{path}:{number}: not a JSON curve row") from None
    return rows


def read_curve(path: str | Path) -> dict:
    """A ``curve.jsonl`` as ``{"baseline": row | None, "train": [rows], "val": [rows]}``, each list sorted by
    step with one row per step (the last written: a resumed run re-does the steps after its checkpoint)."""
    rows = read_rows(path)
    out: dict = {"baseline": None, "train": [], "val": []}
    by_step: dict[str, dict[int, dict]] = {"train": {}, "val": {}}
    for row in rows:
        kind = row.get("kind")
        if kind == "baseline":
            out["baseline"] = row
        elif kind in by_step:
            by_step[kind][int(row["step"])] = row
    for kind, rows_by_step in by_step.items():
        out[kind] = [rows_by_step[s] for s in sorted(rows_by_step)]
    return out


def first_time_below(val_rows: list[dict], level: float) -> float | None:
    """Training seconds of the first validation whose rollout MSE is at or below ``level`` (None: never)."""
    for row in val_rows:
        value = row.get("rollout_mse")
        if value is not None and math.isfinite(value) and value <= level:
            return float(row["time_s"])
    return None
