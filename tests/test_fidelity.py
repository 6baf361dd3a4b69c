"""Each config follows the model it names: the original GNS DeepMind's way, the simplified GNS the paper's.

Every test here failed on the code before 2026-12-06 (checked by running this file against that commit):
the original's normalisation was the data's own, the train config's noise decay silently replaced the
model's, the radius was recorded without its source, TF32 was on ("high") on GPU, and there was no DeepMind
LR schedule.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from gnsx.data.metadata import Metadata
from gnsx.training.builders import apply_matmul_precision, build_system
from gnsx.training.model_settings import combine_std, model_summary
from gnsx.training.schedule import learning_rate

ROOT = Path(__file__).resolve().parents[1]


class _Data:
    metadata = Metadata(
        bounds=[[0.1, 0.9], [0.1, 0.9]],
        sequence_length=10,
        default_connectivity_radius=0.035,
        dim=2,
        dt=0.0025,
        vel_mean=[0.0, -7e-4],
        vel_std=[2.2e-3, 2.3e-3],
        acc_mean=[0.0, -2e-7],
        acc_std=[1.7e-4, 1.8e-4],  # WaterRamps' order: far below the original's 6.7e-4 noise
    )


def _compose(*overrides: str):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def test_the_original_normalises_by_stds_widened_by_its_noise_as_deepmind_does():
    meta = _Data.metadata
    original = build_system(_compose("model=original", "train=paper"), _Data()).hparams
    assert original.noise_std == pytest.approx(6.7e-4)
    assert original.acc_std == pytest.approx(combine_std(meta.acc_std, 6.7e-4))
    assert original.vel_std == pytest.approx(combine_std(meta.vel_std, 6.7e-4))
    assert original.acc_std[1] == pytest.approx(math.hypot(1.8e-4, 6.7e-4))  # the noise dominates
    simplified = build_system(_compose("model=simplified", "train=paper"), _Data()).hparams
    assert simplified.acc_std == pytest.approx(meta.acc_std) and simplified.vel_std == pytest.approx(
        meta.vel_std
    )


def test_noise_and_its_decay_come_from_the_model_config_unless_the_train_config_overrides_them(caplog):
    for model, std, decay in (("simplified", 3e-4, 0.4), ("original", 6.7e-4, 1.0)):
        cfg = _compose(f"model={model}", "train=paper")
        system = build_system(cfg, _Data())
        assert (system.hparams.noise_std, system.hparams.noise_decay) == pytest.approx((std, decay)), model
        summary = model_summary(cfg, system)
        assert (
            summary["noise_std_source"] == "model.noise_std"
            and summary["noise_decay_source"] == "model.noise_decay"
        )
    with caplog.at_level(logging.INFO, logger="gnsx"):
        cfg = _compose("model=simplified", "train=demo")
        system = build_system(cfg, _Data())
    assert (system.hparams.noise_std, system.hparams.noise_decay) == pytest.approx((1e-4, 1.0))
    assert (
        model_summary(cfg, system)["noise_std_source"] == "train.noise_std (overrides model.noise_std=0.0003)"
    )
    assert "noise 0.0001 from train.noise_std (overrides model.noise_std=0.0003)" in caplog.text


def _data_with_radius(radius: float):
    """A stand-in data module whose metadata has ``radius`` as its default connectivity radius."""
    data = _Data()
    data.metadata = Metadata(**{**_Data.metadata.__dict__, "default_connectivity_radius": radius})
    return data


@pytest.mark.parametrize(
    "preset_radius, paper_radius",
    [(0.015, 0.020), (0.035, 0.035 * 0.020 / 0.015)],  # WaterRamps (DeepMind's 0.015), the small preset
)
def test_the_simplified_config_uses_the_papers_radius_relative_to_the_data_and_records_it(
    caplog, preset_radius, paper_radius
):
    """The paper fixes its radius at 0.020 on WaterRamps (sections 6.2.1, 9.0.1), where DeepMind's default is
    0.015: the simplified config scales the dataset's default by 0.020 / 0.015; the original keeps DeepMind's."""
    data = _data_with_radius(preset_radius)
    with caplog.at_level(logging.INFO, logger="gnsx"):
        cfg = _compose("model=simplified")
        system = build_system(cfg, data)
    summary = model_summary(cfg, system)
    assert summary["radius"] == pytest.approx(paper_radius, rel=1e-4)
    assert summary["radius_source"] == "model.radius_scale=1.3333 x the dataset's default_connectivity_radius"
    assert f"connection radius {system.hparams.radius:g} (model.radius_scale=1.3333 x" in caplog.text
    cfg = _compose("model=original")
    summary = model_summary(cfg, build_system(cfg, data))
    assert summary["radius"] == preset_radius
    assert summary["radius_source"] == "the dataset's default_connectivity_radius"


def test_the_radius_each_config_uses_is_logged_and_recorded_with_its_source(caplog):
    with caplog.at_level(logging.INFO, logger="gnsx"):
        cfg = _compose("model=simplified_pairwise")  # the demo's model keeps the dataset's radius
        system = build_system(cfg, _Data())
    summary = model_summary(cfg, system)
    assert (
        summary["radius"] == 0.035 and summary["radius_source"] == "the dataset's default_connectivity_radius"
    )
    assert "connection radius 0.035 (the dataset's default_connectivity_radius)" in caplog.text
    cfg = _compose("model=simplified", "model.radius=0.02")
    summary = model_summary(cfg, build_system(cfg, _Data()))
    assert (summary["radius"], summary["radius_source"]) == (0.02, "model.radius")
    with pytest.raises(Exception, match="model.radius_scale=-1"):
        cfg = _compose("model=simplified", "model.radius_scale=-1")
        build_system(cfg, _Data())


@pytest.mark.parametrize("trainer", ["cpu", "gpu", "ddp"])
def test_fp32_matrix_products_unless_asked(trainer):
    before = torch.get_float32_matmul_precision()
    try:
        torch.set_float32_matmul_precision("high")
        assert apply_matmul_precision(_compose(f"trainer={trainer}")) == "highest"
        assert torch.get_float32_matmul_precision() == "highest"  # no TF32 on CUDA
        assert (
            apply_matmul_precision(_compose(f"trainer={trainer}", "trainer.float32_matmul_precision=high"))
            == "high"
        )
    finally:
        torch.set_float32_matmul_precision(before)


def test_deepmind_learning_rate_schedule():
    assert learning_rate(0, 1e-4, 1e-6, 0, 5_000_000, kind="deepmind") == pytest.approx(1e-4)
    assert learning_rate(5_000_000, 1e-4, 1e-6, 0, 5_000_000, kind="deepmind") == pytest.approx(1e-6 + 9.9e-6)
    assert learning_rate(20_000_000, 1e-4, 1e-6, 0, 5_000_000, kind="deepmind") > 1e-6  # never reaches it
    cfg = _compose("model=original", "train=deepmind")
    system = build_system(cfg, _Data())
    assert system.hparams.lr_schedule == "deepmind" and cfg.train.max_steps == 20_000_000
    optimizer = system.configure_optimizers()
    scheduler = optimizer["lr_scheduler"]["scheduler"]
    assert scheduler.lr_lambdas[0](5_000_000) * system.hparams.lr_init == pytest.approx(1.09e-5)
    # The paper's schedule for the simplified model is unchanged: 1e-4 until 1M steps, 1e-6 from 1.5M.
    assert learning_rate(1_500_000, 1e-4, 1e-6, 1_000_000, 1_500_000) == pytest.approx(1e-6)
