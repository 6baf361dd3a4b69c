"""The momentum-conserving (pairwise) decoder: Newton's third law, free fall at g, the wall gate, culling."""

import pytest
import torch
from test_simulator import METADATA, make_simulator, scene

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.model.features import edge_features, wall_contact_gate
from gnsx.model.training_targets import noisy_training_pair

GRAVITY = [0.0, -9.8 * 0.0025**2]  # per frame^2, WaterRamps' dt
PAIRWISE = dict(decoder="pairwise", gravity=GRAVITY, wall_clip=(0.0, 10.0))


def _randomise(simulator, seed=1):
    """Larger random weights than the default init, so the pair forces are far from 0 and a broken
    antisymmetry would show."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in simulator.parameters():
            parameter.copy_(torch.randn(parameter.shape, generator=generator) * 0.3)
    return simulator


def _cloud(num=80, centre=(0.5, 0.5), spread=0.06, seed=0):
    """Water particles in a disc of radius ``spread`` far from every wall: [N, 2, 2] positions (history 1)."""
    generator = torch.Generator().manual_seed(seed)
    angle = 2 * torch.pi * torch.rand(num, generator=generator)
    radius = spread * torch.rand(num, generator=generator).sqrt()
    start = torch.tensor(centre) + torch.stack([angle.cos(), angle.sin()], 1) * radius[:, None]
    velocity = 2e-3 * torch.randn(num, 2, generator=generator)
    return torch.stack([start - velocity, start], dim=1), torch.full((num,), WATER_PARTICLE_ID)


def _acceleration(simulator, positions, types):
    with torch.no_grad():
        return simulator(positions, types) * simulator.acc_std + simulator.acc_mean  # per frame^2


def test_pair_forces_cancel_so_a_free_cluster_falls_at_g():
    simulator = _randomise(make_simulator({}, **PAIRWISE))
    positions, types = _cloud()
    acceleration = _acceleration(simulator, positions, types)
    # Individual particles are pushed around (the test could not pass by every force being 0) ...
    assert float((acceleration - torch.tensor(GRAVITY)).norm(dim=1).median()) > 1e-5
    # ... but the forces cancel in pairs: the centre of mass falls at g (float32 rounding of 80 sums).
    assert acceleration.mean(0).tolist() == pytest.approx(GRAVITY, abs=1e-9)


def test_the_node_decoder_does_not_conserve_momentum():
    """The same check on the default decoder fails: what the pairwise decoder adds is not automatic."""
    simulator = _randomise(make_simulator({}, wall_clip=(0.0, 10.0)))
    positions, types = _cloud()
    mean = _acceleration(simulator, positions, types).mean(0)
    assert float((mean - torch.tensor(GRAVITY)).norm()) > 1e-6


def test_pair_decoder_matches_a_plain_transcription():
    """f_ij = A([h_i, h_j, x_ij]) - A([h_j, h_i, x_ji]) summed over the edges into i, written edge by edge."""
    simulator = _randomise(make_simulator({}, **PAIRWISE))
    decoder = simulator.network.pair_decoder
    positions, types = _cloud(num=30)
    node_features, edge_index, edge_attr = simulator.build_graph(positions, types)
    latent = torch.randn(30, 64, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        fast = decoder(latent, edge_index, edge_attr, 30, None)
        plain = torch.zeros(30, 2)
        for (sender, receiver), x in zip(edge_index.t().tolist(), edge_attr):
            x_back = torch.cat([-x[:-1], x[-1:]])

            def pair_mlp(first, second, features):
                hidden = torch.relu(decoder.first(torch.cat([first, second, features])))
                return decoder.second(hidden)

            plain[receiver] += pair_mlp(latent[receiver], latent[sender], x) - pair_mlp(
                latent[sender], latent[receiver], x_back
            )
    torch.testing.assert_close(fast, plain, atol=1e-5, rtol=1e-5)


def test_edge_features_of_a_reversed_edge_are_the_swap_the_decoder_assumes():
    positions, _ = _cloud(num=10)
    edge_index = torch.tensor([[0, 3], [3, 0]])  # 0 -> 3 and 3 -> 0
    x = edge_features(positions[:, -1], edge_index, 0.015)
    assert torch.equal(x[1, :2], -x[0, :2]) and torch.equal(x[1, 2], x[0, 2])


def test_wall_force_acts_within_two_radii_only():
    radius = METADATA["radius"]
    bounds = torch.tensor(METADATA["bounds"])
    position = torch.tensor([[0.5, 0.1 + 0.5 * radius], [0.5, 0.1 + 1.5 * radius], [0.5, 0.1 + 2.5 * radius]])
    assert wall_contact_gate(position, bounds, radius).squeeze(1).tolist() == pytest.approx([1.0, 0.5, 0.0])
    # A cloud resting on the floor is pushed by the wall term: its centre of mass no longer falls at g.
    simulator = _randomise(make_simulator({}, **PAIRWISE))
    positions, types = _cloud(centre=(0.5, 0.1 + 0.04), spread=0.04)
    mean = _acceleration(simulator, positions, types).mean(0)
    assert float((mean - torch.tensor(GRAVITY)).norm()) > 1e-6


def test_static_particles_push_water_without_being_pushed():
    simulator = _randomise(make_simulator({}, **PAIRWISE))
    positions, types = _cloud(num=60)
    types[:20] = KINEMATIC_PARTICLE_ID
    with torch.no_grad():
        assert torch.all(simulator(positions, types)[:20] == 0)  # static rows are not computed (culling)
    acceleration = _acceleration(simulator, positions, types)
    # The ramp's pull on the water is an external force: the water's centre of mass does not fall at g.
    assert float((acceleration[20:].mean(0) - torch.tensor(GRAVITY)).norm()) > 1e-6


def test_culled_pairwise_prediction_equals_the_full_graph():
    """Exact culling with one more hop: the decoded particles' neighbours' latents after the last step."""
    simulator = _randomise(make_simulator({}, **PAIRWISE))
    positions, types = scene(num_water=120, num_static=40, frames=2)
    assert simulator.hops == simulator.config["mp_steps"] + 1
    with torch.no_grad():
        culled = simulator(positions, types)
        simulator.cull = False
        full = simulator(positions, types)
    water = types != KINEMATIC_PARTICLE_ID
    torch.testing.assert_close(culled[water], full[water], atol=1e-5, rtol=1e-5)


def test_pairwise_gradients_flow_to_every_parameter():
    simulator = make_simulator({}, **PAIRWISE)
    positions, types = scene(num_water=60, num_static=20, frames=2)
    predicted, target = noisy_training_pair(
        simulator, positions[:, :2], positions[:, 1], types, noise_std=1e-4
    )
    ((predicted - target)[types != KINEMATIC_PARTICLE_ID] ** 2).mean().backward()
    missing = [
        name for name, p in simulator.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0
    ]
    assert missing == []


def test_unknown_decoder_and_bad_gravity_are_refused():
    with pytest.raises(ValueError, match="decoder must be one of"):
        make_simulator({}, decoder="edges")
    with pytest.raises(ValueError, match="gravity must have dim=2 values"):
        make_simulator({}, decoder="pairwise", gravity=[0.0])
