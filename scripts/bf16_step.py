"""One training step in fp32 and under bf16 autocast, interleaved in one process (docs/speed.md).

    .venv/bin/python scripts/bf16_step.py 2300 simplified_pairwise

A batch of two scenes of the scaling benchmark (``gnsx.perf.scaling.training_batch``, WaterRamps spacing), an
untrained model of ``gnsx.model.registry.MODELS``, Adam; two warm-up steps each, then ``rounds`` rounds of one
fp32 step and one bf16 step, 2 threads. Prints the median ms per step of each and their ratio. The step is
the simulator's noisy training pair and an MSE loss, as ``gnsx.perf.scaling.training_step`` without Lightning.
"""

from __future__ import annotations

import contextlib
import statistics
import sys
import time

import torch

from gnsx.model.training_targets import noisy_training_pair
from gnsx.perf.scaling import WATERRAMPS, build_system, training_batch


def main(num_particles: int, model: str, rounds: int = 8) -> None:
    torch.set_num_threads(2)
    batch, bounds = training_batch(num_particles, 1, 2, WATERRAMPS["spacing"])
    system = build_system(model, bounds)
    system.train()
    optimizer = torch.optim.Adam(system.parameters(), lr=1e-4)

    def step(bf16: bool) -> float:
        start = time.perf_counter()
        context = torch.autocast("cpu", dtype=torch.bfloat16) if bf16 else contextlib.nullcontext()
        optimizer.zero_grad(set_to_none=True)
        with context:
            predicted, target = noisy_training_pair(
                system.simulator,
                batch.position_sequence,
                batch.next_position,
                batch.particle_type,
                1e-4,
                batch=batch.batch,
            )
            loss = (predicted.float() - target).square().mean()
        loss.backward()
        optimizer.step()
        return time.perf_counter() - start

    for _ in range(2):
        step(False), step(True)
    times = {False: [], True: []}
    for _ in range(rounds):
        for bf16 in (False, True):
            times[bf16].append(step(bf16))
    fp32, bf16 = (1e3 * statistics.median(times[k]) for k in (False, True))
    print(f"{model} {num_particles} particles x 2: fp32 {fp32:.1f} ms, bf16 {bf16:.1f} ms per step "
          f"(medians of {rounds}); fp32/bf16 {fp32 / bf16:.2f}x")  # fmt: skip


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2300, sys.argv[2] if len(sys.argv) > 2 else "simplified")
