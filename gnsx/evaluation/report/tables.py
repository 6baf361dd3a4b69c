"""The sweep's tables: one row per job (:func:`table_rows`, :data:`COLUMNS`) as markdown, CSV and a wandb table.

* ``report.md``: the table of every job (failed ones with their reason) and the pictures; ``results.csv``.
* ``wandb/``: an offline wandb run (group = the sweep's name) holding the table as a ``wandb.Table`` and the
  pictures (``wandb sync`` uploads it).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gnsx.evaluation.report.analysis import (
    BudgetPick,
    axis_trends,
    best_job,
    budget_lines,
    cells_against_seeds,
    pareto_front,
    ratio_text,
    seed_groups,
    versus_best,
    versus_reference,
)
from gnsx.evaluation.report.jobs import (
    AXIS_LABELS,
    Job,
    all_retimed,
    finite_or_none,
    reference_jobs,
    speed_source,
    split_seeds,
    sweep_name,
    swept_axes,
)
from gnsx.evaluation.spread import DOES_NOT_BEAT, TIED

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
                "baseline_mse": finite_or_none(j.test.get("baseline_mse")),
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
        return ratio_text(value, row.get("baseline_ratio_lo"), row.get("baseline_ratio_hi"))
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
    sweep = sweep_name(jobs, sweep_dir.name)
    lines = [
        f"# Sweep report: {sweep}",
        "",
        f"Multirun directory: `{sweep_dir}`. Jobs: {len(jobs)} ({len(ok)} ok, {len(jobs) - len(ok)} failed).",
        f"Swept: {', '.join(AXIS_LABELS[k] for k in keys) or 'nothing among latent size, MP steps, radius'}.",
        "Speed and memory in the pictures: "
        + ("one inference step at WaterRamps size (`bench`)" if source == "bench" else "the test rollouts")
        + (
            "; every job retimed together in one process (`python -m gnsx.evaluation.report.retime`)."
            if source == "bench" and all_retimed(jobs)
            else "."
        ),
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

    sweep = sweep_name(jobs, out_dir.parent.name)
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


# -- the paper's cell, seeds and what the errors measure ------------------------------------------------------
def rules_line(jobs: Sequence[Job]) -> str:
    """What the error axis measures: the raw network (no rule on any job's test rollouts) or which jobs had
    rules on, named so that nobody reads a with-rules figure as the network's."""
    with_rules = [j for j in jobs if j.ok and any(j.rules.values())]
    if not with_rules:
        return ("Every error is the raw network's rollout (held only by the walls and ramps, as the MPM is; no "
                "rule of `rules=production`), and so is every speed: both measure the network alone.")  # fmt: skip
    names = ", ".join(f"`{j.name}`" for j in with_rules)
    return f"**Errors with rules** (model + rules, not the network alone) for: {names}."


def reference_lines(jobs: Sequence[Job], cell: tuple[int, int] | None, key: str = "rollout_mse") -> list[str]:
    """Which cells cannot be told apart from the reference cell (the paper's 64/5) on the test ``key``,
    paired over the same trajectories (:func:`versus_reference`)."""
    if cell is None:
        return []
    keys = swept_axes(jobs)
    # The lowest seed: the grid, scatter and table show that one.
    candidates = sorted((j for j in reference_jobs(jobs, cell) if j.ok), key=lambda j: j.seed or 0)
    reference = candidates[0] if candidates else None
    if reference is None:
        at = " at the dataset's default radius" if "radius" in keys else ""
        return [f"The reference cell {cell[0]}/{cell[1]}{at} has no finished job.", ""]
    verdicts = versus_reference(reference, jobs, key)
    groups: dict[str, list[str]] = {}
    for job in jobs:
        verdict = verdicts.get(id(job), ("", None))[0]
        if verdict and verdict != "reference":
            groups.setdefault(verdict, []).append(job.label(keys))
    label = reference.label(keys)
    lines = [f"## Against the paper's cell ({label})", ""]
    names = {TIED: "cannot be told apart from", "worse": "worse than", "better": "better than",
             "unknown": "no spread to compare with"}  # fmt: skip
    for verdict in (TIED, "better", "worse", "unknown"):
        if groups.get(verdict):
            lines.append(f"- {names[verdict]} {label} ({key}, paired over test trajectories where both have "
                         f"rows, else mean ± 2 SE): {', '.join(groups[verdict])}")  # fmt: skip
    return lines + [""]


def seed_lines(jobs: Sequence[Job], key: str = "rollout_mse") -> list[str]:
    """The cells trained with several seeds: each seed's mean test ``key``, their mean and standard deviation
    over seeds, beside the standard error over trajectories of one seed and the spread of the cells."""
    groups = seed_groups(jobs, key)
    if not groups:
        return []
    keys = swept_axes(jobs)
    lines = ["## Seed spread", "",
             f"| cell | seeds | {key} per seed | mean | sd over seeds | se over trajectories (lowest seed) |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for g in groups:
        values = ", ".join(f"{v:.3e}" for v in g["values"])
        se = "n/a" if g["se_within"] is None else f"{g['se_within']:.2e}"
        lines.append(f"| {g['job'].label(keys)} | {', '.join(map(str, g['seeds']))} | {values} | "
                     f"{g['mean']:.3e} | {g['sd']:.2e} | {se} |")  # fmt: skip
    primary = [finite_or_none(j.spread(key)[0]) for j in split_seeds(jobs)[0] if j.ok]
    primary = [v for v in primary if v is not None]
    if len(primary) > 1:
        lines += ["", f"Across cells (lowest seed each) the mean {key} runs from {min(primary):.3e} to "
                  f"{max(primary):.3e}; a difference between two cells smaller than about twice the seed sd "
                  "above is within what retraining moves."]  # fmt: skip
    test = cells_against_seeds(jobs, key)
    if test is not None:
        verdict = ("the cells differ beyond the seed spread" if test["p"] < 0.05 else
                   "the cells cannot be told apart from one another beyond the seed spread")  # fmt: skip
        lines += ["", f"Cells against seeds (one-way F test on log10 {key}): the {test['cells']} cells' lowest "
                  f"seeds spread by sd {test['sd_cells']:.3f} decades, one cell's seeds by {test['sd_seeds']:.3f} "
                  f"(pooled, {test['df_seeds']} df); F({test['df_cells']}, {test['df_seeds']}) = "
                  f"{test['F']:.2f}, p = {test['p']:.2g}: {verdict}."]  # fmt: skip
    return lines + [""]


def trend_lines(jobs: Sequence[Job], key: str = "rollout_mse") -> list[str]:
    """The error's trend along each swept axis over every seed of every cell (:func:`axis_trends`)."""
    trends = axis_trends(jobs, key)
    if trends is None:
        return []
    lines = ["## Trend along the axes", "",
             f"Least squares of log10 {key} over every trained job ({trends['jobs']} jobs, every seed, "
             f"{trends['df']} df; log-linear in each axis, no interaction): the error's ratio per",
             ""]  # fmt: skip
    for term in trends["terms"]:
        if term["hi"] < 1:
            verdict = "the error falls"
        elif term["lo"] > 1:
            verdict = "the error rises"
        else:
            verdict = "no trend beyond the scatter"
        lines.append(f"- {term['unit']}: x{term['factor']:.2f} [{term['lo']:.2f}, {term['hi']:.2f}] (95%), "
                     f"p = {term['p']:.2g}: {verdict}")  # fmt: skip
    return lines + [""]
    return lines + [""]
