"""LearnedSimulator (both configurations), features, noise, integration and rollouts."""

import math

import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.model import LearnedSimulator, physics_free_baseline, random_walk_noise, rollout
from gnsx.model.boundary import Boundary
from gnsx.model.features import edge_features, type_scalar_feature, wall_features
from gnsx.model.training_targets import noisy_training_pair, noisy_training_rollout

# WaterRamps metadata (DeepMind's metadata.json; gnsx.data.waterramps).
METADATA = dict(
    dim=2,
    bounds=[[0.1, 0.9], [0.1, 0.9]],
    radius=0.015,
    vel_mean=[-6.14e-08, -7.43e-04],
    vel_std=[2.24e-03, 2.27e-03],
    acc_mean=[-1.71e-07, -2.14e-07],
    acc_std=[1.68e-04, 1.82e-04],
)
SIMPLIFIED = dict()
ORIGINAL = dict(
    latent_size=128,
    mp_steps=10,
    mlp_hidden_size=128,
    mlp_hidden_layers=2,
    history=5,
    type_encoding="embedding",
    type_embedding_size=16,
    wall_clip=(-1.0, 1.0),
    edge_residual=True,
    self_edges=True,
)
CONFIGS = {"simplified": SIMPLIFIED, "original": ORIGINAL}


def make_simulator(config, seed=0, **overrides):
    torch.manual_seed(seed)
    return LearnedSimulator(**{**METADATA, **config, **overrides})


def scene(num_water=250, num_static=40, frames=6, seed=0, quantum=None):
    """Water block near a wall and a row of static ramp particles: positions [N, frames, 2], types [N]."""
    generator = torch.Generator().manual_seed(seed)
    water = 0.105 + 0.12 * torch.rand(num_water, 2, generator=generator)
    ramp = torch.stack([torch.linspace(0.1, 0.4, num_static), torch.full((num_static,), 0.3)], dim=1)
    start = torch.cat([water, ramp])
    velocity = torch.cat([2e-3 * torch.randn(num_water, 2, generator=generator), torch.zeros(num_static, 2)])
    steps = torch.arange(frames, dtype=torch.float32)[None, :, None]
    acceleration = torch.cat([torch.tensor([[0.0, -1e-4]]).expand(num_water, 2), torch.zeros(num_static, 2)])
    positions = start[:, None] + velocity[:, None] * steps + 0.5 * acceleration[:, None] * steps**2
    if quantum is not None:  # positions on a binary grid: shifts by multiples of it are exact in float32
        positions = torch.round(positions / quantum) * quantum
    types = torch.cat(
        [torch.full((num_water,), WATER_PARTICLE_ID), torch.full((num_static,), KINEMATIC_PARTICLE_ID)]
    )
    return positions, types


def mlp_parameters(in_size, hidden, out, hidden_layers, layer_norm):
    sizes = [in_size] + [hidden] * hidden_layers + [out]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:])) + (2 * out if layer_norm else 0)


@pytest.mark.parametrize("name", CONFIGS)
def test_shapes_and_node_features(name):
    simulator = make_simulator(CONFIGS[name])
    positions, types = scene()
    window = positions[:, -simulator.input_frames :]
    nodes, edge_index, edges = simulator.build_graph(window, types)
    type_size = 16 if name == "original" else 1
    assert nodes.shape == (len(types), simulator.history * 2 + 4 + type_size)
    assert edge_index.shape[0] == 2 and edges.shape == (edge_index.shape[1], 3)
    has_self_edges = bool((edge_index[0] == edge_index[1]).any())
    assert has_self_edges == (name == "original")
    assert simulator(window, types).shape == (len(types), 2)
    assert simulator.predict_positions(window, types).shape == (len(types), 2)
    with pytest.raises(ValueError, match="position_sequence"):
        simulator(positions[:, :1], types)


