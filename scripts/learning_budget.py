"""Turn the learning study's training-time budget into a step budget per arm (sweeps/learning.yaml).

Each arm of ``sweeps/learning_arm/`` trains ``--steps`` steps here, two arms at a time with one torch thread
each (as the study runs), and its time per step (validation excluded, results.json's ``steps_per_s``) sets
its ``train.max_steps`` to ``--minutes`` of training and ``train.curve_every_n_steps`` to a sixth of that.
The arm files are rewritten in place and the measurement is saved as JSON beside the study's docs.

    .venv/bin/python scripts/learning_budget.py --minutes 20 --out docs/learning/budget.json

Why a step budget measured once: a clock budget gives an arm fewer steps whenever other work loads the
machine, so the arms would not be comparable; the steps fixed here train the same model whatever the load.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ARMS = ROOT / "sweeps" / "learning_arm"
#: Validations per arm along its budget (the learning curve's points).
CURVE_POINTS = 6


def time_arm(arm: str, steps: int, out: Path) -> float:
    """Steps per second of ``arm`` over ``steps`` training steps (one thread, no validation, no loggers)."""
    run_dir = out / arm
    command = [sys.executable, str(ROOT / "train.py"), "--config-dir", str(ROOT / "sweeps"),
               "--config-name", "learning", f"learning_arm={arm}", f"train.max_steps={steps}",
               "train.curve_every_n_steps=null", "logger=none", "sweep.resume=false",
               f"hydra.run.dir={run_dir}"]  # fmt: skip
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{arm}: calibration run failed:\n{done.stderr[-2000:]}")
    rate = json.loads((run_dir / "results.json").read_text())["steps_per_s"]
    print(f"{arm}: {rate:.2f} steps/s", flush=True)
    return float(rate)


def set_budget(path: Path, max_steps: int, every: int) -> None:
    """Write ``max_steps`` and ``curve_every_n_steps`` into an arm file (placeholders or earlier numbers)."""
    text = path.read_text()
    text = re.sub(r"(\n  max_steps: )\S+", rf"\g<1>{max_steps}", text)
    text = re.sub(r"(\n  curve_every_n_steps: )\S+", rf"\g<1>{every}", text)
    path.write_text(text)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=20.0, help="training minutes per arm (default 20)")
    parser.add_argument("--steps", type=int, default=300, help="calibration steps per arm (default 300)")
    parser.add_argument("--arms", nargs="*", default=None, help="arms to time (default: every arm file)")
    parser.add_argument(
        "--out", type=Path, default=None, help="JSON of the measurement (default: print only)"
    )
    args = parser.parse_args(argv)
    arms = args.arms or sorted(p.stem for p in ARMS.glob("*.yaml"))
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(2) as pool:  # two jobs at once
        rates = dict(zip(arms, pool.map(lambda arm: time_arm(arm, args.steps, Path(tmp)), arms)))
    budget = {}
    for arm, rate in rates.items():
        # Rounded to a multiple of the curve's points (x100), so every validation falls on a whole step.
        unit = 100 * CURVE_POINTS
        max_steps = max(unit, int(round(args.minutes * 60 * rate / unit)) * unit)
        budget[arm] = {
            "steps_per_s": rate,
            "max_steps": max_steps,
            "curve_every_n_steps": max_steps // CURVE_POINTS,
        }
        set_budget(ARMS / f"{arm}.yaml", max_steps, max_steps // CURVE_POINTS)
        print(f"{arm}: {max_steps} steps in {args.minutes:g} min")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        record = {"minutes": args.minutes, "calibration_steps": args.steps, "threads": 1, "parallel_jobs": 2,
                  "arms": budget}  # fmt: skip
        args.out.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
