"""Exact culling (gnsx.model.culling) gives the full graph's predictions (freezing, its approximate cousin in
the rules layer: tests/test_freezing.py).

Tolerance of "identical": normalised accelerations of dynamic particles agree to ``rtol = atol = 1e-5``
(values are O(1); observed differences are 0 to ~1e-7, the rounding of matrix products over fewer rows), next
positions to ``atol = 1e-7`` data units (positions ~0.5 have a float32 spacing of 6e-8, so at most one or two
roundings apart), parameter gradients of the dynamic-particle loss to ``rtol = 1e-4`` and ``atol = 1e-6`` of
the largest gradient.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.model import EncodeProcessDecode, LearnedSimulator, rollout
from gnsx.model.culling import hop_distance, particles_in_reach, plan_culling
from gnsx.model.training_targets import noisy_training_pair
from gnsx.perf.benchmark import MODELS

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "pretrained" / "small" / "model.ckpt"
#: The small preset's facts (the shipped weights' data): walls, radius, statistics of the same order.
SMALL = dict(
    dim=2,
    bounds=[[0.1, 0.9], [0.1, 0.9]],
    radius=0.035,
    vel_mean=[1e-5, -1e-3],
    vel_std=[3e-3, 3e-3],
    acc_mean=[0.0, -2e-5],
    acc_std=[2e-4, 2e-4],
)
ACCELERATION_TOLERANCE = dict(rtol=1e-5, atol=1e-5)
POSITION_TOLERANCE = dict(rtol=0.0, atol=1e-7)


def make(name: str, seed: int = 0, **overrides) -> LearnedSimulator:
    """Random weights, simplified (LearnedSimulator's defaults) or original (conf/model/original.yaml)."""
    torch.manual_seed(seed)
    return LearnedSimulator(**{**SMALL, **MODELS[name], **overrides}).eval()


@pytest.fixture(scope="module")
def shipped() -> LearnedSimulator:
    from gnsx.model.checkpoint import load_simulator

    return load_simulator(SHIPPED)


def window_of(position: torch.Tensor, velocity: torch.Tensor, history: int) -> torch.Tensor:
    """``[N, history + 1, D]`` frames at constant per-frame velocity ending at ``position``."""
    back = torch.arange(history, -1, -1, dtype=position.dtype)[None, :, None]
    return position[:, None] - back * velocity[:, None]


def random_scene(num_water=150, num_static=120, seed=0, history=1, spread=0.25):
    """Water in a corner, static particles scattered over the whole box (many out of reach)."""
    g = torch.Generator().manual_seed(seed)
    water = 0.12 + spread * torch.rand(num_water, 2, generator=g)
    static = 0.1 + 0.8 * torch.rand(num_static, 2, generator=g)
    position = torch.cat([water, static])
    velocity = torch.cat([3e-3 * torch.randn(num_water, 2, generator=g), torch.zeros(num_static, 2)])
    types = torch.cat(
        [torch.full((num_water,), WATER_PARTICLE_ID), torch.full((num_static,), KINEMATIC_PARTICLE_ID)]
    )
    # Shuffled, so that dynamic and static rows interleave.
    order = torch.randperm(len(types), generator=g)
    return window_of(position[order], velocity[order], history), types[order]


def floor_scene(history=1, water_rows=6, floor_rows=12, spacing=0.0156, container=False):
    """A big static floor of particles (optionally with static side walls: a container) and water on top."""
    xs = torch.arange(0.1, 0.9, spacing)
    floor = torch.cartesian_prod(xs, 0.1 + spacing * torch.arange(floor_rows)).float()
    parts = [floor]
    top = 0.1 + spacing * floor_rows
    if container:
        ys = top + spacing * torch.arange(water_rows + 4)
        for x0 in (0.3, 0.6):
            parts.append(torch.cartesian_prod(x0 + spacing * torch.arange(3), ys).float())
    static = torch.cat(parts)
    water = torch.cartesian_prod(0.35 + spacing * torch.arange(14), top + spacing * torch.arange(water_rows))
    g = torch.Generator().manual_seed(1)
    water = water.float() + 0.2 * spacing * torch.rand(water.shape, generator=g)
    velocity = torch.cat([1e-3 * torch.randn(water.shape, generator=g), torch.zeros_like(static)])
    types = torch.cat(
        [torch.full((len(water),), WATER_PARTICLE_ID), torch.full((len(static),), KINEMATIC_PARTICLE_ID)]
    )
    return window_of(torch.cat([water, static]), velocity, history), types


def culled_and_full(simulator: LearnedSimulator, window, types, batch=None):
    """``(forward, predict_positions)`` with culling and without, restoring the switch."""
    was = simulator.cull
    out = []
    with torch.no_grad():
        for cull in (True, False):
            simulator.cull = cull
            out.append((simulator(window, types, batch), simulator.predict_positions(window, types, batch)))
    simulator.cull = was
    return out


def assert_same_predictions(simulator, window, types, batch=None):
    (acc_cull, pos_cull), (acc_full, pos_full) = culled_and_full(simulator, window, types, batch)
    dynamic = types != KINEMATIC_PARTICLE_ID
    torch.testing.assert_close(acc_cull[dynamic], acc_full[dynamic], **ACCELERATION_TOLERANCE)
    assert (acc_cull[~dynamic] == 0).all()  # static rows are not computed
    torch.testing.assert_close(pos_cull, pos_full, **POSITION_TOLERANCE)
    assert torch.equal(pos_cull[~dynamic], window[~dynamic, -1])


def work_kept(simulator, window, types, batch=None) -> dict[str, float]:
    """The culling plan's kept fractions on the full graph (what :func:`plan_culling` leaves)."""
    _, edge_index, _ = simulator.build_graph(window, types, batch)
    return plan_culling(edge_index, types != KINEMATIC_PARTICLE_ID, simulator.config["mp_steps"]).work()


# ------------------------------------------------------------------------------------------------ plan


def test_hop_distance_follows_messages_backwards():
    # Chain 0 -> 1 -> 2 -> 3 -> 4 (sender -> receiver) plus 5 -> 5 (self loop) and 6 isolated.
    edge_index = torch.tensor([[0, 1, 2, 3, 5], [1, 2, 3, 4, 5]])
    sources = torch.zeros(7, dtype=torch.bool)
    sources[4] = True
    assert hop_distance(edge_index, sources, 3).tolist() == [4, 3, 2, 1, 0, 4, 4]
    assert hop_distance(edge_index, sources, 10).tolist() == [4, 3, 2, 1, 0, 11, 11]
    sources[:] = False
    sources[0] = True  # nothing sends to node 0
    assert hop_distance(edge_index, sources, 3).tolist() == [0, 4, 4, 4, 4, 4, 4]


@pytest.mark.parametrize("steps", [1, 3, 5])
def test_plan_prefixes_are_the_hop_sets(steps):
    g = torch.Generator().manual_seed(steps)
    num_nodes = 60
    edge_index = torch.randint(0, num_nodes, (2, 150), generator=g)  # directed, duplicates, self loops
    decode = torch.rand(num_nodes, generator=g) < 0.1
    plan = plan_culling(edge_index, decode, steps)
    distance = hop_distance(edge_index, decode, steps)
    assert set(plan.nodes[: plan.num_decoded].tolist()) == set(torch.nonzero(decode).flatten().tolist())
    for r in range(steps + 1):
        within = set(torch.nonzero(distance <= r).flatten().tolist())
        assert set(plan.nodes[: plan.node_counts[r]].tolist()) == within
        if r < steps:
            into = {e for e in range(edge_index.shape[1]) if int(edge_index[1, e]) in within}
            assert set(plan.edges[: plan.edge_counts[r]].tolist()) == into
    # Renumbered edges point at the same nodes, and are receiver-sorted.
    assert torch.equal(plan.nodes[plan.edge_index], edge_index[:, plan.edges])
    assert bool((plan.edge_index[1].diff() >= 0).all())


def test_particles_in_reach_is_a_superset_that_keeps_graphs_apart():
    g = torch.Generator().manual_seed(0)
    position = torch.rand(400, 2, generator=g)
    sources = torch.zeros(400, dtype=torch.bool)
    sources[:5] = True
    reach = 0.1
    keep = particles_in_reach(position, sources, reach)
    distance = torch.cdist(position.double(), position[:5].double()).min(dim=1).values
    assert bool(keep[distance <= reach].all()) and bool(keep[sources].all())
    assert not bool(keep[distance > 3 * reach].any())  # cells of side ~reach: nothing far is kept
    assert 0 < int(keep.sum()) < 400
    # Same positions, but the sources belong to graph 0 and the rest to graph 1: nothing else is in reach.
    batch = (~sources).long()
    assert torch.equal(particles_in_reach(position, sources, reach, batch), sources)
    assert not bool(particles_in_reach(position, torch.zeros_like(sources), reach).any())
    broken = position.clone()
    broken[7] = float("nan")  # a diverged rollout: keep everything, the neighbour search reports it
    assert bool(particles_in_reach(broken, sources, reach).all())


# ------------------------------------------------------------------------------------------------ network


@pytest.mark.parametrize(
    "hidden_layers,residual,layer_norm", [(1, False, True), (2, True, True), (1, True, False)]
)
def test_network_decoded_rows_and_gradients_equal_the_full_graph(hidden_layers, residual, layer_norm):
    torch.manual_seed(1)
    network = EncodeProcessDecode(
        7, 3, 16, 4, 24, hidden_layers, 2, edge_residual=residual, layer_norm=layer_norm
    )
    g = torch.Generator().manual_seed(2)
    num_nodes = 80
    x = torch.randn(num_nodes, 7, generator=g)
    pairs = torch.randint(0, num_nodes, (2, 200), generator=g)
    edge_index = torch.cat([pairs, pairs.flip(0), torch.arange(num_nodes).repeat(2, 1)], dim=1)
    order = torch.argsort(edge_index[1], stable=True)
    edge_index = edge_index[:, order]
    edge_attr = torch.randn(edge_index.shape[1], 3, generator=g)
    decode = torch.rand(num_nodes, generator=g) < 0.15
    culled = network(x, edge_index, edge_attr, decode=decode)
    full = network(x, edge_index, edge_attr)
    torch.testing.assert_close(culled[decode], full[decode], **ACCELERATION_TOLERANCE)
    assert (culled[~decode] == 0).all()
    grads = []
    for out in (culled, full):
        network.zero_grad()
        out[decode].square().sum().backward(retain_graph=True)
        grads.append(torch.cat([p.grad.flatten() for p in network.parameters()]))
    scale = float(grads[1].abs().max())
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-4, atol=1e-6 * scale)
    # The plan left work out: otherwise this test would not exercise culling.
    assert plan_culling(edge_index, decode, 4).work()["edge_updates"] < 0.9


