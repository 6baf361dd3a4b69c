"""``python -m gnsx.evaluation.report.learning <sweep dir> --out <dir>``: the learning study's curves and table
(``sweeps/learning.yaml``, docs/learning).

Every job of the sweep is one arm and one seed (``learning_arm=<arm>,seed=<s>``) with a ``curve.jsonl``
(:mod:`gnsx.evaluation.curve_file`): the raw network's rollout MSE and final water area on the validation
trajectories at evenly spaced points of its step budget, and the physics-free baseline on the same
trajectories. The report writes:

* ``curves.png``: validation rollout MSE against training time and against samples seen (each arm's mean over
  its seeds, the seeds thin), the baseline's level dashed, and the final area over the truth's against
  training time. With ``--budget-minutes M`` the time axis is the study's budget, ``M x step / max_steps``
  (the arms' step budgets are M minutes at each arm's calibrated rate), so that arms run under different
  machine loads stand on one axis; without it, the measured training time;
* ``report.md`` and ``learning.json``: one row per arm: what it changes against the base arm (read from the
  jobs' composed configs, so the table cannot drift from what ran), steps, measured ms per training step,
  samples, the final validation rollout MSE per seed and pooled (+- SE over trajectories), the ratio to the
  baseline and to the base arm (geometric means over trajectories with 95% t intervals, each trajectory's
  error the geometric mean of its seeds), and the final area over the truth's (+- SE).

Pairing: a trajectory's error varies by orders of magnitude from one scene to the next, so arms are compared
on the same trajectories by the ratio of their errors (:func:`gnsx.evaluation.spread.geometric_mean_interval`);
an interval that contains 1 means the two cannot be told apart at this budget.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.evaluation.curve_file import read_curve
from gnsx.evaluation.spread import geometric_mean_interval, interval_contains_one, mean_se

#: The arm every other arm is compared with.
BASE_ARM = "base"
#: Config keys that differ between jobs without changing what an arm is (paths, budgets, the seed).
IGNORED_KEYS = ("seed", "data.root", "train.max_steps", "train.curve_every_n_steps",
                "logger", "hydra", "threads", "sweep")  # fmt: skip
#: What the committed copy of a job keeps (no checkpoints: the curves and the record are the result).
KEPT_FILES = ("curve.jsonl", "results.json", ".hydra/config.yaml", ".hydra/overrides.yaml")


def _override(overrides: Sequence[str], key: str, default: str | None = None) -> str | None:
    for item in overrides:
        name, _, value = item.partition("=")
        if name == key:
            return value
    return default


def load_jobs(sweep_dir: str | Path, arm_key: str = "learning_arm") -> dict[str, dict[int, dict[str, Any]]]:
    """The sweep's jobs with a curve, by arm (the value of the swept ``arm_key``) and seed:
    ``{"dir", "results", "curve", "config"}``.

    Raises:
        FileNotFoundError: no folder, or no job with a ``curve.jsonl`` in it (named).
    """
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such sweep folder")
    arms: dict[str, dict[int, dict[str, Any]]] = {}
    for folder in sorted(p for p in sweep_dir.iterdir() if (p / "results.json").is_file()):
        results = json.loads((folder / "results.json").read_text())
        overrides = results.get("swept") or results.get("overrides") or []
        arm = _override(overrides, arm_key)
        if arm is None or not (folder / "curve.jsonl").is_file():
            continue
        config_path = folder / ".hydra" / "config.yaml"
        config = yaml.safe_load(config_path.read_text()) if config_path.is_file() else {}
        seed = int(_override(overrides, "seed", "0"))
        curve = read_curve(folder / "curve.jsonl")
        arms.setdefault(arm, {})[seed] = {"dir": folder, "results": results, "curve": curve, "config": config}
    if not arms:
        raise FileNotFoundError(
            f"{sweep_dir}: no job swept over {arm_key} with a curve.jsonl (make learning)"
        )
    order = [BASE_ARM] if BASE_ARM in arms else []
    return {arm: arms[arm] for arm in order + sorted(a for a in arms if a != BASE_ARM)}


def _flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(_flatten(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


def config_changes(config: dict, base: dict) -> list[str]:
    """``key=value`` for every setting of ``config`` that differs from ``base`` (both composed job configs),
    budgets, paths and the seed left out (:data:`IGNORED_KEYS`)."""
    mine, theirs = _flatten(config), _flatten(base)
    changed = []
    for key in sorted(mine.keys() | theirs.keys()):
        if any(key == k or key.startswith(k + ".") for k in IGNORED_KEYS):
            continue
        if mine.get(key) != theirs.get(key):
            value = mine.get(key)
            if isinstance(value, list) and len(value) > 3:  # e.g. the pairwise decoder's gravity vector
                value = "[...]"
            changed.append(f"{key}={value}")
    return changed


def final_row(job: dict) -> dict | None:
    """The last validation row of a job, or None before its first validation."""
    rows = job["curve"]["val"]
    return rows[-1] if rows else None


def _per_trajectory(jobs: dict[int, dict], key: str) -> np.ndarray:
    """``[seeds, trajectories]`` of a final-row per-trajectory list (seeds with a final row only)."""
    rows = [final_row(job) for job in jobs.values()]
    values = [row[key] for row in rows if row is not None and key in row]
    return np.array(values, dtype=np.float64) if values else np.zeros((0, 0))


def _geomean_over_seeds(values: np.ndarray) -> np.ndarray:
    """``[trajectories]``: each trajectory's geometric mean over the seeds (rows) of positive errors."""
    return np.exp(np.mean(np.log(values), axis=0))


