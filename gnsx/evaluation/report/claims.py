"""The paper's claims on figure 9, the radius and the simplified model, each judged by a written rule, and two
figure 9 grids side by side.

    python -m gnsx.evaluation.report.claims --grid docs/fig9/radius_0.035 [--compare GRID] \\
        [--radius docs/radius] [--versus docs/original-vs-simplified] --out DIR

Writes ``DIR/claims.md`` and ``DIR/claims.json`` and prints the markdown. ``--grid``, ``--compare`` and
``--radius`` are report folders of ``python -m gnsx.evaluation.report`` (read by :mod:`.cells`: results.csv
and, when present, every seed's ``jobs/<job>/results.json``); ``--versus`` holds the ``versus.json`` of
``python -m gnsx.evaluation.report.versus``. An input left out or absent makes its claim "not measured", with
the reason; a file without a needed column or field stops the tool with one line naming both. Units: rollout
MSE in data units^2; speed in ms per inference frame at WaterRamps size; memory in MB (that frame's peak);
radius in data units.

Verdicts ("reproduced", "not reproduced", "cannot be told at this budget"), decided by these rules only:

* Errors of two cells: paired over the test trajectories (:func:`gnsx.evaluation.spread.compare`: geometric
  mean of the per-trajectory ratio, 95% t interval); a cell with several seeds enters as the per-trajectory
  geometric mean of its seeds. An interval containing 1 tells nothing apart.
* Seed gate: those intervals hold the trajectories' scatter, not retraining's. Where a grid's F test of cells
  against seeds (:func:`.analysis.cells_against_seeds`) gives p >= 0.05, retraining moves a cell as much as the
  cells differ, and a verdict drawn from its cells' errors (1-4; 7's error parts) becomes "cannot be told";
  the text then says how many seeds per cell would rank the cells with 80% power
  (:func:`.analysis.seeds_for_power`).
* 1: not reproduced when a cell faster than 64/5 beyond the timing tolerance (its ms/frame x 1.15 at most
  64/5's) has a lower error beyond the interval; else reproduced when 64/5 is on the Pareto front of seed-mean
  ms/frame against seed-mean rollout MSE (:func:`.analysis.pareto_front`); else cannot be told.
* 2, 3: 16 (128) against 64 at each MP count both have; n_for: the counts where the claimed side (16 worse, 128
  better) holds beyond the interval, n_against: the opposite. Reproduced when n_for is over half the counts
  and n_against is 0; not reproduced when n_against > n_for; else cannot be told.
* 4: per trajectory, the geometric mean over MP 1-3 and the widths present at every MP count, against the same
  over MP 5-10: reproduced when the ratio 1-3 / 5-10 lies above 1, not reproduced below 1, else cannot be told.
* 5: each width's ms/frame over their mean, fitted with each width's own intercept and slope in MP steps and
  one shared quadratic term; that term's share of the cost at the largest MP count [95%]: reproduced when the
  interval lies within +-10% (the claim is an absence, so the interval must rule a relevant curvature out; 10%
  is above the retime's ~4% spread), not reproduced when it lies wholly outside, else cannot be told.
* 6: least squares of log2 peak MB on log2 width over the cells, the MB ratio per doubling [95%]: reproduced
  above 1, not reproduced when at most 1, else cannot be told.
* 7 (``--radius``, 64/5 cells; WaterRamps radii x preset / 0.015): helps: R(0.020) against R(0.014), reproduced
  when lower, not when higher beyond the interval; confuses: each radius above R(0.020) x 1.05 against R(0.020),
  reproduced when higher, not when lower; slows: its ms/frame ratio, reproduced at 1.15 or more (the timing
  tolerance), not reproduced at 1 or less, else cannot be told.
* 8 (``--versus``): quality: simplified / original rollout MSE, paired, reproduced below 1, not above, else
  cannot be told; speed, memory: original / simplified (no interval recorded) against the paper's 2.3x and 3.3x,
  reproduced at the paper's or more, not reproduced at the paper's / 1.15 or less, else cannot be told.
* 9 (training time; the paper: 12 h for the simplified model against 36 h for the original): 128/10's hours
  to its final error over 64/5's (seed means; no interval), reproduced at 3x or more, not reproduced at 3x /
  1.15 or less, else cannot be told. A run's hours to its final error: the training clock (validation
  excluded) at its first validation whose rollout MSE is within :data:`FINAL_MARGIN` of its last one's
  (``curve.jsonl``); a run without a curve counts its whole training clock (``training_s``). When 64/5 ends
  worse than 128/10 beyond the paired interval, a "reproduced" becomes "cannot be told" (its shorter time was
  not to the same error).
* A claim in parts: not reproduced when any part is, reproduced when all are, else cannot be told.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import stats

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.core.errors import DataError
from gnsx.evaluation.curve_file import read_curve
from gnsx.evaluation.report.analysis import pareto_front, ratio_text, seeds_for_power
from gnsx.evaluation.report.cells import (
    Cell,
    Grid,
    grid_labels,
    load_grid,
    merge_rows,
    side_by_side,
    side_by_side_lines,
)
from gnsx.evaluation.spread import compare, interval_contains_one

REPRODUCED, NOT_REPRODUCED, UNTOLD = "reproduced", "not reproduced", "cannot be told at this budget"
NOT_MEASURED = "not measured"
PAPER_CELL = (64, 5)
TIMING_TOLERANCE = 1.15  #: time (or memory) ratio within which two figures are not told apart
LINEAR_MARGIN = 0.10  #: the curvature's largest share of the cost for the cost to count as linear
PAPER_SPEEDUP, PAPER_MEMORY = 2.3, 3.3  #: the paper's original / simplified time and memory per frame
WATERRAMPS_RADIUS = 0.015  #: DeepMind's WaterRamps connection radius (data units)
PAPER_TRAINING = 3.0  #: the paper's original / simplified training time (36 h / 12 h)
FINAL_MARGIN = 1.10  #: a validation within 10% of the run's last one has reached its final error
ORIGINAL_CELL = (128, 10)  #: the grid's cell with the original GNS's width and depth
CLAIMS = {
    1: "The 64/5 model (embedding size 64, 5 message-passing steps) sits on the Pareto front of speed "
       "against error.",
    2: "An embedding size of 16 is too small.",
    3: "An embedding size of 128 is needed to replicate the ground truth perfectly.",
    4: "1-3 message-passing steps are too restrictive; 5-10 give good results.",
    5: "Inference cost grows linearly with the number of message-passing steps.",
    6: "Memory grows with the embedding size.",
    7: "A radius of 0.014-0.020 (WaterRamps) helps; a larger one confuses the model and dramatically slows it.",
    8: "The simplified model keeps the original's quality with 2.3x faster inference and 3.3x less memory.",
    9: "The simplified model trains in about 3x less time than the original (12 h against 36 h).",
}  # fmt: skip


class ClaimsInputError(DataError):
    """An input file lacks a field the claims need (one line naming both)."""


# -- verdicts ------------------------------------------------------------------------------------------------
def _side(result: dict | None) -> int:
    """+1 when a ratio's interval lies above 1, -1 below, 0 when it contains 1 (or is unknown)."""
    if result is None or interval_contains_one(result["lo"], result["hi"]):
        return 0
    return 1 if result["lo"] > 1 else -1


