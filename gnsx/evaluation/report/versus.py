"""``python -m gnsx.evaluation.report.versus <sweep dir> --data <dataset> --out <dir>``: the paper's figures
6-8 for two models trained for the same budget of training time (``make equal-budget``,
``sweeps/equal_budget.yaml``).

* ``fig6_training_loss.png``: the training loss against training time and against samples seen. Each model's
  loss is in its own normalised-acceleration units (the original's stds are widened by its larger noise,
  DeepMind's ``_combine_std``), so the two curves show each model's progress, not which fits better.
* ``fig7_validation.png``: the raw network's validation rollout MSE (mean +- 1 standard error over the
  validation trajectories) against training time and against samples seen, with each model's physics-free
  baseline level on the same trajectories (dashed; it differs slightly between the models because each rolls
  out from its own number of true input frames).
* ``fig8_strip.png``: truth | original | simplified every 40 frames of one test trajectory, the one whose mean
  of the two models' rollout MSEs is the median of the test split: a typical scene for both, chosen without
  looking at which model does better on it.
* ``report.md`` and ``versus.json``: the test table of each model (16 trajectories, raw), the paired
  comparison with its 95% interval, training steps, samples, steps/s and training time, inference speed and
  memory at WaterRamps size, and when each model first reached the other's final validation error.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.evaluation.curve_file import first_time_below, read_curve
from gnsx.evaluation.spread import compare, format_comparison

#: Line colours per model name (others get matplotlib's cycle).
COLOURS = {"simplified": "tab:blue", "original": "tab:orange"}
#: The order the strip and tables list models in: the paper's figure 8 (truth | original | simplified).
ORDER = ("original", "simplified")
STRIP_EVERY = 40


def load_runs(sweep_dir: str | Path) -> dict[str, dict[str, Any]]:
    """The finished runs of a sweep folder, by model name: ``{"dir", "results", "curve"}``.

    Raises:
        FileNotFoundError: no folder, or fewer than two finished runs with a ``curve.jsonl`` (named).
    """
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such sweep folder")
    runs: dict[str, dict[str, Any]] = {}
    for folder in sorted(p for p in sweep_dir.iterdir() if (p / "results.json").is_file()):
        results = json.loads((folder / "results.json").read_text())
        if results.get("status") != "ok" or not (folder / "curve.jsonl").is_file():
            continue
        name = results.get("model") or folder.name
        runs[name] = {"dir": folder, "results": results, "curve": read_curve(folder / "curve.jsonl")}
    if len(runs) < 2:
        raise FileNotFoundError(
            f"{sweep_dir}: {len(runs)} finished run(s) with a curve.jsonl; the comparison needs two "
            "(`make equal-budget` trains them)"
        )
    order = [n for n in ORDER if n in runs] + sorted(n for n in runs if n not in ORDER)
    return {name: runs[name] for name in order}


def _colour(name: str, index: int) -> str:
    return COLOURS.get(name, f"C{index + 2}")


def _smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Running mean over ``window`` rows (shorter at the start), for a readable loss curve."""
    if window <= 1 or len(values) < 2:
        return values
    cumulative = np.cumsum(np.insert(values, 0, 0.0))
    out = np.empty_like(values)
    for i in range(len(values)):
        lo = max(0, i + 1 - window)
        out[i] = (cumulative[i + 1] - cumulative[lo]) / (i + 1 - lo)
    return out


