"""What a sweep config (``sweeps/*.yaml``, its ``sweep`` block) asks of each job besides its test scores: one
rendered frame of the first test rollout (``sweep.frame``) and the model's speed and memory at WaterRamps size
(``sweep.bench``), at the data's particle spacing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.model.simulator import LearnedSimulator


def data_spacing(metadata: Metadata, position: np.ndarray, particle_type: np.ndarray) -> float:
    """Typical distance between neighbouring fluid particles (data units): the generator's particle spacing
    when the metadata records it (gnsx presets), else the median nearest-neighbour distance of the dynamic
    particles of ``position [N, D]`` (e.g. the first frame of a test trajectory)."""
    settings = metadata.extra.get("gnsx", {}).get("preset_settings", {})
    if settings.get("particle_spacing"):
        return float(settings["particle_spacing"])
    from scipy.spatial import cKDTree

    fluid = position[particle_type != KINEMATIC_PARTICLE_ID]
    distances, _ = cKDTree(fluid).query(fluid, k=2)
    return float(np.median(distances[:, 1]))


def benchmark_at_scale(
    simulator: LearnedSimulator,
    metadata: Metadata,
    spacing: float,
    num_particles: int,
    device: torch.device,
    warmup: int,
    repeats: int,
) -> dict[str, Any]:
    """Inference speed and peak memory of one step (graph build included, :func:`gnsx.perf.benchmark.
    measure_inference`) on a packed scene of ``num_particles`` (WaterRamps' largest scenes have ~2.3k) at the
    data's particle spacing, so each particle has as many neighbours as in training.

    When that many particles do not fit in the data's domain at its spacing (the small preset's particles are
    coarse), the domain is enlarged by steps of 25%: speed and memory do not depend on where the walls are.

    Returns :func:`~gnsx.evaluation.timing.measure_inference`'s dict plus ``spacing`` and ``domain_scale``.
    """
    from gnsx.evaluation.timing import measure_inference, packed_scene

    bounds = metadata.bounds_array().astype(np.float64)  # [D, 2]
    extent = bounds[:, 1] - bounds[:, 0]
    for attempt in range(8):
        scale = 1.25**attempt
        try:
            grown = np.stack([bounds[:, 0], bounds[:, 0] + scale * extent], axis=1)
            sequence, particle_type = packed_scene(num_particles, spacing, grown, simulator.history)
            break
        except ValueError:
            if attempt == 7:
                raise
    measured = measure_inference(
        simulator.to(device), sequence, particle_type, warmup=warmup, repeats=repeats
    )
    return {**measured, "spacing": spacing, "domain_scale": scale}


def render_test_frame(
    simulator: LearnedSimulator, trajectory: dict, metadata: Metadata, frame: int, out_dir: Path
) -> dict[str, str | int]:
    """Roll the model out on one test trajectory up to ``frame``; save that frame, predicted and true, as PNG.

    Args:
        trajectory: ``position [T, N, D]`` and ``particle_type [N]`` tensors (ground truth).
        frame: the frame to draw, clamped to the trajectory (the paper's figure 9 shows one frame per model).
    Returns:
        ``{"frame", "frame_png", "frame_truth_png"}`` (paths of 256 x 256 images, particles coloured by speed
        on the ground truth's colour scale, so every model of a sweep is drawn alike).
    """
    import imageio.v3 as iio

    from gnsx.evaluation.render import render_frame, speeds
    from gnsx.model.rollout import rollout

    position, particle_type = trajectory["position"], trajectory["particle_type"]
    frames = simulator.input_frames
    frame = int(min(max(frame, frames), position.shape[0] - 1))
    simulator = simulator.cpu().eval()
    predicted = rollout(simulator, position[:frames].transpose(0, 1), particle_type.cpu(), frame - frames + 1)
    predicted = torch.cat([position[:frames], predicted]).numpy()  # [frame + 1, N, D]
    truth = position[: frame + 1].numpy()
    types = particle_type.numpy()
    true_speed = speeds(truth)
    scale = float(np.percentile(true_speed[:, types != KINEMATIC_PARTICLE_ID], 99)) or 1.0
    bounds = metadata.bounds_array()
    paths = {"frame": frame}
    for key, positions in (("frame_png", predicted), ("frame_truth_png", truth)):
        image = render_frame(positions[frame], types, speeds(positions[frame - 1 : frame + 1])[1], bounds,
                             speed_scale=scale)  # fmt: skip
        path = out_dir / f"{key.removesuffix('_png')}_{frame:04d}.png"
        iio.imwrite(path, image)
        paths[key] = str(path)
    return paths
