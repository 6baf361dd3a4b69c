"""Scaling benchmark (issue 10): the growing scene, the FLOP formula, rollout memory, the budget and the CLI.

No assertion here is on a time: the machines are shared and timings are noise. The CLI runs on sizes of a few
hundred particles.
"""

from __future__ import annotations

import json
import math

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from gnsx.core.constants import WATER_PARTICLE_ID
from gnsx.model.neighbors import radius_graph
from gnsx.perf import benchmark
from gnsx.perf.benchmark import MODELS, WATERRAMPS, build_model
from gnsx.perf.flops import forward_flops, training_flops
from gnsx.perf.memtrack import TensorMemoryTracker, hold_still, rollout_growth, rollout_memory
from gnsx.perf.scaling import (
    build_system,
    linearity,
    plan_measurement,
    run_scaling,
    scaling_scene,
    training_batch,
    training_step,
)

SPACING, RADIUS = WATERRAMPS["spacing"], WATERRAMPS["radius"]


pytestmark = pytest.mark.usefixtures("one_thread")


# -- the scene -----------------------------------------------------------------------------------------------
def test_scaling_scene_keeps_density_edges_per_particle_and_walls():
    rows = []
    for n in (500, 2300, 8000, 20000):
        sequence, particle_type, bounds = scaling_scene(n, history=1)
        position = sequence[:, -1]
        assert sequence.shape == (n, 2, 2) and bool((particle_type == WATER_PARTICLE_ID).all())
        lo, hi = bounds[0]
        side = hi - lo
        assert bounds[1] == bounds[0] and lo == 0.1
        assert bool(((position > lo) & (position < hi)).all())
        # The block rests in the lower-left corner: one spacing (+- jitter) from the floor and the left wall.
        assert (position.min(dim=0).values - lo).max() < 1.5 * SPACING
        edges = radius_graph(position, RADIUS).shape[1]
        extent = position.max(dim=0).values - position.min(dim=0).values
        rows.append({"n": n, "density": n / side**2, "edges_per_particle": edges / n,
                     "fill": float(extent.prod()) / side**2})  # fmt: skip
        if n == 2300:  # WaterRamps' box at WaterRamps' size
            assert side == pytest.approx(0.8)
    densities = [r["density"] for r in rows]
    assert max(densities) / min(densities) == pytest.approx(1.0, abs=1e-9)
    per_particle = [r["edges_per_particle"] for r in rows]
    # Constant up to the block's surface (a 1 / sqrt(N) share of the particles with fewer neighbours).
    assert max(per_particle) / min(per_particle) < 1.08
    assert per_particle == sorted(per_particle)
    fills = [r["fill"] for r in rows]  # the water fills the same share of the box
    assert max(fills) / min(fills) < 1.1


# -- FLOPs ---------------------------------------------------------------------------------------------------
def _inplace_addmm(self_shape, a_shape, b_shape, out_shape=None, **kwargs) -> int:
    return 2 * a_shape[0] * a_shape[1] * b_shape[1]


def _counter() -> FlopCounterMode:
    # torch's counter knows addmm but not its in-place form, which the split first layer uses.
    return FlopCounterMode(display=False, custom_mapping={torch.ops.aten.addmm_: _inplace_addmm})


@pytest.mark.parametrize("name", sorted(MODELS))
def test_flop_formula_matches_torch_flop_counter(name, monkeypatch):
    # torch's counter sees aten products only: the eager path (the fused kernels run the same products).
    monkeypatch.setenv("GNSX_FUSED", "0")
    history = MODELS[name].get("history", 1)
    sequence, particle_type, bounds = scaling_scene(150, history)
    simulator = build_model(name, bounds=bounds)
    _, edge_index, _ = simulator.build_graph(sequence, particle_type)
    counter = _counter()
    with torch.inference_mode(), counter:
        simulator.predict_positions(sequence, particle_type)
    parts = forward_flops(simulator.config, len(particle_type), edge_index.shape[1])
    assert counter.get_total_flops() == parts["total"]
    assert parts["total"] == parts["encoders"] + parts["processor"] + parts["decoder"]

    batch, bounds = training_batch(120, history, batch_size=2, spacing=SPACING)
    system = build_system(name, bounds)
    system.hparams.noise_std = 0.0  # noise moves a few edges in or out of the clean graph counted here
    optimizer = system.configure_optimizers()["optimizer"]
    graph = system.simulator.build_graph(batch.position_sequence, batch.particle_type, batch.batch)
    counter = _counter()
    with counter:
        training_step(system, batch, optimizer)
    assert counter.get_total_flops() == training_flops(system.simulator.config, 240, graph[1].shape[1])


