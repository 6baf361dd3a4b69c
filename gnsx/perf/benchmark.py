"""Speed benchmarks of the GNS family: scaling with the particle count, model comparisons at one size,
culling and freezing, as one CLI. Every timing is :func:`gnsx.evaluation.timing.measure_inference` (one frame:
neighbour search, graph, network and integration; its docstring says how memory is measured).


CLI (``make bench``): ``python -m gnsx.perf.benchmark`` runs the scaling benchmark (:mod:`gnsx.perf.scaling`): ms/frame,
memory, FLOP/s of inference and a training step of the models (:data:`DEFAULT_MODELS`) at 1k to 100k
particles (1M on a GPU), next to the matmul peak, with a table, JSON and a plot (``docs/benchmark.md``).
``--particles N`` times the same models (untrained weights: speed does not depend on them) on one packed scene
of N particles instead, one after the other, and prints them with the original / simplified ratio (the box
grows past WaterRamps' when the scene needs it).

Culling (``make bench-cull``): ``python -m gnsx.perf.benchmark --cull`` times frames with and without exact
culling (:mod:`gnsx.model.culling`), interleaved frame by frame in one run, on the scenes of
:data:`CULL_SCENES` at WaterRamps size and 10x, next to the fraction of work the culling plan keeps
(``--freeze-speed`` adds approximate freezing).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.threads import apply_threads
from gnsx.data.waterramps import WATERRAMPS
from gnsx.evaluation.timing import measure_inference, packed_scene
from gnsx.model import fused
from gnsx.model.culling import plan_culling
from gnsx.model.registry import DEFAULT_MODELS, MODELS, build_model  # noqa: F401 (re-exported for the CLI)
from gnsx.model.simulator import LearnedSimulator
from gnsx.perf.scaling import markdown_table
from gnsx.rules.freezing import Freezing


def compare_models(
    names: Sequence[str] = ("simplified", "original"),
    num_particles: int = WATERRAMPS["particles"],
    spacing: float = WATERRAMPS["spacing"],
    radius: float = WATERRAMPS["radius"],
    device: str = "cpu",
    warmup: int = 3,
    repeats: int = 20,
    compile: bool = False,
) -> dict[str, dict]:
    """:func:`measure_inference` of each named model on the same packed scene (history padded per model), in
    WaterRamps' box or, for more particles than it holds, a square box of side
    :func:`gnsx.perf.scaling.scaling_side`."""
    # WaterRamps' box, grown (side proportional to sqrt(N) * spacing) for scenes it cannot hold.
    from gnsx.perf.scaling import device_name, scaling_side

    side = scaling_side(num_particles, spacing)
    bounds = WATERRAMPS["bounds"] if side <= 0.8 else [[0.1, 0.1 + side]] * 2
    results = {}
    for name in names:
        simulator = build_model(name, radius, bounds=bounds, compile=compile).to(device)
        sequence, particle_type = packed_scene(num_particles, spacing, bounds, simulator.history)
        result = measure_inference(simulator, sequence, particle_type, warmup=warmup, repeats=repeats)
        results[name] = result | {"parameters": simulator.num_parameters(), "threads": torch.get_num_threads(),
                                  "device_name": device_name(torch.device(device))}  # fmt: skip
        del simulator
    return results


def format_results(results: dict[str, dict]) -> str:
    """A table of :func:`compare_models`' results, with original/simplified ratios when both are there."""
    width = max([12, *(len(name) for name in results)])
    header = f"{'params':>9} {'particles':>9} {'edges':>7} {'ms/frame':>9} {'peak MB':>8}  device"
    lines = [f"{'model':<{width}} {header}"]
    for name, r in results.items():
        peak = "n/a" if r["peak_memory_mb"] is None else f"{r['peak_memory_mb']:.1f}"
        lines.append(
            f"{name:<{width}} {r['parameters']:>9} {r['num_particles']:>9} {r['num_edges']:>7} "
            f"{r['ms_per_frame']:>9.2f} {peak:>8}  {r['device']} ({r['memory_measure']})"
        )
    first = next(iter(results.values()), {})
    if first.get("device_name"):
        lines.append(f"on {first['device_name']}, {first.get('threads', '?')} torch threads")
    if {"simplified", "original"} <= set(results):
        s, o = results["simplified"], results["original"]
        line = f"original / simplified: {o['ms_per_frame'] / s['ms_per_frame']:.2f}x time"
        if s["peak_memory_mb"] and o["peak_memory_mb"] is not None:
            line += f", {o['peak_memory_mb'] / s['peak_memory_mb']:.2f}x memory"
        lines.append(line + "  (paper, GTX 1080 Ti: 2.3x time, 3.3x memory)")
    return "\n".join(lines)