def _verdict(side: int, claimed: int) -> str:
    return UNTOLD if side == 0 else REPRODUCED if side == claimed else NOT_REPRODUCED


def _factor(measured: float, claimed: float) -> str:
    """A figure without an interval: reproduced at ``claimed`` or more, not reproduced at ``claimed`` /
    :data:`TIMING_TOLERANCE` or less, else cannot be told."""
    if measured >= claimed:
        return REPRODUCED
    return NOT_REPRODUCED if measured * TIMING_TOLERANCE <= claimed else UNTOLD


def _combine(verdicts: Sequence[str]) -> str:
    if all(v == NOT_MEASURED for v in verdicts):
        return NOT_MEASURED
    if NOT_REPRODUCED in verdicts:
        return NOT_REPRODUCED
    return REPRODUCED if set(verdicts) == {REPRODUCED} else UNTOLD


def _paired(a: Cell, b: Cell) -> dict | None:
    """:func:`compare` of b with a (b's rollout MSE over a's); None below 2 shared trajectories."""
    result = compare(a.rows, b.rows, "rollout_mse")
    return result if result["trajectories"] >= 2 else None


def _x(result: dict | None) -> str:
    return ratio_text(result["ratio"], result["lo"], result["hi"]) if result else "n/a (no rows)"


