"""The sweep's pictures (matplotlib): the paper's figure 9 grid (:func:`plot_grid`), speed against error with
the Pareto front (:func:`plot_speed_error`) and error and speed against the radius (:func:`plot_radius`).

* ``grid.png``: one frame of each job's first test rollout, rows the embedding size and columns the
  message-passing count (figure 9: capacity falls from top left to bottom right), each cell annotated with
  ms/frame, MB, rollout MSE ± its standard error, the baseline ratio with its interval and whether it can be
  told apart from the best cell (text in red when it does not beat the physics-free baseline), the paper's
  64/5 cell framed in green, failed jobs with their reason, and the ground truth's frame for reference. A
  sweep of one parameter (e.g. the radius) gives one row.
* ``speed_vs_error.png``: ms/frame against test rollout MSE (log-log) with 95% t intervals over the test
  trajectories (mean ± t(n-1) SE), the Pareto front
  marked (no other job is both faster and more accurate), models that do not beat the baseline in red.
* ``radius.png`` (when the radius varies): rollout and one-step error, and ms/frame, against the radius.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnsx.evaluation.report.analysis import BudgetPick, mean_se_text, pareto_front, ratio_text, versus_best
from gnsx.evaluation.report.jobs import (
    Job,
    finite_or_none,
    reference_jobs,
    speed_source,
    sweep_name,
    swept_axes,
)
from gnsx.evaluation.spread import DOES_NOT_BEAT, TIED

#: The paper's model (figure 9's green cell): (latent size, message-passing steps).
PAPER_CELL = (64, 5)
#: Colour of the budget's pick in the pictures (the paper's cell is limegreen, losers red).
PICK_COLOUR = "dodgerblue"

# -- pictures ------------------------------------------------------------------------------------------------
_VERSUS_BEST_TAGS = {"best": "best", TIED: "≈ best", "better": "better than best (paired)"}


def _cell_text(job: Job, source: str, versus: tuple[str, str | None] | None = None) -> str:
    ms, mb = job.ms_per_frame(source), job.memory_mb(source)
    first = f"{ms:.1f} ms/frame" if ms is not None else "? ms/frame"
    first += f", {mb:.0f} MB" if mb is not None else ""
    if job.rollout_mse is None:
        return first
    lines = [first, "MSE " + mean_se_text(*job.spread("rollout_mse"))]
    ratio = job.baseline_ratio()
    if ratio[0] is not None:
        lines.append("base/model " + ratio_text(*ratio))
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
    sweep = sweep_name(jobs)
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
                     budget: BudgetPick | None = None, repeats: Sequence[Job] = ()) -> Path:  # fmt: skip
    """ms/frame against test rollout MSE (95% interval bars), log-log, every successful job labelled, the
    Pareto front joined, jobs that do not beat the physics-free baseline in red; with a ``budget``, its pick
    starred in blue (and the budget drawn when it bounds the rollout MSE). ``repeats``: the other seeds of
    cells trained more than once (:func:`split_seeds`), drawn as grey rings joined to their cell, so that the
    seed spread stands beside the differences between cells."""
    import matplotlib.pyplot as plt

    source = speed_source(jobs)
    keys = swept_axes(jobs)
    points, shown = [], []
    for job in jobs:
        ms, mse = job.ms_per_frame(source), job.rollout_mse
        if job.ok and ms is not None and mse is not None and ms > 0 and mse > 0:
            points.append((ms, mse))
            shown.append(job)
    fig, ax = plt.subplots(figsize=(9, 5))
    if points:
        xs, ys = np.array(points).T
        half = np.array([_interval_half_width(job) for job in shown])
        # On a log axis the lower bar cannot reach zero: clip it just above.
        ax.errorbar(xs, ys, yerr=[np.minimum(half, 0.99 * ys), half], fmt="none", ecolor="0.4", elinewidth=1,
                    capsize=3, zorder=2.5)  # fmt: skip
        losing = np.array([job.versus_baseline() == DOES_NOT_BEAT for job in shown])
        ax.scatter(
            xs[~losing],
            ys[~losing],
            color="tab:blue",
            zorder=3,
            label="model (95% interval over test trajectories)",
        )
        if losing.any():
            ax.scatter(xs[losing], ys[losing], color="red", marker="X", s=70, zorder=3,
                       label="does not beat the baseline")  # fmt: skip
        reference = {id(j) for j in reference_jobs(shown, highlight)}
        ringed = False
        for job, (x, y) in zip(shown, points):
            ax.annotate(job.label(keys), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
            if id(job) in reference:
                at = " at the default radius" if "radius" in keys else ""
                ax.scatter([x], [y], s=220, facecolors="none", edgecolors="limegreen", linewidths=2, zorder=4,
                           label=None if ringed else f"paper's {highlight[0]}/{highlight[1]}{at}")  # fmt: skip
                ringed = True
        if budget is not None and budget.pick in shown:
            x, y = points[shown.index(budget.pick)]
            ax.scatter([x], [y], marker="*", s=320, color=PICK_COLOUR, zorder=5, label="budget pick")
        if budget is not None and budget.key == "rollout_mse":
            ax.axhline(budget.budget, ls="--", lw=1, color=PICK_COLOUR, label=f"budget {budget.budget:.3g}")
        seeds_drawn = False
        for job in repeats:
            ms, mse = job.ms_per_frame(source), job.rollout_mse
            cell = next((i for i, j in enumerate(shown) if j.cell == job.cell), None)
            if not job.ok or ms is None or mse is None or ms <= 0 or mse <= 0 or cell is None:
                continue
            ax.plot([points[cell][0], ms], [points[cell][1], mse], color="0.6", lw=0.8, zorder=2)
            ax.scatter([ms], [mse], s=40, facecolors="none", edgecolors="tab:gray", linewidths=1.5, zorder=3,
                       label=None if seeds_drawn else "another seed of the cell")  # fmt: skip
            seeds_drawn = True
        front = pareto_front(points)
        # A staircase: between two front points, the best error reachable at that speed is the slower one's.
        ax.plot(xs[front], ys[front], "-o", drawstyle="steps-post", color="tab:red", mfc="none", ms=11,
                zorder=2, label="Pareto front")  # fmt: skip
        ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_ticks(ax.xaxis)
        # Outside the axes: inside, it hides points wherever it goes.
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
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
    ax.set_title(f"{sweep_name(jobs)}: speed vs error", fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plain_log_ticks(axis) -> None:
    """Label a log axis at 1-2-5 steps in plain numbers: matplotlib's default labels every minor tick of a
    short range as "3x10^1", and the labels of a decade overlap."""
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(ScalarFormatter())
    axis.set_minor_formatter(NullFormatter())


def plot_radius(jobs: Sequence[Job], path: Path, repeats: Sequence[Job] = ()) -> Path:
    """Three panels against the connection radius: the rollout MSE (95% interval bars over test
    trajectories, the other seeds of a radius as grey rings, the mean over seeds joined, the physics-free
    baseline dashed), the one-step MSE, and ms/frame; failed radii marked. Rollout and one-step errors differ
    by ~10^6, so each gets its own axis."""
    import matplotlib.pyplot as plt

    source = speed_source(jobs)
    ok = sorted((j for j in jobs if j.ok and j.radius is not None), key=lambda j: j.radius)
    seeds = [j for j in repeats if j.ok and j.radius is not None]
    fig, (err_ax, step_ax, ms_ax) = plt.subplots(1, 3, figsize=(14, 4.2))
    radius = np.array([j.radius for j in ok])
    rollout = np.array([finite_or_none(j.rollout_mse) or np.nan for j in ok])
    if len(ok):
        half = np.array([_interval_half_width(j) for j in ok])
        err_ax.errorbar(radius, rollout, yerr=[np.minimum(half, 0.99 * rollout), half], fmt="o", color="tab:blue",
                        ecolor="0.4", capsize=3, label="lowest seed (95% interval over trajectories)")  # fmt: skip
        if seeds:
            err_ax.scatter([j.radius for j in seeds],
                           [finite_or_none(j.rollout_mse) or np.nan for j in seeds],
                           s=40, facecolors="none", edgecolors="tab:gray", linewidths=1.5,
                           label="another seed")  # fmt: skip
            means = [np.nanmean([finite_or_none(x.rollout_mse) or np.nan
                                 for x in [j, *seeds] if x.radius == j.radius])
                     for j in ok]  # fmt: skip
            err_ax.plot(radius, means, "-", color="tab:blue", lw=1, label="mean over seeds")
        baseline = [finite_or_none(j.test.get("baseline_mse")) for j in ok]
        if any(b is not None for b in baseline):
            err_ax.plot(radius, [np.nan if b is None else b for b in baseline], "--", color="tab:red", lw=1,
                        label="physics-free baseline")  # fmt: skip
        step_ax.plot(
            radius, [finite_or_none(j.test.get("onestep_mse")) or np.nan for j in ok], "-s", color="tab:green"
        )
        ms_ax.plot(radius, [j.ms_per_frame(source) or np.nan for j in ok], "-o", color="tab:orange")
    for job in jobs:
        if not job.ok and job.radius is not None:
            for ax in (err_ax, step_ax, ms_ax):
                ax.axvline(job.radius, color="darkred", ls=":", lw=1)
                ax.text(job.radius, 0.98, " failed", color="darkred", fontsize=7, va="top",
                        transform=ax.get_xaxis_transform())  # fmt: skip
    err_ax.set_yscale("log")
    err_ax.set_ylabel("test rollout MSE (data units$^2$)")
    if err_ax.get_legend_handles_labels()[0]:
        err_ax.legend(fontsize=7)
    step_ax.set_ylabel("test one-step MSE (data units$^2$)")
    what = "benchmark at WaterRamps size" if source == "bench" else "test rollout"
    ms_ax.set_ylabel("inference ms/frame")
    ms_ax.set_title(what, fontsize=9)
    for ax in (err_ax, step_ax, ms_ax):
        ax.set_xlabel("connection radius (data units)")
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{sweep_name(jobs)}: error and speed against radius")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _interval_half_width(job: Job, key: str = "rollout_mse") -> float:
    """Half-width of the 95% t interval of the mean test ``key`` over the job's trajectories (0 when its
    spread or trajectory count is unknown)."""
    from scipy.stats import t as student_t

    se = job.spread(key)[1]
    n = finite_or_none(job.test.get("trajectories")) or len(job.rows)
    if se is None or not n or n < 2:
        return 0.0
    return float(se * student_t.ppf(0.975, int(n) - 1))