def arm_summary(arm: str, jobs: dict[int, dict], base_jobs: dict[int, dict] | None) -> dict[str, Any]:
    """One arm's row of the table (see the module docstring); NaN where a figure cannot be computed yet."""
    finals = {seed: final_row(job) for seed, job in sorted(jobs.items())}
    done = {seed: row for seed, row in finals.items() if row is not None}
    results = [job["results"] for job in jobs.values()]
    steps_per_s = [r["steps_per_s"] for r in results if r.get("steps_per_s")]
    out: dict[str, Any] = {
        "arm": arm,
        "seeds": sorted(jobs),
        "finished": sorted(s for s, job in jobs.items() if job["results"].get("status") == "ok"),
        "steps": max((int(row["step"]) for row in done.values()), default=0),
        "samples": max((int(row["samples"]) for row in done.values()), default=0),
        "training_min": float(np.mean([row["time_s"] for row in done.values()]) / 60) if done else math.nan,
        "ms_per_step": 1000.0 / float(np.mean(steps_per_s)) if steps_per_s else math.nan,
        "rollout_mse_by_seed": {seed: float(row["rollout_mse"]) for seed, row in done.items()},
    }
    model = _per_trajectory(jobs, "rollout_mse_per_trajectory")
    area = _per_trajectory(jobs, "area_ratio_final_per_trajectory")
    out["rollout_mse"], out["rollout_mse_se"] = (
        mean_se(model.mean(axis=0)) if model.size else (math.nan, math.nan)
    )
    out["area_ratio"], out["area_ratio_se"] = (
        mean_se(area.mean(axis=0)) if area.size else (math.nan, math.nan)
    )
    baseline = next((job["curve"]["baseline"] for job in jobs.values() if job["curve"]["baseline"]), None)
    out["baseline_mse"] = float(baseline["rollout_mse"]) if baseline else math.nan
    out["x_baseline"] = (math.nan,) * 3
    if model.size and baseline and "rollout_mse_per_trajectory" in baseline:
        ratios = np.array(baseline["rollout_mse_per_trajectory"]) / _geomean_over_seeds(model)
        out["x_baseline"] = geometric_mean_interval(ratios)[:3]
    out["vs_base"] = (math.nan,) * 3
    base = _per_trajectory(base_jobs, "rollout_mse_per_trajectory") if base_jobs else np.zeros((0, 0))
    if arm != BASE_ARM and model.size and base.size and base.shape[1] == model.shape[1]:
        out["vs_base"] = geometric_mean_interval(_geomean_over_seeds(model) / _geomean_over_seeds(base))[:3]
    return out


def _interval(values: Sequence[float], digits: str = ".2f") -> str:
    centre, lo, hi = values
    if not math.isfinite(centre):
        return "–"
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{centre:{digits}}x"
    return f"{centre:{digits}}x [{lo:{digits}}, {hi:{digits}}]"


def _pm(value: float, se: float, spec: str = ".3g") -> str:
    if not math.isfinite(value):
        return "–"
    return f"{value:{spec}} ± {se:{spec}}" if math.isfinite(se) else f"{value:{spec}}"


