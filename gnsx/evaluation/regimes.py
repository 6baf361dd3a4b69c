"""Where a model's error comes from: by horizon, by regime of the flow, one step against the rollout.

``python -m gnsx.evaluation.regimes CKPT [CKPT ...] --data <dataset> --split test --out <dir>``

Every particle of every frame of the ground truth is put in one regime, from its true motion (the MPM's):

* ``flight``: ballistic, its acceleration within :data:`FLIGHT_TOLERANCE` of gravity. In the MPM a block in
  free flight has no internal stress, so every particle of it falls at exactly g, and the physics-free
  baseline (constant velocity plus gravity) predicts it exactly;
* ``pool``: at rest or nearly (speed below :data:`REST_FRAMES` frames of free fall from rest) and not ballistic:
  water resting in a pool or on the floor;
* ``impact``: everything else: impacts on walls, ramps and water, and flowing water.

For each model, and for the physics-free baseline:

* the rollout's position MSE (per coordinate, dynamic particles) over the first 10, 50 and 100 predicted frames
  and over all of them (:func:`gnsx.evaluation.scoring.horizon_mse`);
* the rollout's MSE within each regime, a particle-frame counted in the regime its truth is in at that frame;
* the one-step MSE within each regime: the position error of one step from the true input frames, counted in
  the regime of the frame the step starts from (its true acceleration is what the step predicts).

Each figure is a mean over trajectories with its standard error; the share column is the regime's share of
the particle-frames. One-step errors are ~1e-8 where rollouts reach 1e-2: a model that is good one step at a
time can still lose a regime in the rollout, which is what the two columns side by side show.

With two checkpoints or more, a third table pairs every later model with the first on the same trajectories:
its error over the first's per horizon and regime, the geometric mean over trajectories with a 95% t interval
(an interval containing 1: the two cannot be told apart there). Pass the reference first, e.g. the shipped
weights and then a new model.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main
from gnsx.core.constants import KINEMATIC_PARTICLE_ID
from gnsx.data.metadata import Metadata
from gnsx.evaluation.scoring import baseline_errors, gravity_per_frame, horizon_mse, onestep_predictions
from gnsx.evaluation.spread import geometric_mean_interval, interval_contains_one, mean_se
from gnsx.model.rollout import rollout
from gnsx.model.simulator import LearnedSimulator

#: The regimes, in the order of their integer labels.
REGIMES = ("flight", "impact", "pool")
FLIGHT, IMPACT, POOL = 0, 1, 2
#: Not labelled: static particles, and the first and last frame (no acceleration there).
UNLABELLED = -1
#: Ballistic: ``|a - g| <= FLIGHT_TOLERANCE |g|`` (the MPM's free flight is exact to float rounding).
FLIGHT_TOLERANCE = 0.1
#: At rest: speed per frame below the speed of REST_FRAMES frames of free fall from rest, ``REST_FRAMES |g|``.
REST_FRAMES = 3.0
#: Rollout horizons reported, in predicted frames; None is the whole rollout.
HORIZONS = (10, 50, 100, None)
#: The physics-free baseline's row label; the last column divides each model's one-step MSE by its.
BASELINE_LABEL = "physics-free baseline"


def classify(position: np.ndarray, particle_type: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """The regime of every particle at every frame of a true trajectory.

    Args:
        position: ``[T, N, D]`` true positions (data units); particle_type: ``[N]``.
        gravity: ``[D]`` gravity as a per-frame position increment (data units / frame^2).
    Returns:
        ``[T, N]`` int8 labels (:data:`FLIGHT`, :data:`IMPACT`, :data:`POOL`, :data:`UNLABELLED`).
    """
    position = np.asarray(position, dtype=np.float64)
    labels = np.full(position.shape[:2], UNLABELLED, dtype=np.int8)
    velocity = position[1:-1] - position[:-2]  # [T-2, N, D]: into frame t = 1..T-2
    acceleration = position[2:] - 2 * position[1:-1] + position[:-2]
    g = float(np.linalg.norm(gravity))
    ballistic = np.linalg.norm(acceleration - gravity, axis=-1) <= FLIGHT_TOLERANCE * g
    resting = np.linalg.norm(velocity, axis=-1) <= REST_FRAMES * g
    inner = np.where(ballistic, FLIGHT, np.where(resting, POOL, IMPACT)).astype(np.int8)
    inner[:, np.asarray(particle_type) == KINEMATIC_PARTICLE_ID] = UNLABELLED
    labels[1:-1] = inner
    return labels


def onestep_positions(
    simulator: LearnedSimulator, position: torch.Tensor, particle_type: torch.Tensor
) -> np.ndarray:
    """``[T, N, D]`` one-step predictions from the true input frames (the scoring library's
    :func:`~gnsx.evaluation.scoring.onestep_predictions`, every window): entry ``k + 1`` is predicted from true
    frames ``k - H .. k``; NaN where no step lands (the first ``H + 1`` frames)."""
    frames = simulator.input_frames
    out = np.full(tuple(position.shape), np.nan)
    starts = range(0, position.shape[0] - frames)
    for chunk, predicted in onestep_predictions(simulator, position, particle_type, starts):
        out[np.array(chunk) + frames] = predicted.cpu().numpy()
    return out


def ballistic_onestep(position: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """``[T, N, D]`` the physics-free baseline's one step from every true frame pair: entry ``k + 1`` is
    ``2 x_k - x_{k-1} + g`` (no walls: one step from true frames never reaches one); NaN for the first two.

    Its one-step error is the true acceleration's departure from gravity, ``|a - g|^2``: the part of the motion a
    model has to learn. A model's one-step MSE over the baseline's, per regime, is the share of that part it
    has not learned."""
    out = np.full(position.shape, np.nan)
    out[2:] = 2 * position[1:-1] - position[:-2] + gravity
    return out


def _regime_mse(squared: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """Mean over particle-frames of ``squared [T, N]`` within each regime (NaN for an absent regime)."""
    out = {}
    for index, name in enumerate(REGIMES):
        mask = labels == index
        out[name] = float(squared[mask].mean()) if mask.any() else float("nan")
    return out


def trajectory_sources(
    predicted: np.ndarray, onestep: np.ndarray | None, true: np.ndarray, labels: np.ndarray, input_frames: int
) -> dict[str, Any]:
    """One trajectory's errors by horizon and regime.

    Args:
        predicted: ``[T, N, D]`` a rollout whose first ``input_frames`` frames are the truth's.
        onestep: ``[T, N, D]`` one-step predictions (:func:`onestep_positions`, :func:`ballistic_onestep`) or
            None.
        true: ``[T, N, D]``; labels: ``[T, N]`` (:func:`classify`).
    Returns:
        ``{"horizon": {h: mse}, "rollout": {regime: mse}, "onestep": {regime: mse}, "share": {regime: f}}``.
    """
    dynamic = labels.max(axis=0) != UNLABELLED  # static particles are never labelled
    squared = ((predicted - true) ** 2).mean(axis=-1)  # [T, N] per coordinate
    per_frame = np.full(true.shape[0], np.nan)
    per_frame[input_frames:] = squared[input_frames:, dynamic].mean(axis=1)
    frames = true.shape[0] - input_frames
    horizon = {str(h or "all"): horizon_mse(per_frame, input_frames, h or frames) for h in HORIZONS}
    scored = labels.copy()
    scored[:input_frames] = UNLABELLED  # the input frames are the truth's: not predicted
    out = {"horizon": horizon, "rollout": _regime_mse(squared, scored)}
    if onestep is not None:
        step_squared = ((onestep - true) ** 2).mean(axis=-1)  # entry k+1: the step from frame k
        step_labels = np.full_like(labels, UNLABELLED)
        step_labels[1:] = labels[:-1]  # counted in the regime of the frame the step starts from
        step_labels[:input_frames] = UNLABELLED
        out["onestep"] = _regime_mse(np.nan_to_num(step_squared), step_labels)
    counts = np.array([(scored == i).sum() for i in range(len(REGIMES))], dtype=np.float64)
    out["share"] = dict(zip(REGIMES, (counts / max(counts.sum(), 1)).tolist()))
    return out


def summarise(rows: Sequence[dict]) -> dict[str, Any]:
    """Mean ± SE over trajectories of every figure of :func:`trajectory_sources`' rows."""
    out: dict[str, Any] = {}
    for group in rows[0]:
        out[group] = {key: mean_se([row[group][key] for row in rows]) for key in rows[0][group]}
    return out


