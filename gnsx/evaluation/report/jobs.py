"""A sweep's jobs: one Hydra multirun job folder as a :class:`Job`, every job folder of a multirun
(:func:`load_sweep`), the axes the sweep varies and where speed and memory come from.

Speed and memory come from the benchmark at WaterRamps size (``bench``) when every successful job has it,
otherwise from the test rollouts (``test``); the report says which (:func:`speed_source`).

Errors come with their spread over the test trajectories (:mod:`gnsx.evaluation.spread`): ``<key>_se`` of the test
summary, or computed from the job's per-trajectory ``rows`` when the summary predates it (:meth:`Job.spread`).
The baseline ratio is the geometric mean of ``baseline_mse / rollout_mse`` over trajectories with its 95% t
interval (the ratio of the means when neither is recorded); below 1 the model does not beat the physics-free
baseline (:meth:`Job.baseline_ratio`).

``results.json`` (one per job folder, written by :func:`gnsx.training.run.run_training`)::

    status          "ok" | "failed" | "running" (a job killed before it finished leaves "running")
    error           one line: why the job failed ("diverged: ..." for a NaN/Inf loss or rollout), else null
    sweep, job      the sweep's name (``sweep.name``), the job number in the multirun
    overrides       every Hydra override of the job; ``swept``: the ones the sweep varies; ``name``: the
                    wandb run name (the swept overrides joined by commas)
    run_dir         the job folder
    model           the model config's name; ``model_config``: its architecture (latent_size, mp_steps,
                    mlp_hidden_size, ...) with the effective ``radius`` (data units) and ``noise_std``
    parameters      trainable parameter count
    train_wall_s    wall time of trainer.fit (s, validation included); ``train_steps``: optimizer steps of
                    this run; ``steps_per_s``: steps per second of training (validation excluded);
                    ``job_wall_s``: the whole job (data, training, evaluation, pictures, benchmark)
    test            {rollout_mse, onestep_mse, emd, baseline_mse (data units^2, dynamic particles),
                     ms_per_frame (rollout, graph build included), peak_memory_mb, trajectories, and since
                     the spreads were added <key>_se, baseline_ratio_geomean(_lo, _hi), ...}: the summary of
                     :func:`gnsx.evaluation.scoring.summarise`
    bench           {ms_per_frame, peak_memory_mb, num_particles, spacing, device}: one inference step on a
                    packed scene of WaterRamps size at the data's particle spacing; {error} when it failed
    frame, frame_png, frame_truth_png
                    the rendered frame index of the first test rollout and its PNGs (prediction, ground truth)
    rows            per-test-trajectory errors (:func:`gnsx.evaluation.scoring.score_trajectory`; optional)

A job folder without results.json (the job never started, or crashed before writing) counts as failed, with
its model read from ``.hydra/config.yaml``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gnsx.evaluation.spread import baseline_verdict, geometric_mean_interval, mean_se

#: Grid axes in the order rows, columns, as in the paper's figure 9.
AXES = ("latent_size", "mp_steps", "radius")
AXIS_LABELS = {"latent_size": "embedding size", "mp_steps": "message passing steps", "radius": "radius"}


@dataclass
class Job:
    """One job of a sweep, flattened for the report. Numbers are None when unknown (e.g. a failed job)."""

    job: int | None
    folder: Path
    name: str
    status: str
    error: str | None
    latent_size: int | None = None
    mp_steps: int | None = None
    radius: float | None = None
    parameters: int | None = None
    train_steps: int | None = None
    steps_per_s: float | None = None
    train_wall_s: float | None = None
    test: dict[str, Any] = field(default_factory=dict)
    bench: dict[str, Any] = field(default_factory=dict)
    frame_png: str | None = None
    frame_truth_png: str | None = None
    sweep: str | None = None
    rows: list[dict] = field(default_factory=list)
    #: Training seed (``seed`` of the job's config; None when unknown).
    seed: int | None = None
    #: The rules the test rollouts were scored with (results.json ``rules``; all off: the raw network).
    rules: dict[str, bool] = field(default_factory=dict)
    #: True when the radius is the dataset's own ``default_connectivity_radius`` (no ``model.radius`` set),
    #: False when the config set it, None when the job does not say.
    default_radius: bool | None = None

    @property
    def cell(self) -> tuple:
        """The model the job trains, whatever its seed: ``(latent_size, mp_steps, radius)``."""
        return (self.latent_size, self.mp_steps, self.radius)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def ms_per_frame(self, source: str) -> float | None:
        return finite_or_none((self.bench if source == "bench" else self.test).get("ms_per_frame"))

    def memory_mb(self, source: str) -> float | None:
        return finite_or_none((self.bench if source == "bench" else self.test).get("peak_memory_mb"))

    @property
    def rollout_mse(self) -> float | None:
        return finite_or_none(self.test.get("rollout_mse"))

    def spread(self, key: str) -> tuple[float | None, float | None]:
        """``(mean, standard error)`` of a test error over trajectories: the summary's ``key`` and
        ``<key>_se``, else computed from the per-trajectory rows (None where unknown)."""
        mean, se = finite_or_none(self.test.get(key)), finite_or_none(self.test.get(f"{key}_se"))
        if se is None and self.rows:
            row_mean, row_se = mean_se(row.get(key) for row in self.rows)
            mean = mean if mean is not None else finite_or_none(row_mean)
            se = finite_or_none(row_se)
        return mean, se

    def baseline_ratio(self) -> tuple[float | None, float | None, float | None]:
        """``(ratio, low, high)``: the geometric mean over test trajectories of ``baseline_mse / rollout_mse``
        and its 95% interval (from the summary, else the rows); without either, the ratio of the means and no
        interval. None where unknown."""
        geomean = finite_or_none(self.test.get("baseline_ratio_geomean"))
        if geomean is not None:
            return (geomean, finite_or_none(self.test.get("baseline_ratio_geomean_lo")),
                    finite_or_none(self.test.get("baseline_ratio_geomean_hi")))  # fmt: skip
        ratios = [_ratio(row.get("baseline_mse"), row.get("rollout_mse")) for row in self.rows]
        geomean, lo, hi, n = geometric_mean_interval(ratios)
        if n:
            return geomean, finite_or_none(lo), finite_or_none(hi)
        ratio = finite_or_none(self.test.get("baseline_ratio"))
        if ratio is None:
            ratio = _ratio(self.test.get("baseline_mse"), self.rollout_mse)
        return ratio, None, None

    def versus_baseline(self) -> str | None:
        """:func:`gnsx.evaluation.spread.baseline_verdict` of :meth:`baseline_ratio` (None for a failed job)."""
        return baseline_verdict(*self.baseline_ratio()) if self.ok else None

    def label(self, keys: Sequence[str]) -> str:
        """Short name from the swept values, e.g. ``64/5`` (latent/MP) or ``R=0.035``."""
        parts = []
        for key in keys:
            value = getattr(self, key)
            parts.append(f"R={value:g}" if key == "radius" and value is not None else str(value))
        return "/".join(parts) if parts else (self.name or f"job {self.job}")


def finite_or_none(value: Any) -> float | None:
    """A finite float, or None (missing, null, NaN)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _ratio(numerator: Any, denominator: Any) -> float | None:
    """``numerator / denominator`` of two positive finite numbers, else None."""
    a, b = finite_or_none(numerator), finite_or_none(denominator)
    return a / b if a is not None and b is not None and a >= 0 and b > 0 else None


