"""The fused CPU inference kernels (gnsx.model.fused) against the eager path they replace."""

from pathlib import Path

import pytest
import torch
from torch import nn

from gnsx.model import fused
from gnsx.model.graph_network import MLP
from gnsx.perf.benchmark import build_model

pytestmark = pytest.mark.skipif(not fused.load(), reason="no C++ toolchain: the fused kernels are not built")


def _graph(simulator, num_particles=400, seed=0):
    """A WaterRamps-like block of water with a row of static particles: the simulator's network inputs."""
    from gnsx.perf.benchmark import packed_scene

    sequence, particle_type = packed_scene(
        num_particles, 0.009, simulator.config["bounds"], simulator.history, seed=seed
    )
    sequence = sequence + 1e-3 * torch.randn(sequence.shape, generator=torch.Generator().manual_seed(seed))
    return simulator.build_graph(sequence, particle_type)


def _both(monkeypatch, run):
    """``run()`` on the eager path, then on the fused one (the environment switch), under inference_mode."""
    outputs = []
    for mode in ("0", "1"):
        monkeypatch.setenv(fused.ENV, mode)
        with torch.inference_mode():
            outputs.append(run())
    return outputs


def _close(got, want, tolerance=1e-5):
    scale = float(want.abs().max())
    assert torch.allclose(got, want, rtol=tolerance, atol=tolerance * scale), float((got - want).abs().max())


@pytest.mark.parametrize("hidden_layers", [1, 2])
@pytest.mark.parametrize("layer_norm", [False, True])
def test_mlp_matches_eager(monkeypatch, hidden_layers, layer_norm):
    """Every gnsx MLP shape, a first layer of few columns (the edge encoder's 3) and of many, rows not a
    multiple of the tile."""
    torch.manual_seed(hidden_layers)
    for in_size in (3, 40):
        mlp = MLP(in_size, 24, 16, hidden_layers, layer_norm)
        rows = torch.randn(1001, in_size)
        eager, fast = _both(monkeypatch, lambda mlp=mlp, rows=rows: mlp(rows))
        assert fast.shape == (1001, 16)
        _close(fast, eager)


def test_mlp_with_split_first_layer_and_residual(monkeypatch):
    """phi_v's form: the first layer as blocks over [sum_j m_ij, v_i] (strided views), plus v_i."""
    torch.manual_seed(0)
    mlp = MLP(2 * 16, 24, 16, 1, True)
    aggregated, latent = torch.randn(300, 16), torch.randn(300, 16)
    blocks = list(mlp.first.weight.split(16, dim=1))
    with torch.inference_mode():
        fast = fused.mlp(mlp, [aggregated, latent], blocks, residual=latent)
    with torch.no_grad():  # grad mode on would be eager too; here the reference is the plain formula
        eager = latent + nn.Sequential(*mlp)(torch.cat([aggregated, latent], dim=1))
    _close(fast, eager)


def test_layers_are_recognised_only_in_the_shapes_the_kernel_computes():
    assert fused.mlp_layers(MLP(8, 16, 4, 1, True)) is not None
    assert fused.mlp_layers(MLP(8, 16, 4, 2, False))[1] is None
    assert fused.mlp_layers(MLP(8, 16, 4, 0, True)) is None  # no hidden layer: nothing to fuse
    assert fused.mlp_layers(nn.Sequential(nn.Linear(8, 16), nn.Tanh(), nn.Linear(16, 4))) is None
    assert fused.mlp_layers(nn.Sequential(nn.Linear(8, 16), nn.ReLU(), nn.Linear(16, 4, bias=False))) is None


@pytest.mark.parametrize("name", ["simplified", "simplified_pairwise", "original"])
def test_network_matches_eager_on_both_configs(monkeypatch, name):
    """The whole encode-process-decode forward on a WaterRamps-like graph: the edge step (replacement and
    residual edge updates, 2- and 3-layer MLPs), the node update, encoders and decoder."""
    torch.manual_seed(0)
    simulator = build_model(name)
    node_features, edge_index, edge_attr = _graph(simulator)
    eager, fast = _both(monkeypatch, lambda: simulator.network(node_features, edge_index, edge_attr))
    _close(fast, eager, 1e-4)


@pytest.mark.parametrize("name", ["simplified", "original"])
def test_culled_network_matches_eager(monkeypatch, name):
    """Exact culling: each step updates a prefix of the nodes from a prefix of the edges."""
    torch.manual_seed(0)
    simulator = build_model(name)
    node_features, edge_index, edge_attr = _graph(simulator)
    decode = torch.rand(len(node_features), generator=torch.Generator().manual_seed(4)) < 0.05
    eager, fast = _both(monkeypatch, lambda: simulator.network(node_features, edge_index, edge_attr, decode))
    _close(fast, eager, 1e-4)
    assert (fast[~decode] == 0).all()


