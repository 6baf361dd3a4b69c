"""The budget curve: how many training steps figure 9's cells need (``make budget``, sweeps/budget.yaml).

``python -m gnsx.evaluation.report.budget multirun/budget/main --out docs/fig9/budget``

Reads the jobs of the budget sweep (the paper's 64/5 with the grid's recipe at several lengths and seeds; the
learning rate's schedule is a fraction of each run, so a length is its own run, not a checkpoint of a longer
one) and writes ``budget.md`` (one row per job, then one per length with its seeds pooled, then the rule's
verdict), ``budget.json`` and ``budget.png`` (the raw test rollout error with its interval and the water's
final area against steps and against hours of one thread; the validation curves of every run against the
fraction of its run).

**The rule that picks the grid's budget** (written before the runs finished, in the issue's words): the
shortest length whose error, paired over the 16 test trajectories with seeds pooled, is within 1.3x of the
200k runs'. Made exact:

1. For each length L and each test trajectory t, the seed-pooled error is the geometric mean over L's
   finished seeds of the raw rollout MSE on t (:func:`pooled_errors`); the 200k reference is the same over the
   200k runs' seeds.
2. The ratio of L to 200k is the geometric mean over trajectories of pooled(L, t) / pooled(200k, t), with its
   95% t interval over the trajectories (:func:`gnsx.evaluation.spread.geometric_mean_interval`).
   Trajectories are the independent unit: every seed is scored on the same 16, so seeds are averaged within
   a trajectory rather than counted as more trajectories.
3. "Within 1.3x" is the point estimate: ratio <= :data:`WITHIN`. The interval is reported beside it.
4. Only lengths of at least :data:`MIN_BUDGET` steps are candidates (the grid must train at least that long),
   and a length is read only once both of its seeds have finished (:data:`SEEDS_NEEDED`), as is the 200k
   reference.
5. If no length below 200k qualifies, the grid runs at :data:`FALLBACK` steps (200k for 24 jobs does not fit
   the CPU budget), and the report says what that costs.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.evaluation.report.jobs import Job, finite_or_none, job_config, load_sweep
from gnsx.evaluation.spread import compare, geometric_mean_interval, mean_se

#: The rule's threshold: a length qualifies when its seed-pooled error is at most this times the 200k runs'.
WITHIN = 1.3
#: The reference length: the shipped weights' run (seed 0) and its second seed.
REFERENCE = 200_000
#: The shortest length the grid may train (the issue's floor).
MIN_BUDGET = 40_000
#: The grid's length when no shorter length is within :data:`WITHIN` of the reference.
FALLBACK = 100_000
#: Seeds a length needs, finished, before the rule reads it.
SEEDS_NEEDED = 2


def max_steps(job: Job) -> int | None:
    """The job's ``train.max_steps`` (its length: the schedule is a fraction of it), from its config."""
    value = job_config(job.folder).get("train", {}).get("max_steps")
    try:
        return int(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def by_length(jobs: Sequence[Job]) -> dict[int, list[Job]]:
    """Finished jobs grouped by length, each group sorted by seed."""
    groups: dict[int, list[Job]] = {}
    for job in jobs:
        steps = max_steps(job)
        if job.ok and steps is not None:
            groups.setdefault(steps, []).append(job)
    return {steps: sorted(group, key=lambda j: j.seed or 0) for steps, group in sorted(groups.items())}


def per_trajectory(job: Job, key: str = "rollout_mse") -> dict[int, float]:
    """``{trajectory: value}`` of a job's test rows (finite positive values only)."""
    out = {}
    for i, row in enumerate(job.rows):
        value = finite_or_none(row.get(key))
        if value is not None and value > 0:
            out[int(row.get("trajectory", i))] = value
    return out


def pooled_errors(group: Sequence[Job], key: str = "rollout_mse") -> dict[int, float]:
    """Per trajectory, the geometric mean over the group's seeds of ``key``, on the trajectories every seed has."""
    tables = [per_trajectory(job, key) for job in group]
    if not tables:
        return {}
    common = set.intersection(*(set(t) for t in tables))
    return {t: math.exp(float(np.mean([math.log(table[t]) for table in tables]))) for t in sorted(common)}


def ratio_to(group: Sequence[Job], reference: Sequence[Job]) -> dict[str, Any]:
    """The seed-pooled error of ``group`` over that of ``reference``, paired by trajectory (rule, steps 1-2)."""
    a, b = pooled_errors(group), pooled_errors(reference)
    common = sorted(a.keys() & b.keys())
    ratio, lo, hi, n = geometric_mean_interval([a[t] / b[t] for t in common])
    return {"ratio": ratio, "lo": lo, "hi": hi, "trajectories": n,
            "lower_on": sum(a[t] < b[t] for t in common)}  # fmt: skip


def baseline_ratio(job: Job) -> tuple[float, float, float, int]:
    """Geometric mean over test trajectories of the baseline's rollout MSE over the job's, with its interval."""
    base, model = per_trajectory(job, "baseline_mse"), per_trajectory(job)
    common = sorted(base.keys() & model.keys())
    return geometric_mean_interval([base[t] / model[t] for t in common])


def hours(job: Job) -> float | None:
    """Hours of one thread the job trained (the training clock: validation rollouts excluded)."""
    results = _results(job)
    seconds = finite_or_none(results.get("training_s")) or job.train_wall_s
    return seconds / 3600 if seconds else None


def _results(job: Job) -> dict:
    import json

    try:
        return json.loads((job.folder / "results.json").read_text())
    except (OSError, ValueError):
        return {}


def cpu_of(job: Job) -> str:
    """The CPU the job trained on, as its record names it ('not recorded' for records made before it did)."""
    return str(_results(job).get("cpu") or "not recorded")


def progress(job: Job) -> str:
    """How far an unfinished job got: "running, step N", "interrupted at step N" or its failure."""
    from gnsx.core.runstate import effective_status

    results = _results(job)
    status = effective_status(results) if results else job.status
    step = results.get("global_step")
    at = f", step {step:,}" if isinstance(step, int) else ""
    if status in ("running", "interrupted"):
        return f"{status}{at}"
    return f"{job.status}: {job.error}" if job.error else job.status


def decide(groups: dict[int, list[Job]]) -> dict[str, Any]:
    """The rule (module docstring): the grid's budget, or why it cannot be read yet."""
    reference = groups.get(REFERENCE, [])
    ratios = {steps: ratio_to(group, reference) for steps, group in groups.items()
              if steps != REFERENCE and reference}  # fmt: skip
    if len(reference) < SEEDS_NEEDED:
        return {
            "budget": None,
            "ratios": ratios,
            "why": f"the {REFERENCE:,}-step reference has {len(reference)} of {SEEDS_NEEDED} seeds finished",
        }
    pending = []
    for steps in sorted(s for s in groups if MIN_BUDGET <= s < REFERENCE):
        if len(groups[steps]) < SEEDS_NEEDED:
            pending.append(steps)
            continue
        if ratios[steps]["ratio"] <= WITHIN and not pending:
            return {"budget": steps, "ratios": ratios,
                    "why": f"{steps:,} steps is the shortest length of at least {MIN_BUDGET:,} whose seed-pooled "
                           f"error is within {WITHIN}x of the {REFERENCE:,}-step runs'"}  # fmt: skip
    if pending:
        return {
            "budget": None,
            "ratios": ratios,
            "why": "a shorter length is not finished: " + ", ".join(f"{s:,}" for s in pending),
        }
    return {
        "budget": FALLBACK,
        "ratios": ratios,
        "fallback": True,
        "why": f"no length below {REFERENCE:,} is within {WITHIN}x of it: the grid runs at {FALLBACK:,} steps",
    }


def _interval(ratio: float, lo: float, hi: float) -> str:
    if not math.isfinite(ratio):
        return "–"
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{ratio:.2f}x"
    return f"{ratio:.2f}x [{lo:.2f}, {hi:.2f}]"


def job_rows(groups: dict[int, list[Job]]) -> list[str]:
    """Markdown table: one row per finished job."""
    lines = ["| steps | seed | test rollout MSE ± SE | x baseline [95%] (wins) | final area / truth ± SE "
             "| hours of one thread | steps/s | CPU |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for steps, group in groups.items():
        for job in group:
            mse, se = mean_se(per_trajectory(job).values())
            base, lo, hi, n = baseline_ratio(job)
            model, ref = per_trajectory(job), per_trajectory(job, "baseline_mse")
            wins = sum(model[t] < ref[t] for t in model.keys() & ref.keys())
            area, area_se = mean_se(per_trajectory(job, "area_ratio_final").values())
            h, rate = hours(job), job.steps_per_s
            clock = f"{h:.2f} | {rate:.1f}" if h is not None and rate is not None else "– | –"
            lines.append(f"| {steps:,} | {job.seed} | {mse:.3g} ± {se:.2g} | {_interval(base, lo, hi)} ({wins}/{n}) "
                         f"| {area:.2f} ± {area_se:.2f} | {clock} | {cpu_of(job)} |")  # fmt: skip
    return lines


def pooled_rows(groups: dict[int, list[Job]], decision: dict[str, Any]) -> list[str]:
    """Markdown table: one row per length, seeds pooled, with its ratio to the 200k runs."""
    lines = ["| steps | seeds | seed-pooled error / the 200k runs' [95%] (lower on) | candidate |",
             "|---|---|---|---|"]  # fmt: skip
    for steps, group in groups.items():
        seeds = ",".join(str(j.seed) for j in group)
        if steps == REFERENCE:
            lines.append(f"| {steps:,} | {seeds} | reference | – |")
            continue
        r = decision["ratios"].get(steps)
        text = (
            f"{_interval(r['ratio'], r['lo'], r['hi'])} ({r['lower_on']}/{r['trajectories']})" if r else "–"
        )
        candidate = "below the floor" if steps < MIN_BUDGET else (
            f"needs {SEEDS_NEEDED} seeds" if len(group) < SEEDS_NEEDED else
            ("within" if r and r["ratio"] <= WITHIN else "not within"))  # fmt: skip
        lines.append(f"| {steps:,} | {seeds} | {text} | {candidate} |")
    return lines


def seed_check(groups: dict[int, list[Job]]) -> str | None:
    """Is the shipped 200k seed 0 a lucky seed? Seed 1 over seed 0, paired over the test trajectories."""
    reference = {job.seed: job for job in groups.get(REFERENCE, [])}
    if 0 not in reference or 1 not in reference:
        return None
    result = compare(reference[0].rows, reference[1].rows)
    verdict = {"A better": "seed 0 better", "B better": "seed 1 better"}.get(
        result["verdict"], result["verdict"]
    )
    base1 = baseline_ratio(reference[1])
    return (f"At {REFERENCE:,} steps seed 1 scores {_interval(*base1[:3])} the baseline; its error over seed 0's "
            f"(the shipped weights) is {_interval(result['ratio'], result['lo'], result['hi'])} over "
            f"{result['trajectories']} trajectories: {verdict}.")  # fmt: skip


def plot(groups: dict[int, list[Job]], path: Path) -> Path:
    """``budget.png``: error (per seed, and seed-pooled with its interval) and final area against steps and
    against hours of one thread; the validation curves against the fraction of each run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gnsx.evaluation.curve_file import read_curve

    fig, axes = plt.subplots(1, 4, figsize=(19, 4.4))
    ax_steps, ax_hours, ax_area, ax_curve = axes
    base_levels = []
    for steps, group in groups.items():
        pooled = pooled_errors(group)
        mean, lo, hi, _ = geometric_mean_interval(pooled.values())
        h = [x for x in (hours(j) for j in group) if x is not None]
        for ax, x in ((ax_steps, steps), (ax_hours, float(np.mean(h)) if h else None)):
            if x is None:
                continue
            ax.errorbar([x], [mean], yerr=[[mean - lo], [hi - mean]] if math.isfinite(lo) else None,
                        fmt="o", color="C0", capsize=4, label="seeds pooled, 95% interval")  # fmt: skip
        for job in group:
            err = geometric_mean_interval(per_trajectory(job).values())[0]
            ax_steps.plot([steps], [err], "x", color="grey", label="one seed")
            if hours(job) is not None:
                ax_hours.plot([hours(job)], [err], "x", color="grey", label="one seed")
            area, area_se = mean_se(per_trajectory(job, "area_ratio_final").values())
            ax_area.errorbar([steps], [area], yerr=[area_se], fmt="o", capsize=3,
                             color=f"C{job.seed or 0}", label=f"seed {job.seed}")  # fmt: skip
            base_levels.append(geometric_mean_interval(per_trajectory(job, "baseline_mse").values())[0])
            curve_path = job.folder / "curve.jsonl"
            if curve_path.is_file():
                vals = read_curve(curve_path)["val"]
                ax_curve.plot([v["step"] / steps for v in vals], [v["rollout_mse"] for v in vals], "-",
                              label=f"{steps // 1000}k seed {job.seed}")  # fmt: skip
    if base_levels:
        for ax in (ax_steps, ax_hours):
            ax.axhline(float(np.exp(np.mean(np.log(base_levels)))), ls="--", color="k", lw=1,
                       label="physics-free baseline")  # fmt: skip
    ax_steps.set(xscale="log", yscale="log", xlabel="training steps",
                 ylabel="test rollout MSE, raw (geometric mean)")  # fmt: skip
    ax_hours.set(xscale="log", yscale="log", xlabel="hours of one thread (training clock)")
    ax_area.axhline(1.0, ls="--", color="k", lw=1)
    ax_area.set(xscale="log", xlabel="training steps", ylabel="water area at the last frame / truth's")
    for ax in (ax_steps, ax_hours, ax_area):  # one legend entry per label
        handles, labels = ax.get_legend_handles_labels()
        unique = dict(zip(labels, handles, strict=False))
        ax.legend(unique.values(), unique.keys(), fontsize=8)
    ax_curve.set(yscale="log", xlabel="fraction of the run", ylabel="validation rollout MSE (8 trajectories)")
    if ax_curve.lines:
        ax_curve.legend(fontsize=7)
    else:
        ax_curve.text(0.5, 0.5, "no validation curves", ha="center", transform=ax_curve.transAxes)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(
        "The budget curve: the paper's 64/5, the grid's recipe, raw network (dots: seeds pooled; x: one seed)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gnsx.evaluation.report.budget",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("sweep", type=Path, help="the budget sweep's folder (multirun/budget/main)")
    parser.add_argument("--out", type=Path, required=True, help="folder for budget.md, .json and .png")
    args = parser.parse_args(argv)
    jobs = load_sweep(args.sweep)
    groups = by_length(jobs)
    if not groups:
        raise FileNotFoundError(f"{args.sweep}: no finished job yet")
    decision = decide(groups)
    unfinished = [j for j in jobs if not j.ok]
    command = f"python -m gnsx.evaluation.report.budget {args.sweep} --out {args.out}"
    budget = decision["budget"]
    verdict = (f"**The grid's budget: {budget:,} steps**: {decision['why']}." if budget is not None
               else f"**The budget cannot be read yet**: {decision['why']}.")  # fmt: skip
    lines = ["# The budget curve: how many steps figure 9's cells need", "",
             f"Rebuilt with `{command}`. The paper's 64/5 with the grid's recipe (sweeps/budget.yaml), raw network, "
             "scored on the 16 test trajectories; 'x baseline': geometric mean over trajectories of the "
             "physics-free baseline's rollout MSE over the model's, 95% t interval. Hours: the training clock "
             "(validation rollouts excluded) of one thread, on the CPU named in the row.", "",
             "![budget curve](budget.png)", "", "## Every run", ""]  # fmt: skip
    lines += job_rows(groups)
    lines += ["", "## Seeds pooled, against the 200k runs (the rule of gnsx/evaluation/report/budget.py)", ""]
    lines += pooled_rows(groups, decision)
    lines += ["", verdict, ""]
    check = seed_check(groups)
    if check:
        lines += [check, ""]
    if unfinished:
        lines += [
            "Not finished: " + ", ".join(f"`{j.folder.name}` ({progress(j)})" for j in unfinished) + ".",
            "",
        ]
    text = "\n".join(lines)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "budget.md").write_text(text)
    plot(groups, args.out / "budget.png")
    write_json(args.out / "budget.json", {
        "decision": {k: v for k, v in decision.items() if k != "ratios"},
        "ratios": {str(k): v for k, v in decision["ratios"].items()},
        "jobs": [{"steps": steps, "seed": j.seed, "folder": j.folder.name, "hours": hours(j),
                  "steps_per_s": j.steps_per_s, "cpu": cpu_of(j),
                  "baseline_ratio": baseline_ratio(j)[:3]} for steps, group in groups.items() for j in group],
    })  # fmt: skip
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
