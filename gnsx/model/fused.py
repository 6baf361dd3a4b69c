"""Fused inference kernels (``fused.cpp``): the graph network's MLPs without a memory pass per layer.

What they replace. The eager path writes and re-reads every intermediate of an MLP (the bias broadcast, each
product, ReLU, LayerNorm's passes, the residual add; on the edges also the gather-sum and the segment sum). At
WaterRamps size (16,286 edges x 64 fp32: 4.2 MB per tensor, more than a core's L2) those passes, and on the
node side [2,300, 64] products too small for two threads, cost more than the products on the 2-core Xeon
(docs/speed.md, "Per CPU kind"). The kernels run the same arithmetic in row tiles (:data:`TILE_EDGES` edges or
:data:`TILE_ROWS` nodes, a few hundred KB of per-thread buffers): memory sees each input read once and each
output written once. Two ops:

- ``torch.ops.gnsx.mlp`` (:func:`mlp`): any gnsx MLP (Linear, ReLU, [Linear, ReLU]..., Linear, [LayerNorm]),
  its first layer given as blocks over several inputs (phi_v on ``[sum_j m_ij, v_i]`` without the concat),
  plus a residual: the encoders, the node update, the decoder;
- ``torch.ops.gnsx.edge_step`` (:func:`edge_step`): phi_e from its first layer's per-node terms gathered per
  edge, the per-receiver sum of the messages while the tile is in cache, and the edge update.

When they run (:func:`runs`), and why only then:

- **no autograd** (``torch.is_grad_enabled()`` false: rollouts, evaluation, validation, the benchmark): the
  kernels have no backward; training keeps the eager path, whose gradients the tests check;
- fp32 tensors on the CPU, outside autocast (bf16 training and GPUs keep the eager path); the edge step also needs
  receiver-sorted edges (the radius graph and the culling plan sort them);
- not inside ``torch.compile`` (``model.compile``), whose traced graph keeps the eager ops;
- the kernels built. ``torch.utils.cpp_extension`` compiles them once per machine and caches them under
  ``~/.cache/torch_extensions`` (the name carries a hash of the source, the torch version and the CPU, since
  they are built with ``-march=native``); ``make install`` builds them, so a rollout never pays the ~30 s
  build. Where no C++ compiler is found the build fails once, a warning says so, and the eager path runs.

``GNSX_FUSED=0`` in the environment keeps the eager path everywhere (for comparisons: ``python -m
gnsx.perf.benchmark --no-fused``). Agreement with the eager path, both model configs, with and without
culling: ``tests/test_fused.py`` (float tolerance: the products are the same MKL sgemm on row blocks;
LayerNorm and the per-receiver sums run in the same order, in fp32).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import sys
import time
import weakref
from pathlib import Path

import torch
from torch import Tensor, nn

from gnsx.core.machine import cpu_name

log = logging.getLogger("gnsx")

SOURCE = Path(__file__).with_name("fused.cpp")
#: Edges per tile: [1024, 64] fp32 buffers (256 KB each) stay in a core's L2 (1-2 MB on the CPUs measured),
#: and 16 tiles per step at WaterRamps size keep both threads busy (256-4096 measured within noise).
TILE_EDGES = 1024
#: Node rows per tile of :func:`mlp`: 9 tiles at WaterRamps' 2,300 particles, enough to balance 2 threads.
TILE_ROWS = 256
#: Environment switch: "0" keeps the eager path everywhere.
ENV = "GNSX_FUSED"

_state: dict[str, object] = {}
_layers: weakref.WeakKeyDictionary[nn.Module, tuple | None] = weakref.WeakKeyDictionary()


def extension_name() -> str:
    """The build's cache key: source, torch version and CPU (``-march=native`` code runs on its own CPU only)."""
    digest = hashlib.sha1()
    digest.update(SOURCE.read_bytes())
    digest.update(torch.__version__.encode())
    digest.update(cpu_name().encode())
    return f"gnsx_fused_{digest.hexdigest()[:12]}"


