"""Rolling out a learned simulator on whole trajectories and scoring it: errors with their spread, speed.

Per trajectory (:func:`score_trajectory`), the model is rolled out from the first ``history + 1`` ground-truth
frames to the end, and compared with the ground truth and with the physics-free baseline (constant velocity +
gravity, :func:`gnsx.model.rollout.physics_free_baseline`) rolled out from the same frames:

==========================  ==================================================================================
row key                     meaning (positions in data units, metres for WaterRamps-like data)
==========================  ==================================================================================
``rollout_mse``             position MSE per coordinate over dynamic particles and predicted frames
``rollout_mse_all``         the same over all particles, static ones included (as DeepMind reports it)
``mse_at_10``,              ``rollout_mse`` over the first 10 / 50 predicted frames only (NaN when the rollout
``mse_at_50``               predicts fewer frames): short-horizon accuracy, before the errors compound
``com_mse``                 the part of ``rollout_mse`` that is the water's centre-of-mass error (the rest is
                            its shape's, :func:`gnsx.evaluation.metrics.centre_of_mass_mse`)
``onestep_mse``             position MSE of single steps from ground-truth inputs (every ``onestep_stride``-th
                            frame)
``baseline_mse``            ``rollout_mse`` of the physics-free baseline; ``baseline_mse_at_10``,
                            ``baseline_mse_at_50``: its horizons
``baseline_ratio``          ``baseline_mse / rollout_mse``: above 1 the model beats the baseline
``emd``                     Earth Mover's distance between predicted and true water, mean over the frames
                            that are multiples of ``emd_every`` (and the last); ``emd_final``: the last frame
``baseline_emd``            ``emd`` of the baseline, on the same frames
``kinetic_energy_error``    ``mean_t |E_pred - E_true| / mean_t E_true``, E the mean kinetic energy per unit
                            mass
``neighbour_ratio``         mean over the EMD frames of (mean neighbours within R, predicted / true): above 1
                            the rollout compressed the fluid (volume loss), below 1 it spread it
``area_ratio_final``        area the water covers at the last frame, predicted / true
                            (:func:`gnsx.evaluation.metrics.area_ratio`, cells of 2 particle spacings, the spacing
                            measured on the first true frame): below 1 the water was lumped or packed
``out_of_bounds_fraction``  dynamic particles outside the walls, fraction, mean over predicted frames;
                            ``out_of_bounds_final``: their number at the last frame
``nonfinite``               :func:`gnsx.evaluation.health.rollout_health` of the prediction: NaN/Inf coordinates; the
``max_speed``               fastest dynamic particle (m/s); steps through a ramp; the most particles outside
``ramp_crossings``          the box at any frame; whether it blew up (NaN, or faster than the blow-up speed).
``out_of_bounds_max``       A rollout held by its boundary (the default) has no crossing and nobody outside
``blew_up``
``ms_per_frame``            :func:`gnsx.evaluation.timing.measure_inference` on the trajectory's first frames (median
                            after warm-up, graph build included); ``peak_memory_mb`` likewise
``rollout_ms_per_frame``    wall time of the whole rollout per frame (graph build included)
==========================  ==================================================================================

:func:`summarise` turns the rows into a summary with the spread over trajectories (:mod:`gnsx.evaluation.spread`):

===============================  =============================================================================
summary key                      meaning
===============================  =============================================================================
``<key>``                        mean over trajectories of every row error above (``rollout_mse``,
                                 ``mse_at_10``, ``baseline_emd``, ..., NaN rows left out)
``<key>_se``                     its standard error: sample std (``ddof=1``) / sqrt(n); NaN for n < 2
``baseline_ratio``               ratio of the means, ``baseline_mse / rollout_mse``
``baseline_ratio_geomean``       geometric mean of the per-trajectory ``baseline_ratio``; ``_lo``, ``_hi``:
                                 its 95% interval (t distribution on the log ratios; NaN for n < 2). Below 1
                                 the model does not beat the baseline; an interval containing 1: the two
                                 cannot be told apart
``baseline_ratio_wins``          trajectories on which the model's ``rollout_mse`` is below the baseline's
``ms_per_frame``                 median over trajectories; ``peak_memory_mb``: the max; ``trajectories``: n
``blow_ups``                     trajectories whose rollout blew up (``blew_up``); ``max_speed_max``: the
                                 fastest particle of all, m/s
===============================  =============================================================================

:func:`evaluate_simulator` runs every trajectory and summarises; :func:`format_table` prints the result.
Two models are compared with :func:`gnsx.evaluation.spread.compare` (paired by trajectory). This module is the library
under ``train.py``'s end-of-training evaluation and ``evaluate.py`` (:mod:`gnsx.evaluation.evaluate`); it imports
neither them nor the Lightning system.
"""