# -- culling: scenes where leaving work out pays -------------------------------------------------------------
#: The culling benchmark's scenes (:func:`cull_scene`), and what each is for.
CULL_SCENES = {
    "packed": "packed_scene: water at rest, 6% static ramp rows (the bench default; little to cull)",
    "long_ramps": "a falling block above six long, thick static ramps crossing the box",
    "container": "sloshing water in a container with thick static walls, taller than the water",
    "static_floor": "a water block on a thick static floor spanning the box",
    "resting_pool": "a pool at rest filling the bottom, a small block falling in (no static particle)",
}


def _lattice(lower: Sequence[float], upper: Sequence[float], spacing: float) -> np.ndarray:
    """``[K, 2]`` points of a square lattice of ``spacing`` filling ``[lower, upper)`` (data units)."""
    axes = [np.arange(lo, hi - 1e-9, spacing) for lo, hi in zip(lower, upper)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)


def cull_scene(
    name: str, scale: float = 1.0, history: int = 1, spacing: float = WATERRAMPS["spacing"], seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, list[list[float]]]:
    """One scene of :data:`CULL_SCENES` at ``scale`` times WaterRamps' size (~2,300 particles at 1).

    Every length is a fraction of the box side ``L = 0.8 sqrt(scale)`` (walls at 0.1 and 0.1 + L), thicknesses
    included, at a fixed particle spacing: particle counts grow with ``scale`` and the static share stays.
    Water is a lattice jittered by up to 0.3 spacing; static particles sit on an exact lattice. The history
    frames move the water at a constant per-frame velocity (falling or sloshing; 0 at rest).

    Returns:
        ``position_sequence [N, H + 1, 2]`` float32 (oldest first), ``particle_type [N]`` int64 (water, then
        static) and the box ``bounds [[lo, hi], [lo, hi]]``.
    """
    if name == "packed":
        count = int(round(WATERRAMPS["particles"] * scale))
        bounds = [[0.1, 0.1 + 0.8 * math.sqrt(scale)]] * 2
        sequence, particle_type = packed_scene(count, spacing, bounds, history, seed=seed)
        return sequence, particle_type, bounds
    side = 0.8 * math.sqrt(scale)
    lo = 0.1

    def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        return _lattice((lo + x0 * side, lo + y0 * side), (lo + x1 * side, lo + y1 * side), spacing)

    rest, fall, slosh = np.zeros(2), np.array([0.0, -2e-3]), np.array([1.5e-3, 0.0])
    static = [np.zeros((0, 2))]
    if name == "long_ramps":
        water, velocity = [box(0.05, 0.62, 0.4, 0.97)], [fall]
        thickness = 0.027  # 3 rows at 1x
        for k in range(6):  # alternating slopes, stacked down the box
            y = 0.08 + 0.085 * k
            x0, x1 = (0.1, 0.9) if k % 2 else (0.0, 0.8)
            ramp = box(x0, y, x1, y + thickness)
            slope = 0.05 * (1 if k % 2 else -1)
            ramp[:, 1] += slope * (ramp[:, 0] - lo) / 0.8
            static.append(ramp)
    elif name == "container":
        water, velocity = [box(0.1, 0.1, 0.9, 0.32)], [slosh]
        wall = 0.045
        static += [box(0.1 - wall, 0.1 - wall, 0.9 + wall, 0.1), box(0.1 - wall, 0.1, 0.1, 0.85),
                   box(0.9, 0.1, 0.9 + wall, 0.85)]  # fmt: skip
    elif name == "static_floor":
        water, velocity = [box(0.3, 0.2, 0.65, 0.5)], [fall]
        static.append(box(0.0, 0.0, 1.0, 0.18))
    elif name == "resting_pool":
        water, velocity = [box(0.0, 0.0, 1.0, 0.27), box(0.45, 0.5, 0.55, 0.6)], [rest, fall]
    else:
        raise KeyError(f"unknown scene {name!r}; known: {sorted(CULL_SCENES)}")
    rng = np.random.default_rng(seed)
    water = [block + rng.uniform(-0.3 * spacing, 0.3 * spacing, block.shape) for block in water]
    velocities = np.concatenate([np.broadcast_to(v, block.shape) for block, v in zip(water, velocity)])
    static_position = np.concatenate(static)
    position = np.concatenate([*water, static_position])
    velocities = np.concatenate([velocities, np.zeros_like(static_position)])
    from gnsx.evaluation.scene_rollout import constant_velocity_history

    sequence = constant_velocity_history(position, velocities, 1.0, history).swapaxes(0, 1)  # [N, H + 1, 2]
    particle_type = np.concatenate(
        [np.full(len(velocities) - len(static_position), WATER_PARTICLE_ID),
         np.full(len(static_position), KINEMATIC_PARTICLE_ID)]
    ).astype(np.int64)  # fmt: skip
    return (
        torch.from_numpy(np.ascontiguousarray(sequence)),
        torch.from_numpy(particle_type),
        [[lo, lo + side]] * 2,
    )


