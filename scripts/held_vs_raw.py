"""The shipped weights on data/small's 16 test trajectories: rollouts held by the boundary (the default)
against the raw model; the baseline is held by the same boundary in both. Prints both tables and the paired
comparison, and writes outputs/shipped_held_vs_raw.json.

    .venv/bin/python scripts/held_vs_raw.py      # ~10 min on one CPU thread
"""

import json
import sys
from pathlib import Path

import torch

from gnsx.data.datamodule import TrajectoryDataset
from gnsx.data.metadata import Metadata
from gnsx.data.store import SplitReader
from gnsx.evaluation.scoring import evaluate_simulator, format_table, json_ready
from gnsx.evaluation.spread import compare, format_comparison
from gnsx.model.checkpoint import load_simulator


def main() -> None:
    torch.set_num_threads(1)
    simulator = load_simulator("pretrained/small/model.ckpt")
    metadata = Metadata.load("data/small/metadata.json")
    test = TrajectoryDataset(SplitReader("data/small", "test"))
    out = {}
    for name, constrain in (("held", True), ("raw", False)):
        summary, rows, _ = evaluate_simulator(
            simulator, test, metadata, keep_first=False, timing_repeats=0, constrain=constrain
        )
        out[name] = {"summary": summary, "rows": rows}
        print(format_table(rows, summary, f"shipped weights, {name}", colour=False))
        sys.stdout.flush()
    for key in ("rollout_mse", "emd"):
        print(format_comparison(compare(out["held"]["rows"], out["raw"]["rows"], key), "held", "raw"))
    Path("outputs").mkdir(exist_ok=True)
    Path("outputs/shipped_held_vs_raw.json").write_text(json.dumps(json_ready(out), indent=1))


if __name__ == "__main__":
    main()
