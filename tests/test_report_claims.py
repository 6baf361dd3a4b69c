"""The paper's claims as a report (gnsx.evaluation.report.claims): tiny synthetic report folders on which
each verdict rule can come out either way, the inputs it lacks, and the real docs/ folders."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from gnsx.core.cli import run_main
from gnsx.evaluation.report.cells import GRID_COLUMNS, load_grid, side_by_side
from gnsx.evaluation.report.claims import (
    NOT_MEASURED,
    NOT_REPRODUCED,
    REPRODUCED,
    UNTOLD,
    build,
    claim_depth,
    claim_linear_cost,
    claim_memory,
    claim_pareto,
    claim_radius,
    claim_training_time,
    claim_width,
    hours_to_final,
    main,
)

REPO = Path(__file__).resolve().parents[1]
TRAJECTORIES = 16
#: Each test trajectory's own difficulty, shared by every cell (what pairing takes out).
SCENES = np.random.default_rng(0).lognormal(0.0, 1.0, TRAJECTORIES) * 0.02


def _spec(level=1.0, ms=None, mb=None, noise=0.05, seed=0, mp=5, latent=64):
    """One job: its error level (x the scenes), per-trajectory noise (log sd), ms/frame and MB."""
    return {"level": level, "ms": ms if ms is not None else 10.0 * mp, "mb": mb if mb is not None else latent,
            "noise": noise, "seed": seed}  # fmt: skip


def make_grid(folder: Path, jobs: dict[tuple, list[dict] | dict], radius: float = 0.035, rows: bool = True):
    """A report folder: results.csv (lowest seeds) and jobs/<name>/ (results.json + .hydra/config.yaml).

    ``jobs``: ``{(latent, mp) or (latent, mp, radius): spec or [spec per seed]}`` (:func:`_spec`).
    """
    table = []
    for n, (key, specs) in enumerate(jobs.items()):
        latent, mp, r = (*key, radius)[:3]
        for spec in specs if isinstance(specs, list) else [specs]:
            rng = np.random.default_rng(1000 * n + spec["seed"])
            errors = spec["level"] * SCENES * rng.lognormal(0.0, spec["noise"], TRAJECTORIES)
            name = f"model.latent_size={latent},model.mp_steps={mp},model.radius={r},seed={spec['seed']}"
            mean, se = float(errors.mean()), float(errors.std(ddof=1) / np.sqrt(TRAJECTORIES))
            if rows:
                job = folder / "jobs" / name
                (job / ".hydra").mkdir(parents=True)
                model = {"latent_size": latent, "mp_steps": mp, "radius": r}
                (job / ".hydra" / "config.yaml").write_text(
                    json.dumps({"seed": spec["seed"], "model": model})
                )
                (job / "results.json").write_text(json.dumps({
                    "status": "ok", "job": n, "name": name, "model_config": model,
                    "test": {"rollout_mse": mean, "rollout_mse_se": se},
                    "bench": {"ms_per_frame": spec["ms"], "peak_memory_mb": spec["mb"]},
                    "rows": [{"trajectory": t, "rollout_mse": float(e), "baseline_mse": float(SCENES[t])}
                             for t, e in enumerate(errors)]}))  # fmt: skip
            if spec["seed"] == 0:
                table.append({"status": "ok", "latent_size": latent, "mp_steps": mp, "radius": r,
                              "rollout_mse": mean, "rollout_mse_se": se, "baseline_ratio": 1.0,
                              "baseline_ratio_lo": 0.8, "baseline_ratio_hi": 1.2, "bench_ms_per_frame": spec["ms"],
                              "bench_peak_mb": spec["mb"], "pareto": False})  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=GRID_COLUMNS)
        writer.writeheader()
        writer.writerows(table)
    return folder


def _widths(tmp_path, levels: dict[int, float], noise=0.05, mps=(1, 3, 5, 10)):
    """A grid of the widths in ``levels`` at every MP count, each width at its error level."""
    jobs = {(w, mp): _spec(level, noise=noise, mp=mp, latent=w) for w, level in levels.items() for mp in mps}
    return load_grid(make_grid(tmp_path / "grid", jobs))


def test_sixteen_worse_than_64_is_reproduced_and_better_is_not(tmp_path):
    assert claim_width(_widths(tmp_path / "a", {16: 2.0, 64: 1.0}), 2, 16, +1)["verdict"] == REPRODUCED
    assert claim_width(_widths(tmp_path / "b", {16: 0.5, 64: 1.0}), 2, 16, +1)["verdict"] == NOT_REPRODUCED
    assert claim_width(_widths(tmp_path / "c", {128: 0.5, 64: 1.0}), 3, 128, -1)["verdict"] == REPRODUCED
    assert claim_width(_widths(tmp_path / "d", {128: 2.0, 64: 1.0}), 3, 128, -1)["verdict"] == NOT_REPRODUCED


def test_overlapping_intervals_cannot_be_told(tmp_path):
    row = claim_width(_widths(tmp_path, {16: 1.02, 64: 1.0}, noise=0.6), 2, 16, +1)
    assert row["verdict"] == UNTOLD
    assert "no cell has several seeds" in row["measurement"].lower()


def test_the_seed_gate_holds_back_a_paired_verdict_when_retraining_moves_cells_as_much(tmp_path):
    jobs = {
        (w, mp): _spec(2.0 if w == 16 else 1.0, mp=mp, latent=w) for w in (16, 64) for mp in (1, 3, 5, 10)
    }
    jobs[64, 5] = [_spec(level, seed=s) for s, level in enumerate((1.0, 4.0, 0.25))]  # seeds far apart
    grid = load_grid(make_grid(tmp_path / "grid", jobs))
    assert grid.seed_test is not None and grid.seed_test["p"] >= 0.05
    row = claim_width(grid, 2, 16, +1)
    assert row["verdict"] == UNTOLD and "paired alone: reproduced" in row["measurement"]


def test_linear_timing_is_reproduced_and_quadratic_is_not(tmp_path):
    def timed(name, cost):
        jobs = {(w, mp): _spec(ms=cost(w, mp), mp=mp, latent=w) for w in (16, 64) for mp in (1, 3, 5, 10)}
        return load_grid(make_grid(tmp_path / name, jobs))

    assert claim_linear_cost(timed("linear", lambda w, mp: w * (2 + mp)))["verdict"] == REPRODUCED
    assert claim_linear_cost(timed("quadratic", lambda w, mp: w * mp**2))["verdict"] == NOT_REPRODUCED


def test_memory_growing_with_width_is_reproduced_and_flat_memory_is_not(tmp_path):
    def memory(name, mb):
        jobs = {(w, mp): _spec(mb=mb(w), mp=mp, latent=w) for w in (16, 32, 64) for mp in (1, 5)}
        return load_grid(make_grid(tmp_path / name, jobs))

    assert claim_memory(memory("grows", lambda w: 0.6 * w))["verdict"] == REPRODUCED
    assert claim_memory(memory("flat", lambda w: 30.0))["verdict"] == NOT_REPRODUCED
    assert claim_memory(memory("shrinks", lambda w: 600 / w))["verdict"] == NOT_REPRODUCED


def test_pareto_front_and_a_faster_better_cell(tmp_path):
    front = {(64, 5): _spec(1.0, ms=50), (32, 5): _spec(2.0, ms=20, latent=32), (64, 10): _spec(0.8, ms=100)}
    assert claim_pareto(load_grid(make_grid(tmp_path / "on", front)))["verdict"] == REPRODUCED
    front[32, 5] = _spec(0.5, ms=20, latent=32)  # faster and better beyond its interval
    row = claim_pareto(load_grid(make_grid(tmp_path / "off", front)))
    assert row["verdict"] == NOT_REPRODUCED and "32/5 (20.0 ms" in row["measurement"]


def test_message_passing_steps(tmp_path):
    def depth(name, low_level):
        jobs = {
            (w, mp): _spec(low_level if mp <= 3 else 1.0, mp=mp, latent=w)
            for w in (16, 64)
            for mp in (1, 3, 5, 10)
        }
        return claim_depth(load_grid(make_grid(tmp_path / name, jobs)))["verdict"]

    assert depth("restrictive", 2.0) == REPRODUCED
    assert depth("enough", 0.5) == NOT_REPRODUCED


def test_the_radius_claim_in_parts(tmp_path):
    def radius(name, big_level, big_ms):
        jobs = {(64, 5, 0.033): _spec(2.0, ms=60), (64, 5, 0.047): _spec(1.0, ms=100),
                (64, 5, 0.058): _spec(big_level, ms=big_ms)}  # fmt: skip
        return claim_radius(make_grid(tmp_path / name, jobs), 0.035)

    assert radius("paper", 2.0, 200)["verdict"] == REPRODUCED
    row = radius("wider helps", 0.5, 200)
    assert row["verdict"] == NOT_REPRODUCED and "R=0.058 / R=0.047 0.5" in row["measurement"]
    assert "(not reproduced); slows: 2.00x the ms/frame (200 / 100) (reproduced)" in row["measurement"]
    assert claim_radius(tmp_path / "absent", 0.035)["verdict"] == NOT_MEASURED


def test_without_jobs_the_paired_claims_are_not_measured(tmp_path):
    jobs = {(w, mp): _spec(mp=mp, latent=w) for w in (16, 64) for mp in (1, 3, 5)}
    grid = load_grid(make_grid(tmp_path / "grid", jobs, rows=False))
    assert claim_width(grid, 2, 16, +1)["verdict"] == NOT_MEASURED
    assert claim_depth(grid)["verdict"] == NOT_MEASURED
    assert claim_linear_cost(grid)["verdict"] == REPRODUCED  # results.csv's speed alone


def test_missing_inputs_and_missing_columns(tmp_path, capsys):
    grid = make_grid(tmp_path / "grid", {(64, 5): _spec(), (16, 5): _spec(latent=16)})
    summary = build(grid, tmp_path / "out")
    rows = {c["number"]: c for c in summary["claims"]}
    assert rows[7]["verdict"] == NOT_MEASURED and rows[7]["measurement"] == "no --radius"
    assert rows[8]["verdict"] == NOT_MEASURED and rows[8]["measurement"] == "no --versus"
    text = (grid / "results.csv").read_text().replace("bench_peak_mb", "peak")
    (grid / "results.csv").write_text(text)
    assert run_main(main, ["--grid", str(grid), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "results.csv: no column 'bench_peak_mb'" in err
    versus = tmp_path / "versus"
    versus.mkdir()
    (versus / "versus.json").write_text(json.dumps({"models": ["original", "simplified"], "paired": {}}))
    grid = make_grid(tmp_path / "grid2", {(64, 5): _spec()})
    assert run_main(main, ["--grid", str(grid), "--versus", str(versus), "--out", str(tmp_path / "out")]) == 2
    assert "versus.json: no field 'paired.rollout_mse.ratio'" in capsys.readouterr().err


def test_side_by_side_of_two_grids(tmp_path):
    a = load_grid(make_grid(tmp_path / "a", {(64, 5): [_spec(seed=0), _spec(seed=1)], (16, 1): _spec(mp=1)}))
    b = load_grid(make_grid(tmp_path / "b", {(64, 5): _spec(ms=80)}, radius=0.047))
    table = {(r["latent_size"], r["mp_steps"]): r["grids"] for r in side_by_side([a, b])}
    assert table[64, 5]["R=0.047"]["ms"] == 80 and table[64, 5]["R=0.035"]["seeds"] == 2
    assert table[16, 1]["R=0.047"] is None


@pytest.mark.skipif(not (REPO / "docs/fig9/radius_0.035/results.csv").is_file(), reason="no figure 9 report")
def test_on_the_real_reports(tmp_path, capsys):
    docs = REPO / "docs"
    argv = ["--grid", str(docs / "fig9/radius_0.035"), "--compare", str(docs / "fig9/radius_0.035"),
            "--radius", str(docs / "radius"), "--versus", str(docs / "original-vs-simplified"),
            "--out", str(tmp_path)]  # fmt: skip
    assert main(argv) == 0
    claims = json.loads((tmp_path / "claims.json").read_text())["claims"]
    assert [c["number"] for c in claims] == list(range(1, 10))
    assert all(c["verdict"] in (REPRODUCED, NOT_REPRODUCED, UNTOLD) for c in claims)
    assert all(c["from"] for c in claims)
    markdown = (tmp_path / "claims.md").read_text()
    assert markdown == capsys.readouterr().out.rstrip("\n") + "\n"
    assert sum(line.startswith(f"| {n} |") for line in markdown.splitlines() for n in range(1, 10)) == 9


def _clock(grid_folder: Path, hours: dict[tuple, float], curves: dict[tuple, list[tuple]] | None = None):
    """Give the grid's jobs a training clock (hours) and, for some, a validation curve [(hours, mse)]."""
    for job in (grid_folder / "jobs").iterdir():
        config = json.loads((job / ".hydra" / "config.yaml").read_text())["model"]
        key = (config["latent_size"], config["mp_steps"])
        results = json.loads((job / "results.json").read_text())
        results["training_s"] = 3600 * hours[key]
        (job / "results.json").write_text(json.dumps(results))
        for h, mse in (curves or {}).get(key, []):
            with open(job / "curve.jsonl", "a") as f:
                f.write(
                    json.dumps({"kind": "val", "step": int(h * 1000), "time_s": 3600 * h, "rollout_mse": mse})
                )
                f.write("\n")


