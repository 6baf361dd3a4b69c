"""The sweep report from hand-made job folders: loading (failed, killed, missing jobs), the Pareto front, the
grid/scatter/radius pictures, the markdown table and the wandb table, errors with and without their spread."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from gnsx.evaluation.report import (
    budget_lines,
    build_report,
    grid_layout,
    load_job,
    load_sweep,
    main,
    markdown_table,
    pareto_front,
    pick_for_budget,
    speed_source,
    split_seeds,
    sweep_name,
    swept_axes,
    table_rows,
    versus_best,
)
from gnsx.evaluation.scoring import summarise


def _job(sweep_dir: Path, number: int, results: dict | None, hydra_model: dict | None = None) -> Path:
    """A job folder as Hydra + gnsx.training.run leave it: .hydra/config.yaml, results.json, a frame PNG."""
    folder = sweep_dir / str(number)
    (folder / ".hydra").mkdir(parents=True)
    model = hydra_model or (results or {}).get("model_config", {})
    (folder / ".hydra" / "overrides.yaml").write_text(
        json.dumps(
            [f"model.latent_size={model.get('latent_size')}", f"model.mp_steps={model.get('mp_steps')}"]
        )
    )
    (folder / ".hydra" / "config.yaml").write_text(
        json.dumps({"model": model, "logger": {"project": "gnsx-test"}, "sweep": {"name": "unit"}})
    )  # JSON is YAML
    if results is not None:
        if results.get("status") == "ok":
            frame = folder / "frame_0150.png"
            shade = 40 + 10 * number
            iio.imwrite(frame, np.full((64, 64, 3), shade, np.uint8))
            results.setdefault("frame_png", str(frame))
            results.setdefault("frame_truth_png", str(frame))
        (folder / "results.json").write_text(json.dumps({"job": number, "sweep": "unit", **results}))
    return folder


def _ok(latent: int, mp: int, mse: float, ms: float, radius: float = 0.035, bench_ms: float | None = None):
    return {
        "status": "ok",
        "error": None,
        "name": f"model.latent_size={latent},model.mp_steps={mp}",
        "model_config": {"latent_size": latent, "mp_steps": mp, "radius": radius},
        "parameters": latent * latent * mp,
        "train_steps": 100,
        "steps_per_s": 10.0,
        "train_wall_s": 10.0,
        "test": {
            "rollout_mse": mse,
            "onestep_mse": mse / 100,
            "emd": None,
            "baseline_mse": 0.05,
            "ms_per_frame": ms,
            "peak_memory_mb": 10.0 * latent / 16,
        },  # fmt: skip
        "bench": {"ms_per_frame": bench_ms, "peak_memory_mb": 100.0} if bench_ms else None,
    }


@pytest.fixture
def grid_sweep(tmp_path) -> Path:
    """A 2x2 grid (latent 64/16 x MP 5/1) with one diverged cell, plus a killed and a never-started job."""
    sweep = tmp_path / "grid"
    _job(sweep, 0, _ok(64, 5, mse=0.01, ms=20.0))
    _job(sweep, 1, _ok(64, 1, mse=0.03, ms=8.0))
    _job(sweep, 2, {"status": "failed", "error": "diverged: training loss is nan at step 12",
                    "name": "model.latent_size=16,model.mp_steps=5",
                    "model_config": {"latent_size": 16, "mp_steps": 5, "radius": 0.035}})  # fmt: skip
    _job(sweep, 3, _ok(16, 1, mse=0.02, ms=2.0))
    _job(sweep, 4, {"status": "running", "name": "model.latent_size=32,model.mp_steps=5"},
         hydra_model={"latent_size": 32, "mp_steps": 5})  # fmt: skip
    _job(sweep, 5, None, hydra_model={"latent_size": 32, "mp_steps": 1})
    (sweep / ".submitit").mkdir()  # launcher folders are not jobs
    return sweep


def _green_pixels(path: Path) -> int:
    image = iio.imread(path)[..., :3].astype(int)
    return int((np.abs(image - np.array([50, 205, 50])).sum(axis=-1) < 30).sum())


def test_pareto_front_keeps_the_undominated_points():
    points = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (2.5, 3.0), (0.5, 9.0)]
    assert pareto_front(points) == [5, 0, 1, 3]
    assert pareto_front([]) == []
    assert pareto_front([(1.0, 1.0), (1.0, 1.0)]) == [0]


def test_jobs_that_failed_were_killed_or_never_ran_are_failed(grid_sweep):
    jobs = load_sweep(grid_sweep)
    assert [j.job for j in jobs] == [0, 1, 2, 3, 4, 5]
    status = {j.job: (j.status, j.error) for j in jobs}
    assert status[2] == ("failed", "diverged: training loss is nan at step 12")
    assert status[4][0] == "failed" and "did not finish" in status[4][1]
    assert status[5][0] == "failed" and "no results.json" in status[5][1]
    # Their cells are known from the job's Hydra config.
    assert (jobs[5].latent_size, jobs[5].mp_steps) == (32, 1)
    assert swept_axes(jobs) == ["latent_size", "mp_steps"]
    assert speed_source(jobs) == "test"


def test_table_marks_the_pareto_front_and_lists_every_job(grid_sweep):
    jobs = load_sweep(grid_sweep)
    rows = table_rows(jobs)
    front = {(r["latent_size"], r["mp_steps"]) for r in rows if r["pareto"]}
    # 16/1 is fastest; 64/5 is the most accurate; 64/1 is slower than 16/1 and less accurate.
    assert front == {(16, 1), (64, 5)}
    table = markdown_table(rows)
    assert len(table.splitlines()) == 2 + len(jobs)
    assert "diverged: training loss is nan at step 12" in table
    assert rows[0]["train_min"] == pytest.approx(10.0 / 60)


def test_report_files_for_a_grid_sweep(grid_sweep, tmp_path):
    outputs = build_report(grid_sweep, wandb_mode="offline")
    assert {"grid", "speed_vs_error", "markdown", "csv", "wandb"} <= set(outputs)
    assert "radius" not in outputs  # the radius did not vary
    assert grid_layout(load_sweep(grid_sweep)) == ("latent_size", [64, 32, 16], "mp_steps", [5, 1])
    # The paper's 64/5 cell is framed in green (matplotlib's limegreen), and only when highlighted.
    assert _green_pixels(outputs["grid"]) > 500
    assert iio.imread(outputs["speed_vs_error"]).shape[2] in (3, 4)
    markdown = outputs["markdown"].read_text()
    assert "![grid](grid.png)" in markdown and "![speed_vs_error](speed_vs_error.png)" in markdown
    assert "Jobs: 6 (3 ok, 3 failed)" in markdown
    assert "Pareto front (ms/frame vs rollout MSE, fastest first): 16/1, 64/5." in markdown
    assert markdown.count("- job ") == 3
    assert "- job 5 (`model.latent_size=32,model.mp_steps=1`): no results.json" in markdown
    assert len(outputs["csv"].read_text().strip().splitlines()) == 7
    assert list(outputs["wandb"].glob("*.wandb"))
    # No highlight, another folder, no wandb run.
    again = build_report(grid_sweep, tmp_path / "elsewhere", highlight=None, wandb_mode="disabled")
    assert "wandb" not in again and again["grid"].parent == tmp_path / "elsewhere"
    assert _green_pixels(again["grid"]) == 0


def test_bench_figures_are_preferred_when_every_job_has_them(tmp_path):
    sweep = tmp_path / "bench"
    _job(sweep, 0, _ok(64, 5, mse=0.01, ms=20.0, bench_ms=4.0))
    _job(sweep, 1, _ok(16, 1, mse=0.02, ms=2.0, bench_ms=1.0))
    jobs = load_sweep(sweep)
    assert speed_source(jobs) == "bench"
    assert jobs[0].ms_per_frame("bench") == 4.0 and jobs[0].memory_mb("bench") == 100.0
    markdown = build_report(sweep, wandb_mode="disabled")["markdown"].read_text()
    assert "one inference step at WaterRamps size" in markdown


def test_radius_sweep_gets_error_and_speed_against_radius(tmp_path):
    sweep = tmp_path / "radius"
    for number, (radius, mse, ms) in enumerate([(0.023, 0.05, 3.0), (0.035, 0.02, 5.0), (0.058, 0.03, 12.0)]):
        results = _ok(64, 5, mse=mse, ms=ms, radius=radius)
        results["name"] = f"model.radius={radius}"
        _job(sweep, number, results)
    _job(sweep, 3, {"status": "failed", "error": "RuntimeError: out of memory", "name": "model.radius=0.1",
                    "model_config": {"latent_size": 64, "mp_steps": 5, "radius": 0.1}})  # fmt: skip
    jobs = load_sweep(sweep)
    assert swept_axes(jobs) == ["radius"]
    outputs = build_report(sweep, wandb_mode="disabled")
    assert iio.imread(outputs["radius"]).ndim == 3
    grid = iio.imread(outputs["grid"])
    assert grid.shape[1] > 2 * grid.shape[0]  # one row: 4 radii + ground truth
    markdown = outputs["markdown"].read_text()
    assert "Swept: radius." in markdown and "R=0.023, R=0.035" in markdown
    assert "RuntimeError: out of memory" in markdown


def test_radius_sweep_compares_against_the_default_radius(tmp_path):
    """Every job of a radius sweep is 64/5: the reference is the one at the dataset's default radius (the
    radius figure 9's grid trains with), not whichever 64/5 job comes first; without it there is none."""
    sweep = tmp_path / "radius"
    best = np.array([0.010, 0.020, 0.005, 0.040])
    factors = [np.array([3.0, 3.2, 2.9, 3.1]), 1.0, np.array([1.4, 1.2, 1.3, 0.85])]  # worse, -, tied
    for number, (radius, factor) in enumerate(zip([0.023, 0.035, 0.058], factors)):
        results = _with_rows(_ok(64, 5, 0.0, ms=5.0, radius=radius), list(best * factor), [0.05] * 4)
        results["name"] = f"model.radius={radius}"
        source = "the dataset's default_connectivity_radius" if radius == 0.035 else "model.radius"
        results["model_config"]["radius_source"] = source
        _job(sweep, number, results)
    # The reference point may come from figure 9's sweep: the report is still named after the radius sweep.
    results = json.loads((sweep / "1" / "results.json").read_text())
    (sweep / "1" / "results.json").write_text(json.dumps(results | {"sweep": "fig9_mini"}))
    jobs = load_sweep(sweep)
    assert [j.default_radius for j in sorted(jobs, key=lambda j: j.radius)] == [False, True, False]
    assert sweep_name(jobs) == "unit" and sweep_name([]) == "sweep"
    markdown = build_report(sweep, wandb_mode="disabled")["markdown"].read_text()
    against = markdown.split("## Against the paper's cell (R=0.035)")[1].split("##")[0]
    assert "R=0.058" in against.split("cannot be told apart from R=0.035")[1].split("\n")[0]
    assert "R=0.023" in against.split("worse than R=0.035")[1].split("\n")[0]
    # Without a job at the default radius, no radius is called the reference.
    import shutil

    shutil.rmtree(sweep / "1")
    markdown = build_report(sweep, wandb_mode="disabled")["markdown"].read_text()
    assert "The reference cell 64/5 at the dataset's default radius has no finished job." in markdown


