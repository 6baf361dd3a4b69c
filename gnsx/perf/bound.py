"""A frame against the naive-FLOP bound: the fused and the eager path interleaved in one process.

The bound is what a frame would take if its matrix products ran at the machine's matmul peak and nothing else
cost anything: the frame's *nominal* matmul FLOPs (phi_e's first layer unsplit, ``6 E L W`` per step; 3.13
GFLOP for the simplified model at WaterRamps' 2,300 particles and ~16.3k edges) over the fp32 2048^2 matmul
peak measured between the rounds of the same run. What gnsx executes is less (the split first layer,
:mod:`gnsx.perf.flops`); both are printed.

Why interleaved: the machines gnsx runs on are shared, and their speed drifts by 20-40% within minutes (the
matmul peak too). So every round times the matmul peak, then both paths on the same scene, in alternating
order, and the figures are medians over rounds; the ratio of two paths is only read within one run.

    python -m gnsx.perf.bound --models simplified original --threads 2 --rounds 8

Frames are :meth:`LearnedSimulator.predict_positions` on :func:`gnsx.perf.scaling.scaling_scene` (graph build
included), untrained weights (speed does not depend on them), ``torch.inference_mode``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch

from gnsx.core.machine import cpu_name
from gnsx.core.threads import apply_threads
from gnsx.model import fused
from gnsx.model.registry import MODELS, build_model
from gnsx.perf.flops import forward_flops
from gnsx.perf.scaling import matmul_peak, scaling_scene


def nominal_flops(config: dict, num_nodes: int, num_edges: int) -> int:
    """Matmul FLOPs of a forward pass with phi_e's first layer unsplit (``6 E L W`` per step instead of the
    executed ``2 E L W + 4 N L W``): the naive count the bound divides."""
    latent, width, steps = int(config["latent_size"]), int(config["mlp_hidden_size"]), int(config["mp_steps"])
    split_saving = steps * 4 * latent * width * (num_edges - num_nodes)
    return forward_flops(config, num_nodes, num_edges)["total"] + split_saving


def _frames(simulator, sequence, particle_type, mode: str, warmup: int, frames: int) -> float:
    """Median ms of ``frames`` predictions with ``GNSX_FUSED=mode``, after ``warmup``."""
    os.environ[fused.ENV] = mode
    times = []
    for index in range(warmup + frames):
        start = time.perf_counter()
        simulator.predict_positions(sequence, particle_type)
        if index >= warmup:
            times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


@torch.inference_mode()
def measure(name: str, particles: int, rounds: int, frames: int, warmup: int) -> dict:
    """One model: eager and fused ms/frame per round, the matmul peak per round, FLOPs and the bound."""
    history = MODELS[name].get("history", 1)
    sequence, particle_type, bounds = scaling_scene(particles, history)
    simulator = build_model(name, bounds=bounds)
    previous = os.environ.get(fused.ENV)
    try:
        os.environ[fused.ENV] = "0"
        eager_out = simulator.predict_positions(sequence, particle_type)
        os.environ[fused.ENV] = "1"
        fused_out = simulator.predict_positions(sequence, particle_type)
        edges = int(simulator.build_graph(sequence, particle_type)[1].shape[1])
        eager, fast, peaks = [], [], []
        for index in range(rounds):
            peaks.append(matmul_peak("cpu", repeats=3)["gflops_peak"])
            order = ("0", "1") if index % 2 == 0 else ("1", "0")
            for mode in order:
                ms = _frames(simulator, sequence, particle_type, mode, warmup, frames)
                (eager if mode == "0" else fast).append(ms)
    finally:
        if previous is None:
            os.environ.pop(fused.ENV, None)
        else:
            os.environ[fused.ENV] = previous
    peak = statistics.median(peaks)
    nominal = nominal_flops(simulator.config, particles, edges)
    executed = forward_flops(simulator.config, particles, edges)["total"]
    bound_ms = nominal / peak / 1e6
    eager_ms, fused_ms = statistics.median(eager), statistics.median(fast)
    return {
        "model": name,
        "particles": particles,
        "edges": edges,
        "cpu": cpu_name(),
        "threads": torch.get_num_threads(),
        "fused_available": fused.load(),
        "max_abs_difference": float((eager_out - fused_out).abs().max()),
        "eager_ms": eager_ms,
        "fused_ms": fused_ms,
        "eager_rounds_ms": eager,
        "fused_rounds_ms": fast,
        "matmul_peak_gflops": peak,
        "matmul_peak_rounds": peaks,
        "nominal_gflop": nominal / 1e9,
        "executed_gflop": executed / 1e9,
        "bound_ms": bound_ms,
        "eager_over_bound": eager_ms / bound_ms,
        "fused_over_bound": fused_ms / bound_ms,
        "speedup": eager_ms / fused_ms,
    }


def format_rows(rows: list[dict]) -> str:
    """A markdown table of :func:`measure` rows."""
    lines = [
        f"{rows[0]['cpu']}, {rows[0]['threads']} threads; medians over rounds, fused and eager interleaved",
        "",
        "| model | particles | edges | eager ms | fused ms | speedup | matmul peak GFLOP/s | nominal GFLOP "
        "| bound ms | eager / bound | fused / bound | max abs diff |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['particles']:,} | {r['edges']:,} | {r['eager_ms']:.2f} | {r['fused_ms']:.2f} "
            f"| {r['speedup']:.2f}x | {r['matmul_peak_gflops']:.0f} | {r['nominal_gflop']:.2f} "
            f"| {r['bound_ms']:.2f} | {r['eager_over_bound']:.2f}x | {r['fused_over_bound']:.2f}x "
            f"| {r['max_abs_difference']:.1e} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.perf.bound",
        description="A frame against the naive-FLOP bound: the fused and the eager CPU path interleaved in one "
        "process, the matmul peak between rounds (module docstring).",
    )
    parser.add_argument("--models", nargs="+", default=["simplified"], choices=sorted(MODELS))
    parser.add_argument("--particles", type=int, default=2300, help="water particles (default: WaterRamps')")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    parser.add_argument("--rounds", type=int, default=8, help="rounds of peak, eager, fused (default 8)")
    parser.add_argument("--frames", type=int, default=10, help="timed frames per path and round (default 10)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed frames per path and round (default 2)")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.frames < 1:
        parser.error("--rounds and --frames must be >= 1")
    apply_threads(args.threads)
    if not fused.load():
        parser.error("the fused kernels could not be built here (see the warning above): nothing to compare")
    rows = [measure(name, args.particles, args.rounds, args.frames, args.warmup) for name in args.models]
    print(format_rows(rows))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
