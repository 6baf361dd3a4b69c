"""Evaluation: rollout errors with known answers, their spread over trajectories, benchmark, rollout files,
the evaluate.py entry point, and the scoring library's independence from the training code."""

from __future__ import annotations

import json
import math
import pickle
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import lightning
import numpy as np
import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import DataError
from gnsx.data.datamodule import TrajectoryDataset
from gnsx.data.metadata import Metadata
from gnsx.data.rollout_io import (
    DEEPMIND_KEYS,
    Rollout,
    export_deepmind,
    from_deepmind,
    load_rollout,
    save_rollout,
)
from gnsx.data.store import SplitReader, load_metadata
from gnsx.evaluation.scoring import (
    distribution_frames,
    evaluate_simulator,
    format_table,
    horizon_mse,
    rollout_errors,
    summarise,
)
from gnsx.model.checkpoint import load_simulator, model_label
from gnsx.perf.benchmark import build_model, format_results, measure_inference, packed_scene
from gnsx.rules.rules import Rules
from gnsx.training.system import GNSSystem

ROOT = Path(__file__).resolve().parents[1]
TINY = {"latent_size": 8, "mlp_hidden_size": 8, "mp_steps": 2}
ORIGINAL_TINY = TINY | {
    "history": 5,
    "type_encoding": "embedding",
    "edge_residual": True,
    "wall_clip": (-1.0, 1.0),
}
META = Metadata(
    bounds=[[0.1, 0.9], [0.1, 0.9]], sequence_length=9, default_connectivity_radius=0.05, dim=2, dt=0.0025,
    vel_mean=[0.0, 0.0], vel_std=[1e-3, 1e-3], acc_mean=[0.0, 0.0], acc_std=[1e-4, 1e-4],
)  # fmt: skip


def save_tiny_checkpoint(path: Path, metadata: Metadata, model: dict) -> Path:
    """An untrained tiny GNSSystem, saved like shipped weights (what load_from_checkpoint reads)."""
    stats = {key: getattr(metadata, key) for key in ("vel_mean", "vel_std", "acc_mean", "acc_std")}
    system = GNSSystem(
        model=model,
        dim=metadata.dim,
        bounds=metadata.bounds,
        radius=metadata.default_connectivity_radius,
        **stats,
    )
    state = {"state_dict": system.state_dict(), "hyper_parameters": dict(system.hparams),
             "pytorch-lightning_version": lightning.__version__}  # fmt: skip
    torch.save(state, path)
    return path


@pytest.fixture(scope="module")
def checkpoints(tiny_dataset, tmp_path_factory):
    folder = tmp_path_factory.mktemp("ckpt")
    metadata = load_metadata(tiny_dataset)
    return (
        save_tiny_checkpoint(folder / "simplified.ckpt", metadata, TINY),
        save_tiny_checkpoint(folder / "original.ckpt", metadata, ORIGINAL_TINY),
    )