def load(verbose: bool = False) -> bool:
    """Build (first call on a machine) and load the kernel; True when ``torch.ops.gnsx.edge_step`` is there.

    A failed build (no compiler, no ninja) is logged once and remembered for the process: the eager path runs.
    """
    if "loaded" in _state:
        return bool(_state["loaded"])
    from torch.utils import cpp_extension

    # cpp_extension runs `ninja` from PATH; the ninja wheel (a gnsx dependency) puts it beside this Python,
    # which is not on PATH when a script is run as .venv/bin/python.
    beside_python = Path(sys.executable).parent
    if shutil.which("ninja") is None and (beside_python / "ninja").exists():
        os.environ["PATH"] = f"{beside_python}{os.pathsep}{os.environ.get('PATH', '')}"
    start = time.perf_counter()
    try:
        cpp_extension.load(
            name=extension_name(),
            sources=[str(SOURCE)],
            # -fopenmp: at::parallel_for is inline and runs serially without it; it also enables the
            # `omp simd` reductions of the per-row loops.
            extra_cflags=["-O3", "-march=native", "-fopenmp"],
            extra_ldflags=["-fopenmp"],
            is_python_module=False,
            verbose=verbose,
        )
        _state["loaded"] = True
    except Exception as error:  # noqa: BLE001 - any build failure means: run the eager path
        log.warning("gnsx: fused kernels not built (%s); the eager path runs", str(error).splitlines()[0])
        _state["loaded"] = False
    else:
        seconds = time.perf_counter() - start
        if seconds > 5:
            log.info("gnsx: built the fused kernels in %.0f s (cached for this machine)", seconds)
    return bool(_state["loaded"])


def enabled() -> bool:
    """False when ``GNSX_FUSED_EDGE=0``."""
    return os.environ.get(ENV, "1") != "0"


def mlp_layers(module: nn.Sequential) -> tuple[list[nn.Linear], nn.LayerNorm | None] | None:
    """An MLP's Linear layers and final LayerNorm (or None) when it is Linear, ReLU, [Linear, ReLU]...,
    Linear, [LayerNorm] with at least one hidden layer (every gnsx MLP); None for any other shape.

    Cached per module: the layers are module objects, whose parameters load_state_dict updates in place."""
    if module in _layers:
        return _layers[module]
    layers = list(module)
    norm = layers.pop() if layers and isinstance(layers[-1], nn.LayerNorm) else None
    linears, relus = layers[0::2], layers[1::2]
    shaped = (
        len(linears) >= 2
        and len(relus) == len(linears) - 1
        and all(isinstance(layer, nn.Linear) and layer.bias is not None for layer in linears)
        and all(isinstance(layer, nn.ReLU) for layer in relus)
        and all(a.out_features == b.in_features for a, b in zip(linears[:-1], linears[1:]))
        and all(layer.out_features == linears[0].out_features for layer in linears[:-1])
    )
    if shaped and norm is not None:
        shaped = (
            norm.weight is not None
            and norm.bias is not None
            and tuple(norm.normalized_shape) == (linears[-1].out_features,)
        )
    result = (linears, norm) if shaped else None
    _layers[module] = result
    return result


def edge_step_runs(edge_mlp: nn.Sequential, offsets: Tensor | None, *tensors: Tensor) -> bool:
    """Whether :func:`edge_step` may replace the eager edge block: :func:`runs`, receiver-sorted edges (a row
    pointer) and phi_e of the :func:`mlp_layers` shape ending in a LayerNorm."""
    layers = mlp_layers(edge_mlp)
    return offsets is not None and layers is not None and layers[1] is not None and runs(*tensors)


def runs(*tensors: Tensor) -> bool:
    """Whether the fused kernels may replace the eager ops on these tensors (module docstring, "When")."""
    if torch.is_grad_enabled() or not enabled():
        return False
    # Under CPU autocast (bf16-mixed training's pushforward steps, which run without gradient) the products
    # come out bf16: the eager path, whose autocast handling gnsx.model.padding and add_product_ provide.
    if torch.is_autocast_enabled("cpu"):
        return False
    for tensor in tensors:
        if tensor.device.type != "cpu" or tensor.dtype != torch.float32 or tensor.dim() != 2:
            return False
        if tensor.shape[1] > 0 and tensor.stride(1) != 1:
            return False
    if torch.compiler.is_compiling():
        return False
    return load()


def _tail(linears: list[nn.Linear], norm: nn.LayerNorm | None) -> tuple:
    """The op arguments after the first layer: hidden weights, biases, output weight and bias, LayerNorm."""
    hidden = linears[1:-1]
    return (
        [layer.weight for layer in hidden],
        [layer.bias for layer in hidden],
        linears[-1].weight,
        linears[-1].bias,
        None if norm is None else norm.weight,
        None if norm is None else norm.bias,
        1e-5 if norm is None else float(norm.eps),
    )