from __future__ import annotations

import csv
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.evaluation.health import describe, rollout_health
from gnsx.evaluation.metrics import (
    area_ratio,
    centre_of_mass_mse,
    earth_movers_distance,
    kinetic_energy,
    kinetic_energy_error,
    neighbour_count,
    out_of_bounds,
    particle_spacing,
    position_mse,
    position_mse_per_frame,
)
from gnsx.evaluation.spread import (
    DOES_NOT_BEAT,
    alarm,
    baseline_verdict,
    geometric_mean_interval,
    interval_contains_one,
    mean_se,
    use_colour,
)
from gnsx.evaluation.timing import measure_inference
from gnsx.model.rollout import physics_free_baseline, rollout
from gnsx.model.simulator import LearnedSimulator
from gnsx.rules.rollout import rollout_with_rules
from gnsx.rules.rules import Rules

#: Gravity of WaterRamps-like data (m/s^2, along -y); the baseline moves particles by g*dt^2 per frame^2.
GRAVITY = 9.8
#: One-step MSE batches its windows into graphs of at most this many nodes (bounds the memory).
_ONESTEP_MAX_NODES = 200_000
#: Rollout MSE horizons: ``mse_at_<h>`` is the MSE over the first ``h`` predicted frames.
HORIZONS = (10, 50)
#: Summary keys averaged over trajectories, each with its standard error ``<key>_se`` (the speed is a median,
#: the memory a max).
_MEAN_KEYS = (
    "rollout_mse",
    "rollout_mse_all",
    *(f"mse_at_{h}" for h in HORIZONS),
    "com_mse",
    "onestep_mse",
    "baseline_mse",
    *(f"baseline_mse_at_{h}" for h in HORIZONS),
    "emd",
    "baseline_emd",
    "emd_final",
    "kinetic_energy_error",
    "neighbour_ratio",
    "area_ratio_final",
    "out_of_bounds_fraction",
    "out_of_bounds_final",
    "ramp_crossings",
    "max_speed",
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
            frames off the EMD grid for ``emd`` / ``baseline_emd`` / ``neighbours_*``): ``mse``, ``mse_all``,
            ``baseline_mse``, ``emd``, ``baseline_emd``, ``kinetic_energy_pred``, ``kinetic_energy_true``
            (J/kg), ``neighbours_pred``, ``neighbours_true``, ``out_of_bounds`` (count).
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


def horizon_mse(per_frame_mse: np.ndarray, input_frames: int, horizon: int) -> float:
    """Mean of a ``[T]`` per-frame MSE over the first ``horizon`` predicted frames (``input_frames`` to
    ``input_frames + horizon - 1``); NaN when fewer frames were predicted."""
    predicted = np.asarray(per_frame_mse, dtype=np.float64)[input_frames:]
    if horizon < 1 or len(predicted) < horizon:
        return float("nan")
    return float(np.mean(predicted[:horizon]))


