"""gather_sum and segment_sum (gnsx.model.edge_ops) against the index_select / index_add_ they replace."""

import pytest
import torch

from gnsx.model.edge_ops import gather_sum, receiver_offsets, segment_sum


def _edges(num_receivers, num_senders, num_edges, sort, seed=0):
    generator = torch.Generator().manual_seed(seed)
    # Receiver 1 gets no edge: an empty segment must sum to 0.
    receivers = torch.randint(0, num_receivers, (num_edges,), generator=generator)
    receivers[receivers == 1] = 0
    senders = torch.randint(0, num_senders, (num_edges,), generator=generator)
    if sort:
        order = torch.argsort(receivers * num_senders + senders)
        receivers, senders = receivers[order], senders[order]
    return receivers, senders


@pytest.mark.parametrize("sort", [True, False])
def test_gather_and_segment_sums_forward_and_backward(sort):
    num_receivers, num_senders, num_edges, width = 17, 23, 300, 8
    receivers, senders = _edges(num_receivers, num_senders, num_edges, sort)
    offsets = receiver_offsets(receivers, num_receivers)
    assert (offsets is not None) == sort
    generator = torch.Generator().manual_seed(1)
    receiver_term = torch.randn(num_receivers, width, generator=generator, dtype=torch.float64)
    sender_term = torch.randn(num_senders, width, generator=generator, dtype=torch.float64)
    rows = torch.randn(num_edges, width, generator=generator, dtype=torch.float64)
    inputs = [t.requires_grad_() for t in (receiver_term, sender_term, rows)]

    def fast(receiver_term, sender_term, rows):
        gathered = gather_sum(receiver_term, sender_term, receivers, senders, offsets)
        return gathered, segment_sum(rows * gathered, receivers, offsets, num_receivers)

    def plain(receiver_term, sender_term, rows):
        gathered = receiver_term[receivers] + sender_term[senders]
        summed = torch.zeros(num_receivers, width, dtype=rows.dtype).index_add(0, receivers, rows * gathered)
        return gathered, summed

    for got, want in zip(fast(*inputs), plain(*inputs)):
        torch.testing.assert_close(got, want)
    assert (fast(*inputs)[1][1] == 0).all()
    # Gradients, by the transposed operations written in edge_ops: float64 gradcheck against finite
    # differences and equality with autograd of the plain formulation.
    assert torch.autograd.gradcheck(lambda *t: fast(*t)[1], inputs)
    assert torch.autograd.gradcheck(lambda *t: fast(*t)[0], inputs[:2] + [inputs[2].detach()])


def test_offsets_serve_every_prefix():
    """Culling: the edges into the first r receivers are a prefix; offsets[: r + 1] is its row pointer."""
    receivers, _ = _edges(12, 12, 200, sort=True, seed=3)
    offsets = receiver_offsets(receivers, 12)
    rows = torch.randn(200, 4, dtype=torch.float64)
    for r in (0, 1, 5, 12):
        count = int(offsets[r])
        got = segment_sum(rows[:count], receivers[:count], offsets, r)
        want = torch.zeros(r, 4, dtype=torch.float64).index_add_(0, receivers[:count], rows[:count])
        torch.testing.assert_close(got, want)


def test_empty_graph():
    receivers = torch.empty(0, dtype=torch.long)
    offsets = receiver_offsets(receivers, 3)
    assert offsets.tolist() == [0, 0, 0, 0]
    assert (segment_sum(torch.empty(0, 5), receivers, offsets, 3) == 0).all()
    assert gather_sum(torch.randn(3, 5), torch.randn(3, 5), receivers, receivers, offsets).shape == (0, 5)
