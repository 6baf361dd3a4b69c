"""Exact, deterministic accounting of the memory torch tensors hold, and what a rollout needs.

Why not the process's peak RSS (what :func:`gnsx.evaluation.timing.measure_inference` reports on the CPU): glibc
keeps freed heap and reuses it without the RSS moving, and other work in the same process (a test suite)
shifts it, so a comparison of two RSS peaks can neither prove nor disprove growth of a few MB. Here every
aten operation run inside :class:`TensorMemoryTracker` is seen (a ``TorchDispatchMode``), each storage it
*allocates* (an output whose storage is none of the inputs': views and in-place results are not new memory)
is counted once, and a ``weakref.finalize`` on the storage takes it off when torch frees it. The peak of that
count is exact for what it covers, the same on every run, and independent of the allocator.

What it does not see: memory allocated outside torch operations (numpy arrays, e.g. scipy's neighbour
search before ``torch.from_numpy``; the tensors ``torch.from_numpy`` wraps), scratch buffers inside one
kernel, and tensors that existed before the tracker started (weights, inputs). Read it as the live tensor
memory a computation creates.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

_MB = 1e6


def _storages(tree) -> list[torch.UntypedStorage]:
    return [t.untyped_storage() for t in tree_flatten(tree)[0] if isinstance(t, torch.Tensor)]


class TensorMemoryTracker(TorchDispatchMode):
    """Counts the bytes of tensor storages allocated by torch operations inside ``with tracker:``.

    Attributes:
        current: bytes allocated inside the block and still alive.
        peak: the largest ``current`` seen (bytes); :meth:`reset_peak` sets it to ``current``.
        allocations: number of storages counted.
    """

    def __init__(self) -> None:
        super().__init__()
        self.current = 0
        self.peak = 0
        self.allocations = 0

    def _free(self, nbytes: int) -> None:
        self.current -= nbytes

    def reset_peak(self) -> None:
        self.peak = self.current

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        inputs = {s.data_ptr() for s in _storages((args, kwargs))}
        counted = set()
        for storage in _storages(out):
            pointer, nbytes = storage.data_ptr(), storage.nbytes()
            if nbytes == 0 or pointer in inputs or pointer in counted:
                continue  # a view or an in-place result: no new memory
            counted.add(pointer)
            self.current += nbytes
            self.allocations += 1
            self.peak = max(self.peak, self.current)
            weakref.finalize(storage, self._free, nbytes)
        return out


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
