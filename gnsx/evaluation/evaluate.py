"""Evaluating trained simulators: the end-of-training evaluation of ``train.py`` (:func:`evaluate_run`) and
the logic of the ``evaluate.py`` entry point (:func:`evaluate_checkpoints`: many checkpoints, rollout files,
pictures, paired comparisons).

Both are built on the scoring library :mod:`gnsx.evaluation.scoring` (rollouts, metrics and their spread over
trajectories) and :mod:`gnsx.model.checkpoint`; models are compared with :func:`gnsx.evaluation.spread.compare`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.errors import ConfigError
from gnsx.data.metadata import Metadata
from gnsx.evaluation.scoring import (
    TrajectoryResult,
    evaluate_simulator,
    format_table,
    json_ready,
    loggable,
    mean_per_frame,
    write_csv,
)
from gnsx.evaluation.spread import compare, format_comparison
from gnsx.model.checkpoint import check_fits, load_simulator, model_label, slug
from gnsx.model.simulator import LearnedSimulator
from gnsx.rules.rules import Rules

log = logging.getLogger("gnsx")


def render_comparison(first: dict, metadata: Metadata, path: Path, label: str) -> Path:
    """Animation of ground truth next to the model's rollout (same initial frames)."""
    from gnsx.evaluation.render import render_rollouts, save_animation

    frames = render_rollouts(
        [first["ground_truth"], first["predicted"]],
        first["particle_type"],
        metadata.bounds_array(),
        titles=["ground truth (MPM)", label],
        frame_stride=2,
    )
    return save_animation(frames, path, fps=25)


def _read_json(path: Path) -> dict:
    try:
        payload = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return payload if isinstance(payload, dict) else {}


def evaluate_run(cfg, simulator: LearnedSimulator, datamodule, run_dir: Path, loggers: list) -> dict:
    """End-of-training evaluation for ``train.py``: the trained model, and the shipped weights when present.

    Writes ``results.json`` (``"model"``, ``"parameters"``, ``"test"`` -> summary, ``"rows"``),
    ``test_per_frame.csv``, ``test_rollout.<gif|mp4>`` (and ``pretrained_rollout.*``) into ``run_dir``, logs
    the summary to every logger, prints the tables (and, with shipped weights, the paired comparison of the
    two on the test trajectories, also in ``results.json``'s ``"pretrained"``). Returns the trained model's
    summary.
    """
    datamodule.setup("test")
    metadata = datamodule.metadata
    simulator = simulator.cpu()
    options = {
        key: cfg.evaluate.get(key, default)
        for key, default in (("emd_every", 10), ("emd_method", "auto"), ("onestep_stride", 10),
                             ("timing_repeats", 20))
    }  # fmt: skip
    rules = Rules.from_config(cfg, "rules")
    per_frame: list[dict] = []
    summary, rows, first = evaluate_simulator(
        simulator,
        datamodule.test_set,
        metadata,
        on_trajectory=lambda result: per_frame.extend(result.per_frame_rows()),
        rules=Rules.none(),
        **options,
    )
    title = f"Test rollouts ({cfg.model.name} GNS, this run) vs physics-free baseline"
    print(format_table(rows, summary, f"{title}, {RAW_LABEL}"))
    results = {
        "model": cfg.model.name,
        "parameters": simulator.num_parameters(),
        "test": summary,
        "rows": rows,
        "rules": Rules.none().to_dict(),
    }
    if (
        extra := with_rules_table(simulator, datamodule.test_set, metadata, rules, title, options)
    ) is not None:
        results["with_rules"] = {"rules": extra["rules"], "test": extra["summary"], "rows": extra["rows"]}
    write_csv(run_dir / "test_per_frame.csv", per_frame)
    suffix = cfg.evaluate.render_format
    if cfg.evaluate.render and first is not None:
        path = render_comparison(first, metadata, run_dir / f"test_rollout.{suffix}", f"{cfg.model.name} GNS")
        log.info("Animation: %s", path)
        results["animation"] = str(path)

    pretrained = cfg.evaluate.pretrained
    if pretrained and Path(pretrained).is_file():
        shipped = load_simulator(pretrained)
        p_summary, p_rows, p_first = evaluate_simulator(
            shipped, datamodule.test_set, metadata, rules=Rules.none(), **options
        )
        print(format_table(p_rows, p_summary, f"Test rollouts (shipped weights {pretrained}), {RAW_LABEL}"))
        comparison = compare(p_rows, rows)
        print(format_comparison(comparison, "shipped weights", "this run"))
        results["pretrained"] = {"checkpoint": str(pretrained), "test": p_summary, "rows": p_rows,
                                 "comparison": comparison}  # fmt: skip
        if cfg.evaluate.render and p_first is not None:
            path = render_comparison(
                p_first, metadata, run_dir / f"pretrained_rollout.{suffix}", "shipped GNS"
            )
            log.info("Animation (shipped weights): %s", path)
            results["pretrained"]["animation"] = str(path)

    # Merged into the job's record (status, liveness), which stays readable while the evaluation runs.
    path = run_dir / "results.json"
    write_json(path, {**_read_json(path), **json_ready(results)})
    for logger in loggers:
        logger.log_metrics(loggable(summary, "test"))
    return summary


