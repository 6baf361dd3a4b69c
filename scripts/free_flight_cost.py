"""What free flight costs per rollout frame: the shipped weights' rollouts with and without it, interleaved.

    .venv/bin/python scripts/free_flight_cost.py 2300 400

For each particle count: a block of the scaling benchmark's scene (``gnsx.perf.scaling.scaling_scene``, inside the
shipped model's box), seven rounds of a 20-frame rollout with every rule and with all but free flight,
alternating, 2 threads; prints the median ms per frame and the range of each.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time

import torch

from gnsx.core.allocator import retain_freed_memory
from gnsx.model.checkpoint import load_simulator
from gnsx.perf.scaling import scaling_scene
from gnsx.rules.rollout import rollout_with_rules
from gnsx.rules.rules import Rules


def main(sizes: list[int], rounds: int = 7, frames: int = 20) -> None:
    torch.set_num_threads(2)
    retain_freed_memory()
    simulator = load_simulator("pretrained/small/model.ckpt").eval()
    for n in sizes:
        sequence, particle_type, _ = scaling_scene(n, simulator.history, 0.0156)
        times: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(rounds):
            for free_flight in (True, False):
                start = time.perf_counter()
                rollout_with_rules(
                    simulator,
                    sequence,
                    particle_type,
                    frames,
                    dataclasses.replace(Rules.production(), free_flight=free_flight),
                )
                times[free_flight].append(1000 * (time.perf_counter() - start) / frames)
        for free_flight, values in times.items():
            median = statistics.median(values)
            print(f"{n} particles, free_flight={free_flight}: median {median:.1f} ms/frame "
                  f"(range {min(values):.1f}-{max(values):.1f})")  # fmt: skip


if __name__ == "__main__":
    main([int(arg) for arg in sys.argv[1:]] or [2300, 400])
