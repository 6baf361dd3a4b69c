"""Floating-point operations of the learned simulator, counted analytically from node and edge counts.

Only matrix products are counted, 2 FLOPs per multiply-add (``2 m n k`` for ``[m, k] @ [k, n]``), the
convention of ``torch.utils.flop_counter`` and of a matmul peak; biases, ReLU, LayerNorm, the gathers and
the sum aggregation (``index_select``, ``index_add_``), the features and the neighbour search are not
counted (they are a few operations per element, memory-bound, and not what a matmul peak measures).

Forward pass on a graph of N nodes and E edges (a batch: the totals over its graphs), with latent size L,
MLP hidden width W, k hidden layers per MLP (every MLP: ``in -> W``, ``k - 1`` times ``W -> W``,
``W -> out``), node input size F (``history * D + 2 D`` + 1 for the scalar type or the embedding size),
edge input D + 1 and output D. ``mlp(r, a, b) = 2 r (a W + (k - 1) W^2 + W b)`` is one MLP on r rows:

    encoders   mlp(N, F, L) + mlp(E, D + 1, L)
    per step   edge MLP, first layer split as it is computed (gnsx.model.graph_network.InteractionNetwork):
                   receiver and sender terms once per node       2 N L W + 2 N L W
                   edge term on every edge                       2 E L W
                   the rest of the edge MLP on every edge        2 E ((k - 1) W^2 + W L)
               node MLP, first layer split over [sum_j m_ij, v_i] 2 N L W + 2 N L W
                   the rest of the node MLP                      2 N ((k - 1) W^2 + W L)
    decoder    mlp(N, L, D)
    pairwise   (``decoder: pairwise``, graph_network.PairwiseDecoder: Linear-ReLU-Linear for any k):
               the node decoder above, plus A's first layer split as phi_e's:
                   the two node terms once per node              2 N L W + 2 N L W
                   the edge term for x_ij and for x_ji           2 E (D + 1) W + 2 E (D + 1) W
                   the second layer, once for both directions    2 E W D

so a step costs ``8 N L W + 2 E L W + 2 (N + E)((k - 1) W^2 + W L)``; the unsplit first layer would cost
``6 E L W`` on the edges instead of ``2 E L W + 4 N L W``. The type embedding is a lookup (0 FLOPs).

A training step (forward and backward) costs three times the forward, less the products autograd skips: the
gradient with respect to the encoders' inputs, which need none (the edge features always; the node features
when the type is a scalar: with a learned embedding they carry the embedding's gradient), and the pair
decoder's edge features (both directions). Adam's update
(~10 operations per parameter) is not counted. Exact culling (static particles in the scene) computes less
than this; the scaling benchmark's scenes are all water, so it computes exactly this.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def _sizes(config: Mapping[str, Any]) -> dict[str, int]:
    """Layer sizes of a :class:`~gnsx.model.simulator.LearnedSimulator` from its ``config``."""
    dim = int(config["dim"])
    type_size = int(config["type_embedding_size"]) if config["type_encoding"] == "embedding" else 1
    return {
        "D": dim,
        "L": int(config["latent_size"]),
        "W": int(config["mlp_hidden_size"]),
        "k": int(config["mlp_hidden_layers"]),
        "M": int(config["mp_steps"]),
        "F": int(config["history"]) * dim + 2 * dim + type_size,
    }


def mlp_flops(rows: int, in_size: int, hidden: int, out_size: int, hidden_layers: int) -> int:
    """Matmul FLOPs of one :class:`~gnsx.model.graph_network.MLP` on ``rows`` rows."""
    sizes = [in_size] + [hidden] * hidden_layers + [out_size]
    return 2 * rows * sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))


def forward_flops(config: Mapping[str, Any], num_nodes: int, num_edges: int) -> dict[str, int]:
    """Matmul FLOPs of one forward pass (module docstring), by part.

    Args:
        config: the simulator's ``config`` (``LearnedSimulator.config``).
        num_nodes, num_edges: N and E of the graph the network runs on (self edges included).
    Returns:
        ``encoders``, ``processor`` (all M steps), ``decoder`` and ``total``.
    """
    s = _sizes(config)
    n, e, L, W, k, D = num_nodes, num_edges, s["L"], s["W"], s["k"], s["D"]
    if k < 1:
        raise ValueError("forward_flops: the split first layer needs mlp_hidden_layers >= 1")
    after_first = (k - 1) * W * W + W * L  # per row, the layers of an MLP after its first
    step = 8 * n * L * W + 2 * e * L * W + 2 * (n + e) * after_first
    parts = {
        "encoders": mlp_flops(n, s["F"], W, L, k) + mlp_flops(e, D + 1, W, L, k),
        "processor": s["M"] * step,
        "decoder": mlp_flops(n, L, W, D, k),
    }
    if config.get("decoder", "node") == "pairwise":
        parts["decoder"] += 4 * n * L * W + 4 * e * (D + 1) * W + 2 * e * W * D
    parts["total"] = sum(parts.values())
    return parts


def training_flops(config: Mapping[str, Any], num_nodes: int, num_edges: int) -> int:
    """Matmul FLOPs of one forward and backward pass on a batch of N nodes and E edges (module docstring)."""
    s = _sizes(config)
    edge_input_gradient = 2 * num_edges * (s["D"] + 1) * s["W"]  # one [E, D + 1] x [D + 1, W] product's
    skipped = edge_input_gradient  # edge encoder: no gradient for its input
    if config.get("decoder", "node") == "pairwise":
        skipped += 2 * edge_input_gradient  # the pair decoder's edge terms, x_ij and x_ji: none either
    if config["type_encoding"] != "embedding":
        skipped += 2 * num_nodes * s["F"] * s["W"]  # node encoder: no gradient for its input either
    return 3 * forward_flops(config, num_nodes, num_edges)["total"] - skipped
