"""Exact culling: compute only what can change the prediction of a decoded (dynamic) particle.

After M message-passing steps, a node's latent depends only on nodes within M hops of it (one hop per
step, messages flowing sender -> receiver). So to decode the dynamic particles D exactly:

* at step k (k = 1 .. M), only nodes within ``M - k`` hops of D need their latent updated (at the last
  step, D itself), and only the edges whose receiver is among them are computed: a *shrinking frontier*;
* the encoders only see the nodes within M hops and the edges into nodes within ``M - 1`` hops;
* everything else (static particles farther than M hops, the edges feeding only them) is left out.

Why it is exact, edge latents included: an edge's latent after step k feeds step k + 1 only through its
receiver (``m_ij = phi_e([e_ij, v_i, v_j])`` is summed into ``v_i``), and the edges into the nodes within
``M - k - 1`` hops are a subset of those into the nodes within ``M - k``, so every edge latent that is read
was computed, residual (``e <- e + m``) or not. LayerNorm and the MLPs act per row. Graphs of a batch share
no edge, so hop sets never cross graphs.

Bookkeeping is one permutation: the kept nodes are ordered by hop distance (D first), so "within r hops"
is the prefix ``[0, n_r)`` of the node rows; the kept edges are sorted by receiver in that order, so the
edges into it are the prefix ``[0, e_r)`` of the edge rows. Each step then works on slices, with the fast
path of :class:`gnsx.model.graph_network.InteractionNetwork` unchanged.

Before the graph is even built, :func:`particles_in_reach` drops the particles that cannot be within M hops
of D because they are farther than ``M * R`` from every particle of D (a cell test, so a superset of those
within reach is kept; the hop plan then removes the rest exactly).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
from torch import Tensor

#: Cell side of :func:`particles_in_reach` over the reach: above 1, so a pair exactly ``reach`` apart after
#: float rounding still lies in the same or adjacent cells.
_CELL_MARGIN = 1.01


@dataclass(frozen=True)
class CullPlan:
    """Which nodes and edges each message-passing step computes (see the module docstring).

    Attributes:
        nodes: ``[n_M]`` int64 ids (in the full graph) of the nodes within M hops of the decoded ones, by hop
            distance: the decoded nodes first (``nodes[:n_0]``), in their original order within a distance.
        edges: ``[e_{M-1}]`` int64 ids of the edges whose receiver is within ``M - 1`` hops, sorted by the
            receiver's new row.
        edge_index: ``[2, e_{M-1}]`` those edges with senders and receivers renumbered as rows of ``nodes``
            (row 0 sender, row 1 receiver), receiver-sorted.
        node_counts: ``n_r`` for r = 0 .. M: the nodes within r hops are ``nodes[:n_r]``.
        edge_counts: ``e_r`` for r = 0 .. M - 1: the edges into nodes within r hops are the first ``e_r``.
        num_nodes, num_edges: size of the full graph.
    """

    nodes: Tensor
    edges: Tensor
    edge_index: Tensor
    node_counts: tuple[int, ...]
    edge_counts: tuple[int, ...]
    num_nodes: int
    num_edges: int

    @property
    def num_decoded(self) -> int:
        return self.node_counts[0]

    def work(self) -> dict[str, float]:
        """Fractions of the full graph's work kept (1 = nothing culled; 0/0 counts as 1).

        ``nodes`` and ``edges``: nodes and edges of the culled graph (encoded); ``node_updates`` and
        ``edge_updates``: node and edge MLP evaluations summed over the M steps, against ``M * N`` and
        ``M * E``.
        """
        steps = len(self.edge_counts)
        return {
            "nodes": _fraction(self.node_counts[-1], self.num_nodes),
            "edges": _fraction(self.edge_counts[-1] if steps else 0, self.num_edges),
            "node_updates": _fraction(sum(self.node_counts[:-1]), steps * self.num_nodes),
            "edge_updates": _fraction(sum(self.edge_counts), steps * self.num_edges),
        }


def _fraction(part: int, whole: int) -> float:
    return part / whole if whole else 1.0


def hop_distance(edge_index: Tensor, sources: Tensor, max_hops: int) -> Tensor:
    """Hops from the ``sources`` to every node, against the messages' direction, capped at ``max_hops + 1``.

    Node j is one hop from i when an edge j -> i exists (j sends to i), so a node at distance r can reach a
    source's latent in r message-passing steps. One boolean propagation over the edges per hop, stopping
    early when the frontier empties.

    Args:
        edge_index: ``[2, E]`` (row 0 sender, row 1 receiver).
        sources: ``[N]`` bool.
        max_hops: M.
    Returns:
        ``[N]`` int64: the distance, ``max_hops + 1`` for nodes farther than ``max_hops``.
    """
    senders, receivers = edge_index[0], edge_index[1]
    distance = torch.full(sources.shape, max_hops + 1, dtype=torch.long, device=sources.device)
    distance[sources] = 0
    reached = sources.clone()
    frontier = sources
    for hop in range(1, max_hops + 1):
        into_frontier = frontier.index_select(0, receivers)  # [E] edges whose receiver was just reached
        frontier = torch.zeros_like(reached).index_fill_(0, senders[into_frontier], True) & ~reached
        if not bool(frontier.any()):
            break
        distance[frontier] = hop
        reached |= frontier
    return distance


def plan_culling(edge_index: Tensor, decode: Tensor, mp_steps: int) -> CullPlan:
    """The :class:`CullPlan` that decodes the nodes of ``decode`` exactly after ``mp_steps`` steps.

    Args:
        edge_index: ``[2, E]`` int64 (row 0 sender, row 1 receiver), any order.
        decode: ``[N]`` bool, the nodes whose output is needed.
        mp_steps: M.
    """
    num_nodes, num_edges = int(decode.shape[0]), int(edge_index.shape[1])
    distance = hop_distance(edge_index, decode, mp_steps)  # [N], M + 1 = out of reach
    nodes = torch.argsort(distance, stable=True)
    node_counts = torch.bincount(distance, minlength=mp_steps + 2).cumsum(0)[: mp_steps + 1]
    receiver_distance = distance.index_select(0, edge_index[1])  # [E]
    kept = torch.nonzero(receiver_distance < mp_steps).squeeze(1)
    kept_distance = receiver_distance.index_select(0, kept)
    edge_counts = torch.bincount(kept_distance, minlength=mp_steps).cumsum(0)[:mp_steps]
    counts = torch.cat([node_counts, edge_counts]).tolist()  # one device sync for all the slice bounds
    node_counts, edge_counts = tuple(counts[: mp_steps + 1]), tuple(counts[mp_steps + 1 :])
    nodes = nodes[: node_counts[-1]]
    row = torch.full((num_nodes,), -1, dtype=torch.long, device=decode.device)
    row[nodes] = torch.arange(len(nodes), device=decode.device)
    kept_index = row[edge_index[:, kept]]  # [2, e_{M-1}]; every sender of a kept edge is within M hops
    # Receiver-major, as the radius graph: the prefix property needs it and index_add_ stays cache friendly.
    order = torch.argsort(kept_index[1], stable=True)
    return CullPlan(
        nodes=nodes,
        edges=kept[order],
        edge_index=kept_index[:, order],
        node_counts=node_counts,
        edge_counts=edge_counts,
        num_nodes=num_nodes,
        num_edges=num_edges,
    )


def particles_in_reach(
    position: Tensor, sources: Tensor, reach: float, batch: Tensor | None = None
) -> Tensor:
    """Mask of the particles that may lie within ``reach`` of a source particle of the same graph.

    A cell test: space (and the graph id) is cut into cells of side ``reach`` (times a small margin), and a
    particle is kept when its cell or one of the ``3^D - 1`` around it holds a source. Every particle within
    ``reach`` of a source is kept (and some up to ~2 sqrt(D) reach away): a superset, so culling with it is
    exact. With any NaN/Inf position every particle is kept, so a diverged rollout still fails in the
    neighbour search, where :mod:`gnsx.training.run` reports it.

    Args:
        position: ``[N, D]`` (data units).
        sources: ``[N]`` bool.
        reach: distance (data units), > 0; ``M * R`` for M message-passing steps at radius R.
        batch: ``[N]`` graph id per particle, or None.
    Returns:
        ``[N]`` bool.
    """
    if not bool(sources.any()):
        return sources.clone()
    points = position.detach().double()
    if not bool(torch.isfinite(points).all()):  # a diverged rollout: keep all, the neighbour search says so
        return torch.ones_like(sources)
    side = reach * _CELL_MARGIN
    # Cells counted from the lowest particle (translation invariant), starting at 1 so that the -1 and +1
    # neighbours stay inside a padded grid and a key never wraps into the next row.
    cell = torch.floor((points - points.min(dim=0).values) / side).long() + 1  # [N, D]
    graph = torch.zeros_like(cell[:, 0]) if batch is None else batch.long()
    extents = [int(graph.max()) + 1] + (cell.max(dim=0).values + 2).tolist()
    if float(torch.tensor(extents, dtype=torch.float64).prod()) >= 2.0**62:  # int64 keys would overflow
        return torch.ones_like(sources)
    strides = [1] * len(extents)
    for d in range(len(extents) - 2, -1, -1):
        strides[d] = strides[d + 1] * extents[d + 1]
    stride = torch.tensor(strides, device=cell.device)
    key = (torch.cat([graph[:, None], cell], dim=1) * stride).sum(dim=1)  # [N]
    dim = cell.shape[1]
    offsets = torch.tensor(list(itertools.product((-1, 0, 1), repeat=dim)), device=cell.device)  # [3^D, D]
    shifts = (offsets * stride[1:]).sum(dim=1)  # graph offset 0: neighbours stay in their graph
    near = (torch.unique(key[sources])[:, None] + shifts[None, :]).flatten()
    return torch.isin(key, near) | sources
