"""What a rollout needs, memory against frame count (:func:`rollout_memory`, :func:`rollout_growth`), counted
exactly with :class:`gnsx.evaluation.tensor_memory.TensorMemoryTracker`; why not the process's peak RSS and
what the tracker does not see: that module's docstring."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from gnsx.evaluation.tensor_memory import TensorMemoryTracker

_MB = 1e6


@torch.no_grad()
def hold_still(simulator):
    """Make ``simulator`` predict zero acceleration (its decoder's last layer and ``acc_mean`` zeroed), so a
    scene at rest stays exactly at rest in a rollout: every frame has the same graph.

    Why: an untrained model's accelerations move the particles, they pile up against the walls, and the
    graph (and with it a frame's working memory) grows with the frames for reasons that have nothing to do
    with the rollout's own memory. Returns the simulator (changed in place).
    """
    last = [m for m in simulator.network.decoder.modules() if isinstance(m, torch.nn.Linear)][-1]
    last.weight.zero_()
    last.bias.zero_()
    simulator.acc_mean.zero_()
    return simulator


def rollout_memory(
    simulator, initial_positions: torch.Tensor, particle_type: torch.Tensor, frames: Sequence[int] = (50, 500)
) -> list[dict]:
    """Peak memory of :func:`gnsx.model.rollout.rollout` for each number of frames, on the simulator's device.

    Give it a scene that keeps its graph (:func:`hold_still` on a scene at rest), or the figures measure the
    scene's changes too.

    CPU: the peak of :class:`TensorMemoryTracker` (exact, see the module docstring). CUDA:
    ``torch.cuda.max_memory_allocated`` after ``reset_peak_memory_stats``, less what was allocated before.
    The returned trajectory itself (``[T, N, D]``) grows with T; ``rollout`` gathers the frames in a list and
    stacks them at the end, so two copies of it exist for a moment: a rollout whose *working* memory does not
    grow has ``peak(T2) - peak(T1) <= 2 * (output(T2) - output(T1))``.

    Args:
        initial_positions: ``[N, history + 1, D]``; particle_type: ``[N]``.
        frames: rollout lengths to measure.
    Returns:
        one dict per length: ``frames``, ``peak_mb`` (MB, 10^6 bytes), ``output_mb`` (the returned array),
        ``measure`` (``"tensor_tracker"`` or ``"cuda_max_allocated"``), ``particles``.
    """
    from gnsx.model.rollout import rollout

    device = simulator.acc_std.device
    initial_positions, particle_type = initial_positions.to(device), particle_type.to(device)
    rows = []
    for count in frames:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
            torch.cuda.reset_peak_memory_stats(device)
            before = torch.cuda.memory_allocated(device)
            out = rollout(simulator, initial_positions, particle_type, count)
            torch.cuda.synchronize(device)
            peak, measure = torch.cuda.max_memory_allocated(device) - before, "cuda_max_allocated"
        else:
            tracker = TensorMemoryTracker()
            with tracker:
                out = rollout(simulator, initial_positions, particle_type, count)
            peak, measure = tracker.peak, "tensor_tracker"
        rows.append({
            "frames": int(count),
            "peak_mb": peak / _MB,
            "output_mb": out.numel() * out.element_size() / _MB,
            "measure": measure,
            "particles": int(initial_positions.shape[0]),
        })  # fmt: skip
        del out
    return rows


def rollout_growth(rows: Sequence[dict]) -> dict:
    """Growth of :func:`rollout_memory`'s peak between its shortest and longest rollout, against what the
    returned trajectory alone explains (twice its growth: the frame list and the stacked copy).

    Returns:
        ``frames`` ``[T1, T2]``, ``peak_growth_mb``, ``output_growth_mb``, ``excess_mb`` (peak growth less
        twice the output growth; <= 0: the working memory does not grow with the number of frames).
    """
    first, last = min(rows, key=lambda r: r["frames"]), max(rows, key=lambda r: r["frames"])
    peak_growth = last["peak_mb"] - first["peak_mb"]
    output_growth = last["output_mb"] - first["output_mb"]
    return {
        "frames": [first["frames"], last["frames"]],
        "peak_growth_mb": peak_growth,
        "output_growth_mb": output_growth,
        "excess_mb": peak_growth - 2 * output_growth,
    }
