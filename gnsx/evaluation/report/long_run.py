"""A long run's validation curve, and whether it has gone flat: the learning study's winner trained long.

``python -m gnsx.evaluation.report.long_run docs/learning/long/paperlr [RUN ...] --out docs/learning``

Reads each run folder's ``curve.jsonl`` (written by ``train.curve_every_n_steps``: the raw network rolled out on
the validation trajectories every N steps, with the physics-free baseline's errors on the same trajectories)
and writes ``long_run.png`` (rollout MSE and the water's final area against training steps, the baseline's
level dashed) and ``long_run.md`` (one row per validation).

**Flat** (the issue's stopping rule, "its last three validations show it flat"): for each validation
trajectory, the rollout MSE of the last validation over that of the validation two before it; the geometric
mean of these ratios over trajectories with its 95% t interval (:func:`gnsx.evaluation.spread.geometric_mean_interval`).
An interval containing 1 reads "flat"; below 1, "still falling"; above 1, "rising".
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.evaluation.curve_file import read_curve
from gnsx.evaluation.spread import geometric_mean_interval, interval_contains_one

#: Validations compared by the flatness check: the last one against the one this many validations before.
FLAT_SPAN = 2


def validations(run: Path) -> tuple[list[dict], dict | None]:
    """``(validation rows in step order, the baseline row or None)`` of a run folder's ``curve.jsonl``."""
    path = Path(run) / "curve.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no curve (a run of train.py with train.curve_every_n_steps)")
    curve = read_curve(path)  # sorted by step, a resumed run's repeated steps counted once
    return curve["val"], curve["baseline"]


def baseline_ratio(row: dict, baseline: dict | None) -> tuple[float, float, float]:
    """Geometric mean over trajectories of baseline MSE / model MSE with its 95% interval (NaN without a baseline)."""
    if baseline is None or "rollout_mse_per_trajectory" not in row:
        return float("nan"), float("nan"), float("nan")
    ratios = np.asarray(baseline["rollout_mse_per_trajectory"]) / np.asarray(
        row["rollout_mse_per_trajectory"]
    )
    mean, lo, hi, _ = geometric_mean_interval(ratios)
    return mean, lo, hi


def flatness(vals: Sequence[dict], span: int = FLAT_SPAN) -> dict[str, Any] | None:
    """The last validation's rollout MSE over the one ``span`` validations before, per trajectory, as a geometric
    mean with its 95% interval and a verdict; None with fewer than ``span + 1`` validations."""
    if len(vals) <= span:
        return None
    last, before = vals[-1], vals[-1 - span]
    ratios = np.asarray(last["rollout_mse_per_trajectory"]) / np.asarray(before["rollout_mse_per_trajectory"])
    mean, lo, hi, n = geometric_mean_interval(ratios)
    verdict = "flat" if interval_contains_one(lo, hi) else ("still falling" if hi < 1 else "rising")
    return {"from_step": before["step"], "to_step": last["step"], "ratio": mean, "lo": lo, "hi": hi,
            "trajectories": n, "verdict": verdict}  # fmt: skip


def table(name: str, vals: Sequence[dict], baseline: dict | None) -> list[str]:
    """Markdown rows: step, rollout MSE ± SE, x baseline [95%], one-step MSE, final area ± SE."""
    header = "| step | rollout MSE ± SE | x baseline [95%] | one-step MSE | final area / truth ± SE |"
    lines = [f"### {name}", "", header, "|---|---|---|---|---|"]
    for row in vals:
        mean, lo, hi = baseline_ratio(row, baseline)
        ratio = f"{mean:.2f}x [{lo:.2f}, {hi:.2f}]" if np.isfinite(mean) else "–"
        area = f"{row['area_ratio_final']:.2f} ± {row['area_ratio_final_se']:.2f}"
        lines.append(f"| {row['step']:,} | {row['rollout_mse']:.3g} ± {row['rollout_mse_se']:.2g} | {ratio} "
                     f"| {row['onestep_mse']:.2e} | {area} |")  # fmt: skip
    flat = flatness(vals)
    lines.append("")
    if flat is None:
        lines.append(f"Flatness: needs {FLAT_SPAN + 1} validations, has {len(vals)}.")
    else:
        lines.append(f"Flatness: rollout MSE at step {flat['to_step']:,} over step {flat['from_step']:,}, "
                     f"{flat['ratio']:.2f}x [{flat['lo']:.2f}, {flat['hi']:.2f}] over {flat['trajectories']} "
                     f"trajectories: **{flat['verdict']}**.")  # fmt: skip
    return lines + [""]


def plot(runs: dict[str, tuple[list[dict], dict | None]], path: Path) -> Path:
    """``long_run.png``: rollout MSE (log) and final area against training steps, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_err, ax_area) = plt.subplots(1, 2, figsize=(12, 4.2))
    for name, (vals, baseline) in runs.items():
        steps = [r["step"] for r in vals]
        (line,) = ax_err.plot(steps, [r["rollout_mse"] for r in vals], "o-", label=name)
        if baseline is not None:
            ax_err.axhline(baseline["rollout_mse"], ls="--", color=line.get_color(), lw=1,
                           label=f"physics-free baseline ({name}'s trajectories)")  # fmt: skip
        ax_area.plot(steps, [r["area_ratio_final"] for r in vals], "o-", label=name)
    ax_err.set(yscale="log", xlabel="training step", ylabel="validation rollout MSE, raw network")
    ax_area.axhline(1.0, ls="--", color="k", lw=1)
    ax_area.set(xlabel="training step", ylabel="water area at the last frame / truth's")
    for ax in (ax_err, ax_area):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Long run: raw validation rollout error and the water's area")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gnsx.evaluation.report.long_run",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("runs", nargs="+", type=Path, help="run folders holding curve.jsonl")
    parser.add_argument("--out", type=Path, required=True, help="folder for long_run.png, .md and .json")
    args = parser.parse_args(argv)
    runs = {run.name: validations(run) for run in args.runs}
    command = f"python -m gnsx.evaluation.report.long_run {' '.join(map(str, args.runs))} --out {args.out}"
    lines = ["# The long runs: validation curves", "",
             f"Rebuilt with `{command}`. "
             "Raw network, the validation trajectories; 'x baseline': geometric mean over trajectories of the "
             "physics-free baseline's rollout MSE over the model's, 95% t interval.", "",
             "![long run](long_run.png)", ""]  # fmt: skip
    for name, (vals, baseline) in runs.items():
        lines += table(name, vals, baseline)
    text = "\n".join(lines)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "long_run.md").write_text(text)
    plot(runs, args.out / "long_run.png")
    write_json(args.out / "long_run.json", {name: {"flatness": flatness(vals), "validations": vals}
                                            for name, (vals, _) in runs.items()})  # fmt: skip
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
