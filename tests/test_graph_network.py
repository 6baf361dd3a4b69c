"""MLP, InteractionNetwork and EncodeProcessDecode on tiny graphs."""

import pytest
import torch
from torch import nn

from gnsx.model.graph_network import MLP, EncodeProcessDecode, InteractionNetwork


def random_graph(num_nodes=30, num_edges=120, latent=16, seed=0):
    generator = torch.Generator().manual_seed(seed)
    x = torch.randn(num_nodes, latent, generator=generator)
    edge_index = torch.randint(0, num_nodes, (2, num_edges), generator=generator)
    edge_attr = torch.randn(num_edges, latent, generator=generator)
    return x, edge_index, edge_attr


@pytest.mark.parametrize("hidden_layers", [0, 1, 2])
@pytest.mark.parametrize("layer_norm", [False, True])
def test_mlp_structure(hidden_layers, layer_norm):
    mlp = MLP(5, 8, 3, hidden_layers, layer_norm)
    kinds = [type(layer) for layer in mlp]
    expected = [nn.Linear, nn.ReLU] * hidden_layers + [nn.Linear] + ([nn.LayerNorm] if layer_norm else [])
    assert kinds == expected
    x = torch.randn(7, 5)
    assert mlp(x).shape == (7, 3)
    assert torch.allclose(mlp.after_first(mlp.first(x)), mlp(x))


def test_interaction_network_equations():
    """m_ij = phi_e([e_ij, v_i, v_j]); v_i += phi_v([sum_j m_ij, v_i]); e <- m or e + m."""
    x, edge_index, edge_attr = random_graph()
    senders, receivers = edge_index
    for residual in (False, True):
        layer = InteractionNetwork(16, 24, 1, edge_residual=residual, layer_norm=True)
        new_x, new_e = layer(x, edge_index, edge_attr)
        messages = layer.edge_mlp(torch.cat([edge_attr, x[receivers], x[senders]], dim=1))
        aggregated = torch.zeros_like(x).index_add_(0, receivers, messages)
        expected_x = x + layer.node_mlp(torch.cat([aggregated, x], dim=1))
        expected_e = edge_attr + messages if residual else messages
        assert torch.allclose(new_x, expected_x, atol=1e-5)
        assert torch.allclose(new_e, expected_e, atol=1e-5)


def test_split_first_layer_equals_concat():
    x, edge_index, edge_attr = random_graph(num_nodes=50, num_edges=400, latent=32, seed=3)
    split = InteractionNetwork(32, 48, 2, edge_residual=True, split_first_layer=True)
    naive = InteractionNetwork(32, 48, 2, edge_residual=True, split_first_layer=False)
    naive.load_state_dict(split.state_dict())  # same parameters: state_dict compatible
    for got, want in zip(split(x, edge_index, edge_attr), naive(x, edge_index, edge_attr)):
        assert torch.allclose(got, want, atol=1e-5)
    # Gradients agree too (the split path is what trains).
    grads = []
    for layer in (split, naive):
        layer.zero_grad()
        sum(out.square().sum() for out in layer(x, edge_index, edge_attr)).backward()
        grads.append(layer.edge_mlp.first.weight.grad.clone())
    assert torch.allclose(grads[0], grads[1], rtol=1e-4, atol=1e-4)


def test_messages_flow_from_sender_to_receiver():
    # One edge 0 -> 1: node 1 changes with node 0's latent, node 0 (no incoming edge) only via its own MLP.
    layer = InteractionNetwork(4, 8, 1)
    x = torch.randn(2, 4)
    edge_index = torch.tensor([[0], [1]])
    edge_attr = torch.randn(1, 4)
    out, _ = layer(x, edge_index, edge_attr)
    isolated = x[0] + layer.node_mlp(torch.cat([torch.zeros(4), x[0]]))
    assert torch.allclose(out[0], isolated, atol=1e-6)
    x_changed = x.clone()
    x_changed[0] += 1.0
    out_changed, _ = layer(x_changed, edge_index, edge_attr)
    assert not torch.allclose(out_changed[1], out[1])


@pytest.mark.parametrize(
    "config",
    [
        dict(latent_size=64, mp_steps=5, mlp_hidden_size=64, mlp_hidden_layers=1, edge_residual=False),
        dict(latent_size=128, mp_steps=10, mlp_hidden_size=128, mlp_hidden_layers=2, edge_residual=True),
    ],
)
def test_encode_process_decode_shapes(config):
    model = EncodeProcessDecode(node_in=7, edge_in=3, out_size=2, layer_norm=True, **config)
    assert len(model.processor) == config["mp_steps"]
    # Unshared weights: every step has its own parameters.
    assert len({id(step.edge_mlp.first.weight) for step in model.processor}) == config["mp_steps"]
    assert not any(isinstance(layer, nn.LayerNorm) for layer in model.decoder)
    assert isinstance(model.node_encoder[-1], nn.LayerNorm) and isinstance(
        model.edge_encoder[-1], nn.LayerNorm
    )
    x = torch.randn(40, 7)
    edge_index = torch.randint(0, 40, (2, 200))
    out = model(x, edge_index, torch.randn(200, 3))
    assert out.shape == (40, 2) and torch.isfinite(out).all()