def _gate(verdict: str, grid: Grid) -> tuple[str, str]:
    """The seed gate of the module docstring: (verdict, the sentence saying why)."""
    test = grid.seed_test
    if test is None:
        return verdict, "No cell has several seeds: the intervals hold the trajectories' scatter only."
    text = f"Cells against seeds: F({test['df_cells']}, {test['df_seeds']}) = {test['F']:.2f}, p = {test['p']:.2g}"
    if test["p"] >= 0.05:
        seeds = seeds_for_power(test)
        text += (f" (seed sd {test['sd_seeds']:.3f}, cells' {test['sd_cells']:.3f} in log10 error; "
                 + (f"{seeds} seeds per cell would rank them with 80% power)" if seeds else
                    "no number of seeds up to 20 would rank them at these estimates)"))  # fmt: skip
    if test["p"] >= 0.05 and verdict in (REPRODUCED, NOT_REPRODUCED):
        return (
            UNTOLD,
            f"{text}: retraining moves a cell as much as the cells differ (paired alone: {verdict}).",
        )
    return verdict, text + "."


def _row(number: int, verdict: str, measurement: str, sources: Sequence[str]) -> dict:
    return {"number": number, "claim": CLAIMS[number], "measurement": measurement, "from": list(sources),
            "verdict": verdict}  # fmt: skip


# -- the claims ----------------------------------------------------------------------------------------------
def claim_pareto(grid: Grid) -> dict:
    ref, cells = grid.cell(*PAPER_CELL), [c for c in grid.cells if c.ms and c.mse]
    if ref not in cells:  # Cells compare by identity
        return _row(1, NOT_MEASURED, "no timed 64/5 cell in the grid", grid.sources)
    front = [cells[i] for i in pareto_front([(c.ms, c.mse) for c in cells])]
    faster = [(c, _paired(ref, c)) for c in cells if c.ms * TIMING_TOLERANCE <= ref.ms]
    beating = [f"{c.label} ({c.ms:.1f} ms, error {_x(r)})" for c, r in faster if _side(r) < 0]
    verdict, why = _gate(NOT_REPRODUCED if beating else REPRODUCED if ref in front else UNTOLD, grid)
    csv_front = ", ".join(c.label for c in grid.cells if c.row["pareto"] == "True") or "none"
    text = (f"Front (seed means): {', '.join(c.label for c in front)}; 64/5 is {'on' if ref in front else 'off'}"
            f" it ({ref.ms:.1f} ms/frame, rollout MSE {ref.mse:.2e}). Faster by 15%+ with a lower error beyond"
            f" the paired interval: {'; '.join(beating) or 'none'}. results.csv `pareto` (lowest seeds): "
            f"{csv_front}. {why}")  # fmt: skip
    return _row(1, verdict, text, grid.sources)


def claim_width(grid: Grid, number: int, width: int, claimed: int) -> dict:
    """Claims 2 (width 16, claimed +1: its error over 64's above 1) and 3 (width 128, claimed -1)."""
    pairs = [(c, o) for c in grid.cells if c.latent == 64 and (o := grid.cell(width, c.mp, c.radius))]
    results = [(c, o, r) for c, o in sorted(pairs, key=lambda p: p[0].mp) if (r := _paired(c, o))]
    if not results:
        why = f"no {width}/m and 64/m cells with per-trajectory rows"
        return _row(number, NOT_MEASURED, why, grid.sources)
    sides = [_side(r) for *_, r in results]
    n_for, n_against = sides.count(claimed), sides.count(-claimed)
    verdict = (REPRODUCED if 2 * n_for > len(sides) and n_against == 0 else
               NOT_REPRODUCED if n_against > n_for else UNTOLD)  # fmt: skip
    verdict, why = _gate(verdict, grid)
    text = (f"Rollout MSE, paired: {'; '.join(f'{o.label} / {c.label} {_x(r)}' for c, o, r in results)}. "
            f"{width} {'worse' if claimed > 0 else 'better'} beyond the interval at {n_for} of {len(sides)} MP "
            f"counts, the opposite at {n_against}. {why}")  # fmt: skip
    return _row(number, verdict, text, grid.sources)