def test_cli_prints_the_table(grid_sweep, capsys):
    assert main([str(grid_sweep), "--wandb", "disabled", "--highlight", "none"]) == 0
    printed = capsys.readouterr().out
    assert "# Sweep report: unit" in printed and "grid:" in printed


def test_missing_or_empty_directories_say_so(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such multirun directory"):
        load_sweep(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no job folders"):
        load_sweep(tmp_path / "empty")


# ------------------------------------------------------------------------------------------------ spreads


def _with_rows(results: dict, rollout: list[float], baseline: list[float], summary: bool = True) -> dict:
    """``results`` with per-trajectory rows and (``summary``) the test summary they give, as written since the
    spreads exist; without ``summary`` the rows sit next to an old summary (means only)."""
    rows = [
        {"trajectory": i, "particles": 10, "rollout_mse": r, "baseline_mse": b, "onestep_mse": r / 100,
         "ms_per_frame": 1.0, "peak_memory_mb": None}
        for i, (r, b) in enumerate(zip(rollout, baseline))
    ]  # fmt: skip
    means = {"rollout_mse": float(np.mean(rollout)), "baseline_mse": float(np.mean(baseline))}
    test = summarise(rows) if summary else means
    test["ms_per_frame"] = results["test"]["ms_per_frame"]
    return results | {"test": test, "rows": rows}


def _red_pixels(path: Path) -> int:
    image = iio.imread(path)[..., :3].astype(int)
    return int((np.abs(image - np.array([255, 0, 0])).sum(axis=-1) < 60).sum())


@pytest.fixture
def spread_sweep(tmp_path) -> Path:
    """Jobs with and without spreads: 64/5 best; 64/1 within its spread (paired); 16/1 clearly worse and
    losing to the baseline (paired); 16/5 with standard errors but no rows (2 SE overlap); 32/5 old-style."""
    sweep = tmp_path / "spread"
    best = np.array([0.010, 0.020, 0.005, 0.040])
    _job(sweep, 0, _with_rows(_ok(64, 5, 0.0, ms=20.0), list(best), [0.05] * 4))
    _job(sweep, 1, _with_rows(_ok(64, 1, 0.0, ms=8.0), list(best * [1.4, 1.2, 1.3, 0.85]), [0.05] * 4))
    _job(sweep, 2, _with_rows(_ok(16, 1, 0.0, ms=2.0), list(best * [3.0, 3.2, 2.9, 3.1]), list(best * 2)))
    no_rows = _ok(16, 5, mse=0.04, ms=4.0)
    no_rows["test"]["rollout_mse_se"] = 0.005
    _job(sweep, 3, no_rows)
    _job(sweep, 4, _ok(32, 5, mse=0.03, ms=6.0))
    return sweep


def test_report_ranks_jobs_by_their_spread(spread_sweep):
    jobs = {(j.latent_size, j.mp_steps): j for j in load_sweep(spread_sweep)}
    rows = {(r["latent_size"], r["mp_steps"]): r for r in table_rows(list(jobs.values()))}
    best = rows[(64, 5)]
    assert best["rollout_mse"] == pytest.approx(0.01875)
    assert best["rollout_mse_se"] == pytest.approx(np.std([0.01, 0.02, 0.005, 0.04], ddof=1) / 2)
    assert best["vs_best"] == "best"
    # Geometric mean 3.5x the baseline, but its ratios (5, 2.5, 10, 1.25) spread too widely to tell.
    assert best["baseline_ratio"] == pytest.approx((5 * 2.5 * 10 * 1.25) ** 0.25)
    assert best["baseline_ratio_lo"] < 1 < best["baseline_ratio_hi"]
    assert best["vs_baseline"] == "cannot be told apart from the baseline"
    assert (rows[(64, 1)]["vs_best"], rows[(64, 1)]["vs_best_method"]) == ("cannot be told apart", "paired")
    assert (rows[(16, 1)]["vs_best"], rows[(16, 1)]["vs_best_method"]) == ("worse", "paired")
    assert rows[(16, 1)]["baseline_ratio"] == pytest.approx(2 / np.exp(np.mean(np.log([3.0, 3.2, 2.9, 3.1]))))
    assert rows[(16, 1)]["vs_baseline"] == "does not beat the baseline"
    # Only an SE and no rows: mean ± 2 SE. 0.04 ± 0.01 and 0.019 ± 0.016 overlap.
    assert (rows[(16, 5)]["vs_best"], rows[(16, 5)]["vs_best_method"]) == ("cannot be told apart", "2se")
    assert rows[(16, 5)]["rollout_mse_se"] == 0.005 and rows[(16, 5)]["baseline_ratio_lo"] is None
    # An old results.json: means only, no spread to compare with, the ratio of means for the baseline.
    old = rows[(32, 5)]
    assert old["vs_best"] == "unknown" and old["vs_best_method"] is None and old["rollout_mse_se"] is None
    assert (
        old["baseline_ratio"] == pytest.approx(0.05 / 0.03)
        and old["vs_baseline"] == "cannot be told apart from the baseline"
    )
    assert set(versus_best(list(jobs.values())).values()) >= {("best", None), ("worse", "paired")}


def test_report_files_show_the_spread_and_the_losers(spread_sweep, grid_sweep):
    outputs = build_report(spread_sweep, wandb_mode="disabled")
    markdown = outputs["markdown"].read_text()
    table = [line for line in markdown.splitlines() if line.startswith("| ")]
    assert "rollout_mse_se" not in table[0] and "vs_best" in table[0]  # spreads inside their value's cell
    row_16_1 = next(line for line in table if "model.latent_size=16,model.mp_steps=1" in line)
    assert "**does not beat baseline**" in row_16_1 and "worse (paired)" in row_16_1
    assert " ± " in row_16_1 and "x [" in row_16_1  # mean ± se and the ratio's interval
    assert "cannot be told apart (±2 SE)" in markdown
    assert "**Do not beat the physics-free baseline:** 16/1." in markdown
    assert (
        "Best (lowest mean rollout MSE): 64/5; of the others, cannot be told apart from it: 64/1, 16/5."
        in (markdown)
    )
    assert "overlap of mean ± 2 SE (no per-trajectory rows): 16/5" in markdown
    csv_header = outputs["csv"].read_text().splitlines()[0]
    assert "rollout_mse_se" in csv_header and "vs_best_method" in csv_header
    # The losing cell's text is red in the grid, and its point a red cross in the scatter.
    assert _red_pixels(outputs["grid"]) > 50 and _red_pixels(outputs["speed_vs_error"]) > 50
    # No job loses to the baseline in the old-style grid sweep: nothing red (failed cells are dark red).
    old = build_report(grid_sweep, wandb_mode="disabled")
    assert _red_pixels(old["grid"]) == 0 and _red_pixels(old["speed_vs_error"]) == 0
    assert "Do not beat" not in old["markdown"].read_text()


def test_old_results_without_spreads_load(tmp_path):
    folder = _job(tmp_path / "old", 0, _ok(64, 5, mse=0.01, ms=2.0))
    job = load_job(folder)
    assert job.rows == [] and job.spread("rollout_mse") == (0.01, None)
    assert job.baseline_ratio() == (pytest.approx(5.0), None, None)
    # Old rows (no baseline_ratio key, no horizons) give the spread without the summary's new keys.
    results = _with_rows(_ok(64, 5, 0.0, ms=2.0), [0.01, 0.03], [0.02, 0.06], summary=False)
    job = load_job(_job(tmp_path / "rows", 0, results))
    mean, se = job.spread("rollout_mse")
    assert (mean, se) == (pytest.approx(0.02), pytest.approx(0.01))
    assert job.baseline_ratio()[0] == pytest.approx(2.0) and job.baseline_ratio()[1] == pytest.approx(2.0)


# ------------------------------------------------------------------------------------------------ budget


def _blue_pixels(path: Path) -> int:
    """Pixels of the budget pick's colour (matplotlib's dodgerblue)."""
    image = iio.imread(path)[..., :3].astype(int)
    return int((np.abs(image - np.array([30, 144, 255])).sum(axis=-1) < 30).sum())


def test_budget_picks_the_fastest_model_within_it(spread_sweep):
    jobs = load_sweep(spread_sweep)
    label = {id(j): j.label(["latent_size", "mp_steps"]) for j in jobs}
    # 64/5 is the best (1.9e-2) at 20 ms; 64/1 (2.0e-2) is within 2.5e-2 at 8 ms; the faster three are not.
    result = pick_for_budget(jobs, 2.5e-2)
    assert label[id(result.pick)] == "64/1" and label[id(result.best)] == "64/5"
    assert result.versus_best == ("cannot be told apart", "paired")
    assert result.paired["trajectories"] == 4 and result.paired["lo"] < 1 < result.paired["hi"]
    ratios = {label[id(job)]: (ratio, within) for job, ratio, _, within in result.others}
    assert ratios["64/5"] == (pytest.approx(20.0 / 8.0), True)
    assert ratios["16/1"] == (pytest.approx(2.0 / 8.0), False)
    lines = "\n".join(budget_lines(result, ["latent_size", "mp_steps"]))
    assert "**Pick: 64/1**: 8 ms/frame" in lines
    assert "cannot be told apart from the best model's (64/5" in lines and "over 4 trajectories" in lines
    assert "2.50x faster than 64/5." in lines
    assert "Faster but over the budget: 16/1, 16/5, 32/5." in lines
    # A looser budget admits 32/5, whose old results have no spread to compare with the best.
    looser = pick_for_budget(jobs, 3.5e-2)
    assert label[id(looser.pick)] == "32/5" and looser.versus_best == ("unknown", None)
    assert "cannot be compared with (no spread recorded)" in "\n".join(budget_lines(looser, []))
    # Any error: the fastest, worse than the best on paired trajectories.
    anything = pick_for_budget(jobs, 1.0)
    assert label[id(anything.pick)] == "16/1" and anything.versus_best == ("worse", "paired")
    assert "10.00x faster than 64/5" in "\n".join(budget_lines(anything, ["latent_size", "mp_steps"]))
    # Too tight: nothing within, and the report says which model comes closest.
    none = pick_for_budget(jobs, 1e-3)
    assert none.pick is None and none.others == []
    assert "**No model stays within the budget.** The lowest rollout MSE is 64/5's" in "\n".join(
        budget_lines(none, ["latent_size", "mp_steps"])
    )
    with pytest.raises(ValueError, match="key"):
        pick_for_budget(jobs, 1.0, key="ms_per_frame")


def test_budget_pick_leads_the_report_and_is_marked(spread_sweep, capsys):
    assert main([str(spread_sweep), "--wandb", "disabled", "--budget", "2.5e-2"]) == 0
    printed = capsys.readouterr().out
    assert "## The model for the budget" in printed and "**Pick: 64/1**" in printed
    # Before the pictures and the table: the answer first.
    assert printed.index("**Pick: 64/1**") < printed.index("![grid](grid.png)")
    report = spread_sweep / "report"
    marked = _blue_pixels(report / "grid.png"), _blue_pixels(report / "speed_vs_error.png")
    assert marked[0] > 200 and marked[1] > 100
    # Without a budget: no section, nothing blue.
    plain = build_report(spread_sweep, wandb_mode="disabled")
    assert "The model for the budget" not in plain["markdown"].read_text()
    assert _blue_pixels(plain["grid"]) == 0 and _blue_pixels(plain["speed_vs_error"]) == 0


def test_seeds_of_a_cell_are_one_grid_cell_and_a_seed_spread_line(spread_sweep, tmp_path):
    """A cell trained with several seeds shows its lowest seed in the grid and table, and its seed spread in
    report.md next to the cells that cannot be told apart from the paper's 64/5 (paired over trajectories)."""
    best = np.array([0.010, 0.020, 0.005, 0.040])
    for number, (seed, factor) in enumerate([(1, 1.1), (2, 0.95)], start=5):
        folder = _job(
            spread_sweep, number, _with_rows(_ok(64, 5, 0.0, ms=20.0), list(best * factor), [0.05] * 4)
        )
        config = json.loads((folder / ".hydra" / "config.yaml").read_text())
        (folder / ".hydra" / "config.yaml").write_text(json.dumps(config | {"seed": seed}))
    jobs = load_sweep(spread_sweep)
    primary, repeats = split_seeds(jobs)
    assert len(primary) == 5 and sorted(j.seed for j in repeats) == [1, 2]
    # The scatter shows the other seeds as grey rings beside their cell (none without them).
    from gnsx.evaluation.report.plots import plot_speed_error

    grey = np.array([127, 127, 127])
    with_seeds = iio.imread(plot_speed_error(primary, tmp_path / "a.png", repeats=repeats))[..., :3].astype(
        int
    )
    alone = iio.imread(plot_speed_error(primary, tmp_path / "b.png"))[..., :3].astype(int)
    assert (np.abs(with_seeds - grey).sum(-1) < 20).sum() > 20 + (np.abs(alone - grey).sum(-1) < 20).sum()
    assert next(j for j in primary if j.cell[:2] == (64, 5)).seed is None  # the unseeded (default) run first
    outputs = build_report(spread_sweep, wandb_mode="disabled")
    markdown = outputs["markdown"].read_text()
    assert "## Seed spread" in markdown and "| 64/5 |" in markdown
    means = [float(np.mean(best * f)) for f in (1.0, 1.1, 0.95)]
    assert f"{np.mean(means):.3e}" in markdown and f"{np.std(means, ddof=1):.2e}" in markdown
    assert "## Against the paper's cell (64/5)" in markdown
    against = markdown.split("## Against the paper's cell (64/5)")[1].split("##")[0]
    assert "64/1" in against.split("cannot be told apart from 64/5")[1].split("\n")[0]
    assert "16/1" in against.split("worse than 64/5")[1].split("\n")[0] and "raw network" in markdown
    assert f"from {min(float(np.mean(best)), 0.03):.3e}" in markdown  # across cells: lowest seeds only


def test_cells_against_seeds_says_whether_the_grid_ranks_beyond_retraining(tmp_path):
    """The one-way F test of the report's seed section: cells 10x apart with seeds within 10% rank; cells
    within their seeds' scatter do not; F and p are those of scipy's F distribution on log10 errors."""
    from scipy.stats import f as f_dist

    from gnsx.evaluation.report.analysis import cells_against_seeds

    def sweep(name: str, cell_mse: dict, seed_factors: list[float]) -> list:
        folder, number = tmp_path / name, 0
        for (latent, mp), mse in cell_mse.items():
            for seed, factor in enumerate(seed_factors if (latent, mp) == (64, 5) else [1.0]):
                job = _job(folder, number, _ok(latent, mp, mse=mse * factor, ms=1.0 + number))
                config = json.loads((job / ".hydra" / "config.yaml").read_text())
                (job / ".hydra" / "config.yaml").write_text(json.dumps(config | {"seed": seed}))
                number += 1
        return load_sweep(folder)

    apart = sweep("apart", {(64, 5): 0.01, (64, 1): 0.1, (16, 1): 1.0, (16, 5): 0.03}, [1.0, 1.1, 0.9])
    test = cells_against_seeds(apart)
    assert test["cells"] == 4 and test["df_cells"] == 3 and test["df_seeds"] == 2 and test["p"] < 0.01
    logs = np.log10([0.01, 0.1, 1.0, 0.03])
    seeds = np.log10([0.01, 0.011, 0.009])
    assert test["F"] == pytest.approx(np.var(logs, ddof=1) / np.var(seeds, ddof=1))
    assert test["p"] == pytest.approx(f_dist.sf(test["F"], 3, 2))
    together = sweep("together", {(64, 5): 0.02, (64, 1): 0.025, (16, 1): 0.018}, [1.0, 2.0, 0.5])
    assert cells_against_seeds(together)["p"] > 0.5
    markdown = build_report(tmp_path / "together", wandb_mode="disabled")["markdown"].read_text()
    assert "cannot be told apart from one another beyond the seed spread" in markdown
    assert cells_against_seeds(sweep("one_seed", {(64, 5): 0.02, (64, 1): 0.03}, [1.0])) is None


def test_axis_trends_recover_a_known_slope_and_say_when_there_is_none(tmp_path):
    """Least squares over every job: errors that halve per doubling of the embedding size and do not depend
    on the MP steps give x0.5 and x1 (numpy's lstsq and scipy's t); the report says which axis has a trend."""
    from gnsx.evaluation.report.analysis import axis_trends

    folder, number = tmp_path / "trend", 0
    for i, latent in enumerate((16, 32, 64, 128)):
        for j, mp in enumerate((1, 3, 5, 10)):
            # Halves per doubling of the width, with a +-5% checkerboard scatter that no axis explains.
            mse = 0.1 * (16 / latent) * 10 ** (0.02 * (-1) ** (i + j))
            _job(folder, number, _ok(latent, mp, mse=mse, ms=1.0 + number))
            number += 1
    jobs = load_sweep(folder)
    trends = axis_trends(jobs)
    assert trends["jobs"] == 16 and trends["df"] == 13
    width, depth = trends["terms"]
    assert width["axis"] == "latent_size" and width["factor"] == pytest.approx(0.5)
    assert 0.45 < width["lo"] < width["factor"] < width["hi"] < 0.55 and width["p"] < 1e-6
    assert depth["axis"] == "mp_steps" and depth["factor"] == pytest.approx(1.0) and depth["p"] > 0.9
    markdown = build_report(folder, wandb_mode="disabled")["markdown"].read_text()
    trend = markdown.split("## Trend along the axes")[1]
    assert "doubling of the embedding size: x0.50" in trend and "the error falls" in trend
    assert "doubling of the message-passing steps: x1.0" in trend and "no trend beyond the scatter" in trend
    assert axis_trends(jobs[:3]) is None  # fewer jobs than the terms + 2


def test_speed_vs_error_bars_are_95_percent_t_intervals(spread_sweep):
    from scipy.stats import t as student_t

    from gnsx.evaluation.report.plots import _interval_half_width

    jobs = {job.label(["latent_size", "mp_steps"]): job for job in load_sweep(spread_sweep)}
    best = jobs["64/5"]  # four trajectories with rows
    mean, se = best.spread("rollout_mse")
    assert _interval_half_width(best) == pytest.approx(se * student_t.ppf(0.975, 3))
    assert _interval_half_width(best) > 3 * se  # four trajectories: far wider than one SE
    assert _interval_half_width(jobs["32/5"]) == 0.0  # no spread recorded: no bar


def test_a_job_copied_without_its_config_keeps_its_seed(tmp_path):
    """A job folder committed without ``.hydra/`` (results.json and pictures only) still says its seed, from the
    Hydra overrides its results.json records: the F test of cells against seeds needs it."""
    from gnsx.evaluation.report.jobs import load_job

    folder = tmp_path / "model.latent_size=64,model.mp_steps=5,seed=2"
    folder.mkdir()
    overrides = ["model.latent_size=64", "model.mp_steps=5", "seed=2"]
    (folder / "results.json").write_text(json.dumps({"status": "ok", "overrides": overrides, "test": {}}))
    assert load_job(folder).seed == 2
    (folder / "results.json").write_text(json.dumps({"status": "ok", "overrides": overrides[:2], "test": {}}))
    assert load_job(folder).seed is None


def test_seeds_for_power_matches_a_simulated_grid():
    """The seeds per cell it names give ~80% power in a simulated random-effects grid; one fewer gives less;
    cells that do not differ beyond the seeds get None."""
    from scipy import stats

    from gnsx.evaluation.report.analysis import seeds_for_power

    cells, sd_seed, sd_cell_true = 16, 0.09, 0.06
    test = {"cells": cells, "sd_seeds": sd_seed, "sd_cells": (sd_cell_true**2 + sd_seed**2) ** 0.5}
    k = seeds_for_power(test)
    assert k is not None and k >= 3

    def simulated_power(seeds: int, runs: int = 1500) -> float:
        rng = np.random.default_rng(seeds)
        hits = 0
        for _ in range(runs):
            values = rng.normal(0, sd_cell_true, (cells, 1)) + rng.normal(0, sd_seed, (cells, seeds))
            hits += stats.f_oneway(*values).pvalue < 0.05
        return hits / runs

    assert simulated_power(k) >= 0.75
    assert simulated_power(k - 1) < 0.82
    assert seeds_for_power({"cells": cells, "sd_seeds": 0.09, "sd_cells": 0.08}) is None
    assert seeds_for_power({"cells": cells, "sd_seeds": 0.01, "sd_cells": 0.5}) == 2
