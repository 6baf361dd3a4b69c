"""Figure 9 in motion: every cell of a grid rolled out on one test trajectory, side by side with the truth.

``python -m gnsx.evaluation.report.grid_motion <sweep> --data data/small_400 --out docs/fig9``

The paper points its readers to a video of figure 9; a single frame hides whether a cell's water is still a
block or has settled, so this draws the grid at several frames and as an animation. For each cell of the
sweep (its lowest seed, as ``grid.png``) with final weights in its folder (``model.ckpt``, what
``scripts/keep_jobs.sh`` commits, or ``checkpoints/last.ckpt``), the raw network is rolled out on test
trajectory ``--trajectory`` from its true first frames (the one rollout loop, :func:`gnsx.model.rollout.rollout`,
held by the walls and ramps only, as every scored rollout), and drawn on the truth's colour scale.

Writes into ``--out``:

* ``grid_motion_NNNN.png`` for each frame of ``--frames`` (default: the truth's mid-splash frame, where its
  mean particle speed peaks after the first 20 frames, and the last frame, where it has settled);
* ``grid_motion.mp4`` (or ``.gif``): every ``--every``-th frame of the whole trajectory, the grid's mosaic
  with the truth in the top-left corner panel;
* ``grid_motion.json``: which frames, which weights, the cells that had none.

Rows are the embedding sizes and columns the message-passing steps, large to small from the top left as in
figure 9 (:func:`gnsx.evaluation.report.plots.grid_layout`); a cell without weights is a grey panel that says
so.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gnsx.core.cli import run_main

#: Pixels of one panel of the mosaic.
PANEL = 192
#: The mid-splash frame is looked for after this many frames (the first ones are the initial free fall).
SPLASH_AFTER = 20


def weights_of(folder: Path) -> Path | None:
    """A job's final weights: its ``model.ckpt`` (committed by keep_jobs.sh), else ``checkpoints/last.ckpt``."""
    for path in (folder / "model.ckpt", folder / "checkpoints" / "last.ckpt"):
        if path.is_file():
            return path
    return None


def splash_and_settled(truth: np.ndarray, particle_type: np.ndarray) -> list[int]:
    """``[mid-splash, settled]`` frames of a ``[T, N, 2]`` true trajectory: where the water's mean speed
    peaks after :data:`SPLASH_AFTER` frames, and the last frame."""
    from gnsx.core.constants import KINEMATIC_PARTICLE_ID
    from gnsx.evaluation.render import speeds

    moving = np.asarray(particle_type) != KINEMATIC_PARTICLE_ID
    mean_speed = speeds(truth)[:, moving].mean(axis=1)
    start = min(SPLASH_AFTER, len(mean_speed) - 1)
    return [int(start + np.argmax(mean_speed[start:])), int(truth.shape[0] - 1)]


def roll_out_cells(jobs, trajectory: dict, row_key: str | None, col_key: str) -> dict[tuple, np.ndarray]:
    """``{(row value, column value): [T, N, 2] positions}`` of every job with weights (the values of the
    grid's axes, :func:`gnsx.evaluation.report.plots.grid_layout`), the true first frames included."""
    import torch

    from gnsx.model.checkpoint import load_simulator
    from gnsx.model.rollout import rollout

    position, particle_type = trajectory["position"], trajectory["particle_type"]
    out = {}
    for job in jobs:
        path = weights_of(job.folder)
        if path is None:
            continue
        simulator = load_simulator(path)
        frames = simulator.input_frames
        with torch.inference_mode():
            predicted = rollout(simulator, position[:frames].transpose(0, 1), particle_type,
                                position.shape[0] - frames)  # fmt: skip
        key = (getattr(job, row_key) if row_key else None, getattr(job, col_key))
        out[key] = torch.cat([position[:frames], predicted]).numpy()
    return out