@torch.inference_mode()
def measure_culling(
    simulator: LearnedSimulator,
    position_sequence: torch.Tensor,
    particle_type: torch.Tensor,
    warmup: int = 2,
    repeats: int = 7,
    freeze_speed: float | None = None,
) -> dict:
    """ms/frame of :meth:`LearnedSimulator.predict_positions` with and without culling, interleaved.

    Each repeat times one frame with culling, one without (and one with freezing,
    :class:`gnsx.rules.freezing.Freezing`, when ``freeze_speed`` is given), in turn, so that load from other
    processes hits all modes alike; medians over the repeats. The simulator's culling switch is restored.

    Returns:
        ``particles``, ``static_share``, ``edges`` (full graph), the culling plan's kept fractions
        (``edges_kept``: edges of the culled graph over E; ``node_updates_kept`` and ``edge_updates_kept``:
        MLP evaluations over the M steps, see :meth:`gnsx.model.culling.CullPlan.work`; computed on the full
        graph), ``ms_cull``, ``ms_full``, ``ratio`` (full / cull), and with freezing ``ms_freeze``,
        ``ratio_freeze`` (full / freeze) and ``frozen_share`` (of the dynamic particles).
    """
    device = simulator.acc_std.device
    position_sequence, particle_type = position_sequence.to(device), particle_type.to(device)
    dynamic = particle_type != KINEMATIC_PARTICLE_ID
    _, edge_index, _ = simulator.build_graph(position_sequence, particle_type)
    work = plan_culling(edge_index, dynamic, simulator.hops).work()
    switch = simulator.cull
    freezing = None if freeze_speed is None else Freezing(simulator, freeze_speed)
    # Each mode: culling on or off, and the step it times.
    modes = {"cull": (True, simulator.predict_positions), "full": (False, simulator.predict_positions)}
    if freezing is not None:
        modes["freeze"] = (True, freezing.predict_positions)
    times: dict[str, list[float]] = {mode: [] for mode in modes}
    try:
        for repeat in range(warmup + repeats):
            for mode, (cull, predict) in modes.items():
                simulator.cull = cull
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                start = time.perf_counter()
                predict(position_sequence, particle_type)
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                if repeat >= warmup:
                    times[mode].append(1000 * (time.perf_counter() - start))
        frozen = None if freezing is None else freezing.frozen_particles(position_sequence, particle_type)
    finally:
        simulator.cull = switch
    ms = {mode: statistics.median(values) for mode, values in times.items()}
    result = {
        "particles": int(len(particle_type)),
        "static_share": float((~dynamic).float().mean()),
        "edges": int(edge_index.shape[1]),
        "edges_kept": work["edges"],
        "node_updates_kept": work["node_updates"],
        "edge_updates_kept": work["edge_updates"],
        "ms_cull": ms["cull"],
        "ms_full": ms["full"],
        "ratio": ms["full"] / ms["cull"],
        "repeats": int(repeats),
        "device": str(device),
    }
    if frozen is not None:
        result |= {
            "ms_freeze": ms["freeze"],
            "ratio_freeze": ms["full"] / ms["freeze"],
            "frozen_share": float(frozen.float().sum() / max(1, int(dynamic.sum()))),
        }
    return result


