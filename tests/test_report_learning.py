"""The learning study's report (gnsx.evaluation.report.learning) on a made-up sweep whose answers are known."""

from __future__ import annotations

import json
import math

import pytest
import yaml

from gnsx.evaluation.curve_file import append_row
from gnsx.evaluation.report.learning import build, config_changes, load_jobs

BASELINE = [1e-2, 2e-2, 4e-2, 8e-2]  # per validation trajectory


def _job(sweep, arm, seed, factor, config, steps=(100, 200), area=0.8, status="ok", key="learning_arm"):
    """A job whose final error is ``factor`` x the baseline on every trajectory (times a seed wobble)."""
    folder = sweep / f"{key}={arm},seed={seed}"
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    results = {"status": status, "swept": [f"{key}={arm}", f"seed={seed}"], "steps_per_s": 20.0}
    (folder / "results.json").write_text(json.dumps(results))
    curve = folder / "curve.jsonl"
    append_row(curve, {"kind": "baseline", "rollout_mse": sum(BASELINE) / 4, "rollout_mse_se": 0.0,
                       "trajectories": 4, "rollout_mse_per_trajectory": BASELINE})  # fmt: skip
    wobble = 1.1 if seed else 1 / 1.1  # the seeds' geometric mean is exactly factor
    for i, step in enumerate(steps):
        scale = factor * wobble * (2.0 if i < len(steps) - 1 else 1.0)  # falling to factor at the end
        per = [b * scale for b in BASELINE]
        append_row(curve, {"kind": "val", "step": step, "time_s": step / 20, "samples": 2 * step,
                           "rollout_mse": sum(per) / 4, "rollout_mse_se": 0.0, "area_ratio_final": area,
                           "rollout_mse_per_trajectory": per, "area_ratio_final_per_trajectory": [area] * 4,
                           "trajectories": 4})  # fmt: skip
    return folder


BASE_CONFIG = {"seed": 0, "model": {"latent_size": 64, "decoder": "node"}, "train": {"max_steps": 200,
               "noise_std": None}, "data": {"root": "data/x"}}  # fmt: skip


def test_the_table_reads_known_ratios_and_the_changes_from_the_configs(tmp_path):
    sweep = tmp_path / "sweep"
    for seed in (0, 1):
        _job(sweep, "base", seed, 0.5, {**BASE_CONFIG, "seed": seed})
        pairwise = {**BASE_CONFIG, "seed": seed, "model": {"latent_size": 64, "decoder": "pairwise"},
                    "train": {"max_steps": 300, "noise_std": None}}  # fmt: skip
        _job(sweep, "pairwise", seed, 0.25, pairwise)
    arms = load_jobs(sweep)
    assert list(arms) == ["base", "pairwise"] and sorted(arms["base"]) == [0, 1]
    # Budgets and seeds are not changes; the decoder is.
    assert config_changes(arms["pairwise"][0]["config"], arms["base"][1]["config"]) == [
        "model.decoder=pairwise"
    ]
    stale = tmp_path / "kept" / "learning_arm=base,seed=0" / "checkpoints"  # committed mid-run to resume
    stale.mkdir(parents=True)
    (stale / "last.ckpt").write_bytes(b"weights")
    summary = build(sweep, tmp_path / "out", jobs_dest=tmp_path / "kept", budget_minutes=20)
    rows = {row["arm"]: row for row in summary["arms"]}
    # Every trajectory at exactly 0.5x / 0.25x the baseline (seeds' geometric mean): ratios 2 and 4, no spread.
    assert rows["base"]["x_baseline"][0] == pytest.approx(2.0)
    assert rows["pairwise"]["x_baseline"][0] == pytest.approx(4.0)
    assert rows["pairwise"]["vs_base"] == pytest.approx((0.5, 0.5, 0.5))
    assert math.isnan(rows["base"]["vs_base"][0])
    assert rows["pairwise"]["area_ratio"] == pytest.approx(0.8)
    assert rows["base"]["steps"] == 200 and rows["base"]["samples"] == 400
    assert rows["base"]["ms_per_step"] == pytest.approx(50.0)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "| pairwise | model.decoder=pairwise |" in report and "0.50x [0.50, 0.50]" in report
    assert "--budget-minutes 20`" in report
    assert (tmp_path / "out" / "curves.png").stat().st_size > 10_000
    assert (tmp_path / "kept" / "learning_arm=base,seed=0" / "curve.jsonl").is_file()
    assert not (tmp_path / "kept" / "learning_arm=base,seed=0" / "checkpoints").exists()


def test_arms_within_their_spread_are_called_a_tie_and_running_jobs_are_marked(tmp_path):
    sweep = tmp_path / "sweep"
    _job(sweep, "base", 0, 0.5, BASE_CONFIG)
    folder = _job(sweep, "noise3x", 0, 0.5, {**BASE_CONFIG, "train": {"max_steps": 200, "noise_std": 9e-4}},
                  status="running")  # fmt: skip
    # Per trajectory 0.8x, 1.25x, 0.8x, 1.25x of base: geometric mean 1, interval around it.
    rows = [json.loads(line) for line in (folder / "curve.jsonl").read_text().splitlines()]
    rows[-1]["rollout_mse_per_trajectory"] = [v * f for v, f in zip(rows[-1]["rollout_mse_per_trajectory"],
                                                                    (0.8, 1.25, 0.8, 1.25))]  # fmt: skip
    (folder / "curve.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    build(sweep, tmp_path / "out")
    report = (tmp_path / "out" / "report.md").read_text()
    line = next(row for row in report.splitlines() if row.startswith("| noise3x"))
    assert "(tie)" in line and "(running)" in line and "train.noise_std=0.0009" in line


def test_a_missing_sweep_is_one_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such sweep folder"):
        load_jobs(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no job swept over learning_arm"):
        load_jobs(tmp_path / "empty")


def test_another_swept_group_names_the_arms(tmp_path):
    """The demo's choice (sweeps/demo_choice.yaml) sweeps demo_arm: the same report reads it by that key."""
    sweep = tmp_path / "sweep"
    for seed in (0, 1):
        _job(sweep, "base", seed, 0.5, BASE_CONFIG, key="demo_arm")
        _job(sweep, "winner", seed, 0.25, BASE_CONFIG, key="demo_arm")
    with pytest.raises(FileNotFoundError, match="learning_arm"):
        load_jobs(sweep)
    summary = build(sweep, tmp_path / "out", arm_key="demo_arm")
    rows = {row["arm"]: row for row in summary["arms"]}
    assert set(rows) == {"base", "winner"}
    assert rows["winner"]["vs_base"][0] == pytest.approx(0.5)
    assert "--arm-key demo_arm" in (tmp_path / "out" / "report.md").read_text()
