"""Per-edge gathers and per-receiver sums of the message-passing step, one pass over the E x H tensors each.

Two operations make up everything the graph network does per edge besides its MLPs (docs/speed.md has the
measurements behind every choice here; 2-core CPU, WaterRamps-sized frame, ~16k edges x 64 features):

* :func:`gather_sum` ``out[e] = receiver_term[receivers[e]] + sender_term[senders[e]]``: phi_e's first
  layer applied to the gathered node latents. ``embedding_bag(mode="sum")`` over the stacked table with the
  bag ``(receivers[e], senders[e] + R)`` per edge writes the E x H result once, where two ``index_select``
  and an ``add`` wrote and read it three times (0.53 vs 1.14 ms forward, one thread, H = 64).
* :func:`segment_sum` ``out[i] = sum of rows[e] over the edges e into receiver i``: with receiver-sorted
  edges, the edges into i are the contiguous run ``offsets[i]:offsets[i + 1]``, and ``embedding_bag`` over
  ``arange(E)`` with those offsets reads the rows once, in order, without the scatter of ``index_add_``
  (0.13 vs 0.47 ms forward, one thread). Without offsets (edges in any order) it is ``index_add_``.

Backward passes are written by hand (:class:`torch.autograd.Function`): ``embedding_bag``'s own backward
is 2x slower than the transposed operation, which is a gather for :func:`segment_sum` and one segment sum
plus one scatter for :func:`gather_sum`. Both are exact: every output element is a sum of the same terms as
the plain formulation, in edge order (tests/test_graph_network.py checks forward and backward).
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn.functional import embedding_bag


def add_product_(accumulator: Tensor, rows: Tensor, weight_t: Tensor) -> Tensor:
    """``accumulator += rows @ weight_t`` in place (``[M, H] += [M, K] @ [K, H]``); returns ``accumulator``.

    In-place ops are outside autocast's reach, so under ``bf16-mixed`` training the accumulator (the output
    of an autocast matmul) is bf16 while ``rows`` or the weights may still be fp32: both take the
    accumulator's dtype first. In fp32 the casts are no-ops and this is ``addmm_``.
    """
    if rows.dtype != accumulator.dtype:
        rows = rows.to(accumulator.dtype)
    if weight_t.dtype != accumulator.dtype:
        weight_t = weight_t.to(accumulator.dtype)
    return accumulator.addmm_(rows, weight_t)


def receiver_offsets(receivers: Tensor, num_receivers: int) -> Tensor | None:
    """CSR row pointer ``[num_receivers + 1]`` of receiver-sorted edges, or None when ``receivers`` is not
    sorted (then the sums fall back to ``index_add_``).

    With culling the edges into the first r nodes are a prefix of the edge list, so ``offsets[: r + 1]`` is
    the row pointer of that prefix: one call per graph serves every message-passing step.

    Args:
        receivers: ``[E]`` int64 receiver of each edge, every value below ``num_receivers``.
        num_receivers: R, the number of receiver rows.
    """
    if receivers.numel() > 1 and not bool((receivers[1:] >= receivers[:-1]).all()):
        return None
    offsets = receivers.new_zeros(num_receivers + 1)
    torch.cumsum(torch.bincount(receivers, minlength=num_receivers), dim=0, out=offsets[1:])
    return offsets


def _segment_sum(rows: Tensor, offsets: Tensor | None, receivers: Tensor, num_receivers: int) -> Tensor:
    """``[num_receivers, F]`` sums of ``rows`` ``[E, F]`` per receiver, no autograd."""
    if offsets is None:
        return rows.new_zeros(num_receivers, rows.shape[1]).index_add_(0, receivers, rows)
    edge_ids = torch.arange(rows.shape[0], device=rows.device)
    return embedding_bag(edge_ids, rows, offsets[: num_receivers + 1], mode="sum", include_last_offset=True)


class _SegmentSum(torch.autograd.Function):
    @staticmethod
    def forward(ctx, rows: Tensor, receivers: Tensor, offsets: Tensor | None, num_receivers: int) -> Tensor:
        ctx.save_for_backward(receivers)
        return _segment_sum(rows, offsets, receivers, num_receivers)

    @staticmethod
    def backward(ctx, grad: Tensor):
        (receivers,) = ctx.saved_tensors
        return grad.index_select(0, receivers), None, None, None


class _GatherSum(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx,
        receiver_term: Tensor,
        sender_term: Tensor,
        receivers: Tensor,
        senders: Tensor,
        offsets: Tensor | None,
    ) -> Tensor:
        ctx.save_for_backward(receivers, senders, offsets)
        table = torch.cat([receiver_term, sender_term])  # [R + N, H], small next to E x H
        bags = torch.stack([receivers, senders + receiver_term.shape[0]], dim=1)  # [E, 2]
        ctx.sizes = receiver_term.shape[0], sender_term.shape[0]
        return embedding_bag(bags, table, mode="sum")

    @staticmethod
    def backward(ctx, grad: Tensor):
        receivers, senders, offsets = ctx.saved_tensors
        num_receivers, num_senders = ctx.sizes
        grad_receiver = _segment_sum(grad, offsets, receivers, num_receivers)
        grad_sender = grad.new_zeros(num_senders, grad.shape[1]).index_add_(0, senders, grad)
        return grad_receiver, grad_sender, None, None, None


def gather_sum(
    receiver_term: Tensor, sender_term: Tensor, receivers: Tensor, senders: Tensor, offsets: Tensor | None
) -> Tensor:
    """``[E, H]``: ``receiver_term[receivers] + sender_term[senders]`` in one pass (module docstring).

    Args:
        receiver_term: ``[R, H]``, indexed by ``receivers``.
        sender_term: ``[N, H]``, indexed by ``senders``.
        receivers, senders: ``[E]`` int64.
        offsets: :func:`receiver_offsets` of ``receivers`` (any R' >= R rows of it), or None; used by the
            backward pass only.
    """
    return _GatherSum.apply(receiver_term, sender_term, receivers, senders, offsets)


def segment_sum(rows: Tensor, receivers: Tensor, offsets: Tensor | None, num_receivers: int) -> Tensor:
    """``[num_receivers, F]``: the sum of ``rows`` ``[E, F]`` over each receiver's edges (module docstring).

    Args:
        rows: ``[E, F]`` per-edge values (the messages).
        receivers: ``[E]`` int64, every value below ``num_receivers``.
        offsets: :func:`receiver_offsets` of ``receivers`` (at least ``num_receivers + 1`` entries; the
            first ``num_receivers + 1`` are used), or None for edges in any order.
        num_receivers: rows of the result.
    """
    return _SegmentSum.apply(rows, receivers, offsets, num_receivers)
