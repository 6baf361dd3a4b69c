"""The learning study's sweep (sweeps/learning.yaml): each arm changes one thing against the base arm, the
arms' step budgets are the same training time, and a tiny multirun writes the curves the report reads and
skips its finished jobs on a rerun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from gnsx.evaluation.curve_file import read_curve
from gnsx.evaluation.report.learning import build, config_changes

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "sweeps"
CONF = ROOT / "conf"

#: What each arm must change against the base arm (budgets aside), as composed.
EXPECTED = {
    "pairwise": {"model.decoder=pairwise"},  # gravity null: the data's g dt^2 (train.py fills it in)
    "wall10": {"model.wall_clip=[0.0, 10.0]"},
    "history2": {"model.history=2"},
    "history5": {"model.history=5"},
    "noise3x": {"train.noise_std=0.0009"},
    "pushforward": {"train.pushforward_steps=1"},
    "unroll3": {"train.unroll_steps=3"},
    "radius035": {"model.radius_scale=1.0"},
    "paperlr": {
        "train.lr_init=0.0001",
        "train.lr_final=1e-06",
        "train.lr_decay_start=${steps_fraction:0.625,${train.max_steps}}",  # 14,250 (resolved: the test below)
        "train.lr_decay_end=${steps_fraction:0.9375,${train.max_steps}}",  # 21,375
    },  # fmt: skip
}
#: Combination arms: two single arms' changes together, on the budget of the one whose network they use.
COMBINED = {"paperlr_pairwise": ("paperlr", "pairwise")}
EXPECTED |= {arm: set().union(*(EXPECTED[part] for part in parts)) for arm, parts in COMBINED.items()}


def _compose(arm: str):
    with initialize_config_dir(config_dir=str(SWEEPS), version_base="1.3"):
        cfg = compose(
            config_name="learning", overrides=[f"hydra.searchpath=[file://{CONF}]", f"learning_arm={arm}"]
        )
    return OmegaConf.to_container(cfg, resolve=False)


def _arms() -> list[str]:
    raw = OmegaConf.load(SWEEPS / "learning.yaml")
    return str(raw.hydra.sweeper.params.learning_arm).split(",")


def test_every_arm_changes_one_thing_against_the_base_arm():
    arms = _arms()
    assert arms[0] == "base" and set(arms[1:]) == set(EXPECTED) and len(arms) == len(EXPECTED) + 1
    base = _compose("base")
    # The base arm is the paper's simplified 64/5 at the paper's radius with the paper's noise, no mirror.
    assert (base["model"]["name"], base["model"]["latent_size"], base["model"]["mp_steps"]) == (
        "simplified",
        64,
        5,
    )
    assert base["model"]["radius_scale"] == pytest.approx(0.020 / 0.015, rel=1e-4)
    assert (base["model"]["noise_std"], base["model"]["noise_decay"]) == (3e-4, 0.4)
    assert base["train"]["noise_std"] is None and base["train"]["mirror"] is False
    assert base["evaluate"]["enabled"] is False and base["train"]["val_max_trajectories"] == 8
    for arm, expected in EXPECTED.items():
        assert set(config_changes(_compose(arm), base)) == expected, arm


def test_the_arms_step_budgets_are_the_same_training_time():
    """Each arm's steps are its measured rate times the budget (docs/learning/budget.json), validated at 6
    evenly spaced points; arms of the same cost share one budget."""
    record = json.loads((ROOT / "docs" / "learning" / "budget.json").read_text())
    seconds = 60 * record["minutes"]
    for arm in _arms():
        train = _compose(arm)["train"]
        if arm == "paperlr":  # the base arm's network and budget, another schedule
            assert train["max_steps"] == _compose("base")["train"]["max_steps"]
            continue
        if arm in COMBINED:  # the budget of the arm whose network it uses (a schedule costs nothing per step)
            network = COMBINED[arm][-1]
            assert train["max_steps"] == _compose(network)["train"]["max_steps"], arm
            continue
        rate = record["equalised"]["mean_steps_per_s"] if arm in record["equalised"]["arms"] else (
            record["arms"][arm]["steps_per_s"])  # fmt: skip
        assert train["max_steps"] == record["arms"][arm]["max_steps"], arm
        assert abs(train["max_steps"] / rate - seconds) < 0.02 * seconds, arm
        assert train["curve_every_n_steps"] * 6 == train["max_steps"], arm


def test_a_tiny_study_writes_curves_the_report_reads_and_a_rerun_skips_it(tmp_path, tiny_dataset):
    sweep_dir = tmp_path / "study"
    cmd = [sys.executable, str(ROOT / "train.py"), "-m", "--config-dir", str(SWEEPS), "--config-name", "learning",
           f"hydra.sweep.dir={sweep_dir}", f"data.root={tiny_dataset}", "data.generate_if_missing=false",
           "learning_arm=base,unroll3", "seed=0", "train.max_steps=4", "train.curve_every_n_steps=2",
           "model.latent_size=8", "model.mlp_hidden_size=8", "model.mp_steps=1", "logger=csv",
           "hydra/launcher=sequential"]  # fmt: skip
    env = {**os.environ, "MPLBACKEND": "Agg"}
    run = lambda: subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)  # noqa: E731
    done = run()
    assert done.returncode == 0, done.stderr[-3000:]
    jobs = sorted(p for p in sweep_dir.iterdir() if p.is_dir())
    assert [p.name.split(",")[0] for p in jobs] == ["learning_arm=base", "learning_arm=unroll3"]
    for job in jobs:
        curve = read_curve(job / "curve.jsonl")
        assert [row["step"] for row in curve["val"]] == [2, 4]
        assert len(curve["val"][-1]["rollout_mse_per_trajectory"]) == 1
        assert len(curve["baseline"]["rollout_mse_per_trajectory"]) == 1
        results = json.loads((job / "results.json").read_text())
        assert results["status"] == "ok" and results["evaluated"] is False and results["global_step"] == 4
    summary = build(sweep_dir, tmp_path / "report")
    assert [row["arm"] for row in summary["arms"]] == ["base", "unroll3"]
    assert summary["changes"]["unroll3"] == ["train.unroll_steps=3"]
    rerun = run()
    log = rerun.stdout + rerun.stderr
    assert rerun.returncode == 0 and log.count("finished earlier (no test evaluation): skipped") == 2


def test_the_paper_schedule_keeps_its_shape_in_the_long_run():
    """paperlr's decay points are fractions of the run: 14,250-21,375 of the study's 22,800 steps, 125,000-187,500
    of the 200k long run (sweeps/learning_long.yaml), never the study's absolute steps."""
    with initialize_config_dir(config_dir=str(SWEEPS), version_base="1.3"):
        cfg = compose(config_name="learning_long",
                      overrides=[f"hydra.searchpath=[file://{CONF}]", "learning_arm=paperlr"])  # fmt: skip
    train = OmegaConf.to_container(cfg.train, resolve=True)
    assert (train["max_steps"], train["lr_decay_start"], train["lr_decay_end"]) == (200_000, 125_000, 187_500)
    assert (train["lr_init"], train["lr_final"]) == (1e-4, 1e-6)


