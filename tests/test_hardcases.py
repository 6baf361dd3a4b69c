"""The hard-case suite (gnsx/evaluation/hardcases.py) on short rollouts."""

import json

import numpy as np
import pytest
from test_simulator import make_simulator

from gnsx.evaluation.hardcases import CASES, drift, format_report, run_suite
from gnsx.mpm.presets import get_preset
from gnsx.rules.rules import Rules


def test_drift_is_the_mean_displacement_over_the_last_frames():
    positions = np.zeros((150, 2, 2))
    positions[:, 0, 0] = np.arange(150) * 1e-4  # 1 cm per 100 frames
    mask = np.array([True, True])
    assert drift(positions, mask, 100) == pytest.approx(0.5e-2)
    assert np.isnan(drift(positions[:50], mask, 100))


def test_every_case_is_a_valid_scene_of_the_small_preset():
    from gnsx.mpm.generate import check_scene
    from gnsx.mpm.scenes import Scene

    names = [c.name for c in CASES]
    assert len(set(names)) == len(names)
    for case in CASES:
        scene = Scene.from_dict(case.scene, where=case.name)
        if scene.blocks:
            check_scene(scene, get_preset("small"), where=case.name)


def test_the_suite_holds_a_wild_model_by_the_boundary(tmp_path):
    """Random weights with a huge acceleration scale throw the water out of the box; the raw network (held by
    the walls and ramps) keeps it in; ``--rules production`` adds a labelled third variant."""
    simulator = make_simulator({}, radius=0.035, acc_std=[3e-3, 3e-3], bounds=[[0.1, 0.9], [0.1, 0.9]])
    cases = tuple(c for c in CASES if c.name in ("jet_ramp", "statics_only"))
    report = run_suite(simulator, cases, out_dir=tmp_path, frames_scale=0.12, progress=False)
    rows = {(r["case"], r["variant"]): r for r in report["cases"]}
    assert set(rows) == {(c, v) for c in ("jet_ramp", "statics_only") for v in ("no_walls", "raw")}
    held, free = rows["jet_ramp", "raw"], rows["jet_ramp", "no_walls"]
    assert held["out_max"] == 0 and held["crossings"] == 0 and held["nonfinite"] == 0
    assert free["out_max"] > 0 or free["crossings"] > 0
    assert held["truth_crossings"] == 0  # the MPM never tunnels
    assert rows["statics_only", "raw"]["water_particles"] == 0
    saved = json.loads((tmp_path / "report.json").read_text())
    assert len(saved["cases"]) == 4 and saved["precision"]["rms_m"] and not any(saved["rules"].values())
    assert (tmp_path / "strips" / "jet_ramp.png").stat().st_size > 0
    assert "| jet_ramp | raw |" in format_report(report)
    with_rules = run_suite(simulator, cases[:1], frames_scale=0.12, progress=False, rules=Rules.production())
    variants = [r["variant"] for r in with_rules["cases"]]
    assert variants == ["no_walls", "raw", "with_rules"] and all(with_rules["rules"].values())