def plot_training_loss(runs: dict[str, dict], path: Path, smooth_rows: int = 20) -> Path:
    """Figure 6: the training loss against training minutes and samples seen (log y)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for i, (name, run) in enumerate(runs.items()):
        rows = run["curve"]["train"]
        if not rows:
            continue
        loss = _smooth(np.array([r["loss"] for r in rows], float), smooth_rows)
        minutes = np.array([r["time_s"] for r in rows]) / 60.0
        samples = np.array([r["samples"] for r in rows])
        for ax, x in zip(axes, (minutes, samples)):
            ax.plot(x, loss, color=_colour(name, i), label=name, lw=1.2)
    axes[0].set_xlabel("training time (min, validation excluded)")
    axes[1].set_xlabel("training samples seen")
    axes[0].set_ylabel(f"training loss (running mean of {smooth_rows} logged points)")
    for ax in axes:
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    fig.suptitle("Figure 6: training loss (each model in its own normalised units)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_validation(runs: dict[str, dict], path: Path) -> Path:
    """Figure 7: validation rollout MSE +- 1 SE against training minutes and samples seen, baselines dashed."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for i, (name, run) in enumerate(runs.items()):
        rows, colour = run["curve"]["val"], _colour(name, i)
        if not rows:
            continue
        mse = np.array([r["rollout_mse"] for r in rows], float)
        se = np.nan_to_num(np.array([r.get("rollout_mse_se") for r in rows], float))
        minutes = np.array([r["time_s"] for r in rows]) / 60.0
        samples = np.array([r["samples"] for r in rows])
        for ax, x in zip(axes, (minutes, samples)):
            ax.errorbar(x, mse, yerr=se, color=colour, marker="o", ms=4, capsize=3, label=f"{name} (raw)")
            baseline = run["curve"]["baseline"]
            if baseline is not None:
                ax.axhline(baseline["rollout_mse"], color=colour, ls="--", lw=1,
                           label=f"physics-free baseline ({name}'s input frames)")  # fmt: skip
    axes[0].set_xlabel("training time (min, validation excluded)")
    axes[1].set_xlabel("training samples seen")
    n = next((r["curve"]["val"][-1].get("trajectories") for r in runs.values() if r["curve"]["val"]), "?")
    axes[0].set_ylabel(f"validation rollout MSE (mean ± SE, {n} trajectories)")
    for ax in axes:
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    axes[1].legend(fontsize=8)
    fig.suptitle("Figure 7: validation rollout error of the raw network")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def crossings(runs: dict[str, dict]) -> list[dict[str, Any]]:
    """For each ordered pair (A, B): the training time at which A's validation error first reached B's final
    one (None: never within A's budget)."""
    out = []
    for a, run_a in runs.items():
        for b, run_b in runs.items():
            if a == b or not run_a["curve"]["val"] or not run_b["curve"]["val"]:
                continue
            final_a, final_b = run_a["curve"]["val"][-1], run_b["curve"]["val"][-1]
            reached = first_time_below(run_a["curve"]["val"], final_b["rollout_mse"])
            # Whether the two final errors differ by more than their combined standard error.
            se = math.hypot(final_a.get("rollout_mse_se") or 0.0, final_b.get("rollout_mse_se") or 0.0)
            apart = abs(final_a["rollout_mse"] - final_b["rollout_mse"]) > se
            out.append({"model": a, "reaches": b, "level": final_b["rollout_mse"],
                        "level_se": final_b.get("rollout_mse_se"), "level_time_s": final_b["time_s"],
                        "time_s": reached, "finals_apart": apart})  # fmt: skip
    return out


def crossing_line(item: dict) -> str:
    level = (f"{item['reaches']}'s final validation error ({item['level']:.3g} ± {_fmt(item.get('level_se'), '.2g')} "
             f"at {item['level_time_s'] / 60:.0f} min)")  # fmt: skip
    caveat = "" if item.get("finals_apart", True) else " The two final errors are within 1 SE of each other."
    if item["time_s"] is None:
        return f"- {item['model']} never reached {level} within its budget.{caveat}"
    return f"- {item['model']} first reached {level} at {item['time_s'] / 60:.1f} min of training.{caveat}"