def _compose_demo_choice(arm: str):
    with initialize_config_dir(config_dir=str(SWEEPS), version_base="1.3"):
        cfg = compose(
            config_name="demo_choice", overrides=[f"hydra.searchpath=[file://{CONF}]", f"demo_arm={arm}"]
        )
    return OmegaConf.to_container(cfg, resolve=False)


def test_the_demo_choice_pits_the_demo_as_shipped_against_the_study_winner():
    """sweeps/demo_choice.yaml: its base arm is the demo's own model and recipe, its winner is the study's
    paperlr arm exactly (on the demo's data), so the choice tests the winner and nothing else."""
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        demo = OmegaConf.to_container(compose(config_name="config"), resolve=False)
    base, winner = _compose_demo_choice("base"), _compose_demo_choice("winner")
    for key in ("model", "data"):
        assert base[key] == demo[key]
    for key in ("lr_init", "lr_final", "noise_std", "noise_decay", "mirror"):
        assert base["train"][key] == demo["train"][key]
    changes = set(config_changes(winner, _compose("paperlr")))
    assert {c.partition("=")[0] for c in changes} <= {"data.trajectories", "data.trajectories.train",
                                                      "data.trajectories.valid", "data.trajectories.test"}  # fmt: skip
    assert base["train"]["max_steps"] == winner["train"]["max_steps"] == 12200
