"""The shipped weights (``pretrained/small``, written by ``make pretrain``) are complete, match their config,
saw at least 5x the demo's training samples, and reproduce their recorded test rollout on a trajectory
regenerated here with the MPM solver."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from gnsx.data.metadata import Metadata
from gnsx.evaluation.scoring import score_trajectory
from gnsx.model.checkpoint import load_simulator
from gnsx.mpm.generate import simulate_split_item
from gnsx.mpm.presets import Preset
from gnsx.rules.rules import Rules

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "pretrained" / "small"


@pytest.fixture(scope="module")
def shipped():
    results = json.loads((SHIPPED / "results.json").read_text())
    return results, OmegaConf.load(SHIPPED / "config.yaml")


def test_shipped_folder_is_complete_and_small():
    for name in (
        "model.ckpt",
        "config.yaml",
        "metadata.json",
        "metrics.csv",
        "results.json",
        "training_curve.png",
    ):
        assert (SHIPPED / name).is_file(), name
    assert (SHIPPED / "model.ckpt").stat().st_size < 2_000_000  # weights only, no optimizer state


def test_shipped_weights_match_their_config_and_budget(shipped):
    results, config = shipped
    simulator = load_simulator(SHIPPED / "model.ckpt")
    assert simulator.num_parameters() == results["parameters"]
    assert simulator.wall_clip == tuple(config.model.wall_clip)
    for key in ("latent_size", "mp_steps", "history", "type_encoding"):
        assert simulator.config[key] == config.model[key], key
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        demo = compose(config_name="config")
    # The run saw at least 5x the training samples the demo gets: its time budget fits about half its step
    # cap on this CPU (8,664-9,806 steps of 20,000 measured); validation chose which checkpoint ships. (The
    # pretrain is time-fitted too, so a busy machine gives it fewer than its 100k-step cap.) A fine-tune
    # counts the samples of the weights it started from (`samples_seen`, recorded since 2026-12-03; older
    # runs: steps x batch).
    shipped_samples = results.get("samples_seen") or results["train_steps"] * config.data.batch_size
    assert shipped_samples >= 5 * (demo.train.max_steps // 2) * demo.data.batch_size
    state = torch.load(SHIPPED / "model.ckpt", map_location="cpu", weights_only=False)
    # ``global_step``: the run's steps over every resumed fit (``train_steps`` counts the last fit's alone).
    run_steps = results.get("global_step", results["train_steps"])
    assert state["global_step"] == results["checkpoint"]["global_step"] <= run_steps
    assert "optimizer_states" not in state
    assert results["test"]["rollout_mse"] < results["test"]["baseline_mse"]


def test_shipped_weights_reproduce_their_test_rollout(shipped):
    results, config = shipped
    simulator = load_simulator(SHIPPED / "model.ckpt")
    metadata = Metadata.load(SHIPPED / "metadata.json")
    # The data the weights were scored on, regenerated with the solver its metadata records (the presets'
    # solver has changed since: issue 13).
    preset = Preset.from_dict(metadata.extra["gnsx"]["preset_settings"])
    trajectory = simulate_split_item(preset, int(config.data.generate_seed), "test", 0)
    row = score_trajectory(
        simulator,
        torch.as_tensor(trajectory.position),
        torch.as_tensor(trajectory.particle_type),
        metadata,
        emd_every=0,
        timing_repeats=0,
        # The rules its results.json records (none, the boundary alone, in files written before 2026-12-01).
        rules=Rules.from_results(results),
    ).row
    recorded = next(r for r in results["rows"] if r["trajectory"] == 0)
    assert row["baseline_mse"] == pytest.approx(recorded["baseline_mse"], rel=1e-4)  # the same trajectory
    assert row["onestep_mse"] == pytest.approx(recorded["onestep_mse"], rel=0.02)
    # A 250-frame rollout of splashing water amplifies float rounding (thread counts, CPU), so the whole
    # rollout is compared loosely; a changed feature or model code would miss by far more.
    assert row["rollout_mse"] == pytest.approx(recorded["rollout_mse"], rel=0.25)


def test_best_validation_checkpoint_matches_logged_step_to_saved_file(tmp_path):
    from gnsx.training.export import best_validation_checkpoint

    run = tmp_path / "run"
    (run / "checkpoints" / "permanent").mkdir(parents=True)
    (run / "csv" / "version_0").mkdir(parents=True)
    for step in (10, 20, 30):
        (run / "checkpoints" / "permanent" / f"step{step:08d}.ckpt").write_bytes(b"")
    rows = ["step,train/loss,val/rollout_mse", "9,1.0,", "9,,0.5", "19,,0.2", "29,,0.3", "39,,0.1"]
    (run / "csv" / "version_0" / "metrics.csv").write_text("\n".join(rows) + "\n")
    path, mse = best_validation_checkpoint(run)  # step 40 scored best but was not saved
    assert path.name == "step00000020.ckpt" and mse == 0.2


def test_best_scored_checkpoint_pools_the_trajectories_of_every_results_file(tmp_path):
    from gnsx.core.errors import DataError
    from gnsx.training.export import best_scored_checkpoint

    def results(name: str, scores: dict[str, list[float]]):
        models = [
            {"checkpoint": c, "rows": [{"rollout_mse": v} for v in values]} for c, values in scores.items()
        ]
        path = tmp_path / name
        path.write_text(json.dumps({"models": models}))
        return path

    # a wins the 2-trajectory file, b the pooled 6 trajectories (mean 0.25 against 0.3).
    valid = results("valid.json", {"a.ckpt": [0.1, 0.1], "b.ckpt": [0.2, 0.3]})
    fresh = results("fresh.json", {"a.ckpt": [0.4, 0.4, 0.4, 0.4], "b.ckpt": [0.3, 0.2, 0.3, 0.2]})
    assert best_scored_checkpoint([valid]) == (Path("a.ckpt"), pytest.approx(0.1), 2)
    best, mse, count = best_scored_checkpoint([valid, fresh])
    assert best == Path("b.ckpt") and mse == pytest.approx(0.25) and count == 6
    other = results("other.json", {"c.ckpt": [0.1]})
    with pytest.raises(DataError, match="other checkpoints"):
        best_scored_checkpoint([valid, other])
    (tmp_path / "bad.json").write_text("[]")
    with pytest.raises(DataError, match="bad.json"):
        best_scored_checkpoint([tmp_path / "bad.json"])


def test_failed_export_leaves_the_shipped_folder_untouched(tmp_path):
    from gnsx.training.export import export

    run = tmp_path / "run"
    (run / "checkpoints" / "permanent").mkdir(parents=True)
    (run / ".hydra").mkdir()
    (run / ".hydra" / "config.yaml").write_text("model: {}\n")  # no data.root: the test evaluation cannot run
    header = {"state_dict": {}, "hyper_parameters": {"model": {}}}  # what read_checkpoint requires
    torch.save({**header, "global_step": 5}, run / "checkpoints" / "last.ckpt")
    torch.save({**header, "global_step": 4}, run / "checkpoints" / "permanent" / "step00000004.ckpt")
    dest = tmp_path / "shipped"
    dest.mkdir()
    (dest / "model.ckpt").write_bytes(b"previous weights")
    with pytest.raises(FileNotFoundError, match="data.root"):
        export(run, dest, checkpoint=run / "checkpoints" / "permanent" / "step00000004.ckpt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "shipped"]  # no staging folder left
    assert [p.name for p in dest.iterdir()] == ["model.ckpt"]
    assert (dest / "model.ckpt").read_bytes() == b"previous weights"
    info = export(run, dest)  # the last checkpoint needs no evaluation: it replaces the folder
    assert info["global_step"] == 5
    assert torch.load(dest / "model.ckpt", weights_only=False)["global_step"] == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "shipped"]


def test_export_reuses_a_test_evaluation_of_the_same_checkpoint_only(tmp_path):
    """``--test-results``: an evaluate.py file that scored the exported checkpoint on the test split is used
    as is; one of another checkpoint, or of another split, is refused and nothing is written."""
    from gnsx.core.errors import DataError
    from gnsx.training.export import export

    run = tmp_path / "run"
    (run / "checkpoints" / "permanent").mkdir(parents=True)
    # A model config that records its gravity, as every one since 2026-12-07 (nothing for export to add).
    header = {"state_dict": {}, "hyper_parameters": {"model": {"gravity": [0.0, -1.0]}}}
    torch.save({**header, "global_step": 5}, run / "checkpoints" / "last.ckpt")
    chosen = run / "checkpoints" / "permanent" / "step00000004.ckpt"
    torch.save({**header, "global_step": 4}, chosen)
    data = tmp_path / "data"
    data.mkdir()
    (data / "metadata.json").write_text('{"bounds": [[0, 1], [0, 1]]}')

    def results_of(name: str, checkpoint: Path, split: str = "test") -> Path:
        model = {
            "checkpoint": str(checkpoint),
            "parameters": 7,
            "summary": {"rollout_mse": 0.5},
            "rows": [{}],
        }
        path = tmp_path / name
        path.write_text(
            json.dumps({"split": split, "data_root": "x", "rules": {"hold_rest": True}, "models": [model]})
        )
        return path

    dest = tmp_path / "shipped"
    for bad, match in (
        (results_of("other.json", run / "checkpoints" / "last.ckpt"), "scored no model from"),
        (results_of("valid.json", chosen, split="valid"), "not 'test'"),
    ):
        with pytest.raises(DataError, match=match):
            export(run, dest, checkpoint=chosen, test_results=bad, data_root=data)
        assert not dest.exists()
    info = export(run, dest, checkpoint=chosen, test_results=results_of("ok.json", chosen), data_root=data)
    assert info["global_step"] == 4
    written = json.loads((dest / "results.json").read_text())
    assert written["test"] == {"rollout_mse": 0.5} and written["parameters"] == 7
    assert written["rules"] == {"hold_rest": True} and written["test_data_root"] == "x"
    assert (dest / "metadata.json").read_text() == '{"bounds": [[0, 1], [0, 1]]}'


def test_selection_skips_checkpoints_whose_pool_at_rest_drifts(tmp_path):
    """The shipping rule: the lowest validation error among checkpoints that keep a pool at rest (the
    pretrain's step 10k scored best and drifted 4.5 cm per 100 frames; docs/decisions)."""
    from gnsx.training.export import export, first_at_rest

    drifts = {"a.ckpt": 4.5, "b.ckpt": 0.06, "c.ckpt": 0.1}
    ranked = [Path(n) for n in drifts]
    checkpoint, checked, passed = first_at_rest(ranked, lambda c: {"drift_cm": drifts[c.name]}, 0.5)
    assert checkpoint == Path("b.ckpt") and passed
    assert [c["drift_cm"] for c in checked] == [4.5, 0.06]  # stops at the first that passes
    checkpoint, checked, passed = first_at_rest(ranked, lambda c: {"drift_cm": 9.0}, 0.5)
    assert checkpoint == Path("a.ckpt") and not passed and len(checked) == 3  # none passes: the best by score
    # A hold that keeps the pool by freezing the corner dam does not pass (step 12k of the 2026-12-02 pools
    # run with the hold at 0.75 g: 0.03 m/s held against 0.64 free).
    dams = {"a.ckpt": (0.6, 0.7), "b.ckpt": (0.03, 0.64), "c.ckpt": (0.6, 0.72)}

    def still_pool(c):
        return {"drift_cm": 0.01, "dam_speed": dams[c.name][0], "dam_speed_free": dams[c.name][1]}

    checkpoint, checked, passed = first_at_rest(ranked, still_pool, 0.5)
    assert checkpoint == Path("a.ckpt") and passed
    checkpoint, checked, passed = first_at_rest(ranked[1:], still_pool, 0.5)
    assert checkpoint == Path("c.ckpt") and passed and len(checked) == 2
    # Nor one whose falling block misses g by more than 5% (the 2026-12-04 dam fine-tune's step 6k: 5.4%).
    falls = {"a.ckpt": 0.054, "b.ckpt": 0.049, "c.ckpt": 0.01}

    def at_rest_and_falling(c):
        return {"drift_cm": 0.01, "fall_error": falls[c.name]}

    checkpoint, checked, passed = first_at_rest(ranked, at_rest_and_falling, 0.5)
    assert checkpoint == Path("b.ckpt") and passed and [c["fall_error"] for c in checked] == [0.054, 0.049]

    run = tmp_path / "run"
    (run / "checkpoints" / "permanent").mkdir(parents=True)
    (run / "csv" / "version_0").mkdir(parents=True)
    header = {"state_dict": {}, "hyper_parameters": {"model": {}}}
    for step in (10, 20, 30):
        torch.save(
            {**header, "global_step": step}, run / "checkpoints" / "permanent" / f"step{step:08d}.ckpt"
        )
    (run / "checkpoints" / "last.ckpt").symlink_to(run / "checkpoints" / "permanent" / "step00000030.ckpt")
    rows = ["step,val/rollout_mse", "9,0.1", "19,0.3", "29,0.2"]  # step 10 best, then 30, then 20
    (run / "csv" / "version_0" / "metrics.csv").write_text("\n".join(rows) + "\n")
    drift_by_step = {10: 4.5, 20: 0.06, 30: 0.3}

    def drift_of(path):
        return {"drift_cm": drift_by_step[int(path.stem[4:])]}

    dest = tmp_path / "shipped"
    # Step 30 is the last checkpoint: shipped without a test evaluation (none can run here: no data.root).
    info = export(run, dest, select_best_val=True, rest_check_of=drift_of)
    assert info["global_step"] == 30
    selected = json.loads((dest / "results.json").read_text())["checkpoint"]["selected"]
    assert selected["val_rollout_mse"] == 0.2 and selected["rest_gate"]["passed"]
    assert [c["drift_cm"] for c in selected["rest_gate"]["checked"]] == [4.5, 0.3]


@pytest.mark.xfail(
    strict=True,
    reason="not met by the weights shipped on 2026-12-07 (the paper's node decoder, 200k steps): a block at "
    "rest in mid-air -8.80 m/s^2, one falling at 1 m/s -11.35 (16% off g); docs/decisions/shipped-weights.md",
)
def test_shipped_model_falls_at_g():
    """A learned simulator must get free flight right: a falling block accelerates at g (within 5%).

    A target the shipped weights do not meet, kept strict so that weights which meet it turn this test
    into a failure that asks for the marker's removal. The network's median particle, one step, no rules
    (with the rules, free flight replaces the network for a block in flight). The pairwise-decoder weights
    shipped before 2026-12-07 met it (-9.75 to -10.04 m/s^2: their pair forces cancel in sum); the
    node-decoder weights before them predicted -4.3 to -9.3 m/s^2, and those before them -10.3 to -12.5."""
    from gnsx.evaluation.hardcases import FREE_FALL_CASES, free_fall_acceleration, free_fall_error

    simulator = load_simulator(SHIPPED / "model.ckpt")
    for height, speed in FREE_FALL_CASES:
        assert free_fall_acceleration(simulator, height, speed) == pytest.approx(-9.8, rel=0.05)
    assert free_fall_error(simulator) < 0.05  # what the export's gate checks
