"""What a sweep's numbers say: the speed/error Pareto front (:func:`pareto_front`), the best job and whether
each other job can be told apart from it (:func:`best_job`, :func:`versus_best`), whether the cells differ
beyond the seed spread at all (:func:`cells_against_seeds`) and along each axis (:func:`axis_trends`), and
the model a scene needs, the fastest within an error budget (:func:`pick_for_budget`, :func:`budget_lines`).

Each job is compared with the best one (lowest mean rollout MSE): paired over the same test trajectories
(:func:`gnsx.evaluation.spread.compare`) when both have per-trajectory rows, otherwise by the overlap of mean
± 2 SE; the table says which (``vs_best_method``).

With ``--budget E`` (``--budget-key``: rollout_mse, onestep_mse or emd): the model a scene needs, the
fastest successful job whose mean test error is at most E (:func:`pick_for_budget`), its speed ratio to
every other job and whether its error can be told apart from the best job's (paired over the test
trajectories with :func:`gnsx.evaluation.spread.compare` when both have per-trajectory rows, else mean ± 2 SE); it
leads ``report.md`` and is framed in blue in the grid and starred in the scatter.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field

from gnsx.evaluation.report.jobs import Job, finite_or_none, speed_source, split_seeds, swept_axes
from gnsx.evaluation.spread import TIED, compare


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
    candidates = [j for j in jobs if j.ok and finite_or_none(j.spread(key)[0]) is not None]
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
    return versus_reference(best_job(jobs, key), jobs, key, "best")


def versus_reference(
    best: Job | None, jobs: Sequence[Job], key: str = "rollout_mse", own: str = "reference"
) -> dict[int, tuple[str, str | None]]:
    """:func:`versus_best` against any job ``best`` (e.g. the paper's 64/5 cell); ``best`` itself gets
    ``(own, None)``."""
    out: dict[int, tuple[str, str | None]] = {}
    if best is None:
        return out
    best_mean, best_se = best.spread(key)
    for job in jobs:
        if not job.ok or finite_or_none(job.spread(key)[0]) is None:
            continue
        if job is best:
            out[id(job)] = (own, None)
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
        if j.ok and j.ms_per_frame(source) is not None and finite_or_none(j.spread(key)[0]) is not None
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
                f" The lowest {what} is {closest.label(keys)}'s, {mean_se_text(*closest.spread(result.key))}."
                if closest
                else ""
            )
        )
        return lines
    ms = pick.ms_per_frame(result.source)
    lines.append(
        f"**Pick: {pick.label(keys)}**: {ms:.3g} ms/frame, {what} {mean_se_text(*pick.spread(result.key))},"
        " the fastest model within the budget."
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
            f"Its {what} {told} the best model's"
            f" ({best.label(keys)}, {mean_se_text(*best.spread(result.key))})"
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


def mean_se_text(mean: float | None, se: float | None, fmt: str = ".2e") -> str:
    """``mean`` formatted with ``fmt``, then ``" ± se"`` when ``se`` is known; ``"n/a"`` when ``mean`` is None."""
    if mean is None:
        return "n/a"
    return f"{mean:{fmt}} ± {se:.1e}" if se is not None else f"{mean:{fmt}}"


def ratio_text(ratio: float | None, lo: float | None, hi: float | None) -> str:
    """A ratio as ``"1.23x [lo, hi]"`` (the interval only when both bounds are known), ``"n/a"`` when None."""
    if ratio is None:
        return "n/a"
    return f"{ratio:.2f}x [{lo:.2f}, {hi:.2f}]" if lo is not None and hi is not None else f"{ratio:.2f}x"


# -- seeds: is a difference between cells larger than what a reseed moves? -----------------------------------
def seed_groups(jobs: Sequence[Job], key: str = "rollout_mse") -> list[dict]:
    """For every cell trained with several seeds (all ok): ``{"job": the lowest seed's job, "seeds", "values"
    (the mean test ``key`` of each seed), "mean", "sd" (sample standard deviation over seeds), "se_within" (the
    lowest seed's standard error over trajectories)}``, cells in the order of their first job."""
    cells: dict[tuple, list[Job]] = {}
    for job in jobs:
        if job.ok and finite_or_none(job.spread(key)[0]) is not None:
            cells.setdefault(job.cell, []).append(job)
    out = []
    for members in cells.values():
        if len(members) < 2:
            continue
        members = sorted(members, key=lambda j: j.seed or 0)
        values = [float(j.spread(key)[0]) for j in members]
        mean = sum(values) / len(values)
        sd = (sum((v - mean) ** 2 for v in values) / (len(values) - 1)) ** 0.5
        out.append({"job": members[0], "seeds": [j.seed for j in members], "values": values, "mean": mean,
                    "sd": sd, "se_within": members[0].spread(key)[1]})  # fmt: skip
    return out


def cells_against_seeds(jobs: Sequence[Job], key: str = "rollout_mse") -> dict | None:
    """Whether the cells of a sweep differ by more than retraining moves one cell: a one-way F test on
    log10 of the mean test ``key``.

    The between-cell variance is that of the cells' lowest seeds (one job per cell, as the grid shows them);
    each of those is one draw of its cell, so it holds the cells' own differences plus one seed's scatter.
    The within-cell variance is pooled over the cells trained with several seeds (:func:`seed_groups`). When
    the cells do not differ, the ratio F of the two is ~1; a small p says that the grid as a whole ranks
    beyond the seed spread (it says nothing about any two particular cells). Logs, because errors spread in
    ratios. Assumes one seed variance for every cell, estimated from the cells that have seeds.

    Returns:
        None with fewer than 2 cells or no cell with several seeds; else ``{"cells", "df_cells", "df_seeds",
        "sd_cells", "sd_seeds" (sample sds of log10 key), "F", "p"}``.
    """
    from scipy import stats

    groups = seed_groups(jobs, key)
    primary = [finite_or_none(j.spread(key)[0]) for j in split_seeds(jobs)[0] if j.ok]
    primary = [math.log10(v) for v in primary if v is not None and v > 0]
    if len(primary) < 2 or not groups:
        return None
    logs = [[math.log10(v) for v in group["values"] if v > 0] for group in groups]
    logs = [values for values in logs if len(values) > 1]
    df_seeds = sum(len(values) - 1 for values in logs)
    within = sum((len(values) - 1) * statistics.variance(values) for values in logs)  # pooled sum of squares
    if df_seeds < 1 or within <= 0:
        return None
    var_cells = statistics.variance(primary)
    var_seeds = within / df_seeds
    ratio = var_cells / var_seeds
    return {"cells": len(primary), "df_cells": len(primary) - 1, "df_seeds": df_seeds,
            "sd_cells": var_cells**0.5, "sd_seeds": var_seeds**0.5, "F": ratio,
            "p": float(stats.f.sf(ratio, len(primary) - 1, df_seeds))}  # fmt: skip


def seeds_for_power(test: dict, power: float = 0.8, alpha: float = 0.05, most: int = 20) -> int | None:
    """Seeds per cell with which :func:`cells_against_seeds` would find the cells apart (p < ``alpha``) with
    probability ``power``, if every cell were trained that many times and entered as its seeds' mean.

    One-way random-effects model on log10 errors, from the test's own estimates: seed variance s^2 =
    ``sd_seeds``^2, cell variance c^2 = ``sd_cells``^2 - s^2 (the lowest seeds hold one seed's scatter too).
    With k seeds a cell mean scatters by c^2 + s^2 / k, and F / (1 + k c^2 / s^2) follows F(cells - 1,
    cells (k - 1)), so the power is ``P(F(cells - 1, cells (k - 1)) > F_crit / (1 + k c^2 / s^2))``. None when
    the estimated cell variance is not positive (no number of seeds would rank them) or above ``most``.
    """
    from scipy import stats

    cells = int(test["cells"])
    ratio = (test["sd_cells"] ** 2 - test["sd_seeds"] ** 2) / test["sd_seeds"] ** 2  # c^2 / s^2
    if ratio <= 0 or cells < 2:
        return None
    for k in range(2, most + 1):
        df1, df2 = cells - 1, cells * (k - 1)
        critical = stats.f.ppf(1 - alpha, df1, df2)
        if stats.f.sf(critical / (1 + k * ratio), df1, df2) >= power:
            return k
    return None


#: How each swept axis enters :func:`axis_trends`: (transform, what one unit of it is).
TREND_UNITS = {
    "latent_size": (math.log2, "doubling of the embedding size"),
    "mp_steps": (math.log2, "doubling of the message-passing steps"),
    "radius": (lambda r: r / 0.01, "0.01 of radius (data units)"),
}


def axis_trends(jobs: Sequence[Job], key: str = "rollout_mse") -> dict | None:
    """The error's trend along each swept axis over every seed of every cell: least squares of log10 of the
    mean test ``key`` on the axes (log2 of embedding size and MP steps, the radius per 0.01), with t intervals.

    Every trained job is one point, so the seeds of a cell count as its replicates and the residual scatter
    holds both the seed spread and how far the cells stray from a straight trend. Complements
    :func:`cells_against_seeds`: a grid whose cells cannot be ranked one by one may still show a trend along
    an axis. Assumes the trend is log-linear on each axis and the axes add up (no interaction).

    Returns:
        None when there is no swept axis or too few jobs (fewer than the terms + 2); else ``{"jobs", "df",
        "terms": [{"axis", "unit", "factor" (10**slope: the error's ratio per unit), "lo", "hi" (95%), "p"}]}``.
    """
    import numpy as np
    from scipy import stats

    axes = [k for k in swept_axes(jobs) if k in TREND_UNITS]
    points = [
        (j, finite_or_none(j.spread(key)[0]))
        for j in jobs
        if j.ok and all(getattr(j, k) is not None for k in axes)
    ]
    points = [(j, v) for j, v in points if v is not None and v > 0]
    terms = len(axes) + 1
    if not axes or len(points) < terms + 2:
        return None
    design = np.array([[1.0] + [TREND_UNITS[k][0](float(getattr(j, k))) for k in axes] for j, _ in points])
    target = np.log10([v for _, v in points])
    beta, *_ = np.linalg.lstsq(design, target, rcond=None)
    df = len(points) - terms
    residual = target - design @ beta
    cov = float(residual @ residual) / df * np.linalg.inv(design.T @ design)
    se = np.sqrt(np.diag(cov))
    half = stats.t.ppf(0.975, df) * se
    out = []
    for i, axis in enumerate(axes, start=1):
        t_value = beta[i] / se[i] if se[i] > 0 else math.inf
        out.append({"axis": axis, "unit": TREND_UNITS[axis][1], "factor": float(10 ** beta[i]),
                    "lo": float(10 ** (beta[i] - half[i])), "hi": float(10 ** (beta[i] + half[i])),
                    "p": float(2 * stats.t.sf(abs(t_value), df))})  # fmt: skip
    return {"jobs": len(points), "df": df, "terms": out}