@torch.inference_mode()
def onestep_predictions(
    simulator: LearnedSimulator, position: torch.Tensor, particle_type: torch.Tensor, starts: Sequence[int]
) -> Iterator[tuple[list[int], torch.Tensor]]:
    """Single steps from ground-truth inputs ``p[s..s+H]`` for each ``s`` of ``starts``, batched as disjoint
    graphs of at most ``_ONESTEP_MAX_NODES`` nodes.

    Args:
        position: ``[T, N, D]`` ground truth; particle_type: ``[N]``.
    Yields:
        ``(chunk, predicted)``: the starts of one batch and their predicted frames ``s + H + 1``,
        ``[len(chunk), N, D]``.
    """
    frames = simulator.input_frames
    num_particles, dim = position.shape[1], position.shape[2]
    per_batch = max(1, _ONESTEP_MAX_NODES // max(num_particles, 1))
    for i in range(0, len(starts), per_batch):
        chunk = list(starts[i : i + per_batch])
        windows = torch.stack([position[s : s + frames] for s in chunk])  # [K, H+1, N, D]
        k = len(chunk)
        sequence = windows.permute(0, 2, 1, 3).reshape(k * num_particles, frames, dim)
        graph = torch.arange(k, device=position.device).repeat_interleave(num_particles)
        predicted = simulator.predict_positions(sequence, particle_type.repeat(k), batch=graph)
        yield chunk, predicted.reshape(k, num_particles, dim)


def onestep_mse(
    simulator: LearnedSimulator, position: torch.Tensor, particle_type: torch.Tensor, stride: int = 10
) -> float:
    """Position MSE per coordinate of single-step predictions from ground-truth inputs (dynamic particles),
    on every ``stride``-th input window (:func:`onestep_predictions`).

    Args:
        position: ``[T, N, D]`` ground truth; particle_type: ``[N]``.
    """
    frames = simulator.input_frames
    starts = list(range(0, position.shape[0] - frames, max(stride, 1)))
    if not starts:
        return float("nan")
    dynamic = particle_type != KINEMATIC_PARTICLE_ID
    total, count = 0.0, 0
    for chunk, predicted in onestep_predictions(simulator, position, particle_type, starts):
        target = position[torch.tensor(chunk, device=position.device) + frames]  # [K, N, D]
        error = (predicted - target) ** 2
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
        scalars (``rollout_mse``, ``rollout_mse_all``, ``com_mse``, ``mse_at_<h>`` for each of
        :data:`HORIZONS`, ``emd``,
        ``emd_final``, ``kinetic_energy_error``, ``neighbour_ratio``, ``area_ratio_final``,
        ``out_of_bounds_fraction``,
        ``out_of_bounds_final``) and ``[T]`` per-frame arrays (NaN where not computed) as in
        :class:`TrajectoryResult`, the baseline's aside.
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
        "com_mse": centre_of_mass_mse(predicted[frames:], true[frames:], mask),
        **{f"mse_at_{h}": horizon_mse(per_frame["mse"], frames, h) for h in HORIZONS},
        "emd": float(np.mean(emd)),
        "emd_final": float(emd[-1]),
        "kinetic_energy_error": kinetic_energy_error(
            per_frame["kinetic_energy_pred"][frames:], per_frame["kinetic_energy_true"][frames:]
        ),
        "neighbour_ratio": float(np.mean(ratio)) if set_frames else float("nan"),
        "area_ratio_final": area_ratio(predicted[-1, mask], true[-1, mask], particle_spacing(true[0, mask])),
        "out_of_bounds_fraction": float(
            np.mean(per_frame["out_of_bounds"][frames:]) / max(int(mask.sum()), 1)
        ),
        "out_of_bounds_final": int(per_frame["out_of_bounds"][-1]),
    }
    return errors, per_frame


