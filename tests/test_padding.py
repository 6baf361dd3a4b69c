"""bf16 training on the CPU: the padded graph (gnsx.model.padding) computes what the plain one does, and a
bf16-autocast training pair stays close to the fp32 one, forward and backward."""

import pytest
import torch

from gnsx.model.edge_ops import add_product_, receiver_offsets
from gnsx.model.padding import EDGE_BUCKET, NODE_BUCKET, needs_padding, pad_graph
from gnsx.model.training_targets import noisy_training_pair
from gnsx.perf.benchmark import build_model


def _scene(simulator, num_particles=150, seed=0):
    """Positions ``[N, H + 1, D]``, types ``[N]`` of a jittered block of water beside static particles."""
    from gnsx.perf.benchmark import packed_scene

    sequence, particle_type = packed_scene(
        num_particles, 0.009, simulator.config["bounds"], simulator.history, seed=seed
    )
    generator = torch.Generator().manual_seed(seed)
    return sequence + 1e-3 * torch.randn(sequence.shape, generator=generator), particle_type


def test_pad_graph_sizes_and_order():
    simulator = build_model("simplified_pairwise")
    x, edge_index, edge_attr = simulator.build_graph(*_scene(simulator))
    px, pindex, pattr = pad_graph(x, edge_index, edge_attr)
    assert px.shape[0] % NODE_BUCKET == 0 and px.shape[0] > x.shape[0]
    assert pindex.shape[1] % EDGE_BUCKET == 0 and pindex.shape[1] >= edge_index.shape[1]
    assert pattr.shape == (pindex.shape[1], edge_attr.shape[1])
    assert torch.equal(pindex[:, : edge_index.shape[1]], edge_index) and torch.equal(px[: len(x)], x)
    # Dummy edges join the last dummy node to itself, so no real node hears from them, and the receivers
    # stay sorted (the segment sums keep their fast path).
    assert (pindex[:, edge_index.shape[1] :] == px.shape[0] - 1).all()
    assert receiver_offsets(edge_index[1], len(x)) is not None
    assert receiver_offsets(pindex[1], len(px)) is not None


@pytest.mark.parametrize("name", ["simplified_pairwise", "original"])
def test_padded_network_matches_plain_forward_and_backward(name):
    """fp32, so the comparison is tight: the first N rows and every parameter gradient agree."""
    torch.manual_seed(0)
    simulator = build_model(name)
    x, edge_index, edge_attr = simulator.build_graph(*_scene(simulator))
    x = x.detach()
    results = []
    for padded in (False, True):
        simulator.zero_grad()
        inputs = pad_graph(x, edge_index, edge_attr) if padded else (x, edge_index, edge_attr)
        out = simulator.network(*inputs)[: len(x)]
        out.square().sum().backward()
        results.append((out.detach(), [p.grad.clone() for p in simulator.network.parameters()]))
    (plain, plain_grads), (padded, padded_grads) = results
    assert torch.allclose(plain, padded, rtol=1e-5, atol=1e-5)
    for want, got in zip(plain_grads, padded_grads):
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-4 * float(want.abs().max()) + 1e-9)


def test_padding_only_under_cpu_autocast():
    x = torch.zeros(3)
    assert not needs_padding(x)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert needs_padding(x)


def test_add_product_takes_the_accumulators_dtype():
    generator = torch.Generator().manual_seed(0)
    rows, weight = torch.randn(50, 8, generator=generator), torch.randn(8, 4, generator=generator)
    accumulator = torch.randn(50, 4, generator=generator)
    want = accumulator + rows @ weight
    assert torch.allclose(add_product_(accumulator.clone(), rows, weight), want, atol=1e-5)
    got = add_product_(accumulator.to(torch.bfloat16), rows, weight)  # fp32 operands, bf16 accumulator
    assert got.dtype == torch.bfloat16
    assert torch.allclose(got.float(), want, rtol=0.05, atol=0.05 * float(want.abs().max()))


def test_bf16_training_pair_close_to_fp32():
    """One training pair (no noise) under bf16 autocast against fp32: predictions within a few percent of
    their spread (rms), and the loss gradient points the same way (bf16 keeps 8 bits of mantissa)."""
    torch.manual_seed(0)
    simulator = build_model("simplified_pairwise")
    sequence, particle_type = _scene(simulator, num_particles=200, seed=1)
    next_position = 2 * sequence[:, -1] - sequence[:, -2]
    dynamic = particle_type != 3
    results = []
    for bf16 in (False, True):
        simulator.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            predicted, target = noisy_training_pair(simulator, sequence, next_position, particle_type, 0.0)
            loss = (predicted[dynamic].float() - target[dynamic]).square().mean()
        loss.backward()
        grads = torch.cat([p.grad.flatten() for p in simulator.parameters() if p.grad is not None])
        results.append((predicted.detach().float(), grads))
    (fp32, fp32_grads), (bf16, bf16_grads) = results
    assert torch.isfinite(bf16).all() and torch.isfinite(bf16_grads).all()
    error = float((bf16 - fp32)[dynamic].square().mean().sqrt() / fp32[dynamic].std())
    cosine = float(torch.nn.functional.cosine_similarity(fp32_grads, bf16_grads, dim=0))
    print(f"bf16 vs fp32: prediction error {error:.4f} of the std, gradient cosine {cosine:.5f}")
    assert error < 0.1  # 0.066 measured: the pair decoder's difference A(ij) - A(ji) cancels most digits
    assert cosine > 0.98


def test_auto_precision_follows_the_cpu_flags(tmp_path):
    from gnsx.training.precision import cpu_has_native_bf16, resolve_precision

    zen4, avx2 = tmp_path / "zen4", tmp_path / "avx2"
    zen4.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 avx512f avx512_bf16 avx512_vnni\n")
    avx2.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 fma\n")
    assert cpu_has_native_bf16(zen4) and not cpu_has_native_bf16(avx2)
    assert not cpu_has_native_bf16(tmp_path / "missing")
    assert resolve_precision("auto", "cpu", zen4) == "bf16-mixed"
    assert resolve_precision("auto", "cpu", avx2) == "32-true"
    assert resolve_precision("auto", "gpu", zen4) == "32-true"  # launch-bound there (module docstring)
    assert resolve_precision("32-true", "cpu", zen4) == "32-true"
    assert resolve_precision("bf16-mixed", "cpu", avx2) == "bf16-mixed"  # an explicit choice stands
