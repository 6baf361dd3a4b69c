"""Report of one Hydra multirun sweep: the paper's figure 9 grid, speed against error with the Pareto front, a
markdown table and a wandb table.

    python -m gnsx.evaluation.report multirun/fig9_mini/2026-11-26_13-00-00     # writes <that dir>/report/
    python -m gnsx.evaluation.report <sweep dir> --budget 3e-2    # + the fastest model with test rollout MSE <= 3e-2

Outputs (in ``<sweep dir>/report/``):

* ``grid.png``: one frame of each job's first test rollout, rows the embedding size and columns the
  message-passing count (figure 9: capacity falls from top left to bottom right), each cell annotated with
  ms/frame, MB, rollout MSE ± its standard error, the baseline ratio with its interval and whether it can be
  told apart from the best cell (text in red when it does not beat the physics-free baseline), the paper's
  64/5 cell framed in green, failed jobs with their reason, and the ground truth's frame for reference. A
  sweep of one parameter (e.g. the radius) gives one row.
* ``speed_vs_error.png``: ms/frame against test rollout MSE (log-log) with ±1 SE error bars, the Pareto front
  marked (no other job is both faster and more accurate), models that do not beat the baseline in red.
* ``radius.png`` (when the radius varies): rollout and one-step error, and ms/frame, against the radius.
* ``report.md``: the table of every job (failed ones with their reason) and the pictures; ``results.csv``.
* With ``--budget E`` (``--budget-key``: rollout_mse, onestep_mse or emd): the model a scene needs, the
  fastest successful job whose mean test error is at most E (:func:`pick_for_budget`), its speed ratio to
  every other job and whether its error can be told apart from the best job's (paired over the test
  trajectories with :func:`gnsx.evaluation.spread.compare` when both have per-trajectory rows, else mean ± 2 SE); it
  leads ``report.md`` and is framed in blue in the grid and starred in the scatter.
* ``wandb/``: an offline wandb run (group = the sweep's name) holding the table as a ``wandb.Table`` and the
  pictures (``wandb sync`` uploads it).

Speed and memory come from the benchmark at WaterRamps size (``bench``) when every successful job has it,
otherwise from the test rollouts (``test``); the report says which.

Errors come with their spread over the test trajectories (:mod:`gnsx.evaluation.spread`): ``<key>_se`` of the test
summary, or computed from the job's per-trajectory ``rows`` when the summary predates it. The baseline ratio
is the geometric mean of ``baseline_mse / rollout_mse`` over trajectories with its 95% t interval (the ratio
of the means when neither is recorded); below 1 the model does not beat the physics-free baseline. Each job is
compared with the best one (lowest mean rollout MSE): paired over the same test trajectories
(:func:`gnsx.evaluation.spread.compare`) when both have per-trajectory rows, otherwise by the overlap of mean ± 2 SE; the
table says which (``vs_best_method``).

``results.json`` (one per job folder, written by :func:`gnsx.training.pipeline.run_training`)::

    status          "ok" | "failed" | "running" (a job killed before it finished leaves "running")
    error           one line: why the job failed ("diverged: ..." for a NaN/Inf loss or rollout), else null
    sweep, job      the sweep's name (``sweep.name``), the job number in the multirun
    overrides       every Hydra override of the job; ``swept``: the ones the sweep varies; ``name``: the
                    wandb run name (the swept overrides joined by commas)
    run_dir         the job folder
    model           the model config's name; ``model_config``: its architecture (latent_size, mp_steps,
                    mlp_hidden_size, ...) with the effective ``radius`` (data units) and ``noise_std``
    parameters      trainable parameter count
    train_wall_s    wall time of trainer.fit (s, validation included); ``train_steps``: optimizer steps of
                    this run; ``steps_per_s``: steps per second of training (validation excluded);
                    ``job_wall_s``: the whole job (data, training, evaluation, pictures, benchmark)
    test            {rollout_mse, onestep_mse, emd, baseline_mse (data units^2, dynamic particles),
                     ms_per_frame (rollout, graph build included), peak_memory_mb, trajectories, and since
                     the spreads were added <key>_se, baseline_ratio_geomean(_lo, _hi), ...}: the summary of
                     :func:`gnsx.evaluation.scoring.summarise`
    bench           {ms_per_frame, peak_memory_mb, num_particles, spacing, device}: one inference step on a
                    packed scene of WaterRamps size at the data's particle spacing; {error} when it failed
    frame, frame_png, frame_truth_png
                    the rendered frame index of the first test rollout and its PNGs (prediction, ground truth)
    rows            per-test-trajectory errors (:func:`gnsx.evaluation.scoring.score_trajectory`; optional)

A job folder without results.json (the job never started, or crashed before writing) counts as failed, with
its model read from ``.hydra/config.yaml``.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.evaluation.spread import (
    DOES_NOT_BEAT,
    TIED,
    baseline_verdict,
    compare,
    geometric_mean_interval,
    mean_se,
)

#: The paper's model (figure 9's green cell): (latent size, message-passing steps).
PAPER_CELL = (64, 5)
#: Colour of the budget's pick in the pictures (the paper's cell is limegreen, losers red).
PICK_COLOUR = "dodgerblue"
#: Grid axes in the order rows, columns, as in the paper's figure 9.
AXES = ("latent_size", "mp_steps", "radius")
AXIS_LABELS = {"latent_size": "embedding size", "mp_steps": "message passing steps", "radius": "radius"}


@dataclass
class Job:
    """One job of a sweep, flattened for the report. Numbers are None when unknown (e.g. a failed job)."""

    job: int | None
    folder: Path
    name: str
    status: str
    error: str | None
    latent_size: int | None = None
    mp_steps: int | None = None
    radius: float | None = None
    parameters: int | None = None
    train_steps: int | None = None
    steps_per_s: float | None = None
    train_wall_s: float | None = None
    test: dict[str, Any] = field(default_factory=dict)
    bench: dict[str, Any] = field(default_factory=dict)
    frame_png: str | None = None
    frame_truth_png: str | None = None
    sweep: str | None = None
    rows: list[dict] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def ms_per_frame(self, source: str) -> float | None:
        return _number((self.bench if source == "bench" else self.test).get("ms_per_frame"))

    def memory_mb(self, source: str) -> float | None:
        return _number((self.bench if source == "bench" else self.test).get("peak_memory_mb"))

    @property
    def rollout_mse(self) -> float | None:
        return _number(self.test.get("rollout_mse"))

    def spread(self, key: str) -> tuple[float | None, float | None]:
        """``(mean, standard error)`` of a test error over trajectories: the summary's ``key`` and
        ``<key>_se``, else computed from the per-trajectory rows (None where unknown)."""
        mean, se = _number(self.test.get(key)), _number(self.test.get(f"{key}_se"))
        if se is None and self.rows:
            row_mean, row_se = mean_se(row.get(key) for row in self.rows)
            mean = mean if mean is not None else _number(row_mean)
            se = _number(row_se)
        return mean, se

    def baseline_ratio(self) -> tuple[float | None, float | None, float | None]:
        """``(ratio, low, high)``: the geometric mean over test trajectories of ``baseline_mse / rollout_mse``
        and its 95% interval (from the summary, else the rows); without either, the ratio of the means and no
        interval. None where unknown."""
        geomean = _number(self.test.get("baseline_ratio_geomean"))
        if geomean is not None:
            return (geomean, _number(self.test.get("baseline_ratio_geomean_lo")),
                    _number(self.test.get("baseline_ratio_geomean_hi")))  # fmt: skip
        ratios = [_ratio(row.get("baseline_mse"), row.get("rollout_mse")) for row in self.rows]
        geomean, lo, hi, n = geometric_mean_interval(ratios)
        if n:
            return geomean, _number(lo), _number(hi)
        ratio = _number(self.test.get("baseline_ratio"))
        if ratio is None:
            ratio = _ratio(self.test.get("baseline_mse"), self.rollout_mse)
        return ratio, None, None

    def versus_baseline(self) -> str | None:
        """:func:`gnsx.evaluation.spread.baseline_verdict` of :meth:`baseline_ratio` (None for a failed job)."""
        return baseline_verdict(*self.baseline_ratio()) if self.ok else None

    def label(self, keys: Sequence[str]) -> str:
        """Short name from the swept values, e.g. ``64/5`` (latent/MP) or ``R=0.035``."""
        parts = []
        for key in keys:
            value = getattr(self, key)
            parts.append(f"R={value:g}" if key == "radius" and value is not None else str(value))
        return "/".join(parts) if parts else (self.name or f"job {self.job}")


def _number(value: Any) -> float | None:
    """A finite float, or None (missing, null, NaN)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _ratio(numerator: Any, denominator: Any) -> float | None:
    """``numerator / denominator`` of two positive finite numbers, else None."""
    a, b = _number(numerator), _number(denominator)
    return a / b if a is not None and b is not None and a >= 0 and b > 0 else None