# ------------------------------------------------------------------------------------------------ simulator


@pytest.mark.parametrize("name", ["simplified", "original"])
@pytest.mark.parametrize("seed", [0, 1])
def test_random_scenes_random_weights(name, seed):
    simulator = make(name, seed)
    window, types = random_scene(seed=seed, history=simulator.history)
    assert_same_predictions(simulator, window, types)
    assert work_kept(simulator, window, types)["node_updates"] < 0.9


@pytest.mark.parametrize("scene_file", sorted((ROOT / "scenes").glob("*.yaml")), ids=lambda p: p.stem)
def test_example_scenes_with_the_shipped_and_random_weights(scene_file, shipped):
    from gnsx.evaluation.scene_rollout import load_scene
    from gnsx.mpm.generate import initial_state
    from gnsx.mpm.presets import get_preset

    preset = get_preset("small")
    position, velocity, types = initial_state(load_scene(scene_file), preset)
    position, types = torch.from_numpy(position), torch.from_numpy(types)
    per_frame = torch.from_numpy(velocity) * preset.frame_dt
    for simulator in (shipped, make("simplified"), make("original")):
        window = window_of(position, per_frame, simulator.history)
        assert_same_predictions(simulator, window, types)
    # A few rollout steps feed culled predictions back: still the same trajectory.
    window = window_of(position, per_frame, shipped.history)
    frames = []
    for cull in (True, False):
        shipped.cull = cull
        frames.append(rollout(shipped, window, types, num_steps=3))
    shipped.cull = True
    torch.testing.assert_close(frames[0], frames[1], rtol=0.0, atol=1e-6)


