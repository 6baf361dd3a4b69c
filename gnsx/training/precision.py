"""Training precision: ``trainer.precision=auto`` picks bf16-mixed where the CPU multiplies bf16 natively.

Lightning's ``bf16-mixed`` runs the training step under ``torch.autocast``: the Linear layers' products in
bf16 (fp32 accumulation inside oneDNN), everything else (features, graph, LayerNorm statistics, the loss,
Adam, the weights) in fp32. Rollouts and evaluation always run in fp32, whatever a model was trained with.

Why ``auto`` and not a fixed choice (figures in docs/speed.md, "bf16 training on the CPU"):

- On a CPU with AVX512-BF16 (AMD Zen 4, Intel Cooper Lake and later) or AMX, the products run 2.5-3.5x
  faster in bf16 and the whole training step of the small preset ~1.3x faster (2,300 particles: ~1.9x),
  given :mod:`gnsx.model.padding`.
- On a CPU without them (AVX2 only) bf16 is emulated and slower than fp32: ``auto`` keeps fp32 there.
- On a GPU the simplified model's step is launch-bound (issue 10): bf16 would not shorten it, so ``auto``
  keeps fp32, as the paper trained.
"""

from __future__ import annotations

from pathlib import Path

#: /proc/cpuinfo flags of native bf16 dot products.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")


def cpu_has_native_bf16(cpuinfo: str | Path = "/proc/cpuinfo") -> bool:
    """True when the CPU's flags include :data:`BF16_FLAGS` (False where the file cannot be read)."""
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.partition(":")[2].split())
            return any(flag in flags for flag in BF16_FLAGS)
    return False


def resolve_precision(precision, accelerator: str, cpuinfo: str | Path = "/proc/cpuinfo"):
    """Lightning's precision for ``trainer.precision`` on ``trainer.accelerator``.

    ``auto``: ``bf16-mixed`` when training runs on a CPU (``cpu``, or ``auto`` without CUDA) with native
    bf16 (:func:`cpu_has_native_bf16`), else ``32-true``. Any other value is returned as given (Lightning
    checks it).
    """
    if str(precision) != "auto":
        return precision
    on_cpu = str(accelerator) == "cpu"
    if str(accelerator) == "auto":
        import torch

        on_cpu = not torch.cuda.is_available()
    return "bf16-mixed" if on_cpu and cpu_has_native_bf16(cpuinfo) else "32-true"