# -- rollout memory ------------------------------------------------------------------------------------------
def test_rollout_memory_does_not_grow_with_frames():
    sequence, particle_type, bounds = scaling_scene(120, history=1)
    simulator = hold_still(build_model("simplified", bounds=bounds))
    rows = rollout_memory(simulator, sequence, particle_type, frames=(10, 100))
    growth = rollout_growth(rows)
    assert rows[1]["output_mb"] == pytest.approx(10 * rows[0]["output_mb"])
    # Beyond the returned trajectory (and its stacked copy), nothing grows with the frames.
    assert growth["peak_growth_mb"] > 0 and growth["excess_mb"] <= 1e-3
    # The tracker sees growth where there is some: a rollout that keeps each frame's graph.
    kept, predict = [], simulator.predict_positions

    def leaky(window, types, batch=None):
        kept.append(simulator.build_graph(window, types))
        return predict(window, types, batch)

    simulator.predict_positions = leaky
    leak = rollout_growth(rollout_memory(simulator, sequence, particle_type, frames=(5, 15)))
    assert leak["excess_mb"] > 0.5 * 10 * sum(t.numel() * t.element_size() for t in kept[0]) / 1e6


def test_tensor_tracker_counts_allocations_not_views():
    tracker = TensorMemoryTracker()
    with tracker:
        a = torch.zeros(1000)  # 4,000 bytes
        b = a[:10]
        a.add_(1)
        assert tracker.current == 4000
        del a
        assert tracker.current == 4000  # the view keeps the storage
        del b
        assert tracker.current == 0 and tracker.peak == 4000


# -- budget, linearity ---------------------------------------------------------------------------------------
def test_plan_measurement_shrinks_repeats_and_skips_with_a_reason():
    previous = {"particles": 1000, "ms_per_unit": 100.0, "unit": "frame", "peak_memory_mb": 50.0}
    assert plan_measurement(None, 10**6, 2, 20, 1.0, 1.0) == (20, None)
    assert plan_measurement(previous, 2000, 2, 20, 60.0, None) == (20, None)
    assert plan_measurement(previous, 10_000, 2, 20, 10.0, None) == (8, None)  # 1 s per frame
    repeats, reason = plan_measurement(previous, 100_000, 2, 20, 40.0, None)  # 10 s x (2 + 3) > 40
    assert repeats is None and "--max-seconds 40" in reason
    repeats, reason = plan_measurement(previous, 100_000, 2, 20, 1e9, 1000.0)  # 5 GB > 1 GB
    assert repeats is None and "5.0 GB" in reason


def test_linearity_against_the_size_nearest_2300():
    rows = [{"model": "m", "mode": "inference", "particles": n, "ms_per_frame": ms}
            for n, ms in ((1000, 1.0), (2000, 2.0), (100_000, 150.0))]  # fmt: skip
    result = linearity(rows)["m/inference"]
    assert result["reference_particles"] == 2000 and result["max_particles"] == 100_000
    assert result["ratio"] == pytest.approx(1.5)
    assert [r["linear_ratio"] for r in rows] == pytest.approx([1.0, 1.0, 1.5])


def test_run_scaling_skips_what_does_not_fit():
    results = run_scaling(["simplified"], [100, 200, 400], training=False, repeats=1, warmup=0,
                          max_seconds=1e-6, matmul_size=64, log=lambda line: None)  # fmt: skip
    # The first size has nothing to extrapolate from.
    assert [r["particles"] for r in results["rows"]] == [100]
    assert [s["particles"] for s in results["skipped"]] == [200, 400]
    assert all("--max-seconds" in s["reason"] for s in results["skipped"])
    assert results["linearity"]["simplified/inference"]["ratio"] is None