@pytest.mark.parametrize("name", ["simplified", "original"])
def test_big_static_floor_and_container_cull_most_of_the_work(name):
    simulator = make(name)
    for container in (False, True):
        window, types = floor_scene(simulator.history, container=container)
        assert_same_predictions(simulator, window, types)
        kept = work_kept(simulator, window, types)
        assert kept["node_updates"] < 0.6 and kept["nodes"] < 1.0, kept


@pytest.mark.parametrize("name", ["simplified", "original"])
def test_hard_cases(name):
    simulator = make(name)
    frames = simulator.history + 1
    # Particles exactly on the walls and corners (walls at 0.1 and 0.9), static ones among them.
    on_walls = torch.tensor([[0.1, 0.1], [0.9, 0.9], [0.1, 0.5], [0.5, 0.9], [0.11, 0.1], [0.9, 0.12]])
    types = torch.tensor([WATER_PARTICLE_ID, WATER_PARTICLE_ID, KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID,
                          KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID])  # fmt: skip
    assert_same_predictions(
        simulator, window_of(on_walls, torch.zeros_like(on_walls), simulator.history), types
    )
    # One particle, dynamic or static.
    one = torch.full((1, frames, 2), 0.5)
    assert_same_predictions(simulator, one, torch.tensor([WATER_PARTICLE_ID]))
    assert_same_predictions(simulator, one, torch.tensor([KINEMATIC_PARTICLE_ID]))
    # Statics only: nothing is computed, an all-zero acceleration, positions held.
    window, types = random_scene(num_water=0, num_static=50, history=simulator.history)
    with torch.no_grad():
        assert torch.equal(simulator(window, types), torch.zeros(50, 2))
        assert torch.equal(simulator.predict_positions(window, types), window[:, -1])
    # Empty scene.
    empty = torch.zeros(0, frames, 2)
    with torch.no_grad():
        assert simulator(empty, torch.zeros(0, dtype=torch.long)).shape == (0, 2)


