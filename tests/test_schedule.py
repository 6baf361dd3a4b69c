import math

import pytest

from gnsx.schedule import learning_rate, noise_std


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