def mlp(
    module: nn.Sequential,
    inputs: list[Tensor],
    first_weights: list[Tensor],
    residual: Tensor | None = None,
) -> Tensor:
    """``module`` (:func:`mlp_layers` shape) on rows whose first layer is ``sum_i inputs[i] @ first_weights[i].T
    + first.bias``, plus ``residual``.

    Args:
        module: the MLP; its first Linear supplies the bias, ``first_weights`` the weight blocks.
        inputs: ``[M, K_i]`` each (unit column stride; row-strided views are fine).
        first_weights: ``[H, K_i]`` each, column blocks of the first Linear's ``[H, sum K_i]`` weight (views).
        residual: ``[M, out]`` added to the output, or None.

    Returns:
        ``[M, out]``.
    """
    layers = mlp_layers(module)
    assert layers is not None
    linears, norm = layers
    hidden_w, hidden_b, w_out, b_out, gamma, beta, eps = _tail(linears, norm)
    return torch.ops.gnsx.mlp(
        inputs, first_weights, linears[0].bias, hidden_w, hidden_b, w_out, b_out, gamma, beta, eps, residual,
        _balanced(inputs[0].shape[0], TILE_ROWS),
    )  # fmt: skip


def edge_step(
    edge_mlp: nn.Sequential,
    receiver_term: Tensor,
    sender_term: Tensor,
    edge_attr: Tensor,
    senders: Tensor,
    receivers: Tensor,
    offsets: Tensor,
    residual: bool,
) -> tuple[Tensor, Tensor]:
    """phi_e after its first layer's node terms, the segment sum and the edge update, fused.

    Args:
        edge_mlp: phi_e (:func:`mlp_layers` shape, ending in a LayerNorm); its first Linear's weight is
            ``[H, 3L]`` with columns ``[e_ij, v_i, v_j]``, of which the kernel uses the edge block.
        receiver_term: ``[R, H]`` ``v_i W_r^T + b`` per receiver row (unit column stride).
        sender_term: ``[N, H]`` ``v_j W_s^T`` per node (unit column stride).
        edge_attr: ``[E, L]`` edge latents, receiver-sorted; E must be ``offsets[R]``.
        senders, receivers: ``[>= E]`` int64.
        offsets: ``[>= R + 1]`` receiver row pointer (:func:`gnsx.model.edge_ops.receiver_offsets`).
        residual: ``e <- e + m`` instead of ``e <- m``.

    Returns:
        (edge_attr' ``[E, L]``, aggregated ``[R, L]``: the sum of the messages over each receiver's edges).
    """
    layers = mlp_layers(edge_mlp)
    assert layers is not None and layers[1] is not None, "phi_e ends in a LayerNorm in every gnsx config"
    linears, norm = layers
    hidden_w, hidden_b, w_out, b_out, gamma, beta, eps = _tail(linears, norm)
    latent = edge_attr.shape[1]
    return torch.ops.gnsx.edge_step(
        receiver_term, sender_term, edge_attr.contiguous(), senders.contiguous(), receivers.contiguous(),
        offsets.contiguous(),
        linears[0].weight[:, :latent],  # [H, L] view, row stride 3L: no copy
        hidden_w, hidden_b, w_out, b_out, gamma, beta, eps, residual, _balanced(edge_attr.shape[0], TILE_EDGES),
    )  # fmt: skip


def _balanced(count: int, tile: int) -> int:
    """A tile size near ``tile`` that cuts ``count`` rows into a multiple of the thread count (no thread
    waits for another's extra tile: 9 tiles on 2 threads cost as much as 10)."""
    threads = max(1, torch.get_num_threads())
    tiles = max(1, -(-count // tile))
    tiles = -(-tiles // threads) * threads
    return max(1, -(-count // tiles))


def build() -> int:
    """Build (or find cached) the kernels and say so; 1 if they cannot be built (``make install`` runs this:
    ``python -c "from gnsx.model import fused; fused.build()"``)."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    start = time.perf_counter()
    ok = load()
    status = "ready" if ok else "NOT built: the eager path runs"
    print(f"gnsx fused CPU kernels: {status} ({extension_name()}, {time.perf_counter() - start:.1f} s)")
    return 0 if ok else 1