def test_training_time_claim_from_clocks_and_curves(tmp_path):
    jobs = {(64, 5): _spec(1.0), (128, 10): _spec(1.0, mp=10, latent=128)}
    folder = make_grid(tmp_path / "grid", jobs)
    _clock(folder, {(64, 5): 1.0, (128, 10): 3.5})
    claim = claim_training_time(load_grid(folder))
    assert claim["verdict"] == REPRODUCED and "3.50x" in claim["measurement"]
    # 128/10 reached its final error (within 10%) at 2 h of its 3.5: 2x, below 3 / 1.15.
    curve = [(1.0, 0.05), (2.0, 0.0105), (3.5, 0.0100)]
    _clock(folder, {(64, 5): 1.0, (128, 10): 3.5}, {(128, 10): curve})
    job = next(p for p in (folder / "jobs").iterdir() if "latent_size=128" in p.name)
    assert hours_to_final(job) == (pytest.approx(2.0), "curve")
    claim = claim_training_time(load_grid(folder))
    assert claim["verdict"] == NOT_REPRODUCED and "2.00x" in claim["measurement"]


def test_training_time_is_held_back_when_the_faster_model_ends_worse(tmp_path):
    jobs = {(64, 5): _spec(2.0), (128, 10): _spec(1.0, mp=10, latent=128)}
    folder = make_grid(tmp_path / "grid", jobs)
    _clock(folder, {(64, 5): 1.0, (128, 10): 4.0})
    claim = claim_training_time(load_grid(folder))
    assert claim["verdict"] == UNTOLD and "time alone: reproduced" in claim["measurement"]
    assert (
        claim_training_time(load_grid(make_grid(tmp_path / "bare", jobs, rows=False)))["verdict"]
        == NOT_MEASURED
    )