def _job_config(folder: Path) -> dict:
    """The job's composed config from Hydra's ``.hydra/config.yaml`` (empty when absent)."""
    path = folder / ".hydra" / "config.yaml"
    if not path.is_file():
        return {}
    from omegaconf import OmegaConf

    try:
        return OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception:  # an unreadable config only costs the report the job's model fields
        return {}


def load_job(folder: Path) -> Job:
    """A job folder of a multirun as a :class:`Job` (see the module docstring for what counts as failed)."""
    path = folder / "results.json"
    results: dict = {}
    if path.is_file():
        try:
            results = json.loads(path.read_text())
        except ValueError as error:
            results = {"status": "failed", "error": f"{path}: unreadable results.json ({error})"}
    else:
        results = {"status": "failed", "error": "no results.json (the job never ran or was killed)"}
        overrides = folder / ".hydra" / "overrides.yaml"
        if overrides.is_file():
            import yaml

            results["name"] = ",".join(map(str, yaml.safe_load(overrides.read_text()) or []))
    status = results.get("status", "ok" if "test" in results else "failed")
    error = results.get("error")
    from gnsx.core.runstate import INTERRUPTED, effective_status, interrupted_reason

    if effective_status(results) == INTERRUPTED:
        status, error = INTERRUPTED, interrupted_reason(results)
    elif status == "running":
        status, error = "failed", "did not finish (killed, out of memory or timed out?)"
    config = _job_config(folder)
    model_cfg = config.get("model", {})
    model = results.get("model_config") or {}

    def pick(key: str, cast):
        value = model.get(key, model_cfg.get(key))
        try:
            return cast(value) if value is not None else None
        except (TypeError, ValueError):  # e.g. an unresolved interpolation
            return None

    try:
        number = int(results.get("job", folder.name))
    except (TypeError, ValueError):
        number = None
    return Job(
        job=number,
        folder=folder,
        name=results.get("name") or folder.name,
        status=status,
        error=error,
        latent_size=pick("latent_size", int),
        mp_steps=pick("mp_steps", int),
        radius=pick("radius", float),
        parameters=results.get("parameters"),
        train_steps=results.get("train_steps"),
        steps_per_s=_number(results.get("steps_per_s")),
        train_wall_s=_number(results.get("train_wall_s")),
        test=results.get("test") or {},
        bench=results.get("bench") or {},
        frame_png=results.get("frame_png"),
        frame_truth_png=results.get("frame_truth_png"),
        sweep=results.get("sweep") or config.get("sweep", {}).get("name"),
        rows=[row for row in results.get("rows") or [] if isinstance(row, dict)],
    )


