"""A sweep's report folder read back as its cells, every seed of a cell averaged, and two figure 9 grids side by
side (for :mod:`gnsx.evaluation.report.claims`).

A report folder is what ``python -m gnsx.evaluation.report <sweep> --out DIR`` leaves in ``DIR``:
``results.csv`` (:data:`~gnsx.evaluation.report.tables.COLUMNS`, one row per cell: its lowest seed) and,
when the jobs were copied there, ``jobs/<job>/results.json`` (every seed, with the per-trajectory test rows).
Without ``jobs/`` a cell is its results.csv row alone, with no per-trajectory rows to pair.

A cell with several seeds is their average: ms/frame and MB their mean; rollout MSE their mean with the SE over
seeds (:func:`gnsx.evaluation.spread.mean_se`); per-trajectory rows the geometric mean of the seeds, trajectory
by trajectory, and the baseline ratio the geometric mean over trajectories of baseline / those rows with its 95%
t interval (:func:`gnsx.evaluation.spread.geometric_mean_interval`). Units: rollout MSE in data units^2,
ms per inference frame and that frame's peak MB at WaterRamps size (``bench``), radius in data units.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gnsx.core.errors import DataError
from gnsx.evaluation.report.analysis import cells_against_seeds, ratio_text
from gnsx.evaluation.report.jobs import Job, finite_or_none, load_sweep
from gnsx.evaluation.spread import geometric_mean_interval, mean_se

#: The results.csv columns a grid needs.
GRID_COLUMNS = ("status", "latent_size", "mp_steps", "radius", "rollout_mse", "rollout_mse_se",
                "baseline_ratio", "baseline_ratio_lo", "baseline_ratio_hi", "bench_ms_per_frame",
                "bench_peak_mb", "pareto")  # fmt: skip


class GridInputError(DataError):
    """A report folder without results.csv, or a results.csv without a needed column (one line, both named)."""


def merge_rows(row_lists: Sequence[Sequence[dict]], keys=("rollout_mse", "baseline_mse")) -> list[dict]:
    """Per-trajectory rows holding the geometric mean of each of ``keys`` over ``row_lists``, for the
    trajectories they all hold (by ``trajectory``, else position); empty lists are left out."""
    tables = [{int(r.get("trajectory", i)): r for i, r in enumerate(rows)} for rows in row_lists if rows]
    shared = sorted(set.intersection(*(set(table) for table in tables))) if tables else []
    out = []
    for t in shared:
        values = {k: [finite_or_none(table[t].get(k)) for table in tables] for k in keys}
        kept = {k: v for k, v in values.items() if all(x is not None and x > 0 for x in v)}
        out.append({"trajectory": t, **{k: float(np.exp(np.mean(np.log(v)))) for k, v in kept.items()}})
    return out


@dataclass(eq=False)  # one cell is equal to itself only
class Cell:
    """One (latent_size, mp_steps, radius) cell, its seeds averaged (module docstring): ``row`` its
    results.csv row, ``rows`` its per-trajectory rows, ``mse`` ± ``se`` (over trajectories for one seed, over
    seeds for several), ``baseline`` (baseline / model ratio, low, high), ``ms`` per frame, ``mb`` peak."""

    latent: int
    mp: int
    radius: float | None
    row: dict
    seeds: int
    rows: list[dict]
    mse: float | None
    se: float | None
    baseline: tuple
    ms: float | None
    mb: float | None
    #: The cell's jobs, one per seed (empty when the report folder has no ``jobs/``).
    jobs: tuple = ()

    @property
    def label(self) -> str:
        return f"{self.latent}/{self.mp}"


def _cell(key: tuple, row: dict, jobs: list[Job]) -> Cell:
    rows, n = merge_rows([j.rows for j in jobs]), len(jobs)
    ms = [v for j in jobs if (v := j.ms_per_frame("bench")) is not None]
    mb = [v for j in jobs if (v := j.memory_mb("bench")) is not None]
    ms = float(np.mean(ms)) if ms else finite_or_none(row["bench_ms_per_frame"])
    mb = float(np.mean(mb)) if mb else finite_or_none(row["bench_peak_mb"])
    if n > 1:
        mse, se = mean_se(j.spread("rollout_mse")[0] for j in jobs)
        ratios = [r["baseline_mse"] / r["rollout_mse"] for r in rows if len(r) == 3]  # both keys kept
        return Cell(*key, row, n, rows, mse, se, geometric_mean_interval(ratios)[:3], ms, mb, tuple(jobs))
    baseline = tuple(
        finite_or_none(row[c]) for c in ("baseline_ratio", "baseline_ratio_lo", "baseline_ratio_hi")
    )
    return Cell(
        *key,
        row,
        1,
        rows,
        finite_or_none(row["rollout_mse"]),
        finite_or_none(row["rollout_mse_se"]),
        baseline,
        ms,
        mb,
        tuple(jobs),
    )


@dataclass
class Grid:
    """A report folder: its cells, the files they came from and the F test of its cells against its seeds
    (:func:`~gnsx.evaluation.report.analysis.cells_against_seeds`; None without a cell of several seeds)."""

    path: Path
    cells: list[Cell]
    seed_test: dict | None
    sources: list[str]

    def cell(self, latent: int, mp: int, radius: float | None = None) -> Cell | None:
        match = (c for c in self.cells if (c.latent, c.mp) == (latent, mp) and radius in (None, c.radius))
        return next(match, None)

    @property
    def label(self) -> str:
        """``R=<radius>`` when every cell has one radius, else the folder's name."""
        radii = {c.radius for c in self.cells}
        return f"R={radii.pop():g}" if len(radii) == 1 and None not in radii else self.path.name


