"""Inference ms/frame at WaterRamps size (2,300 particles, 1 thread): gnsx.evaluation.timing.measure_inference
against torch.utils.benchmark.Timer.blocked_autorange on the same untrained model, three times each, interleaved
(docs/decisions/layout-and-libraries.md)."""

import statistics

import torch
from torch.utils.benchmark import Timer

from gnsx.core.threads import apply_threads
from gnsx.data.waterramps import WATERRAMPS
from gnsx.evaluation.timing import measure_inference, packed_scene
from gnsx.model.registry import build_model

apply_threads(1)
for name in ("simplified", "original"):
    sim = build_model(name)
    seq, types = packed_scene(2300, WATERRAMPS["spacing"], WATERRAMPS["bounds"], sim.history)
    loop, timer = [], []
    for _ in range(3):
        loop.append(measure_inference(sim, seq, types, warmup=3, repeats=20)["ms_per_frame"])
        with torch.inference_mode():
            m = Timer(
                "sim.predict_positions(seq, types)",
                globals=dict(sim=sim, seq=seq, types=types),
                num_threads=torch.get_num_threads(),
            ).blocked_autorange(min_run_time=1.0)
        timer.append(1000 * m.median)
    print(
        f"{name}: gnsx loop median of 3 runs {statistics.median(loop):.1f} ms "
        f"(runs {', '.join(f'{v:.1f}' for v in loop)}); "
        f"Timer.blocked_autorange {statistics.median(timer):.1f} ms (runs {', '.join(f'{v:.1f}' for v in timer)})"
    )