def test_parameter_counts_match_the_architecture():
    simplified = make_simulator(SIMPLIFIED)
    L = 64
    expected = (
        mlp_parameters(7, L, L, 1, True)  # node encoder: 2 velocity + 4 walls + 1 type
        + mlp_parameters(3, L, L, 1, True)  # edge encoder
        + 5 * (mlp_parameters(3 * L, L, L, 1, True) + mlp_parameters(2 * L, L, L, 1, True))
        + mlp_parameters(L, L, 2, 1, False)
    )
    assert simplified.num_parameters() == expected
    assert 150_000 < expected < 170_000  # the paper's ~160k
    original = make_simulator(ORIGINAL)
    L = 128
    expected = (
        9 * 16  # type embedding
        + mlp_parameters(10 + 4 + 16, L, L, 2, True)
        + mlp_parameters(3, L, L, 2, True)
        + 10 * (mlp_parameters(3 * L, L, L, 2, True) + mlp_parameters(2 * L, L, L, 2, True))
        + mlp_parameters(L, L, 2, 2, False)
    )
    assert original.num_parameters() == expected


def test_feature_values():
    bounds = torch.tensor(METADATA["bounds"])
    position = torch.tensor([[0.1075, 0.5], [0.95, 0.8925]])
    simplified = wall_features(position, bounds, 0.015, (0.0, 1.0))
    original = wall_features(position, bounds, 0.015, (-1.0, 1.0))
    # [lower_x, lower_y, upper_x, upper_y] / R: 0.0075/0.015 = 0.5 from the left wall, far from the others.
    assert torch.allclose(simplified[0], torch.tensor([0.5, 1.0, 1.0, 1.0]))
    assert torch.allclose(simplified[1], torch.tensor([1.0, 1.0, 0.0, 0.5]), atol=1e-5)
    assert torch.allclose(original[1], torch.tensor([1.0, 1.0, -1.0, 0.5]), atol=1e-5)  # outside: negative
    edges = edge_features(torch.tensor([[0.0, 0.0], [0.009, 0.012]]), torch.tensor([[0], [1]]), 0.015)
    assert torch.allclose(edges, torch.tensor([[-0.6, -0.8, 1.0]]))  # (sender - receiver) / R, norm
    assert torch.allclose(
        type_scalar_feature(torch.tensor([0, 5, 8])).squeeze(1), torch.tensor([0, 0.625, 1])
    )


@pytest.mark.parametrize("name", CONFIGS)
def test_translation_invariance(name):
    simulator = make_simulator(CONFIGS[name])
    quantum = 2.0**-16
    positions, types = scene(quantum=quantum)
    window = positions[:, -simulator.input_frames :]
    shift = torch.tensor([0.3125, -0.046875])  # multiples of the quantum: the shift is exact in float32
    bounds = torch.tensor(METADATA["bounds"])
    moved = make_simulator(CONFIGS[name], bounds=(bounds + shift[:, None]).tolist())
    moved.load_state_dict({**simulator.state_dict(), "bounds": moved.bounds})
    expected = simulator(window, types)
    assert torch.allclose(moved(window + shift, types), expected, atol=1e-6)
    # Shifting the particles but not the bounds changes the wall features, hence the prediction.
    assert not torch.allclose(simulator(window + shift * 0.1, types), expected, atol=1e-3)


def test_integrator_round_trip():
    simulator = make_simulator(ORIGINAL)
    positions, types = scene(frames=7)
    window, next_position = positions[:, :6], positions[:, 6]
    target = simulator.normalized_target(next_position, window)
    assert torch.allclose(simulator.integrate(target, window), next_position, atol=1e-6)
    # The water's constant acceleration (0, -1e-4) comes back de-normalised.
    water = types == WATER_PARTICLE_ID
    acceleration = target * simulator.acc_std + simulator.acc_mean
    assert torch.allclose(
        acceleration[water], torch.tensor([0.0, -1e-4]).expand(int(water.sum()), 2), atol=2e-7
    )


def test_random_walk_noise_statistics():
    positions = torch.zeros(20_000, 6, 2)
    types = torch.full((20_000,), WATER_PARTICLE_ID)
    types[:100] = KINEMATIC_PARTICLE_ID
    noise = random_walk_noise(positions, 6.7e-4, types, generator=torch.Generator().manual_seed(0))
    assert noise.shape == positions.shape
    assert (noise[:100] == 0).all()
    assert (noise[:, 0] == 0).all()  # the oldest position is clean
    velocity_noise = noise[100:, 1:] - noise[100:, :-1]
    step_std = (velocity_noise[:, 1:] - velocity_noise[:, :-1]).std()
    assert step_std == pytest.approx(6.7e-4 / math.sqrt(5), rel=0.03)  # 3e-4 per step
    assert velocity_noise[:, -1].std() == pytest.approx(6.7e-4, rel=0.03)  # noise_std is the last velocity's


