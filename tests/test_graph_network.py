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


@pytest.mark.parametrize("hidden_layers,residual", [(1, False), (2, True)])
def test_fast_layer_matches_reference_forward_and_backward(hidden_layers, residual):
    """The split first layers and index_add_ aggregation compute the equations, gradients included."""
    from reference_gns import incidence

    x, edge_index, edge_attr = random_graph(num_nodes=50, num_edges=400, latent=32, seed=3)
    x.requires_grad_(True)
    layer = InteractionNetwork(32, 48, hidden_layers, edge_residual=residual)
    senders, receivers = edge_index

    def reference(x):
        messages = layer.edge_mlp(torch.cat([edge_attr, x[receivers], x[senders]], dim=1))
        aggregated = incidence(edge_index, x.shape[0], x.dtype) @ messages
        new_e = edge_attr + messages if residual else messages
        return x + layer.node_mlp(torch.cat([aggregated, x], dim=1)), new_e

    outputs = [layer(x, edge_index, edge_attr), reference(x)]
    for got, want in zip(*outputs):
        assert torch.allclose(got, want, atol=1e-5)
    grads = []
    for new_x, new_e in outputs:
        layer.zero_grad()
        x.grad = None
        (new_x.square().sum() + new_e.sin().sum()).backward()
        grads.append([x.grad.clone()] + [p.grad.clone() for p in layer.parameters()])
    for got, want in zip(*grads):
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-4)


def test_messages_flow_from_sender_to_receiver():
    # One edge 0 -> 1: node 1 changes with node 0's latent, node 0 (no incoming edge) only via its own MLP.
    # Seeded: with 8 hidden units an unlucky draw (the RNG state earlier tests leave) can make every ReLU of
    # the message dead, and then node 1 cannot change.
    torch.manual_seed(0)
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


def _waterramps_like_graph(simulator, num_particles=300, seed=0):
    """Node/edge inputs of ``simulator`` for a jittered block of water with a row of static particles."""
    from gnsx.perf.benchmark import packed_scene

    sequence, particle_type = packed_scene(
        num_particles, 0.009, simulator.config["bounds"], simulator.history, seed=seed
    )
    sequence = sequence + 1e-3 * torch.randn(sequence.shape, generator=torch.Generator().manual_seed(seed))
    node_features, edge_index, edge_attr = simulator.build_graph(sequence, particle_type)
    # Detached: the type embedding's graph would otherwise be shared by the two backward passes.
    return node_features.detach(), edge_index, edge_attr


@pytest.mark.parametrize("name", ["simplified", "original"])
def test_fast_network_matches_reference_on_both_configs(name):
    """Random weights: the whole encode-process-decode forward and its parameter gradients."""
    from reference_gns import reference_forward

    from gnsx.perf.benchmark import build_model

    torch.manual_seed(0)
    simulator = build_model(name)
    node_features, edge_index, edge_attr = _waterramps_like_graph(simulator)
    outputs = [
        simulator.network(node_features, edge_index, edge_attr),
        reference_forward(simulator.network, node_features, edge_index, edge_attr),
    ]
    assert torch.allclose(outputs[0], outputs[1], rtol=1e-4, atol=1e-4)
    grads = []
    for out in outputs:
        simulator.zero_grad()
        out.square().sum().backward()
        grads.append([p.grad.clone() for p in simulator.network.parameters()])
    for got, want in zip(*grads):
        assert torch.allclose(got, want, rtol=1e-3, atol=1e-3 * float(want.abs().max()))


def test_fast_network_matches_reference_with_shipped_weights():
    """Trained weights (pretrained/small): same predictions as the reference transcription."""
    from pathlib import Path

    from reference_gns import reference_forward

    from gnsx.model.checkpoint import load_simulator

    path = Path(__file__).resolve().parents[1] / "pretrained" / "small" / "model.ckpt"
    simulator = load_simulator(path)
    node_features, edge_index, edge_attr = _waterramps_like_graph(simulator, num_particles=400, seed=1)
    with torch.no_grad():
        fast = simulator.network(node_features, edge_index, edge_attr)
        reference = reference_forward(simulator.network, node_features, edge_index, edge_attr)
    assert torch.allclose(fast, reference, rtol=1e-4, atol=1e-4 * float(reference.abs().max()))