def baseline_errors(
    true: np.ndarray,
    particle_type: np.ndarray,
    input_frames: int,
    metadata: Metadata,
    emd_every: int = 10,
    emd_method: str = "auto",
) -> tuple[np.ndarray, dict, dict[str, np.ndarray]]:
    """The physics-free baseline rolled out from the first ``input_frames`` true frames, and its errors.

    Args:
        true: ``[T, N, D]`` ground-truth positions; particle_type: ``[N]``.
        input_frames, metadata, emd_every, emd_method: as in :func:`rollout_errors`.
    Returns:
        ``baseline [T, N, D]`` (the true first ``input_frames`` frames, then the baseline's), the row keys
        ``baseline_mse``, ``baseline_mse_at_<h>``, ``baseline_emd``, and the ``[T]`` per-frame arrays
        ``baseline_mse`` and ``baseline_emd`` (NaN where not computed).
    """
    frames, num_frames = input_frames, true.shape[0]
    initial = torch.from_numpy(np.array(true[:frames])).transpose(0, 1)  # [N, H+1, D], a writable copy
    predicted = physics_free_baseline(
        initial, torch.tensor(particle_type), num_frames - frames, gravity_per_frame(metadata),
        metadata.bounds_array(),
    )  # fmt: skip
    baseline = np.concatenate([true[:frames], predicted.numpy()])
    dynamic = np.asarray(particle_type) != KINEMATIC_PARTICLE_ID
    per_frame = {key: np.full(num_frames, np.nan) for key in ("baseline_mse", "baseline_emd")}
    per_frame["baseline_mse"][frames:] = position_mse_per_frame(baseline[frames:], true[frames:], dynamic)
    set_frames = distribution_frames(num_frames, frames, emd_every)  # the frames of the model's emd
    for t in set_frames:
        per_frame["baseline_emd"][t] = earth_movers_distance(
            baseline[t, dynamic], true[t, dynamic], method=emd_method
        )
    row = {
        "baseline_mse": position_mse(baseline[frames:], true[frames:], dynamic),
        **{f"baseline_mse_at_{h}": horizon_mse(per_frame["baseline_mse"], frames, h) for h in HORIZONS},
        "baseline_emd": float(np.mean(per_frame["baseline_emd"][set_frames])) if set_frames else float("nan"),
    }
    return baseline, row, per_frame


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
    constrain: bool = True,
    rules: Rules | None = None,
) -> TrajectoryResult:
    """Roll out one trajectory from its first ``history + 1`` frames and compute every metric.

    Args:
        simulator: the model (rolled out on its device).
        position: ``[T, N, D]`` ground-truth positions (data units); particle_type: ``[N]`` int64.
        metadata: the dataset's metadata (bounds, dt for energies, connectivity radius for neighbour counts,
            gravity for the baseline).
        index: the trajectory's index in its split (reported in the rows).
        emd_every: EMD and neighbour counts on frames that are multiples of this (and the last); 0: skip them.
        emd_method: ``"exact"``, ``"sinkhorn"`` or ``"auto"`` (:func:`gnsx.evaluation.metrics.earth_movers_distance`).
        onestep_stride: one-step MSE on every ``onestep_stride``-th frame.
        timing_warmup, timing_repeats: :func:`gnsx.evaluation.timing.measure_inference` on the initial frames;
            ``timing_repeats=0`` skips it (``ms_per_frame`` and ``peak_memory_mb`` are then NaN/None).
        constrain: hold the model's rollout by the walls and ramps (:class:`gnsx.model.boundary.Boundary`)
            and the ``rules``; ``False`` scores the raw model. The baseline is always held by the boundary.
        rules: with ``constrain``, the simulator's rules on the model's rollout
            (:class:`gnsx.rules.rules.Rules`; ``None``: none of them).
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
        torch.cat(
            [
                position[:frames],
                rollout_with_rules(simulator, initial, particle_type, steps, rules, constrain=constrain),
            ]
        )
        .cpu()
        .numpy()
    )
    rollout_seconds = time.perf_counter() - start
    true = position.cpu().numpy()
    types = particle_type.cpu().numpy()
    errors, per_frame = rollout_errors(predicted, true, types, frames, metadata, emd_every, emd_method)
    baseline, baseline_row, baseline_per_frame = baseline_errors(
        true, types, frames, metadata, emd_every, emd_method
    )
    per_frame |= baseline_per_frame
    health = rollout_health(predicted, types, metadata, first_frame=frames)
    row = {
        "trajectory": int(index),
        "particles": int(position.shape[1]),
        "frames": int(steps),
        **errors,
        "onestep_mse": onestep_mse(simulator, position, particle_type, onestep_stride),
        **baseline_row,
        "baseline_ratio": baseline_row["baseline_mse"] / max(errors["rollout_mse"], 1e-30),
        "ms_per_frame": float(timing["ms_per_frame"]),
        "peak_memory_mb": timing["peak_memory_mb"],
        "rollout_ms_per_frame": 1000 * rollout_seconds / steps,
        **{k: v for k, v in health.items() if k not in ("speed_limit", "out_of_bounds_final")},
    }
    if health["blew_up"]:
        print(f"warning: trajectory {index} blew up: {describe(health)}", file=sys.stderr)
    return TrajectoryResult(index, row, per_frame, true, predicted, baseline, types, frames)


def summarise(rows: Sequence[dict]) -> dict:
    """Summary over trajectories (keys in the module docstring): means of the errors with their standard
    errors, the baseline ratio (ratio of means, and geometric mean of the per-trajectory ratios with its 95%
    interval and the model's wins), median ``ms_per_frame``, max ``peak_memory_mb``.

    Rows without a key (e.g. written before it existed) leave it out of the summary.
    """
    summary = {}
    for key in _MEAN_KEYS:
        if rows and key in rows[0]:
            summary[key], summary[f"{key}_se"] = mean_se(r.get(key) for r in rows)
    speeds = [r["ms_per_frame"] for r in rows if not math.isnan(r.get("ms_per_frame", math.nan))]
    summary["ms_per_frame"] = float(np.median(speeds)) if speeds else float("nan")
    memory = [r["peak_memory_mb"] for r in rows if r.get("peak_memory_mb") is not None]
    summary["peak_memory_mb"] = float(max(memory)) if memory else None
    summary["trajectories"] = len(rows)
    if rows and "blew_up" in rows[0]:
        summary["blow_ups"] = sum(bool(r.get("blew_up")) for r in rows)
        summary["max_speed_max"] = max(float(r.get("max_speed", float("nan"))) for r in rows)
    if "baseline_mse" in summary:
        summary["baseline_ratio"] = summary["baseline_mse"] / max(summary["rollout_mse"], 1e-30)
        ratios = [r.get("baseline_ratio", _ratio(r.get("baseline_mse"), r.get("rollout_mse"))) for r in rows]
        geomean, lo, hi, _ = geometric_mean_interval(ratios)
        summary |= {"baseline_ratio_geomean": geomean, "baseline_ratio_geomean_lo": lo,
                    "baseline_ratio_geomean_hi": hi}  # fmt: skip
        summary["baseline_ratio_wins"] = sum(
            _ratio(r.get("baseline_mse"), r.get("rollout_mse")) > 1 for r in rows
        )
    return summary


def _ratio(numerator, denominator) -> float:
    """``numerator / denominator`` (NaN when either is missing or NaN; the denominator at least 1e-30)."""
    if numerator is None or denominator is None:
        return float("nan")
    return float(numerator) / max(float(denominator), 1e-30)


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
    constrain: bool = True,
    rules: Rules | None = None,
    on_trajectory: Callable[[TrajectoryResult], None] | None = None,
) -> tuple[dict, list[dict], dict | None]:
    """Roll out and score every trajectory (see :func:`score_trajectory` for the arguments).

    Args:
        trajectories: dicts with ``position [T, N, D]`` and ``particle_type [N]`` tensors (and optionally
            ``index``), e.g. a :class:`~gnsx.data.datamodule.TrajectoryDataset`.
        keep_first: return the first trajectory's positions for rendering.
        on_trajectory: called with each :class:`TrajectoryResult` as it is done (to save rollouts or per-frame
            rows without keeping every trajectory in memory).
    Returns:
        ``(summary, rows, first)``: the summary (:func:`summarise`, keys in the module docstring), one row of
        scalars per trajectory (:func:`score_trajectory`), and the first trajectory's
        ``ground_truth``/``predicted``/``baseline`` ``[T, N, D]`` and ``particle_type`` as numpy (None if
        ``keep_first`` is False).
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
            constrain=constrain,
            rules=rules,
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


#: Columns of :func:`format_table`: (header, row key, width, format).
_TABLE_COLUMNS = (
    ("rollout MSE", "rollout_mse", 11, ".3e"),
    *((f"MSE@{h}", f"mse_at_{h}", 9, ".2e") for h in HORIZONS),
    ("one-step", "onestep_mse", 9, ".2e"),
    ("baseline", "baseline_mse", 9, ".2e"),
    *((f"base@{h}", f"baseline_mse_at_{h}", 9, ".2e") for h in HORIZONS),
    ("base/model", "baseline_ratio", 10, ".2f"),
    ("EMD", "emd", 9, ".2e"),
    ("base EMD", "baseline_emd", 9, ".2e"),
    ("KE err", "kinetic_energy_error", 7, ".2f"),
    ("nbr ratio", "neighbour_ratio", 9, ".3f"),
    ("area", "area_ratio_final", 5, ".2f"),
    ("ms/frame", "ms_per_frame", 9, ".1f"),
)


def format_table(rows: list[dict], summary: dict, title: str, colour: bool | None = None) -> str:
    """A plain-text table of per-trajectory errors, their means and standard errors, and the verdict against
    the physics-free baseline.

    Below the rows: a ``mean`` line, a ``± se`` line (standard errors over trajectories), the baseline ratio
    (ratio of means; geometric mean of the per-trajectory ratios with its 95% interval; the model's wins),
    and a verdict line: ``MODEL DOES NOT BEAT THE PHYSICS-FREE BASELINE`` when the geometric mean is below 1
    (in red when ``colour``; default: stdout is a terminal or ``FORCE_COLOR`` is set), ``cannot be told apart
    from the baseline`` when the interval contains 1.
    """
    colour = use_colour(sys.stdout) if colour is None else colour
    head = f"{'traj':>5} {'particles':>9} " + " ".join(f"{h:>{w}}" for h, _, w, _ in _TABLE_COLUMNS)

    def line(name: str, particles: str, r: dict, keys: Callable[[str], str] = lambda k: k) -> str:
        cells = []
        for _, key, width, fmt in _TABLE_COLUMNS:
            value = r.get(keys(key))
            cells.append(f"{'' if value is None else format(float(value), fmt):>{width}}")
        return f"{name:>5} {particles:>9} " + " ".join(cells)

    lines = [title, head] + [line(str(r["trajectory"]), str(r["particles"]), r) for r in rows]
    means = {k: v for k, v in summary.items() if k != "baseline_ratio"}  # the ratio column: see below
    lines.append(line("mean", "", means))
    lines.append(line("± se", "", summary, keys=lambda k: f"{k}_se"))
    lines.extend(baseline_lines(summary, colour))
    if summary.get("blow_ups"):
        message = (
            f"{summary['blow_ups']}/{summary['trajectories']} ROLLOUTS BLEW UP (NaN, or a particle at "
            f"{summary['max_speed_max']:.3g} m/s): see the rows' blew_up, max_speed and nonfinite"
        )
        lines.append(alarm(message, colour))
    return "\n".join(lines)


def baseline_lines(summary: dict, colour: bool = False) -> list[str]:
    """The baseline ratio of a :func:`summarise` summary and the verdict: :func:`format_table`'s end."""
    if "baseline_ratio" not in summary:
        return []
    geomean, lo, hi = (
        float("nan") if summary.get(key) is None else float(summary[key])
        for key in ("baseline_ratio_geomean", "baseline_ratio_geomean_lo", "baseline_ratio_geomean_hi")
    )
    n = summary.get("trajectories", 0)
    interval = f"[{lo:.2f}, {hi:.2f}] (95%, t)" if math.isfinite(lo) else "[interval needs 2+ trajectories]"
    lines = [
        f"baseline/model MSE: ratio of means {summary['baseline_ratio']:.2f}x; geometric mean {geomean:.2f}x"
        f" {interval}; the model wins on {summary.get('baseline_ratio_wins', 0)}/{n} trajectories"
    ]
    verdict = baseline_verdict(geomean, lo, hi)
    if verdict == DOES_NOT_BEAT:
        lines.append(alarm("MODEL DOES NOT BEAT THE PHYSICS-FREE BASELINE", colour))
    if not math.isfinite(lo):
        lines.append("Too few trajectories to tell the model from the baseline (score 2 or more).")
    elif verdict is not None and interval_contains_one(lo, hi):
        lines.append("The model cannot be told apart from the baseline (the interval contains 1).")
    elif verdict is not None and verdict != DOES_NOT_BEAT:
        lines.append("The model beats the physics-free baseline (the interval lies above 1).")
    return lines


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


def mean_per_frame(rows: Sequence[dict], keys: Sequence[str] = ("mse", "emd")) -> dict[int, dict[str, float]]:
    """``{frame: {key: mean over trajectories}}`` of per-frame rows (NaN entries ignored)."""
    by_frame: dict[int, dict[str, list[float]]] = {}
    for row in rows:
        for key in keys:
            if not math.isnan(row[key]):
                by_frame.setdefault(row["frame"], {}).setdefault(key, []).append(row[key])
    return {t: {k: float(np.mean(v)) for k, v in values.items()} for t, values in sorted(by_frame.items())}


@torch.inference_mode()
def evaluate_trajectory(
    simulator: LearnedSimulator, position: torch.Tensor, particle_type: torch.Tensor, onestep_stride: int = 10
) -> dict[str, float]:
    """Rollout and one-step position MSE of one trajectory (the validation metrics).

    Args:
        position: ``[T, N, D]`` ground-truth positions.
        particle_type: ``[N]``.
    Returns:
        ``rollout_mse``: MSE per coordinate over dynamic particles and all predicted frames, the rollout
        starting from the first ``history + 1`` ground-truth frames; ``onestep_mse``: the same for single
        steps from ground-truth inputs on every ``onestep_stride``-th frame
        (:func:`onestep_mse`); ``area_ratio_final``: the area the water covers at the last frame, predicted
        over true (:func:`gnsx.evaluation.metrics.area_ratio`; below 1 the rollout lost volume).
    """
    frames = simulator.input_frames
    position = position.to(simulator.acc_std.device)
    particle_type = particle_type.to(position.device)
    dynamic = particle_type != KINEMATIC_PARTICLE_ID
    initial = position[:frames].transpose(0, 1)
    predicted = rollout(simulator, initial, particle_type, position.shape[0] - frames)
    water = dynamic.cpu().numpy()
    true_final, true_first = position[-1].cpu().numpy()[water], position[0].cpu().numpy()[water]
    return {
        "rollout_mse": position_mse(predicted, position[frames:], dynamic),
        "onestep_mse": onestep_mse(simulator, position, particle_type, stride=onestep_stride),
        "area_ratio_final": area_ratio(
            predicted[-1].cpu().numpy()[water], true_final, particle_spacing(true_first)
        ),
    }