@pytest.mark.parametrize("name", CONFIGS)
def test_noisy_target_corrects_velocity_noise_only(name):
    simulator = make_simulator(CONFIGS[name])
    positions, types = scene(frames=simulator.input_frames + 1)
    window, next_position = positions[:, :-1], positions[:, -1]
    noise_std = 3e-4
    predicted, target = noisy_training_pair(
        simulator, window, next_position, types, noise_std, generator=torch.Generator().manual_seed(7)
    )
    noise = random_walk_noise(window, noise_std, types, generator=torch.Generator().manual_seed(7))
    noisy = window + noise
    assert torch.allclose(predicted, simulator(noisy, types))
    # DeepMind: p[k+1] + n_last - 2 (p[k] + n_last) + (p[k-1] + n_prev), normalised.
    acceleration = (next_position + noise[:, -1]) - 2 * noisy[:, -1] + noisy[:, -2]
    expected = (acceleration - simulator.acc_mean) / simulator.acc_std
    assert torch.allclose(target, expected, atol=2e-3)  # float32 rounding at positions ~0.2, /acc_std
    clean = simulator.normalized_target(next_position, window)
    velocity_noise = noise[:, -1] - noise[:, -2]
    assert torch.allclose(target, clean - velocity_noise / simulator.acc_std, atol=2e-3)
    if simulator.history == 1:  # the simplified scheme: p~ = p + eps, v~ = v + eps, a~ = a - eps
        assert (noise[:, 0] == 0).all() and torch.equal(velocity_noise, noise[:, -1])
    static = types == KINEMATIC_PARTICLE_ID
    assert torch.equal(target[static], clean[static])


@pytest.mark.parametrize("correction", [0.5, 1.0])
def test_noise_position_correction_leads_the_target_back_to_the_truth(correction):
    simulator = make_simulator(SIMPLIFIED)
    positions, types = scene(frames=simulator.input_frames + 1)
    window, next_position = positions[:, :-1], positions[:, -1]
    pair = lambda c: noisy_training_pair(
        simulator,  # noqa: E731
        window,
        next_position,
        types,
        3e-4,
        generator=torch.Generator().manual_seed(7),
        position_correction=c,
    )
    predicted, deepmind = pair(0.0)
    predicted_c, corrected = pair(correction)
    assert torch.equal(predicted, predicted_c)  # the input is the same; only the target moves
    noise = random_walk_noise(window, 3e-4, types, generator=torch.Generator().manual_seed(7))
    # H = 1: a~ = a - eps - correction * eps; static particles have no noise, so no correction.
    expected = deepmind - correction * noise[:, -1] / simulator.acc_std
    assert torch.allclose(corrected, expected, atol=2e-3)
    if correction == 1.0:  # predicting the target acceleration lands on the true next position
        noisy = window + noise
        acceleration = corrected * simulator.acc_std + simulator.acc_mean
        landed = noisy[:, -1] + (noisy[:, -1] - noisy[:, -2]) + acceleration
        assert torch.allclose(landed, next_position, atol=1e-6)
    with pytest.raises(ValueError, match="position_correction"):
        pair(1.5)