def mosaic_frames(
    rollouts: dict[tuple, np.ndarray],
    truth: np.ndarray,
    particle_type: np.ndarray,
    bounds: np.ndarray,
    rows: Sequence,
    cols: Sequence,
    frames: Sequence[int],
    size: int = PANEL,
) -> np.ndarray:
    """``[len(frames), (len(rows) + 1) * size, len(cols) * size, 3]`` uint8: one header row with the truth
    in its first panel, then one row per embedding size and one column per MP count (``rows``, ``cols``:
    the values of the grid's axes, the keys of ``rollouts``)."""
    from gnsx.evaluation.render import _radii, _title, colour_scale, render_frame, speeds

    types = np.asarray(particle_type)
    scale = colour_scale(speeds(truth), types)
    dot = _radii([truth], types, bounds, size, None)
    speed_of = {key: speeds(r) for key, r in rollouts.items()}
    true_speed = speeds(truth)
    blank = np.full((size, size, 3), 40, np.uint8)
    out = []
    for t in frames:
        header = [
            _title(
                render_frame(truth[t], types, true_speed[t], bounds, size, scale, *dot), f"truth, frame {t}"
            )
        ]
        header += [blank] * (len(cols) - 1)
        lines = [np.concatenate(header, axis=1)]
        for row in rows:
            panels = []
            for col in cols:
                key, name = (row, col), "/".join(str(v) for v in (row, col) if v is not None)
                if key in rollouts:
                    image = render_frame(rollouts[key][t], types, speed_of[key][t], bounds, size, scale, *dot)
                    panels.append(_title(image, name))
                else:
                    panels.append(_title(blank.copy(), f"{name}: no weights"))
            lines.append(np.concatenate(panels, axis=1))
        out.append(np.concatenate(lines, axis=0))
    return np.stack(out)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gnsx.evaluation.report.grid_motion",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("sweep", type=Path, help="a grid sweep's folder (jobs with their weights)")
    parser.add_argument("--data", type=Path, required=True, help="the dataset the grid trained on")
    parser.add_argument("--out", type=Path, required=True, help="folder for the pictures and the animation")
    parser.add_argument("--trajectory", type=int, default=0, help="test trajectory (default 0, as grid.png)")
    parser.add_argument("--frames", type=int, nargs="*", default=None,
                        help="frames to draw (default: the truth's mid-splash frame and its last)")  # fmt: skip
    parser.add_argument("--every", type=int, default=3, help="animation: every N-th frame (default 3)")
    parser.add_argument(
        "--format", choices=("mp4", "gif"), default="mp4", help="animation format (default mp4)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args(argv)
    import imageio.v3 as iio
    import torch

    from gnsx.data.datamodule import TrajectoryDataset
    from gnsx.data.store import load_metadata, open_split
    from gnsx.evaluation.render import save_animation
    from gnsx.evaluation.report.jobs import load_sweep, split_seeds
    from gnsx.evaluation.report.plots import grid_layout

    torch.set_num_threads(args.threads)
    jobs, _ = split_seeds([j for j in load_sweep(args.sweep) if j.ok])
    if not jobs:
        raise FileNotFoundError(f"{args.sweep}: no finished job")
    metadata = load_metadata(args.data)
    dataset = TrajectoryDataset(open_split(args.data, "test", metadata))
    if not 0 <= args.trajectory < len(dataset):
        raise ValueError(
            f"--trajectory {args.trajectory}: {args.data} has test trajectories 0..{len(dataset) - 1}"
        )
    trajectory = dataset[args.trajectory]
    truth, types = trajectory["position"].numpy(), trajectory["particle_type"].numpy()
    row_key, rows, col_key, cols = grid_layout(jobs)
    rollouts = roll_out_cells(jobs, trajectory, row_key, col_key)
    frames = args.frames or splash_and_settled(truth, types)
    bad = [f for f in frames if not 0 <= f < truth.shape[0]]
    if bad:
        raise ValueError(f"--frames {bad}: trajectory {args.trajectory} has frames 0..{truth.shape[0] - 1}")
    bounds = metadata.bounds_array()
    args.out.mkdir(parents=True, exist_ok=True)
    pictures = []
    for frame, image in zip(frames, mosaic_frames(rollouts, truth, types, bounds, rows, cols, frames)):
        path = args.out / f"grid_motion_{frame:04d}.png"
        iio.imwrite(path, image)
        pictures.append(str(path))
    every = list(range(0, truth.shape[0], max(1, args.every)))
    animation = save_animation(mosaic_frames(rollouts, truth, types, bounds, rows, cols, every, size=128),
                               args.out / f"grid_motion.{args.format}", fps=20)  # fmt: skip
    record: dict[str, Any] = {
        "sweep": str(args.sweep), "data": str(args.data), "trajectory": args.trajectory, "frames": frames,
        "pictures": pictures, "animation": str(animation), "every": args.every,
        "weights": {f"{j.latent_size}/{j.mp_steps}": str(weights_of(j.folder)) for j in jobs if weights_of(j.folder)},
        "without_weights": [f"{j.latent_size}/{j.mp_steps}" for j in jobs if weights_of(j.folder) is None],
    }  # fmt: skip
    (args.out / "grid_motion.json").write_text(json.dumps(record, indent=2))
    print(
        f"wrote {', '.join(pictures)} and {animation}; cells without weights: {record['without_weights'] or 'none'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError, ValueError)))