def _key(latent, mp, radius) -> tuple:
    return int(float(latent)), int(float(mp)), None if radius is None else round(float(radius), 6)


def load_grid(folder: str | Path) -> Grid:
    """A report folder as a :class:`Grid`; raises :class:`GridInputError` naming the file and column."""
    folder = Path(folder)
    table = folder / "results.csv"
    if not table.is_file():
        raise GridInputError(str(table), "no such file (a report folder holds results.csv)")
    with open(table, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in GRID_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise GridInputError(str(table), f"no column {missing[0]!r} (needed: {', '.join(GRID_COLUMNS)})")
        rows = [r for r in reader if r["status"] == "ok"]
    try:
        every = [j for j in load_sweep(folder / "jobs") if j.ok and j.latent_size and j.mp_steps]
    except FileNotFoundError:  # no jobs/, or no job in it: results.csv alone
        every = []
    seeds: dict[tuple, list[Job]] = {}
    for job in sorted(every, key=lambda j: j.seed or 0):
        seeds.setdefault(_key(job.latent_size, job.mp_steps, job.radius), []).append(job)
    cells = []
    for row in rows:
        key = _key(row["latent_size"], row["mp_steps"], finite_or_none(row["radius"]))
        cells.append(_cell(key, row, seeds.get(key, [])))
    sources = [str(table)] + ([f"{folder / 'jobs'}/*/results.json"] if every else [])
    return Grid(folder, cells, cells_against_seeds(every) if every else None, sources)


# -- side by side ------------------------------------------------------------------------------------------
def grid_labels(grids: Sequence[Grid]) -> list[str]:
    """Each grid's :attr:`Grid.label`, or every grid's path where two labels are the same."""
    labels = [g.label for g in grids]
    return labels if len(set(labels)) == len(labels) else [str(g.path) for g in grids]


def side_by_side(grids: Sequence[Grid]) -> list[dict]:
    """One row per (latent_size, mp_steps) of any grid: ``{"latent_size", "mp_steps", "grids": {label:
    {seeds, mse, se, baseline, ms, mb} or None where the grid lacks the cell}}``, labels of :func:`grid_labels`."""
    fields = ("seeds", "mse", "se", "baseline", "ms", "mb")
    keys = sorted({(c.latent, c.mp) for g in grids for c in g.cells})
    out = []
    for latent, mp in keys:
        cells = {label: g.cell(latent, mp) for label, g in zip(grid_labels(grids), grids)}
        values = {label: c and {f: getattr(c, f) for f in fields} for label, c in cells.items()}
        out.append({"latent_size": latent, "mp_steps": mp, "grids": values})
    return out


def _values(v: dict | None) -> list[str]:
    if v is None:
        return ["-"] * 4
    fmt = lambda x, spec=".1f": format(x, spec) if x else "n/a"
    mse = fmt(v["mse"], ".2e") + (f" ± {v['se']:.1e}" if v["se"] else "")
    mse += f" ({v['seeds']} seeds)" if v["seeds"] > 1 else ""
    return [mse, ratio_text(*v["baseline"]), fmt(v["ms"]), fmt(v["mb"])]


def side_by_side_lines(table: Sequence[dict], labels: Sequence[str]) -> list[str]:
    """:func:`side_by_side` as a markdown table, one block of columns per grid."""
    head = [f"{g}: {h}" for g in labels for h in ("rollout MSE ± se", "x baseline [95%]", "ms/frame", "MB")]
    lines = ["| cell | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
    for row in table:
        values = [v for g in labels for v in _values(row["grids"][g])]
        lines.append(f"| {row['latent_size']}/{row['mp_steps']} | " + " | ".join(values) + " |")
    return lines