def median_trajectory(rows_by_model: Sequence[Sequence[dict]], key: str = "rollout_mse") -> int:
    """The test trajectory whose mean of the models' ``key`` is the median (the lower middle one for an even
    count): a typical scene for every model, chosen without looking at which model wins on it."""
    by_traj: dict[int, list[float]] = {}
    for rows in rows_by_model:
        for i, row in enumerate(rows):
            by_traj.setdefault(int(row.get("trajectory", i)), []).append(float(row[key]))
    scores = sorted((float(np.mean(v)), t) for t, v in by_traj.items() if len(v) == len(rows_by_model))
    if not scores:
        raise ValueError(f"no test trajectory has a {key} for every model")
    return scores[(len(scores) - 1) // 2][1]


def strip_checkpoints(runs: dict[str, dict], checkpoints: dict[str, Path] | None = None) -> dict[str, Path]:
    """The weights figure 8 draws for each model: ``checkpoints[name]`` when given, else the run's
    ``checkpoints/last.ckpt`` (its final weights)."""
    given = checkpoints or {}
    return {name: given.get(name) or run["dir"] / "checkpoints" / "last.ckpt" for name, run in runs.items()}


def render_strip(
    runs: dict[str, dict],
    data_root: Path,
    trajectory: int,
    path: Path,
    checkpoints: dict[str, Path] | None = None,
) -> Path:
    """Figure 8: ground truth and each model's raw rollout every :data:`STRIP_EVERY` frames, from
    :func:`strip_checkpoints` (each run's final weights unless ``checkpoints`` names another file)."""
    import torch

    from gnsx.data.store import load_metadata, open_split
    from gnsx.evaluation.render import save_strip
    from gnsx.model.checkpoint import load_simulator
    from gnsx.model.rollout import rollout

    meta = load_metadata(data_root)
    traj = open_split(data_root, "test", meta)[trajectory]
    true = np.array(traj.position, dtype=np.float32)  # [T, N, D]
    types = np.array(traj.particle_type, dtype=np.int64)
    rollouts, titles = [true], ["truth"]
    for name, weights in strip_checkpoints(runs, checkpoints).items():
        simulator = load_simulator(weights)
        frames = simulator.input_frames
        position = torch.from_numpy(true)
        with torch.inference_mode():
            predicted = rollout(simulator, position[:frames].transpose(0, 1), torch.from_numpy(types),
                                true.shape[0] - frames)  # fmt: skip
        rollouts.append(np.concatenate([true[:frames], predicted.numpy()]))
        titles.append(name)
    count = (true.shape[0] - 1) // STRIP_EVERY + 1
    return save_strip(
        rollouts, types, meta.bounds_array(), path, titles=titles, every=STRIP_EVERY, count=count
    )


def _fmt(value: Any, spec: str = ".3g") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, spec)


