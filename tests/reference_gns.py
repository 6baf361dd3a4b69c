"""A plain transcription of the paper's graph network equations, kept only in the tests.

It reads the parameters of a :class:`gnsx.model.graph_network.EncodeProcessDecode` and computes, with no
trick of the fast path (no split first layer, no ``index_add_``):

    m_ij = phi_e([e_ij, v_i, v_j])                  (per-edge concatenation, then the whole MLP)
    v_i <- v_i + phi_v([sum_j m_ij, v_i])            (the sum as a dense incidence-matrix product)
    e_ij <- m_ij   or   e_ij + m_ij                  (edge residual)
    f_i = sum_j A([v_i, v_j, x_ij]) - A([v_j, v_i, x_ji])   (pair decoder: whole MLP on both concatenations)

so a test comparing the two proves the fast path computes the equations, forward and backward.
"""

from __future__ import annotations

import torch
from torch import Tensor

from gnsx.model.graph_network import EncodeProcessDecode


def incidence(edge_index: Tensor, num_nodes: int, dtype: torch.dtype) -> Tensor:
    """``[N, E]`` matrix with a 1 at (receiver of edge k, k): ``incidence @ messages`` sums each receiver's
    incoming messages."""
    matrix = torch.zeros(num_nodes, edge_index.shape[1], dtype=dtype)
    matrix[edge_index[1], torch.arange(edge_index.shape[1])] = 1.0
    return matrix


def reference_forward(
    network: EncodeProcessDecode, x: Tensor, edge_index: Tensor, edge_attr: Tensor
) -> Tensor:
    """The network's output ``[N, out]`` (``[N, 2 out]`` with the pair decoder: node decoder, pair forces)
    computed from the equations with the network's own parameters."""
    senders, receivers = edge_index
    node_latent = network.node_encoder(x)
    edge_latent = network.edge_encoder(edge_attr)
    summation = incidence(edge_index, x.shape[0], x.dtype)
    for step in network.processor:
        messages = step.edge_mlp(
            torch.cat([edge_latent, node_latent[receivers], node_latent[senders]], dim=1)
        )
        aggregated = summation @ messages
        node_latent = node_latent + step.node_mlp(torch.cat([aggregated, node_latent], dim=1))
        edge_latent = edge_latent + messages if step.edge_residual else messages
    decoded = network.decoder(node_latent)
    pair = network.pair_decoder
    if pair is None:
        return decoded

    def pair_mlp(first: Tensor, second: Tensor, features: Tensor) -> Tensor:
        return pair.second(torch.relu(pair.first(torch.cat([first, second, features], dim=1))))

    # x_ji: the displacement to the other particle changes sign, the distance does not.
    reversed_attr = torch.cat([-edge_attr[:, :-1], edge_attr[:, -1:]], dim=1)
    forces = pair_mlp(node_latent[receivers], node_latent[senders], edge_attr) - pair_mlp(
        node_latent[senders], node_latent[receivers], reversed_attr
    )
    return torch.cat([decoded, summation @ forces], dim=1)