@pytest.mark.parametrize("name", ["simplified", "simplified_pairwise", "original"])
def test_culled_network_matches_reference_on_decoded_rows(name):
    """Exact culling (decode=mask) is an option of the fast path: its decoded rows are the reference's."""
    from reference_gns import reference_forward

    from gnsx.model.culling import plan_culling
    from gnsx.perf.benchmark import build_model

    torch.manual_seed(0)
    simulator = build_model(name)
    node_features, edge_index, edge_attr = _waterramps_like_graph(simulator)
    decode = torch.rand(len(node_features), generator=torch.Generator().manual_seed(4)) < 0.05
    with torch.no_grad():
        culled = simulator.network(node_features, edge_index, edge_attr, decode=decode)
        reference = reference_forward(simulator.network, node_features, edge_index, edge_attr)
    assert torch.allclose(culled[decode], reference[decode], rtol=1e-4, atol=1e-4)
    assert (culled[~decode] == 0).all()
    assert plan_culling(edge_index, decode, simulator.config["mp_steps"]).work()["edge_updates"] < 0.9


def _decoded_loss_gradients(network, node_features, edge_index, edge_attr, decode, mode):
    """Parameter gradients of a loss on the decoded rows, from the fast path (``mode`` "culled" or "full")
    or the reference transcription ("reference")."""
    from reference_gns import reference_forward

    network.zero_grad()
    if mode == "reference":
        out = reference_forward(network, node_features, edge_index, edge_attr)
    else:
        out = network(node_features, edge_index, edge_attr, decode=decode if mode == "culled" else None)
    out[decode].square().sum().backward()
    return [p.grad.clone() for p in network.parameters() if p.grad is not None]


@pytest.mark.parametrize("name", ["simplified", "simplified_pairwise", "original", "shipped"])
def test_culled_gradients_match_reference(name):
    """Backward of the culled fast path (segment sums over receiver-sorted prefixes, gather_sum) equals
    autograd of the reference, random weights of both configs and the shipped weights."""
    from pathlib import Path

    from gnsx.model.checkpoint import load_simulator
    from gnsx.perf.benchmark import build_model

    torch.manual_seed(0)
    if name == "shipped":
        shipped = Path(__file__).resolve().parents[1] / "pretrained" / "small" / "model.ckpt"
        simulator = load_simulator(shipped)
    else:
        simulator = build_model(name)
    node_features, edge_index, edge_attr = _waterramps_like_graph(simulator, num_particles=120, seed=2)
    decode = torch.rand(len(node_features), generator=torch.Generator().manual_seed(5)) < 0.2
    got, want = (
        _decoded_loss_gradients(simulator.network, node_features, edge_index, edge_attr, decode, mode)
        for mode in ("culled", "reference")
    )
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert torch.allclose(g, w, rtol=1e-3, atol=1e-3 * float(w.abs().max()) + 1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["simplified", "original"])
def test_compiled_network_matches_eager(name):
    """``compile=True`` (torch.compile of the blocks) changes speed only: same rollout frame, same training
    gradients (to the rounding the reference test allows: ReLU kinks amplify it in 10 residual steps),
    culled and not, on two graph sizes (dynamic shapes)."""
    from gnsx.perf.benchmark import build_model

    torch.manual_seed(0)
    eager = build_model(name)
    compiled = build_model(name, compile=True)
    compiled.load_state_dict(eager.state_dict())
    assert compiled.config["compile"] and list(compiled.state_dict()) == list(eager.state_dict())
    for num_particles, cull in ((200, True), (260, False)):
        graph = _waterramps_like_graph(eager, num_particles=num_particles, seed=num_particles)
        decode = torch.rand(len(graph[0]), generator=torch.Generator().manual_seed(6)) < 0.5
        mode = "culled" if cull else "full"
        with torch.inference_mode():
            torch.testing.assert_close(
                compiled.network(*graph, decode=decode if cull else None),
                eager.network(*graph, decode=decode if cull else None),
                rtol=1e-4,
                atol=1e-5,
            )
        got, want = (_decoded_loss_gradients(sim.network, *graph, decode, mode) for sim in (compiled, eager))
        for g, w in zip(got, want):
            assert torch.allclose(g, w, rtol=1e-3, atol=1e-3 * float(w.abs().max()) + 1e-9)