def claim_depth(grid: Grid) -> dict:
    mps = sorted({c.mp for c in grid.cells})
    widths = [w for w in sorted({c.latent for c in grid.cells}) if all(grid.cell(w, m) for m in mps)]
    by_mp = {m: merge_rows([grid.cell(w, m).rows for w in widths], ("rollout_mse",)) for m in mps}
    low = merge_rows([by_mp[m] for m in mps if m <= 3], ("rollout_mse",))
    high = merge_rows([by_mp[m] for m in mps if 5 <= m <= 10], ("rollout_mse",))
    result = compare(high, low, "rollout_mse")
    if result["trajectories"] < 2:
        return _row(4, NOT_MEASURED, "needs per-trajectory rows at MP 1-3 and 5-10", grid.sources)
    verdict, why = _gate(_verdict(_side(result), +1), grid)
    each = "; ".join(f"{m}: {_x(compare(by_mp[5], by_mp[m]))}" for m in mps if m != 5) if 5 in mps else "n/a"
    text = (
        f"Geometric mean over widths {', '.join(map(str, widths))}: rollout MSE at MP 1-3 / MP 5-10 "
        f"{_x(result)} (paired, {result['trajectories']} trajectories); each MP count / MP 5: {each}. {why}"
    )
    return _row(4, verdict, text, grid.sources)


