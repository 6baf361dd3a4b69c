"""Retiming a sweep's jobs together (gnsx.evaluation.report.retime): the in-job timing is kept beside the new
one, a record without weights is timed as the model it describes, and the report says which timing it uses."""

from __future__ import annotations

import json

import pytest

from gnsx.evaluation.report.jobs import all_retimed, load_sweep
from gnsx.evaluation.report.retime import main, timed_jobs

MODEL = {"name": "simplified", "latent_size": 16, "mp_steps": 2, "mlp_hidden_size": 16, "mlp_hidden_layers": 1,
         "history": 1, "type_encoding": "scalar", "wall_clip": [0.0, 1.0], "edge_residual": False,
         "layer_norm": True, "self_edges": False, "neighbor_search": "auto", "compile": False, "radius": 0.035,
         "noise_std": 1e-4}  # fmt: skip
IN_JOB = {"ms_per_frame": 999.0, "peak_memory_mb": 1.0, "num_particles": 200, "spacing": 0.015625,
          "domain_scale": 1.0, "device": "cpu"}  # fmt: skip


@pytest.fixture
def sweep(tmp_path):
    for name, status in (("a", "ok"), ("b", "ok"), ("c", "failed")):
        folder = tmp_path / name
        folder.mkdir()
        results = {"status": status, "model_config": {**MODEL, "mp_steps": 1 + len(name) + (name == "b")},
                   "bench": dict(IN_JOB), "test": {"rollout_mse": 0.01}}  # fmt: skip
        (folder / "results.json").write_text(json.dumps(results))
    return tmp_path


def test_retime_keeps_the_in_job_timing_and_marks_the_new_one(sweep, capsys):
    ready, skipped = timed_jobs(sweep)
    assert [p.name for p in ready] == ["a", "b"] and skipped == ["c: status failed"]
    assert not all_retimed(load_sweep(sweep))
    assert main([str(sweep), "--rounds", "2", "--repeats", "2", "--warmup", "1"]) == 0
    for name in ("a", "b"):
        results = json.loads((sweep / name / "results.json").read_text())
        assert results["bench_in_job"] == IN_JOB
        bench = results["bench"]
        assert bench["timing"].startswith("retimed") and len(bench["ms_per_frame_rounds"]) == 2
        assert bench["ms_per_frame"] != 999.0 and bench["ms_per_frame_min"] <= bench["ms_per_frame"]
        assert bench["weights"].startswith("untrained") and bench["num_particles"] == 200
    assert all_retimed(load_sweep(sweep))
    # A second retime starts again from the in-job scene and keeps the first in-job record.
    assert main([str(sweep), "--rounds", "1", "--repeats", "1", "--warmup", "0"]) == 0
    assert json.loads((sweep / "a" / "results.json").read_text())["bench_in_job"] == IN_JOB
    assert "skipped c: status failed" in capsys.readouterr().out


def test_retime_counts_memory_exactly_whatever_ran_before(sweep):
    """The retimed memory is one frame's tensor peak plus the weights, counted by the tensor tracker: the same
    on a second retime (another order, other models run before it), unlike a shared process's peak RSS."""
    from gnsx.evaluation.report.retime import job_model, job_scene
    from gnsx.evaluation.tensor_memory import frame_memory

    assert main([str(sweep), "--rounds", "1", "--repeats", "1", "--warmup", "0"]) == 0
    first = {n: json.loads((sweep / n / "results.json").read_text())["bench"] for n in ("a", "b")}
    assert main([str(sweep), "--rounds", "1", "--repeats", "1", "--warmup", "0"]) == 0
    for name in ("a", "b"):
        results = json.loads((sweep / name / "results.json").read_text())
        bench = results["bench"]
        assert bench["memory_measure"].startswith("tensor_tracker")
        assert bench["peak_memory_mb"] == pytest.approx(first[name]["peak_memory_mb"], rel=1e-12)
        assert bench["peak_memory_mb"] == pytest.approx(bench["frame_mb"] + bench["weights_mb"])
        simulator, _ = job_model(sweep / name, results)
        weights = sum(t.numel() * t.element_size() for t in [*simulator.parameters(), *simulator.buffers()])
        assert bench["weights_mb"] == pytest.approx(weights / 1e6)
    # A frame of more particles needs more memory (the count is not a constant).
    simulator, _ = job_model(sweep / "a", json.loads((sweep / "a" / "results.json").read_text()))
    bounds = simulator.bounds.cpu().numpy().astype("float64")
    small = frame_memory(simulator, *job_scene({**IN_JOB, "num_particles": 100}, bounds, simulator.history))
    large = frame_memory(simulator, *job_scene({**IN_JOB, "num_particles": 400}, bounds, simulator.history))
    assert large["frame_mb"] > 2 * small["frame_mb"] > 0


def test_retime_refuses_a_missing_folder_in_one_line(tmp_path, capsys):
    from gnsx.core.cli import run_main
    from gnsx.evaluation.report import retime

    assert run_main(retime.main, [str(tmp_path / "nope")], user_errors=(FileNotFoundError, ValueError)) == 2
    assert capsys.readouterr().err.strip().endswith("no such sweep folder")
