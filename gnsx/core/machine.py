"""The machine a measurement ran on, in words: every timing and every training record names its CPU.

Why more than ``/proc/cpuinfo``'s model name: on the virtual machines gnsx is built on the name can be as bare as
"Intel(R) Xeon(R) Processor", while the speed of a frame depends on which generation it is and whether it
multiplies bf16 natively (gnsx.training.precision). So the name carries the family/model numbers, the
matrix-product extensions present and the core count, e.g. ``Intel(R) Xeon(R) Processor (family 6 model 207;
avx512_bf16; 2 cores)``.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: /proc/cpuinfo flags named in :func:`cpu_name` (the ones that change which matmul kernels run).
NAMED_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_tile")


def cpu_name(cpuinfo: str | Path = "/proc/cpuinfo") -> str:
    """The CPU's model name with its family/model numbers, the widest matrix extensions and the core count.

    Falls back to :func:`platform.processor` (or "cpu") where ``cpuinfo`` cannot be read.
    """
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return platform.processor() or "cpu"
    fields: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        key = key.strip()
        if sep and key not in fields:
            fields[key] = value.strip()
    name = fields.get("model name") or platform.processor() or "cpu"
    flags = set(fields.get("flags", "").split())
    # avx512_bf16 implies avx512f implies avx2: name only the widest of each family present.
    named = [f for f in NAMED_FLAGS if f in flags]
    if "avx512f" in named:
        named.remove("avx2")
    if "avx512_bf16" in named:
        named.remove("avx512f")
    if "amx_bf16" in named and "amx_tile" in named:
        named.remove("amx_tile")
    facts = []
    if "cpu family" in fields and "model" in fields:
        facts.append(f"family {fields['cpu family']} model {fields['model']}")
    if named:
        facts.append(", ".join(named))
    facts.append(f"{os.cpu_count()} cores")
    return f"{name} ({'; '.join(facts)})"
