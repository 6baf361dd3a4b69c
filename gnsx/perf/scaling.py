"""Scaling benchmark (``make bench``): cost per frame against particle count, inference and training.

For each size N (default 1k, 2.3k, 10k, 100k; 1M on a GPU) and each model (simplified, original), one scene
of N water particles at WaterRamps' spacing (0.009) and radius (0.015) in a box that grows with N
(:func:`scaling_scene`): the water's density, the edges per particle and the share of the box the water fills
stay those of WaterRamps at 2.3k, so the work per particle is constant and a linear-cost simulator takes
``N / 2300`` times its 2.3k time. Measured per size, model and mode:

* **inference**: :func:`gnsx.evaluation.timing.measure_inference` (one ``predict_positions``: neighbour search, graph,
  features, network, integration; median after warm-up) and its peak memory;
* **training**: :func:`measure_training`, one optimizer step on a batch of ``batch_size`` scenes (the
  trainer's default 2) through :class:`gnsx.training.system.GNSSystem`'s loss path: ``noisy_training_pair`` with its
  noise std, :func:`gnsx.training.system.acceleration_loss` over the water, backward, and the optimizer of
  ``GNSSystem.configure_optimizers`` (fused Adam and its LR schedule); only Lightning's logging and its
  NaN-step bookkeeping are left out. Its "ms/frame" is ms per step / batch size;
* particle-steps per second, matmul FLOPs per frame from :mod:`gnsx.perf.flops` and the achieved GFLOP/s, next to
  the fp32 matmul peak of the same device and thread count measured in the same run (:func:`matmul_peak`, at
  the start and at the end: load from other processes shows as a difference);
* the linearity ratio ``ms(N_max) / (N_max / N_ref * ms(N_ref))`` per model and mode, N_ref the size nearest
  2.3k (1: exactly linear; the issue asks for at most 1.3 at 100k).

A size whose time or memory, extrapolated linearly from the previous measured size of the same model and
mode, exceeds ``max_seconds`` (warm-up and 3 repeats) or ``max_memory_mb`` is skipped with its reason; so is
one that runs out of memory. Repeats shrink with size to fit ``max_seconds`` (at least 3).
"""

from __future__ import annotations

import gc
import math
import os
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path

import numpy as np
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.core.machine import cpu_name
from gnsx.data.waterramps import WATERRAMPS
from gnsx.evaluation.timing import measure_inference, memory_peak, memory_start, packed_scene
from gnsx.model import fused
from gnsx.model.registry import MODELS, build_model
from gnsx.model.training_targets import noisy_training_pair
from gnsx.perf.flops import forward_flops, training_flops

#: Sizes of ``make bench`` (particles per scene); a GPU adds :data:`CUDA_EXTRA_SIZES`.
DEFAULT_SIZES = (1_000, 2_300, 10_000, 100_000)
CUDA_EXTRA_SIZES = (1_000_000,)
#: The size the linear line starts from (WaterRamps' largest scenes).
REFERENCE_PARTICLES = WATERRAMPS["particles"]
#: Side of WaterRamps' box (walls at 0.1 and 0.9).
WATERRAMPS_SIDE = 0.8
MIN_REPEATS = 3
_MB = 1e6


# -- the scene --------------------------------------------------------------------------------------------
def scaling_side(num_particles: int, spacing: float = WATERRAMPS["spacing"]) -> float:
    """Box side (data units) for N particles: ``0.8 sqrt(N / 2300) * spacing / 0.009``.

    WaterRamps' 0.8 box at 2.3k particles and 0.009 spacing; the area grows with N, so the water fills the
    same share of the box (~29% at that spacing) at every N. At least ``ceil(sqrt(N)) + 2`` spacings, so a
    handful of particles still fits.
    """
    side = WATERRAMPS_SIDE * math.sqrt(num_particles / REFERENCE_PARTICLES) * spacing / WATERRAMPS["spacing"]
    return max(side, (math.ceil(math.sqrt(max(num_particles, 1))) + 2) * spacing)


