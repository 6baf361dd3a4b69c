"""Inference speed and memory of a learned simulator, measured one way everywhere (evaluation, sweeps, CLI).

One *frame* is one call of :meth:`LearnedSimulator.predict_positions`: neighbour search and graph build,
features, the graph network and the integration, exactly what a rollout repeats per frame. Timings are the
median over ``repeats`` frames after ``warmup`` frames (first calls pay for allocator growth, kernel choice
and lazy initialisation).

Memory:

* CUDA: ``torch.cuda.max_memory_allocated`` over the measured frames, after
  ``torch.cuda.reset_peak_memory_stats`` (everything PyTorch holds on the GPU at the peak: weights, inputs,
  graph, activations), in MB (10^6 bytes). This is the figure comparable to the paper's 142 MB vs 468 MB.
* CPU (Linux): the increase of the process's peak resident set size (``VmHWM``, reset by writing ``5`` to
  ``/proc/self/clear_refs``) over its resident size just before the first warm-up frame: the working memory
  of a frame (graph and activations), weights and inputs excluded. glibc's ``malloc_trim`` first returns
  freed heap to the OS so that earlier work does not hide the increase; memory the allocator still keeps is
  reused without showing up, so read it as a lower bound. Elsewhere ``peak_memory_mb`` is None.
"""

from __future__ import annotations

import ctypes
import math
import statistics
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.model.simulator import LearnedSimulator

_MB = 1e6


