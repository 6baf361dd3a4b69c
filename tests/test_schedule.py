import math

import pytest

from gnsx.training.schedule import learning_rate, noise_std, warmup_factor


def test_learning_rate_follows_paper_eq8():
    kw = dict(lr_init=1e-4, lr_final=1e-6, decay_start=1_000_000, decay_end=1_500_000)
    assert learning_rate(0, **kw) == 1e-4
    assert learning_rate(1_000_000, **kw) == 1e-4
    assert learning_rate(1_250_000, **kw) == pytest.approx(1e-5, rel=1e-9)  # halfway in log space
    assert learning_rate(1_500_000, **kw) == pytest.approx(1e-6)
    assert learning_rate(1_600_000, **kw) == 1e-6
    # Eq. 8 as a per-step multiplicative update gives the same value.
    step_factor = (1e-6 / 1e-4) ** (1 / 500_000)
    assert learning_rate(1_000_100, **kw) == pytest.approx(1e-4 * step_factor**100, rel=1e-9)


def test_noise_decays_with_lr_to_04x():
    kw = dict(lr_init=1e-4, lr_final=1e-6, decay_start=10, decay_end=20)
    assert noise_std(0, 3e-4, 0.4, **kw) == pytest.approx(3e-4)
    assert noise_std(20, 3e-4, 0.4, **kw) == pytest.approx(1.2e-4)  # the paper's final 0.00012
    assert noise_std(15, 3e-4, 0.4, **kw) == pytest.approx(3e-4 * math.sqrt(0.4))
    assert noise_std(15, 3e-4, 1.0, **kw) == pytest.approx(3e-4)


def test_warmup_ramps_the_learning_rate_linearly_then_leaves_it():
    assert warmup_factor(0, 0) == 1.0
    assert warmup_factor(0, 4) == 0.25
    assert warmup_factor(2, 4) == 0.75
    assert warmup_factor(3, 4) == 1.0
    assert warmup_factor(100, 4) == 1.0


def test_system_optimizer_follows_warmup_times_decay():
    from gnsx.training.system import GNSSystem

    system = GNSSystem(
        model=dict(latent_size=8, mlp_hidden_size=8, mp_steps=1),
        dim=2, bounds=[[0.0, 1.0], [0.0, 1.0]], radius=0.1,
        vel_mean=[0.0, 0.0], vel_std=[1.0, 1.0], acc_mean=[0.0, 0.0], acc_std=[1.0, 1.0],
        lr_init=1e-3, lr_final=1e-5, lr_decay_start=0, lr_decay_end=100, lr_warmup_steps=10,
    )  # fmt: skip
    scheduler = system.configure_optimizers()["lr_scheduler"]["scheduler"]
    lrs = []
    for _ in range(12):
        lrs.append(scheduler.get_last_lr()[0])
        scheduler.optimizer.step()
        scheduler.step()
    kw = dict(lr_init=1e-3, lr_final=1e-5, decay_start=0, decay_end=100)
    for step, lr in enumerate(lrs):
        assert lr == pytest.approx(learning_rate(step, **kw) * min(1.0, (step + 1) / 10), rel=1e-9)