@pytest.mark.parametrize("name", CONFIGS)
def test_pushforward_starts_the_loss_step_where_the_model_got_to(name):
    simulator = make_simulator(CONFIGS[name])
    steps = 2
    positions, types = scene(frames=simulator.input_frames + steps + 1)
    window, next_position = positions[:, :-1], positions[:, -1]
    pair = lambda noise: noisy_training_pair(
        simulator,  # noqa: E731
        window,
        next_position,
        types,
        noise,
        pushforward_steps=steps,
    )
    predicted, target = pair(0.0)
    # By hand: the model's own two steps from the oldest frames, then one step scored against the truth.
    # Without gradient, as in training (so on the same path: the fused CPU kernels where they apply).
    pushed = window[:, : simulator.input_frames]
    for _ in range(steps):
        with torch.no_grad():
            following = simulator.predict_positions(pushed, types)
        pushed = torch.cat([pushed[:, 1:], following.unsqueeze(1)], dim=1)
    assert not torch.equal(pushed[:, -1], window[:, -1])  # the model drifted: the test has something to see
    assert torch.allclose(predicted, simulator(pushed, types))
    # The drift is treated as the noise is: the target keeps the position deviation, undoes the velocity's.
    drift = pushed[:, -1] - window[:, -1]
    assert torch.allclose(target, simulator.normalized_target(next_position + drift, pushed), atol=2e-3)
    static = types == KINEMATIC_PARTICLE_ID
    assert torch.equal(pushed[static, -1], window[static, -1])
    # Only the loss step carries a gradient.
    simulator.zero_grad()
    predicted, target = pair(3e-4)
    assert predicted.requires_grad and not target.requires_grad
    with pytest.raises(ValueError, match="pushforward_steps 1 and unroll_steps 1 needs"):
        noisy_training_pair(simulator, window, next_position, types, 0.0, pushforward_steps=1)


@pytest.mark.parametrize("name", CONFIGS)
def test_unrolled_loss_steps_follow_the_models_own_rollout_with_gradient(name):
    simulator = make_simulator(CONFIGS[name])
    steps = 3
    positions, types = scene(frames=simulator.input_frames + steps)
    window, next_position = positions[:, :-1], positions[:, -1]
    predicted, target = noisy_training_rollout(
        simulator, window, next_position, types, 0.0, unroll_steps=steps
    )
    assert predicted.shape == target.shape == (steps, *next_position.shape)
    # By hand: each step from the model's own positions, scored against the true frame after it, the
    # deviation treated as the noise (its velocity part undone by the target).
    current = window[:, : simulator.input_frames]
    for step in range(steps):
        truth_now, truth_next = (
            positions[:, simulator.input_frames - 1 + step],
            positions[:, simulator.input_frames + step],
        )
        assert torch.allclose(predicted[step], simulator(current, types), atol=1e-5)
        expected = simulator.normalized_target(truth_next + current[:, -1] - truth_now, current)
        assert torch.allclose(target[step], expected, atol=2e-3)
        current = torch.cat([current[:, 1:], simulator.predict_positions(current, types).unsqueeze(1)], dim=1)
    # The first step is the single step of before.
    single = noisy_training_pair(
        simulator, window[:, : simulator.input_frames], positions[:, simulator.input_frames], types, 0.0
    )
    assert torch.allclose(predicted[0], single[0]) and torch.allclose(target[0], single[1])
    # The gradient of a later step reaches the weights through the earlier steps' predictions too: the last
    # step's loss depends on the first step's output.
    first_output = simulator.network.parameters().__next__()
    loss_last = ((predicted[-1] - target[-1]) ** 2).mean()
    (grad,) = torch.autograd.grad(loss_last, first_output, retain_graph=True)
    assert grad.abs().sum() > 0
    with pytest.raises(ValueError, match="unroll_steps 3 needs"):
        noisy_training_rollout(simulator, window[:, :-1], next_position, types, 0.0, unroll_steps=steps)


def test_batched_forward_equals_single_forwards():
    simulator = make_simulator(SIMPLIFIED)
    first, types_a = scene(seed=1, frames=2)
    second, types_b = scene(seed=2, frames=2, num_water=180)  # overlapping in space with the first
    batch = torch.cat([torch.zeros(len(types_a)), torch.ones(len(types_b))]).long()
    joint = simulator(torch.cat([first, second]), torch.cat([types_a, types_b]), batch)
    assert torch.allclose(joint[: len(types_a)], simulator(first, types_a), atol=1e-5)
    assert torch.allclose(joint[len(types_a) :], simulator(second, types_b), atol=1e-5)
    # Without the batch vector the overlapping scenes would interact.
    unbatched = simulator(torch.cat([first, second]), torch.cat([types_a, types_b]))
    assert not torch.allclose(unbatched[: len(types_a)], simulator(first, types_a), atol=1e-3)