def compare_culling(
    models: Sequence[str] = ("simplified",),
    scenes: Sequence[str] = tuple(CULL_SCENES),
    scales: Sequence[float] = (1.0, 10.0),
    device: str = "cpu",
    warmup: int = 2,
    repeats: int = 7,
    freeze_speed: float | None = None,
) -> list[dict]:
    """:func:`measure_culling` of every model on every scene at every scale (the model's box fits the
    scene's). Rows carry ``model``, ``scene`` and ``scale``."""
    rows = []
    for name in models:
        for scale in scales:
            for scene in scenes:
                history = MODELS[name].get("history", 1)
                sequence, particle_type, bounds = cull_scene(scene, scale, history)
                simulator = build_model(name, bounds=bounds).to(device)
                result = measure_culling(simulator, sequence, particle_type, warmup, repeats, freeze_speed)
                rows.append({"model": name, "scene": scene, "scale": scale} | result)
    return rows


def format_culling(rows: Sequence[dict]) -> str:
    """A markdown table of :func:`compare_culling`'s rows."""
    freeze = any("ms_freeze" in r for r in rows)
    header = ["model", "scene", "size", "particles", "static", "edges kept", "node updates kept", "ms cull",
              "ms full", "full / cull"]  # fmt: skip
    if freeze:
        header += ["frozen", "ms freeze", "full / freeze"]
    table = []
    for r in rows:
        cells = [r["model"], r["scene"], f"{r['scale']:g}x", f"{r['particles']:,}",
                 f"{r['static_share']:.0%}", f"{r['edges_kept']:.0%} of {r['edges']:,}",
                 f"{r['node_updates_kept']:.0%}",
                 f"{r['ms_cull']:.1f}", f"{r['ms_full']:.1f}", f"{r['ratio']:.2f}x"]  # fmt: skip
        if freeze:
            cells += (
                [f"{r['frozen_share']:.0%}", f"{r['ms_freeze']:.1f}", f"{r['ratio_freeze']:.2f}x"]
                if "ms_freeze" in r
                else ["", "", ""]
            )
        table.append(cells)
    return markdown_table(header, table)


# -- approximate freezing: its error against the exact path --------------------------------------------------
#: The freezing check's own scene (small preset's box, metres and m/s): a pool at rest over the whole floor
#: and a block falling into its middle, so that most water is at rest and far from the motion for a while.
FREEZE_POOL = {
    "blocks": [{"lower": [0.1, 0.1], "upper": [0.9, 0.3], "velocity": [0.0, 0.0]},
               {"lower": [0.45, 0.6], "upper": [0.55, 0.7], "velocity": [0.0, -1.0]}],
    "ramps": [],
}  # fmt: skip
#: Frames predicted for a case without ground truth (the small preset's 250 frames less 2 given).
FREEZE_STEPS = 248


