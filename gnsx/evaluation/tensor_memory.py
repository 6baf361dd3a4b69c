"""Exact, deterministic accounting of the memory torch tensors hold (:class:`TensorMemoryTracker`), and of
one predicted frame's (:func:`frame_memory`).

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


def frame_memory(simulator, position_sequence: torch.Tensor, particle_type: torch.Tensor) -> dict:
    """What one predicted frame needs: the peak of the tensors it creates (graph build included, as far as
    torch builds it) plus the model's weights and buffers, in MB (10^6 bytes).

    Deterministic and independent of whatever else the process ran before, unlike a process's peak RSS (the
    module docstring), so models measured one after another in one process compare like with like. Not
    counted: the inputs, and memory outside torch operations (e.g. a scipy neighbour search's arrays).

    Args:
        simulator: a :class:`gnsx.model.simulator.LearnedSimulator` (any ``torch.nn.Module`` with
            ``predict_positions``).
        position_sequence: ``[N, history + 1, D]`` positions (data units); particle_type: ``[N]``.
    Returns:
        ``peak_memory_mb`` (frame peak + weights), ``frame_mb``, ``weights_mb``, ``memory_measure``.
    """
    weights = sum(t.numel() * t.element_size() for t in [*simulator.parameters(), *simulator.buffers()])
    tracker = TensorMemoryTracker()
    with torch.inference_mode(), tracker:
        simulator.predict_positions(position_sequence, particle_type)
    return {
        "peak_memory_mb": (tracker.peak + weights) / _MB,
        "frame_mb": tracker.peak / _MB,
        "weights_mb": weights / _MB,
        "memory_measure": "tensor_tracker: peak of one frame's tensors + weights and buffers (exact)",
    }
