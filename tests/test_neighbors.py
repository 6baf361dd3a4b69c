"""radius_graph: both back ends give the same, correct, deterministic edge set."""

import pytest
import torch

from gnsx.model.neighbors import radius_graph


def brute_force_edges(position, radius, batch=None, self_loops=False):
    """Reference [2, E] (sender, receiver) sorted by receiver then sender, by an all-pairs test."""
    delta = position.double()[None, :, :] - position.double()[:, None, :]  # [receiver, sender, D]
    within = (delta**2).sum(-1) <= radius * radius
    if not self_loops:
        within &= ~torch.eye(len(position), dtype=torch.bool)
    if batch is not None:
        within &= batch[:, None] == batch[None, :]
    receivers, senders = within.nonzero(as_tuple=True)  # row-major: receiver-major, sender ascending
    return torch.stack([senders, receivers])


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("batched", [False, True])
@pytest.mark.parametrize("self_loops", [False, True])
def test_methods_match_brute_force(dim, batched, self_loops):
    generator = torch.Generator().manual_seed(dim * 10 + batched)
    position = torch.rand(400, dim, generator=generator)
    batch = torch.randint(0, 3, (400,), generator=generator) if batched else None
    radius = 0.08 if dim == 2 else 0.15
    expected = brute_force_edges(position, radius, batch, self_loops)
    assert expected.shape[1] > 400  # a non-trivial graph
    for method in ("kdtree", "cell", "auto"):
        edges = radius_graph(position, radius, batch, self_loops=self_loops, method=method)
        assert edges.dtype == torch.long
        assert torch.equal(edges, expected), method


def test_points_exactly_at_radius_are_connected_by_both_methods():
    # A lattice of spacing 0.25 (exact in binary): axis neighbours at exactly the radius, diagonals beyond.
    grid = torch.stack(torch.meshgrid(torch.arange(12.0), torch.arange(9.0), indexing="ij"), -1).reshape(
        -1, 2
    )
    position = 0.25 * grid
    kdtree = radius_graph(position, 0.25, method="kdtree")
    cell = radius_graph(position, 0.25, method="cell")
    assert torch.equal(kdtree, cell)
    assert kdtree.shape[1] == 2 * (11 * 9 + 12 * 8)  # both directions of every axis-aligned pair


def test_no_edges_across_graphs_even_when_overlapping():
    position = torch.rand(200, 2, generator=torch.Generator().manual_seed(1)) * 0.2
    twice = torch.cat([position, position])
    batch = torch.cat([torch.zeros(200, dtype=torch.long), torch.ones(200, dtype=torch.long)])
    single = radius_graph(position, 0.03)
    for method in ("kdtree", "cell"):
        edges = radius_graph(twice, 0.03, batch, method=method)
        assert torch.equal(batch[edges[0]], batch[edges[1]])
        # The batched graph is the single graph twice, the second copy offset by 200 nodes.
        assert torch.equal(edges, torch.cat([single, single + 200], dim=1))


def test_both_directions_sorted_and_self_loop_flag():
    position = torch.rand(300, 2, generator=torch.Generator().manual_seed(2))
    edges = radius_graph(position, 0.1)
    senders, receivers = edges
    assert (senders != receivers).all()
    forward = set(zip(senders.tolist(), receivers.tolist()))
    assert forward == set(zip(receivers.tolist(), senders.tolist()))
    key = receivers * 300 + senders
    assert (key[1:] > key[:-1]).all()  # strictly increasing: receiver-major, no duplicates
    with_loops = radius_graph(position, 0.1, self_loops=True)
    assert with_loops.shape[1] == edges.shape[1] + 300
    assert (with_loops[0] == with_loops[1]).sum() == 300


def test_empty_and_isolated_inputs():
    assert radius_graph(torch.zeros(0, 2), 0.1).shape == (2, 0)
    far_apart = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    for method in ("kdtree", "cell"):
        assert radius_graph(far_apart, 0.5, method=method).shape == (2, 0)
        assert radius_graph(far_apart, 0.5, self_loops=True, method=method).tolist() == [[0, 1], [0, 1]]


def test_bad_arguments_are_named():
    position = torch.rand(10, 2)
    with pytest.raises(ValueError, match="radius"):
        radius_graph(position, 0.0)
    with pytest.raises(ValueError, match="method"):
        radius_graph(position, 0.1, method="octree")
    with pytest.raises(ValueError, match="batch"):
        radius_graph(position, 0.1, batch=torch.zeros(3, dtype=torch.long))


def test_cell_list_refuses_a_grid_too_large_for_int64_keys():
    sparse = torch.tensor([[0.0, 0.0, 0.0], [1e7, 1e7, 1e7]])
    with pytest.raises(ValueError, match="kdtree"):
        radius_graph(sparse, 1e-3, method="cell")
    assert radius_graph(sparse, 1e-3, method="kdtree").shape == (2, 0)
