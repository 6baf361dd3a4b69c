"""How many CPU threads torch uses: enough to use idle cores, never more than the cores left free.

Why not torch's default (one thread per core): its OpenMP threads spin-wait for each other at every
operation, and when other processes hold some of the cores a waiting thread burns its core while the thread
it waits for is not scheduled. Measured on this repository's 2-core machine with other jobs running: the
demo trained at 1.8 steps/s with torch's default of 2 threads and at 8.8 steps/s with 1 thread (issue 11);
``python -m gnsx.perf.throughput --data data/small --batch-size 2`` at load ~3 ran 11.2-14.5 steps/s with 1
thread, and with 2 threads did not finish 70 steps in 200 s. A run on an idle machine loses by the same rule
only what the idle core would have added (~1.6x at most here). ``OMP_WAIT_POLICY=PASSIVE`` (waiting threads
sleep instead of spinning) ran 2 threads at 11.3 steps/s at load ~3, but on an idle machine it halved the
training loop (``python -m gnsx.perf.throughput --data data/small --batch-size 2 --threads 2 --steps 150``:
6.7 steps/s against 14.1 with OpenMP's default), so gnsx does not set it; load that arrives after the choice
is not handled (set ``threads=1`` or ``OMP_WAIT_POLICY=PASSIVE`` yourself on a machine you share).

``threads: auto`` (the default of ``train.py``) therefore takes the cores this process may run on
(``os.sched_getaffinity``), shares them among the processes of this node (DDP ranks on the CPU, or the
parallel jobs of a sweep), subtracts the cores other processes keep busy (measured over half a second by psutil while
this process sleeps; the 1-minute load average where psutil cannot tell) and rounds
to the nearest count, at least 1 and at most :data:`MAX_THREADS` (more threads do not speed up
graphs of this size). ``threads: N`` sets N; ``threads: null`` leaves torch's default.
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger("gnsx")

#: The most threads ``auto`` chooses.
MAX_THREADS = 8


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity; all cores where the OS does not say)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def machine_load(window_s: float = 0.5) -> float:
    """Cores kept busy by other processes: psutil's busy share of each of this process's cores over
    ``window_s`` while it sleeps, summed; else the 1-minute load average (0 where neither is known)."""
    import psutil

    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = list(range(os.cpu_count() or 1))
    try:
        busy = psutil.cpu_percent(interval=window_s, percpu=True)
        return sum(busy[c] for c in cpus if c < len(busy)) / 100.0
    except (OSError, RuntimeError):
        pass
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return 0.0


def choose_threads(processes: int = 1, cores: int | None = None, load: float | None = None) -> int:
    """Threads per process for ``processes`` processes of this node (see the module docstring).

    Args:
        cores: available cores (default :func:`available_cores`).
        load: other processes' load (default :func:`machine_load`).
    """
    cores = available_cores() if cores is None else int(cores)
    load = machine_load() if load is None else float(load)
    processes = max(1, int(processes))
    share = max(1, cores // processes)
    free = max(0.0, cores - load) / processes
    return int(max(1, min(share, MAX_THREADS, round(free))))


def apply_threads(setting: int | str | None, processes: int = 1) -> int:
    """Set torch's intra-op threads from a ``threads`` setting (None, ``"auto"`` or N); log and return the
    count torch uses.

    Every CLI that computes with torch calls this first, so it also applies the process's CPU memory
    policy (:func:`gnsx.core.allocator.retain_freed_memory`: large tensors reuse freed memory instead of being
    page-faulted in again every frame).
    """
    import torch

    from gnsx.core.allocator import retain_freed_memory

    retain_freed_memory()

    if setting is None:
        log.info("Threads: %d (torch's default; threads=auto adapts to the load)", torch.get_num_threads())
        return torch.get_num_threads()
    if setting == "auto":
        cores, load = available_cores(), machine_load()
        count = choose_threads(processes, cores, load)
        log.info("Threads: %d (auto: %d cores, load %.1f, %d process(es) here; threads=N to choose)",
                 count, cores, load, processes)  # fmt: skip
    else:
        count = int(setting)
    torch.set_num_threads(count)
    return count
