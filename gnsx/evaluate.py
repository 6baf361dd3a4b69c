"""Evaluation of a learned simulator on whole trajectories: rollouts, their errors, speed and memory.

Per trajectory (:func:`score_trajectory`), the model is rolled out from the first ``history + 1`` ground-truth
frames to the end, and compared with the ground truth:

==========================  ==================================================================================
metric                      meaning (positions in data units, metres for WaterRamps-like data)
==========================  ==================================================================================
``rollout_mse``             position MSE per coordinate over dynamic particles and predicted frames
``rollout_mse_all``         the same over all particles, static ones included (as DeepMind reports it)
``onestep_mse``             position MSE of single steps from ground-truth inputs (every ``onestep_stride``-th
                            frame)
``baseline_mse``            ``rollout_mse`` of the physics-free baseline (constant velocity + gravity)
``emd``                     Earth Mover's distance between predicted and true water, mean over the frames
                            that are multiples of ``emd_every`` (and the last); ``emd_final``: the last frame
``kinetic_energy_error``    ``mean_t |E_pred - E_true| / mean_t E_true``, E the mean kinetic energy per unit
                            mass
``neighbour_ratio``         mean over the EMD frames of (mean neighbours within R, predicted / true): above 1
                            the rollout compressed the fluid (volume loss), below 1 it spread it
``out_of_bounds_fraction``  dynamic particles outside the walls, fraction, mean over predicted frames;
                            ``out_of_bounds_final``: their number at the last frame
``ms_per_frame``            :func:`gnsx.benchmark.measure_inference` on the trajectory's first frames (median
                            after warm-up, graph build included); ``peak_memory_mb`` likewise
``rollout_ms_per_frame``    wall time of the whole rollout per frame (graph build included)
==========================  ==================================================================================

:func:`evaluate_simulator` runs every trajectory and summarises (means of the errors, median of the speed, max
of the memory); :func:`evaluate_run` is the end-of-training evaluation of ``train.py``. The evaluation entry
point ``evaluate.py`` (many checkpoints, rollout files, pictures) is built on these.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from gnsx.benchmark import measure_inference
from gnsx.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.metrics import (
    earth_movers_distance,
    kinetic_energy,
    kinetic_energy_error,
    neighbour_count,
    out_of_bounds,
    position_mse,
    position_mse_per_frame,
)
from gnsx.model.rollout import physics_free_baseline, rollout
from gnsx.model.simulator import LearnedSimulator

log = logging.getLogger("gnsx")

#: Gravity of WaterRamps-like data (m/s^2, along -y); the baseline moves particles by g*dt^2 per frame^2.
GRAVITY = 9.8
#: One-step MSE batches its windows into graphs of at most this many nodes (bounds the memory).
_ONESTEP_MAX_NODES = 200_000
#: Summary keys averaged over trajectories (the speed is a median, the memory a max).
_MEAN_KEYS = (
    "rollout_mse",
    "rollout_mse_all",
    "onestep_mse",
    "baseline_mse",
    "emd",
    "emd_final",
    "kinetic_energy_error",
    "neighbour_ratio",
    "out_of_bounds_fraction",
    "out_of_bounds_final",
    "rollout_ms_per_frame",
)


def gravity_per_frame(metadata: Metadata) -> torch.Tensor:
    """Gravity as a per-frame position increment ``[D]`` (data units / frame^2), pointing along -y (the last
    axis in 2D, the second in 3D, as in DeepMind's datasets)."""
    g = torch.zeros(metadata.dim)
    g[1] = -GRAVITY * metadata.dt**2
    return g


@dataclass
class TrajectoryResult:
    """Everything :func:`score_trajectory` computed for one trajectory.

    Attributes:
        index: the trajectory's index in its split.
        row: scalar metrics (see the module docstring), plus ``trajectory``, ``particles``, ``frames``.
        per_frame: ``{name: [T]}`` float64 arrays over all frames (NaN where not computed: input frames, and
            frames off the EMD grid for ``emd`` / ``neighbours_*``): ``mse``, ``mse_all``, ``baseline_mse``,
            ``emd``, ``kinetic_energy_pred``, ``kinetic_energy_true`` (J/kg), ``neighbours_pred``,
            ``neighbours_true``, ``out_of_bounds`` (count).
        ground_truth, predicted, baseline: ``[T, N, D]`` float32 positions (the first ``input_frames``
            frames of ``predicted`` and ``baseline`` are the ground truth's).
        particle_type: ``[N]`` int64.
        input_frames: ``history + 1``.
    """

    index: int
    row: dict
    per_frame: dict[str, np.ndarray]
    ground_truth: np.ndarray
    predicted: np.ndarray
    baseline: np.ndarray
    particle_type: np.ndarray
    input_frames: int

    def per_frame_rows(self) -> list[dict]:
        """One dict per predicted frame: ``trajectory``, ``frame`` and the per-frame metrics (CSV-ready)."""
        rows = []
        for t in range(self.input_frames, self.ground_truth.shape[0]):
            row = {"trajectory": self.index, "frame": t}
            row.update({k: float(v[t]) for k, v in self.per_frame.items()})
            rows.append(row)
        return rows


def distribution_frames(num_frames: int, input_frames: int, every: int) -> list[int]:
    """Frames where the set metrics (EMD, neighbour count) are computed: multiples of ``every`` at or after
    ``input_frames``, and the last frame. Absolute frame numbers, so models with different histories are
    compared on the same frames. ``every <= 0``: none."""
    if every <= 0 or num_frames <= input_frames:
        return []
    first = math.ceil(input_frames / every) * every
    return sorted(set(range(first, num_frames, every)) | {num_frames - 1})


@torch.inference_mode()
def onestep_mse(
    simulator: LearnedSimulator, position: torch.Tensor, particle_type: torch.Tensor, stride: int = 10
) -> float:
    """Position MSE per coordinate of single-step predictions from ground-truth inputs (dynamic particles).

    Inputs ``p[k-H..k]`` for every ``stride``-th ``k`` from ``H``, batched as disjoint graphs of at most
    ``_ONESTEP_MAX_NODES`` nodes.

    Args:
        position: ``[T, N, D]`` ground truth; particle_type: ``[N]``.
    """
    frames = simulator.input_frames
    num_particles, dim = position.shape[1], position.shape[2]
    starts = list(range(0, position.shape[0] - frames, max(stride, 1)))
    if not starts:
        return float("nan")
    dynamic = particle_type != KINEMATIC_PARTICLE_ID
    per_batch = max(1, _ONESTEP_MAX_NODES // max(num_particles, 1))
    total, count = 0.0, 0
    for i in range(0, len(starts), per_batch):
        chunk = starts[i : i + per_batch]
        windows = torch.stack([position[s : s + frames] for s in chunk])  # [K, H+1, N, D]
        k = len(chunk)
        sequence = windows.permute(0, 2, 1, 3).reshape(k * num_particles, frames, dim)
        graph = torch.arange(k, device=position.device).repeat_interleave(num_particles)
        predicted = simulator.predict_positions(sequence, particle_type.repeat(k), batch=graph)
        target = position[torch.tensor(chunk, device=position.device) + frames]  # [K, N, D]
        error = (predicted.reshape(k, num_particles, dim) - target) ** 2
        total += float(error[:, dynamic].sum())
        count += int(error[:, dynamic].numel())
    return total / max(count, 1)


def rollout_errors(
    predicted: np.ndarray,
    true: np.ndarray,
    particle_type: np.ndarray,
    input_frames: int,
    metadata: Metadata,
    emd_every: int = 10,
    emd_method: str = "auto",
) -> tuple[dict, dict[str, np.ndarray]]:
    """Errors of a rollout against its ground truth, over the predicted frames (from ``input_frames`` on).

    Args:
        predicted, true: ``[T, N, D]`` positions (data units), the same first ``input_frames`` frames.
        particle_type: ``[N]``; static (kinematic) particles count in ``rollout_mse_all`` alone.
        metadata: bounds, ``dt`` (energies) and ``default_connectivity_radius`` (neighbour counts).
        emd_every, emd_method: see :func:`score_trajectory`.
    Returns:
        scalars (``rollout_mse``, ``rollout_mse_all``, ``emd``, ``emd_final``, ``kinetic_energy_error``,
        ``neighbour_ratio``, ``out_of_bounds_fraction``, ``out_of_bounds_final``) and ``[T]`` per-frame arrays
        (NaN where not computed) as in :class:`TrajectoryResult`, ``baseline_mse`` aside.
    """
    frames, num_frames = input_frames, predicted.shape[0]
    mask = np.asarray(particle_type) != KINEMATIC_PARTICLE_ID
    names = ("mse", "mse_all", "emd", "kinetic_energy_pred", "kinetic_energy_true", "neighbours_pred",
             "neighbours_true", "out_of_bounds")  # fmt: skip
    per_frame = {name: np.full(num_frames, np.nan) for name in names}
    per_frame["mse"][frames:] = position_mse_per_frame(predicted[frames:], true[frames:], mask)
    per_frame["mse_all"][frames:] = position_mse_per_frame(predicted[frames:], true[frames:])
    # Energies from frame H on (its velocity p[H] - p[H-1] is the last given one), so entry t is frame t.
    per_frame["kinetic_energy_pred"][frames:] = kinetic_energy(predicted[frames - 1 :], metadata.dt, mask)
    per_frame["kinetic_energy_true"][frames:] = kinetic_energy(true[frames - 1 :], metadata.dt, mask)
    per_frame["out_of_bounds"][frames:] = out_of_bounds(predicted[frames:], metadata.bounds_array(), mask)
    radius = metadata.default_connectivity_radius
    set_frames = distribution_frames(num_frames, frames, emd_every)
    for t in set_frames:
        per_frame["emd"][t] = earth_movers_distance(predicted[t, mask], true[t, mask], method=emd_method)
        per_frame["neighbours_pred"][t] = neighbour_count(predicted[t], radius, mask)
        per_frame["neighbours_true"][t] = neighbour_count(true[t], radius, mask)

    emd = per_frame["emd"][set_frames] if set_frames else np.array([np.nan])
    ratio = per_frame["neighbours_pred"][set_frames] / np.maximum(
        per_frame["neighbours_true"][set_frames], 1e-12
    )
    errors = {
        "rollout_mse": position_mse(predicted[frames:], true[frames:], mask),
        "rollout_mse_all": position_mse(predicted[frames:], true[frames:]),
        "emd": float(np.mean(emd)),
        "emd_final": float(emd[-1]),
        "kinetic_energy_error": kinetic_energy_error(
            per_frame["kinetic_energy_pred"][frames:], per_frame["kinetic_energy_true"][frames:]
        ),
        "neighbour_ratio": float(np.mean(ratio)) if set_frames else float("nan"),
        "out_of_bounds_fraction": float(
            np.mean(per_frame["out_of_bounds"][frames:]) / max(int(mask.sum()), 1)
        ),
        "out_of_bounds_final": int(per_frame["out_of_bounds"][-1]),
    }
    return errors, per_frame


@torch.inference_mode()
def score_trajectory(
    simulator: LearnedSimulator,
    position: torch.Tensor,
    particle_type: torch.Tensor,
    metadata: Metadata,
    index: int = 0,
    emd_every: int = 10,
    emd_method: str = "auto",
    onestep_stride: int = 10,
    timing_warmup: int = 3,
    timing_repeats: int = 20,
) -> TrajectoryResult:
    """Roll out one trajectory from its first ``history + 1`` frames and compute every metric.

    Args:
        simulator: the model (rolled out on its device).
        position: ``[T, N, D]`` ground-truth positions (data units); particle_type: ``[N]`` int64.
        metadata: the dataset's metadata (bounds, dt for energies, connectivity radius for neighbour counts,
            gravity for the baseline).
        index: the trajectory's index in its split (reported in the rows).
        emd_every: EMD and neighbour counts on frames that are multiples of this (and the last); 0: skip them.
        emd_method: ``"exact"``, ``"sinkhorn"`` or ``"auto"`` (:func:`gnsx.metrics.earth_movers_distance`).
        onestep_stride: one-step MSE on every ``onestep_stride``-th frame.
        timing_warmup, timing_repeats: :func:`gnsx.benchmark.measure_inference` on the initial frames;
            ``timing_repeats=0`` skips it (``ms_per_frame`` and ``peak_memory_mb`` are then NaN/None).
    """
    device = simulator.acc_std.device
    position = position.to(device=device, dtype=torch.float32)
    particle_type = particle_type.to(device)
    frames = simulator.input_frames
    num_frames = position.shape[0]
    if num_frames <= frames:
        raise ValueError(
            f"trajectory {index}: {num_frames} frames, but the model needs more than its {frames} input "
            "frames"
        )
    steps = num_frames - frames
    initial = position[:frames].transpose(0, 1)  # [N, H+1, D]

    timing = {"ms_per_frame": float("nan"), "peak_memory_mb": None}
    if timing_repeats > 0:
        timing = measure_inference(simulator, initial, particle_type, timing_warmup, timing_repeats)
    start = time.perf_counter()
    predicted = (
        torch.cat([position[:frames], rollout(simulator, initial, particle_type, steps)]).cpu().numpy()
    )
    rollout_seconds = time.perf_counter() - start
    baseline = physics_free_baseline(
        initial.cpu(), particle_type.cpu(), steps, gravity_per_frame(metadata), metadata.bounds_array()
    )
    baseline = torch.cat([position[:frames].cpu(), baseline]).numpy()
    true = position.cpu().numpy()
    types = particle_type.cpu().numpy()
    errors, per_frame = rollout_errors(predicted, true, types, frames, metadata, emd_every, emd_method)
    dynamic = types != KINEMATIC_PARTICLE_ID
    per_frame["baseline_mse"] = np.full(num_frames, np.nan)
    per_frame["baseline_mse"][frames:] = position_mse_per_frame(baseline[frames:], true[frames:], dynamic)
    row = {
        "trajectory": int(index),
        "particles": int(position.shape[1]),
        "frames": int(steps),
        **errors,
        "onestep_mse": onestep_mse(simulator, position, particle_type, onestep_stride),
        "baseline_mse": position_mse(baseline[frames:], true[frames:], dynamic),
        "ms_per_frame": float(timing["ms_per_frame"]),
        "peak_memory_mb": timing["peak_memory_mb"],
        "rollout_ms_per_frame": 1000 * rollout_seconds / steps,
    }
    return TrajectoryResult(index, row, per_frame, true, predicted, baseline, types, frames)


def summarise(rows: Sequence[dict]) -> dict:
    """Summary over trajectories: means of the errors, median ``ms_per_frame``, max ``peak_memory_mb``."""
    summary = {
        key: float(np.nanmean([r[key] for r in rows])) for key in _MEAN_KEYS if rows and key in rows[0]
    }
    speeds = [r["ms_per_frame"] for r in rows if not math.isnan(r["ms_per_frame"])]
    summary["ms_per_frame"] = float(np.median(speeds)) if speeds else float("nan")
    memory = [r["peak_memory_mb"] for r in rows if r.get("peak_memory_mb") is not None]
    summary["peak_memory_mb"] = float(max(memory)) if memory else None
    summary["trajectories"] = len(rows)
    if "baseline_mse" in summary:
        summary["baseline_ratio"] = summary["baseline_mse"] / max(summary["rollout_mse"], 1e-30)
    return summary


def evaluate_simulator(
    simulator: LearnedSimulator,
    trajectories: Iterable[dict],
    metadata: Metadata,
    keep_first: bool = True,
    *,
    emd_every: int = 10,
    emd_method: str = "auto",
    onestep_stride: int = 10,
    timing_warmup: int = 3,
    timing_repeats: int = 20,
    on_trajectory: Callable[[TrajectoryResult], None] | None = None,
) -> tuple[dict, list[dict], dict | None]:
    """Roll out and score every trajectory (see :func:`score_trajectory` for the arguments).

    Args:
        trajectories: dicts with ``position [T, N, D]`` and ``particle_type [N]`` tensors (and optionally
            ``index``), e.g. a :class:`~gnsx.datamodule.TrajectoryDataset`.
        keep_first: return the first trajectory's positions for rendering.
        on_trajectory: called with each :class:`TrajectoryResult` as it is done (to save rollouts or per-frame
            rows without keeping every trajectory in memory).
    Returns:
        ``(summary, rows, first)``: the summary (:func:`summarise`: ``rollout_mse``, ``rollout_mse_all``,
        ``onestep_mse``, ``baseline_mse``, ``baseline_ratio``, ``emd``, ``emd_final``,
        ``kinetic_energy_error``, ``neighbour_ratio``, ``out_of_bounds_fraction``, ``out_of_bounds_final``,
        ``ms_per_frame``, ``peak_memory_mb``, ``rollout_ms_per_frame``, ``trajectories``), one row of scalars
        per trajectory, and
        the first trajectory's ``ground_truth``/``predicted``/``baseline`` ``[T, N, D]`` and ``particle_type``
        as numpy (None if ``keep_first`` is False).
    """
    simulator.eval()
    rows, first = [], None
    if hasattr(trajectories, "__len__") and hasattr(trajectories, "__getitem__"):
        # Index explicitly: a torch Dataset without __iter__ is iterated through __getitem__ until IndexError,
        # which walks past a TrajectoryDataset's max_trajectories into the whole split.
        dataset = trajectories
        trajectories = (dataset[i] for i in range(len(dataset)))
    for i, traj in enumerate(trajectories):
        result = score_trajectory(
            simulator,
            traj["position"],
            traj["particle_type"],
            metadata,
            index=int(traj.get("index", i)),
            emd_every=emd_every,
            emd_method=emd_method,
            onestep_stride=onestep_stride,
            timing_warmup=timing_warmup,
            timing_repeats=timing_repeats,
        )
        rows.append(result.row)
        if keep_first and first is None:
            first = {
                "ground_truth": result.ground_truth,
                "predicted": result.predicted,
                "baseline": result.baseline,
                "particle_type": result.particle_type,
            }
        if on_trajectory is not None:
            on_trajectory(result)
    return summarise(rows), rows, first


def format_table(rows: list[dict], summary: dict, title: str) -> str:
    """A plain-text table of per-trajectory errors and the summary line."""
    head = (f"{'traj':>5} {'particles':>9} {'rollout MSE':>12} {'one-step':>10} {'baseline':>10} {'EMD':>9}"
            f" {'KE err':>7} {'nbr ratio':>9} {'ms/frame':>9}")  # fmt: skip

    def line(name: str, particles: str, r: dict) -> str:
        return (f"{name:>5} {particles:>9} {r['rollout_mse']:>12.3e} {r['onestep_mse']:>10.2e}"
                f" {r['baseline_mse']:>10.2e} {r['emd']:>9.2e} {r['kinetic_energy_error']:>7.2f}"
                f" {r['neighbour_ratio']:>9.3f} {r['ms_per_frame']:>9.1f}")  # fmt: skip

    lines = [title, head] + [line(str(r["trajectory"]), str(r["particles"]), r) for r in rows]
    lines.append(line("mean", "", summary) + f"   baseline/model = {summary['baseline_ratio']:.2f}x")
    return "\n".join(lines)


def write_csv(path: str | Path, rows: Sequence[dict]) -> Path:
    """Write dict rows (the union of their keys as columns, first-seen order) as CSV."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return path


def loggable(summary: dict, prefix: str) -> dict[str, float]:
    """The numeric entries of a summary, keys prefixed (``test/rollout_mse``), NaN and None left out."""
    out = {}
    for key, value in summary.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            continue
        out[f"{prefix}/{key}"] = float(value)
    return out


def json_ready(value):
    """``value`` with every NaN/inf float replaced by None (strict JSON has no NaN), recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    return value


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

    Writes ``results.json`` (``"model"``, ``"parameters"``, ``"test"`` -> summary, ``"rows"``),
    ``test_per_frame.csv``, ``test_rollout.<gif|mp4>`` (and ``pretrained_rollout.*``) into ``run_dir``, logs
    the summary to every logger, prints the tables. Returns the trained model's summary.
    """
    from gnsx.pipeline import write_json

    datamodule.setup("test")
    metadata = datamodule.metadata
    simulator = simulator.cpu()
    options = {
        key: cfg.evaluate.get(key, default)
        for key, default in (("emd_every", 10), ("emd_method", "auto"), ("onestep_stride", 10),
                             ("timing_repeats", 20))
    }  # fmt: skip
    per_frame: list[dict] = []
    summary, rows, first = evaluate_simulator(
        simulator,
        datamodule.test_set,
        metadata,
        on_trajectory=lambda result: per_frame.extend(result.per_frame_rows()),
        **options,
    )
    print(
        format_table(
            rows, summary, f"Test rollouts ({cfg.model.name} GNS, this run) vs physics-free baseline"
        )
    )
    results = {
        "model": cfg.model.name,
        "parameters": simulator.num_parameters(),
        "test": summary,
        "rows": rows,
    }
    write_csv(run_dir / "test_per_frame.csv", per_frame)
    suffix = cfg.evaluate.render_format
    if cfg.evaluate.render and first is not None:
        path = render_comparison(first, metadata, run_dir / f"test_rollout.{suffix}", f"{cfg.model.name} GNS")
        log.info("Animation: %s", path)
        results["animation"] = str(path)

    pretrained = cfg.evaluate.pretrained
    if pretrained and Path(pretrained).is_file():
        from gnsx.system import GNSSystem

        shipped = GNSSystem.load_from_checkpoint(pretrained, map_location="cpu").simulator
        p_summary, p_rows, p_first = evaluate_simulator(shipped, datamodule.test_set, metadata, **options)
        print(format_table(p_rows, p_summary, f"Test rollouts (shipped weights {pretrained})"))
        results["pretrained"] = {"checkpoint": str(pretrained), "test": p_summary, "rows": p_rows}
        if cfg.evaluate.render and p_first is not None:
            path = render_comparison(
                p_first, metadata, run_dir / f"pretrained_rollout.{suffix}", "shipped GNS"
            )
            log.info("Animation (shipped weights): %s", path)
            results["pretrained"]["animation"] = str(path)

    write_json(run_dir / "results.json", json_ready(results))
    for logger in loggers:
        logger.log_metrics(loggable(summary, "test"))
    return summary


# ---------------------------------------------------------------------------------------------- checkpoints


def checkpoint_path(path: str | Path) -> Path:
    """A ``.ckpt`` file, or a run directory's ``checkpoints/last.ckpt``.

    Raises:
        FileNotFoundError: naming the path that holds no checkpoint.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "checkpoints" / "last.ckpt"
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no checkpoint here (give a .ckpt file or a run directory)")
    return p


def load_simulator(path: str | Path, device: str | torch.device = "cpu") -> LearnedSimulator:
    """The trained :class:`LearnedSimulator` of a checkpoint (or run directory), eval mode, on ``device``."""
    from gnsx.system import GNSSystem

    system = GNSSystem.load_from_checkpoint(checkpoint_path(path), map_location="cpu")
    return system.simulator.to(device).eval()


def model_label(simulator: LearnedSimulator) -> str:
    """``"simplified GNS 64/5"``, ``"original GNS 128/10"`` or ``"GNS <latent>/<steps>"``, from its config."""
    cfg = simulator.config
    size = f"{cfg['latent_size']}/{cfg['mp_steps']}"
    if cfg["history"] == 1 and cfg["type_encoding"] == "scalar" and not cfg["edge_residual"]:
        return f"simplified GNS {size}"
    if cfg["history"] == 5 and cfg["type_encoding"] == "embedding" and cfg["edge_residual"]:
        return f"original GNS {size}"
    return f"GNS {size}"


def slug(label: str) -> str:
    """A folder name for a label (letters, digits, ``-``, ``_``)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label).strip("_") or "model"


def mean_per_frame(rows: Sequence[dict], keys: Sequence[str] = ("mse", "emd")) -> dict[int, dict[str, float]]:
    """``{frame: {key: mean over trajectories}}`` of per-frame rows (NaN entries ignored)."""
    by_frame: dict[int, dict[str, list[float]]] = {}
    for row in rows:
        for key in keys:
            if not math.isnan(row[key]):
                by_frame.setdefault(row["frame"], {}).setdefault(key, []).append(row[key])
    return {t: {k: float(np.mean(v)) for k, v in values.items()} for t, values in sorted(by_frame.items())}


def evaluate_checkpoints(
    checkpoints: Sequence[str | Path],
    data_root: str | Path,
    out_dir: str | Path,
    split: str = "test",
    labels: Sequence[str] | None = None,
    max_trajectories: int | None = None,
    device: str = "cpu",
    emd_every: int = 10,
    emd_method: str = "auto",
    onestep_stride: int = 10,
    timing_warmup: int = 3,
    timing_repeats: int = 20,
    save_rollouts: bool = True,
    deepmind: bool = False,
    render: bool = True,
    render_trajectory: int = 0,
    render_formats: Sequence[str] = ("gif",),
    frame_stride: int = 2,
    fps: int = 25,
    strip_every: int = 100,
    strip_count: int = 7,
    loggers: Sequence = (),
) -> dict:
    """Evaluate checkpoints on every trajectory of a split and write what a user needs to judge them.

    Writes into ``out_dir``:

    * ``results.json``: ``{"split", "data_root", "models": [{"label", "folder", "checkpoint", "parameters",
      "summary", "rows"}], "outputs"}`` (summary and rows as :func:`evaluate_simulator`'s);
    * per model, in ``<label slug>/``: ``trajectories.csv`` (one row per trajectory), ``per_frame.csv`` (one
      row per trajectory and predicted frame, see :class:`TrajectoryResult`), ``rollouts/<split>_<i>.npz``
      (gnsx rollout files, :mod:`gnsx.rollout_io`; with ``deepmind`` also DeepMind's ``.pkl``);
    * with ``render``: ``comparison.<gif|mp4>`` (ground truth and every model side by side, the paper's
      figure 8, on trajectory ``render_trajectory``), ``strip.png`` (frames 0, ``strip_every``, ... one row
      per panel, figure 1) and ``<label slug>/final_frame.png``.

    Every logger gets ``<split>/<slug>/<metric>`` summaries and the per-frame means of ``mse`` and ``emd``
    (``<split>/<slug>/frame_mse`` at step = frame).

    Args:
        checkpoints: ``.ckpt`` files or run directories.
        data_root: the gnsx dataset (its metadata gives bounds, dt and the neighbour radius).
        labels: one per checkpoint (default :func:`model_label`, made unique).
        Others: see :func:`score_trajectory` and :mod:`gnsx.render`.
    Returns:
        the ``results.json`` payload.
    """
    from gnsx.data.store import SplitReader, load_metadata
    from gnsx.datamodule import TrajectoryDataset
    from gnsx.rollout_io import Rollout, export_deepmind, save_rollout

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    metadata = load_metadata(data_root)
    dataset = TrajectoryDataset(SplitReader(data_root, split), max_trajectories)
    if labels is not None and len(labels) != len(checkpoints):
        raise ValueError(
            f"{len(labels)} labels for {len(checkpoints)} checkpoints; give one label per checkpoint"
        )
    results = {"split": split, "data_root": str(data_root), "models": []}
    panels: list[np.ndarray] = []
    titles: list[str] = []
    shown: dict | None = None
    used: set[str] = set()
    for k, checkpoint in enumerate(checkpoints):
        simulator = load_simulator(checkpoint, device)
        label = labels[k] if labels is not None else model_label(simulator)
        name = slug(label)
        while name in used:
            name += "_"
        used.add(name)
        folder = out_dir / name
        per_frame: list[dict] = []

        def keep(
            result: TrajectoryResult,
            label=label,
            folder=folder,
            per_frame=per_frame,
            checkpoint=checkpoint,
            config=simulator.config,
        ) -> None:
            nonlocal shown
            per_frame.extend(result.per_frame_rows())
            if save_rollouts:
                provenance = {"checkpoint": str(checkpoint), "model": label, "split": split,
                              "trajectory": result.index, "simulator": config}  # fmt: skip
                item = Rollout(
                    predicted=result.predicted,
                    particle_type=result.particle_type,
                    input_frames=result.input_frames,
                    ground_truth=result.ground_truth,
                    metadata=metadata.to_dict() | {"rollout": provenance},
                )
                save_rollout(folder / "rollouts" / f"{split}_{result.index:04d}.npz", item)
                if deepmind:
                    export_deepmind(folder / "rollouts" / f"{split}_{result.index:04d}.pkl", item)
            if render and result.index == render_trajectory:
                panels.append(result.predicted)
                titles.append(label)
                if shown is None:
                    shown = {"ground_truth": result.ground_truth, "particle_type": result.particle_type}

        summary, rows, _ = evaluate_simulator(
            simulator,
            dataset,
            metadata,
            keep_first=False,
            emd_every=emd_every,
            emd_method=emd_method,
            onestep_stride=onestep_stride,
            timing_warmup=timing_warmup,
            timing_repeats=timing_repeats,
            on_trajectory=keep,
        )
        print(format_table(rows, summary, f"{split} rollouts: {label} ({checkpoint})"))
        write_csv(folder / "trajectories.csv", rows)
        write_csv(folder / "per_frame.csv", per_frame)
        results["models"].append(
            {
                "label": label,
                "folder": name,
                "checkpoint": str(checkpoint),
                "parameters": simulator.num_parameters(),
                "summary": summary,
                "rows": rows,
            }  # fmt: skip
        )
        for logger in loggers:
            logger.log_metrics(loggable(summary, f"{split}/{name}"))
            for t, values in mean_per_frame(per_frame).items():
                logger.log_metrics({f"{split}/{name}/frame_{key}": v for key, v in values.items()}, step=t)

    if render and shown is not None:
        from gnsx.render import render_rollouts, save_animation, save_frame, save_strip, speeds

        bounds = metadata.bounds_array()
        rollouts = [shown["ground_truth"], *panels]
        names = ["ground truth", *titles]
        frames = render_rollouts(rollouts, shown["particle_type"], bounds, names, frame_stride=frame_stride)
        outputs = {}
        for fmt in render_formats:
            outputs[f"comparison_{fmt}"] = str(save_animation(frames, out_dir / f"comparison.{fmt}", fps=fps))
        strip = save_strip(rollouts, shown["particle_type"], bounds, out_dir / "strip.png", names,
                           every=strip_every, count=strip_count)  # fmt: skip
        outputs["strip"] = str(strip)
        for model, rollout_positions in zip(results["models"], panels):
            final = save_frame(rollout_positions[-1], shown["particle_type"], bounds,
                               out_dir / model["folder"] / "final_frame.png",
                               speed=speeds(rollout_positions[-2:])[-1], title=model["label"])  # fmt: skip
            model["final_frame"] = str(final)
        results["outputs"] = outputs
    (out_dir / "results.json").write_text(json.dumps(json_ready(results), indent=2))
    return results