def claim_linear_cost(grid: Grid) -> dict:
    timed: dict[int, list] = {}
    for c in grid.cells:
        timed.setdefault(c.latent, []).extend([(c.mp, c.ms)] if c.ms else [])
    timed = {w: sorted(p) for w, p in sorted(timed.items()) if len({m for m, _ in p}) >= 3}
    df = sum(map(len, timed.values())) - 2 * len(timed) - 1
    if df < 1:
        return _row(5, NOT_MEASURED, "needs 3+ timed MP counts at one width or more", grid.sources)
    design, target, fits = [], [], []
    for k, (w, points) in enumerate(timed.items()):
        m, ms = np.array(points, dtype=float).T
        fit = stats.linregress(m, ms)
        fits.append(f"{w}: {fit.slope:.2f} ms/step + {fit.intercept:.1f} ms, R^2 {fit.rvalue**2:.4f}, "
                    f"intercept {fit.intercept / (fit.intercept + 5 * fit.slope):.0%} of 5 steps")  # fmt: skip
        for mp, y in points:  # columns: each width's intercept and slope, then the shared mp^2
            design.append(
                [float(j // 2 == k) * (mp if j % 2 else 1) for j in range(2 * len(timed))] + [mp**2]
            )
            target.append(y / ms.mean())
    design, target = np.array(design), np.array(target)
    beta, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = target - design @ beta
    se = math.sqrt(float(residual @ residual) / df * np.linalg.inv(design.T @ design)[-1, -1])
    top = max(m for p in timed.values() for m, _ in p)
    cost = np.mean([t for t, row in zip(target, design) if row[-1] == top**2]) / top**2  # at top, per top^2
    share, half = beta[-1] / cost, stats.t.ppf(0.975, df) * se / cost
    lo, hi = share - half, share + half
    verdict = (REPRODUCED if -LINEAR_MARGIN <= lo and hi <= LINEAR_MARGIN else
               NOT_REPRODUCED if hi < -LINEAR_MARGIN or lo > LINEAR_MARGIN else UNTOLD)  # fmt: skip
    text = (f"Bench ms/frame against MP steps, per width: {'; '.join(fits)}. The quadratic term's share of the "
            f"cost at {top} steps: {share:+.1%} [{lo:+.1%}, {hi:+.1%}] (95%, {df} df; linear: within "
            f"+-{LINEAR_MARGIN:.0%}).")  # fmt: skip
    return _row(5, verdict, text, grid.sources)


def claim_memory(grid: Grid) -> dict:
    points = sorted((c.latent, c.mb) for c in grid.cells if c.mb)
    if len(dict(points)) < 2 or len(points) < 3:
        return _row(6, NOT_MEASURED, "needs peak MB at 2+ widths (3+ cells)", grid.sources)
    fit = stats.linregress(*np.log2(np.array(points)).T)
    half = stats.t.ppf(0.975, len(points) - 2) * np.nan_to_num(fit.stderr)  # NaN: MB constant
    lo, hi = 2 ** (fit.slope - half), 2 ** (fit.slope + half)
    ranges = "; ".join(f"{w}: {min(v for x, v in points if x == w):.1f}-{max(v for x, v in points if x == w):.1f}"
                       for w in dict(points))  # fmt: skip
    big, ref = grid.cell(128, 10), grid.cell(*PAPER_CELL)
    paper = f" 128/10 / 64/5: {big.mb / ref.mb:.2f}x (the paper: 3.7x on a GPU)." if big and ref else ""
    text = (f"Peak MB per width: {ranges}. Per doubling of the width: {2**fit.slope:.2f}x [{lo:.2f}, {hi:.2f}]"
            f" (95%, log-log least squares over {len(points)} cells).{paper}")  # fmt: skip
    return _row(6, REPRODUCED if lo > 1 else NOT_REPRODUCED if hi <= 1 else UNTOLD, text, grid.sources)


def training_hours(job_folder: Path) -> float | None:
    """A run's whole training clock in hours (``results.json`` ``training_s``; records older than it carry only
    ``train_wall_s``, trainer.fit's wall time with its validations), None without either."""
    record = (
        json.loads((job_folder / "results.json").read_text())
        if (job_folder / "results.json").is_file()
        else {}
    )
    seconds = record.get("training_s", record.get("train_wall_s"))
    return None if seconds is None else float(seconds) / 3600


def hours_to_final(job_folder: Path) -> tuple[float | None, str]:
    """Hours of one thread's training clock until a run reached its final error (claim 9 of the module
    docstring), and how it was measured ("curve" or "whole run"); None without a record."""
    curve_path = job_folder / "curve.jsonl"
    vals = read_curve(curve_path)["val"] if curve_path.is_file() else []
    vals = [v for v in vals if v.get("rollout_mse") is not None and v.get("time_s") is not None]
    if vals:
        final = vals[-1]["rollout_mse"]
        first = next(v for v in vals if v["rollout_mse"] <= FINAL_MARGIN * final)
        return float(first["time_s"]) / 3600, "curve"
    hours = training_hours(job_folder)
    return hours, "whole run" if hours is not None else "no record"


def _cell_hours(cell: Cell) -> tuple[float | None, str, float | None]:
    """(seed-mean hours to the final error, how measured, seed-mean whole training clock in hours)."""
    measured = [hours_to_final(job.folder) for job in cell.jobs]
    hours = [h for h, _ in measured if h is not None]
    whole = [h for job in cell.jobs if (h := training_hours(job.folder)) is not None]
    how = "/".join(sorted({m for h, m in measured if h is not None})) or "no record"
    return (float(np.mean(hours)) if hours else None), how, (float(np.mean(whole)) if whole else None)


def claim_training_time(grid: Grid) -> dict:
    ref, big = grid.cell(*PAPER_CELL), grid.cell(*ORIGINAL_CELL)
    if ref is None or big is None or not ref.jobs or not big.jobs:
        return _row(9, NOT_MEASURED, "needs the 64/5 and 128/10 cells with their jobs", grid.sources)
    (h_ref, how_ref, whole_ref), (h_big, how_big, whole_big) = _cell_hours(ref), _cell_hours(big)
    if not h_ref or not h_big:
        return _row(9, NOT_MEASURED, "no training clock recorded for 64/5 or 128/10", grid.sources)
    ratio, quality = h_big / h_ref, _paired(big, ref)
    verdict = _factor(ratio, PAPER_TRAINING)
    held = ""
    if verdict == REPRODUCED and _side(quality) > 0:  # faster, but to a worse error: not the paper's claim
        verdict, held = (
            UNTOLD,
            " 64/5 ends worse beyond the interval, so its shorter time is not to the same error"
            f" (time alone: {REPRODUCED}).",
        )
    whole = f"; whole runs {whole_big:.2f} h against {whole_ref:.2f} h" if whole_ref and whole_big else ""
    text = (f"Hours of one thread to the final error (within {FINAL_MARGIN - 1:.0%} of the last validation; "
            f"128/10 by {how_big}, 64/5 by {how_ref}): 128/10 {h_big:.2f} h against 64/5 {h_ref:.2f} h, "
            f"{ratio:.2f}x (the paper: {PAPER_TRAINING:g}x){whole}. Rollout MSE 64/5 / 128/10, paired: "
            f"{_x(quality)}.{held}")  # fmt: skip
    return _row(9, verdict, text, grid.sources)


def claim_radius(folder: Path | None, preset_radius: float) -> dict:
    if folder is None or not (folder / "results.csv").is_file():
        return _row(7, NOT_MEASURED, f"{folder}/results.csv: no such file" if folder else "no --radius", [])
    grid, scale = load_grid(folder), preset_radius / WATERRAMPS_RADIUS
    cells = [c for c in grid.cells if (c.latent, c.mp) == PAPER_CELL and c.radius]
    near = lambda r: min((c for c in cells if abs(c.radius / r - 1) <= 0.05),
                         key=lambda c: abs(c.radius - r), default=None)  # fmt: skip
    small, paper = near(0.014 * scale), near(0.020 * scale)
    if not (small and paper):
        why = f"no 64/5 jobs at R = {0.014 * scale:.3f} and {0.020 * scale:.3f} (+-5%)"
        return _row(7, NOT_MEASURED, why, grid.sources)
    helps = _paired(small, paper)
    parts = [(f"helps: R={paper.radius:g} / R={small.radius:g} {_x(helps)}",
              _gate(_verdict(_side(helps), -1), grid)[0] if helps else NOT_MEASURED)]  # fmt: skip
    for big in (c for c in cells if c.radius > paper.radius * 1.05):
        confuses, slows = _paired(paper, big), big.ms / paper.ms if big.ms and paper.ms else math.nan
        parts += [(f"confuses: R={big.radius:g} / R={paper.radius:g} {_x(confuses)}",
                   _gate(_verdict(_side(confuses), +1), grid)[0] if confuses else NOT_MEASURED),
                  (f"slows: {slows:.2f}x the ms/frame ({big.ms:.0f} / {paper.ms:.0f})",
                   _factor(slows, TIMING_TOLERANCE) if slows > 0 else NOT_MEASURED)]  # fmt: skip
    if len(parts) == 1:
        parts.append(("confuses, slows: no radius above R(0.020) in the sweep", NOT_MEASURED))
    text = (
        f"64/5 at WaterRamps radii x{scale:.3g} (preset {preset_radius:g} / {WATERRAMPS_RADIUS}); rollout "
        f"MSE paired, seeds averaged: {'; '.join(f'{p} ({v})' for p, v in parts)}. {_gate(UNTOLD, grid)[1]}"
    )
    return _row(7, _combine([v for _, v in parts]), text, grid.sources)


def _field(data: dict, dotted: str, path: Path):
    for name in dotted.split("."):
        if not isinstance(data, dict) or name not in data:
            raise ClaimsInputError(str(path), f"no field {dotted!r}")
        data = data[name]
    return data


def claim_versus(folder: Path | None) -> dict:
    path = folder / "versus.json" if folder else None
    if path is None or not path.is_file():
        return _row(8, NOT_MEASURED, f"{path}: no such file" if path else "no --versus", [])
    try:
        data = json.loads(path.read_text())
    except ValueError as error:
        raise ClaimsInputError(str(path), f"not JSON ({error})") from None
    if sorted(_field(data, "models", path)) != ["original", "simplified"]:
        raise ClaimsInputError(str(path), "field 'models' must be 'original' and 'simplified'")
    paired = {k: float(_field(data, f"paired.rollout_mse.{k}", path)) for k in ("ratio", "lo", "hi")}
    if data["models"][0] != "original":  # compare() gave original / simplified
        paired = {"ratio": 1 / paired["ratio"], "lo": 1 / paired["hi"], "hi": 1 / paired["lo"]}
    run = {(n, k): float(_field(data, f"runs.{n}.bench.{k}", path))
           for n in ("original", "simplified") for k in ("ms_per_frame", "peak_memory_mb")}  # fmt: skip
    speed = run["original", "ms_per_frame"] / run["simplified", "ms_per_frame"]
    memory = run["original", "peak_memory_mb"] / run["simplified", "peak_memory_mb"]
    verdicts = [_verdict(_side(paired), -1), _factor(speed, PAPER_SPEEDUP), _factor(memory, PAPER_MEMORY)]
    how = data["runs"]["simplified"]["bench"].get("memory_measure", "measure not recorded")
    text = (f"Quality: simplified / original rollout MSE {_x(paired)}, paired ({verdicts[0]}). Speed: original /"
            f" simplified ms/frame {speed:.1f}x ({run['original', 'ms_per_frame']:.0f} / "
            f"{run['simplified', 'ms_per_frame']:.1f} ms; the paper {PAPER_SPEEDUP}x) ({verdicts[1]}). Memory: "
            f"{memory:.2f}x ({run['original', 'peak_memory_mb']:.0f} / {run['simplified', 'peak_memory_mb']:.0f}"
            f" MB, {how}; the paper {PAPER_MEMORY}x) ({verdicts[2]}).")  # fmt: skip
    return _row(8, _combine(verdicts), text, [str(path)])


# -- outputs ---------------------------------------------------------------------------------------------------
def markdown(claims: Sequence[dict], table: Sequence[dict], grids: Sequence[Grid]) -> str:
    labels = grid_labels(grids)
    also = f"; beside `{grids[1].path}` ({labels[1]})" if len(grids) > 1 else ""
    lines = ["# The paper's claims, one by one", "",
             f"Grid: `{grids[0].path}` ({labels[0]}){also}. Each verdict follows a rule written in "
             "`gnsx/evaluation/report/claims.py` (95% intervals; an interval containing 1 cannot be told).", "",
             "| # | the paper | measured | from | verdict |", "|---|---|---|---|---|"]  # fmt: skip
    for c in claims:
        cells = [str(c["number"]), c["claim"], c["measurement"], ", ".join(f"`{s}`" for s in c["from"]) or "-",
                 f"**{c['verdict']}**"]  # fmt: skip
        lines.append("| " + " | ".join(s.replace("|", "\\|") for s in cells) + " |")
    lines += ["", "## Side by side", "", "Rollout MSE ± se over the test trajectories (one seed) or over the "
              "seeds (their mean); baseline / model rollout MSE [95%]; ms and peak MB of one frame at WaterRamps "
              "size.", "", *side_by_side_lines(table, labels)]  # fmt: skip
    return "\n".join(lines) + "\n"


def build(grid: Path, out: Path, compare_grid: Path | None = None, radius: Path | None = None,
          versus: Path | None = None, preset_radius: float = 0.035) -> dict:  # fmt: skip
    """Every claim and the side-by-side table; writes ``out/claims.md`` and ``out/claims.json``."""
    grids = [load_grid(grid)] + ([load_grid(compare_grid)] if compare_grid else [])
    g = grids[0]
    claims = [claim_pareto(g), claim_width(g, 2, 16, +1), claim_width(g, 3, 128, -1), claim_depth(g),
              claim_linear_cost(g), claim_memory(g), claim_radius(radius, preset_radius),
              claim_versus(versus), claim_training_time(g)]  # fmt: skip
    table = side_by_side(grids)
    text = markdown(claims, table, grids)
    out.mkdir(parents=True, exist_ok=True)
    (out / "claims.md").write_text(text)
    summary = {"grid": str(grid), "compare": compare_grid and str(compare_grid), "claims": claims,
               "side_by_side": table, "seed_test": g.seed_test}  # fmt: skip
    write_json(out / "claims.json", summary)
    return {**summary, "markdown": text}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gnsx.evaluation.report.claims",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("--grid", type=Path, required=True, help="a figure 9 report folder")
    parser.add_argument("--compare", type=Path, help="a second grid, for the side-by-side table")
    parser.add_argument("--radius", type=Path, help="the radius sweep's report folder")
    parser.add_argument("--versus", type=Path, help="the folder holding versus.json")
    parser.add_argument("--preset-radius", type=float, default=0.035, help="the data's default radius")
    parser.add_argument("--out", type=Path, required=True, help="folder for claims.md and claims.json")
    args = parser.parse_args(argv)
    print(build(args.grid, args.out, args.compare, args.radius, args.versus, args.preset_radius)["markdown"])
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main))
