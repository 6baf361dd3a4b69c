"""What ``train.py`` does with its Hydra config: data, model, loggers, Lightning fit, test evaluation,
pictures, and the bookkeeping of one job: training time and speed, ``results.json``, failure handling, wandb
grouping.

The composed config is read here and by the modules this one calls to build the run
(:mod:`~gnsx.training.inputs`, :mod:`~gnsx.training.model_settings`, :mod:`~gnsx.training.builders`,
:mod:`~gnsx.training.loggers`, :mod:`~gnsx.training.job`); what they call in turn takes typed arguments.

Every run writes ``results.json`` into its run directory (schema in :mod:`gnsx.evaluation.report`):
``"status": "running"`` when it starts (with its pid, host and a heartbeat, :mod:`gnsx.core.runstate`),
``"ok"`` or ``"failed"`` (with a one-line ``"error"``) when it ends, ``"interrupted"`` when a later run or
reader finds it killed. Bad input is refused before anything is written
(:func:`~gnsx.training.inputs.check_inputs`). A job whose training diverges (too many NaN/Inf steps in a row,
:mod:`gnsx.training.numerics`) or whose test rollout becomes NaN/Inf fails with an error starting
``"diverged:"``. In a Hydra multirun a failed job returns NaN instead of raising, so the other jobs of the
sweep still run (Hydra's launchers stop the whole sweep at the first exception); a single run re-raises after
recording. Sweep configs (``sweeps/*.yaml``) add a ``sweep`` block: its name groups the wandb runs, and it
asks for one rendered frame of the first test rollout and a speed/memory benchmark at WaterRamps size for each
job.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from lightning.fabric.utilities.rank_zero import rank_zero_only
from omegaconf import DictConfig, OmegaConf, open_dict

from gnsx.core import runstate
from gnsx.core.atomic import write_json
from gnsx.core.errors import GnsxError, RunFailed
from gnsx.core.threads import apply_threads
from gnsx.data.datamodule import ParticleDataModule
from gnsx.evaluation.evaluate import evaluate_run
from gnsx.training.builders import (
    apply_matmul_precision,
    build_system,
    build_trainer,
    local_processes,
    training_clock,
)
from gnsx.training.inputs import check_inputs, resolve_checkpoint
from gnsx.training.job import (
    TEST_KEYS,
    as_divergence,
    check_finite_rollout,
    finished_result,
    job_identity,
    one_line,
    read_results,
    run_dir_of,
)
from gnsx.training.loggers import build_loggers, finish_wandb
from gnsx.training.model_settings import model_summary
from gnsx.training.resilience import Heartbeat
from gnsx.training.sweep_extras import benchmark_at_scale, data_spacing, render_test_frame
from gnsx.training.system import GNSSystem
from gnsx.training.time_budget import TrainingClock

log = logging.getLogger("gnsx")


def schedule_summary(cfg: DictConfig, trainer: L.Trainer, clock: TrainingClock, system: GNSSystem) -> dict:
    """How many steps the run got against its schedule (also logged): ``global_step``, ``scheduled_steps``
    (``train.max_steps``), ``fitted_steps`` (the time budget's, or None), ``skipped_steps`` (NaN/Inf) and
    ``samples_seen`` (training samples the final weights have seen, a fine-tune's start included)."""
    planned = getattr(clock, "planned_steps", None) or int(cfg.train.max_steps)
    fitted = getattr(clock, "fitted", None)
    done = int(trainer.global_step)
    summary = {"global_step": done, "scheduled_steps": planned, "fitted_steps": fitted,
               "skipped_steps": int(system.skipped.total),
               "samples_seen": int(system.samples_seen)}  # fmt: skip
    rate = clock.summary().get("steps_per_s")
    fitted_text = f"; the time budget fitted the schedule to {fitted:,}" if fitted else ""
    log.info(
        "Steps: %s of %s scheduled (%.0f%%%s), %s steps/s on %d thread(s); %d skipped for a NaN/Inf loss or "
        "gradient",
        f"{done:,}", f"{planned:,}", 100.0 * done / planned, fitted_text,
        f"{rate:.1f}" if rate else "?", torch.get_num_threads(), summary["skipped_steps"],
    )  # fmt: skip
    return summary


def _train_and_evaluate(
    cfg: DictConfig, run_dir: Path, record: dict, loggers: list, datamodule: ParticleDataModule
) -> float | None:
    """Train, then evaluate on the test split; fills ``record`` and ``loggers`` as it goes (they survive a
    failure). Returns the test rollout MSE (None when evaluation is off)."""
    # Parallel sweep jobs on one machine (the joblib launcher) set sweep.torch_threads: n_jobs x threads
    # should not exceed the cores. Otherwise `threads` (auto: gnsx.core.threads).
    threads = OmegaConf.select(cfg, "sweep.torch_threads", default=None) or cfg.get("threads")
    record["threads"] = apply_threads(threads, processes=local_processes(cfg))
    L.seed_everything(int(cfg.seed), workers=True)
    record["float32_matmul_precision"] = apply_matmul_precision(cfg)
    loggers.extend(
        build_loggers(cfg, run_dir, name=record["name"], group=cfg.logger.group or record["sweep"])
    )
    system = build_system(cfg, datamodule)
    record["model_config"] = model_summary(cfg, system)
    record["parameters"] = system.simulator.num_parameters()
    clock = training_clock(cfg)
    callbacks = [clock]
    val_every_minutes = OmegaConf.select(cfg.train, "val_every_minutes", default=None)
    curve_every_n_steps = OmegaConf.select(cfg.train, "curve_every_n_steps", default=None)
    if val_every_minutes is not None or curve_every_n_steps is not None:
        from gnsx.training.curves import CurveValidation

        every_s = None if val_every_minutes is None else 60.0 * float(val_every_minutes)
        every_n_steps = None if every_s is not None else int(curve_every_n_steps)
        callbacks.append(CurveValidation(clock, every_s, run_dir / "curve.jsonl", every_n_steps=every_n_steps,
                                         loss_every_n_steps=int(cfg.train.log_every_n_steps)))  # fmt: skip
        record["curve"] = str(run_dir / "curve.jsonl")

    def beat(fields: dict) -> None:
        record.update(fields)
        write_json(run_dir / "results.json", record)

    trainer = build_trainer(cfg, run_dir, loggers, callbacks=[*callbacks, Heartbeat(beat)])
    record["precision"] = str(trainer.precision)
    log.info("Model: %s, %d parameters", cfg.model.name, record["parameters"])
    try:
        trainer.fit(system, datamodule=datamodule, ckpt_path=resolve_checkpoint(cfg.train.ckpt_path))
        # The final weights into last.ckpt: Lightning's last.ckpt follows the step and wall-clock
        # checkpoints, and a run whose fitted step count is not a multiple of checkpoint_every_n_steps ends
        # between two of them (the equal-budget runs of 2026-12-06 left last.ckpt 435 and 630 steps before
        # their end). The test evaluation below scores these weights; export and evaluate.py read last.ckpt.
        trainer.save_checkpoint(run_dir / "checkpoints" / "last.ckpt")
    finally:
        record.update(clock.summary())
        record.update(schedule_summary(cfg, trainer, clock, system))
    record["evaluated"] = bool(cfg.evaluate.enabled)
    if not (cfg.evaluate.enabled and trainer.is_global_zero):
        return None
    # The benchmark runs where the model trained (Lightning moves it back to the CPU after fit).
    device = trainer.strategy.root_device
    summary = evaluate_run(cfg, system.simulator, datamodule, run_dir, loggers)
    check_finite_rollout(summary)
    frame = OmegaConf.select(cfg, "sweep.frame", default=None)
    bench = OmegaConf.select(cfg, "sweep.bench", default=None)
    metadata = datamodule.metadata
    if frame is not None or bench is not None:
        first = datamodule.test_set[0]
    if frame is not None:
        record.update(render_test_frame(system.simulator, first, metadata, int(frame), run_dir))
    if bench is not None:
        spacing = bench.get("spacing") or data_spacing(
            metadata, first["position"][0].numpy(), first["particle_type"].numpy()
        )
        try:
            record["bench"] = benchmark_at_scale(
                system.simulator, metadata, float(spacing), int(bench.num_particles), device,
                warmup=int(bench.get("warmup", 3)), repeats=int(bench.get("repeats", 20)),
            )  # fmt: skip
        except Exception as error:  # e.g. out of memory at WaterRamps size: a result, not a failed job
            record["bench"] = {"error": one_line(error)}
            log.warning("Benchmark at %d particles failed: %s", int(bench.num_particles), one_line(error))
    return float(summary["rollout_mse"])


def run_training(cfg: DictConfig) -> float | None:
    """Train, then evaluate on the test split; returns the test rollout MSE (None when evaluation is off).

    Checks every input first (:func:`check_inputs`): bad input raises a one-line
    :class:`~gnsx.core.errors.GnsxError` before anything is written (a multirun job records it and returns
    NaN). Then writes ``results.json`` (see the module docstring), "running" with the process's liveness
    (:mod:`gnsx.core.runstate`) and a heartbeat while it trains; a killed earlier run in this directory, and the
    run this one resumes from, are marked "interrupted". In a multirun a failed job returns NaN; a single run
    re-raises (``gnsx.core.cli`` prints bad input and divergence as one line).
    """
    start = time.perf_counter()
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    identity = job_identity(cfg, hydra_cfg)
    results_path = run_dir / "results.json"
    if OmegaConf.select(cfg, "sweep.resume", default=False):
        done = finished_result(results_path)
        if done is not None:
            score = "no test evaluation" if math.isnan(done) else f"test rollout MSE {done:.4g}"
            log.info("%s: finished earlier (%s): skipped (sweep.resume)", run_dir, score)
            return done
        if (run_dir / "checkpoints" / "last.ckpt").is_file() and cfg.train.ckpt_path is None:
            log.info("%s: resuming from its checkpoints/last.ckpt (sweep.resume)", run_dir)
            with open_dict(cfg):
                cfg.train.ckpt_path = str(run_dir)
    writer = rank_zero_only.rank == 0  # DDP: one process writes the results
    bad_input: GnsxError | None = None
    datamodule: ParticleDataModule | None = None
    try:
        datamodule = check_inputs(cfg)
    except GnsxError as error:
        if not identity["multirun"]:
            raise  # nothing written: an earlier results.json in this folder stays as it was
        bad_input = error  # a sweep job records it below, like any failure
    run_dir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {"status": "running", "error": None, **identity, "run_dir": str(run_dir)}
    if writer:
        previous = runstate.mark_interrupted(results_path)
        if previous is not None:
            log.warning("%s: the previous run here was %s", results_path, previous["error"])
            record["previous"] = {key: previous.get(key) for key in ("status", "error", "global_step")}
            before = previous.get("cpus") or [previous.get("cpu")]
            record["cpus"] = [cpu for cpu in dict.fromkeys([*before, record["cpu"]]) if cpu]
        resumed = run_dir_of(cfg.train.ckpt_path)
        if resumed is not None and resumed.resolve() != run_dir.resolve():
            runstate.mark_interrupted(resumed / "results.json", resumed_in=str(run_dir))
        record.update(runstate.liveness())
        write_json(results_path, record)
    loggers: list = []
    result: float | None = None
    try:
        if bad_input is not None:
            # The sweep's wandb group still shows the job (finished with exit code 1).
            loggers.extend(build_loggers(cfg, run_dir, name=identity["name"],
                                         group=cfg.logger.group or identity["sweep"]))  # fmt: skip
            raise bad_input
        result = _train_and_evaluate(cfg, run_dir, record, loggers, datamodule)
        record["status"] = "ok"
    except Exception as error:  # a sweep job records any failure and lets the other jobs run
        reason = as_divergence(error)
        record["status"], record["error"] = "failed", one_line(reason)
        expected = isinstance(reason, GnsxError | RunFailed)  # one line (gnsx.core.cli), no traceback
        if identity["multirun"]:
            log.error("Job %s failed: %s", identity["name"], record["error"], exc_info=not expected)
        elif not expected:
            log.error("Job %s failed: %s", identity["name"], record["error"])  # the traceback follows
        if not identity["multirun"]:
            if reason is not error:
                raise reason from error
            raise
        result = float("nan")
    finally:
        if record["status"] == "running":  # KeyboardInterrupt, SystemExit, SIGTERM
            record["status"], record["error"] = runstate.INTERRUPTED, "interrupted (stopped by a signal)"
        record["job_wall_s"] = time.perf_counter() - start
        # evaluate_run wrote the test summary (and its per-trajectory rows) into results.json: keep them.
        results = {**read_results(results_path), **record}
        results["test"] = {key: None for key in TEST_KEYS} | (results.get("test") or {})
        results.setdefault("bench", None)
        if writer:
            write_json(results_path, results)
        if cfg.logger.wandb:
            finish_wandb(results)
    return result
