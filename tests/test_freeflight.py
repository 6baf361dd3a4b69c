"""Water in free flight falls at g (gnsx/rules/freeflight.py): a cluster that touches nothing and moves as one
body takes the exact free-fall step; one that breaks ranks or comes near a wall or a ramp is the model's."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID, WATER_PARTICLE_ID
from gnsx.core.errors import ConfigError
from gnsx.model.checkpoint import load_simulator
from gnsx.model.rollout import rollout
from gnsx.rules.freeflight import FreeFlight
from gnsx.rules.rollout import rollout_with_rules
from gnsx.rules.rules import Rules
from gnsx.rules.scale import rules_radius

SHIPPED = Path(__file__).resolve().parents[1] / "pretrained" / "small" / "model.ckpt"
GRAVITY = torch.tensor([0.0, -6e-5], dtype=torch.float64)  # per frame^2
RULE = FreeFlight(
    gravity=GRAVITY,
    bounds=torch.tensor([[0.1, 0.9], [0.1, 0.9]], dtype=torch.float64),
    reach=0.07,
    tolerance=3e-5,
    clearance=0.07,
    lookahead=0.0,
)


def block(lower, shape=(5, 4), spacing=0.0156, seed=0):
    """``[n, 2]`` float64 jittered lattice positions with its lower corner at ``lower``."""
    grid = np.stack(np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij"), -1).reshape(-1, 2)
    jitter = np.random.default_rng(seed).uniform(-0.1, 0.1, grid.shape)
    return torch.from_numpy(np.asarray(lower) + (grid + jitter) * spacing)


def window_of(current, velocity):
    return torch.stack([current - velocity, current], dim=1)


def test_a_rigid_free_block_falls_at_g_and_a_block_that_breaks_ranks_is_the_models():
    a, b = block((0.2, 0.5)), block((0.6, 0.5), seed=1)  # 0.3 m apart: two clusters
    current = torch.cat([a, b])
    velocity = torch.cat([torch.tensor([[1e-3, -2e-3]]).expand(len(a), 2), torch.zeros(len(b), 2)]).double()
    velocity[len(a) + 3] += torch.tensor([0.0, 4e-5])  # one particle of b moves off the body's velocity
    types = torch.full((len(current),), WATER_PARTICLE_ID)
    window = window_of(current, velocity)
    model = current + velocity + 1e-6  # whatever the model predicted
    out, free = RULE.apply(window, model, types)
    assert free[: len(a)].all() and not free[len(a) :].any()  # one member out of step frees none of b
    assert torch.allclose(out[: len(a)], current[: len(a)] + velocity[: len(a)] + GRAVITY, rtol=0, atol=1e-15)
    assert torch.equal(out[len(a) :], model[len(a) :])


@pytest.mark.parametrize("where", ["wall", "ramp", "water"])
def test_a_cluster_near_a_wall_a_ramp_or_other_water_is_not_free(where):
    a = block((0.4, 0.5))
    others = {
        "wall": torch.empty(0, 2, dtype=torch.float64),
        "ramp": torch.tensor([[0.45, 0.45]], dtype=torch.float64),  # 0.05 below the block: inside clearance
        "water": torch.tensor([[0.4, 0.45]], dtype=torch.float64),  # within reach of the block: one cluster
    }[where]
    if where == "wall":
        a = a - torch.tensor([0.25, 0.0], dtype=torch.float64)  # lower left corner at x = 0.15 < 0.1 + 0.07
    current = torch.cat([a, others])
    types = torch.full((len(current),), WATER_PARTICLE_ID)
    if where == "ramp":
        types[len(a) :] = KINEMATIC_PARTICLE_ID
    velocity = torch.zeros_like(current)
    velocity[: len(a)] = torch.tensor([0.0, -2e-3])  # the other water (if any) at rest: out of step
    if where == "wall":
        velocity[: len(a)] = torch.tensor([-1e-3, 0.0])  # towards the left wall
    free = RULE.free_particles(window_of(current, velocity), types)
    assert not free.any()
    if where != "water":  # moving away from the wall or the ramp: nothing pushes it
        velocity[: len(a)] = torch.tensor([1e-3, 5e-3]) if where == "wall" else torch.tensor([0.0, 5e-3])
        assert RULE.free_particles(window_of(current, velocity), types)[: len(a)].all()


@pytest.mark.parametrize("obstacle", ["floor", "ramp"])
def test_a_falling_block_stays_free_until_its_next_step_would_bring_it_within_the_clearance(obstacle):
    """Clearance 0.045 with one frame of look-ahead: at 4.06 mm per frame (after gravity) towards the floor
    or a ramp particle below, the block is free while its distance, less that step, is at least 0.045."""
    rule = FreeFlight(GRAVITY, torch.tensor([[0.1, 0.9], [0.1, 0.9]], dtype=torch.float64), 0.07, 3e-5, 0.045)
    surface = 0.1 if obstacle == "floor" else 0.3
    velocity_y = -4e-3
    closing = -velocity_y - float(GRAVITY[1])  # 4.06e-3 per frame
    for gap, expected in ((0.045 + closing + 1e-3, True), (0.045 + closing - 1e-3, False)):
        a = block((0.4, 0.0), shape=(4, 3))
        a[:, 1] += surface + gap - a[:, 1].min()  # lowest particle `gap` above the surface
        others = torch.tensor([[float(a[a[:, 1].argmin(), 0]), surface]], dtype=torch.float64)
        current = a if obstacle == "floor" else torch.cat([a, others])
        types = torch.full((len(current),), WATER_PARTICLE_ID)
        types[len(a) :] = KINEMATIC_PARTICLE_ID
        velocity = torch.zeros_like(current)
        velocity[: len(a), 1] = velocity_y
        free = rule.free_particles(window_of(current, velocity), types)
        assert bool(free[: len(a)].all()) is expected and bool(free[: len(a)].any()) is expected, gap


def test_water_resting_on_the_floor_is_not_free():
    pool = block((0.3, 0.1), shape=(10, 3))  # bottom row at the floor, at rest: gravity pushes it into it
    types = torch.full((len(pool),), WATER_PARTICLE_ID)
    assert not RULE.free_particles(window_of(pool, torch.zeros_like(pool)), types).any()


def test_the_shipped_models_rollout_of_a_block_in_free_flight_is_exact_until_it_nears_the_floor():
    simulator = load_simulator(SHIPPED)
    rule = FreeFlight.for_simulator(simulator)
    radius = rules_radius(simulator)  # the data's (0.035), not the graph's (the paper's 0.047)
    assert rule is not None and rule.reach == pytest.approx(2 * radius)
    assert rule.clearance == pytest.approx(1.3 * radius) and rule.lookahead == 1.0
    current = block((0.4, 0.6), shape=(6, 6)).float()
    velocity = torch.tensor([[0.0, -2e-3]]).expand_as(current)
    types = torch.full((len(current),), WATER_PARTICLE_ID)
    steps = 20  # the block's bottom falls from 0.6 to ~0.55: far above the floor's clearance
    g = rule.gravity.float()
    exact = torch.stack([current + k * velocity + k * (k + 1) / 2 * g for k in range(1, steps + 1)])
    held = rollout_with_rules(simulator, window_of(current, velocity), types, steps, Rules.production())
    without_flight = dataclasses.replace(Rules.production(), free_flight=False)
    model = rollout_with_rules(simulator, window_of(current, velocity), types, steps, without_flight)
    raw = rollout(simulator, window_of(current, velocity), types, steps)  # the default: no rule
    # float32 round-off only (velocities are position differences: ~1e-7 per step, summed over 20 steps)
    assert (held - exact).abs().max() < 2e-5
    assert (model - exact).abs().max() > 1e-4  # the model alone shuffles the block's particles (3.9 mm)
    assert torch.equal(
        raw, rollout_with_rules(simulator, window_of(current, velocity), types, steps, Rules.none())
    )
    assert (raw - exact).abs().max() > 1e-4


def test_rules_read_from_configs_and_from_older_results():
    # Off unless asked: the raw network is the default of every figure (issue: rules are opt-in).
    assert Rules() == Rules.from_mapping(None) == Rules.from_mapping({}) == Rules.none()
    assert not Rules().any() and Rules().label() == "raw"
    assert Rules.production().any() and all(Rules.production().to_dict().values())
    assert Rules.from_mapping({"free_flight": True}) == Rules(free_flight=True)
    with pytest.raises(ConfigError, match=r"evaluate.rules.free_flght: unknown rule"):
        Rules.from_mapping({"free_flght": True}, "evaluate.rules")
    with pytest.raises(ConfigError, match=r"rules.hold_rest=yes: must be true or false"):
        Rules.from_mapping({"hold_rest": "yes"})
    # results.json before the rules block: the two rules of the time at the top level, or nothing at all.
    assert Rules.from_results({}) == Rules.none()
    assert Rules.from_results({"hold_rest": True, "incompressible": True}) == Rules(
        hold_rest=True, incompressible=True
    )
    assert Rules.from_results({"rules": Rules.production().to_dict()}) == Rules.production()
    # A rules block before 2026-12-03 has no level_pool: those rollouts ran without test 4.
    old = {key: value for key, value in Rules.production().to_dict().items() if key != "level_pool"}
    assert Rules.from_results({"rules": old}) == dataclasses.replace(Rules.production(), level_pool=False)


def test_the_rules_take_their_length_from_the_data_not_from_the_models_graph():
    """A model whose graph reaches 0.05 on data of radius 0.035 keeps the MPM's reach (2 x 0.035): with the
    model's radius free flight reached 0.1 and missed most fresh blocks (docs/decisions)."""
    from gnsx.model.simulator import LearnedSimulator
    from gnsx.rules.rest import RestHold

    facts = dict(
        dim=2,
        bounds=[[0.1, 0.9], [0.1, 0.9]],
        vel_mean=[0.0, 0.0],
        vel_std=[1e-3, 1e-3],
        acc_mean=[0.0, -6e-5],
        acc_std=[1e-4, 1e-4],
        decoder="pairwise",
    )
    wide = LearnedSimulator(radius=0.05, data_radius=0.035, **facts)
    assert FreeFlight.for_simulator(wide).reach == pytest.approx(0.07)
    assert RestHold.for_simulator(wide).radius == pytest.approx(0.035)
    # Checkpoints saved before data_radius existed used the data's radius as the model's.
    older = LearnedSimulator(radius=0.035, **facts)
    assert rules_radius(older) == 0.035 and FreeFlight.for_simulator(older).reach == pytest.approx(0.07)
    assert rules_radius(LearnedSimulator(**wide.config)) == 0.035  # travels with the checkpoint's config


