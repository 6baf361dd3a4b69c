"""Paired comparison of two sweep jobs over the test trajectories both scored, for pairs a report does not
print (report.md compares each job with the reference cell and with the best one only).

    python scripts/paired_jobs.py JOB_A JOB_B [JOB_A JOB_B ...] [--key rollout_mse]

Each JOB is a job folder holding ``results.json`` (e.g. ``docs/radius/jobs/<overrides>``). Prints B/A: the
geometric mean over trajectories of B's error over A's, its 95% t interval and the verdict of
:func:`gnsx.evaluation.spread.compare`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from gnsx.evaluation.spread import compare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("jobs", nargs="+", type=Path, help="job folders, in pairs A B")
    parser.add_argument("--key", default="rollout_mse")
    args = parser.parse_args()
    if len(args.jobs) % 2:
        parser.error("give the job folders in pairs: A B [A B ...]")
    for a, b in zip(args.jobs[::2], args.jobs[1::2]):
        rows = [json.loads((job / "results.json").read_text())["rows"] for job in (a, b)]
        result = compare(*rows, args.key)
        if result is None:
            print(f"{b.name} / {a.name}: no shared trajectories")
            continue
        print(f"{b.name} / {a.name}: {result['ratio']:.2f}x [{result['lo']:.2f}, {result['hi']:.2f}] over "
              f"{result['trajectories']} trajectories: {result['verdict']}")  # fmt: skip


if __name__ == "__main__":
    main()
