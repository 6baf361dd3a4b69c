"""Report of one Hydra multirun sweep: the paper's figure 9 grid, speed against error with the Pareto front, a
markdown table and a wandb table.

    python -m gnsx.evaluation.report multirun/fig9_mini/2026-11-26_13-00-00     # writes <that dir>/report/
    python -m gnsx.evaluation.report <sweep dir> --budget 3e-2    # + the fastest model with test rollout MSE <= 3e-2

Modules (outputs in ``<sweep dir>/report/``):

* :mod:`~gnsx.evaluation.report.jobs`: a job folder and a sweep as :class:`Job` s (the ``results.json`` schema).
* :mod:`~gnsx.evaluation.report.analysis`: the Pareto front, the best job and the fastest model within a budget.
* :mod:`~gnsx.evaluation.report.plots`: the pictures ``grid.png``, ``speed_vs_error.png`` and ``radius.png``.
* :mod:`~gnsx.evaluation.report.tables`: the table as ``report.md``, ``results.csv`` and a wandb run (``wandb/``).
* this package: :func:`build_report` (all of the above for one multirun directory) and the CLI :func:`main`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from gnsx.evaluation.report.analysis import (
    BUDGET_KEYS,
    BudgetPick,
    best_job,
    budget_lines,
    pareto_front,
    pick_for_budget,
    versus_best,
)
from gnsx.evaluation.report.jobs import (
    AXES,
    AXIS_LABELS,
    Job,
    job_config,
    load_job,
    load_sweep,
    speed_source,
    split_seeds,
    sweep_name,
    swept_axes,
)
from gnsx.evaluation.report.plots import (
    PAPER_CELL,
    PICK_COLOUR,
    grid_layout,
    plot_grid,
    plot_radius,
    plot_speed_error,
)
from gnsx.evaluation.report.tables import (
    COLUMNS,
    MARKDOWN_COLUMNS,
    log_wandb_table,
    markdown_table,
    reference_lines,
    rules_line,
    seed_lines,
    table_rows,
    trend_lines,
    write_csv,
    write_markdown,
)

__all__ = [
    "AXES",
    "AXIS_LABELS",
    "BUDGET_KEYS",
    "COLUMNS",
    "MARKDOWN_COLUMNS",
    "PAPER_CELL",
    "PICK_COLOUR",
    "BudgetPick",
    "Job",
    "best_job",
    "budget_lines",
    "build_report",
    "grid_layout",
    "load_job",
    "load_sweep",
    "log_wandb_table",
    "main",
    "markdown_table",
    "pareto_front",
    "pick_for_budget",
    "reference_lines",
    "rules_line",
    "seed_lines",
    "trend_lines",
    "split_seeds",
    "sweep_name",
    "plot_grid",
    "plot_radius",
    "plot_speed_error",
    "speed_source",
    "swept_axes",
    "table_rows",
    "versus_best",
    "write_csv",
    "write_markdown",
]


def build_report(
    sweep_dir: str | Path,
    out_dir: str | Path | None = None,
    highlight: tuple[int, int] | None = PAPER_CELL,
    wandb_mode: str = "offline",
    project: str | None = None,
    budget: float | None = None,
    budget_key: str = "rollout_mse",
) -> dict[str, Path]:
    """Every output of the submodules' docstrings (the pictures of :mod:`~gnsx.evaluation.report.plots`, the
    tables of :mod:`~gnsx.evaluation.report.tables`) for one multirun directory. Returns ``{what: path}``.

    With ``budget`` (an upper bound on the mean test ``budget_key``), :func:`pick_for_budget`'s pick leads
    ``report.md`` and is marked in the grid (blue frame, "budget pick") and the scatter (blue star).
    """
    sweep_dir = Path(sweep_dir)
    every_seed = load_sweep(sweep_dir)
    # One job per cell (its lowest seed) in the grid, scatter and table; the other seeds in "Seed spread".
    jobs, repeats = split_seeds(every_seed)
    pick = pick_for_budget(jobs, budget, budget_key) if budget is not None else None
    out = Path(out_dir) if out_dir is not None else sweep_dir / "report"
    out.mkdir(parents=True, exist_ok=True)
    keys = swept_axes(jobs)
    pictures: dict[str, Path] = {}
    if any(j.frame_png for j in jobs) or {"latent_size", "mp_steps"} & set(keys):
        pictures["grid"] = plot_grid(jobs, out / "grid.png", highlight, pick.pick if pick else None)
    pictures["speed_vs_error"] = plot_speed_error(jobs, out / "speed_vs_error.png", highlight, pick, repeats)
    if "radius" in keys:
        pictures["radius"] = plot_radius(jobs, out / "radius.png", repeats)
    rows = table_rows(jobs)
    outputs = dict(pictures)
    outputs["markdown"] = write_markdown(jobs, rows, pictures, sweep_dir, out / "report.md", pick)
    extra = [rules_line(jobs), "", *reference_lines(jobs, highlight), *seed_lines(every_seed),
             *trend_lines(every_seed)]  # fmt: skip
    outputs["markdown"].write_text(outputs["markdown"].read_text().rstrip("\n") + "\n\n" + "\n".join(extra))
    outputs["csv"] = write_csv(rows, out / "results.csv")
    if project is None:
        project = job_config(jobs[0].folder).get("logger", {}).get("project", "gnsx")
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