def job_config(folder: Path) -> dict:
    """The job's composed config from Hydra's ``.hydra/config.yaml`` (empty when absent)."""
    path = folder / ".hydra" / "config.yaml"
    if not path.is_file():
        return {}
    from omegaconf import OmegaConf

    try:
        return OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception:  # an unreadable config only costs the report the job's model fields
        return {}


def load_job(folder: Path) -> Job:
    """A job folder of a multirun as a :class:`Job` (see the module docstring for what counts as failed)."""
    path = folder / "results.json"
    results: dict = {}
    if path.is_file():
        try:
            results = json.loads(path.read_text())
        except ValueError as error:
            results = {"status": "failed", "error": f"{path}: unreadable results.json ({error})"}
    else:
        results = {"status": "failed", "error": "no results.json (the job never ran or was killed)"}
        overrides = folder / ".hydra" / "overrides.yaml"
        if overrides.is_file():
            import yaml

            results["name"] = ",".join(map(str, yaml.safe_load(overrides.read_text()) or []))
    status = results.get("status", "ok" if "test" in results else "failed")
    error = results.get("error")
    from gnsx.core.runstate import INTERRUPTED, effective_status, interrupted_reason

    if effective_status(results) == INTERRUPTED:
        status, error = INTERRUPTED, interrupted_reason(results)
    elif status == "running":
        status, error = "failed", "did not finish (killed, out of memory or timed out?)"
    config = job_config(folder)
    model_cfg = config.get("model", {})
    model = results.get("model_config") or {}

    def pick(key: str, cast):
        value = model.get(key, model_cfg.get(key))
        try:
            return cast(value) if value is not None else None
        except (TypeError, ValueError):  # e.g. an unresolved interpolation
            return None

    try:
        number = int(results.get("job", folder.name))
    except (TypeError, ValueError):
        number = None
    return Job(
        job=number,
        folder=folder,
        name=results.get("name") or folder.name,
        status=status,
        error=error,
        latent_size=pick("latent_size", int),
        mp_steps=pick("mp_steps", int),
        radius=pick("radius", float),
        parameters=results.get("parameters"),
        train_steps=results.get("train_steps"),
        steps_per_s=finite_or_none(results.get("steps_per_s")),
        train_wall_s=finite_or_none(results.get("train_wall_s")),
        test=results.get("test") or {},
        bench=results.get("bench") or {},
        frame_png=_here(folder, results.get("frame_png")),
        frame_truth_png=_here(folder, results.get("frame_truth_png")),
        sweep=results.get("sweep") or config.get("sweep", {}).get("name"),
        rows=[row for row in results.get("rows") or [] if isinstance(row, dict)],
        seed=_int(config.get("seed", _override(results, "seed"))),
        rules={str(k): bool(v) for k, v in (results.get("rules") or {}).items()},
        default_radius=_default_radius(model.get("radius_source")),
    )


