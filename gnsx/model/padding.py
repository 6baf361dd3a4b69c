"""Row padding of the graph to a few fixed sizes, so bf16 matrix products on the CPU reuse their kernels.

Under ``bf16-mixed`` training on a CPU, every Linear layer becomes a oneDNN matmul, and oneDNN builds (JIT
compiles) a kernel per distinct shape, cached by shape. The node count N and edge count E change every batch,
so nearly every product of a training step missed that cache: on the small preset, fp32 took 80 ms per
step and bf16 102 ms with the batches varying, against 67 and 53 ms when one batch was repeated (2 threads,
AMD EPYC with AVX512-BF16; docs/speed.md, "bf16 training on the CPU"). fp32 goes to MKL's sgemm, which has
no per-shape kernels, and is not padded.

:func:`pad_graph` rounds N and E up to multiples of :data:`NODE_BUCKET` / :data:`EDGE_BUCKET` with dummy
nodes (zero features) and dummy edges (zero features) that run from the last dummy node to itself. The real
rows are untouched and no real node receives anything from a dummy:

- every dummy edge's receiver is the last row, above every real receiver, so the edges stay sorted by
  receiver (what :func:`gnsx.model.edge_ops.receiver_offsets` needs);
- dummy nodes are nobody's sender on a real edge, and the caller drops their output rows, so nothing reaches
  the loss from them and their gradients are exactly 0.

The cost is at most one bucket of extra rows: ~3% more edge rows at ~10k edges.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: Node rows are rounded up to a multiple of this (at least one dummy node, the dummy edges' endpoint).
NODE_BUCKET = 64
#: Edge rows are rounded up to a multiple of this.
EDGE_BUCKET = 512


def needs_padding(x: Tensor) -> bool:
    """True where products run through per-shape kernels: CPU autocast to a lower precision (bf16)."""
    return x.device.type == "cpu" and torch.is_autocast_enabled("cpu")


def pad_graph(x: Tensor, edge_index: Tensor, edge_attr: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Pad ``x`` ``[N, F]``, ``edge_index`` ``[2, E]`` (receiver-sorted or not) and ``edge_attr``
    ``[E, G]`` to ``[N', F]``, ``[2, E']``, ``[E', G]`` with N' > N and E' >= E bucket multiples (module
    docstring). The first N rows of any node output computed on the padded graph are those of the graph.
    """
    num_nodes, num_edges = x.shape[0], edge_index.shape[1]
    padded_nodes = (num_nodes // NODE_BUCKET + 1) * NODE_BUCKET  # > num_nodes: room for the dummy endpoint
    padded_edges = -(-num_edges // EDGE_BUCKET) * EDGE_BUCKET
    x = torch.cat([x, x.new_zeros(padded_nodes - num_nodes, x.shape[1])])
    dummy = edge_index.new_full((2, padded_edges - num_edges), padded_nodes - 1)
    edge_index = torch.cat([edge_index, dummy], dim=1)
    edge_attr = torch.cat([edge_attr, edge_attr.new_zeros(padded_edges - num_edges, edge_attr.shape[1])])
    return x, edge_index, edge_attr
