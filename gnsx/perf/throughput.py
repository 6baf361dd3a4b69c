"""Training throughput: samples/s and steps/s of the real training loop (``make bench-train``).

One command measures what a user's ``train.py`` gets: the Lightning ``Trainer.fit`` loop with the data module,
the noise, the loss, the backward pass, Adam and the logging, on a gnsx dataset. A *sample* is one training
graph (one frame of one trajectory); a *step* is one optimizer step on ``batch_size`` samples. The first
``warmup`` steps are not timed (allocator growth, lazy initialisation, cuDNN/cuBLAS choice); the figure is the
median of the per-window rates over ``windows`` windows of ``steps // windows`` steps, so a short burst from
other jobs on a shared machine moves it less than a plain mean would.

The script imports only APIs that every gnsx version since the first has (``GNSSystem``,
``ParticleDataModule``, ``gnsx.model.registry.MODELS``), so running it from an older checkout measures the older
code the same way::

    python -m gnsx.perf.throughput --data data/small --batch-size 2 8 --threads 2
    (cd old-checkout && python /path/to/gnsx/perf/throughput.py --data ... )   # the same loop on older code
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from gnsx.core.cli import ArgumentParser, check_int, check_output_path, run_main
from gnsx.core.errors import ConfigError
from gnsx.core.threads import apply_threads
from gnsx.data.datamodule import ParticleDataModule
from gnsx.model.registry import MODELS
from gnsx.training.system import GNSSystem


class _StepClock(Callback):
    """Wall-clock time at the end of every training batch (synchronised on CUDA)."""

    def __init__(self):
        self.times: list[float] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        if torch.cuda.is_available() and pl_module.device.type == "cuda":
            torch.cuda.synchronize()
        self.times.append(time.perf_counter())


def measure_training(
    data_root: str | Path,
    model: str = "simplified",
    batch_size: int = 2,
    steps: int = 200,
    warmup: int = 20,
    windows: int = 5,
    device: str = "cpu",
    seed: int = 0,
    devices: int = 1,
    precision: str = "32-true",
) -> dict:
    """Time ``steps`` optimizer steps after ``warmup`` of the Lightning training loop.

    Args:
        data_root: a gnsx dataset (its train split is sampled, its metadata configures the model).
        model: a key of :data:`gnsx.model.registry.MODELS`.
        batch_size: graphs per step.
        steps, warmup, windows: timed steps, untimed first steps, windows the timed steps are cut into.
        device: ``"cpu"`` or ``"cuda"``.
        devices: data-parallel processes (DDP; on the CPU over gloo, one per core with one thread each):
            a step then takes ``batch_size`` samples on every process.
        precision: Lightning's ``Trainer(precision=...)``: ``"32-true"``, ``"bf16-mixed"`` (autocast) or
            ``"auto"`` (:func:`gnsx.training.precision.resolve_precision`; the result names what ran).
    Returns:
        ``{"model", "batch_size", "device", "threads", "steps_per_s", "samples_per_s", "ms_per_step",
        "window_steps_per_s": [...]}`` (rates are medians over the windows).
    """
    if steps < windows or windows < 1:
        raise ValueError(
            f"measure_training: need steps >= windows >= 1, got steps={steps}, windows={windows}"
        )
    L.seed_everything(seed, workers=True)
    arch = MODELS[model]
    datamodule = ParticleDataModule(data_root, history=arch.get("history", 1), batch_size=batch_size)
    meta = datamodule.metadata
    system = GNSSystem(
        model=dict(arch),
        dim=meta.dim,
        bounds=[list(map(float, b)) for b in meta.bounds],
        radius=float(meta.default_connectivity_radius),
        vel_mean=list(meta.vel_mean),
        vel_std=list(meta.vel_std),
        acc_mean=list(meta.acc_mean),
        acc_std=list(meta.acc_std),
        noise_std=1e-4,
        lr_init=1e-4,
        lr_final=1e-6,
        lr_decay_start=0,
        lr_decay_end=10 * (steps + warmup),
    )
    if (
        precision == "auto"
    ):  # imported here: older checkouts (module docstring) have no gnsx.training.precision
        from gnsx.training.precision import resolve_precision

        precision = resolve_precision(precision, device)
    clock = _StepClock()
    trainer = L.Trainer(
        accelerator=device,
        devices=devices,
        strategy="ddp" if devices > 1 else "auto",
        precision=precision,
        max_steps=warmup + steps,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[clock],
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trainer.fit(system, datamodule=datamodule)
    times = clock.times[warmup - 1 :]  # the end of the last warm-up step starts the clock
    per_window = (len(times) - 1) // windows
    rates = [per_window / (times[(k + 1) * per_window] - times[k * per_window]) for k in range(windows)]
    steps_per_s = statistics.median(rates)
    return {
        "model": model,
        "batch_size": batch_size,
        "device": device,
        "threads": torch.get_num_threads(),
        "devices": devices,
        "precision": precision,
        "steps_per_s": steps_per_s,
        "samples_per_s": steps_per_s * batch_size * devices,
        "ms_per_step": 1000.0 / steps_per_s,
        "window_steps_per_s": rates,
        "device_name": _device_name(device),
    }


def _device_name(device: str) -> str:
    """The GPU's or the CPU's name (the CPU's generation and matrix extensions: gnsx.core.machine); older
    checkouts without gnsx.core.machine (module docstring) get the bare platform name."""
    if device == "cuda":
        return torch.cuda.get_device_name()
    try:
        from gnsx.core.machine import cpu_name
    except ImportError:
        import platform

        return platform.processor() or "cpu"
    return cpu_name()


def main(argv: list[str] | None = None) -> int:
    """The command line; bad input prints one line and returns 2 (:func:`gnsx.core.cli.run_main`)."""
    return run_main(_main, argv)


def _main(argv: list[str]) -> int:
    parser = ArgumentParser(
        prog="python -m gnsx.perf.throughput",
        description="Training samples/s and steps/s of the Lightning training loop on a gnsx dataset.",
    )
    parser.add_argument("--data", default="data/small", help="gnsx dataset folder (default data/small)")
    parser.add_argument("--models", nargs="+", default=["simplified"], choices=sorted(MODELS))
    parser.add_argument("--batch-size", type=int, nargs="+", default=[2, 8])
    parser.add_argument("--steps", type=int, default=200, help="timed steps (default 200)")
    parser.add_argument("--warmup", type=int, default=20, help="untimed first steps (default 20)")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument(
        "--devices", type=int, default=1, help="DDP processes (CPU: one per core, --threads 1)"
    )
    parser.add_argument(
        "--precision",
        nargs="+",
        default=["32-true"],
        choices=["auto", "32-true", "bf16-mixed"],
        help="training precision(s) to time (default 32-true; bf16-mixed is autocast; auto: gnsx.training.precision)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = parser.parse_args(argv)
    if not (Path(args.data) / "metadata.json").is_file():
        raise ConfigError(
            f"--data {args.data}", "no gnsx dataset here (metadata.json missing); `make data` makes one"
        )
    threads = [] if args.threads is None else [args.threads]
    flags = {
        "--batch-size": (args.batch_size, 1),
        "--steps": ([args.steps], 1),
        "--warmup": ([args.warmup], 0),
        "--devices": ([args.devices], 1),
        "--threads": (threads, 1),
    }
    for flag, (values, minimum) in flags.items():
        for value in values:
            check_int(value, flag, minimum=minimum)
    if args.json:
        check_output_path(args.json, "--json")
    apply_threads(args.threads or None)
    results = []
    # Under DDP every process runs this; rank 0 alone prints (the launcher sets LOCAL_RANK for the others).
    report = os.environ.get("LOCAL_RANK", "0") == "0"
    if report:
        print(
            f"{'model':<11} {'precision':<10} {'batch':>5} {'steps/s':>8} {'samples/s':>10} {'ms/step':>8}"
            "  device (threads)"
        )
    for model in args.models:
        for precision in args.precision:
            for batch_size in args.batch_size:
                r = measure_training(
                    args.data,
                    model,
                    batch_size,
                    args.steps,
                    args.warmup,
                    device=args.device,
                    devices=args.devices,
                    precision=precision,
                )
                results.append(r)
                if not report:
                    continue
                print(
                    f"{model:<11} {precision:<10} {batch_size:>5} {r['steps_per_s']:>8.2f} "
                    f"{r['samples_per_s']:>10.1f} {r['ms_per_step']:>8.1f}  {r['device']} ({r['threads']})"
                    + (f" x {args.devices} DDP processes" if args.devices > 1 else ""),
                    flush=True,
                )
    if results and report:
        print(f"on {results[0]['device_name']}")
    if args.json and report:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