def _scene(num_frames: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Water falling at constant speed over a static ramp: ``[T, 13, 2]`` positions and types."""
    rng = np.random.default_rng(0)
    water = rng.uniform(0.3, 0.6, (10, 2))
    ramp = np.array([[0.2, 0.2], [0.25, 0.2], [0.3, 0.2]])
    t = np.arange(num_frames)[:, None, None]
    position = np.concatenate([water[None] + [0.0, -0.002] * t, np.broadcast_to(ramp, (num_frames, 3, 2))], 1)
    types = np.r_[np.full(10, WATER_PARTICLE_ID), np.full(3, KINEMATIC_PARTICLE_ID)]
    return position.astype(np.float64), types


# ------------------------------------------------------------------------------------------- known answers


def test_perfect_rollout_has_zero_error():
    true, types = _scene()
    errors, per_frame = rollout_errors(true.copy(), true, types, 2, META, emd_every=3)
    assert errors["rollout_mse"] == 0 and errors["rollout_mse_all"] == 0
    assert errors["emd"] == pytest.approx(0, abs=1e-8) and errors["kinetic_energy_error"] == 0
    assert errors["neighbour_ratio"] == pytest.approx(1.0) and errors["out_of_bounds_final"] == 0
    assert errors["area_ratio_final"] == 1.0
    # EMD on frames 3, 6, 9 (multiples of 3 after the 2 input frames, and the last), NaN elsewhere.
    assert list(np.flatnonzero(~np.isnan(per_frame["emd"]))) == [3, 6, 9]
    assert np.isnan(per_frame["mse"][:2]).all() and (per_frame["mse"][2:] == 0).all()


def test_shifted_rollout_errors_are_the_shift():
    true, types = _scene()
    shift = np.array([0.03, 0.04])
    predicted = true.copy()
    predicted[2:, :10] += shift  # water displaced rigidly in every predicted frame, ramps exact
    errors, per_frame = rollout_errors(predicted, true, types, 2, META, emd_every=2)
    assert errors["rollout_mse"] == pytest.approx((0.03**2 + 0.04**2) / 2)  # per coordinate, water only
    assert errors["rollout_mse_all"] == pytest.approx((0.03**2 + 0.04**2) / 2 * 10 / 13)
    assert errors["emd"] == pytest.approx(0.05) and errors["emd_final"] == pytest.approx(0.05)
    assert errors["neighbour_ratio"] == pytest.approx(1.0)  # a rigid shift keeps the volume
    # Frame 2 jumps by the shift (a burst of kinetic energy), later frames move as the truth does.
    assert per_frame["kinetic_energy_pred"][2] > per_frame["kinetic_energy_true"][2]
    np.testing.assert_allclose(per_frame["kinetic_energy_pred"][3:], per_frame["kinetic_energy_true"][3:])


def test_compressed_rollout_shows_volume_loss_and_escapes_show_out_of_bounds():
    true, types = _scene()
    predicted = true.copy()
    centre = true[:, :10].mean(1, keepdims=True)
    predicted[2:, :10] = (centre + 0.2 * (true[:, :10] - centre))[2:]  # water squeezed to a fifth of its size
    squeezed = rollout_errors(predicted, true, types, 2, META)[0]
    assert squeezed["neighbour_ratio"] > 1.5 and squeezed["area_ratio_final"] < 1.0
    predicted = true.copy()
    predicted[-1, :4] = [0.95, 0.5]  # 4 of 10 water particles leave through the right wall in the last frame
    errors, _ = rollout_errors(predicted, true, types, 2, META)
    assert errors["out_of_bounds_final"] == 4
    assert errors["out_of_bounds_fraction"] == pytest.approx(4 / 10 / 8)


def test_horizons_average_the_first_predicted_frames():
    true, types = _scene(num_frames=62)  # 2 input frames, 60 predicted
    predicted = true.copy()
    step = 0.001 * np.arange(1, 61)  # the k-th predicted frame is off by 0.001 k along both axes
    predicted[2:, :10] += step[:, None, None]
    errors, per_frame = rollout_errors(predicted, true, types, 2, META, emd_every=0)
    np.testing.assert_allclose(per_frame["mse"][2:], step**2)  # per coordinate, water only
    assert errors["mse_at_10"] == pytest.approx(np.mean(step[:10] ** 2))
    assert errors["mse_at_50"] == pytest.approx(np.mean(step[:50] ** 2))
    assert errors["mse_at_10"] < errors["mse_at_50"] < errors["rollout_mse"]
    short, _ = rollout_errors(predicted[:30], true[:30], types, 2, META, emd_every=0)
    assert short["mse_at_10"] == errors["mse_at_10"] and np.isnan(short["mse_at_50"])  # 28 predicted frames
    assert horizon_mse(per_frame["mse"], 2, 60) == pytest.approx(errors["rollout_mse"])
    assert np.isnan(horizon_mse(per_frame["mse"], 2, 61))


def _row(trajectory: int, rollout: float, baseline: float, **more) -> dict:
    row = {"trajectory": trajectory, "particles": 10, "rollout_mse": rollout, "baseline_mse": baseline}
    return row | {"baseline_ratio": baseline / rollout, "ms_per_frame": 1.0, "peak_memory_mb": None, **more}


def test_summary_carries_standard_errors_and_the_geometric_mean_baseline_ratio():
    rows = [_row(0, 1.0, 2.0, mse_at_10=0.1), _row(1, 2.0, 2.0, mse_at_10=0.3), _row(2, 3.0, 6.0)]
    rows[2]["mse_at_10"] = float("nan")  # e.g. a rollout shorter than the horizon
    summary = summarise(rows)
    assert summary["rollout_mse"] == 2.0 and summary["rollout_mse_se"] == pytest.approx(1 / math.sqrt(3))
    assert summary["baseline_mse_se"] == pytest.approx(4 / math.sqrt(3) / math.sqrt(3))  # std 4/sqrt(3)
    assert summary["mse_at_10"] == pytest.approx(0.2)  # NaN rows left out
    assert summary["mse_at_10_se"] == pytest.approx(0.1)
    assert summary["baseline_ratio"] == pytest.approx((10 / 3) / 2)  # ratio of the means, as before
    assert summary["baseline_ratio_geomean"] == pytest.approx(4 ** (1 / 3))  # ratios 2, 1, 2
    assert summary["baseline_ratio_geomean_lo"] < 4 ** (1 / 3) < summary["baseline_ratio_geomean_hi"]
    assert summary["baseline_ratio_wins"] == 2  # a tie is not a win
    assert summary["trajectories"] == 3 and summary["ms_per_frame"] == 1.0
    one = summarise(rows[:1])
    assert one["rollout_mse"] == 1.0 and np.isnan(one["rollout_mse_se"])
    assert np.isnan(one["baseline_ratio_geomean_lo"])
    # Rows written before the horizons existed still summarise (those keys are left out).
    old = [{k: v for k, v in r.items() if k not in ("mse_at_10", "baseline_ratio")} for r in rows]
    assert "mse_at_10" not in summarise(old)
    assert summarise(old)["baseline_ratio_geomean"] == pytest.approx(4 ** (1 / 3))


def test_table_says_loudly_when_the_model_does_not_beat_the_baseline(monkeypatch):
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    losing = [_row(i, 2.0 * f, 1.0 * f) for i, f in enumerate((1.0, 1.1, 0.9, 1.05))]
    table = format_table(losing, summarise(losing), "losing", colour=True)
    assert "\033[1;31mMODEL DOES NOT BEAT THE PHYSICS-FREE BASELINE\033[0m" in table
    assert "geometric mean 0.50x [0.50, 0.50]" in table and "wins on 0/4 trajectories" in table
    plain = format_table(losing, summarise(losing), "losing")  # pytest's stdout is no terminal
    assert "MODEL DOES NOT BEAT THE PHYSICS-FREE BASELINE" in plain and "\033[" not in plain
    monkeypatch.setenv("FORCE_COLOR", "1")
    assert "\033[1;31m" in format_table(losing, summarise(losing), "losing")
    monkeypatch.delenv("FORCE_COLOR")

    mixed = [_row(i, 1.0, r) for i, r in enumerate((3.0, 0.5, 2.0, 0.6))]
    table = format_table(mixed, summarise(mixed), "mixed")
    assert "cannot be told apart from the baseline" in table and "DOES NOT BEAT" not in table
    lines = table.splitlines()
    assert lines[1].split()[:4] == ["traj", "particles", "rollout", "MSE"]
    assert lines[6].startswith(" mean") and lines[7].startswith(" ± se")
    winning = [_row(i, 1.0, r) for i, r in enumerate((3.0, 3.3, 2.9, 3.1))]
    assert "The model beats the physics-free baseline" in format_table(winning, summarise(winning), "w")


def test_scoring_imports_nothing_of_the_training_code():
    code = (
        "import sys, gnsx.evaluation.scoring\n"
        "heavy = ('gnsx.training.run', 'gnsx.evaluation.evaluate', 'gnsx.training.system')\n"
        "bad = [m for m in heavy if m in sys.modules]\n"
        "assert not bad, bad"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]


def test_distribution_frames_are_absolute_so_models_share_them():
    assert distribution_frames(30, 2, 10) == [10, 20, 29]
    assert distribution_frames(30, 6, 10) == [10, 20, 29]
    assert distribution_frames(30, 2, 0) == []


# ------------------------------------------------------------------------------------------- simulators


def test_evaluate_simulator_on_a_split(tiny_dataset, checkpoints):
    metadata = load_metadata(tiny_dataset)
    for checkpoint, frames, count in zip(checkpoints, (2, 6), (2, 1)):
        dataset = TrajectoryDataset(SplitReader(tiny_dataset, "train"), max_trajectories=count)
        simulator = load_simulator(checkpoint)
        assert simulator.input_frames == frames
        seen = []
        summary, rows, first = evaluate_simulator(
            simulator,
            dataset,
            metadata,
            emd_every=10,
            timing_warmup=1,
            timing_repeats=2,
            on_trajectory=seen.append,
        )
        assert summary["trajectories"] == len(rows) == len(seen) == count  # max_trajectories is honoured
        for key in ("rollout_mse", "rollout_mse_all", "onestep_mse", "baseline_mse", "emd", "ms_per_frame",
                    "mse_at_10", "baseline_mse_at_10", "baseline_emd", "baseline_ratio_geomean"):  # fmt: skip
            assert np.isfinite(summary[key]) and summary[key] > 0, key
        assert np.isfinite(summary["rollout_mse_se"]) == (count > 1)
        row, per_frame = rows[0], seen[0].per_frame
        assert np.isnan(row["mse_at_50"]) and np.isnan(row["baseline_mse_at_50"])  # fewer than 50 frames
        first_ten = slice(frames, frames + 10)
        assert row["mse_at_10"] == pytest.approx(np.mean(per_frame["mse"][first_ten]))
        assert row["baseline_mse_at_10"] == pytest.approx(np.mean(per_frame["baseline_mse"][first_ten]))
        assert row["baseline_ratio"] == pytest.approx(row["baseline_mse"] / row["rollout_mse"])
        # The baseline's EMD is taken on the model's EMD frames.
        emd_frames = np.flatnonzero(~np.isnan(per_frame["emd"]))
        np.testing.assert_array_equal(np.flatnonzero(~np.isnan(per_frame["baseline_emd"])), emd_frames)
        assert row["baseline_emd"] == pytest.approx(np.mean(per_frame["baseline_emd"][emd_frames]))
        assert summary["peak_memory_mb"] is None or summary["peak_memory_mb"] >= 0
        assert rows[0]["frames"] == 30 - frames
        assert len(seen[0].per_frame_rows()) == 30 - frames
        assert first["predicted"].shape == first["ground_truth"].shape == (30, rows[0]["particles"], 2)
        np.testing.assert_array_equal(first["predicted"][:frames], first["ground_truth"][:frames])
    assert model_label(load_simulator(checkpoints[0])) == "simplified GNS 8/2"
    assert model_label(load_simulator(checkpoints[1])) == "original GNS 8/2"


def test_measure_inference_and_packed_scene():
    sequence, types = packed_scene(500, 0.02, [[0.1, 0.9], [0.1, 0.9]], history=2)
    assert sequence.shape == (500, 3, 2) and types.shape == (500,)
    assert (types == KINEMATIC_PARTICLE_ID).sum() == 30 and (types == WATER_PARTICLE_ID).sum() == 470
    first = sequence[:, 0].numpy()
    assert (first >= 0.1).all() and (first <= 0.9).all()
    assert torch.equal(sequence[:, 0], sequence[:, -1])  # at rest
    gaps = np.linalg.norm(first[:, None] - first[None], axis=-1) + np.eye(500)
    assert gaps.min() > 0.3 * 0.02  # jittered lattice: no two particles on top of each other
    with pytest.raises(ValueError, match="do not fit"):
        packed_scene(5000, 0.05, [[0.1, 0.9], [0.1, 0.9]], history=1)

    simulator = build_model("simplified", radius=0.05, latent_size=8, mlp_hidden_size=8, mp_steps=2)
    sequence, types = packed_scene(300, 0.02, [[0.1, 0.9], [0.1, 0.9]], simulator.history)
    result = measure_inference(simulator, sequence, types, warmup=1, repeats=3)
    assert result["ms_per_frame"] >= result["ms_per_frame_min"] > 0
    assert result["num_particles"] == 300 and result["num_edges"] > 300 and result["repeats"] == 3
    assert result["memory_measure"] in ("cpu_peak_rss_increase", "unavailable")
    table = format_results({"simplified": result | {"parameters": 1}, "original": result | {"parameters": 2}})
    assert "original / simplified: 1.00x time" in table


# ------------------------------------------------------------------------------------------- rollout files


def test_rollout_file_round_trip_without_pickle(tmp_path):
    true, types = _scene()
    predicted = true + 0.001
    predicted[:2] = true[:2]
    rollout = Rollout(
        predicted, types, 2, true, {"bounds": META.bounds, "dt": 0.0025, "rollout": {"model": "x"}}
    )
    path = save_rollout(tmp_path / "r.npz", rollout)
    with np.load(path, allow_pickle=False) as npz:  # gnsx's format never needs pickle
        assert set(npz.files) == {"predicted", "particle_type", "input_frames", "metadata", "ground_truth"}
    back = load_rollout(path)
    np.testing.assert_array_equal(back.predicted, predicted.astype(np.float32))
    np.testing.assert_array_equal(back.ground_truth, true.astype(np.float32))
    np.testing.assert_array_equal(back.particle_type, types)
    assert back.input_frames == 2 and back.metadata["rollout"]["model"] == "x"
    np.testing.assert_array_equal(back.bounds, META.bounds)
    without = load_rollout(save_rollout(tmp_path / "p.npz", Rollout(predicted, types, 2)))
    assert without.ground_truth is None and without.metadata == {}


def test_deepmind_export_has_exactly_their_keys(tmp_path):
    true, types = _scene()
    rollout = Rollout(true + 0.01, types, 6, true, {"bounds": META.bounds})
    path = export_deepmind(tmp_path / "r.pkl", rollout)
    with open(path, "rb") as f:
        data = pickle.load(f)
    assert set(data) == set(DEEPMIND_KEYS)
    assert data["initial_positions"].shape == (6, 13, 2)
    assert data["predicted_rollout"].shape == data["ground_truth_rollout"].shape == (4, 13, 2)
    np.testing.assert_array_equal(data["particle_types"], types)
    back = from_deepmind(data)
    np.testing.assert_array_equal(back.predicted, rollout.predicted)
    assert back.input_frames == 6
    with pytest.raises(DataError, match="ground truth"):
        export_deepmind(tmp_path / "x.pkl", Rollout(true, types, 2))


def test_rollout_file_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="not found"):
        load_rollout(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", positions=np.zeros(3))
    with pytest.raises(DataError, match=r"other\.npz: not a gnsx rollout: missing member"):
        load_rollout(tmp_path / "other.npz")
    with pytest.raises(DataError, match="particle_type must be"):
        Rollout(np.zeros((3, 4, 2)), np.zeros(5), 1)
    with pytest.raises(DataError, match="end in .npz"):
        save_rollout(tmp_path / "r.pkl", Rollout(np.zeros((3, 4, 2)), np.zeros(4), 1))


# ------------------------------------------------------------------------------------------- entry point


def test_evaluate_entry_point_two_checkpoints_side_by_side(tmp_path, tiny_dataset, checkpoints):
    run = tmp_path / "eval"
    cmd = [
        sys.executable, str(ROOT / "evaluate.py"), f"checkpoint=[{checkpoints[1]},{checkpoints[0]}]",
        f"data.root={tiny_dataset}", "split=test", "logger=csv", "metrics.timing_repeats=2",
        "metrics.timing_warmup=1", "render.frame_stride=1", "render.strip_every=10", "save.deepmind=true",
        f"hydra.run.dir={run}",
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = json.loads((run / "results.json").read_text())
    labels = [m["label"] for m in results["models"]]
    assert labels == ["original GNS 8/2", "simplified GNS 8/2"]
    for model in results["models"]:
        assert model["summary"]["trajectories"] == 1 and model["summary"]["rollout_mse"] > 0
        folder = run / model["folder"]
        assert (folder / "trajectories.csv").is_file() and (folder / "final_frame.png").is_file()
        assert len((folder / "per_frame.csv").read_text().splitlines()) == 1 + model["rows"][0]["frames"]
        rollout = load_rollout(folder / "rollouts" / "test_0000.npz")
        assert rollout.predicted.shape[0] == 30 and rollout.metadata["rollout"]["model"] == model["label"]
        assert (folder / "rollouts" / "test_0000.pkl").is_file()
    animation = iio.imread(run / "comparison.gif")
    assert animation.shape[:3] == (30, 256, 3 * 256)  # ground truth | original | simplified, every frame
    assert iio.imread(run / "strip.png").shape[:2] == (3 * 192, 3 * 192)  # frames 0, 10, 20; three rows
    logged = next((run / "csv").glob("version_*/metrics.csv")).read_text()
    assert "test/simplified_GNS_8_2/rollout_mse" in logged and "test/original_GNS_8_2/frame_mse" in logged
    assert "test/simplified_GNS_8_2/rollout_mse_se" not in logged  # one trajectory: no spread, not logged
    # The second model compared with the first, paired by trajectory (one: they cannot be told apart).
    comparisons = results["comparisons"]
    assert [(c["a"], c["b"], c["key"]) for c in comparisons] == [
        ("original GNS 8/2", "simplified GNS 8/2", "rollout_mse"),
        ("original GNS 8/2", "simplified GNS 8/2", "emd"),
    ]
    assert all(c["verdict"] == "cannot be told apart" and c["trajectories"] == 1 for c in comparisons)
    assert "Paired comparisons with original GNS 8/2" in done.stdout and "± se" in done.stdout


def test_the_raw_network_is_the_default_and_rules_only_add_a_labelled_table(
    tmp_path, tiny_dataset, checkpoints
):
    """Every config defaults to the raw network (walls and ramps only); ``rules=production`` adds a second
    table with the rules beside the raw one, which stays the primary figure (summary, rows, comparisons)."""
    from hydra import compose, initialize_config_dir

    from gnsx.evaluation.evaluate import evaluate_checkpoints

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        for name in ("config", "evaluate", "simulate"):
            assert Rules.from_config(compose(config_name=name, overrides=["checkpoint=x"] * (name != "config")),
                                     "rules") == Rules.none(), name  # fmt: skip
            production = compose(
                config_name=name, overrides=["rules=production"] + ["checkpoint=x"] * (name != "config")
            )
            assert Rules.from_config(production, "rules") == Rules.production(), name

    common = dict(split="test", max_trajectories=1, emd_every=0, timing_repeats=0, save_rollouts=False,
                  render=False)  # fmt: skip
    raw = evaluate_checkpoints([checkpoints[0]], tiny_dataset, tmp_path / "raw", **common)
    both = evaluate_checkpoints(
        [checkpoints[0]], tiny_dataset, tmp_path / "both", rules=Rules.production(), **common
    )
    assert raw["rules"] == both["rules"] == Rules.none().to_dict() and "with_rules" not in raw
    assert both["with_rules"] == Rules.production().to_dict()
    model_raw, model_both = raw["models"][0], both["models"][0]
    assert "with_rules" not in model_raw
    # The primary figure is the same raw rollout whether or not rules were asked for.
    assert model_both["summary"]["rollout_mse"] == model_raw["summary"]["rollout_mse"]
    extra = model_both["with_rules"]
    assert extra["rules"] == Rules.production().to_dict() and len(extra["rows"]) == 1
    assert extra["rows"][0]["baseline_mse"] == model_raw["rows"][0]["baseline_mse"]  # the baseline: no rules
    assert np.isfinite(extra["summary"]["rollout_mse"])
    assert json.loads((tmp_path / "both" / "results.json").read_text())["with_rules"]["free_flight"] is True