def _proc_status_kb(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak_rss() -> bool:
    """Give freed heap back to the OS, then reset VmHWM to the current RSS; False where impossible."""
    try:
        # Without the trim, memory freed by earlier work (another model's rollout) stays resident and is
        # reused silently, and the peak increase reads as ~0.
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return _proc_status_kb("VmHWM") is not None


def memory_start(device: torch.device) -> tuple[str, int | None]:
    """Start a peak-memory measurement (module docstring): ``(measure, rss_before)``, measure one of
    ``"cuda_max_allocated"``, ``"cpu_peak_rss_increase"``, ``"unavailable"``."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)
        return "cuda_max_allocated", None
    rss = _proc_status_kb("VmRSS") if _reset_peak_rss() else None
    return ("cpu_peak_rss_increase", rss) if rss is not None else ("unavailable", None)


def memory_peak(device: torch.device, measure: str, rss_before: int | None) -> float | None:
    """The peak since :func:`memory_start`, MB (None where it cannot be measured)."""
    if measure == "cuda_max_allocated":
        return torch.cuda.max_memory_allocated(device) / _MB
    if measure == "cpu_peak_rss_increase":
        return max(0, _proc_status_kb("VmHWM") - rss_before) * 1024 / _MB
    return None


@torch.inference_mode()
def measure_inference(
    simulator: LearnedSimulator,
    position_sequence: torch.Tensor,
    particle_type: torch.Tensor,
    warmup: int = 3,
    repeats: int = 20,
) -> dict:
    """Time one-frame predictions (graph build included) and measure their peak memory.

    The same input is predicted ``warmup + repeats`` times on the simulator's device (inputs are moved there);
    the simulator's mode is left as it is.

    Args:
        simulator: the model (on the device to measure).
        position_sequence: ``[N, history + 1, D]`` positions, oldest first (data units).
        particle_type: ``[N]`` int64.
        warmup: untimed frames first.
        repeats: timed frames (at least 1).
    Returns:
        ``ms_per_frame`` (median, milliseconds), ``ms_per_frame_min``, ``peak_memory_mb`` (see the module
        docstring; None where it cannot be measured), ``memory_measure`` (``"cuda_max_allocated"``,
        ``"cpu_peak_rss_increase"`` or ``"unavailable"``), ``num_particles``, ``num_edges``, ``device``,
        ``repeats``.
    """
    if repeats < 1:
        raise ValueError(f"measure_inference: repeats must be >= 1, got {repeats}")
    device = simulator.acc_std.device
    position_sequence = position_sequence.to(device)
    particle_type = particle_type.to(device)
    cuda = device.type == "cuda"

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize(device)

    measure, rss_before = memory_start(device)
    for _ in range(warmup):
        simulator.predict_positions(position_sequence, particle_type)
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        simulator.predict_positions(position_sequence, particle_type)
        sync()
        times.append(time.perf_counter() - start)
    peak = memory_peak(device, measure, rss_before)
    # Edge count (after the measurement, so it does not warm the allocator): what the network works on.
    num_edges = int(simulator.build_graph(position_sequence, particle_type)[1].shape[1])
    return {
        "ms_per_frame": 1000 * statistics.median(times),
        "ms_per_frame_min": 1000 * min(times),
        "peak_memory_mb": peak,
        "memory_measure": measure,
        "num_particles": int(position_sequence.shape[0]),
        "num_edges": num_edges,
        "device": str(device),
        "repeats": int(repeats),
    }


def packed_scene(
    num_particles: int,
    spacing: float,
    bounds: Sequence[Sequence[float]],
    history: int,
    seed: int = 0,
    ramp_fraction: float = 0.06,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A block of water at rest plus a few static ramp particles: a fixed-size scene to time any model on.

    The water is a jittered square lattice (offsets up to 0.3 spacing per axis, like the generator's
    particles) resting on the lower wall in the left corner; ``ramp_fraction`` of the particles (WaterRamps
    has ~6% ramp particles) form horizontal rows of static particles ``spacing`` apart, three spacings above
    the water. Every history frame is the same (the water is at rest).

    Args:
        num_particles: N, water and ramp particles together.
        spacing: particle spacing (data units); with the model's radius R, neighbours per particle grow as
            ``(R / spacing)^2`` (WaterRamps: 0.009 at R = 0.015; gnsx's small preset: R / 2.25).
        bounds: ``[2][2]`` domain walls ``[lower, upper]`` per dimension (2D only).
        history: H; the scene has ``H + 1`` frames.
        seed: jitter seed.
    Returns:
        ``position_sequence [N, H + 1, 2]`` float32 (oldest first) and ``particle_type [N]`` int64
        (water first, then ramps).
    Raises:
        ValueError: the particles do not fit in the bounds at this spacing.
    """
    bounds = np.asarray(bounds, np.float64)
    if bounds.shape != (2, 2):
        raise ValueError(f"packed_scene: bounds must be [2][2] (2D), got shape {bounds.shape}")
    if num_particles < 1 or not spacing > 0:
        raise ValueError(
            f"packed_scene: need num_particles >= 1 and spacing > 0, got {num_particles}, {spacing}"
        )
    num_ramp = int(round(ramp_fraction * num_particles)) if num_particles > 10 else 0
    num_water = num_particles - num_ramp
    lo, size = bounds[:, 0] + spacing, bounds[:, 1] - bounds[:, 0] - 2 * spacing
    per_row = int(size[0] // spacing) + 1
    columns = min(per_row, math.ceil(math.sqrt(num_water)))
    rows = math.ceil(num_water / columns)
    ramp_rows = math.ceil(num_ramp / per_row) if num_ramp else 0
    height = (rows - 1 + (3 * ramp_rows)) * spacing
    if height > size[1]:
        raise ValueError(
            f"packed_scene: {num_particles} particles at spacing {spacing} do not fit in bounds "
            f"{bounds.tolist()}"
        )
    rng = np.random.default_rng(seed)
    index = np.arange(num_water)
    water = lo + spacing * np.stack([index % columns, index // columns], axis=1)
    water = water + rng.uniform(-0.3 * spacing, 0.3 * spacing, water.shape)
    index = np.arange(num_ramp)
    ramp_y = lo[1] + (rows - 1) * spacing + 3 * spacing * (1 + index // per_row)
    ramps = np.stack([lo[0] + spacing * (index % per_row), ramp_y], axis=1)
    position = np.concatenate([water, ramps]).astype(np.float32)
    particle_type = np.concatenate(
        [np.full(num_water, WATER_PARTICLE_ID), np.full(num_ramp, KINEMATIC_PARTICLE_ID)]
    ).astype(np.int64)
    sequence = np.repeat(position[:, None], history + 1, axis=1)
    return torch.from_numpy(sequence), torch.from_numpy(particle_type)