def scaling_scene(
    num_particles: int, history: int, spacing: float = WATERRAMPS["spacing"], seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, list[list[float]]]:
    """N water particles at rest in the lower-left corner of a square box of side :func:`scaling_side`.

    The water is :func:`gnsx.evaluation.timing.packed_scene`'s square block (a jittered lattice of ``spacing``, no
    ramps) with its lowest row and leftmost column one spacing from the floor and the left wall. The walls
    move out with N: the block keeps touching two walls (so the wall features take the same values on its
    bottom and left rows) and the box keeps the same share of empty space (so the top and right walls stay as
    far from the water, relative to its size). Density and edges per particle are those of a lattice of
    ``spacing`` at every N, up to the block's surface, whose share of the particles shrinks as
    ``1 / sqrt(N)`` (the particles there have fewer neighbours: ~4% fewer edges per particle at 1k than at
    100k).

    Returns:
        ``position_sequence [N, history + 1, 2]`` float32 (every frame the same), ``particle_type [N]``
        int64 (all water) and ``bounds [[0.1, 0.1 + side]] * 2``.
    """
    side = scaling_side(num_particles, spacing)
    bounds = [[0.1, 0.1 + side]] * 2
    sequence, particle_type = packed_scene(num_particles, spacing, bounds, history, seed, ramp_fraction=0.0)
    return sequence, particle_type, bounds


def training_batch(num_particles: int, history: int, batch_size: int, spacing: float, seed: int = 0):
    """A training batch like the trainer's: ``batch_size`` scenes of :func:`scaling_scene` (different
    jitter), collated by PyG's ``Batch`` as :class:`gnsx.data.datamodule.FrameDataset`'s samples are.

    Returns:
        the ``Batch`` (``position_sequence``, ``next_position`` = the last position, ``particle_type``,
        ``batch``) and the scenes' bounds.
    """
    from torch_geometric.data import Batch, Data

    samples, bounds = [], None
    for index in range(batch_size):
        sequence, particle_type, bounds = scaling_scene(num_particles, history, spacing, seed + index)
        samples.append(Data(position_sequence=sequence, next_position=sequence[:, -1].clone(),
                            particle_type=particle_type, num_nodes=num_particles))  # fmt: skip
    return Batch.from_data_list(samples), bounds


# -- measurements -----------------------------------------------------------------------------------------
def build_system(
    name: str, bounds: Sequence[Sequence[float]], radius: float = WATERRAMPS["radius"], compile: bool = False
):
    """An untrained :class:`gnsx.training.system.GNSSystem` of a :data:`gnsx.model.registry.MODELS` config with
    WaterRamps'
    statistics in ``bounds`` (``compile``: the ``model.compile`` switch)."""
    from gnsx.training.system import GNSSystem

    facts = {k: WATERRAMPS[k] for k in ("vel_mean", "vel_std", "acc_mean", "acc_std")}
    bounds = [list(pair) for pair in bounds]
    return GNSSystem(model=dict(MODELS[name], compile=compile), dim=2, bounds=bounds, radius=radius, **facts)


def training_step(system, batch, optimizer, scheduler=None) -> torch.Tensor:
    """One optimizer step of ``GNSSystem.training_step``'s loss path (module docstring); returns the loss."""
    from gnsx.training.system import acceleration_loss

    optimizer.zero_grad(set_to_none=True)
    predicted, target = noisy_training_pair(system.simulator,
        batch.position_sequence, batch.next_position, batch.particle_type, system.current_noise_std(),
        batch=batch.batch,
    )  # fmt: skip
    dynamic = batch.particle_type != KINEMATIC_PARTICLE_ID
    h = system.hparams
    loss = acceleration_loss(predicted[dynamic], target[dynamic], h.loss, h.huber_delta)
    loss.backward()
    optimizer.step()
    if scheduler is not None:
        scheduler.step()
    return loss.detach()


def measure_training(system, batch, warmup: int = 2, repeats: int = 10) -> dict:
    """Time :func:`training_step` (median of ``repeats`` after ``warmup``) and its peak memory (as
    :func:`gnsx.evaluation.timing.measure_inference`: CUDA max allocated, or the CPU peak-RSS increase, which here
    includes Adam's moments, allocated in the first warm-up step).

    Returns:
        ``ms_per_step``, ``ms_per_step_min``, ``peak_memory_mb``, ``memory_measure``, ``num_nodes``,
        ``num_edges`` (of the batch's graph), ``device``, ``repeats``.
    """
    if repeats < 1:
        raise ValueError(f"measure_training: repeats must be >= 1, got {repeats}")
    device = system.simulator.acc_std.device
    batch = batch.to(device)
    system.train()
    setup = system.configure_optimizers()
    optimizer, scheduler = setup["optimizer"], setup["lr_scheduler"]["scheduler"]

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    measure, rss_before = memory_start(device)
    for _ in range(warmup):
        training_step(system, batch, optimizer, scheduler)
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        training_step(system, batch, optimizer, scheduler)
        sync()
        times.append(time.perf_counter() - start)
    peak = memory_peak(device, measure, rss_before)
    with torch.no_grad():
        graph = system.simulator.build_graph(batch.position_sequence, batch.particle_type, batch.batch)
    return {
        "ms_per_step": 1000 * statistics.median(times),
        "ms_per_step_min": 1000 * min(times),
        "peak_memory_mb": peak,
        "memory_measure": measure,
        "num_nodes": int(batch.particle_type.shape[0]),
        "num_edges": int(graph[1].shape[1]),
        "device": str(device),
        "repeats": int(repeats),
    }