def test_batched_graphs_cull_each_graph_on_its_own():
    simulator = make("simplified")
    first, types_a = random_scene(seed=3)
    second, types_b = floor_scene()  # overlapping in space with the first
    window, types = torch.cat([first, second]), torch.cat([types_a, types_b])
    batch = torch.cat([torch.zeros(len(types_a)), torch.ones(len(types_b))]).long()
    assert_same_predictions(simulator, window, types, batch)
    with torch.no_grad():
        joint = simulator(window, types, batch)
        torch.testing.assert_close(joint[: len(types_a)], simulator(first, types_a), rtol=1e-5, atol=1e-5)
    # Graph 1's floor far below graph 0's water is not kept because of it.
    alone = particles_in_reach(second[:, -1], types_b != KINEMATIC_PARTICLE_ID, simulator.reach)
    together = particles_in_reach(window[:, -1], types != KINEMATIC_PARTICLE_ID, simulator.reach, batch)
    assert torch.equal(together[len(types_a) :], alone)


@pytest.mark.parametrize("name", ["simplified", "original"])
def test_training_loss_and_gradients_are_the_same(name):
    """The training loss counts dynamic particles only (gnsx.training.system), so culling is exact for training."""
    from gnsx.training.system import acceleration_loss

    simulator = make(name).train()
    window, types = random_scene(history=simulator.history, seed=4)
    next_position = window[:, -1] + (window[:, -1] - window[:, -2])
    dynamic = types != KINEMATIC_PARTICLE_ID
    results = []
    for cull in (True, False):
        simulator.cull = cull
        simulator.zero_grad()
        predicted, target = noisy_training_pair(
            simulator, window, next_position, types, 3e-4, generator=torch.Generator().manual_seed(5)
        )
        loss = acceleration_loss(predicted[dynamic], target[dynamic])
        loss.backward()
        results.append(
            (
                loss.detach(),
                torch.cat([p.grad.flatten() for p in simulator.parameters() if p.grad is not None]),
            )
        )
    torch.testing.assert_close(results[0][0], results[1][0], rtol=1e-5, atol=0.0)
    scale = float(results[1][1].abs().max())
    torch.testing.assert_close(results[0][1], results[1][1], rtol=1e-4, atol=1e-6 * scale)


def test_the_switch_is_in_the_config():
    simulator = make("simplified", cull=False)
    assert simulator.config["cull"] is False
    rebuilt = LearnedSimulator(**simulator.config)
    assert not rebuilt.cull
    rebuilt.cull = True
    assert rebuilt.config["cull"]
    assert make("simplified").cull  # on by default
    with pytest.raises(TypeError, match="freeze_speed"):  # a rule of the layer above (gnsx.rules.freezing)
        make("simplified", freeze_speed=1e-5)


# ------------------------------------------------------------------------------------------------ benchmark


def test_culling_benchmark_rows_and_table():
    from gnsx.perf.benchmark import CULL_SCENES, compare_culling, cull_scene, format_culling

    for name in CULL_SCENES:
        window, types, bounds = cull_scene(name, scale=0.2)
        assert window.shape == (len(types), 2, 2) and bounds[0][1] > bounds[0][0]
        inside = (window[:, -1] >= bounds[0][0] - 0.05) & (window[:, -1] <= bounds[0][1] + 0.05)
        assert bool(inside.all()), name
    rows = compare_culling(scenes=["static_floor", "resting_pool"], scales=[0.2], warmup=0, repeats=1,
                           freeze_speed=1e-5)  # fmt: skip
    floor, pool = rows
    assert floor["static_share"] > 0.5 and floor["node_updates_kept"] < 0.5 and floor["edges_kept"] < 0.6
    assert pool["static_share"] == 0 and pool["node_updates_kept"] == 1.0  # nothing static: nothing culled
    assert pool["frozen_share"] > 0.5  # the pool at rest, far from the falling block, is frozen
    table = format_culling(rows)
    assert (
        table.count("\n") == 3
        and "| simplified | static_floor | 0.2x |" in table
        and "full / freeze" in table
    )


def test_freeze_check_against_the_exact_path():
    from gnsx.perf.benchmark import format_freeze, freeze_check

    simulator = make("simplified")
    window, types = floor_scene(simulator.history)
    truth = window[:, -1].expand(4, -1, -1).clone()
    rows = freeze_check(simulator, [("floor", window, types, truth)], freeze_speed=5e-3, emd_every=2)
    row = rows[0]
    assert row["frames"] == 4 and row["frozen_share"] > 0.5 and row["mse_vs_exact"] > 0
    assert "rollout_mse_freeze" in row and simulator.cull  # the model is left as it was
    assert "| floor |" in format_freeze(rows)