def load_sweep(sweep_dir: str | Path) -> list[Job]:
    """Every job folder of a multirun directory (a subfolder with ``.hydra/`` or ``results.json``), by job."""
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such multirun directory")
    folders = [
        p
        for p in sweep_dir.iterdir()
        if p.is_dir() and ((p / ".hydra").is_dir() or (p / "results.json").is_file())
    ]
    if not folders:
        raise FileNotFoundError(f"{sweep_dir}: no job folders (subfolders with .hydra/ or results.json)")
    jobs = [load_job(p) for p in folders]
    return sorted(jobs, key=lambda j: (j.job is None, j.job if j.job is not None else 0, j.folder.name))


def swept_axes(jobs: Sequence[Job]) -> list[str]:
    """The model axes (latent_size, mp_steps, radius) taking more than one value across the jobs."""
    return [key for key in AXES if len({getattr(j, key) for j in jobs if getattr(j, key) is not None}) > 1]


def speed_source(jobs: Sequence[Job]) -> str:
    """``"bench"`` when every successful job has a benchmark at scale, else ``"test"`` (the test rollouts)."""
    ok = [j for j in jobs if j.ok]
    return "bench" if ok and all(j.ms_per_frame("bench") is not None for j in ok) else "test"


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats on both coordinates (both minimised), sorted by the first.

    Args:
        points: ``(cost, error)`` pairs, e.g. (ms/frame, rollout MSE).
    """
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def best_job(jobs: Sequence[Job], key: str = "rollout_mse") -> Job | None:
    """The successful job with the lowest mean test error ``key`` (None when there is none)."""
    candidates = [j for j in jobs if j.ok and _number(j.spread(key)[0]) is not None]
    return min(candidates, key=lambda j: j.spread(key)[0]) if candidates else None


def versus_best(jobs: Sequence[Job], key: str = "rollout_mse") -> dict[int, tuple[str, str | None]]:
    """Whether each successful job can be told apart from the best one (:func:`best_job`) on ``key``
    (default the rollout MSE).

    Returns:
        ``{id(job): (verdict, method)}``: verdict ``"best"``, ``"worse"``, ``"better"`` (a paired geometric
        mean can favour another job than the lowest mean), ``"cannot be told apart"`` or ``"unknown"`` (no
        spread known); method ``"paired"`` (:func:`gnsx.evaluation.spread.compare` over the test trajectories both
        jobs' rows share, at least 2), ``"2se"`` (the jobs' mean ± 2 SE intervals overlap or not) or None.
    """
    best = best_job(jobs, key)
    out: dict[int, tuple[str, str | None]] = {}
    if best is None:
        return out
    best_mean, best_se = best.spread(key)
    for job in jobs:
        if not job.ok or _number(job.spread(key)[0]) is None:
            continue
        if job is best:
            out[id(job)] = ("best", None)
            continue
        paired = compare(best.rows, job.rows, key) if best.rows and job.rows else None
        if paired is not None and paired["trajectories"] >= 2:
            verdict = {"A better": "worse", "B better": "better"}.get(paired["verdict"], TIED)
            out[id(job)] = (verdict, "paired")
            continue
        mean, se = job.spread(key)
        if se is None or best_se is None:
            out[id(job)] = ("unknown", None)
        elif abs(mean - best_mean) > 2 * (se + best_se):
            out[id(job)] = ("worse" if mean > best_mean else "better", "2se")
        else:
            out[id(job)] = (TIED, "2se")
    return out


# -- the model a scene needs: fastest within an error budget -------------------------------------------------
#: Test errors a budget can bound (lower is better; data units^2 for the MSEs, data units for EMD).
BUDGET_KEYS = ("rollout_mse", "onestep_mse", "emd")
_BUDGET_NAMES = {"rollout_mse": "rollout MSE", "onestep_mse": "one-step MSE", "emd": "EMD"}


@dataclass
class BudgetPick:
    """What :func:`pick_for_budget` found: the fastest successful job whose mean held-out error ``key`` is at
    most ``budget``.

    Attributes:
        pick: that job, or None when no job with a known speed stays within the budget.
        best: the job with the lowest mean error (:func:`best_job`).
        versus_best: ``(verdict, method)`` of the pick against the best (:func:`versus_best`): ``"best"``,
            ``"worse"``, ``"cannot be told apart"``, ... and ``"paired"`` / ``"2se"`` / None.
        paired: :func:`gnsx.evaluation.spread.compare` of best and pick (``ratio`` = pick's error over the best's) when
            both have per-trajectory rows, else None.
        others: per other successful job with a known speed and error: ``(job, speed ratio = its ms/frame over
            the pick's, its mean error, within the budget)``, fastest first.
    """

    key: str
    budget: float
    source: str
    pick: Job | None
    best: Job | None
    versus_best: tuple[str, str | None] | None = None
    paired: dict | None = None
    others: list[tuple[Job, float | None, float, bool]] = field(default_factory=list)


def pick_for_budget(jobs: Sequence[Job], budget: float, key: str = "rollout_mse") -> BudgetPick:
    """The model a scene needs: among the successful jobs with a known speed (:func:`speed_source`), the
    fastest whose mean test ``key`` is at most ``budget``, with how much faster it is than each other job and
    whether its error can be told apart from the best job's."""
    if key not in BUDGET_KEYS:
        raise ValueError(f"pick_for_budget: key must be one of {BUDGET_KEYS}, got {key!r}")
    source = speed_source(jobs)
    timed = [
        j
        for j in jobs
        if j.ok and j.ms_per_frame(source) is not None and _number(j.spread(key)[0]) is not None
    ]
    timed.sort(key=lambda j: j.ms_per_frame(source))
    within = [j for j in timed if j.spread(key)[0] <= budget]
    pick = within[0] if within else None
    best = best_job(jobs, key)
    result = BudgetPick(key=key, budget=float(budget), source=source, pick=pick, best=best)
    if pick is None:
        return result
    result.versus_best = versus_best(jobs, key).get(id(pick))
    if best is not None and best is not pick and best.rows and pick.rows:
        result.paired = compare(best.rows, pick.rows, key)
    ms = pick.ms_per_frame(source)
    result.others = [
        (j, j.ms_per_frame(source) / ms if ms > 0 else None, j.spread(key)[0], j.spread(key)[0] <= budget)
        for j in timed
        if j is not pick
    ]
    return result


def budget_lines(result: BudgetPick, keys: Sequence[str]) -> list[str]:
    """Markdown lines saying which model the budget picks and by how much it beats the others."""
    what = _BUDGET_NAMES[result.key]
    speed = "benchmark at WaterRamps size" if result.source == "bench" else "test rollouts"
    lines = [f"Budget: test {what} at most {result.budget:.3g} (mean over the test trajectories); speed from"
             f" the {speed}."]  # fmt: skip
    pick = result.pick
    if pick is None:
        closest = result.best
        lines.append(
            "**No model stays within the budget.**"
            + (
                f" The lowest {what} is {closest.label(keys)}'s, {_with_se(*closest.spread(result.key))}."
                if closest
                else ""
            )
        )
        return lines
    ms = pick.ms_per_frame(result.source)
    lines.append(
        f"**Pick: {pick.label(keys)}**: {ms:.3g} ms/frame, {what} {_with_se(*pick.spread(result.key))}, the"
        " fastest model within the budget."
    )
    verdict, method = result.versus_best or (None, None)
    best = result.best
    if verdict == "best":
        lines.append(f"It is also the most accurate model (lowest mean {what}).")
    elif best is not None:
        how = {
            "paired": "paired over the same test trajectories",
            "2se": "by the overlap of mean ± 2 SE",
        }.get(method, "")
        told = {TIED: "cannot be told apart from", "worse": "is worse than", "better": "is better than"}.get(
            verdict, "cannot be compared with (no spread recorded)"
        )
        line = (
            f"Its {what} {told} the best model's ({best.label(keys)}, {_with_se(*best.spread(result.key))})"
        )
        if result.paired is not None and math.isfinite(result.paired["ratio"]):
            paired = result.paired
            interval = f" [{paired['lo']:.2f}, {paired['hi']:.2f}]" if math.isfinite(paired["lo"]) else ""
            line += (f": pick / best {paired['ratio']:.2f}x{interval}, geometric mean over"
                     f" {paired['trajectories']} trajectories")  # fmt: skip
        lines.append(line + (f", {how}." if how else "."))
    faster = [f"{ratio:.2f}x faster than {job.label(keys)}" + ("" if within else " (over budget)")
              for job, ratio, _, within in result.others if ratio is not None and ratio >= 1]  # fmt: skip
    if faster:
        lines.append("Speed: " + "; ".join(faster) + ".")
    over = [job.label(keys) for job, ratio, _, within in result.others if ratio is not None and ratio < 1]
    if over:
        lines.append(f"Faster but over the budget: {', '.join(over)}.")
    return lines


def _with_se(mean: float | None, se: float | None, fmt: str = ".2e") -> str:
    if mean is None:
        return "n/a"
    return f"{mean:{fmt}} ± {se:.1e}" if se is not None else f"{mean:{fmt}}"


def _ratio_text(ratio: float | None, lo: float | None, hi: float | None) -> str:
    if ratio is None:
        return "n/a"
    return f"{ratio:.2f}x [{lo:.2f}, {hi:.2f}]" if lo is not None and hi is not None else f"{ratio:.2f}x"


# -- pictures ------------------------------------------------------------------------------------------------
_VERSUS_BEST_TAGS = {"best": "best", TIED: "≈ best", "better": "better than best (paired)"}


def _cell_text(job: Job, source: str, versus: tuple[str, str | None] | None = None) -> str:
    ms, mb = job.ms_per_frame(source), job.memory_mb(source)
    first = f"{ms:.1f} ms/frame" if ms is not None else "? ms/frame"
    first += f", {mb:.0f} MB" if mb is not None else ""
    if job.rollout_mse is None:
        return first
    lines = [first, "MSE " + _with_se(*job.spread("rollout_mse"))]
    ratio = job.baseline_ratio()
    if ratio[0] is not None:
        lines.append("base/model " + _ratio_text(*ratio))
    tag = _VERSUS_BEST_TAGS.get(versus[0]) if versus else None
    if job.versus_baseline() == DOES_NOT_BEAT:
        lines.append("does not beat baseline" + (f"; {tag}" if tag else ""))
    elif tag:
        lines.append(tag)
    return "\n".join(lines)


def _cell_colour(job: Job) -> str:
    return "red" if job.versus_baseline() == DOES_NOT_BEAT else "black"


def grid_layout(jobs: Sequence[Job]) -> tuple[str | None, list, str, list]:
    """``(row_key, row_values, col_key, col_values)`` of the grid picture: the first two swept axes of
    :data:`AXES` (one row when only one varies). Latent sizes and MP counts run from large to small (capacity
    falls from top left to bottom right, as in figure 9), radii from small to large."""
    axes_keys = swept_axes(jobs)[:2] or ["mp_steps"]
    row_key = axes_keys[0] if len(axes_keys) == 2 else None
    col_key = axes_keys[-1]
    row_values = sorted({getattr(j, row_key) for j in jobs}, key=_desc) if row_key else [None]
    col_values = sorted({getattr(j, col_key) for j in jobs}, key=_desc if col_key != "radius" else _asc)
    return row_key, row_values, col_key, col_values


def plot_grid(jobs: Sequence[Job], path: Path, highlight: tuple[int, int] | None = PAPER_CELL,
              pick: Job | None = None) -> Path:  # fmt: skip
    """Figure 9: one rendered test frame per job on a grid of the swept axes (first two of :data:`AXES`);
    ``pick`` (:func:`pick_for_budget`) framed in blue and tagged "budget pick"."""
    import imageio.v3 as iio
    import matplotlib.pyplot as plt

    row_key, row_values, col_key, col_values = grid_layout(jobs)
    cells: dict[tuple, Job] = {}
    for job in jobs:
        cells.setdefault((getattr(job, row_key) if row_key else None, getattr(job, col_key)), job)
    source = speed_source(jobs)
    versus = versus_best(jobs)
    truth = next(
        (j.frame_truth_png for j in jobs if j.frame_truth_png and Path(j.frame_truth_png).is_file()), None
    )
    ncols = len(col_values) + (1 if truth else 0)
    fig, grid = plt.subplots(
        len(row_values), ncols, figsize=(2.6 * ncols, 3.4 * len(row_values) + 0.3), squeeze=False
    )
    for r, row_value in enumerate(row_values):
        for c, col_value in enumerate(col_values):
            ax = grid[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            job = cells.get((row_value, col_value))
            if job is None:
                ax.set_facecolor("0.92")
                ax.text(0.5, 0.5, "not run", ha="center", va="center", transform=ax.transAxes)
            elif job.ok and job.frame_png and Path(job.frame_png).is_file():
                ax.imshow(iio.imread(job.frame_png))
                ax.set_xlabel(
                    _cell_text(job, source, versus.get(id(job))), fontsize=8, color=_cell_colour(job)
                )
            else:
                ax.set_facecolor("0.85")
                reason = "failed: " + (job.error or "unknown") if not job.ok else "no frame rendered"
                ax.text(0.5, 0.5, "\n".join(textwrap.wrap(reason, 26)[:6]), ha="center", va="center",
                        fontsize=7, color="darkred", transform=ax.transAxes)  # fmt: skip
                if job.ok:
                    ax.set_xlabel(_cell_text(job, source, versus.get(id(job))), fontsize=8,
                                  color=_cell_colour(job))  # fmt: skip
            if r == 0:
                ax.set_title(_axis_value(col_key, col_value), fontsize=10)
            if c == 0 and row_key:
                ax.set_ylabel(_axis_value(row_key, row_value), fontsize=10)
            is_paper = (
                highlight is not None
                and job is not None
                and (job.latent_size, job.mp_steps) == tuple(highlight)
                and {row_key, col_key} <= {"latent_size", "mp_steps", None}
            )
            picked = pick is not None and job is pick
            for spine in ax.spines.values():
                # The paper's cell keeps its green frame when it is also the pick; the tag says so.
                spine.set_edgecolor("limegreen" if is_paper else PICK_COLOUR if picked else "0.6")
                spine.set_linewidth(4 if is_paper or picked else 0.8)
            if picked:
                ax.text(0.5, 0.98, "budget pick", ha="center", va="top", fontsize=9, fontweight="bold",
                        color=PICK_COLOUR, transform=ax.transAxes,
                        bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8})  # fmt: skip
        if truth:
            ax = grid[r, -1]
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.imshow(iio.imread(truth))
                ax.set_title("ground truth", fontsize=10)
            else:
                ax.axis("off")
    what = "benchmark at WaterRamps size" if source == "bench" else "test rollouts"
    sweep = next((j.sweep for j in jobs if j.sweep), "sweep")
    title = f"{sweep}: one test frame per model; ms/frame and peak MB from the {what}"
    fig.suptitle(title + "\ntest MSE ± SE over trajectories; red: does not beat the physics-free baseline",
                 fontsize=10)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _desc(value):
    return -value if value is not None else math.inf


def _asc(value):
    return value if value is not None else math.inf


def _axis_value(key: str, value) -> str:
    if key == "radius":
        return f"radius {value:g}" if value is not None else "radius ?"
    return f"{'MP' if key == 'mp_steps' else 'latent'} {value}"


def plot_speed_error(jobs: Sequence[Job], path: Path, highlight: tuple[int, int] | None = PAPER_CELL,
                     budget: BudgetPick | None = None) -> Path:  # fmt: skip
    """ms/frame against test rollout MSE (±1 SE error bars), log-log, every successful job labelled, the
    Pareto front joined, jobs that do not beat the physics-free baseline in red; with a ``budget``, its pick
    starred in blue (and the budget drawn when it bounds the rollout MSE)."""
    import matplotlib.pyplot as plt

    source = speed_source(jobs)
    keys = swept_axes(jobs)
    points, shown = [], []
    for job in jobs:
        ms, mse = job.ms_per_frame(source), job.rollout_mse
        if job.ok and ms is not None and mse is not None and ms > 0 and mse > 0:
            points.append((ms, mse))
            shown.append(job)
    fig, ax = plt.subplots(figsize=(7, 5))
    if points:
        xs, ys = np.array(points).T
        se = np.array([job.spread("rollout_mse")[1] or 0.0 for job in shown])
        # On a log axis the lower bar cannot reach zero: clip it just above.
        ax.errorbar(xs, ys, yerr=[np.minimum(se, 0.99 * ys), se], fmt="none", ecolor="0.4", elinewidth=1,
                    capsize=3, zorder=2.5)  # fmt: skip
        losing = np.array([job.versus_baseline() == DOES_NOT_BEAT for job in shown])
        ax.scatter(xs[~losing], ys[~losing], color="tab:blue", zorder=3, label="model (±1 SE)")
        if losing.any():
            ax.scatter(xs[losing], ys[losing], color="red", marker="X", s=70, zorder=3,
                       label="does not beat the baseline")  # fmt: skip
        for job, (x, y) in zip(shown, points):
            ax.annotate(job.label(keys), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
            if highlight is not None and (job.latent_size, job.mp_steps) == tuple(highlight):
                ax.scatter([x], [y], s=220, facecolors="none", edgecolors="limegreen", linewidths=2, zorder=4,
                           label=f"paper's {highlight[0]}/{highlight[1]}")  # fmt: skip
        if budget is not None and budget.pick in shown:
            x, y = points[shown.index(budget.pick)]
            ax.scatter([x], [y], marker="*", s=320, color=PICK_COLOUR, zorder=5, label="budget pick")
        if budget is not None and budget.key == "rollout_mse":
            ax.axhline(budget.budget, ls="--", lw=1, color=PICK_COLOUR, label=f"budget {budget.budget:.3g}")
        front = pareto_front(points)
        # A staircase: between two front points, the best error reachable at that speed is the slower one's.
        ax.plot(xs[front], ys[front], "-o", drawstyle="steps-post", color="tab:red", mfc="none", ms=11,
                zorder=2, label="Pareto front")  # fmt: skip
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no successful job", ha="center", va="center", transform=ax.transAxes)
    failed = [j for j in jobs if not j.ok]
    if failed:
        names = ", ".join(j.label(keys) for j in failed)
        ax.text(0.01, 0.01, f"{len(failed)} failed job(s) not shown: {names}", transform=ax.transAxes,
                fontsize=7, color="darkred")  # fmt: skip
    what = "benchmark at WaterRamps size" if source == "bench" else "test rollout"
    ax.set_xlabel(f"inference ms/frame ({what}, graph build included)")
    ax.set_ylabel("test rollout MSE (data units$^2$)")
    ax.set_title(f"{next((j.sweep for j in jobs if j.sweep), 'sweep')}: speed vs error", fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_radius(jobs: Sequence[Job], path: Path) -> Path:
    """Rollout (and one-step) MSE, and ms/frame, against the connection radius; failed radii marked."""
    import matplotlib.pyplot as plt

    source = speed_source(jobs)
    ok = sorted((j for j in jobs if j.ok and j.radius is not None), key=lambda j: j.radius)
    fig, (err_ax, ms_ax) = plt.subplots(1, 2, figsize=(10, 4))
    radius = [j.radius for j in ok]
    for key, style in (("rollout_mse", "-o"), ("onestep_mse", "--s")):
        values = [_number(j.test.get(key)) for j in ok]
        if any(v is not None for v in values):
            err_ax.plot(
                radius, [np.nan if v is None else v for v in values], style, label=key.replace("_", " ")
            )
    ms = [j.ms_per_frame(source) for j in ok]
    ms_ax.plot(radius, [np.nan if v is None else v for v in ms], "-o", color="tab:orange")
    for job in jobs:
        if not job.ok and job.radius is not None:
            for ax in (err_ax, ms_ax):
                ax.axvline(job.radius, color="darkred", ls=":", lw=1)
                ax.text(job.radius, 0.98, " failed", color="darkred", fontsize=7, va="top",
                        transform=ax.get_xaxis_transform())  # fmt: skip
    err_ax.set_yscale("log")
    err_ax.set_xlabel("connection radius (data units)")
    err_ax.set_ylabel("test MSE (data units$^2$)")
    if err_ax.get_legend_handles_labels()[0]:
        err_ax.legend(fontsize=8)
    ms_ax.set_xlabel("connection radius (data units)")
    what = "benchmark at WaterRamps size" if source == "bench" else "test rollout"
    ms_ax.set_ylabel(f"inference ms/frame ({what})")
    for ax in (err_ax, ms_ax):
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{next((j.sweep for j in jobs if j.sweep), 'sweep')}: error and speed against radius")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# -- tables --------------------------------------------------------------------------------------------------
COLUMNS = (
    "job", "name", "status", "latent_size", "mp_steps", "radius", "parameters", "train_steps", "steps_per_s",
    "train_min", "rollout_mse", "rollout_mse_se", "onestep_mse", "onestep_mse_se", "emd", "emd_se",
    "baseline_mse", "baseline_ratio", "baseline_ratio_lo", "baseline_ratio_hi", "vs_baseline", "vs_best",
    "vs_best_method", "test_ms_per_frame", "test_peak_mb", "bench_ms_per_frame", "bench_peak_mb", "pareto",
    "error",
)  # fmt: skip
#: The markdown table's columns: spreads and intervals shown in their value's cell, not on their own.
MARKDOWN_COLUMNS = tuple(
    c for c in COLUMNS if not c.endswith(("_se", "_lo", "_hi")) and c != "vs_best_method"
)


def table_rows(jobs: Sequence[Job]) -> list[dict[str, Any]]:
    """One dict per job with :data:`COLUMNS` (None where unknown).

    ``<key>_se``: standard errors over test trajectories; ``baseline_ratio`` (``_lo``, ``_hi``): the geometric
    mean of baseline / model rollout MSE and its 95% interval (:meth:`Job.baseline_ratio`); ``vs_baseline``:
    :func:`gnsx.evaluation.spread.baseline_verdict`; ``vs_best``, ``vs_best_method``: :func:`versus_best`; ``pareto``
    marks the speed/error front.
    """
    source = speed_source(jobs)
    versus = versus_best(jobs)
    candidates = [
        j for j in jobs if j.ok and j.ms_per_frame(source) is not None and j.rollout_mse is not None
    ]
    front = {
        id(candidates[i]) for i in pareto_front([(j.ms_per_frame(source), j.rollout_mse) for j in candidates])
    }
    rows = []
    for j in jobs:
        ratio = j.baseline_ratio() if j.ok else (None, None, None)
        rows.append(
            {
                "job": j.job,
                "name": j.name,
                "status": j.status,
                "latent_size": j.latent_size,
                "mp_steps": j.mp_steps,
                "radius": j.radius,
                "parameters": j.parameters,
                "train_steps": j.train_steps,
                "steps_per_s": j.steps_per_s,
                "train_min": j.train_wall_s / 60 if j.train_wall_s is not None else None,
                **{
                    name: value
                    for key in ("rollout_mse", "onestep_mse", "emd")
                    for name, value in zip((key, f"{key}_se"), j.spread(key))
                },
                "baseline_mse": _number(j.test.get("baseline_mse")),
                **dict(zip(("baseline_ratio", "baseline_ratio_lo", "baseline_ratio_hi"), ratio)),
                "vs_baseline": j.versus_baseline(),
                "vs_best": versus.get(id(j), (None, None))[0],
                "vs_best_method": versus.get(id(j), (None, None))[1],
                "test_ms_per_frame": j.ms_per_frame("test"),
                "test_peak_mb": j.memory_mb("test"),
                "bench_ms_per_frame": j.ms_per_frame("bench"),
                "bench_peak_mb": j.memory_mb("bench"),
                "pareto": id(j) in front,
                "error": j.error or (j.bench.get("error") and f"benchmark: {j.bench['error']}") or None,
            }
        )
    return rows


def _fmt(value: Any) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else ""
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return f"{value:.3g}" if value == 0 or 1e-2 <= abs(value) < 1e4 else f"{value:.2e}"
    return str(value).replace("|", "\\|")


def _markdown_cell(row: dict[str, Any], column: str) -> str:
    value = row.get(column)
    if column in ("rollout_mse", "onestep_mse", "emd") and value is not None:
        se = row.get(f"{column}_se")
        return _fmt(value) + (f" ± {se:.1e}" if se is not None else "")
    if column == "baseline_ratio" and value is not None:
        return _ratio_text(value, row.get("baseline_ratio_lo"), row.get("baseline_ratio_hi"))
    if column == "vs_baseline" and value == DOES_NOT_BEAT:
        return "**does not beat baseline**"
    if column == "vs_best" and value is not None and row.get("vs_best_method"):
        return f"{value} ({'paired' if row['vs_best_method'] == 'paired' else '±2 SE'})"
    if value is None and column in ("error", "vs_baseline", "vs_best"):
        return ""
    return _fmt(value)


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """A GitHub markdown table of :func:`table_rows` (:data:`MARKDOWN_COLUMNS`): errors as ``mean ± se``, the
    baseline ratio with its interval, models that do not beat the baseline in bold."""
    header = "| " + " | ".join(MARKDOWN_COLUMNS) + " |"
    rule = "|" + "|".join("---" for _ in MARKDOWN_COLUMNS) + "|"
    lines = [header, rule]
    for row in rows:
        lines.append("| " + " | ".join(_markdown_cell(row, c) for c in MARKDOWN_COLUMNS) + " |")
    return "\n".join(lines)


def write_markdown(jobs: Sequence[Job], rows: Sequence[dict], pictures: dict[str, Path], sweep_dir: Path,
                   path: Path, budget: BudgetPick | None = None) -> Path:  # fmt: skip
    """``report.md``: counts, the budget's pick (when given), pictures, the table, the Pareto front and the
    failed jobs with their reasons."""
    source = speed_source(jobs)
    keys = swept_axes(jobs)
    ok = [j for j in jobs if j.ok]
    sweep = next((j.sweep for j in jobs if j.sweep), sweep_dir.name)
    lines = [
        f"# Sweep report: {sweep}",
        "",
        f"Multirun directory: `{sweep_dir}`. Jobs: {len(jobs)} ({len(ok)} ok, {len(jobs) - len(ok)} failed).",
        f"Swept: {', '.join(AXIS_LABELS[k] for k in keys) or 'nothing among latent size, MP steps, radius'}.",
        "Speed and memory in the pictures: "
        + ("one inference step at WaterRamps size (`bench`)." if source == "bench" else "the test rollouts."),
        "Errors: position MSE per coordinate over dynamic particles, test split (data units squared), mean ±"
        " standard error over the test trajectories. `baseline_ratio`: geometric mean over trajectories of"
        " the physics-free baseline's rollout MSE over the model's, with its 95% t interval (below 1: the"
        " model does not beat the baseline; an interval containing 1: the two cannot be told apart).",
        "",
    ]
    if budget is not None:  # first: the answer to the question the budget asks
        lines += ["## The model for the budget", "", *budget_lines(budget, keys), ""]
    for title, picture in pictures.items():
        lines += [f"![{title}]({picture.name})", ""]
    lines += [markdown_table(rows), ""]
    front = sorted((r for r in rows if r["pareto"]), key=lambda r: r[f"{source}_ms_per_frame"])
    if front:
        labels = [
            next(j for j in jobs if j.job == r["job"] and j.name == r["name"]).label(keys) for r in front
        ]
        lines += [f"Pareto front (ms/frame vs rollout MSE, fastest first): {', '.join(labels)}.", ""]
    lines += _spread_notes(jobs, rows, keys)
    failed = [j for j in jobs if not j.ok]
    if failed:
        lines += ["## Failed jobs", ""]
        lines += [f"- job {j.job} (`{j.name}`): {j.error or 'unknown reason'}" for j in failed]
        lines.append("")
    path.write_text("\n".join(lines))
    return path


def _spread_notes(jobs: Sequence[Job], rows: Sequence[dict], keys: Sequence[str]) -> list[str]:
    """The markdown lines on the comparison with the best job and on the models losing to the baseline."""
    best = best_job(jobs)
    if best is None:
        return []
    label = {id(j): j.label(keys) for j in jobs}
    by_method: dict[str | None, list[str]] = {}
    for job, row in zip(jobs, rows):
        if row["vs_best"] not in (None, "best"):
            by_method.setdefault(row["vs_best_method"], []).append(label[id(job)])
    lines = []
    if by_method:
        tied = [label[id(j)] for j, r in zip(jobs, rows) if r["vs_best"] == TIED]
        others = f"cannot be told apart from it: {', '.join(tied)}." if tied else "none is within its spread."
        lines.append(f"Best (lowest mean rollout MSE): {label[id(best)]}; of the others, {others}")
        methods = {"paired": "paired comparison over the same test trajectories (geometric-mean ratio, 95% t"
                   " interval)", "2se": "overlap of mean ± 2 SE (no per-trajectory rows)",
                   None: "unknown (no spread recorded)"}  # fmt: skip
        lines += ["Compared with the best by:"]
        lines += [f"- {methods[m]}: {', '.join(names)}" for m, names in by_method.items()]
    losing = [label[id(j)] for j in jobs if j.versus_baseline() == DOES_NOT_BEAT]
    if losing:
        lines.append(f"\n**Do not beat the physics-free baseline:** {', '.join(losing)}.")
    return [*lines, ""]


def write_csv(rows: Sequence[dict], path: Path) -> Path:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def log_wandb_table(jobs: Sequence[Job], rows: Sequence[dict], pictures: dict[str, Path], out_dir: Path,
                    project: str, mode: str) -> Path | None:  # fmt: skip
    """The table (with each job's frame) and the pictures as one wandb run in the sweep's group.

    Returns the run's local folder (None when ``mode == "disabled"``).
    """
    if mode == "disabled":
        return None
    import wandb

    sweep = next((j.sweep for j in jobs if j.sweep), out_dir.parent.name)
    run = wandb.init(
        project=project,
        group=sweep,
        name=f"{sweep}/report",
        job_type="report",
        dir=str(out_dir),
        mode=mode,
        config={"sweep_dir": str(out_dir.parent), "jobs": len(jobs)},
    )
    try:
        columns = [*COLUMNS, "frame"]
        data = []
        for job, row in zip(jobs, rows):
            frame = wandb.Image(job.frame_png) if job.frame_png and Path(job.frame_png).is_file() else None
            data.append([row[c] for c in COLUMNS] + [frame])
        run.log({"results": wandb.Table(columns=columns, data=data),
                 **{title: wandb.Image(str(p)) for title, p in pictures.items()}})  # fmt: skip
        folder = Path(run.dir).parent
    finally:
        run.finish()
    return folder


def build_report(
    sweep_dir: str | Path,
    out_dir: str | Path | None = None,
    highlight: tuple[int, int] | None = PAPER_CELL,
    wandb_mode: str = "offline",
    project: str | None = None,
    budget: float | None = None,
    budget_key: str = "rollout_mse",
) -> dict[str, Path]:
    """Everything of the module docstring for one multirun directory. Returns ``{what: path}``.

    With ``budget`` (an upper bound on the mean test ``budget_key``), :func:`pick_for_budget`'s pick leads
    ``report.md`` and is marked in the grid (blue frame, "budget pick") and the scatter (blue star).
    """
    sweep_dir = Path(sweep_dir)
    jobs = load_sweep(sweep_dir)
    pick = pick_for_budget(jobs, budget, budget_key) if budget is not None else None
    out = Path(out_dir) if out_dir is not None else sweep_dir / "report"
    out.mkdir(parents=True, exist_ok=True)
    keys = swept_axes(jobs)
    pictures: dict[str, Path] = {}
    if any(j.frame_png for j in jobs) or {"latent_size", "mp_steps"} & set(keys):
        pictures["grid"] = plot_grid(jobs, out / "grid.png", highlight, pick.pick if pick else None)
    pictures["speed_vs_error"] = plot_speed_error(jobs, out / "speed_vs_error.png", highlight, pick)
    if "radius" in keys:
        pictures["radius"] = plot_radius(jobs, out / "radius.png")
    rows = table_rows(jobs)
    outputs = dict(pictures)
    outputs["markdown"] = write_markdown(jobs, rows, pictures, sweep_dir, out / "report.md", pick)
    outputs["csv"] = write_csv(rows, out / "results.csv")
    if project is None:
        project = _job_config(jobs[0].folder).get("logger", {}).get("project", "gnsx")
    wandb_dir = log_wandb_table(jobs, rows, pictures, out, project, wandb_mode)
    if wandb_dir is not None:
        outputs["wandb"] = wandb_dir
    return outputs


def _parse_cell(text: str) -> tuple[int, int] | None:
    if text.lower() == "none":
        return None
    latent, mp = text.lower().split("x")
    return int(latent), int(mp)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.report", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("sweep_dir", help="a Hydra multirun directory (holds one folder per job)")
    parser.add_argument("--out", default=None, help="output folder (default: <sweep_dir>/report)")
    parser.add_argument(
        "--highlight",
        default=f"{PAPER_CELL[0]}x{PAPER_CELL[1]}",
        help="grid cell to frame, LATENTxMP (default: the paper's 64x5; 'none' for none)",
    )
    parser.add_argument(
        "--wandb",
        default="offline",
        choices=("offline", "online", "disabled"),
        help="the report's wandb run (default offline: `wandb sync` uploads it later)",
    )
    parser.add_argument("--project", default=None, help="wandb project (default: the jobs' logger.project)")
    parser.add_argument(
        "--budget",
        type=float,
        default=None,
        help="error budget: pick the fastest model whose mean test error (--budget-key) is at most this",
    )
    parser.add_argument("--budget-key", default="rollout_mse", choices=BUDGET_KEYS)
    args = parser.parse_args(argv)
    outputs = build_report(args.sweep_dir, args.out, _parse_cell(args.highlight), args.wandb, args.project,
                           args.budget, args.budget_key)  # fmt: skip
    print(Path(outputs["markdown"]).read_text())
    for what, path in outputs.items():
        print(f"{what}: {path}")
    return 0