def test_rollout_feeds_back_and_holds_static_particles():
    simulator = make_simulator(ORIGINAL)
    positions, types = scene()
    static = types == KINEMATIC_PARTICLE_ID
    boundary = Boundary.from_particles(simulator.bounds, positions[:, -1], types)
    for constrain in (False, True):
        # The boundary alone (no constraints: the rules have their own tests in their layer, gnsx.rules).
        predicted = rollout(simulator, positions, types, num_steps=4, constrain=constrain)
        assert predicted.shape == (4, len(types), 2)
        assert torch.equal(predicted[:, static], positions[static, -1].expand(4, -1, -1))
        # Step by step by hand: a sliding window of the last history + 1 frames.
        window = positions
        for step in range(4):
            next_position = simulator.predict_positions(window, types)
            if constrain:
                next_position = boundary.apply(window[:, -1], next_position, ~static)
            assert torch.allclose(predicted[step], next_position, atol=1e-6)
            window = torch.cat([window[:, 1:], next_position[:, None]], dim=1)
    # Given positions of the static particles are used as they are; the dynamic rows are ignored.
    predicted = rollout(simulator, positions, types, num_steps=4, constrain=False)
    given = torch.rand(4, len(types), 2)
    moved = rollout(simulator, positions, types, num_steps=4, static_positions=given, constrain=False)
    assert torch.equal(moved[:, static], given[:, static])
    assert torch.equal(moved[0, ~static], predicted[0, ~static])
    with pytest.raises(ValueError, match="initial_positions"):
        rollout(simulator, positions[:, :2], types, num_steps=1)


def test_checkpoint_config_rebuilds_the_model():
    simulator = make_simulator(ORIGINAL)
    rebuilt = LearnedSimulator(**simulator.config)
    rebuilt.load_state_dict(simulator.state_dict())
    positions, types = scene()
    assert torch.equal(rebuilt(positions, types), simulator(positions, types))
    with pytest.raises(ValueError, match="vel_std"):
        LearnedSimulator(**{**METADATA, "vel_std": [1.0]})


def test_physics_free_baseline():
    bounds = torch.tensor(METADATA["bounds"])
    gravity = torch.tensor([0.0, -1e-4])
    positions, types = scene(frames=2)
    water = types == WATER_PARTICLE_ID
    predicted = physics_free_baseline(positions, types, 400, gravity, bounds)
    assert predicted.shape == (400, len(types), 2)
    assert torch.equal(predicted[:, ~water], positions[~water, -1].expand(400, -1, -1))
    assert (predicted >= bounds[:, 0] - 1e-7).all() and (predicted <= bounds[:, 1] + 1e-7).all()
    # Away from the walls it is ballistic: p(t) = p + t v + t (t + 1) / 2 g (semi-implicit Euler).
    velocity = positions[:, 1] - positions[:, 0]
    t = torch.arange(1, 4, dtype=torch.float32)[:, None, None]
    ballistic = positions[:, 1] + t * velocity + t * (t + 1) / 2 * gravity
    inside = (ballistic > bounds[:, 0]) & (ballistic < bounds[:, 1])  # [3, N, 2]
    free = water & inside.all(dim=2).all(dim=0)
    assert free.sum() > 100
    assert torch.allclose(predicted[:3, free], ballistic[:, free], atol=1e-6)
    # Particles end up resting on the floor.
    assert torch.allclose(predicted[-1, water, 1], torch.tensor(0.1), atol=1e-6)


def test_a_model_fits_the_data_it_was_trained_on_whatever_its_own_radius():
    """``check_fits`` compares the default radius of the model's training data with the target's: the paper's
    radius (0.0467) on the small preset (0.035) fits it, and neither fits WaterRamps-size data (0.015)."""
    from gnsx.core.errors import CheckpointError
    from gnsx.model.checkpoint import check_fits

    bounds = METADATA["bounds"]
    paper = make_simulator({}, radius=0.0467, data_radius=0.035)
    check_fits(paper, "paper.ckpt", bounds, 0.035, 2, "the small preset")
    with pytest.raises(
        CheckpointError, match=r"radius 0.0467 \(on data of default radius 0.035\).*2.3x apart"
    ):
        check_fits(paper, "paper.ckpt", bounds, 0.015, 2, "preset=waterramps")
    unrecorded = make_simulator({}, radius=0.035)  # no data_radius: its own radius stands for the data's
    with pytest.raises(CheckpointError, match="2.3x apart"):
        check_fits(unrecorded, "old.ckpt", bounds, 0.015, 2, "preset=waterramps")