def model_rows(
    simulator: LearnedSimulator | None, trajectories: Sequence[dict], metadata: Metadata
) -> list[dict[str, Any]]:
    """:func:`trajectory_sources` of every trajectory (``{"position" [T, N, D], "particle_type" [N]}`` tensors)
    for a model, or for the physics-free baseline when ``simulator`` is None (one input frame pair)."""
    gravity = gravity_per_frame(metadata).numpy()
    rows = []
    for trajectory in trajectories:
        position, types = trajectory["position"], trajectory["particle_type"]
        true = position.numpy().astype(np.float64)
        labels = classify(true, types.numpy(), gravity)
        if simulator is None:
            frames = 2  # the baseline reads one velocity
            predicted, _, _ = baseline_errors(position.numpy(), types.numpy(), frames, metadata, emd_every=0)
            onestep = ballistic_onestep(true, gravity)
            rows.append(trajectory_sources(predicted.astype(np.float64), onestep, true, labels, frames))
            continue
        frames = simulator.input_frames
        initial = position[:frames].transpose(0, 1)
        with torch.inference_mode():
            rolled = rollout(simulator, initial, types, position.shape[0] - frames).numpy()
        predicted = np.concatenate([true[:frames], rolled.astype(np.float64)])
        onestep = onestep_positions(simulator, position, types)
        rows.append(trajectory_sources(predicted, onestep, true, labels, frames))
    return rows


