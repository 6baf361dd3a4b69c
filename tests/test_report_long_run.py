"""The long run's report (gnsx.evaluation.report.long_run): its flatness verdict can say each of flat, still
falling and rising, and the tool writes its table and picture from a curve file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gnsx.evaluation.report.long_run import flatness, main


def _val(step: int, per_trajectory) -> dict:
    per_trajectory = [float(v) for v in per_trajectory]
    return {"kind": "val", "step": step, "rollout_mse": float(np.mean(per_trajectory)), "rollout_mse_se": 0.001,
            "onestep_mse": 5e-9, "area_ratio_final": 0.8, "area_ratio_final_se": 0.05,
            "rollout_mse_per_trajectory": per_trajectory}  # fmt: skip


@pytest.mark.parametrize(("factor", "verdict"), [(0.5, "still falling"), (2.0, "rising"), (None, "flat")])
def test_the_flatness_verdict_follows_the_last_validations(factor, verdict):
    rng = np.random.default_rng(0)
    first = rng.uniform(0.01, 0.03, size=8)
    if factor is None:  # scatter around the same level: some trajectories up, some down
        last = first * np.exp(np.array([0.3, -0.3, 0.2, -0.2, 0.1, -0.1, 0.25, -0.25]))
    else:
        last = first * factor * np.exp(rng.normal(0.0, 0.05, size=8))
    vals = [_val(10_000, first), _val(20_000, first), _val(30_000, last)]
    result = flatness(vals)
    assert result["verdict"] == verdict and (result["from_step"], result["to_step"]) == (10_000, 30_000)
    assert flatness(vals[:2]) is None  # two validations cannot show three


def test_the_tool_writes_the_table_and_the_picture(tmp_path):
    run = tmp_path / "paperlr"
    run.mkdir()
    baseline = {"kind": "baseline", "rollout_mse": 0.02, "rollout_mse_per_trajectory": [0.02, 0.03]}
    rows = [baseline, {"kind": "train", "step": 50, "loss": 1.0}, _val(10_000, [0.02, 0.02]),
            _val(20_000, [0.01, 0.015])]  # fmt: skip
    (run / "curve.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    assert main([str(run), "--out", str(tmp_path / "out")]) == 0
    text = (tmp_path / "out" / "long_run.md").read_text()
    assert "| 20,000 |" in text and "2.00x" in text  # x baseline at 20k: geometric mean of 2 and 2
    assert (tmp_path / "out" / "long_run.png").stat().st_size > 0


def test_a_run_without_a_curve_is_a_one_line_error(tmp_path):
    from gnsx.core.cli import run_main

    assert (
        run_main(main, [str(tmp_path / "nothing"), "--out", str(tmp_path)], user_errors=(FileNotFoundError,))
        == 2
    )
