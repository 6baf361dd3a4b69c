"""Figure 9 in motion (gnsx.evaluation.report.grid_motion): every cell with weights is rolled out and drawn on
one mosaic beside the truth; a cell without weights is named, not dropped; the frames are where the truth
splashes and where it has settled."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from test_evaluate import save_tiny_checkpoint

from gnsx.data.store import load_metadata
from gnsx.evaluation.report.grid_motion import PANEL, main, splash_and_settled


def _cell(sweep: Path, latent: int, mp: int, metadata, weights: bool) -> Path:
    folder = sweep / f"fig9_cell={latent}x{mp}"
    folder.mkdir(parents=True)
    model = {"latent_size": latent, "mlp_hidden_size": latent, "mp_steps": mp}
    results = {"status": "ok", "model_config": model | {"radius": metadata.default_connectivity_radius},
               "test": {"rollout_mse": 0.01}}  # fmt: skip
    (folder / "results.json").write_text(json.dumps(results))
    if weights:
        save_tiny_checkpoint(folder / "model.ckpt", metadata, model)
    return folder


def test_the_grid_is_drawn_at_its_splash_and_settled_frames_and_animated(tmp_path, tiny_dataset):
    metadata = load_metadata(tiny_dataset)
    sweep = tmp_path / "sweep"
    for latent, mp, weights in ((8, 1, True), (8, 2, True), (4, 1, True), (4, 2, False)):
        _cell(sweep, latent, mp, metadata, weights)
    out = tmp_path / "out"
    assert (
        main([str(sweep), "--data", str(tiny_dataset), "--out", str(out), "--every", "5", "--format", "gif"])
        == 0
    )
    record = json.loads((out / "grid_motion.json").read_text())
    assert record["without_weights"] == ["4/2"] and len(record["weights"]) == 3
    assert len(record["frames"]) == 2 and record["frames"][1] == 29  # the tiny trajectories have 30 frames
    image = iio.imread(record["pictures"][0])
    assert image.shape == (3 * PANEL, 2 * PANEL, 3)  # a truth row, then rows 8 and 4 x columns 2 and 1
    animation = iio.imread(out / "grid_motion.gif")
    assert animation.shape[0] == 6  # frames 0, 5, ..., 25


def test_the_splash_frame_is_where_the_truth_moves_fastest():
    frames = 60
    x = np.zeros((frames, 3, 2))
    step = np.where(np.arange(frames) == 41, 0.05, 0.001)  # one fast frame, at 41
    x[:, :, 0] = np.cumsum(step)[:, None]
    assert splash_and_settled(x, np.zeros(3, dtype=np.int64)) == [41, frames - 1]


def test_frames_outside_the_trajectory_are_a_clear_error(tmp_path, tiny_dataset):
    metadata = load_metadata(tiny_dataset)
    _cell(tmp_path / "sweep", 8, 1, metadata, True)
    with pytest.raises(ValueError, match="--frames"):
        main(
            [
                str(tmp_path / "sweep"),
                "--data",
                str(tiny_dataset),
                "--out",
                str(tmp_path / "o"),
                "--frames",
                "99",
            ]
        )