def model_sources(
    simulator: LearnedSimulator | None, trajectories: Sequence[dict], metadata: Metadata
) -> dict[str, Any]:
    """:func:`summarise` of :func:`model_rows`: mean ± SE over the trajectories."""
    return summarise(model_rows(simulator, trajectories, metadata))


def paired_ratios(rows: Sequence[dict], reference: Sequence[dict]) -> dict[str, dict[str, tuple]]:
    """A model's error over a reference model's on the same trajectories, for every figure of
    :func:`trajectory_sources` but the shares.

    Args:
        rows, reference: per-trajectory rows of the two models (:func:`model_rows`), same trajectories in the
            same order.
    Returns:
        ``{group: {key: (geometric mean, low, high, n)}}`` (:func:`~gnsx.evaluation.spread.geometric_mean_interval`;
        a trajectory where either error is absent or zero is left out).
    """
    if len(rows) != len(reference):
        raise ValueError(
            f"paired ratios need the same trajectories: {len(rows)} rows against {len(reference)}"
        )
    out: dict[str, dict[str, tuple]] = {}
    for group in ("horizon", "rollout", "onestep"):
        if group not in rows[0] or group not in reference[0]:
            continue
        out[group] = {}
        for key in rows[0][group]:
            mine = np.array([row[group][key] for row in rows], dtype=np.float64)
            theirs = np.array([row[group][key] for row in reference], dtype=np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                out[group][key] = geometric_mean_interval(mine / theirs)
    return out


def _fmt(pair: tuple[float, float]) -> str:
    mean, se = pair
    if not np.isfinite(mean):
        return "–"
    return f"{mean:.3g} ± {se:.2g}" if np.isfinite(se) else f"{mean:.3g}"


def table(sources: dict[str, dict]) -> list[str]:
    """Markdown: one table by horizon, one by regime (rollout and one step side by side, and the one-step MSE
    over the baseline's: the share of the non-gravitational acceleration a model has not learned)."""
    first = next(iter(sources.values()))
    horizons = list(first["horizon"])
    lines = ["| model | " + " | ".join(f"rollout MSE, first {h} frames" if h != "all" else "rollout MSE, all"
                                         for h in horizons) + " |",  # fmt: skip
             "|---|" + "---|" * len(horizons)]  # fmt: skip
    for name, src in sources.items():
        lines.append(f"| {name} | " + " | ".join(_fmt(src["horizon"][h]) for h in horizons) + " |")
    lines += [
        "",
        "| model | regime | share of particle-frames | rollout MSE | one-step MSE | one-step / baseline's |",
        "|---|---|---|---|---|---|",
    ]
    reference = sources.get(BASELINE_LABEL, {}).get("onestep")
    for name, src in sources.items():
        for regime in REGIMES:
            onestep = _fmt(src["onestep"][regime]) if "onestep" in src else "–"
            share = "–"
            if reference is not None and "onestep" in src and reference[regime][0] > 0:
                share = f"{src['onestep'][regime][0] / reference[regime][0]:.3g}"
            lines.append(f"| {name} | {regime} | {src['share'][regime][0]:.2f} | {_fmt(src['rollout'][regime])} "
                         f"| {onestep} | {share} |")  # fmt: skip
    return lines


def _ratio(entry: tuple) -> str:
    centre, low, high, _ = entry
    if not np.isfinite(centre):
        return "–"
    if not (np.isfinite(low) and np.isfinite(high)):
        return f"{centre:.3g}x"
    tie = " (tie)" if interval_contains_one(low, high) else ""
    return f"{centre:.3g}x [{low:.3g}, {high:.3g}]{tie}"


def paired_table(ratios: dict[str, dict[str, dict]], reference: str) -> list[str]:
    """Markdown: each model's error over ``reference``'s (:func:`paired_ratios`), by horizon, then by regime
    for the rollout and the one step."""
    if not ratios:
        return []
    first = next(iter(ratios.values()))
    horizons = list(first["horizon"])
    lines = [f"Paired over trajectories: each model's error over {reference}'s, geometric mean [95%]; (tie): the",
             "interval contains 1.", "",
             "| model | " + " | ".join(f"first {h} frames" if h != "all" else "whole rollout" for h in horizons)
             + " | " + " | ".join(f"{r} rollout" for r in REGIMES) + " | "
             + " | ".join(f"{r} one-step" for r in REGIMES) + " |",
             "|---|" + "---|" * (len(horizons) + 2 * len(REGIMES))]  # fmt: skip
    for name, ratio in ratios.items():
        cells = [_ratio(ratio["horizon"][h]) for h in horizons]
        cells += [_ratio(ratio["rollout"][r]) for r in REGIMES]
        cells += [_ratio(ratio["onestep"][r]) if "onestep" in ratio else "–" for r in REGIMES]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    from gnsx.data.datamodule import TrajectoryDataset
    from gnsx.data.store import load_metadata, open_split
    from gnsx.model.checkpoint import load_simulator, model_label

    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.regimes", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("checkpoints", nargs="+", type=Path, help="checkpoints (.ckpt) or run folders")
    parser.add_argument("--data", type=Path, required=True, help="the dataset (gnsx format)")
    parser.add_argument("--split", default="test", help="split to score (default test)")
    parser.add_argument("--max-trajectories", type=int, default=None, help="the split's first N only")
    parser.add_argument("--label", action="append", default=[], help="a name per checkpoint, in order")
    parser.add_argument("--out", type=Path, default=None, help="folder for regimes.md and regimes.json")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    metadata = load_metadata(args.data)
    trajectories = list(TrajectoryDataset(open_split(args.data, args.split, metadata), args.max_trajectories))
    rows: dict[str, list[dict]] = {BASELINE_LABEL: model_rows(None, trajectories, metadata)}
    for i, path in enumerate(args.checkpoints):
        simulator = load_simulator(path).eval()
        label = args.label[i] if i < len(args.label) else model_label(simulator) + f" ({path})"
        rows[label] = model_rows(simulator, trajectories, metadata)
    sources = {label: summarise(model) for label, model in rows.items()}
    models = list(rows)[1:]  # the checkpoints, in order: the first is the reference
    ratios = {label: paired_ratios(rows[label], rows[models[0]]) for label in models[1:]}
    lines = [f"# Where the error comes from: {args.split} split of {args.data}, {len(trajectories)} trajectories",
             "", "Raw network (walls and ramps only). Command: `python -m gnsx.evaluation.regimes "
             + " ".join(str(p) for p in args.checkpoints) + f" --data {args.data} --split {args.split}`.",
             "", *table(sources), ""]  # fmt: skip
    if ratios:
        lines += [*paired_table(ratios, models[0]), ""]
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "regimes.md").write_text(text)
        record = {"sources": sources, "paired_with": models[0] if ratios else None, "paired": ratios}
        write_json(args.out / "regimes.json", json.loads(json.dumps(record, default=list)))
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError,)))