@torch.inference_mode()
def freeze_check(
    simulator: LearnedSimulator,
    cases: Sequence[tuple[str, torch.Tensor, torch.Tensor, torch.Tensor | None]],
    freeze_speed: float,
    steps: int | None = None,
    emd_every: int = 10,
) -> list[dict]:
    """Rollouts with approximate freezing against the exact path (culling on in both), case by case.

    Args:
        cases: ``(name, initial [N, H + 1, D], particle_type [N], truth [T, N, D] or None)``; truth frames
            start after the initial ones.
        freeze_speed: the frozen rollout's speed at rest (:class:`gnsx.rules.freezing.Freezing`, data units
            per frame).
        steps: frames to predict (default: the truth's length, else :data:`FREEZE_STEPS`).
    Returns:
        one row per case: ``particles``, ``frames``, ``mse_vs_exact`` (position MSE per coordinate of the
        frozen rollout against the exact one, dynamic particles, every frame), ``emd_vs_exact`` (mean Earth
        Mover's distance between their dynamic particles every ``emd_every`` frames), ``frozen_share``
        (frozen dynamic particles, mean over the same frames), ``ms_exact``, ``ms_freeze`` (median ms/frame
        of one model step, :meth:`~LearnedSimulator.predict_positions` or the frozen one, on the frozen
        rollout's inputs at those frames, the two modes interleaved frame by frame; the boundary of the
        rollout is not timed), ``ratio`` and, with truth, ``rollout_mse_exact`` and ``rollout_mse_freeze``
        (against it). The model is not changed.
    """
    from gnsx.evaluation.metrics import earth_movers_distance, position_mse
    from gnsx.model.rollout import rollout

    freezing = Freezing(simulator, freeze_speed)
    # The model's step of each mode.
    modes = {"exact": simulator.predict_positions, "freeze": freezing.predict_positions}
    rows = []
    for name, initial, particle_type, truth in cases:
        num_steps = steps or (len(truth) if truth is not None else FREEZE_STEPS)
        dynamic = particle_type != KINEMATIC_PARTICLE_ID
        rollouts = {
            mode: rollout(simulator, initial, particle_type, num_steps, predict=predict)
            for mode, predict in modes.items()
        }
        frozen, exact = rollouts["freeze"], rollouts["exact"]
        every = list(range(emd_every - 1, num_steps, emd_every)) or [num_steps - 1]
        frames = torch.cat([initial.transpose(0, 1), frozen])  # [H + 1 + T, N, D]
        size = initial.shape[1]
        windows = [frames[t + 1 : t + 1 + size].transpose(0, 1) for t in every]  # inputs of frame t + 1
        held = [freezing.frozen_particles(window, particle_type) for window in windows]
        # Speed: one frame of each mode in turn on the frozen rollout's own states (so other load hits
        # both alike), the median per mode.
        times: dict[str, list[float]] = {mode: [] for mode in modes}
        for window in windows:
            for mode, predict in modes.items():
                start = time.perf_counter()
                predict(window, particle_type)
                times[mode].append(1000 * (time.perf_counter() - start))
        ms = {mode: statistics.median(values) for mode, values in times.items()}
        row = {
            "case": name,
            "particles": int(len(particle_type)),
            "frames": int(num_steps),
            "mse_vs_exact": position_mse(frozen, exact, dynamic),
            "emd_vs_exact": float(np.mean([
                earth_movers_distance(frozen[t, dynamic], exact[t, dynamic], method="auto") for t in every
            ])),
            "frozen_share": float(torch.stack(held)[:, dynamic].float().mean()),
            "ms_exact": ms["exact"],
            "ms_freeze": ms["freeze"],
            "ratio": ms["exact"] / ms["freeze"],
        }  # fmt: skip
        if truth is not None:
            truth = truth[:num_steps]
            row["rollout_mse_exact"] = position_mse(exact, truth, dynamic)
            row["rollout_mse_freeze"] = position_mse(frozen, truth, dynamic)
        rows.append(row)
    return rows


def freeze_cases(data: str | Path, trajectories: int, history: int, split: str = "test") -> list[tuple]:
    """The freezing check's cases: the first ``trajectories`` of a dataset split and :data:`FREEZE_POOL`
    simulated with the small preset's MPM solver (~1 min), each with its ground truth, the model starting
    from the truth's first ``history + 1`` frames."""
    from gnsx.data.store import SplitReader
    from gnsx.mpm.generate import simulate_scene
    from gnsx.mpm.presets import get_preset
    from gnsx.mpm.scenes import Scene

    frames = history + 1
    positions = []
    reader = SplitReader(data, split)
    for i in range(min(trajectories, len(reader))):
        trajectory = reader[i]
        positions.append((f"{split} {i}", np.array(trajectory.position), np.array(trajectory.particle_type)))
    pool = simulate_scene(Scene.from_dict(FREEZE_POOL), get_preset("small"), seed=0)
    positions.append(("pool", pool.position, pool.particle_type))
    cases = []
    for name, position, particle_type in positions:
        position = torch.from_numpy(np.ascontiguousarray(position))
        initial = position[:frames].transpose(0, 1)  # [N, H + 1, D]
        cases.append((name, initial, torch.from_numpy(np.asarray(particle_type)), position[frames:]))
    return cases


