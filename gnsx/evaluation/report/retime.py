"""``python -m gnsx.evaluation.report.retime <sweep dir>``: time every finished job of a sweep again, together,
in one process, so that the speed axis of the report compares like with like.

A sweep job times its model right after training, under whatever else the machine runs then: with the
parallel launcher the other job trains on the second core, and figure 9's first CPU run measured 110 ms/frame
for 64/5 against 51 ms for 64/3. Here every job's final weights (``checkpoints/last.ckpt``) predict one frame
of the same WaterRamps-size scene the job used (its ``bench``: particle count, spacing and domain scale), with
the jobs interleaved in a new random order each round, so a burst of load hits every job alike; a job's figure
is the median over rounds of each round's median. Memory is counted exactly, not as the process's peak RSS
(which depends on what the process ran before): the peak of one frame's tensors plus the weights
(:func:`gnsx.evaluation.tensor_memory.frame_memory`).

A committed job record without its checkpoint is timed as the untrained model its ``results.json``
describes: the cost of a frame does not depend on the weights. Each job's ``results.json`` keeps the in-job
measurement as ``bench_in_job`` and gets the new one as ``bench`` (with ``"timing": "retimed ..."``, the
rounds, repeats, threads and which weights), which the report then uses. Run it on an otherwise idle machine;
``--threads 1`` matches how the sweep jobs were timed (one thread each).
"""

from __future__ import annotations

import argparse
import json
import random
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnsx.core.atomic import write_json
from gnsx.core.cli import run_main


def timed_jobs(sweep_dir: Path) -> tuple[list[Path], list[str]]:
    """Job folders that can be retimed (finished, a ``bench`` with its scene, final weights), and a line for
    each folder skipped."""
    ready, skipped = [], []
    for folder in sorted(p for p in sweep_dir.iterdir() if (p / "results.json").is_file()):
        results = json.loads((folder / "results.json").read_text())
        bench = results.get("bench_in_job") or results.get("bench") or {}
        if results.get("status") != "ok":
            skipped.append(f"{folder.name}: status {results.get('status')}")
        elif not bench.get("spacing") or not bench.get("num_particles"):
            skipped.append(f"{folder.name}: no benchmark scene recorded (bench.spacing, bench.num_particles)")
        elif not (folder / "checkpoints" / "last.ckpt").is_file() and not results.get("model_config"):
            skipped.append(
                f"{folder.name}: neither checkpoints/last.ckpt nor the model config in results.json"
            )
        else:
            ready.append(folder)
    return ready, skipped


def job_model(folder: Path, results: dict):
    """The job's final weights, or (a committed record without them) the untrained model its results.json
    describes, with WaterRamps' bounds and statistics like the small preset's (a frame's cost does not depend
    on the weights); and which of the two it is."""
    import inspect

    from gnsx.model.checkpoint import load_simulator
    from gnsx.model.registry import build_model
    from gnsx.model.simulator import LearnedSimulator

    checkpoint = folder / "checkpoints" / "last.ckpt"
    if checkpoint.is_file():
        return load_simulator(checkpoint), "final weights"
    config = results["model_config"]
    params = inspect.signature(LearnedSimulator.__init__).parameters
    arch = {k: v for k, v in config.items() if k in params and k not in ("radius", "dim", "compile")}
    if "wall_clip" in arch:
        arch["wall_clip"] = tuple(arch["wall_clip"])
    return build_model(
        config["name"], radius=float(config["radius"]), **arch
    ), "untrained (no checkpoint here)"


def job_scene(bench: dict, bounds: np.ndarray, history: int):
    """The packed scene a job was timed on: ``bench["num_particles"]`` at ``bench["spacing"]`` in the data's
    ``bounds [D, 2]`` grown by ``bench["domain_scale"]`` (:func:`gnsx.evaluation.timing.packed_scene`)."""
    from gnsx.evaluation.timing import packed_scene

    extent = bounds[:, 1] - bounds[:, 0]
    scale = float(bench.get("domain_scale") or 1.0)
    grown = np.stack([bounds[:, 0], bounds[:, 0] + scale * extent], axis=1)
    return packed_scene(int(bench["num_particles"]), float(bench["spacing"]), grown, history)