def _override(results: dict, key: str) -> str | None:
    """The value of ``key=<value>`` among results.json's Hydra ``overrides``, or None: what a job folder
    copied without its ``.hydra/`` (its config) still says of the settings a sweep varied."""
    for override in results.get("overrides") or []:
        name, _, value = str(override).partition("=")
        if name.lstrip("+~") == key:
            return value
    return None


def _default_radius(source: Any) -> bool | None:
    """Whether results.json's ``model_config.radius_source`` names the dataset's default radius."""
    if not isinstance(source, str):
        return None
    return "default_connectivity_radius" in source


def _here(folder: Path, recorded: str | None) -> str | None:
    """A picture the job recorded, found in its own folder when the recorded path is gone (the folder was
    moved or copied, e.g. a finished cell restored from a committed docs/fig9/.../jobs/)."""
    if recorded is None or Path(recorded).is_file():
        return recorded
    local = folder / Path(recorded).name
    return str(local) if local.is_file() else recorded


def _int(value: Any) -> int | None:
    try:
        return int(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def split_seeds(jobs: Sequence[Job]) -> tuple[list[Job], list[Job]]:
    """``(primary, repeats)``: one job per cell (its lowest seed: what the grid, scatter and table show) and
    the other seeds of the cells trained more than once (what the seed-spread section shows)."""
    primary: dict[tuple, Job] = {}
    for job in sorted(jobs, key=lambda j: j.seed or 0):  # no seed recorded: the config default, 0
        if job.latent_size is None and job.mp_steps is None and job.radius is None:
            primary[("job", id(job))] = job  # a failed job with no model facts is its own cell
        else:
            primary.setdefault(job.cell, job)
    kept = {id(j) for j in primary.values()}
    return [j for j in jobs if id(j) in kept], [j for j in jobs if id(j) not in kept]


def load_sweep(sweep_dir: str | Path) -> list[Job]:
    """Every job folder of a multirun directory (a subfolder with ``.hydra/`` or ``results.json``), by job."""
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such multirun directory")
    folders = [
        p
        for p in sweep_dir.iterdir()
        if p.is_dir() and ((p / ".hydra").is_dir() or (p / "results.json").is_file())
    ]
    if not folders:
        raise FileNotFoundError(f"{sweep_dir}: no job folders (subfolders with .hydra/ or results.json)")
    jobs = [load_job(p) for p in folders]
    return sorted(jobs, key=lambda j: (j.job is None, j.job if j.job is not None else 0, j.folder.name))


def reference_jobs(jobs: Sequence[Job], cell: tuple[int, int] | None) -> list[Job]:
    """The jobs (every seed) of the reference cell ``cell`` = (latent_size, mp_steps), e.g. the paper's 64/5.

    In a radius sweep every job is that cell, so the reference is the cell at the dataset's own default radius
    (the radius the figure 9 grid trains with); with no job at the default radius there is no reference,
    rather than an arbitrary radius called "the paper's cell".
    """
    if cell is None:
        return []
    matching = [j for j in jobs if (j.latent_size, j.mp_steps) == tuple(cell)]
    if len({j.radius for j in matching}) > 1:
        matching = [j for j in matching if j.default_radius]
    return matching


def sweep_name(jobs: Sequence[Job], default: str = "sweep") -> str:
    """The sweep most jobs belong to (a report may hold a few jobs of another sweep, e.g. figure 9's 64/5
    seeds as the reference point of the radius sweep); ``default`` when no job says."""
    names = [j.sweep for j in jobs if j.sweep]
    return max(dict.fromkeys(names), key=names.count) if names else default


def swept_axes(jobs: Sequence[Job]) -> list[str]:
    """The model axes (latent_size, mp_steps, radius) taking more than one value across the jobs."""
    return [key for key in AXES if len({getattr(j, key) for j in jobs if getattr(j, key) is not None}) > 1]


def speed_source(jobs: Sequence[Job]) -> str:
    """``"bench"`` when every successful job has a benchmark at scale, else ``"test"`` (the test rollouts)."""
    ok = [j for j in jobs if j.ok]
    return "bench" if ok and all(j.ms_per_frame("bench") is not None for j in ok) else "test"


def all_retimed(jobs: Sequence[Job]) -> bool:
    """True when every successful job's ``bench`` was retimed with the others in one process
    (:mod:`gnsx.evaluation.report.retime`), not inside the job."""
    ok = [j for j in jobs if j.ok]
    return bool(ok) and all(str(j.bench.get("timing", "")).startswith("retimed") for j in ok)