#: What the primary table of every evaluation measures (the network; the rules are only ever a second table).
RAW_LABEL = "raw network (walls and ramps only; baseline: walls only)"


def with_rules_table(
    simulator: LearnedSimulator, trajectories, metadata: Metadata, rules: Rules, title: str, options: dict
) -> dict | None:
    """The same trajectories scored again with the simulator's ``rules`` on the model's rollouts, printed and
    returned beside the raw table (None when no rule is on).

    The figure measures model + rules (module :mod:`gnsx.rules.rules`), so it is labelled so and never
    replaces the raw one. Timing is left to the raw table (``timing_repeats=0`` here): ms/frame times the
    network, which the rules do not change.

    Returns:
        ``{"rules": {...}, "summary": {...}, "rows": [...]}``.
    """
    if not rules.any():
        return None
    summary, rows, _ = evaluate_simulator(
        simulator,
        trajectories,
        metadata,
        keep_first=False,
        **{**options, "timing_repeats": 0, "rules": rules},
    )
    print(format_table(rows, summary, f"{title}, {rules.label()}: model + rules, not the network alone"))
    return {"rules": rules.to_dict(), "summary": summary, "rows": rows}


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
    allow_mismatch: bool = False,
    rules: Rules | None = None,
) -> dict:
    """Evaluate checkpoints on every trajectory of a split and write what a user needs to judge them.

    Writes into ``out_dir``:

    * ``results.json``: ``{"split", "data_root", "rules", "models": [{"label", "folder",
      "checkpoint", "parameters", "summary", "rows", "with_rules"}], "comparisons", "outputs"}``: ``summary``
      and ``rows`` are the raw network's (``rules`` records that: all off); with ``rules`` on, each model's
      ``with_rules`` holds the same trajectories scored with them (:func:`with_rules_table`), and the
      top-level ``with_rules`` names them (summary and rows as
      :func:`~gnsx.evaluation.scoring.evaluate_simulator`'s; ``comparisons``: with two or more models, each later model
      against the first, :func:`~gnsx.evaluation.spread.compare` on ``rollout_mse`` and ``emd`` plus ``"a"``, ``"b"``
      (the labels), also printed);
    * per model, in ``<label slug>/``: ``trajectories.csv`` (one row per trajectory), ``per_frame.csv`` (one
      row per trajectory and predicted frame, see :class:`~gnsx.evaluation.scoring.TrajectoryResult`),
      ``rollouts/<split>_<i>.npz`` (gnsx rollout files, :mod:`gnsx.data.rollout_io`; with ``deepmind`` also
      DeepMind's ``.pkl``);
    * with ``render``: ``comparison.<gif|mp4>`` (ground truth and every model side by side, the paper's
      figure 8, on trajectory ``render_trajectory``), ``strip.png`` (frames 0, ``strip_every``, ... one row
      per panel, figure 1) and ``<label slug>/final_frame.png``.

    Every logger gets ``<split>/<slug>/<metric>`` summaries and the per-frame means of ``mse`` and ``emd``
    (``<split>/<slug>/frame_mse`` at step = frame).

    Args:
        checkpoints: ``.ckpt`` files or run directories.
        data_root: the gnsx dataset (its metadata gives bounds, dt and the neighbour radius).
        labels: one per checkpoint (default :func:`~gnsx.model.checkpoint.model_label`, made unique).
        rules: the simulator's rules for a second table beside the raw one (:class:`gnsx.rules.rules.Rules`;
            None or all off: the raw table alone); recorded in ``results.json``.
        allow_mismatch: evaluate a model on data unlike its training data (another dimension, walls, or a
            connectivity radius more than 2x apart, :func:`~gnsx.model.checkpoint.check_fits`); refused otherwise.
        Others: see :func:`~gnsx.evaluation.scoring.score_trajectory` and :mod:`gnsx.evaluation.render`.
    Returns:
        the ``results.json`` payload.
    """
    from gnsx.data.datamodule import TrajectoryDataset
    from gnsx.data.rollout_io import Rollout, export_deepmind, save_rollout
    from gnsx.data.store import load_metadata, open_split

    out_dir = Path(out_dir)
    if labels is not None and len(labels) != len(checkpoints):
        raise ConfigError(
            f"labels={list(labels)}",
            f"{len(labels)} labels for {len(checkpoints)} checkpoints; give one label per checkpoint",
        )
    # Every input is read and checked before anything is written or rolled out.
    simulators = [load_simulator(checkpoint, device) for checkpoint in checkpoints]
    metadata = load_metadata(data_root)
    dataset = TrajectoryDataset(open_split(data_root, split, metadata), max_trajectories)
    for checkpoint, simulator in zip(checkpoints, simulators):
        if not allow_mismatch:
            target = f"the dataset {data_root} ({metadata.dim}-D)"
            check_fits(simulator, str(checkpoint), metadata.bounds, metadata.default_connectivity_radius,
                       metadata.dim, target)  # fmt: skip
    out_dir.mkdir(parents=True, exist_ok=True)
    rules = rules or Rules()
    results = {
        "split": split,
        "data_root": str(data_root),
        "rules": Rules.none().to_dict(),
        "models": [],
    }
    if rules.any():
        results["with_rules"] = rules.to_dict()
    panels: list[np.ndarray] = []
    titles: list[str] = []
    shown: dict | None = None
    used: set[str] = set()
    for k, (checkpoint, simulator) in enumerate(zip(checkpoints, simulators)):
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
            rules=Rules.none(),
            on_trajectory=keep,
        )
        title = f"{split} rollouts: {label} ({checkpoint})"
        print(format_table(rows, summary, f"{title}, {RAW_LABEL}"))
        options = dict(emd_every=emd_every, emd_method=emd_method, onestep_stride=onestep_stride)
        extra = with_rules_table(simulator, dataset, metadata, rules, title, options)
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
                **({"with_rules": extra} if extra is not None else {}),
            }  # fmt: skip
        )
        for logger in loggers:
            logger.log_metrics(loggable(summary, f"{split}/{name}"))
            for t, values in mean_per_frame(per_frame).items():
                logger.log_metrics({f"{split}/{name}/frame_{key}": v for key, v in values.items()}, step=t)

    if len(results["models"]) > 1:
        first = results["models"][0]
        results["comparisons"] = []
        print(f"Paired comparisons with {first['label']} ({split} trajectories, errors B / A):")
        for model in results["models"][1:]:
            for key in ("rollout_mse", "emd"):
                comparison = compare(first["rows"], model["rows"], key)
                print("  " + format_comparison(comparison, first["label"], model["label"]))
                results["comparisons"].append({"a": first["label"], "b": model["label"], **comparison})

    if render and shown is not None:
        from gnsx.evaluation.render import render_rollouts, save_animation, save_frame, save_strip, speeds

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
    write_json(out_dir / "results.json", json_ready(results))
    return results
