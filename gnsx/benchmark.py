"""Kept for now so that `python -m gnsx.benchmark` still works:
the tool is :mod:`gnsx.perf.benchmark` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.perf.benchmark", run_name="__main__", alter_sys=True)
