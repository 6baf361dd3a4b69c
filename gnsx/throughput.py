"""Kept for now so that `python -m gnsx.throughput` still works:
the tool is :mod:`gnsx.perf.throughput` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.perf.throughput", run_name="__main__", alter_sys=True)