def test_shipped_weights_roll_out_the_same(monkeypatch):
    """Trained weights, a 20-frame rollout: the two paths stay within float noise of each other (a
    rollout feeds its errors back, so this is looser than one frame but far below the model's error)."""
    from gnsx.model.checkpoint import load_simulator

    path = Path(__file__).resolve().parents[1] / "pretrained" / "small" / "model.ckpt"
    simulator = load_simulator(path)
    from gnsx.perf.benchmark import packed_scene

    sequence, particle_type = packed_scene(400, 0.009, simulator.config["bounds"], simulator.history, seed=2)

    def rollout():
        window = sequence.clone()
        for _ in range(20):
            following = simulator.predict_positions(window, particle_type)
            window = torch.cat([window[:, 1:], following[:, None]], dim=1)
        return window[:, -1]

    eager, fast = _both(monkeypatch, rollout)
    assert float((fast - eager).abs().max()) < 1e-4  # data units; the box is 1 wide, a particle 0.009


def test_training_keeps_the_eager_path(monkeypatch):
    """With autograd on, the kernels (no backward) are never called, and gradients flow."""
    calls = []
    monkeypatch.setattr(fused, "edge_step", lambda *a, **k: calls.append(1))
    monkeypatch.setattr(fused, "mlp", lambda *a, **k: calls.append(1))
    simulator = build_model("simplified")
    node_features, edge_index, edge_attr = _graph(simulator, num_particles=100)
    out = simulator.network(node_features, edge_index, edge_attr)
    out.square().sum().backward()
    assert not calls
    assert simulator.network.processor[0].edge_mlp.first.weight.grad is not None


def test_autocast_keeps_the_eager_path(monkeypatch):
    """bf16-mixed training's pushforward steps run without gradient but under CPU autocast: eager."""
    calls = []
    monkeypatch.setattr(fused, "edge_step", lambda *a, **k: calls.append(1))
    simulator = build_model("simplified")
    node_features, edge_index, edge_attr = _graph(simulator, num_particles=100)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        out = simulator.network(node_features, edge_index, edge_attr)
    assert not calls and torch.isfinite(out).all()


def test_switch_off_keeps_the_eager_path(monkeypatch):
    calls = []
    monkeypatch.setattr(fused, "edge_step", lambda *a, **k: calls.append(1))
    monkeypatch.setenv(fused.ENV, "0")
    simulator = build_model("simplified")
    node_features, edge_index, edge_attr = _graph(simulator, num_particles=100)
    with torch.inference_mode():
        simulator.network(node_features, edge_index, edge_attr)
    assert not calls and not fused.runs(torch.zeros(2, 2))


def test_edge_step_rejects_offsets_that_do_not_cover_the_edges():
    torch.manual_seed(0)
    mlp = MLP(3 * 8, 8, 8, 1, True)
    receivers = torch.tensor([0, 0, 1, 2])
    senders = torch.tensor([1, 2, 0, 0])
    wrong_offsets = torch.tensor([0, 2, 3, 3])  # says 3 edges, there are 4
    terms = torch.randn(3, 8)
    with torch.inference_mode(), pytest.raises(RuntimeError, match=r"offsets\[R\] must equal the edge count"):
        fused.edge_step(mlp, terms, terms, torch.randn(4, 8), senders, receivers, wrong_offsets, False)


def test_bound_counts_the_unsplit_first_layer():
    """The naive count differs from the executed one by phi_e's split: M * 4 L W (E - N); at WaterRamps'
    2,300 particles and 16,286 edges the simplified model's nominal frame is 3.13 GFLOP (docs/speed.md)."""
    from gnsx.perf.bound import nominal_flops
    from gnsx.perf.flops import forward_flops

    config = build_model("simplified").config
    nominal = nominal_flops(config, 2300, 16286)
    executed = forward_flops(config, 2300, 16286)["total"]
    assert nominal - executed == 5 * 4 * 64 * 64 * (16286 - 2300)
    assert round(nominal / 1e9, 2) == 3.13


def test_bound_tool_reports_both_paths(tmp_path):
    """One short round (a figure, not a timing assertion): both paths timed, the bound from the peak."""
    import json

    from gnsx.perf.bound import main

    out = tmp_path / "bound.json"
    threads = torch.get_num_threads()
    try:
        assert main(["--models", "simplified", "--particles", "300", "--rounds", "1", "--frames", "1",
                     "--warmup", "0", "--threads", "1", "--json", str(out)]) == 0  # fmt: skip
    finally:
        torch.set_num_threads(threads)  # the CLI sets the process's thread count
    (row,) = json.loads(out.read_text())
    assert row["eager_ms"] > 0 and row["fused_ms"] > 0 and row["bound_ms"] > 0
    assert row["max_abs_difference"] < 1e-4
    assert row["fused_over_bound"] == pytest.approx(row["fused_ms"] / row["bound_ms"])


def test_a_graph_without_edges(monkeypatch):
    """Particles farther apart than the radius: no edges, every aggregate 0, same output as eager."""
    simulator = build_model("simplified")
    node_features = torch.randn(5, simulator.network.node_encoder.first.in_features)
    edge_index = torch.zeros(2, 0, dtype=torch.long)
    edge_attr = torch.zeros(0, simulator.network.edge_encoder.first.in_features)
    eager, fast = _both(monkeypatch, lambda: simulator.network(node_features, edge_index, edge_attr))
    _close(fast, eager)
