"""Kept for now so that `python -m gnsx.mpm.sensitivity` still works:
the tool is :mod:`gnsx.evaluation.sensitivity` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.evaluation.sensitivity", run_name="__main__", alter_sys=True)