def _number(value: float) -> str:
    return f"{value:.1f}" if math.isfinite(value) else "–"


def table(rows: Sequence[dict], changes: dict[str, list[str]]) -> list[str]:
    """The report's Markdown table, one line per arm."""
    lines = [
        "| arm | changes against base | steps | ms/step | train min | samples | rollout MSE by seed "
        "| rollout MSE ± SE | x baseline [95%] | / base [95%] | final area / truth ± SE |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        seeds = ", ".join(f"{v:.3g}" for _, v in sorted(row["rollout_mse_by_seed"].items())) or "–"
        if len(row["finished"]) < len(row["seeds"]) or not row["finished"]:
            seeds += " (running)"
        vs_base = "–" if row["arm"] == BASE_ARM else _interval(row["vs_base"])
        if row["arm"] != BASE_ARM and math.isfinite(row["vs_base"][0]):
            vs_base += " (tie)" if interval_contains_one(*row["vs_base"][1:]) else ""
        lines.append(
            f"| {row['arm']} | {'; '.join(changes.get(row['arm'], [])) or '–'} | {row['steps']:,} "
            f"| {_number(row['ms_per_step'])} | {_number(row['training_min'])} | {row['samples']:,} | {seeds} "
            f"| {_pm(row['rollout_mse'], row['rollout_mse_se'])} | {_interval(row['x_baseline'])} | {vs_base} "
            f"| {_pm(row['area_ratio'], row['area_ratio_se'], '.2f')} |"
        )
    return lines


def _minutes(row: dict, job: dict, budget_minutes: float | None) -> float:
    """A validation row's training time: the measured one, or its share of the arm's step budget."""
    if budget_minutes is None:
        return row["time_s"] / 60
    max_steps = (job["config"].get("train") or {}).get("max_steps") or row["step"]
    return budget_minutes * row["step"] / float(max_steps)


def plot_curves(arms: dict[str, dict[int, dict]], path: Path, budget_minutes: float | None = None) -> Path:
    """``curves.png``: rollout MSE against training minutes and samples, the final area against minutes."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    for index, (arm, jobs) in enumerate(arms.items()):
        colour = f"C{index % 10}"
        runs = [job for job in jobs.values() if job["curve"]["val"]]
        curves = [job["curve"]["val"] for job in runs]
        times = [[_minutes(r, job, budget_minutes) for r in job["curve"]["val"]] for job in runs]
        for rows, minutes in zip(curves, times):  # each seed, thin
            axes[0].plot(minutes, [r["rollout_mse"] for r in rows], color=colour, lw=0.6, alpha=0.5)
            axes[1].plot([r["samples"] for r in rows], [r["rollout_mse"] for r in rows], color=colour,
                         lw=0.6, alpha=0.5)  # fmt: skip
            axes[2].plot(minutes, [r.get("area_ratio_final", math.nan) for r in rows], color=colour, lw=0.6,
                         alpha=0.5)  # fmt: skip
        # The seeds' mean (geometric for the error) at the validation points they share.
        length = min(len(rows) for rows in curves) if curves else 0
        if length:
            minutes = np.mean([t[:length] for t in times], axis=0)
            samples = np.mean([[r["samples"] for r in rows[:length]] for rows in curves], axis=0)
            error = np.exp(
                np.mean([[math.log(r["rollout_mse"]) for r in rows[:length]] for rows in curves], 0)
            )
            area = np.mean(
                [[r.get("area_ratio_final", math.nan) for r in rows[:length]] for rows in curves], 0
            )
            axes[0].plot(minutes, error, color=colour, marker="o", ms=4, lw=2, label=arm)
            axes[1].plot(samples, error, color=colour, marker="o", ms=4, lw=2)
            axes[2].plot(minutes, area, color=colour, marker="o", ms=4, lw=2)
    baseline = next((j["curve"]["baseline"] for jobs in arms.values() for j in jobs.values()
                     if j["curve"]["baseline"]), None)  # fmt: skip
    if baseline is not None:
        for ax in axes[:2]:
            ax.axhline(baseline["rollout_mse"], color="k", ls="--", lw=1, label="physics-free baseline")
    axes[2].axhline(1.0, color="k", ls="--", lw=1)
    if budget_minutes is None:
        time_label = "training time (min, measured, validation excluded)"
    else:
        time_label = "training time (min of the budget: step / budget steps x budget)"
    axes[0].set_xlabel(time_label)
    axes[1].set_xlabel("training samples seen")
    axes[2].set_xlabel(time_label)
    axes[0].set_ylabel("validation rollout MSE, raw network (geometric mean of seeds)")
    axes[2].set_ylabel("water area at the last frame / truth's (mean over trajectories)")
    for ax in axes[:2]:
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    axes[2].grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=2)
    fig.suptitle("Learning study: raw validation rollout error and volume, per arm (thin lines: seeds)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def copy_jobs(arms: dict[str, dict[int, dict]], dest: Path) -> None:
    """Keep each finished job's curve, record and config under ``dest/<job folder>`` (no checkpoints), so
    that the report can be rebuilt from a commit and ``make learning`` skips the finished jobs."""
    for jobs in arms.values():
        for job in jobs.values():
            if job["results"].get("status") != "ok":
                continue
            target = dest / job["dir"].name
            # A job committed mid-run with its checkpoint (to resume on another machine) keeps none once done.
            shutil.rmtree(target / "checkpoints", ignore_errors=True)
            for name in KEPT_FILES:
                source = job["dir"] / name
                if source.is_file():
                    (target / name).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(source, target / name)


def build(
    sweep_dir: str | Path,
    out: str | Path,
    jobs_dest: str | Path | None = None,
    budget_minutes: float | None = None,
    arm_key: str = "learning_arm",
) -> dict[str, Any]:
    """Write ``curves.png``, ``report.md`` and ``learning.json`` into ``out``; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    arms = load_jobs(sweep_dir, arm_key)
    base_jobs = arms.get(BASE_ARM)
    base_config = next(iter(base_jobs.values()))["config"] if base_jobs else {}
    changes = {
        arm: config_changes(next(iter(jobs.values()))["config"], base_config) for arm, jobs in arms.items()
    }
    rows = [arm_summary(arm, jobs, base_jobs) for arm, jobs in arms.items()]
    plot_curves(arms, out / "curves.png", budget_minutes)
    trajectories = next((r["trajectories"] for jobs in arms.values() for j in jobs.values()
                         for r in j["curve"]["val"][-1:]), "?")  # fmt: skip
    lines = [
        "# Learning study: the table",
        "",
        f"Raw network, final validation point of each arm, {trajectories} validation trajectories. Rebuilt with",
        f"`python -m gnsx.evaluation.report.learning {sweep_dir} --out {out}"
        + ("" if budget_minutes is None else f" --budget-minutes {budget_minutes:g}")
        + ("" if arm_key == "learning_arm" else f" --arm-key {arm_key}")
        + "`.",
        "'x baseline': the physics-free baseline's rollout MSE over the arm's, '/ base': the arm's over the base",
        "arm's; both geometric means over trajectories (each trajectory's error the geometric mean of its",
        "seeds) with 95% t intervals; '(tie)': the interval contains 1. 'ms/step': measured beside a second",
        "job; 'train min': training time of the run, validation excluded (it varies with the machine's load:",
        "the budgets are in steps, sweeps/learning.yaml says why).",
        "",
        *table(rows, changes),
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))
    summary = {"sweep": str(sweep_dir), "arms": rows, "changes": changes}
    write_json(out / "learning.json", summary)
    if jobs_dest is not None:
        copy_jobs(arms, Path(jobs_dest))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.report.learning", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("sweep", type=Path, help="the study's sweep folder (make learning)")
    parser.add_argument(
        "--out", type=Path, required=True, help="folder for curves.png, report.md, learning.json"
    )
    parser.add_argument("--copy-jobs", type=Path, default=None, metavar="DIR",
                        help="keep each finished job's curve, record and config here (no checkpoints)")  # fmt: skip
    parser.add_argument("--budget-minutes", type=float, default=None, metavar="M",
                        help="time axis: M x step / max_steps (the equal budget); default: measured")  # fmt: skip
    parser.add_argument("--arm-key", default="learning_arm", metavar="KEY",
                        help="the swept group naming the arms (e.g. demo_arm); default: learning_arm")  # fmt: skip
    args = parser.parse_args(argv)
    build(args.sweep, args.out, args.copy_jobs, args.budget_minutes, args.arm_key)
    print((args.out / "report.md").read_text())
    print(f"wrote {args.out} (curves.png, report.md, learning.json)")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