def matmul_peak(device: str | torch.device = "cpu", size: int | None = None, repeats: int = 5) -> dict:
    """fp32 GFLOP/s of a square ``[n, n] @ [n, n]`` (``2 n^3`` FLOPs), on the current torch thread count.

    ``n`` defaults to 2048 on the CPU (~17 GFLOP, compute-bound) and 8192 on CUDA. The best of ``repeats``
    after one warm-up is the peak; the median is reported too. On CUDA, TF32 follows
    ``torch.backends.cuda.matmul.allow_tf32`` (off by default: true fp32, like the model's products).
    """
    device = torch.device(device)
    n = size or (8192 if device.type == "cuda" else 2048)
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(n, n, generator=generator).to(device)
    b = torch.randn(n, n, generator=generator).to(device)
    times = []
    for index in range(repeats + 1):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        torch.mm(a, b)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        if index:  # the first is a warm-up
            times.append(time.perf_counter() - start)
    flops = 2 * n**3
    return {
        "size": n,
        "gflops_peak": flops / min(times) / 1e9,
        "gflops_median": flops / statistics.median(times) / 1e9,
        "threads": torch.get_num_threads(),
        "tf32": bool(torch.backends.cuda.matmul.allow_tf32) if device.type == "cuda" else False,
        "device": str(device),
    }


# -- the run ----------------------------------------------------------------------------------------------
def memory_limit_mb(device: torch.device) -> float | None:
    """Default memory budget of one measurement: half the CPU's ``MemAvailable`` (the CPU figure is a lower
    bound, and the machine may be shared) or 85% of the GPU's free memory; None where unknown."""
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return 0.85 * free / _MB
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return 0.5 * int(line.split()[1]) * 1024 / _MB
    except OSError:
        pass
    return None


def plan_measurement(
    previous: dict | None, particles: int, warmup: int, repeats: int, max_seconds: float,
    max_memory_mb: float | None,
) -> tuple[int | None, str | None]:  # fmt: skip
    """Repeats for the next size from the previous measured row of the same model and mode, by linear
    extrapolation; ``(None, reason)`` when it would not fit the time or memory budget."""
    if previous is None:
        return repeats, None
    factor = particles / previous["particles"]
    seconds = previous["ms_per_unit"] / 1000 * factor  # one frame (inference) or one step (training)
    if seconds * (warmup + min(MIN_REPEATS, repeats)) > max_seconds:
        return None, (
            f"~{seconds:.1f} s per {previous['unit']} (linear from {previous['particles']:,}): warm-up + "
            f"{min(MIN_REPEATS, repeats)} exceed --max-seconds {max_seconds:g}"
        )
    peak = previous.get("peak_memory_mb")
    if max_memory_mb is not None and peak is not None and peak * factor > max_memory_mb:
        return None, (
            f"~{peak * factor / 1000:.1f} GB peak (linear from {previous['particles']:,}) exceeds the "
            f"{max_memory_mb / 1000:.1f} GB budget"
        )
    fitting = int(max_seconds / max(seconds, 1e-9)) - warmup
    return max(min(MIN_REPEATS, repeats), min(repeats, fitting)), None


def _out_of_memory(error: BaseException) -> bool:
    return isinstance(error, MemoryError | torch.OutOfMemoryError) or (
        isinstance(error, RuntimeError) and "memory" in str(error).lower()
    )


def _release(device: torch.device) -> None:
    gc.collect()
    if device.type == "cuda":
        torch.cuda.empty_cache()