def format_freeze(rows: Sequence[dict]) -> str:
    """A markdown table of :func:`freeze_check`'s rows."""
    header = ["case", "particles", "frames", "frozen", "MSE vs exact", "EMD vs exact", "rollout MSE exact",
              "rollout MSE freeze", "ms exact", "ms freeze", "exact / freeze"]  # fmt: skip
    cells = []
    for r in rows:
        truth = [f"{r[k]:.2e}" if k in r else "n/a" for k in ("rollout_mse_exact", "rollout_mse_freeze")]
        cells.append([r["case"], f"{r['particles']:,}", str(r["frames"]), f"{r['frozen_share']:.0%}",
                      f"{r['mse_vs_exact']:.2e}", f"{r['emd_vs_exact']:.2e}", *truth, f"{r['ms_exact']:.1f}",
                      f"{r['ms_freeze']:.1f}", f"{r['ratio']:.2f}x"])  # fmt: skip
    return markdown_table(header, cells)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.perf.benchmark",
        description="Scaling benchmark (default, make bench): ms/frame, memory and GFLOP/s of inference "
        "and training of the simplified GNS, gnsx's default (simplified_pairwise) and the original GNS "
        "from 1k to 100k particles (1M on a GPU), with the "
        "matmul peak, a table, JSON and a plot. --particles N: the same models on one packed scene of N "
        "particles. --cull: ms/frame with and without exact culling on scenes where it pays "
        "(make bench-cull).",
    )
    parser.add_argument("--models", nargs="+", default=None, choices=sorted(MODELS),
                        help="default: the three models (--cull: simplified)")  # fmt: skip
    parser.add_argument(
        "--particles",
        type=int,
        default=None,
        help="one size, the default models, packed scene with ramps (former default: 2300)",
    )
    parser.add_argument("--spacing", type=float, default=WATERRAMPS["spacing"])
    parser.add_argument("--radius", type=float, default=WATERRAMPS["radius"])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument(
        "--warmup", type=int, default=None, help="untimed frames (default 2; 3 with --particles)"
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed frames (default 20; scaling: at most 20 inference / 10 training, "
        "fewer at large sizes; 7 per mode with --cull)",
    )
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument(
        "--compile",
        action="store_true",
        help="model.compile on (torch.compile of the network's blocks; warm-up includes compiling)",
    )
    parser.add_argument(
        "--no-fused",
        action="store_true",
        help="the eager edge block instead of the fused kernel (gnsx.model.fused; GNSX_FUSED_EDGE=0)",
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="write the results here (scaling: outputs/bench/scaling_<device>.json)",
    )
    scaling = parser.add_argument_group("scaling (the default mode; docs/benchmark.md)")
    scaling.add_argument(
        "--sizes",
        nargs="+",
        type=int,
        default=None,
        help="particles per scene (default 1000 2300 10000 100000; 1000000 on cuda)",
    )
    scaling.add_argument(
        "--max-seconds",
        type=float,
        default=60.0,
        help="time budget per measurement; a size predicted past it is skipped",
    )
    scaling.add_argument(
        "--max-memory-gb",
        type=float,
        default=None,
        help="memory budget per measurement (default: half the CPU's available "
        "memory, or 85%% of the GPU's free memory)",
    )
    scaling.add_argument("--batch-size", type=int, default=2, help="scenes per training step (trainer: 2)")
    scaling.add_argument("--no-training", action="store_true", help="inference only")
    scaling.add_argument("--plot", type=Path, default=None, help="PNG (default: the JSON's path, .png)")
    scaling.add_argument("--matmul-size", type=int, default=None, help="matmul peak's n (2048 CPU, 8192 GPU)")
    scaling.add_argument(
        "--rollout-memory",
        action="store_true",
        help="also measure a rollout's peak memory at --rollout-frames",
    )
    scaling.add_argument("--rollout-frames", nargs="+", type=int, default=[50, 500])
    scaling.add_argument("--rollout-particles", type=int, default=1000)
    cull = parser.add_argument_group("culling (--cull)")
    cull.add_argument("--cull", action="store_true", help="time culling on/off (interleaved) per scene")
    cull.add_argument("--scenes", nargs="+", default=list(CULL_SCENES), choices=list(CULL_SCENES))
    cull.add_argument("--scales", nargs="+", type=float, default=[1.0, 10.0],
                      help="sizes in multiples of WaterRamps' ~2,300 particles (default 1 10)")  # fmt: skip
    cull.add_argument("--freeze-speed", type=float, default=None,
                      help="also time approximate freezing at this speed (data units per frame)")  # fmt: skip
    freeze = parser.add_argument_group("freezing error (--freeze-check, needs --freeze-speed)")
    freeze.add_argument("--freeze-check", action="store_true",
                        help="rollouts with freezing against the exact path: error and speed")  # fmt: skip
    freeze.add_argument("--checkpoint", default="pretrained/small/model.ckpt")
    freeze.add_argument("--data", default="data/small", help="dataset whose test split is rolled out")
    freeze.add_argument("--trajectories", type=int, default=16)
    args = parser.parse_args(argv)
    apply_threads(args.threads or None)
    if args.no_fused:
        os.environ[fused.ENV] = "0"
    if args.freeze_check:
        if args.freeze_speed is None:
            parser.error("--freeze-check needs --freeze-speed")
        from gnsx.model.checkpoint import load_simulator

        simulator = load_simulator(args.checkpoint, args.device)
        cases = freeze_cases(args.data, args.trajectories, simulator.history)
        results = freeze_check(simulator, cases, args.freeze_speed)
        print(f"freeze_speed {args.freeze_speed:g} (data units per frame), {args.checkpoint}")
        print(format_freeze(results))
    elif args.cull:
        results = compare_culling(
            args.models or ["simplified"], args.scenes, args.scales, args.device,
            2 if args.warmup is None else args.warmup, 7 if args.repeats is None else args.repeats,
            args.freeze_speed,
        )  # fmt: skip
        threads = torch.get_num_threads()
        print(f"ms/frame: median of interleaved frames, graph build included; {threads} torch threads")
        print(format_culling(results))
    elif args.particles is not None:
        results = compare_models(
            args.models or list(DEFAULT_MODELS), args.particles, args.spacing, args.radius, args.device,
            3 if args.warmup is None else args.warmup, 20 if args.repeats is None else args.repeats,
            compile=args.compile,
        )  # fmt: skip
        print(format_results(results))
    else:
        return _scaling_main(args, parser)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


def _scaling_main(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The scaling mode of :func:`main` (:mod:`gnsx.perf.scaling`)."""
    from gnsx.perf import scaling

    device = torch.device(args.device)
    extra = scaling.CUDA_EXTRA_SIZES if device.type == "cuda" else ()
    sizes = args.sizes or [*scaling.DEFAULT_SIZES, *extra]
    checks = [("--sizes", sizes, 1), ("--batch-size", [args.batch_size], 1),
              ("--rollout-frames", args.rollout_frames, 1),
              ("--rollout-particles", [args.rollout_particles], 1),
              ("--repeats", [args.repeats or 1], 1), ("--warmup", [args.warmup or 0], 0)]  # fmt: skip
    for flag, values, low in checks:
        if min(values) < low:
            raise ValueError(f"{flag}: must be >= {low}, got {min(values)}")
    json_path = args.json or scaling.default_json_path(args.device)
    results = scaling.run_scaling(
        args.models or list(DEFAULT_MODELS), sizes, args.device,
        2 if args.warmup is None else args.warmup, args.repeats, args.max_seconds,
        None if args.max_memory_gb is None else 1000 * args.max_memory_gb, args.batch_size,
        not args.no_training, args.radius, args.spacing, args.matmul_size,
        log=lambda line: print(line, file=sys.stderr, flush=True), compile=args.compile,
    )  # fmt: skip
    if args.rollout_memory:
        from gnsx.perf.memtrack import hold_still, rollout_growth, rollout_memory

        name = (args.models or ["simplified"])[0]
        history = MODELS[name].get("history", 1)
        sequence, particle_type, bounds = scaling.scaling_scene(args.rollout_particles, history, args.spacing)
        simulator = hold_still(build_model(name, args.radius, bounds=bounds)).to(args.device)
        rows = rollout_memory(simulator, sequence, particle_type, args.rollout_frames)
        results["rollout_memory"] = {"model": name, "rows": rows, "growth": rollout_growth(rows)}
    print(scaling.format_scaling(results))
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(results, indent=2))
    plot = scaling.plot_scaling(results, args.plot or json_path.with_suffix(".png"))
    print(f"wrote {json_path} and {plot}")
    return 0


if __name__ == "__main__":
    from gnsx.core.cli import run_main

    sys.exit(run_main(main, user_errors=(ValueError,)))