def retime(
    sweep_dir: Path, threads: int = 1, rounds: int = 5, repeats: int = 10, warmup: int = 3, seed: int = 0
) -> dict[str, dict]:
    """Retime every ready job (:func:`timed_jobs`); write each one's ``results.json``; return the new
    benches by folder name."""
    import torch

    from gnsx.core.threads import apply_threads
    from gnsx.evaluation.tensor_memory import frame_memory
    from gnsx.evaluation.timing import measure_inference

    ready, skipped = timed_jobs(sweep_dir)
    for line in skipped:
        print(f"skipped {line}")
    if not ready:
        raise FileNotFoundError(f"{sweep_dir}: no job to retime ({len(skipped)} skipped)")
    used = apply_threads(threads)
    models: dict[str, dict] = {}
    first: dict[str, dict] = {}
    for folder in ready:
        results = json.loads((folder / "results.json").read_text())
        bench = results.get("bench_in_job") or results["bench"]
        simulator, weights = job_model(folder, results)
        sequence, types = job_scene(
            bench, simulator.bounds.cpu().numpy().astype(np.float64), simulator.history
        )
        models[folder.name] = {"folder": folder, "results": results, "bench": bench, "simulator": simulator,
                               "sequence": sequence, "types": types, "medians": [], "weights": weights}  # fmt: skip
    order = list(models)
    rng = random.Random(seed)
    with torch.inference_mode():
        for round_index in range(rounds):
            rng.shuffle(order)
            for name in order:
                m = models[name]
                measured = measure_inference(m["simulator"], m["sequence"], m["types"], warmup, repeats)
                m["medians"].append(measured["ms_per_frame"])
                first.setdefault(name, measured)
            print(f"round {round_index + 1}/{rounds} done")
        for m in models.values():
            m["memory"] = frame_memory(m["simulator"], m["sequence"], m["types"])
    out = {}
    for name, m in models.items():
        measured = first[name]
        bench = {
            **m["bench"],
            "ms_per_frame": float(np.median(m["medians"])),
            "ms_per_frame_min": float(np.min(m["medians"])),
            "ms_per_frame_rounds": m["medians"],
            # Exact and the same whatever ran before in this process (a shared process's peak RSS is not:
            # it counted 53 MB for 64/5 here against 77 MB inside the job).
            **m["memory"],
            "num_edges": measured.get("num_edges"),
            "timing": f"retimed with every job of the sweep in one process, interleaved ({rounds} rounds of "
            f"{repeats} frames after {warmup} warm-ups; median of the round medians)",
            "threads": used,
            "weights": m["weights"],
            "repeats": repeats,
        }
        results = m["results"]
        results.setdefault("bench_in_job", m["bench"])
        results["bench"] = bench
        write_json(m["folder"] / "results.json", results)
        out[name] = bench
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gnsx.evaluation.report.retime", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("sweep", type=Path, help="multirun folder of the sweep")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the sweep jobs' count: 1)")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds over every job")
    parser.add_argument("--repeats", type=int, default=10, help="timed frames per job and round")
    parser.add_argument("--warmup", type=int, default=3, help="untimed frames before each job's frames")
    args = parser.parse_args(argv)
    if not args.sweep.is_dir():
        raise FileNotFoundError(f"{args.sweep}: no such sweep folder")
    if min(args.threads, args.rounds, args.repeats) < 1 or args.warmup < 0:
        raise ValueError("--threads, --rounds and --repeats must be >= 1, --warmup >= 0")
    benches = retime(args.sweep, args.threads, args.rounds, args.repeats, args.warmup)
    width = max(map(len, benches))
    for name, bench in sorted(benches.items(), key=lambda kv: kv[1]["ms_per_frame"]):
        print(f"{name:<{width}}  {bench['ms_per_frame']:8.1f} ms/frame (min {bench['ms_per_frame_min']:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, user_errors=(FileNotFoundError, ValueError)))