def test_the_rules_take_the_datas_gravity_for_either_decoder(tmp_path):
    """Free flight and the rest hold follow the gravity a model records, whichever decoder it has; a
    node-decoder checkpoint trained before gravity was recorded gets it from its data at export."""
    from test_simulator import make_simulator

    from gnsx.rules.rest import RestHold
    from gnsx.rules.scale import rules_gravity
    from gnsx.training.export import record_gravity

    g = [0.0, -9.8 * 0.0025**2]
    for decoder in ("node", "pairwise"):
        simulator = make_simulator({}, decoder=decoder, gravity=g)
        assert rules_gravity(simulator).tolist() == pytest.approx(g, abs=1e-12)
        rule = FreeFlight.for_simulator(simulator)
        assert rule is not None and rule.gravity.tolist() == pytest.approx(g, abs=1e-12)
        hold = RestHold.for_simulator(simulator, acceleration=0.5)
        assert hold.acceleration == pytest.approx(0.5 * 9.8 * 0.0025**2, rel=1e-5)
    unrecorded = make_simulator({}, decoder="node")
    assert rules_gravity(unrecorded) is None and FreeFlight.for_simulator(unrecorded) is None

    path = tmp_path / "model.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": {"model": {"gravity": None}}, "global_step": 3}, path)
    metadata = SHIPPED.parent / "metadata.json"  # the small preset's: dt = 0.0025 s
    assert record_gravity(path, metadata)
    state = torch.load(path, weights_only=False)
    dt = json.loads(metadata.read_text())["dt"]
    assert state["hyper_parameters"]["model"]["gravity"] == pytest.approx([0.0, -9.8 * dt**2])
    assert state["global_step"] == 3
    assert not record_gravity(path, metadata)  # recorded: left as it is
