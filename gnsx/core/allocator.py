"""Keep freed CPU memory in the process, so large tensors do not page-fault anew at every frame.

glibc serves an allocation above its mmap threshold (at most 32 MB on 64-bit Linux) with a fresh ``mmap``
and returns it to the kernel on free. A 100k-particle frame allocates and frees dozens of E x 64 fp32
tensors of ~200 MB per message-passing step, so every one of them is faulted in page by page (and zeroed
by the kernel) again at every frame. Measured in two processes run one after the other (the setting is
per process), one thread, 100k particles (~764k edges): the simplified model's frame took 9.1 s with glibc's
defaults and 3.6 s with mmap disabled and trimming off; the scaling benchmark went from 1.88x to 0.95x linear
at 100k, while a 2.3k-particle frame (~4 MB tensors, under the threshold) did not change (docs/speed.md,
section 3).

:func:`retain_freed_memory` therefore tells glibc (``mallopt``) to take every allocation from its heap and
never trim it: freed blocks are reused by the next frame's tensors of the same sizes. The cost: the
process's resident memory stays at its high-water mark instead of shrinking after a peak, which for a
simulator that repeats the same frame sizes is the memory it needs anyway. Elsewhere than glibc (macOS,
musl) it does nothing. ``GNSX_GLIBC_MALLOC_DEFAULTS=1`` in the environment keeps glibc's defaults.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

log = logging.getLogger("gnsx")

# mallopt parameters, glibc's malloc.h.
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4

_applied: bool | None = None


def retain_freed_memory() -> bool:
    """Take all allocations from the heap and never return it to the OS (glibc only; idempotent).

    Returns:
        True when glibc accepted both settings (now or on an earlier call), False where it does not apply.
    """
    global _applied
    if _applied is not None:
        return _applied
    _applied = False
    if os.environ.get("GNSX_GLIBC_MALLOC_DEFAULTS") == "1":
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # mallopt returns 1 on success. A trim threshold of INT_MAX (2 GiB) keeps any realistic free top chunk.
    _applied = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
    if _applied:
        log.debug("glibc malloc: mmap off, trimming off (gnsx.core.allocator)")
    return _applied