def model_table(runs: dict[str, dict]) -> list[str]:
    """Markdown rows: the test metrics (raw network) and the training each model got."""
    lines = [
        "| model | parameters | steps | samples | steps/s | training (min) | test rollout MSE ± se | "
        "x baseline [95%] | beats it on | EMD ± se | ms/frame (test scenes) | ms/frame, peak MB (2,300 particles) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, run in runs.items():
        r, t = run["results"], run["results"].get("test") or {}
        bench = r.get("bench") or {}
        ratio = (f"{_fmt(t.get('baseline_ratio_geomean'), '.2f')}x [{_fmt(t.get('baseline_ratio_geomean_lo'), '.2f')}, "
                 f"{_fmt(t.get('baseline_ratio_geomean_hi'), '.2f')}]")  # fmt: skip
        lines.append(
            f"| {name} | {r.get('parameters', 0):,} | {r.get('global_step', 0):,} | {r.get('samples_seen', 0):,} | "
            f"{_fmt(r.get('steps_per_s'), '.1f')} | {_fmt((r.get('training_s') or float('nan')) / 60, '.1f')} | "
            f"{_fmt(t.get('rollout_mse'), '.2e')} ± {_fmt(t.get('rollout_mse_se'), '.1e')} | {ratio} | "
            f"{t.get('baseline_ratio_wins', '?')}/{t.get('trajectories', '?')} | "
            f"{_fmt(t.get('emd'), '.3f')} ± {_fmt(t.get('emd_se'), '.3f')} | {_fmt(t.get('ms_per_frame'), '.1f')} | "
            f"{_fmt(bench.get('ms_per_frame'), '.1f')}, {_fmt(bench.get('peak_memory_mb'), '.0f')} |"
        )
    return lines


def build(
    sweep_dir: Path,
    data_root: Path,
    out: Path,
    trajectory: int | None = None,
    checkpoints: dict[str, Path] | None = None,
) -> dict[str, Any]:
    """Every figure and table of the comparison into ``out``; returns what ``versus.json`` holds.
    ``checkpoints``: model name -> the weights figure 8 draws (default: each run's last.ckpt)."""
    runs = load_runs(sweep_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(runs)
    rows = {n: runs[n]["results"].get("rows") or [] for n in names}
    pictures = {
        "fig6": plot_training_loss(runs, out / "fig6_training_loss.png"),
        "fig7": plot_validation(runs, out / "fig7_validation.png"),
    }
    if trajectory is None:
        trajectory = median_trajectory([rows[n] for n in names])
    pictures["fig8"] = render_strip(runs, data_root, trajectory, out / "fig8_strip.png", checkpoints)
    a, b = names[0], names[1]
    paired = {key: compare(rows[a], rows[b], key) for key in ("rollout_mse", "emd")}
    cross = crossings(runs)
    summary = {
        "sweep": str(sweep_dir),
        "models": names,
        "trajectory": trajectory,
        "strip_checkpoints": {n: str(path) for n, path in strip_checkpoints(runs, checkpoints).items()},
        "paired": paired,
        "crossings": cross,
        "runs": {
            n: {
                k: runs[n]["results"].get(k)
                for k in (
                    "parameters",
                    "global_step",
                    "samples_seen",
                    "steps_per_s",
                    "training_s",
                    "validation_s",
                    "threads",
                    "precision",
                    "test",
                    "bench",
                    "model_config",
                )
            }
            for n in names
        },  # fmt: skip
        "baseline_val": {n: runs[n]["curve"]["baseline"] for n in names},
        "pictures": {k: p.name for k, p in pictures.items()},
    }
    write_json(out / "versus.json", summary)
    budgets = {n: (runs[n]["results"].get("training_s") or float("nan")) / 60 for n in names}
    lines = [
        f"# {' vs '.join(names)}: equal training-time budget",
        "",
        f"Runs: `{sweep_dir}`. Training time per model (validation excluded): "
        + ", ".join(f"{n} {budgets[n]:.1f} min" for n in names)
        + ". Raw network (no rules) everywhere.",
        "",
        "## Test trajectories (raw network)",
        "",
        *model_table(runs),
        "",
        "Paired over the test trajectories (geometric mean of the per-trajectory ratio, 95% t interval):",
        "",
        *(f"- {format_comparison(p, a, b)}" for p in paired.values()),
        "",
        "## Validation curves",
        "",
        *(crossing_line(c) for c in cross),
        "",
        "![figure 6](fig6_training_loss.png)",
        "",
        "![figure 7](fig7_validation.png)",
        "",
        f"## Figure 8: test trajectory {trajectory}",
        "",
        "The trajectory whose mean of the two models' rollout MSEs is the median of the test split. Rows: "
        + " | ".join(["truth", *names])
        + f", every {STRIP_EVERY} frames.",
        "",
        "![figure 8](fig8_strip.png)",
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.report.versus", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "sweep", type=Path, help="sweep folder with one finished run per model (make equal-budget)"
    )
    parser.add_argument(
        "--data", type=Path, required=True, help="the dataset the runs trained on (test split)"
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="folder for the figures, report.md, versus.json"
    )
    parser.add_argument(
        "--trajectory", type=int, default=None, help="test trajectory of figure 8 (default: median)"
    )
    parser.add_argument("--checkpoint", action="append", default=[], metavar="MODEL=PATH",
                        help="weights figure 8 draws for MODEL (default: the run's last.ckpt); repeatable")  # fmt: skip
    args = parser.parse_args(argv)
    checkpoints = {}
    for item in args.checkpoint:
        name, sep, path = item.partition("=")
        if not sep or not Path(path).is_file():
            raise FileNotFoundError(f"--checkpoint {item}: expected MODEL=PATH of an existing checkpoint")
        checkpoints[name] = Path(path)
    if not (args.data / "metadata.json").is_file():
        raise FileNotFoundError(f"--data {args.data}: no gnsx dataset here (metadata.json missing)")
    summary = build(args.sweep, args.data, args.out, args.trajectory, checkpoints)
    print((args.out / "report.md").read_text())
    print(f"wrote {args.out} ({', '.join(summary['pictures'].values())}, report.md, versus.json)")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