# -- CLI -----------------------------------------------------------------------------------------------------
def test_cli_prints_table_writes_json_and_plot(tmp_path, capsys):
    path = tmp_path / "bench" / "scaling.json"
    code = benchmark.main([
        "--sizes", "100", "200", "--repeats", "1", "--warmup", "0", "--threads", "1", "--json", str(path),
        "--matmul-size", "128", "--rollout-memory", "--rollout-frames", "3", "6", "--rollout-particles", "80",
    ])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "| model | mode | particles |" in out and "fp32 matmul peak" in out
    assert "linearity simplified/training" in out and "rollout memory (simplified" in out
    results = json.loads(path.read_text())
    assert len(results["rows"]) == 12  # 2 sizes x 3 models x (inference, training)
    assert set(results["linearity"]) == {f"{m}/{mode}" for m in MODELS for mode in ("inference", "training")}
    meta = results["meta"]
    assert meta["threads"] == 1 and meta["matmul_gflops_peak"] > 0
    for row in results["rows"]:
        assert math.isclose(row["peak_fraction"], row["gflops"] / meta["matmul_gflops_peak"])
        assert row["gflops"] > 0
        assert row["particle_steps_per_s"] > 0 and row["edges_per_particle"] > 4
        assert row["batch_size"] == (2 if row["mode"] == "training" else 1)
    assert [r["frames"] for r in results["rollout_memory"]["rows"]] == [3, 6]
    assert path.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_cli_compile_measures_the_compiled_model(tmp_path, capsys):
    # torch.compile of the blocks for inference and training (~30-60 s of compiling: slow).
    path = tmp_path / "compiled.json"
    argv = ["--sizes", "100", "--models", "simplified", "--repeats", "1", "--warmup", "1", "--compile",
            "--matmul-size", "128", "--json", str(path)]  # fmt: skip
    assert benchmark.main(argv) == 0
    assert "model.compile on" in capsys.readouterr().out
    results = json.loads(path.read_text())
    assert results["meta"]["compile"] is True and len(results["rows"]) == 2
    assert build_system("simplified", [[0.1, 0.9]] * 2, compile=True).simulator.config["compile"] is True


def test_cli_one_size_past_the_waterramps_box(capsys):
    # Issue 10: --particles past ~2.5k used to refuse (the packed scene did not fit WaterRamps' box).
    argv = ["--particles", "6000", "--models", "simplified", "--repeats", "1", "--warmup", "0"]
    assert benchmark.main(argv) == 0
    assert "simplified" in capsys.readouterr().out


def test_cli_rejects_bad_sizes():
    with pytest.raises(ValueError, match="--sizes: must be >= 1"):
        benchmark.main(["--sizes", "0"])


_RSS_AFTER_FREE = """
import sys
import torch
from gnsx.core.allocator import retain_freed_memory

def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024

applied = retain_freed_memory()
before = rss_mb()
big = torch.ones(64 * 2**20 // 4)  # 64 MB, above glibc's largest mmap threshold (32 MB)
del big
print(applied, rss_mb() - before)
"""


@pytest.mark.parametrize("defaults", [False, True])
def test_freed_large_tensors_stay_in_the_process(defaults):
    """gnsx.core.allocator: a freed 64 MB tensor stays resident (the next frame reuses it without page faults);
    with GNSX_GLIBC_MALLOC_DEFAULTS=1 glibc unmaps it as usual."""
    import os
    import subprocess
    import sys

    if not os.path.exists("/proc/self/status"):
        pytest.skip("needs /proc to read the resident memory")
    env = dict(os.environ, GNSX_GLIBC_MALLOC_DEFAULTS="1" if defaults else "0")
    out = subprocess.run(
        [sys.executable, "-c", _RSS_AFTER_FREE], capture_output=True, text=True, env=env, check=True
    ).stdout.split()
    applied, kept_mb = out[0] == "True", float(out[1])
    if defaults:
        assert not applied and kept_mb < 16
    else:
        assert applied and kept_mb > 48
