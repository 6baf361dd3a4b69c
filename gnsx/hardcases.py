"""Kept for now so that `python -m gnsx.hardcases` still works:
the tool is :mod:`gnsx.evaluation.hardcases` (README, "Code structure")."""

import runpy

if __name__ == "__main__":
    runpy.run_module("gnsx.evaluation.hardcases", run_name="__main__", alter_sys=True)