def run_scaling(
    models: Sequence[str] = ("simplified", "original"),
    sizes: Sequence[int] = DEFAULT_SIZES,
    device: str = "cpu",
    warmup: int = 2,
    repeats: int | None = None,
    max_seconds: float = 60.0,
    max_memory_mb: float | None = None,
    batch_size: int = 2,
    training: bool = True,
    radius: float = WATERRAMPS["radius"],
    spacing: float = WATERRAMPS["spacing"],
    matmul_size: int | None = None,
    log: Callable[[str], None] = print,
    compile: bool = False,
) -> dict:
    """Measure every size, model and mode (module docstring).

    Args:
        repeats: most timed frames/steps per measurement (default 20 for inference, 10 for training); fewer
            at large sizes to fit ``max_seconds``, at least 3.
        max_seconds: time budget of one measurement (warm-up included), seconds.
        max_memory_mb: memory budget of one measurement (default :func:`memory_limit_mb`).
        log: where progress lines go.
        compile: measure with ``model.compile`` on (``torch.compile`` of the network's blocks); the warm-up
            frames then include the compilation, so give at least one.
    Returns:
        ``meta`` (device, threads, torch, load, matmul peaks, settings), ``rows`` (one per measurement),
        ``skipped`` (model, mode, particles, reason) and ``linearity`` (:func:`linearity`).
    """
    dev = torch.device(device)
    limit = max_memory_mb if max_memory_mb is not None else memory_limit_mb(dev)
    meta = {
        "date": datetime.now().isoformat(timespec="seconds"),
        "command": " ".join(["python -m gnsx.perf.benchmark", *sys.argv[1:]]) if sys.argv else "",
        "device": str(dev),
        "device_name": device_name(dev),
        "threads": torch.get_num_threads(),
        # The BLAS/OpenMP pools of numpy and scipy beside torch's (threadpoolctl): what else may compete.
        "thread_pools": _thread_pools(),
        "torch": torch.__version__,
        "load_average_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "radius": radius,
        "spacing": spacing,
        "batch_size": batch_size,
        "warmup": warmup,
        "max_seconds": max_seconds,
        "max_memory_mb": limit,
        "sizes": [int(n) for n in sizes],
        "models": list(models),
        "compile": bool(compile),
        "fused": fused.enabled() and fused.load(),
    }
    log(f"matmul peak ({dev}, {meta['threads']} threads) ...")
    meta["matmul_start"] = matmul_peak(dev, matmul_size)
    rows, skipped = [], []
    last: dict[tuple[str, str], dict] = {}
    modes = ("inference", "training") if training else ("inference",)
    for particles in sorted(int(n) for n in sizes):
        for name in models:
            for mode in modes:
                most = repeats or (20 if mode == "inference" else 10)
                count, reason = plan_measurement(
                    last.get((name, mode)), particles, warmup, most, max_seconds, limit
                )
                if reason is None:
                    try:
                        row = _measure(
                            name, mode, particles, dev, warmup, count, batch_size, radius, spacing, compile
                        )
                    except Exception as error:  # noqa: BLE001 - only out-of-memory is a skip
                        if not _out_of_memory(error):
                            raise
                        reason = f"out of memory: {str(error).splitlines()[0][:120]}"
                    finally:
                        _release(dev)
                if reason is not None:
                    skipped.append({"model": name, "mode": mode, "particles": particles, "reason": reason})
                    log(f"skip {name} {mode} {particles:,}: {reason}")
                    continue
                rows.append(row)
                last[(name, mode)] = row
                log(f"{name:<10} {mode:<9} {particles:>9,}  {row['ms_per_frame']:10.2f} ms/frame  "
                    f"({row['repeats']} repeats)")  # fmt: skip
    meta["matmul_end"] = matmul_peak(dev, matmul_size)
    meta["load_average_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    peak = max(meta["matmul_start"]["gflops_peak"], meta["matmul_end"]["gflops_peak"])
    meta["matmul_gflops_peak"] = peak
    for row in rows:
        row["peak_fraction"] = row["gflops"] / peak
    results = {"meta": meta, "rows": rows, "skipped": skipped}
    results["linearity"] = linearity(rows)
    return results


def _thread_pools() -> list[dict]:
    """Each native thread pool loaded in this process (library, API, threads), from threadpoolctl."""
    from threadpoolctl import threadpool_info

    keys = ("internal_api", "prefix", "num_threads", "version")
    return [{key: pool.get(key) for key in keys} for pool in threadpool_info()]


def device_name(device: torch.device) -> str:
    """The GPU's name, or the CPU's with its generation and matrix extensions (:func:`gnsx.core.machine.cpu_name`):
    a CPU timing depends on which kind of machine it ran on."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return cpu_name()


def _measure(
    name: str, mode: str, particles: int, device: torch.device, warmup: int, repeats: int, batch_size: int,
    radius: float, spacing: float, compile: bool = False,
) -> dict:  # fmt: skip
    """One row of :func:`run_scaling`."""
    history = MODELS[name].get("history", 1)
    if mode == "inference":
        sequence, particle_type, bounds = scaling_scene(particles, history, spacing)
        simulator = build_model(name, radius, bounds=bounds, compile=compile).to(device)
        result = measure_inference(simulator, sequence, particle_type, warmup=warmup, repeats=repeats)
        nodes, edges, per_frame, unit_ms = particles, result["num_edges"], 1, result["ms_per_frame"]
        flops = forward_flops(simulator.config, nodes, edges)["total"]
        parameters = simulator.num_parameters()
    else:
        batch, bounds = training_batch(particles, history, batch_size, spacing)
        system = build_system(name, bounds, radius, compile).to(device)
        result = measure_training(system, batch, warmup=warmup, repeats=repeats)
        nodes, edges, per_frame = result["num_nodes"], result["num_edges"], batch_size
        unit_ms = result["ms_per_step"]
        flops = training_flops(system.simulator.config, nodes, edges)
        parameters = system.simulator.num_parameters()
    seconds = unit_ms / 1000
    return {
        "model": name,
        "mode": mode,
        "particles": particles,
        "batch_size": per_frame,
        "edges": edges,
        "edges_per_particle": edges / nodes,
        "box_side": bounds[0][1] - bounds[0][0],
        "repeats": result["repeats"],
        "unit": "frame" if mode == "inference" else "step",
        "ms_per_unit": unit_ms,
        "ms_per_frame": unit_ms / per_frame,
        "particle_steps_per_s": nodes / seconds,
        "peak_memory_mb": result["peak_memory_mb"],
        "memory_measure": result["memory_measure"],
        "gflop_per_frame": flops / per_frame / 1e9,
        "gflops": flops / seconds / 1e9,
        "parameters": parameters,
    }


def linearity(rows: Sequence[dict], reference: int = REFERENCE_PARTICLES) -> dict[str, dict]:
    """Per ``"model/mode"``: the largest measured N against the size nearest ``reference`` (in log scale).

    ``ratio = ms(N_max) / (N_max / N_ref * ms(N_ref))``; also sets ``linear_ratio`` (the same against every
    N) on the rows. Series with one size have ratio None.
    """
    out = {}
    for key in dict.fromkeys((r["model"], r["mode"]) for r in rows):
        series = sorted((r for r in rows if (r["model"], r["mode"]) == key), key=lambda r: r["particles"])
        ref = min(series, key=lambda r: abs(math.log(r["particles"] / reference)))
        for r in series:
            r["linear_ratio"] = r["ms_per_frame"] / (r["particles"] / ref["particles"] * ref["ms_per_frame"])
        top = series[-1]
        out[f"{key[0]}/{key[1]}"] = {
            "reference_particles": ref["particles"],
            "max_particles": top["particles"],
            "ratio": top["linear_ratio"] if top is not ref else None,
        }
    return out


# -- output -----------------------------------------------------------------------------------------------
def format_scaling(results: dict) -> str:
    """The run as a markdown table, then the matmul peak, the linearity ratios and the skipped sizes."""
    meta = results["meta"]
    header = ["model", "mode", "particles", "edges/particle", "box side", "repeats", "ms/frame", "x linear",
              "M particle-steps/s", "peak MB", "GFLOP/frame", "GFLOP/s", "% matmul peak"]  # fmt: skip
    nan = float("nan")
    cells = []
    for r in results["rows"]:
        peak = "n/a" if r["peak_memory_mb"] is None else f"{r['peak_memory_mb']:,.0f}"
        mode = r["mode"] + (f" (batch {r['batch_size']})" if r["mode"] == "training" else "")
        cells.append([r["model"], mode, f"{r['particles']:,}", f"{r['edges_per_particle']:.2f}",
                      f"{r['box_side']:.2f}", str(r["repeats"]), f"{r['ms_per_frame']:,.2f}",
                      f"{r.get('linear_ratio', nan):.2f}", f"{r['particle_steps_per_s'] / 1e6:.3f}", peak,
                      f"{r['gflop_per_frame']:.3f}", f"{r['gflops']:.1f}",
                      f"{100 * r.get('peak_fraction', nan):.1f}%"])  # fmt: skip
    cuda = meta["device"].startswith("cuda")
    load = f"{_load(meta.get('load_average_start'))} at start, {_load(meta.get('load_average_end'))} at end"
    lines = [
        f"device {meta['device_name']} ({meta['device']}), {meta['threads']} torch threads, "
        f"torch {meta['torch']}; load average {load}"
        + ("; model.compile on (torch.compile)" if meta.get("compile") else "")
        + ("" if cuda else "; inference " + ("fused CPU kernels" if meta.get("fused_edge") else "eager")),
        "ms/frame: median after warm-up, graph build included; training: one optimizer step / batch size. "
        "x linear: ms/frame over N/N_ref x ms/frame at N_ref. Memory: "
        + ("CUDA max allocated" if cuda else "CPU peak-RSS increase (lower bound)"),
        markdown_table(header, cells),
    ]
    start, end = meta["matmul_start"], meta["matmul_end"]
    lines.append(
        f"fp32 matmul peak ({start['size']}^2, {start['threads']} threads): {start['gflops_peak']:.1f} "
        f"GFLOP/s at start, {end['gflops_peak']:.1f} at end "
        f"(medians {start['gflops_median']:.1f}, {end['gflops_median']:.1f})"
    )
    for key, lin in results["linearity"].items():
        ref, top = lin["reference_particles"], lin["max_particles"]
        if lin["ratio"] is None:
            lines.append(f"linearity {key}: n/a (the largest size, {top:,}, is the reference)")
        else:
            lines.append(f"linearity {key}: {lin['ratio']:.2f} ({top:,} vs {top / ref:.1f} x {ref:,})")
    for s in results["skipped"]:
        lines.append(f"skipped {s['model']} {s['mode']} {s['particles']:,}: {s['reason']}")
    memory = results.get("rollout_memory")
    if memory:
        lines.append(format_rollout_memory(memory))
    return "\n".join(lines)


def format_rollout_memory(memory: dict) -> str:
    """One paragraph on :func:`gnsx.perf.memtrack.rollout_memory`'s figures."""
    rows, growth = memory["rows"], memory["growth"]
    parts = ", ".join(
        f"{r['frames']} frames {r['peak_mb']:.2f} MB (output {r['output_mb']:.2f})" for r in rows
    )
    first = rows[0]
    return (
        f"rollout memory ({memory['model']}, {first['particles']:,} particles, {first['measure']}): "
        f"{parts}; peak growth {growth['peak_growth_mb']:.2f} MB against 2 x "
        f"{growth['output_growth_mb']:.2f} MB of trajectory: excess {growth['excess_mb']:+.2f} MB"
    )


def _load(values) -> str:
    return "n/a" if not values else "/".join(f"{v:.2f}" for v in values)


def plot_scaling(results: dict, path: str | Path) -> Path:
    """Log-log PNG of ms/frame against particles: every model and mode, each with its ideal linear line
    through its reference size (dotted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 5), dpi=120)
    colours = {"simplified": "tab:blue", "simplified_pairwise": "tab:green", "original": "tab:red"}
    for key, lin in results["linearity"].items():
        model, mode = key.split("/")
        series = sorted((r for r in results["rows"] if (r["model"], r["mode"]) == (model, mode)),
                        key=lambda r: r["particles"])  # fmt: skip
        x = np.array([r["particles"] for r in series], float)
        y = np.array([r["ms_per_frame"] for r in series])
        style = "-o" if mode == "inference" else "--s"
        colour = colours.get(model)
        ax.plot(x, y, style, color=colour, label=f"{model} {mode}")
        ref = next(r for r in series if r["particles"] == lin["reference_particles"])
        ideal = ref["ms_per_frame"] * x / ref["particles"]
        ax.plot(x, ideal, ":", color=colour, alpha=0.6, linewidth=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("particles per scene")
    ax.set_ylabel("ms per frame (training: per sample)")
    meta = results["meta"]
    ax.set_title(f"{meta['device_name'][:60]}, {meta['threads']} threads\n"
                 f"dotted: linear from {REFERENCE_PARTICLES:,}", fontsize=9)  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def default_json_path(device: str) -> Path:
    """``outputs/bench/scaling_<device type>.json``."""
    return Path("outputs/bench") / f"scaling_{torch.device(device).type}.json"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join(lines + ["| " + " | ".join(cells) + " |" for cells in rows])
