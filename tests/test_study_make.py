"""`make study` end to end: the README's command builds the three-method study (MPM, original, simplified) from
the committed equal-budget models, with their budget in the method names, and the clips and manifest load."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAIR = ROOT / "pretrained" / "equal_budget"
BUDGET = "equal 32-minute CPU budget"


@pytest.mark.skipif(
    not (PAIR / "original" / "model.ckpt").is_file(), reason="the equal-budget pair is not shipped"
)
def test_make_study_builds_mpm_original_and_simplified_with_their_budget(tiny_dataset, tmp_path):
    from gnsx.study.manifest import load_study

    study = tmp_path / "study"
    env = {**os.environ, "WANDB_MODE": "offline", "MPLBACKEND": "Agg"}
    done = subprocess.run(
        ["make", "--no-print-directory", "study", f"STUDY_DIR={study}", f"DATA={tiny_dataset}",
         "STUDY_TRAJECTORIES=1", "ARGS=--frames 12 --size 64"],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    manifest = load_study(study)
    methods = {m for group in manifest.groups for m in group}
    assert methods == {"MPM", f"original GNS 128/10, {BUDGET}", f"simplified GNS 64/5, {BUDGET}"}
    assert len(manifest.pairs) == 3  # one scene, one pair per group
    assert BUDGET in manifest.name
    for pair in manifest.pairs:
        for file in pair.files.values():
            assert (study / file).stat().st_size > 0
