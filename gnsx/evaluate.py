"""Test-split evaluation at the end of training: rollouts, their error against a physics-free baseline, speed,
and an animation of one rollout next to ground truth.
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch

from gnsx.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.metrics import position_mse
from gnsx.model.rollout import physics_free_baseline, rollout
from gnsx.model.simulator import LearnedSimulator

log = logging.getLogger("gnsx")

#: Gravity of WaterRamps-like data (m/s^2, along -y); the baseline moves particles by g*dt^2 per frame^2.
GRAVITY = 9.8


def gravity_per_frame(metadata: Metadata) -> torch.Tensor:
    """Gravity as a per-frame position increment ``[D]`` (data units / frame^2), pointing along -y (the last axis
    in 2D, the second in 3D, as in DeepMind's datasets)."""
    g = torch.zeros(metadata.dim)
    g[1] = -GRAVITY * metadata.dt**2
    return g


@torch.inference_mode()
def evaluate_simulator(
    simulator: LearnedSimulator, trajectories: Iterable[dict], metadata: Metadata, keep_first: bool = True
) -> tuple[dict, list[dict], dict | None]:
    """Roll out every trajectory from its first ``history + 1`` frames.

    Args:
        trajectories: dicts with ``position [T, N, D]`` and ``particle_type [N]`` tensors.
    Returns:
        (summary, per-trajectory rows, the first trajectory's full ground-truth/predicted/baseline positions
        ``[T, N, D]`` as numpy for rendering). Errors are position MSE per coordinate over dynamic particles,
        averaged over predicted frames; ``ms_per_frame`` is the rollout wall time per frame, graph build included.
    """
    simulator.eval()
    frames = simulator.input_frames
    rows, first = [], None
    for index, traj in enumerate(trajectories):
        position, particle_type = traj["position"], traj["particle_type"]
        dynamic = particle_type != KINEMATIC_PARTICLE_ID
        steps = position.shape[0] - frames
        initial = position[:frames].transpose(0, 1)
        start = time.perf_counter()
        predicted = rollout(simulator, initial, particle_type, steps)
        elapsed = time.perf_counter() - start
        baseline = physics_free_baseline(
            initial, particle_type, steps, gravity_per_frame(metadata), metadata.bounds_array()
        )
        rows.append(
            {
                "trajectory": int(traj.get("index", index)),
                "particles": int(position.shape[1]),
                "frames": int(steps),
                "rollout_mse": position_mse(predicted, position[frames:], dynamic),
                "baseline_mse": position_mse(baseline, position[frames:], dynamic),
                "ms_per_frame": 1000 * elapsed / max(steps, 1),
            }
        )
        if keep_first and first is None:
            first = {
                "ground_truth": position.numpy(),
                "predicted": torch.cat([position[:frames], predicted]).numpy(),
                "baseline": torch.cat([position[:frames], baseline]).numpy(),
                "particle_type": particle_type.numpy(),
            }
    summary = {
        "rollout_mse": float(np.mean([r["rollout_mse"] for r in rows])),
        "baseline_mse": float(np.mean([r["baseline_mse"] for r in rows])),
        "ms_per_frame": float(statistics.median(r["ms_per_frame"] for r in rows)),
        "trajectories": len(rows),
    }
    summary["baseline_ratio"] = summary["baseline_mse"] / max(summary["rollout_mse"], 1e-30)
    return summary, rows, first


def format_table(rows: list[dict], summary: dict, title: str) -> str:
    """A plain-text table of per-trajectory errors and the summary line."""
    lines = [title, f"{'traj':>5} {'particles':>9} {'rollout MSE':>12} {'baseline MSE':>13} {'ms/frame':>9}"]
    for r in rows:
        lines.append(
            f"{r['trajectory']:>5} {r['particles']:>9} {r['rollout_mse']:>12.3e} {r['baseline_mse']:>13.3e}"
            f" {r['ms_per_frame']:>9.1f}"
        )
    lines.append(
        f"{'mean':>5} {'':>9} {summary['rollout_mse']:>12.3e} {summary['baseline_mse']:>13.3e}"
        f" {summary['ms_per_frame']:>9.1f}   baseline/model = {summary['baseline_ratio']:.2f}x"
    )
    return "\n".join(lines)


def render_comparison(first: dict, metadata: Metadata, path: Path, label: str) -> Path:
    """Animation of ground truth next to the model's rollout (same initial frames)."""
    from gnsx.render import render_rollouts, save_animation

    frames = render_rollouts(
        [first["ground_truth"], first["predicted"]],
        first["particle_type"],
        metadata.bounds_array(),
        titles=["ground truth (MPM)", label],
        frame_stride=2,
    )
    return save_animation(frames, path, fps=25)


def evaluate_run(cfg, simulator: LearnedSimulator, datamodule, run_dir: Path, loggers: list) -> dict:
    """End-of-training evaluation for ``train.py``: the trained model, and the shipped weights when present.

    Writes ``results.json``, ``test_rollout.<gif|mp4>`` (and ``pretrained_rollout.*``) into ``run_dir``,
    logs the summary to every logger, prints the tables. Returns the trained model's summary.
    """
    from gnsx.pipeline import write_json

    datamodule.setup("test")
    metadata = datamodule.metadata
    simulator = simulator.cpu()
    summary, rows, first = evaluate_simulator(simulator, datamodule.test_set, metadata)
    print(format_table(rows, summary, f"Test rollouts ({cfg.model.name} GNS, this run) vs physics-free baseline"))
    results = {"model": cfg.model.name, "parameters": simulator.num_parameters(), "test": summary, "rows": rows}
    suffix = cfg.evaluate.render_format
    if cfg.evaluate.render and first is not None:
        path = render_comparison(first, metadata, run_dir / f"test_rollout.{suffix}", f"{cfg.model.name} GNS")
        log.info("Animation: %s", path)
        results["animation"] = str(path)

    pretrained = cfg.evaluate.pretrained
    if pretrained and Path(pretrained).is_file():
        from gnsx.system import GNSSystem

        shipped = GNSSystem.load_from_checkpoint(pretrained, map_location="cpu").simulator
        p_summary, p_rows, p_first = evaluate_simulator(shipped, datamodule.test_set, metadata)
        print(format_table(p_rows, p_summary, f"Test rollouts (shipped weights {pretrained})"))
        results["pretrained"] = {"checkpoint": str(pretrained), "test": p_summary, "rows": p_rows}
        if cfg.evaluate.render and p_first is not None:
            path = render_comparison(p_first, metadata, run_dir / f"pretrained_rollout.{suffix}", "shipped GNS")
            log.info("Animation (shipped weights): %s", path)
            results["pretrained"]["animation"] = str(path)

    write_json(run_dir / "results.json", results)
    for logger in loggers:
        logger.log_metrics({f"test/{k}": v for k, v in summary.items()})
    return summary
